"""The result contract (torchhand/result.py) on a real `torchhand synthesize` output: round trip, hands, versions,
partial runs, and errors that name the file and the key."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

import torchhand
from torchhand.errors import (FileFormatError, InputValueError, MissingFileError, ShapeError, TorchhandError,
                              UnknownNameError)
from torchhand.io.result import FORMAT_VERSION, load_result, load_solution, parse_solution_spec, solution_from_arrays

from ..render.real_result import real_box_turn

REQUIRED = ("q", "joint_names", "root_pose", "object_pose", "fps", "contact_mask", "contact_link",
            "contact_link_name", "contact_point", "contact_normal", "contact_force", "contact_sliding",
            "env_contact_mask", "env_contact_point", "env_contact_force", "reconstructed")


@pytest.fixture(scope="session")
def real(tmp_path_factory):
    return real_box_turn(tmp_path_factory)


def _arrays(path) -> dict:
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def _copy(real, tmp_path):
    out = tmp_path / "result"
    shutil.copytree(real, out)
    return out


def test_round_trip(real):
    r = torchhand.load_result(real)
    assert isinstance(r, torchhand.Result)
    assert r.complete is True and r.format_version == FORMAT_VERSION == r.stats["format_version"]
    assert len(r.solution_files) == len(r.solutions) == r.stats["solutions"] == 3
    model = r.hand_models["right"]
    T = r.scene.T
    for i, s in enumerate(r.solutions):
        raw = _arrays(r.solution_files[i])
        assert s.index == i and s.T == T and s.format_version == FORMAT_VERSION
        assert [h.side for h in s.hands] == [t.side for t in r.scene.hands] == ["right"]
        assert s.q.shape == (T, model.num_joints) and s.q.dtype == np.float64
        assert s.hands[0].joint_names == tuple(model.joint_names)
        assert s.root_pose.shape == (T, 4, 4) and s.hands[0].guiding.shape == (T, 5)
        for key in ("q", "root_pose", "object_pose", "contact_point", "contact_normal", "contact_force",
                    "env_contact_point", "env_contact_force"):
            assert np.array_equal(getattr(s, key), raw[key]), key
        for key in ("contact_mask", "contact_link", "contact_sliding", "env_contact_mask"):
            assert np.array_equal(getattr(s, key), raw[key]) and getattr(s, key).dtype == raw[key].dtype, key
        assert s.contact_mask.any() and not (s.contact_sliding & ~s.contact_mask).any()
        assert s.contact_link_name == tuple(model.link_names) == s.contact_link_names()
        assert s.fps == pytest.approx(r.scene.fps) and s.friction == pytest.approx(r.scene.friction)
        assert s.strategy == r.stats["strategy"] and s.reconstructed is r.stats["reconstructed"][i]
        assert (i in r.stats["unsmoothed"]) is (not s.reconstructed)
        side, link = s.contact_side_link()
        assert (side[s.contact_mask] == 0).all() and (link == np.where(s.contact_mask, s.contact_link, -1)).all()
        again = solution_from_arrays(raw, r.solution_files[i])
        assert np.array_equal(again.q, s.q) and again.index == i
    assert r.solution(1).path == r.solution_files[1]
    with pytest.raises(InputValueError, match="has 3 solutions"):
        r.solution(3)


def test_one_hand_q_and_two_hands(real, tmp_path):
    s = load_solution(real / "solutions" / "sol_000.npz")
    assert s.q is s.hands[0].q and s.root_pose is s.hands[0].root_pose and s.hand("right") is s.hands[0]
    with pytest.raises(UnknownNameError, match="'right'"):
        s.hand("left")
    data = _arrays(real / "solutions" / "sol_000.npz")
    names = [str(n) for n in data["contact_link_name"]]
    two = {**data, "q_right": data["q"], "q_left": data["q"] + 0.1, "root_pose_right": data["root_pose"],
           "root_pose_left": data["root_pose"], "guiding_right": data["guiding"], "guiding_left": data["guiding"],
           "contact_link_name": np.array([f"right/{n}" for n in names] + [f"left/{n}" for n in names])}
    np.savez(tmp_path / "sol_007.npz", **two)
    s2 = load_solution(tmp_path / "sol_007.npz")
    assert s2.index == 7 and [h.side for h in s2.hands] == ["right", "left"]
    assert np.array_equal(s2.hand("left").q, data["q"] + 0.1) and s2.hand("left").root_pose.shape == s.root_pose.shape
    for attr in ("q", "root_pose"):
        with pytest.raises(InputValueError, match=r'hand\("right"\)\.' + attr + r' or \.hand\("left"\)'):
            getattr(s2, attr)
    with pytest.raises(ShapeError, match="expected 1 hand"):  # the directory's scene has one hand
        shutil.copy(tmp_path / "sol_007.npz", _copy(real, tmp_path) / "solutions" / "sol_000.npz")
        load_result(tmp_path / "result").solution(0)


def test_newer_format_version_is_refused(real, tmp_path):
    root = _copy(real, tmp_path)
    f = root / "solutions" / "sol_001.npz"
    np.savez(f, **{**_arrays(f), "format_version": np.array(FORMAT_VERSION + 1)})
    with pytest.raises(FileFormatError, match=rf"sol_001.npz: format_version {FORMAT_VERSION + 1} is newer"):
        load_solution(f)
    stats = json.loads((root / "stats.json").read_text())
    (root / "stats.json").write_text(json.dumps({**stats, "format_version": FORMAT_VERSION + 1}))
    with pytest.raises(FileFormatError, match="stats.json: format_version"):
        load_result(root)
    (root / "stats.json").write_text(json.dumps({**stats, "format_version": "1"}))
    with pytest.raises(FileFormatError, match="expected a non-negative integer"):
        load_result(root)


def test_unversioned_files_read_as_version_0(real, tmp_path):
    root = _copy(real, tmp_path)
    f = root / "solutions" / "sol_000.npz"
    data = _arrays(f)
    del data["format_version"]
    np.savez(f, **data)
    stats = json.loads((root / "stats.json").read_text())
    for key in ("format_version", "complete"):
        del stats[key]
    (root / "stats.json").write_text(json.dumps(stats))
    r = load_result(root)
    assert r.format_version == 0 and r.complete is True and r.solution(0).format_version == 0
    del data["contact_sliding"]
    np.savez(f, **data)
    with pytest.raises(FileFormatError, match="missing array 'contact_sliding'.*before format_version 1"):
        r.solution(0)


def test_partial_result(real, tmp_path):
    root = _copy(real, tmp_path)
    for extra in sorted((root / "solutions").glob("sol_*.npz"))[1:]:
        extra.unlink()
    (root / "stats.json").write_text(json.dumps({"format_version": FORMAT_VERSION, "complete": False,
                                                 "scene": "box-turn", "solutions": 1}))
    r = load_result(root)
    assert r.complete is False and len(r.solutions) == 1 and r.solutions[0].T == r.scene.T
    shutil.rmtree(root / "solutions")  # a run that has written its scene and stats only
    r = load_result(root)
    assert r.complete is False and r.solutions == ()
    (root / "stats.json").write_text(json.dumps({"complete": "no"}))
    with pytest.raises(FileFormatError, match="stats.json: complete: expected true or false"):
        load_result(root)
    (root / "stats.json").write_text(json.dumps({"format_version": FORMAT_VERSION, "complete": True}))
    with pytest.raises(MissingFileError, match="no solutions/ directory"):
        load_result(root)


@pytest.mark.parametrize("key", REQUIRED)
def test_missing_key_names_file_and_key(real, tmp_path, key):
    data = _arrays(real / "solutions" / "sol_000.npz")
    del data[key]
    np.savez(tmp_path / "sol_000.npz", **data)
    with pytest.raises(FileFormatError, match=rf"sol_000.npz: missing array '{key}'"):
        load_solution(tmp_path / "sol_000.npz")


@pytest.mark.parametrize("key, change, error, message", [
    ("root_pose", lambda a: a[:, :3], ShapeError, r"root_pose: expected shape \({T}, 4, 4\), got \({T}, 3, 4\)"),
    ("contact_force", lambda a: a[..., :2], ShapeError, r"contact_force: expected shape \({T}, \d+, 3\)"),
    ("contact_sliding", lambda a: a[:-1], ShapeError, r"contact_sliding: expected shape \({T}, \d+\)"),
    ("object_pose", lambda a: a[:-1], ShapeError, r"object_pose: expected shape \({T}, 4, 4\)"),
    ("joint_names", lambda a: a[:-1], ShapeError, r"joint_names: expected 30 names"),
    ("contact_mask", lambda a: a.astype(np.float64), FileFormatError, "contact_mask: expected bool values"),
    ("q", lambda a: np.where(np.arange(a.size).reshape(a.shape) == 7, np.nan, a), FileFormatError,
     "q: contains NaN or inf"),
    ("fps", lambda a: np.array(-30.0), FileFormatError, "fps: expected a positive number"),
    ("contact_link", lambda a: np.where(a >= 0, 99, a), FileFormatError,
     r"contact_link: expected indices in \[0, 20\)"),
    ("reconstructed", lambda a: np.array([True, False]), FileFormatError, "reconstructed: expected a 0-d array"),
])
def test_bad_arrays_name_file_key_and_shape(real, tmp_path, key, change, error, message):
    data = _arrays(real / "solutions" / "sol_001.npz")
    data[key] = change(data[key])
    np.savez(tmp_path / "sol_001.npz", **data)
    with pytest.raises(error, match=rf"sol_001.npz: {message.replace('{T}', str(len(data['q'])))}"):
        load_solution(tmp_path / "sol_001.npz")


def test_bad_files_and_directories(real, tmp_path):
    with pytest.raises(MissingFileError, match="does not exist"):
        load_solution(tmp_path / "none.npz")
    (tmp_path / "junk.npz").write_bytes(b"PK\x03\x04 not a zip")
    with pytest.raises(FileFormatError, match="junk.npz: not a readable solution npz"):
        load_solution(tmp_path / "junk.npz")
    with pytest.raises(MissingFileError, match="does not exist"):
        load_result(tmp_path / "nope")
    with pytest.raises(MissingFileError, match="no scene/ directory"):
        load_result(tmp_path)
    root = _copy(real, tmp_path)
    (root / "stats.json").write_text("{not json")
    with pytest.raises(FileFormatError, match="stats.json: not valid JSON"):
        load_result(root)
    (root / "stats.json").write_text("[1, 2]")
    with pytest.raises(FileFormatError, match="stats.json: expected a JSON object"):
        load_result(root)


def test_hand_model_fallback(real, tmp_path):
    root = _copy(real, tmp_path)
    (root / "hand.xml").unlink()
    r = load_result(root)
    assert r.hand_models["right"].num_joints == load_result(real).hand_models["right"].num_joints


def test_parse_solution_spec():
    assert parse_solution_spec(None, 3) == [0] and parse_solution_spec("all", 3) == [0, 1, 2]
    assert parse_solution_spec("0,2", 3) == [0, 2] and parse_solution_spec("1:", 3) == [1, 2]
    for bad in ("3", "x", "-1"):
        with pytest.raises(TorchhandError, match="--solutions"):
            parse_solution_spec(bad, 3)
    with pytest.raises(InputValueError, match="no solutions"):
        parse_solution_spec("all", 0)


def test_import_stays_light():
    import subprocess
    import sys

    code = ("import sys, torchhand.io.result\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'pyrender', 'trimesh')\n"
            "             or m.startswith('torchhand.synthesis')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "[]", out.stdout + out.stderr
