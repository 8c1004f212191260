"""The plan of a batch run (:class:`RunPlan`, :func:`plan_run`): workers x threads on the CPUs this process may
use, the device, local pool or Ray (rule in :mod:`torchhand.batch.runner`)."""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass

from ..errors import InputValueError

__all__ = ["RunPlan", "plan_run", "usable_cpus"]


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity mask), else ``os.cpu_count()``."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


@dataclass(frozen=True)
class RunPlan:
    """How a batch runs (not part of any job's id).

    workers: jobs at a time; threads: torch threads per job; cpus: CPUs usable here
    device: "cpu" or "cuda"; backend: "local" or "ray" (ray_address: "local" for ``--ray auto``, else the address)
    gpus: CUDA devices given to local workers round-robin (``CUDA_VISIBLE_DEVICES``), empty for the CPU
    group: synthesis jobs that differ only by seed run this many to one worker process, their searches batched
        (:func:`torchhand.synthesis.pipeline.synthesize_seeds`); 0: all of them, split evenly over the workers (one
        process per device); 1: one job per process
    """

    workers: int
    threads: int
    cpus: int
    device: str = "cpu"
    backend: str = "local"
    ray_address: str | None = None
    gpus: tuple[str, ...] = ()
    group: int = 1

    def to_dict(self) -> dict:
        return asdict(self)


def plan_run(*, workers: int | None = None, threads: int | None = None, device: str = "cpu",
             ray: str | None = None, cpus: int | None = None, gpus: tuple[str, ...] = (),
             group: int | None = None) -> RunPlan:
    """The run's plan (module docstring). ``ray``: None (local pool), ``"auto"`` (a local Ray instance) or a
    cluster address, where ``workers`` caps the jobs in flight (default: what the cluster's CPUs hold). ``group``:
    seeds per worker process (:class:`RunPlan`); default 0 (all, one process per device) with ``device="cuda"``,
    else 1; Ray runs one job per task."""
    if group is not None and (isinstance(group, bool) or not isinstance(group, int) or group < 0):
        raise InputValueError(f"--group: expected an integer >= 0, got {group}")
    if group is None:
        group = 0 if device == "cuda" else 1
    if ray is not None and group != 1:
        group = 1
    for name, value in (("--workers", workers), ("--threads", threads)):
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
            raise InputValueError(f"{name}: expected an integer >= 1, got {value}")
    if device not in ("cpu", "cuda"):
        raise InputValueError(f"--device: expected cpu or cuda, got {device!r}")
    cpus = cpus or usable_cpus()
    if ray is not None and ray != "auto":
        return RunPlan(workers=workers or 0, threads=threads or 1, cpus=cpus, device=device, backend="ray",
                       ray_address=ray)
    if workers is None:
        workers = len(gpus) if device == "cuda" and gpus else max(1, cpus // (threads or 1))
    threads = threads or max(1, cpus // workers)
    return RunPlan(workers=workers, threads=threads, cpus=cpus, device=device,
                   backend="ray" if ray else "local", ray_address="local" if ray else None,
                   gpus=gpus if device == "cuda" else (), group=group)
