"""``torchhand batch MANIFEST --out DIR``: many jobs from one manifest, resumable and exactly once, on a local
process pool or a Ray cluster (docs/batch.md).

MANIFEST (batch.toml) has a [defaults] table and [[jobs]] tables naming a method (synthesize, manipulate,
capture) whose lists expand as a product (scenes x seeds x hands; scenes x grasps; interactions x scenes); options
are the method's flags (max_nodes = 400 is --max-nodes 400). Each job writes a result
directory (docs/result_format.md) atomically to DIR/jobs/<id>/, with the checker's report (check.json); DIR/jobs.jsonl
records every start, finish and failure; DIR/summary.csv, summary.md and summary.png are written at the end of
every run. Run the same command again after an interruption (Ctrl-C, kill -9, a crash, a reboot): finished jobs
are kept, the others run again from the start, no job is finished twice. A job that fails is recorded and the batch
goes on.

Exit code 0 when every job of the manifest is finished (a manipulate job whose grasp is unsuitable is finished:
that is its answer), 1 when some failed (run again to retry them), 2 for bad
input (nothing is written), 130 when interrupted.
"""

from __future__ import annotations

import argparse
import os
import sys

from ..errors import InputValueError
from ._common import Progress


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("batch", help="run a manifest of jobs, resumably, on a local pool or a Ray cluster",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("manifest", metavar="MANIFEST", help="the batch manifest (TOML, docs/batch.md)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="batch directory: new, empty, or this manifest's earlier batch (resumed); checked before "
                        "any work")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="jobs at a time (default: one per usable CPU, or per GPU with --device cuda; with a Ray "
                        "cluster address: as many as its CPUs hold)")
    p.add_argument("--threads", type=int, default=None, metavar="N",
                   help="torch threads per job (default: usable CPUs // workers, at least 1; with a Ray cluster "
                        "address: 1); results are reproducible for a given thread count")
    p.add_argument("--ray", metavar="ADDRESS|auto", default=None,
                   help="run the jobs as Ray tasks: 'auto' starts a local Ray instance with workers x threads CPUs, "
                        "an address joins a cluster (pip install 'torchhand[ray]')")
    p.add_argument("--device", default="cpu", choices=["cpu", "cuda"], help="device of every job (default cpu)")
    p.add_argument("--group", type=int, default=None, metavar="N",
                   help="synthesis jobs that differ only by seed run N to a worker process, their searches as one "
                        "batch (each job's files are the ones it gets alone); 0: all of them, split over the "
                        "workers (default with --device cuda: one process per GPU), 1: one job per process (default "
                        "on the CPU); Ray runs one job per task")
    p.add_argument("--update", action="store_true",
                   help="accept a manifest whose jobs differ from those DIR was started with: it becomes the "
                        "batch's; finished jobs it shares are kept")
    p.add_argument("--no-progress", action="store_true", help="no progress bar or progress lines")
    p.set_defaults(func=run)


def _gpus(args) -> tuple[str, ...]:
    """CUDA devices for local workers (InputValueError when --device cuda has none)."""
    if args.device != "cuda" or (args.ray and args.ray != "auto"):
        return ()
    import torch

    if not torch.cuda.is_available():
        raise InputValueError("--device cuda: no CUDA device is available; use --device cpu")
    visible = os.environ.get("CUDA_VISIBLE_DEVICES", "").strip()
    return tuple(v.strip() for v in visible.split(",") if v.strip()) if visible else \
        tuple(str(i) for i in range(torch.cuda.device_count()))


def _n(count: int, word: str) -> str:
    return f"{count} {word}{'' if count == 1 else 's'}"


def _duration(s: float | None) -> str:
    if s is None:
        return "?"
    s = int(round(s))
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s" if s >= 60 else f"{s}s"


def run(args) -> int:
    from ..batch import load_manifest, plan_run, run_batch
    from ..batch.store import validate_out

    plan = plan_run(workers=args.workers, threads=args.threads, device=args.device, ray=args.ray,
                    group=args.group)  # bad numbers
    manifest = load_manifest(args.manifest)
    if args.ray is not None:
        from ..batch.ray_backend import check_address, require_ray

        require_ray()
        if args.ray != "auto":
            check_address(args.ray)
    gpus = _gpus(args)
    if gpus:
        plan = plan_run(workers=args.workers, threads=args.threads, device=args.device, ray=args.ray, gpus=gpus,
                        group=args.group)
    validate_out(args.out, manifest, update=args.update)
    bar = Progress("batch", disable=args.no_progress)
    write = (lambda line: bar.bar.write(line, file=sys.stdout)) if bar.bar is not None else print

    if plan.backend == "local" or plan.ray_address == "local":
        where = f"{_n(plan.workers, 'worker')} x {_n(plan.threads, 'thread')} ({_n(plan.cpus, 'CPU')})"
        if plan.workers * plan.threads > plan.cpus:
            where += ", oversubscribed"
    else:
        where = f"Ray cluster {plan.ray_address}, {_n(plan.threads, 'thread')} per job"
    write(f"batch: {len(manifest.jobs)} jobs from {args.manifest} into {args.out}; {where}"
          + (" on Ray" if plan.ray_address == "local" else "") + f", device {plan.device}"
          + ("" if plan.group == 1 else "; seeds of a synthesis job batched in one process ("
             + ("all, split over the workers" if plan.group == 0 else f"{plan.group} at a time") + ")"))

    def notify(kind, job_id, record, c):
        if kind == "finish":
            write(f"finished {job_id}: {record.get('solutions')} solution(s), check {record.get('check')}"
                  + (f", {record['seconds']:.1f} s" if record.get("seconds") is not None else "")
                  + (" (recovered)" if record.get("recovered") else "")
                  + (" (grasp unsuitable: not retried)" if record.get("outcome") == "unsuitable" else ""))
        elif kind == "fail":
            write(f"FAILED {job_id} (attempt {record.get('attempt')}): {record.get('error')} "
                  f"[{record.get('log', '')}]")
        text = (f"{c.done}/{c.total} done, {c.running} running, {c.failed} failed"
                + (f", ETA {_duration(c.eta_s)}" if c.running or c.done + c.failed < c.total else ""))
        bar.update("jobs", text, (c.done + c.failed) / max(c.total, 1))

    try:
        outcome = run_batch(manifest, args.out, plan, update=args.update, notify=notify, note=write)
    finally:
        bar.close()
    done = outcome.already + len(outcome.finished)
    print(f"batch: {outcome.total} jobs: {done} finished ({outcome.already} before this run), "
          f"{len(outcome.failed)} failed, {len(outcome.pending)} not run; wrote "
          + ", ".join(str(p) for p in outcome.summary))
    if outcome.failed:
        print(f"{len(outcome.failed)} job(s) failed (errors in {os.path.join(args.out, 'summary.md')} and "
              f"jobs.jsonl); run the same command again to retry them", file=sys.stderr)
    if outcome.interrupted:
        print("torchhand: interrupted; run the same command again to resume", file=sys.stderr)
        return 130
    return 0 if done == outcome.total else 1
