"""``torchhand batch``: manifests expand and are validated before any work; each job is finished exactly once and
its directory appears whole; a batch survives ``kill -9`` of itself or of one worker and a rerun finishes every job;
the local pool and Ray give identical arrays; the summary counts every job once, from what is on disk.

Jobs are tiny (box-turn and bottle-turn, frames 0:4, a node budget of 300, one solution): a few seconds each.
Nothing here waits on the clock except as a hang guard (``_wait_for``).
"""

from __future__ import annotations

import csv
import fcntl
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from torchhand.batch import load_manifest
from torchhand.batch.manifest import OPTIONS
from torchhand.cli import main as cli
from torchhand.errors import TorchhandError
from torchhand.io.result import load_result

SMALL = """
[defaults]
method = "synthesize"
solutions = 1
max_nodes = 300
frames = "0:4"
trees = 4
candidates = 8
"""
FOUR = SMALL + '[[jobs]]\nscenes = ["box-turn", "bottle-turn"]\nseeds = [0, 1]\n'
THREE = SMALL + '[[jobs]]\nscenes = ["box-turn"]\nseeds = [0, 1, 2]\n'
HANG_GUARD_S = 600


def _write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def _events(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "jobs.jsonl").read_text().splitlines()]


def _job_dirs(out: Path) -> list[Path]:
    return sorted(p for p in (out / "jobs").iterdir() if not p.name.startswith("."))


def _arrays(result_dir: Path) -> list[dict]:
    rows = []
    for f in sorted((result_dir / "solutions").glob("sol_*.npz")):
        with np.load(f) as z:
            rows.append({k: z[k] for k in z.files})
    return rows


def _wait_for(what: str, condition, timeout: float = HANG_GUARD_S):
    """Poll ``condition`` until it returns something truthy; fail after ``timeout`` s (a hang guard only)."""
    t0 = time.monotonic()
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() - t0 > timeout:
            pytest.fail(f"hang guard: {what} did not happen within {timeout} s")
        time.sleep(0.05)


def _alive(pid: int) -> bool:
    """A process that exists and is not a zombie."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state not in ("Z", "X")


def _assert_exactly_once(out: Path, ids: set[str]) -> None:
    """Every job finished exactly once, each attempt started once and ended once, every directory whole."""
    ev = _events(out)
    finishes = [e["job"] for e in ev if e["event"] == "finish"]
    assert sorted(finishes) == sorted(ids), "each job finishes exactly once"
    starts = [(e["job"], e["attempt"]) for e in ev if e["event"] == "start"]
    ends = [(e["job"], e["attempt"]) for e in ev if e["event"] in ("finish", "fail")]
    assert len(starts) == len(set(starts)) and sorted(starts) == sorted(ends), "every attempt starts and ends once"
    assert {p.name for p in _job_dirs(out)} == ids
    for d in _job_dirs(out):
        res = load_result(d)
        stats = json.loads((d / "stats.json").read_text())
        meta = json.loads((d / "job.json").read_text())
        assert res.complete and stats["complete"] is True and len(res.solutions) == stats["solutions"]
        assert meta["id"] == d.name and json.loads((d / "check.json").read_text())["path"]
        assert (d.name, meta["attempt"]) in starts
    assert not list((out / "jobs" / ".staging").iterdir())
    with open(out / "summary.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert sorted(r["job"] for r in rows) == sorted(ids) and {r["status"] for r in rows} == {"finished"}


# --------------------------------------------------------------------------------------------- manifests


@pytest.fixture(scope="module")
def hand_xml(tmp_path_factory) -> Path:
    """The built-in right hand exported as MJCF: a hand file that needs no shared data."""
    path = tmp_path_factory.mktemp("hands") / "my_hand.xml"
    assert cli(["hand", "export-mjcf", str(path)]) == 0
    return path


def test_manifest_expands_scenes_seeds_hands_as_a_product(tmp_path, hand_xml):
    shutil.copy(hand_xml, tmp_path / "h.xml")
    m = load_manifest(_write(tmp_path / "sub" / "batch.toml", SMALL + '[[jobs]]\nscenes = ["box-turn", '
                             '"bottle-turn"]\nseeds = [0, 1, 2]\nhands = ["default", "../h.xml"]\n'
                             '[[jobs]]\nscenes = ["box-turn"]\nseeds = [0]\nmax_nodes = 500\n'))
    assert len(m.jobs) == 2 * 3 * 2 + 1 and len(set(m.ids)) == len(m.jobs)
    assert [(j.scene, j.seed, j.hand == "default") for j in m.jobs[:4]] == [
        ("box-turn", 0, True), ("box-turn", 0, False), ("box-turn", 1, True), ("box-turn", 1, False)]
    assert m.jobs[0].id.startswith("box-turn_s0_default_") and m.jobs[1].id.startswith("box-turn_s0_h_")
    hand = m.jobs[1].argv()[m.jobs[1].argv().index("--hand") + 1]
    assert hand == f"right={(tmp_path / 'h.xml').resolve()}"          # relative to the manifest's directory
    assert dict(m.jobs[-1].options)["max_nodes"] == 500 and dict(m.jobs[0].options)["max_nodes"] == 300


def test_job_id_hashes_what_is_computed_not_how_it_is_written(tmp_path, hand_xml):
    import torchhand

    ids = lambda text: load_manifest(_write(tmp_path / "m.toml", text)).ids  # noqa: E731
    base = ids(THREE)
    assert ids(THREE.replace('trees = 4', 'trees = 4\nepsilon = 10.0\nstrategy = "mixed"')) == base  # defaults
    assert ids(THREE.replace("max_nodes = 300", "max_nodes = 301")) != base
    # a scene directory is hashed by content: a copy elsewhere has the same id, an edited one another
    a = torchhand.load_scene("box-turn").export(tmp_path / "scenes" / "bt")
    b = tmp_path / "copy" / "bt"
    shutil.copytree(a, b)
    one = lambda d: ids(SMALL + f'[[jobs]]\nscenes = ["{d}"]\n')[0]  # noqa: E731
    assert one(a) == one(b) and one(a).startswith("bt_s0_default_")
    toml = b / "scene.toml"
    toml.write_text(toml.read_text().replace("friction = 0.8", "friction = 0.9"))
    assert one(a) != one(b)
    # a hand file too
    h2 = tmp_path / "h2.xml"
    h2.write_bytes(hand_xml.read_bytes())
    hid = lambda p: ids(SMALL + f'[[jobs]]\nscenes = ["box-turn"]\nhands = ["{p}"]\n')[0]  # noqa: E731
    assert hid(hand_xml).split("_")[-1] == hid(h2).split("_")[-1]
    h2.write_bytes(hand_xml.read_bytes().replace(b"<mujoco", b"<!-- edited -->\n<mujoco", 1))
    assert hid(hand_xml).split("_")[-1] != hid(h2).split("_")[-1]


def test_options_are_synthesize_flags_with_its_defaults(tmp_path):
    """The manifest's option table and `torchhand synthesize` agree on every flag and default, and a job's
    command line parses back to its options."""
    import argparse

    from torchhand.cli import synthesize_cmd

    sub = argparse.ArgumentParser().add_subparsers()
    synthesize_cmd.register(sub)
    parser = sub.choices["synthesize"]
    dests = {a.dest: a for a in parser._actions}
    for name, spec in OPTIONS.items():
        action = next(a for a in parser._actions if spec.flag in a.option_strings)
        assert action.default == spec.default, name
    job = load_manifest(_write(tmp_path / "m.toml", THREE)).jobs[2]
    args = parser.parse_args(job.argv()[1:] + ["--out", "x"])
    assert args.scene == "box-turn" and args.seed == 2 and "seed" in dests
    for name, value in job.options:
        assert getattr(args, name) == value, name


@pytest.mark.parametrize("table, message", [
    ('[[jobs]]\nscenes = ["box-turn"]\nmax_node = 5\n', "unknown key 'max_node'"),
    ('[defaults]\nsolution = 2\n[[jobs]]\nscenes = ["box-turn"]\n', "unknown key 'solution'"),
    ('[[jobs]]\nscenes = ["box-turn"]\nseed = 1\n', "seeds = [0, 1]"),
    ('[[jobs]]\nscenes = ["box-turn"]\nmax_nodes = "many"\n', "max_nodes: expected an integer"),
    ('[[jobs]]\nscenes = ["box-turn"]\nframes = "9:3"\n', "frames"),
    ('[[jobs]]\nscenes = ["box-turn"]\nframes = "0:500"\n', "beyond scene box-turn's 66 frames"),
    ('[[jobs]]\nscenes = ["box-turn"]\nstrategy = "fast"\n', "strategy"),
    ('[[jobs]]\nscenes = []\n', "scenes: expected a non-empty list"),
    ('[[jobs]]\nseeds = [0]\n', "no 'scenes'"),
    ('[[jobs]]\nmethod = "capture"\nscenes = ["box-turn"]\n', "no 'interactions'"),
    ('[[jobs]]\nmethod = "manipulate"\nscenes = ["box-turn"]\n', "'box-turn' has no packaged grasp"),
    ('[[jobs]]\nmethod = "splice"\nscenes = ["box-turn"]\n', "torchhand splice --body"),
    ('[[jobs]]\nmethod = "dance"\nscenes = ["box-turn"]\n', "unknown method 'dance'"),
    ('[[jobs]]\nscenes = ["no-such-scene"]\n', "'no-such-scene' is neither a built-in scene"),
    ('[[jobs]]\nscenes = ["./missing_dir"]\n', "does not exist"),
    ('[[jobs]]\nscenes = ["box-turn"]\nhands = ["left=h.xml"]\n', "does not exist"),
    ('[jobs]\nscenes = ["box-turn"]\n', "at least one [[jobs]]"),
    ('[[jobs]\n', "malformed TOML"),
])
def test_bad_manifests_name_the_problem(tmp_path, table, message):
    with pytest.raises(TorchhandError, match=None) as err:
        load_manifest(_write(tmp_path / "m.toml", table))
    assert message in str(err.value) and "\n" not in str(err.value)


def test_a_hand_for_a_side_the_scene_lacks(tmp_path, hand_xml):
    with pytest.raises(TorchhandError, match="scene box-turn has no left hand"):
        load_manifest(_write(tmp_path / "m.toml", f'[[jobs]]\nscenes = ["box-turn"]\nhands = ["left={hand_xml}"]\n'))


def test_example_manifest_parses():
    example = Path(__file__).resolve().parents[2] / "examples" / "batch.toml"
    m = load_manifest(example, check_inputs=False)
    assert len(m.jobs) == 12 and {j.method for j in m.jobs} == {"synthesize"}


def test_ray_is_imported_only_for_ray():
    code = ("import sys, torchhand.batch, torchhand.batch.ray_backend; from torchhand.cli import build_parser; "
            "build_parser(); print('ray' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "False", out.stderr


# --------------------------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("case", ["unknown key", "unknown scene", "missing hand", "unknown method", "future method",
                                  "workers 0", "threads 0", "ray missing", "out is a file", "out not a batch"])
def test_bad_input_is_one_line_exit_2_and_nothing_written(tmp_path, capsys, monkeypatch, case):
    text = {"unknown key": FOUR.replace("trees = 4", "treez = 4"),
            "unknown scene": SMALL + '[[jobs]]\nscenes = ["box-turm"]\n',
            "missing hand": SMALL + '[[jobs]]\nscenes = ["box-turn"]\nhands = ["hands/none.xml"]\n',
            "unknown method": FOUR.replace('method = "synthesize"', 'method = "synthesise"'),
            "future method": FOUR.replace('method = "synthesize"', 'method = "splice"')}.get(case, FOUR)
    manifest = _write(tmp_path / "batch.toml", text)
    out = tmp_path / "out"
    extra = {"workers 0": ["--workers", "0"], "threads 0": ["--threads", "0"], "ray missing": ["--ray", "auto"]}
    if case == "ray missing":
        monkeypatch.setitem(sys.modules, "ray", None)               # `import ray` raises ImportError
    if case == "out is a file":
        out.write_text("x")
    if case == "out not a batch":
        out.mkdir()
        (out / "cat.jpg").write_text("x")
    before = sorted(p.name for p in tmp_path.rglob("*"))
    rc = cli(["batch", str(manifest), "--out", str(out), "--no-progress"] + extra.get(case, []))
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and err[0].startswith("torchhand: error:"), err
    expected = {"unknown key": "treez", "unknown scene": "box-turm", "missing hand": "none.xml",
                "unknown method": "synthesise", "future method": "splice", "workers 0": "--workers",
                "threads 0": "--threads", "ray missing": "pip install 'torchhand[ray]'",
                "out is a file": "not a directory", "out not a batch": "not a batch directory"}[case]
    assert expected in err[0]
    assert sorted(p.name for p in tmp_path.rglob("*")) == before


def test_an_unreachable_ray_cluster_is_bad_input(tmp_path, capsys):
    pytest.importorskip("ray", reason="Ray is not installed (pip install 'torchhand[ray]')")
    out = tmp_path / "out"
    rc = cli(["batch", str(_write(tmp_path / "batch.toml", FOUR)), "--out", str(out), "--ray", "127.0.0.1:1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "cannot reach a Ray cluster" in err[0] and not out.exists()


# --------------------------------------------------------------------------------------------- a local batch


@pytest.fixture(scope="module")
def local_batch(tmp_path_factory):
    """Four jobs on the local pool, two workers."""
    root = tmp_path_factory.mktemp("batch")
    manifest = _write(root / "batch.toml", FOUR)
    out = root / "local"
    rc = cli(["batch", str(manifest), "--out", str(out), "--workers", "2", "--no-progress"])
    return rc, manifest, out


def test_local_batch_finishes_every_job_once_with_its_check(local_batch):
    rc, manifest, out = local_batch
    assert rc == 0
    ids = set(load_manifest(manifest).ids)
    assert len(ids) == 4
    _assert_exactly_once(out, ids)
    batch = json.loads((out / "batch.json").read_text())
    assert batch["runs"][-1]["workers"] == 2 and batch["runs"][-1]["threads"] == 1
    assert (out / "batch.toml").read_text() == manifest.read_text()
    for d in _job_dirs(out):
        assert json.loads((d / "stats.json").read_text())["threads"] == 1
        assert json.loads((d / "job.json").read_text())["threads"] == 1


def test_summary_counts_every_job_once_from_stats(local_batch):
    _, _, out = local_batch
    with open(out / "summary.csv") as fh:
        rows = {r["job"]: r for r in csv.DictReader(fh)}
    assert set(rows) == {d.name for d in _job_dirs(out)}
    for d in _job_dirs(out):
        stats, check = (json.loads((d / f).read_text()) for f in ("stats.json", "check.json"))
        r = rows[d.name]
        for key in ("solutions", "dead_ends", "total_frames", "success_frames"):
            assert int(r[key]) == stats[key], key
        assert float(r["success_ratio"]) == pytest.approx(stats["success_ratio"])
        assert float(r["solution_ratio"]) == pytest.approx(stats["solution_ratio"])
        assert r["check"] == ("none" if not check["solutions"] else "pass" if check["passed"] else "fail")
    with open(out / "summary_scenes.csv") as fh:
        scenes = {r["scene"]: r for r in csv.DictReader(fh)}
    assert set(scenes) == {"box-turn", "bottle-turn", "all"}
    for name, agg in scenes.items():
        mine = [r for r in rows.values() if name in ("all", r["scene"])]
        assert int(agg["jobs"]) == len(mine) and int(agg["finished"]) == len(mine)
        for key in ("solutions", "dead_ends", "total_frames", "success_frames"):
            assert int(agg[key]) == sum(int(r[key]) for r in mine), (name, key)
        total = sum(int(r["total_frames"]) for r in mine)
        assert float(agg["success_ratio"]) == pytest.approx(sum(int(r["success_frames"]) for r in mine) / total)
    assert (out / "summary.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    md = (out / "summary.md").read_text()
    assert all(md.count(i) == 1 for i in rows)


def test_rerun_of_a_finished_batch_runs_nothing(local_batch, capsys):
    rc, manifest, out = local_batch
    before = [e for e in _events(out) if e["event"] != "batch"]
    assert cli(["batch", str(manifest), "--out", str(out), "--no-progress"]) == 0
    assert [e for e in _events(out) if e["event"] != "batch"] == before
    assert "4 finished (4 before this run)" in capsys.readouterr().out


def test_another_manifest_is_refused_unless_update(local_batch, tmp_path, capsys):
    _, manifest, src = local_batch
    out = tmp_path / "copy"
    shutil.copytree(src, out)
    fewer = _write(tmp_path / "fewer.toml", SMALL + '[[jobs]]\nscenes = ["bottle-turn"]\nseeds = [0, 1]\n')
    batch_json = (out / "batch.json").read_bytes()
    assert cli(["batch", str(fewer), "--out", str(out), "--no-progress"]) == 2
    assert "another manifest" in capsys.readouterr().err and (out / "batch.json").read_bytes() == batch_json
    starts = sum(e["event"] == "start" for e in _events(out))
    assert cli(["batch", str(fewer), "--out", str(out), "--no-progress", "--update"]) == 0
    assert sum(e["event"] == "start" for e in _events(out)) == starts          # its jobs were finished
    with open(out / "summary.csv") as fh:
        assert sorted(r["job"] for r in csv.DictReader(fh)) == sorted(load_manifest(fewer).ids)


def test_a_second_batch_process_on_the_same_directory_is_refused(local_batch, tmp_path, capsys):
    _, manifest, src = local_batch
    out = tmp_path / "copy"
    shutil.copytree(src, out)
    with open(out / ".batch.lock", "a") as held:                    # as a running batch process holds it
        fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)
        assert cli(["batch", str(manifest), "--out", str(out), "--no-progress"]) == 2
    assert "another torchhand batch is running" in capsys.readouterr().err


# --------------------------------------------------------------------------------------------- kill -9


def _start_batch(manifest: Path, out: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "torchhand.cli", "batch", str(manifest), "--out", str(out),
                             "--workers", "2", "--no-progress", *extra], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)


def _in_flight(out: Path) -> list[dict]:
    """Start lines of attempts that have not ended, whose worker is alive."""
    if not (out / "jobs.jsonl").is_file():
        return []
    ev = _events(out)
    ended = {(e["job"], e["attempt"]) for e in ev if e["event"] in ("finish", "fail")}
    return [e for e in ev if e["event"] == "start" and (e["job"], e["attempt"]) not in ended and _alive(e["pid"])]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_a_worker_dies_with_the_process_that_started_it():
    """No orphan: a worker is killed by the kernel when its batch process dies (a child that would sleep an hour
    ends at once)."""
    code = ("import subprocess, sys, time; from torchhand.batch import worker; "
            "p = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(3600)'], **worker.popen_kwargs()); "
            "print(p.pid, flush=True); time.sleep(3600)")
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        child = int(parent.stdout.readline())
        assert _alive(child)
        parent.kill()
        parent.wait()
        _wait_for("the orphaned child to be killed", lambda: not _alive(child), timeout=60)
    finally:
        parent.kill()


def test_kill_9_of_the_batch_process_then_rerun_finishes_every_job_once(tmp_path):
    manifest = _write(tmp_path / "batch.toml", THREE)
    ids = set(load_manifest(manifest).ids)
    out = tmp_path / "out"
    proc = _start_batch(manifest, out)
    try:
        _wait_for("a first finished job", lambda: (out / "jobs.jsonl").is_file()
                  and any(e["event"] == "finish" for e in _events(out)))
        workers = [e["pid"] for e in _events(out) if e["event"] == "start"]
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    # its workers die with it (no orphan keeps writing), and no job directory is partial
    _wait_for("the killed batch's workers to end", lambda: not any(_alive(p) for p in workers))
    done = _job_dirs(out)
    assert 1 <= len(done) < len(ids), "the batch was killed in the middle"
    for d in done:
        assert json.loads((d / "stats.json").read_text())["complete"] is True and (d / "check.json").is_file()
    assert cli(["batch", str(manifest), "--out", str(out), "--workers", "2", "--no-progress"]) == 0
    _assert_exactly_once(out, ids)
    ev = _events(out)
    assert all(e.get("late") for e in ev if e["event"] == "fail"), "the only failures are the killed attempts"


def test_kill_9_of_one_worker_is_a_recorded_failure_and_a_rerun_finishes_it(tmp_path):
    manifest = _write(tmp_path / "batch.toml", THREE)
    ids = set(load_manifest(manifest).ids)
    out = tmp_path / "out"
    proc = _start_batch(manifest, out)
    try:
        victim = _wait_for("a running worker", lambda: _in_flight(out))[0]
        os.kill(victim["pid"], signal.SIGKILL)
        rc = proc.wait(timeout=HANG_GUARD_S)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert rc == 1                                                    # the batch went on, and says a job failed
    ev = _events(out)
    fails = [e for e in ev if e["event"] == "fail"]
    assert [(e["job"], e["attempt"]) for e in fails] == [(victim["job"], victim["attempt"])]
    assert "SIGKILL" in fails[0]["error"] and not (out / "jobs" / victim["job"]).exists()
    assert {e["job"] for e in ev if e["event"] == "finish"} == ids - {victim["job"]}
    with open(out / "summary.csv") as fh:
        status = {r["job"]: r["status"] for r in csv.DictReader(fh)}
    assert status[victim["job"]] == "failed" and list(status.values()).count("finished") == len(ids) - 1
    assert cli(["batch", str(manifest), "--out", str(out), "--workers", "2", "--no-progress"]) == 0
    _assert_exactly_once(out, ids)
    assert [e["attempt"] for e in _events(out) if e["event"] == "finish" and e["job"] == victim["job"]] == [2]


# ------------------------------------------------------------------------------------ seeds in one worker process

FOUR_GROUPED = SMALL + '[[jobs]]\nscenes = ["box-turn"]\nseeds = [0, 1, 2]\n\n[[jobs]]\nscenes = ["bottle-turn"]\n' \
    + 'seeds = [5]\n'
SIX = FOUR_GROUPED + '\n[[jobs]]\nscenes = ["box-turn"]\nseeds = [7, 8]\ntrees = 3\n'


def test_seeds_grouped_in_one_process_give_each_jobs_own_files(tmp_path):
    """``--group 0`` runs box-turn's three seeds as one batched process (one scheduler), the other job alone: every
    job is finished once, in its own directory with its check, and its solution arrays are those of the same job run
    one per process."""
    manifest = _write(tmp_path / "batch.toml", FOUR_GROUPED)
    grouped, alone = tmp_path / "grouped", tmp_path / "alone"
    assert cli(["batch", str(manifest), "--out", str(grouped), "--workers", "1", "--group", "0",
                "--no-progress"]) == 0
    assert cli(["batch", str(manifest), "--out", str(alone), "--workers", "2", "--no-progress"]) == 0
    ids = set(load_manifest(manifest).ids)
    assert len(ids) == 4
    _assert_exactly_once(grouped, ids)
    starts = [e for e in _events(grouped) if e["event"] == "start"]
    assert sorted(e.get("group", 1) for e in starts) == [1, 3, 3, 3]
    assert len({e["pid"] for e in starts if e.get("group")}) == 1
    assert json.loads((grouped / "batch.json").read_text())["runs"][-1]["group"] == 0
    for d in _job_dirs(grouped):
        assert (d / "check.json").is_file()
        a, b = _arrays(d), _arrays(alone / "jobs" / d.name)
        assert len(a) == len(b)
        for x, y in zip(a, b):
            assert x.keys() == y.keys() and all(np.array_equal(x[k], y[k]) for k in x), d.name
    # the scene row's rate: the group's node tests over its one shared search, not over three
    box = [json.loads((d / "stats.json").read_text()) for d in _job_dirs(grouped)
           if json.loads((d / "stats.json").read_text())["scene"] == "box-turn"]
    with open(grouped / "summary_scenes.csv") as fh:
        rate = float(next(r for r in csv.DictReader(fh) if r["scene"] == "box-turn")["node_tests_per_s"])
    assert rate == pytest.approx(box[0]["timings_s"]["batch_nodes"] / box[0]["timings_s"]["search_s"], rel=1e-6)
    assert cli(["batch", str(manifest), "--out", str(grouped), "--group", "0", "--no-progress"]) == 0
    assert len([e for e in _events(grouped) if e["event"] == "start"]) == 4          # a rerun runs nothing


def test_kill_9_of_a_grouped_worker_fails_its_jobs_and_a_rerun_alone_finishes_them(tmp_path):
    """A worker running three seeds in one process dies: each of its jobs still running gets its own failed attempt
    (none leaves a directory), the other jobs finish, and a rerun without grouping finishes each job exactly once."""
    long = FOUR_GROUPED.replace("solutions = 1", "solutions = 50")
    manifest = _write(tmp_path / "batch.toml", long)             # the group runs its budget: there is time to kill
    ids = set(load_manifest(manifest).ids)
    out = tmp_path / "out"
    proc = _start_batch(manifest, out, "--workers", "1", "--group", "0")
    try:
        group = _wait_for("a running group", lambda: [e for e in _in_flight(out) if e.get("group") == 3])
        pid = group[0]["pid"]
        os.kill(pid, signal.SIGKILL)
        rc = proc.wait(timeout=HANG_GUARD_S)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert rc == 1
    ev = _events(out)
    ran = {(e["job"], e["attempt"]) for e in ev if e["event"] == "start" and e["pid"] == pid}
    failed = {(e["job"], e["attempt"]) for e in ev if e["event"] == "fail"}
    finished = {(e["job"], e["attempt"]) for e in ev if e["event"] == "finish"}
    assert len(ran) == 3 and failed and failed <= ran and ran <= failed | finished and not failed & finished
    assert all("SIGKILL" in e["error"] for e in ev if e["event"] == "fail")
    assert not any((out / "jobs" / job).exists() for job, _ in failed)
    assert {job for job, _ in finished} == ids - {job for job, _ in failed}
    assert cli(["batch", str(manifest), "--out", str(out), "--workers", "2", "--no-progress"]) == 0
    _assert_exactly_once(out, ids)
    again = [e for e in _events(out) if e["event"] == "start" and (e["job"], e["attempt"] - 1) in failed]
    assert len(again) == len(failed) and not any(e.get("group") for e in again)


def test_grouping_keeps_other_jobs_alone_and_splits_over_workers():
    """Only synthesis jobs whose command lines differ in ``--seed`` alone share a process; group 0 splits them
    evenly over the workers."""
    import tempfile

    from torchhand.batch.runner import plan_run, units

    with tempfile.TemporaryDirectory() as d:
        jobs = load_manifest(_write(Path(d) / "b.toml", SIX)).jobs
    todo = [(j, 1) for j in jobs]
    sizes = lambda plan: sorted(len(u) for u in units(todo, plan))
    assert sizes(plan_run(workers=1, threads=1, cpus=2)) == [1] * 6
    assert sizes(plan_run(workers=1, threads=1, cpus=2, group=0)) == [1, 2, 3]
    assert sizes(plan_run(workers=2, threads=1, cpus=2, group=0)) == [1, 1, 1, 1, 2]
    assert sizes(plan_run(workers=1, threads=1, cpus=2, group=2)) == [1, 1, 2, 2]
    with pytest.raises(TorchhandError, match="--group"):
        plan_run(workers=1, threads=1, cpus=2, group=-1)
