"""Batch runs: many jobs from one manifest, resumable and exactly once, on one machine or a Ray cluster
(``torchhand batch MANIFEST --out DIR``, docs/batch.md): jobs of ``torchhand synthesize``, ``torchhand manipulate``
and ``torchhand capture resynthesize``.

==================== ====================================================================================
module               what
==================== ====================================================================================
:mod:`.manifest`     ``batch.toml``: parsing, validation, expansion (synthesize, manipulate, capture), job ids
:mod:`.inputs`       every scene, hand, grasp and interaction of a manifest loaded once, before any work
:mod:`.store`        the batch directory: layout, the journal ``jobs.jsonl``, the lock, exactly-once promotion
:mod:`.worker`       one attempt of one job, in its own process: the method, then the checker
:mod:`.runner`       threads per worker, the local process pool, :func:`run_batch`
:mod:`.ray_backend`  the same attempts as Ray tasks (optional extra ``torchhand[ray]``, imported lazily)
:mod:`.summary`      ``summary.csv`` / ``.md`` / ``.png`` from what is on disk
==================== ====================================================================================

Example::

    from torchhand.batch import load_manifest, plan_run, run_batch
    manifest = load_manifest("examples/batch.toml")
    outcome = run_batch(manifest, "out/batch", plan_run(workers=2))
    print(outcome.finished, outcome.failed)

Units: seconds for every time; node tests per second of search.
"""

from __future__ import annotations

from .manifest import Job, Manifest, load_manifest, parse_manifest
from .runner import BatchOutcome, Counts, RunPlan, plan_run, run_batch, usable_cpus
from .summary import write_summary

__all__ = ["Job", "Manifest", "load_manifest", "parse_manifest", "RunPlan", "Counts", "BatchOutcome", "plan_run",
           "run_batch", "usable_cpus", "write_summary"]
