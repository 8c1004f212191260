"""Ray backend of ``torchhand batch --ray auto|ADDRESS``: the same jobs, the same worker, the same directory.

Each attempt is one Ray task (:func:`ray_attempt`) asking for ``num_cpus = threads`` (and ``num_gpus = 1`` with
``--device cuda`` for the methods that run on it, :func:`torchhand.batch.worker.run_device`), with ``max_retries = 0`` so that every failure is recorded here. The task runs the batch
worker (:mod:`.worker`) as a subprocess on its node, into a temporary directory, and returns the finished result
as a tar archive with the attempt's log; results stream back with ``ray.wait`` as they finish, and this process
unpacks each into ``DIR/jobs/.staging/<id>.<n>/`` and promotes it exactly as the local pool does
(:func:`torchhand.batch.store.finish_attempt`). So nothing but this process writes the batch directory, and the
nodes of a cluster need no shared filesystem for the output. They do need the inputs: a built-in scene needs
nothing, a scene directory or a hand file must be readable at the same absolute path on every node.

``--ray auto`` starts a local Ray instance (``ray.init(address="local", num_cpus=workers * threads)``, no
dashboard, worker output not forwarded); an address joins a running cluster, where ``--workers`` caps the jobs in
flight (default: the cluster's CPUs over ``threads``). Ray is an optional extra (``pip install
'torchhand[ray]'``), imported only here.
"""

from __future__ import annotations

import collections
import io
import logging
import socket
import subprocess
import tarfile
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import InputValueError
from . import worker
from .store import Journal, Layout, finish_attempt

if TYPE_CHECKING:
    from ._plan import RunPlan
    from ._progress import _Tracker
    from .manifest import Job

__all__ = ["require_ray", "check_address", "ray_attempt", "run_ray"]


def require_ray():
    """The ``ray`` module, or InputValueError saying how to install it."""
    try:
        import ray
    except ImportError:
        raise InputValueError("--ray: Ray is not installed; pip install 'torchhand[ray]'") from None
    return ray


def check_address(address: str, timeout: float = 5.0) -> None:
    """InputValueError unless ``address`` (``HOST:PORT`` or ``ray://HOST:PORT``) accepts a TCP connection within
    ``timeout`` seconds: Ray itself retries an unreachable address for minutes."""
    host, sep, port = address.split("://", 1)[-1].rpartition(":")
    if not sep or not host or not port.isdigit():
        raise InputValueError(f"--ray {address}: expected auto, HOST:PORT or ray://HOST:PORT")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout).close()
    except OSError as err:
        raise InputValueError(f"--ray {address}: cannot reach a Ray cluster there ({err.strerror or err}); start one "
                              f"with `ray start --head`, or use --ray auto") from None


def ray_attempt(argv: list[str], threads: int, device: str) -> dict:
    """One attempt of a job, as a Ray task: the worker subprocess into a temporary directory.

    Returns ``returncode`` (negative: killed by that signal), ``log`` (bytes), ``host``, ``pid``, ``seconds``
    and, when the worker succeeded, ``result``: the result directory as an uncompressed tar archive (bytes).
    """
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="torchhand-batch-") as tmp:
        stage, log = Path(tmp) / "result", Path(tmp) / "attempt.log"
        with open(log, "wb") as fh:
            proc = subprocess.Popen(worker.command(argv, stage, threads, device), stdout=fh,
                                    stderr=subprocess.STDOUT, cwd=tmp, env=worker.environment(threads),
                                    **worker.popen_kwargs())
            rc = proc.wait()
        out = {"returncode": rc, "log": log.read_bytes(), "host": socket.gethostname(), "pid": proc.pid,
               "seconds": round(time.monotonic() - t0, 3)}
        if rc == 0 and stage.is_dir():
            buf = io.BytesIO()
            with tarfile.open(fileobj=buf, mode="w") as tar:
                tar.add(stage, arcname=".")
            out["result"] = buf.getvalue()
        return out


def _init(ray, plan: RunPlan) -> None:
    quiet = {"include_dashboard": False, "log_to_driver": False, "logging_level": logging.ERROR}
    if plan.ray_address == "local":
        ray.init(address="local", num_cpus=plan.workers * plan.threads,
                 num_gpus=None if plan.device == "cuda" else 0, **quiet)
    else:
        check_address(plan.ray_address)
        try:
            ray.init(address=plan.ray_address, **quiet)
        except (ConnectionError, ValueError, RuntimeError) as err:
            raise InputValueError(f"--ray {plan.ray_address}: cannot join the Ray cluster: "
                                  f"{str(err).splitlines()[0] if str(err) else type(err).__name__}") from None


def run_ray(layout: Layout, journal: Journal, todo: list[tuple[Job, int]], plan: RunPlan,
            tracker: _Tracker) -> None:
    """Run ``todo`` ((job, attempt) pairs) as Ray tasks (module docstring); record every start, finish and
    failure as the local pool does."""
    ray = require_ray()
    _init(ray, plan)
    try:
        capacity = plan.workers
        if not capacity:
            res = ray.cluster_resources()
            capacity = max(1, int(res.get("CPU", 1) // plan.threads))
            if plan.device == "cuda":
                capacity = max(1, min(capacity, int(res.get("GPU", 1))))
        remote = ray.remote(ray_attempt)
        tasks = {m: remote.options(num_cpus=plan.threads, max_retries=0,
                                   num_gpus=1 if worker.run_device(m, plan.device) == "cuda" else 0)
                 for m in {job.method for job, _ in todo}}
        queue = collections.deque(todo)
        inflight: dict = {}
        try:
            while queue or inflight:
                while queue and len(inflight) < capacity:
                    job, n = queue.popleft()
                    ref = tasks[job.method].remote(job.argv(), plan.threads, plan.device)
                    inflight[ref] = (job, n, time.monotonic())
                    record = journal.append("start", job=job.id, attempt=n, threads=plan.threads,
                                            device=worker.run_device(job.method, plan.device), backend="ray",
                                            ray_address=plan.ray_address)
                    tracker.event("start", job.id, record)
                ready, _ = ray.wait(list(inflight), num_returns=1, timeout=1.0)
                for ref in ready:
                    job, n, t0 = inflight.pop(ref)
                    record = _collect(ray, ref, layout, journal, job, n, plan, t0)
                    tracker.event(record["event"], job.id, record)
        except BaseException:
            for ref, (job, n, t0) in inflight.items():
                ray.cancel(ref, force=True)
                record = finish_attempt(layout, journal, job, n, returncode=None, error="interrupted: the batch "
                                        "process cancelled its Ray task", meta={"backend": "ray"})
                tracker.event(record["event"], job.id, record)
            raise
    finally:
        ray.shutdown()


def _collect(ray, ref, layout: Layout, journal: Journal, job: Job, n: int, plan: RunPlan, t0: float) -> dict:
    """Unpack a finished task's result into the attempt's staging directory and promote it (or record the
    failure)."""
    meta = {"threads": plan.threads, "device": plan.device, "backend": "ray", "ray_address": plan.ray_address,
            "seconds": round(time.monotonic() - t0, 3)}
    try:
        res = ray.get(ref)
    except ray.exceptions.RayError as err:
        text = str(err).strip().splitlines()
        return finish_attempt(layout, journal, job, n, returncode=None, meta=meta,
                              error=f"Ray task failed: {type(err).__name__}: {text[-1] if text else ''}"[:500])
    layout.log(job.id, n).write_bytes(res["log"])
    meta.update(host=res["host"], pid=res["pid"], returncode=res["returncode"], task_seconds=res["seconds"])
    rc = res["returncode"]
    if rc == 0 and "result" in res:
        stage = layout.stage(job.id, n)
        with tarfile.open(fileobj=io.BytesIO(res["result"]), mode="r") as tar:
            tar.extractall(stage, filter="data")
    return finish_attempt(layout, journal, job, n, returncode=rc, meta=meta,
                          error="" if rc == 0 else worker.describe_exit(rc, layout.log(job.id, n)))
