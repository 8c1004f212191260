"""Nothing lost: ``torchhand synthesize``'s output is validated before any work, written atomically, checkpointed
as solutions are found, and never replaced without --overwrite. Runs are bounded by node tests, never by time."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from torchhand.cli import main as cli
from torchhand.io.result import load_result

# box-turn's first 8 frames with a small search (4 trees of 8 candidates): a few seconds, a real path
FRAMES = ["--frames", "0:8", "--trees", "4", "--candidates", "8"]
SMALL = FRAMES + ["--max-nodes", "2000", "--solutions", "2", "--seed", "0", "--no-progress"]


def _arrays(out: Path) -> list[dict]:
    rows = []
    for f in sorted((out / "solutions").glob("sol_*.npz")):
        with np.load(f) as z:
            rows.append({k: z[k] for k in z.files})
    return rows


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("out") / "bt"
    rc = cli(["synthesize", "box-turn", "--out", str(out)] + SMALL)
    return rc, out


def test_small_run_writes_a_complete_versioned_result(small_run):
    rc, out = small_run
    assert rc == 0
    stats = json.loads((out / "stats.json").read_text())
    assert stats["complete"] is True and stats["format_version"] == 1 and stats["max_nodes"] == 2000
    assert stats["stopped_by"] in ("solutions", "max_nodes") and stats["threads"] >= 1
    res = load_result(out)
    assert res.complete and len(res.solutions) == stats["solutions"] >= 1
    for sol in res.solutions:
        assert sol.format_version == 1 and sol.reconstructed
        assert sol.q.shape == (8, 30)
    assert not (out / ".torchhand.lock").exists()


def test_same_seed_and_node_budget_give_identical_arrays(small_run, tmp_path):
    """A node budget makes the run independent of the clock: a second run gives byte-identical arrays."""
    _, first = small_run
    out = tmp_path / "again"
    assert cli(["synthesize", "box-turn", "--out", str(out)] + SMALL) == 0
    a, b = _arrays(first), _arrays(out)
    assert len(a) == len(b) >= 1
    for x, y in zip(a, b):
        assert x.keys() == y.keys()
        for k in x:
            assert x[k].dtype == y[k].dtype and x[k].tobytes() == y[k].tobytes(), k


def test_existing_result_needs_overwrite_and_stays_whole(small_run, tmp_path, capsys):
    _, first = small_run
    before = {p.name: p.read_bytes() for p in (first / "solutions").iterdir()}
    t0 = time.perf_counter()
    assert cli(["synthesize", "box-turn", "--out", str(first)] + SMALL) == 2
    assert time.perf_counter() - t0 < 5
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--overwrite" in err[0]
    assert {p.name: p.read_bytes() for p in (first / "solutions").iterdir()} == before


def test_overwrite_replaces_a_result_but_never_another_directory(tmp_path, capsys):
    other = tmp_path / "photos"
    other.mkdir()
    (other / "cat.jpg").write_bytes(b"x")
    assert cli(["synthesize", "box-turn", "--out", str(other), "--overwrite"] + SMALL) == 2
    assert "not a result directory" in capsys.readouterr().err
    assert (other / "cat.jpg").read_bytes() == b"x"
    out = tmp_path / "r"
    assert cli(["synthesize", "box-turn", "--out", str(out)] + FRAMES + ["--max-nodes", "2000", "--solutions", "1",
                                                                        "--seed", "1", "--no-progress"]) == 0
    assert cli(["synthesize", "box-turn", "--out", str(out), "--overwrite"] + SMALL) == 0
    stats = json.loads((out / "stats.json").read_text())
    assert stats["seed"] == 0 and stats["complete"]
    assert not out.with_name("r.partial").exists()
    assert not list(tmp_path.glob("r.old-*"))


def test_unwritable_out_fails_at_once(tmp_path, capsys):
    """--out under a regular file: one line, exit 2, in well under 5 s, before any work."""
    blocker = tmp_path / "file"
    blocker.write_text("")
    t0 = time.perf_counter()
    assert cli(["synthesize", "box-turn", "--out", str(blocker / "out"), "--no-progress"]) == 2
    assert time.perf_counter() - t0 < 5
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot write" in err[0]


def test_progress_lines_without_a_terminal(tmp_path):
    """stderr is not a terminal: progress comes as plain lines (stage, node tests, solutions, time)."""
    out = tmp_path / "p"
    proc = subprocess.run([sys.executable, "-m", "torchhand.cli", "synthesize", "box-turn", "--out", str(out)]
                          + SMALL[:-1], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("synthesize:")]
    assert any("search:" in ln and "node tests" in ln and "solutions" in ln for ln in lines), proc.stderr
    assert "\r" not in proc.stderr


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGINT])
def test_an_interrupted_run_leaves_its_solutions_readable(tmp_path, sig):
    """kill -9 (or Ctrl-C) after the first solution: every solution written so far reads back, and stats.json
    says the run is partial. The run is bounded by nodes; the wait below only guards against a hang."""
    out = tmp_path / "k"
    cmd = [sys.executable, "-m", "torchhand.cli", "synthesize", "box-turn", "--out", str(out), *FRAMES,
           "--max-nodes", "200000", "--solutions", "50", "--seed", "0", "--no-progress"]
    # Ctrl-C's default action in the child, whatever this process inherited: a suite started as a background job
    # of a non-interactive shell ignores SIGINT, the child would inherit that and run to completion (exit 0)
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 600
        while not (out / "solutions" / "sol_000.npz").exists():
            assert proc.poll() is None, proc.stderr.read()
            assert time.monotonic() < deadline, "no solution was written"
            time.sleep(0.2)
        proc.send_signal(sig)
        rc = proc.wait(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert rc == (-9 if sig == signal.SIGKILL else 130)
    res = load_result(out)
    assert not res.complete
    assert len(res.solutions) >= 1
    assert all(s.q.shape == (8, 30) for s in res.solutions)
    if sig == signal.SIGINT:
        assert json.loads((out / "stats.json").read_text()).get("interrupted") is True
    # a later run into the same place is refused without --overwrite (the partial result is kept) ...
    assert cli(["synthesize", "box-turn", "--out", str(out)] + SMALL) == 2
    # ... and replaces it with it
    assert cli(["synthesize", "box-turn", "--out", str(out), "--overwrite"] + SMALL) == 0
    assert load_result(out).complete


def test_two_runs_cannot_write_one_directory(tmp_path):
    """A second run into a directory that another run is writing fails at once with exit 2."""
    out = tmp_path / "shared"
    cmd = [sys.executable, "-m", "torchhand.cli", "synthesize", "box-turn", "--out", str(out), *FRAMES,
           "--max-nodes", "200000", "--solutions", "50", "--no-progress"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while not (out / ".torchhand.lock").exists():
            assert time.monotonic() < deadline and proc.poll() is None
            time.sleep(0.1)
        second = subprocess.run(cmd, capture_output=True, text=True, timeout=120,
                                env=dict(os.environ, PYTHONUNBUFFERED="1"))
        assert second.returncode == 2
        assert "another torchhand run" in second.stderr
    finally:
        proc.kill()
        proc.wait()
