"""One attempt of one batch job, in its own process: ``python -m torchhand.cli.batch_worker --stage DIR --threads K
--device D -- synthesize SCENE ...`` (the process entry is :mod:`torchhand.cli.batch_worker`, which runs the command
in the CLI layer; this module holds what the batch needs around it: the command line, environment, exit
descriptions, the check and the unsuitable-grasp record).

Runs the ``torchhand`` command (``torchhand.cli.main``) with ``--out DIR --threads K`` added, and those of
``--device D`` and ``--no-progress`` that the command has (:data:`RUN_FLAGS`), then, when its ``stats.json`` says
``"complete": true``, the independent checker (:func:`torchhand.check.check_result`) on the result, whose report
it writes to ``DIR/check.json`` (atomically, last). Exit code 0 then, whether or not solutions were found and
whatever the checker's verdict (a ``capture`` whose rollouts all stopped at an unsolved LCP exits 1 with a complete
result of no solution: that is its answer, not a failure); otherwise the command's own code (2: bad input, the
error line on stderr) or 3 (the run did not complete).

A ``manipulate`` that exits 1 found the grasp unsuitable for the motion (docs/manipulation.md): a deterministic
answer, so the attempt is finished, not failed. The worker checks the partial result when there is one
(``check.json``) and then writes ``DIR/unsuitable.json`` (last): ``status: "grasp_unsuitable"``, the ``frame``,
``frames_done`` and the command's ``message``.

The batch process runs this as a subprocess so that a crash or ``kill -9`` of one job cannot take the batch down,
and on Linux asks the kernel to kill it when the batch process dies (:func:`popen_kwargs`), so that no orphan keeps
writing after a ``kill -9`` of the batch.
"""

from __future__ import annotations

import io
import os
import signal
import sys
from pathlib import Path

from .._numerics import ENV_MODE, portable_env

__all__ = ["RUN_FLAGS", "UNSUITABLE", "Tee", "command", "group_command", "describe_exit", "environment", "popen_kwargs",
           "record_unsuitable", "run_device", "write_check"]

RUN_FLAGS = {"synthesize": ("--device", "--no-progress"), "manipulate": ("--no-progress",), "capture": ("--device",)}
"""Method -> the run flags its command has besides ``--out`` and ``--threads`` (a test holds them to the CLI)."""

UNSUITABLE = "unsuitable.json"
"""The file that marks a finished attempt whose answer is "grasp unsuitable" (module docstring)."""


def run_device(method: str, device: str) -> str:
    """The device a job of ``method`` runs on when the batch asks for ``device``: commands without ``--device``
    (manipulate) run on the CPU."""
    return device if "--device" in RUN_FLAGS.get(method, ("--device",)) else "cpu"


def command(argv: list[str], stage: Path, threads: int, device: str) -> list[str]:
    """The worker's command line for a job's ``argv`` (:meth:`torchhand.batch.manifest.Job.argv`)."""
    return [sys.executable, "-m", "torchhand.cli.batch_worker", "--stage", str(stage), "--threads", str(threads),
            "--device", device, "--", *argv]


def group_command(argv: list[str], each: list, threads: int, device: str) -> list[str]:
    """The worker's command line for synthesis jobs that differ only by seed: ``argv`` without ``--seed``, and per
    job its (seed, staging directory) in ``each``."""
    pairs = [a for seed, stage in each for a in ("--each", f"{seed}={stage}")]
    return [sys.executable, "-m", "torchhand.cli.batch_worker", *pairs, "--threads", str(threads),
            "--device", device, "--", *argv]


def environment(threads: int, base: dict | None = None) -> dict:
    """The worker's environment: ``base`` (default ``os.environ``) with the thread pools of OpenMP, OpenBLAS and
    MKL (NumPy's and SciPy's, which the checker uses) sized to the job's ``threads``, so that ``workers``
    workers keep to ``workers × threads`` CPUs; idle OpenMP threads sleep (``OMP_WAIT_POLICY=PASSIVE`` unless
    set); and the portable numeric profile (torchhand/_numerics.py) unless ``TORCHHAND_NUMERICS=native``, so that a
    job's result does not depend on the CPU of the node that runs it."""
    env = dict(os.environ if base is None else base)
    env.update({k: str(threads) for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")})
    env.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    if env.get(ENV_MODE, "").strip() != "native":
        env.update(portable_env())
    return env


def popen_kwargs() -> dict:
    """``subprocess.Popen`` arguments of a worker: stdin closed; on Linux, SIGKILL when its parent dies."""
    kw: dict = {"stdin": -3}                                     # subprocess.DEVNULL
    if sys.platform.startswith("linux"):
        parent = os.getpid()

        def die_with_parent():                                   # runs in the child, before exec
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, signal.SIGKILL)                        # PR_SET_PDEATHSIG
            if os.getppid() != parent:                           # the parent died before prctl took effect
                os._exit(1)

        kw["preexec_fn"] = die_with_parent
    return kw


def describe_exit(returncode: int, log: Path) -> str:
    """Why a worker failed, in one line: the signal that killed it, or its exit code and the last ``error:`` line
    (else the last line) of its log."""
    if returncode < 0:
        try:
            return f"worker killed by {signal.Signals(-returncode).name}"
        except ValueError:
            return f"worker killed by signal {-returncode}"
    try:
        lines = [ln.strip() for ln in Path(log).read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        lines = []
    errors = [ln for ln in lines if "error:" in ln]
    last = (errors or lines or [""])[-1][:500]
    return f"worker exited with {returncode}" + (f": {last}" if last else "")


def write_check(stage: Path) -> None:
    """The checker's report on the result in ``stage``, written to ``check.json``."""
    from .._atomic import atomic_json
    from ..check import check_result

    report = check_result(stage)
    atomic_json(stage / "check.json", report.to_dict())
    print(f"check: {'PASS' if report.passed else 'FAIL'}: {sum(s.passed for s in report.solutions)} of "
          f"{len(report.solutions)} solutions pass{'' if report.complete else ' (partial result)'}", flush=True)


def record_unsuitable(stage: Path, stats: dict, lines) -> int:
    """Record a manipulate attempt that found the grasp unsuitable as finished: check the partial result (if any),
    then write ``unsuitable.json`` last."""
    import re

    from .._atomic import atomic_json

    said = [ln for ln in lines if "grasp unsuitable" in ln]
    message = (said or [""])[-1].strip()
    message = message.split(": ", 1)[1] if message.startswith("torchhand:") else message
    message = re.sub(r";\s*(nothing written|frames \S+ written to .*)$", "", message)   # where: the staging dir
    info = stats.get("unsuitable") or {}
    m = re.search(r"at frame (\d+)", message)
    frame = info.get("frame", int(m[1]) if m else None)
    if stats:
        write_check(stage)
    stage.mkdir(parents=True, exist_ok=True)
    atomic_json(stage / UNSUITABLE, {"status": "grasp_unsuitable", "frame": frame,
                                     "frames_done": stats.get("T", 0) if stats else 0, "message": message,
                                     "partial_result": bool(stats)})
    print(f"grasp unsuitable at frame {frame}: recorded as the job's answer (not retried)", flush=True)
    return 0


class Tee(io.TextIOBase):
    """A text stream that writes through to ``target`` and keeps the last 100 complete lines written."""

    def __init__(self, target):
        import collections

        self.target, self.lines, self._part = target, collections.deque(maxlen=100), ""

    def write(self, text: str) -> int:
        self.target.write(text)
        parts = (self._part + text).split("\n")
        self.lines.extend(parts[:-1])
        self._part = parts[-1]
        return len(text)

    def flush(self) -> None:
        self.target.flush()

