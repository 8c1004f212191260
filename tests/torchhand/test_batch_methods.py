"""``torchhand batch`` with ``method = "manipulate"`` (Liu 2009) and ``method = "capture"`` (Kry & Pai 2006
resynthesis): the option tables agree with the commands, manifests expand and hash what the jobs compute, bad
manifests are refused before any work with a line naming the problem, and one small batch (a built-in manipulation,
a manipulation whose grasp is unsuitable, a resynthesis of a tiny pinch interaction) finishes every job once, records
the unsuitable grasp as the job's answer, passes the independent checker, and does nothing when run again.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from torchhand.batch import load_manifest
from torchhand.batch.manifest import CAPTURE_OPTIONS, MANIPULATE_OPTIONS
from torchhand.batch.worker import RUN_FLAGS
from torchhand.cli import main as cli
from torchhand.errors import TorchhandError
from torchhand.scene.builtin.liu import grasp_path

from .test_resynth import pinch_files

MANIPULATE = '[[jobs]]\nmethod = "manipulate"\nscenes = ["liu-push"]\nframes = "0:8"\n'


def _write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def pinch(tmp_path_factory) -> Path:
    """A directory holding pinch/scene/ and pinch/interaction.npz (a two-finger pinch lifting a box, 30 fps)."""
    root = tmp_path_factory.mktemp("capture")
    pinch_files(root / "pinch", fps=30.0)
    return root


@pytest.fixture(scope="module")
def pushed(tmp_path_factory) -> Path:
    """liu-push as a scene directory with its packaged grasp and a 1000 N push on the object from frame 0, beyond
    what 30 N contacts can hold: the grasp is unsuitable at frame 0."""
    from torchhand.scene import load_scene

    root = tmp_path_factory.mktemp("pushed")
    scene = load_scene("liu-push")
    push = torch.zeros(scene.T, 6, dtype=torch.float64)
    push[:, 0] = 1000.0
    d = dataclasses.replace(scene, external_wrench=push).export(root / "pushed0")
    shutil.copyfile(grasp_path("liu-push"), d / "grasp.npz")
    return d


def _parser(method: str) -> argparse.ArgumentParser:
    from torchhand.cli import capture_cmd, manipulate_cmd

    sub = argparse.ArgumentParser().add_subparsers()
    if method == "manipulate":
        manipulate_cmd.register(sub)
        return sub.choices["manipulate"]
    capture_cmd.register(sub)
    return sub.choices["capture"]._subparsers._group_actions[0].choices["resynthesize"]


def _floats(text) -> tuple | None:
    return None if text is None else tuple(float(v) for v in str(text).split(","))


# ------------------------------------------------------------------------------------------ option tables


@pytest.mark.parametrize("method, table", [("manipulate", MANIPULATE_OPTIONS), ("capture", CAPTURE_OPTIONS)])
def test_option_tables_are_the_commands_flags_with_their_defaults(method, table):
    """Every option is a flag of the command with the command's default; every flag of the command is an option,
    an input or a run flag (so a new flag is noticed); the run flags the worker adds are the command's."""
    parser = _parser(method)
    flags = {s: a for a in parser._actions for s in a.option_strings}
    for name, spec in table.items():
        assert spec.flag in flags, (method, spec.flag)
        default = flags[spec.flag].default
        default = _floats(default) if spec.kind == "floats" else bool(default) if spec.kind == "bool" else default
        assert default == spec.default, (method, name, default, spec.default)
        if spec.choices:
            assert tuple(flags[spec.flag].choices) == spec.choices, (method, name)
    # --variants (capture): a file of named variants, the command line's alternative to a manifest's option lists
    inputs = {"--grasp", "--scene", "--out", "--overwrite", "--threads", "--device", "--no-progress", "-h", "--help",
              "--variants"}
    options = {spec.flag for spec in table.values()}
    assert set(flags) - inputs == options, (method, set(flags) - inputs ^ options)
    for flag in ("--device", "--no-progress"):
        assert (flag in flags) == (flag in RUN_FLAGS[method]), (method, flag)


def test_synthesize_options_with_choices_offer_the_commands_choices():
    """A manifest's synthesize options that take one of a list (``strategy``, ``dtype``, ...) offer exactly what
    ``torchhand synthesize`` accepts, so a new strategy is noticed here."""
    from torchhand.batch.manifest import OPTIONS
    from torchhand.cli import synthesize_cmd

    sub = argparse.ArgumentParser().add_subparsers()
    synthesize_cmd.register(sub)
    flags = {s: a for a in sub.choices["synthesize"]._actions for s in a.option_strings}
    with_choices = [spec for spec in OPTIONS.values() if spec.choices]
    assert any(spec.flag == "--strategy" for spec in with_choices)
    for spec in with_choices:
        assert tuple(flags[spec.flag].choices) == spec.choices, spec.flag


def test_a_jobs_command_line_parses_back_to_its_options(tmp_path, pinch):
    m = load_manifest(_write(tmp_path / "m.toml", MANIPULATE + "window = 5\nno_objective = true\n"))
    (job,) = m.jobs
    args = _parser("manipulate").parse_args(job.argv()[1:] + ["--out", "x"])
    assert args.scene == "liu-push" and args.grasp is None           # the scene's own grasp: the command finds it
    assert (args.window, args.max_force, args.frames, args.no_objective) == (5, 30.0, "0:8", True)
    text = (f'[[jobs]]\nmethod = "capture"\ninteractions = ["{pinch}/pinch/interaction.npz"]\n'
            f'scenes = ["{pinch}/pinch/scene"]\nmass = [0.05, 0.1]\nfriction = 0.6\ngrip = "delayed"\n')
    (job,) = load_manifest(_write(tmp_path / "c.toml", text)).jobs
    args = _parser("capture").parse_args(job.argv()[2:] + ["--out", "x"])
    assert args.interaction == str(pinch / "pinch" / "interaction.npz") and args.scene == str(pinch / "pinch" / "scene")
    opts = dict(job.options)
    for name, spec in CAPTURE_OPTIONS.items():
        value = getattr(args, name)
        assert (_floats(value) if spec.kind == "floats" else value) == opts[name], name
    assert opts["mass"] == (0.05, 0.1) and opts["friction"] == (0.6,) and opts["compliance_scale"] == (1.0,)


# ------------------------------------------------------------------------------------------ expansion and ids


def test_manipulate_jobs_are_scenes_by_grasps_and_hash_the_grasp(tmp_path):
    g = tmp_path / "grasps" / "g.npz"
    g.parent.mkdir()
    shutil.copyfile(grasp_path("liu-push"), g)
    text = ('[defaults]\nseeds = [0, 1]\nframes = "0:8"\n'          # seeds: taken by the synthesize table only
            '[[jobs]]\nmethod = "manipulate"\nscenes = ["liu-push", "liu-drag"]\ngrasps = ["default", "grasps/g.npz"]\n'
            '[[jobs]]\nscenes = ["box-turn"]\nmax_nodes = 10\n')
    ids = lambda t: load_manifest(_write(tmp_path / "m.toml", t)).ids  # noqa: E731
    m = load_manifest(_write(tmp_path / "m.toml", text))
    assert [j.method for j in m.jobs] == ["manipulate"] * 4 + ["synthesize"] * 2
    jobs = m.jobs[:4]
    assert [(j.scene, j.default_grasp) for j in jobs] == [("liu-push", True), ("liu-push", False),
                                                         ("liu-drag", True), ("liu-drag", False)]
    assert {j.seed for j in jobs} == {None} and {j.hand for j in jobs} == {"grasp"}
    assert jobs[0].id.startswith("liu-push_grasp_") and jobs[1].id.startswith("liu-push_g_")
    assert jobs[1].argv()[2:4] == ["--grasp", str(g.resolve())] and "--grasp" not in jobs[0].argv()
    # the grasp is hashed by content: liu-push's packaged grasp and its copy compute the same
    assert jobs[0].id.split("_")[-1] == jobs[1].id.split("_")[-1]
    base = ids(text)
    assert ids(text.replace('frames = "0:8"', 'frames = "0:8"\nwindow = 6\nmax_force = 30')) == base   # defaults
    assert ids(text.replace('frames = "0:8"', 'frames = "0:8"\nwindow = 7')) != base
    assert ids(text.replace('frames = "0:8"', 'frames = "0:8"\nno_objective = true')) != base
    with np.load(g) as z:
        data = {k: z[k] for k in z.files}
    data["wrist_in_object"][0, 3] += 1e-4                                # 0.1 mm: another grasp
    np.savez(g, **data)
    edited = ids(text)
    assert edited[1] != base[1] and edited[0] == base[0] and edited[4:] == base[4:]


def test_capture_jobs_are_interactions_by_scenes_and_hash_the_interaction(tmp_path, pinch):
    shutil.copytree(pinch / "pinch", tmp_path / "pinch")
    shutil.copytree(tmp_path / "pinch", tmp_path / "pinch2")
    text = ('[[jobs]]\nmethod = "capture"\ninteractions = ["pinch/interaction.npz", "pinch2/interaction.npz"]\n'
            'scenes = ["pinch/scene", "pinch2/scene"]\n')
    ids = lambda t: load_manifest(_write(tmp_path / "m.toml", t)).ids  # noqa: E731
    base = ids(text)
    m = load_manifest(tmp_path / "m.toml")
    # interaction-major; the two scene directories have the same name and content: one job per interaction
    assert [(Path(j.interaction).parent.name, Path(j.scene).parent.name) for j in m.jobs] == [
        ("pinch", "pinch"), ("pinch2", "pinch")]
    assert m.jobs[0].id.startswith("scene_pinch_") and m.jobs[1].id.startswith("scene_pinch2_")
    assert len({i.split("_")[-1] for i in base}) == 1                   # identical copies compute the same
    assert ids(text + "compliance_scale = [1.0]\ngrip = \"none\"\npyramid_m = 4\n") == base   # defaults filled in
    assert ids(text + "mass = 0.05\n") == ids(text + "mass = [0.05]\n") != base              # one number = a list
    assert ids(text + "mass = [0.05, 0.1]\n") != ids(text + "mass = [0.1, 0.05]\n")           # rollout order
    inter = tmp_path / "pinch2" / "interaction.npz"
    with np.load(inter) as z:
        data = {k: z[k] for k in z.files}
    data["C"] = data["C"] * 1.5
    np.savez(inter, **data)
    edited = ids(text)
    assert edited[0] == base[0] and edited[1] != base[1]


# ------------------------------------------------------------------------------------------ refusals

INTER = '[[jobs]]\nmethod = "capture"\ninteractions = ["{p}/pinch/interaction.npz"]\nscenes = ["{p}/pinch/scene"]\n'


@pytest.mark.parametrize("text, message", [
    (MANIPULATE + "seeds = [0, 1]\n", "key 'seeds' does not apply to method 'manipulate' (its result does not "
                                      "depend on a seed)"),
    (MANIPULATE + 'hands = ["default"]\n', "key 'hands' does not apply to method 'manipulate' (the hand is the "
                                           "grasp's)"),
    (INTER + 'hands = ["default"]\n', "key 'hands' does not apply to method 'capture' (the hand is the scene's)"),
    (INTER + "seeds = [3]\n", "key 'seeds' does not apply to method 'capture'"),
    (INTER + 'frames = "0:4"\n', "key 'frames' does not apply to method 'capture'"),
    (MANIPULATE + "max_nodes = 5\n", "key 'max_nodes' does not apply to method 'manipulate'"),
    (MANIPULATE + "windw = 5\n", "unknown key 'windw'"),
    (MANIPULATE + 'grasp = "g.npz"\n', 'list grasps as grasps = ["g.npz"]'),
    (MANIPULATE + "window = 0\n", "window: expected a number >= 1, got 0"),
    (MANIPULATE + "window = 9\n", "window: expected at most the 8 frames of the motion, got 9"),
    (MANIPULATE + "max_force = -1\n", "max_force: expected a number > 0"),
    (MANIPULATE.replace("0:8", "0:500"), "goes beyond scene liu-push's 60 frames"),
    (MANIPULATE + 'grasps = ["nope.npz"]\n', "grasp file 'nope.npz'"),
    ('[[jobs]]\nmethod = "manipulate"\nscenes = ["box-turn"]\n', "built-in scene 'box-turn' has no packaged grasp"),
    (INTER + 'grip = "tight"\n', "grip: expected one of none, delayed, imminent"),
    (INTER + "mass = []\n", "mass: expected a number or a non-empty list"),
    (INTER + "mass = [0.05, -1]\n", "mass: expected a number > 0"),
    (INTER + 'friction = ["high"]\n', "friction: expected a number or a list of numbers"),
    (INTER + "tighten = 1.5\n", "tighten: expected a number > 0 and <= 1"),
    (INTER + "pyramid_m = 2.5\n", "pyramid_m: expected an integer"),
    (INTER + "dt = 1.0\n", "is longer than the frame time"),
    (INTER.replace("{p}/pinch/interaction.npz", "{p}/none.npz"), "interaction file"),
    (INTER.replace("{p}/pinch/scene", "liu-push"), "is not a joint of the scene's hand"),
    ('[[jobs]]\nmethod = "capture"\nscenes = ["liu-push"]\n', "no 'interactions'"),
    ('[[jobs]]\nmethod = "splice"\nscenes = ["box-turn"]\n', "torchhand splice --body"),
    ("[defaults]\nseeds = [0, 1]\n" + MANIPULATE, "[defaults]: key 'seeds' applies to no [[jobs]] table of this "
                                                 "manifest (methods: manipulate)"),
])
def test_bad_manifests_name_the_problem(tmp_path, pinch, text, message):
    with pytest.raises(TorchhandError) as err:
        load_manifest(_write(tmp_path / "m.toml", text.replace("{p}", str(pinch))))
    assert message in str(err.value) and "\n" not in str(err.value), str(err.value)


def test_grasps_and_scenes_that_do_not_fit_are_refused(tmp_path, pushed):
    """A grasp whose joints are not its hand's; a scene directory without grasp.npz; a right-hand grasp on a scene
    with only a left hand."""
    with np.load(grasp_path("liu-push")) as z:
        data = {k: z[k] for k in z.files}
    bad = dict(data, joint_names=np.array(["j_" + str(n) for n in data["joint_names"]]))
    np.savez(tmp_path / "bad.npz", **bad)
    with pytest.raises(TorchhandError, match="joint_names do not match the hand"):
        load_manifest(_write(tmp_path / "m.toml", MANIPULATE + 'grasps = ["bad.npz"]\n'))
    bare = tmp_path / "bare"
    shutil.copytree(pushed, bare)
    (bare / "grasp.npz").unlink()
    with pytest.raises(TorchhandError, match="has no grasp.npz; list grasp files"):
        load_manifest(_write(tmp_path / "m.toml", '[[jobs]]\nmethod = "manipulate"\nscenes = ["bare"]\n'))
    left = dict(data, side=np.array("left"))
    np.savez(tmp_path / "left.npz", **left)
    with pytest.raises(TorchhandError, match="is a left hand's grasp; scene liu-push has right"):
        load_manifest(_write(tmp_path / "m.toml", MANIPULATE + 'grasps = ["left.npz"]\n'))


# ------------------------------------------------------------------------------------------ one small batch


@pytest.fixture(scope="module")
def batch(tmp_path_factory, pinch, pushed):
    """liu-push frames 0:8 (its packaged grasp), the pushed liu-push (unsuitable at frame 0) and the pinch
    resynthesis, on two workers of one thread; ``frames`` in [defaults] is taken by the manipulate tables only."""
    root = tmp_path_factory.mktemp("methods")
    shutil.copytree(pinch / "pinch", root / "pinch")
    shutil.copytree(pushed, root / "pushed0")
    manifest = _write(root / "batch.toml", '[defaults]\nframes = "0:8"\n'
                      '[[jobs]]\nmethod = "manipulate"\nscenes = ["liu-push"]\n'
                      '[[jobs]]\nmethod = "manipulate"\nscenes = ["pushed0"]\nframes = "0:6"\nwindow = 2\n'
                      '[[jobs]]\nmethod = "capture"\ninteractions = ["pinch/interaction.npz"]\n'
                      'scenes = ["pinch/scene"]\n')
    out = root / "out"
    rc = cli(["batch", str(manifest), "--out", str(out), "--workers", "2", "--threads", "1", "--no-progress"])
    return rc, manifest, out


def test_batch_runs_each_method_once_and_records_an_unsuitable_grasp(batch):
    rc, manifest, out = batch
    assert rc == 0
    push_id, pushed_id, cap_id = load_manifest(manifest).ids
    events = [json.loads(line) for line in (out / "jobs.jsonl").read_text().splitlines()]
    finishes = {e["job"]: e for e in events if e["event"] == "finish"}
    assert sorted(finishes) == sorted([push_id, pushed_id, cap_id]) and not [e for e in events if e["event"] == "fail"]
    assert finishes[pushed_id]["outcome"] == "unsuitable" and "outcome" not in finishes[push_id]
    # the manipulation: a complete liu2009 result of 8 frames that the checker passes
    d = out / "jobs" / push_id
    stats, check = (json.loads((d / f).read_text()) for f in ("stats.json", "check.json"))
    assert stats["method"] == "liu2009" and stats["complete"] is True and stats["T"] == 8 and check["passed"]
    assert json.loads((d / "job.json").read_text())["job"]["argv"][:2] == ["manipulate", "liu-push"]
    # the unsuitable grasp: a finished answer, frame 0, nothing to check
    u = json.loads((out / "jobs" / pushed_id / "unsuitable.json").read_text())
    assert u["status"] == "grasp_unsuitable" and u["frame"] == 0 and u["frames_done"] == 0
    assert u["message"].startswith("grasp unsuitable for this motion at frame 0: ") and "staging" not in u["message"]
    # the resynthesis: a kry_pai result with its one rollout completed, checked
    d = out / "jobs" / cap_id
    stats, check = (json.loads((d / f).read_text()) for f in ("stats.json", "check.json"))
    assert stats["method"] == "kry_pai" and stats["solutions"] == 1 and len(check["solutions"]) == 1
    assert [r["status"] for r in stats["rollouts"]] == ["COMPLETED"]
    with open(out / "summary.csv") as fh:
        rows = {r["job"]: r for r in csv.DictReader(fh)}
    assert [rows[i]["status"] for i in (push_id, pushed_id, cap_id)] == ["finished", "unsuitable", "finished"]
    assert rows[push_id]["check"] == "pass" and rows[push_id]["outcome"] == "8 frames, 0 contact(s) added"
    assert rows[pushed_id]["outcome"].endswith("(no frame written)") and rows[pushed_id]["check"] == "none"
    assert rows[cap_id]["outcome"] == "1/1 rollouts completed" and rows[cap_id]["method"] == "capture"
    assert "1 unsuitable (grasp)" in (out / "summary.md").read_text()


def test_torchhand_check_passes_the_manipulation(batch, capsys):
    _, manifest, out = batch
    rc = cli(["check", str(out / "jobs" / load_manifest(manifest).ids[0]), "--no-progress", "--threads", "1"])
    assert rc == 0 and "PASS: 1 of 1 solutions pass (complete run, scene liu-push)" in capsys.readouterr().out


def test_a_rerun_does_nothing(batch, capsys):
    _, manifest, out = batch
    before = (out / "jobs.jsonl").read_text().count('"event": "start"')
    capsys.readouterr()
    rc = cli(["batch", str(manifest), "--out", str(out), "--workers", "2", "--threads", "1", "--no-progress"])
    assert rc == 0 and "3 finished (3 before this run), 0 failed" in capsys.readouterr().out
    assert (out / "jobs.jsonl").read_text().count('"event": "start"') == before
