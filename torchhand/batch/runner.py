"""Running a batch: the plan (workers × threads), the local process pool, and :func:`run_batch`, which ties the
manifest, the batch directory (:mod:`.store`), a backend (local or Ray) and the summary together.

Threads: every job runs with an explicit torch thread count, ``threads``, recorded in ``batch.json``, in each
job's ``job.json`` and in its ``stats.json``. A seed with a node budget gives the same result for the same thread
count (docs/synthesis.md), so the count is chosen once per run: ``--threads``, else ``CPUs // workers`` (at least
1), where CPUs are the ones this process may use (``os.sched_getaffinity``) and workers default to one per CPU.
So ``workers × threads ≤ CPUs`` unless both are given explicitly.

Local pool: one worker subprocess (:mod:`.worker`) per running job, at most ``workers`` at a time, polled by this
single-threaded loop. A worker that crashes or is killed is a failed attempt, recorded; the batch goes on. With
``group`` other than 1 (the default on a GPU), synthesis jobs that differ only by seed share a worker process, whose
searches run as one batch (:func:`units`); each job keeps its own attempt, staging directory, log and exactly-once
promotion, and a worker that dies fails the attempts of all its jobs.

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

__all__ = ["RunPlan", "Counts", "BatchOutcome", "usable_cpus", "plan_run", "run_batch", "units"]


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
    """Run ``todo`` ((job, attempt) pairs) on a pool of ``plan.workers`` worker subprocesses, a group of seeds
    (:func:`units`) to a process."""
    queue = collections.deque(units(todo, plan))
    running: dict[int, tuple[list, subprocess.Popen, float]] = {}          # slot -> a unit's attempts
    try:
        while queue or running:
            for slot in range(plan.workers):
                if queue and slot not in running:
                    running[slot] = _launch(layout, journal, queue.popleft(), plan, slot, tracker)
            time.sleep(0.1)
            for slot, (unit, proc, t0) in list(running.items()):
                rc = proc.poll()
                if rc is None:
                    continue
                del running[slot]
                log = layout.log(*unit[0])
                for job, n in unit:
                    record = finish_attempt(layout, journal, job, n, returncode=rc,
                                            error="" if rc == 0 else worker.describe_exit(rc, log),
                                            meta=_meta(plan, t0, proc.pid, rc))
                    tracker.event(record["event"], job.id, record)
    except BaseException:                  # Ctrl-C or a bug: stop the workers, record their attempts as failed
        for unit, proc, t0 in running.values():
            proc.terminate()
        for unit, proc, t0 in running.values():
            try:
                rc = proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                rc = proc.wait()
            for job, n in unit:
                record = finish_attempt(layout, journal, job, n, returncode=rc, error="interrupted: the batch "
                                        "process stopped its workers", meta=_meta(plan, t0, proc.pid, rc))
                tracker.event(record["event"], job.id, record)
        raise


def units(todo: list[tuple[Job, int]], plan: RunPlan) -> list[list[tuple[Job, int]]]:
    """The attempts of ``todo`` in worker processes: synthesis jobs whose command lines differ only in ``--seed``
    go ``plan.group`` to a process (0: all of them, split evenly over ``plan.workers``), in manifest order; every
    other job alone."""
    if plan.group == 1:
        return [[item] for item in todo]
    out: list[list] = []
    similar: dict[tuple, list] = {}
    for job, n in todo:
        if job.method == "synthesize":
            similar.setdefault(tuple(_without_seed(job.argv())), []).append((job, n))
        else:
            out.append([(job, n)])
    for members in similar.values():
        size = plan.group or -(-len(members) // max(plan.workers, 1))
        out.extend(members[i:i + size] for i in range(0, len(members), size))
    return out


def _without_seed(argv: list[str]) -> list[str]:
    i = argv.index("--seed")
    return argv[:i] + argv[i + 2:]


def _meta(plan: RunPlan, t0: float, pid: int | None, rc: int | None) -> dict:
    import socket

    return {"threads": plan.threads, "device": plan.device, "backend": plan.backend, "host": socket.gethostname(),
            "pid": pid, "returncode": rc, "seconds": round(time.monotonic() - t0, 3)}


def _launch(layout: Layout, journal: Journal, unit: list, plan: RunPlan, slot: int, tracker: _Tracker):
    """Start one worker process for ``unit`` (one attempt, or a group of seeds' attempts). Every attempt's log is
    locked here and held by the worker (the first log gets its output; the others say where it is)."""
    env = worker.environment(plan.threads)
    if plan.gpus:
        env["CUDA_VISIBLE_DEVICES"] = plan.gpus[slot % len(plan.gpus)]
    (job, n) = unit[0]
    if len(unit) == 1:
        cmd = worker.command(job.argv(), layout.stage(job.id, n), plan.threads, plan.device)
    else:
        cmd = worker.group_command(_without_seed(job.argv()), [(j.seed, layout.stage(j.id, k)) for j, k in unit],
                                   plan.threads, plan.device)
    handles = []
    try:
        for j, k in unit:
            fh = open(layout.log(j.id, k), "ab")
            handles.append(fh)
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)   # a fresh file; the worker inherits the lock
            if len(handles) > 1:
                fh.write(f"this attempt runs with {len(unit)} seeds in one process: its output is in "
                         f"{layout.log(job.id, n).name}\n".encode())
                fh.flush()
        t0 = time.monotonic()
        proc = subprocess.Popen(cmd, stdout=handles[0], stderr=subprocess.STDOUT, cwd=layout.logs, env=env,
                                pass_fds=tuple(fh.fileno() for fh in handles[1:]), **worker.popen_kwargs())
    finally:
        for fh in handles:
            fh.close()
    for j, k in unit:
        record = journal.append("start", job=j.id, attempt=k, pid=proc.pid, threads=plan.threads,
                                device=worker.run_device(j.method, plan.device), backend="local",
                                log=str(layout.log(j.id, k).relative_to(layout.root)),
                                **({"group": len(unit)} if len(unit) > 1 else {}))
        tracker.event("start", j.id, record)
    return unit, proc, t0


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
