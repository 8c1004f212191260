"""A real result directory for tests: ``torchhand synthesize box-turn`` run once per test session.

The command is :data:`SYNTHESIZE`: frames 14-37 of box-turn, where the hand starts turning the box on the table
(the hand's contacts carry force), three solutions within 6000 node tests. The search budget is a node count and the command pins the portable numeric
profile, so the solutions are the same on any x86-64 machine with AVX2 for a given thread count (1 here unless
``TORCHHAND_THREADS`` says otherwise). :func:`real_box_turn` runs it in a subprocess the first time it is called and returns the
same directory afterwards (tests/render, tests/torchhand/test_result.py and test_check.py share it).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

SCENE = "box-turn"
SYNTHESIZE = ["synthesize", SCENE, "--frames", "14:38", "--solutions", "3", "--max-nodes", "6000", "--seed", "0",
              "--no-progress"]
"""Arguments of ``torchhand`` after which ``--out DIR`` is added."""

_DIRS: dict = {}


def real_box_turn(tmp_path_factory) -> Path:
    """The result directory of ``torchhand`` :data:`SYNTHESIZE` ``--out DIR``; fails the requesting test with the
    command's output when it exits non-zero or writes fewer than 2 solutions."""
    if SCENE in _DIRS:
        return _DIRS[SCENE]
    out = tmp_path_factory.mktemp("real") / SCENE
    env = {**os.environ, "TORCHHAND_THREADS": os.environ.get("TORCHHAND_THREADS", "1")}
    cmd = [sys.executable, "-m", "torchhand.cli", *SYNTHESIZE, "--out", str(out)]
    run = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=1800)
    found = sorted((out / "solutions").glob("sol_*.npz")) if (out / "solutions").is_dir() else []
    if run.returncode != 0 or len(found) < 2:
        pytest.fail(f"`torchhand {' '.join(SYNTHESIZE)} --out {out}` exited {run.returncode} with "
                    f"{len(found)} solution(s):\n{run.stdout}\n{run.stderr}")
    _DIRS[SCENE] = out
    return out
