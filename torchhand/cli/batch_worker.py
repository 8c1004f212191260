"""``python -m torchhand.cli.batch_worker --stage DIR --threads K --device D -- METHOD SCENE ...``: one attempt of one
batch job, in its own process, started by the batch runner (:func:`torchhand.batch.worker.command`).

``--each SEED=DIR`` (repeated, instead of ``--stage``) runs synthesis jobs that differ only by seed in one process:
``synthesize ... --seeds`` writes each seed's result into its own staging directory, and each complete one is
checked (:func:`torchhand.batch.worker.group_command`).

Runs the ``torchhand`` command with ``--out DIR --threads K`` (and ``--device``, ``--no-progress`` where it has
them), then checks a complete result; exit codes and files as :mod:`torchhand.batch.worker` describes.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
from pathlib import Path

from ..batch.worker import RUN_FLAGS, Tee, record_unsuitable, write_check
from . import main as cli
from ._common import apply_graph_setting

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m torchhand.cli.batch_worker", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--stage", help="the attempt's result directory (must not exist)")
    p.add_argument("--each", action="append", default=[], metavar="SEED=DIR",
                   help="a synthesis job of a group: its seed and staging directory (repeated)")
    p.add_argument("--threads", type=int, required=True)
    p.add_argument("--device", default="cpu")
    p.add_argument("command", nargs=argparse.REMAINDER, help="-- METHOD SCENE [options]")
    a = p.parse_args(argv)
    apply_graph_setting()
    cmd = a.command[1:] if a.command[:1] == ["--"] else a.command
    if a.each:
        return _group(cmd, a)
    stage = Path(a.stage)
    method = cmd[0] if cmd else ""
    flags = RUN_FLAGS.get(method, ("--device", "--no-progress"))
    run = ["--out", str(stage), "--threads", str(a.threads)] + (["--device", a.device] if "--device" in flags else [])
    run += ["--no-progress"] if "--no-progress" in flags else []
    print(f"worker pid {os.getpid()}: torchhand {' '.join(cmd + run)}", flush=True)
    tee = Tee(sys.stderr)
    with contextlib.redirect_stderr(tee):
        rc = cli(cmd + run)
    sys.stdout.flush()
    try:
        stats = json.loads((stage / "stats.json").read_text())
    except (OSError, ValueError):
        stats = {}
    said = stats.get("status") == "grasp_unsuitable" if stats else any("grasp unsuitable" in ln for ln in tee.lines)
    if method == "manipulate" and rc == 1 and stats.get("complete") is not True and said:
        return record_unsuitable(stage, stats, tee.lines)
    if stats.get("complete") is not True:
        print(f"torchhand batch worker: error: the run did not complete (exit code {rc})", file=sys.stderr)
        return rc if rc not in (0, 1) else 3
    write_check(stage)
    return 0


def _group(cmd: list[str], a) -> int:
    """Synthesis jobs of one group: one ``synthesize --seeds`` run, each seed into its staging directory; exit 0
    when every one completed (then checked), else 3 (or the command's code for bad input)."""
    each = [item.partition("=") for item in a.each]
    seeds, stages = [seed for seed, _, _ in each], [Path(d) for _, _, d in each]
    run = ["--seeds", ",".join(seeds), "--out", str(stages[0]), "--threads", str(a.threads), "--device", a.device,
           "--no-progress"] + [x for item in a.each for x in ("--out-each", item)]
    print(f"worker pid {os.getpid()}: torchhand {' '.join(cmd + run)}", flush=True)
    rc = cli(cmd + run)
    sys.stdout.flush()
    done = 0
    for stage in stages:
        try:
            stats = json.loads((stage / "stats.json").read_text())
        except (OSError, ValueError):
            stats = {}
        if stats.get("complete") is True:
            write_check(stage)
            done += 1
    if done < len(stages):
        print(f"torchhand batch worker: error: {len(stages) - done} of {len(stages)} runs did not complete (exit "
              f"code {rc})", file=sys.stderr)
        return rc if rc not in (0, 1) else 3
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
