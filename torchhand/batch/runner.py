"""Running a batch: the plan (workers × threads), the local process pool, and :func:`run_batch`, which ties the
manifest, the batch directory (:mod:`.store`), a backend (local or Ray) and the summary together.

Threads: every job runs with an explicit torch thread count, ``threads``, recorded in ``batch.json``, in each
job's ``job.json`` and in its ``stats.json``. A seed with a node budget gives the same result for the same thread
count (docs/synthesis.md), so the count is chosen once per run: ``--threads``, else ``CPUs // workers`` (at least
1), where CPUs are the ones this process may use (``os.sched_getaffinity``) and workers default to one per CPU.
So ``workers × threads ≤ CPUs`` unless both are given explicitly.

Local pool: one worker subprocess (:mod:`.worker`) per running job, at most ``workers`` at a time, polled by this
single-threaded loop. A worker that crashes or is killed is a failed attempt, recorded; the batch goes on.

Modules: ``_plan`` (:class:`RunPlan`, :func:`plan_run`, the rule above), ``_progress`` (:class:`Counts` and the
tracker both backends report to); this module holds the local pool and :func:`run_batch`, re-exporting the plan.
"""

from __future__ import annotations

import collections
import fcntl
import os
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

from . import worker
from ._plan import RunPlan, plan_run, usable_cpus
from ._progress import Counts, _Tracker
from .manifest import Job, Manifest
from .store import Journal, Layout, finish_attempt, open_batch, recover

__all__ = ["RunPlan", "Counts", "BatchOutcome", "usable_cpus", "plan_run", "run_batch"]


@dataclass(frozen=True)
class BatchOutcome:
    """What a run did. finished: jobs finished in this run; already: finished before it; failed: ids whose last
    attempt of this run failed; pending: jobs not run (interrupted); summary: files written; unsuitable: the jobs of
    ``finished`` whose answer is "grasp unsuitable" (manipulate)."""

    total: int
    already: int
    finished: tuple[str, ...]
    failed: tuple[str, ...]
    pending: tuple[str, ...]
    plan: RunPlan
    summary: tuple[Path, ...]
    interrupted: bool = False
    unsuitable: tuple[str, ...] = ()


def run_local(layout: Layout, journal: Journal, todo: list[tuple[Job, int]], plan: RunPlan,
              tracker: _Tracker) -> None:
    """Run ``todo`` ((job, attempt) pairs) on a pool of ``plan.workers`` worker subprocesses."""
    queue = collections.deque(todo)
    running: dict[int, tuple[Job, int, subprocess.Popen, float]] = {}          # slot -> attempt
    try:
        while queue or running:
            for slot in range(plan.workers):
                if queue and slot not in running:
                    job, n = queue.popleft()
                    running[slot] = _launch(layout, journal, job, n, plan, slot, tracker)
            time.sleep(0.1)
            for slot, (job, n, proc, t0) in list(running.items()):
                rc = proc.poll()
                if rc is None:
                    continue
                del running[slot]
                log = layout.log(job.id, n)
                record = finish_attempt(layout, journal, job, n, returncode=rc,
                                        error="" if rc == 0 else worker.describe_exit(rc, log),
                                        meta=_meta(plan, t0, proc.pid, rc))
                tracker.event(record["event"], job.id, record)
    except BaseException:                  # Ctrl-C or a bug: stop the workers, record their attempts as failed
        for job, n, proc, t0 in running.values():
            proc.terminate()
        for job, n, proc, t0 in running.values():
            try:
                rc = proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                rc = proc.wait()
            record = finish_attempt(layout, journal, job, n, returncode=rc, error="interrupted: the batch process "
                                    "stopped its workers", meta=_meta(plan, t0, proc.pid, rc))
            tracker.event(record["event"], job.id, record)
        raise


def _meta(plan: RunPlan, t0: float, pid: int | None, rc: int | None) -> dict:
    import socket

    return {"threads": plan.threads, "device": plan.device, "backend": plan.backend, "host": socket.gethostname(),
            "pid": pid, "returncode": rc, "seconds": round(time.monotonic() - t0, 3)}


def _launch(layout: Layout, journal: Journal, job: Job, n: int, plan: RunPlan, slot: int, tracker: _Tracker):
    stage, log = layout.stage(job.id, n), layout.log(job.id, n)
    env = worker.environment(plan.threads)
    if plan.gpus:
        env["CUDA_VISIBLE_DEVICES"] = plan.gpus[slot % len(plan.gpus)]
    with open(log, "ab") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)       # a fresh file; the worker inherits the lock
        t0 = time.monotonic()
        proc = subprocess.Popen(worker.command(job.argv(), stage, plan.threads, plan.device), stdout=fh,
                                stderr=subprocess.STDOUT, cwd=layout.logs, env=env, **worker.popen_kwargs())
    record = journal.append("start", job=job.id, attempt=n, pid=proc.pid, threads=plan.threads,
                            device=worker.run_device(job.method, plan.device),
                            backend="local", log=str(log.relative_to(layout.root)))
    tracker.event("start", job.id, record)
    return job, n, proc, t0


def run_batch(manifest: Manifest, out, plan: RunPlan, *, update: bool = False, notify=None,
              note=lambda line: None) -> BatchOutcome:
    """Run every unfinished job of ``manifest`` into the batch directory ``out`` with ``plan``, then write the
    summary (:func:`torchhand.batch.summary.write_summary`), also when interrupted.

    notify: ``notify(kind, job_id, record, counts)`` on every start / finish / fail (:class:`Counts`)
    note: ``note(line)`` for remarks (removed staging directories, recovered attempts)
    Raises InputValueError for a bad ``out`` (before any work) or a busy batch directory.
    """
    from .summary import write_summary

    layout, journal, lock = open_batch(Path(out), manifest, plan.to_dict(), update=update)
    try:
        finished, attempt = recover(layout, journal, manifest.jobs, note=note)
        todo = [(j, attempt[j.id]) for j in manifest.jobs if j.id not in finished]
        tracker = _Tracker(len(manifest.jobs), len(finished), notify)
        journal.append("batch", action="begin", pid=os.getpid(), jobs=len(manifest.jobs), finished=len(finished),
                       to_run=len(todo), **plan.to_dict())
        tracker.event("begin", "")
        interrupted = False
        try:
            if todo and plan.backend == "ray":
                from .ray_backend import run_ray

                run_ray(layout, journal, todo, plan, tracker)
            elif todo:
                run_local(layout, journal, todo, plan, tracker)
        except KeyboardInterrupt:
            interrupted = True
        finally:
            paths = write_summary(layout.root)
            journal.append("batch", action="end", pid=os.getpid(), finished=len(tracker.finished),
                           failed=len(tracker.failed), interrupted=interrupted)
        done = set(tracker.finished) | set(tracker.failed)
        return BatchOutcome(total=len(manifest.jobs), already=len(finished), finished=tuple(tracker.finished),
                            failed=tuple(tracker.failed), pending=tuple(j.id for j, _ in todo if j.id not in done),
                            plan=plan, summary=tuple(paths), interrupted=interrupted,
                            unsuitable=tuple(tracker.unsuitable))
    finally:
        lock.close()
