"""One attempt of one batch job, in its own process: ``python -m torchhand.batch --stage DIR --threads K --device D
-- synthesize SCENE ...`` (``torchhand/batch/__main__.py`` calls :func:`main`).

Runs the ``torchhand`` command (``torchhand.cli.main``) with ``--out DIR --threads K --device D --no-progress``
added, and, when its ``stats.json`` says ``"complete": true``, the independent checker
(:func:`torchhand.check.check_result`) on the result, whose report it writes to ``DIR/check.json`` (atomically,
last). Exit code 0 then, whether or not solutions were found and whatever the checker's verdict; otherwise the
command's own code (2: bad input, the error line on stderr) or 3 (the run did not complete).

The batch process runs this as a subprocess so that a crash or ``kill -9`` of one job cannot take the batch down,
and on Linux asks the kernel to kill it when the batch process dies (:func:`popen_kwargs`), so that no orphan keeps
writing after a ``kill -9`` of the batch.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
from pathlib import Path

__all__ = ["command", "environment", "popen_kwargs", "describe_exit", "main"]


def command(argv: list[str], stage: Path, threads: int, device: str) -> list[str]:
    """The worker's command line for a job's ``argv`` (:meth:`torchhand.batch.manifest.Job.argv`)."""
    return [sys.executable, "-m", "torchhand.batch", "--stage", str(stage), "--threads", str(threads),
            "--device", device, "--", *argv]


def environment(threads: int, base: dict | None = None) -> dict:
    """The worker's environment: ``base`` (default ``os.environ``) with the thread pools of OpenMP, OpenBLAS and
    MKL (NumPy's and SciPy's, which the checker uses) sized to the job's ``threads``, so that ``workers``
    workers keep to ``workers × threads`` CPUs; idle OpenMP threads sleep (``OMP_WAIT_POLICY=PASSIVE`` unless
    set)."""
    env = dict(os.environ if base is None else base)
    env.update({k: str(threads) for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")})
    env.setdefault("OMP_WAIT_POLICY", "PASSIVE")
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


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m torchhand.batch", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--stage", required=True, help="the attempt's result directory (must not exist)")
    p.add_argument("--threads", type=int, required=True)
    p.add_argument("--device", default="cpu")
    p.add_argument("command", nargs=argparse.REMAINDER, help="-- METHOD SCENE [options]")
    a = p.parse_args(argv)
    cmd = a.command[1:] if a.command[:1] == ["--"] else a.command
    from ..cli import main as cli

    stage = Path(a.stage)
    print(f"worker pid {os.getpid()}: torchhand {' '.join(cmd)} --out {stage} --threads {a.threads} "
          f"--device {a.device}", flush=True)
    rc = cli(cmd + ["--out", str(stage), "--threads", str(a.threads), "--device", a.device, "--no-progress"])
    sys.stdout.flush()
    try:
        stats = json.loads((stage / "stats.json").read_text())
    except (OSError, ValueError):
        stats = {}
    if stats.get("complete") is not True:
        print(f"torchhand batch worker: error: the run did not complete (exit code {rc})", file=sys.stderr)
        return rc if rc not in (0, 1) else 3
    from .._atomic import atomic_json
    from ..check import check_result

    report = check_result(stage)
    atomic_json(stage / "check.json", report.to_dict())
    print(f"check: {'PASS' if report.passed else 'FAIL'}: {sum(s.passed for s in report.solutions)} of "
          f"{len(report.solutions)} solutions pass", flush=True)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
