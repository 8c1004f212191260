"""``torchhand scene``: exit codes, one-line errors, and nothing written or destroyed on failure."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from torchhand.cli import main
from torchhand.scene import load_scene
from torchhand.scene.builtin import list_builtin_scenes

from tests.conftest import shared_data_dir as shared_data


MANIPNET = shared_data() / "mocap" / "manipnet" / "mug1"


def run(capsys, *argv):
    rc = main(list(argv))
    out, err = capsys.readouterr()
    return rc, out, err


def assert_one_line_error(rc, out, err, *fragments):
    assert rc == 2
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("torchhand: error: ")
    assert "Traceback" not in err
    for f in fragments:
        assert f in lines[0]


def snapshot(d: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(d.iterdir())}


def test_list(capsys):
    rc, out, _ = run(capsys, "scene", "list")
    assert rc == 0
    for n in list_builtin_scenes():
        assert n in out


def test_show_builtin(capsys):
    rc, out, _ = run(capsys, "scene", "show", "box-turn")
    assert rc == 0
    assert "66 at 30 fps" in out and "duration" in out and "0.250 kg" in out
    assert "right" in out and "table at z = 0.7500 m" in out


def test_show_unknown_name(capsys):
    rc, out, err = run(capsys, "scene", "show", "box-twirl")
    assert_one_line_error(rc, out, err, "box-twirl", "box-turn", "two-hand-box")


def test_show_missing_dir(capsys, tmp_path):
    rc, out, err = run(capsys, "scene", "show", str(tmp_path / "none"))
    assert_one_line_error(rc, out, err, "none")


def test_export_show_and_no_overwrite(capsys, tmp_path):
    target = tmp_path / "out"
    rc, out, _ = run(capsys, "scene", "export", "two-hand-box", str(target), "--frames", "4:40", "--fps", "15")
    assert rc == 0 and "wrote" in out
    scene = load_scene(target)
    assert scene.T == 18 and scene.fps == 15.0 and scene.sides == ("right", "left")
    rc, out, _ = run(capsys, "scene", "show", str(target))
    assert rc == 0 and "18 at 15 fps" in out
    before = snapshot(target)
    rc, out, err = run(capsys, "scene", "export", "box-turn", str(target))
    assert_one_line_error(rc, out, err, "--overwrite")
    assert snapshot(target) == before
    rc, _, _ = run(capsys, "scene", "export", "box-turn", str(target), "--overwrite")
    assert rc == 0 and load_scene(target).name == "box-turn"


def test_export_bad_frames(capsys, tmp_path):
    for frames in ("abc", "3:2", "0:999"):
        rc, out, err = run(capsys, "scene", "export", "box-turn", str(tmp_path / "x"), "--frames", frames)
        assert_one_line_error(rc, out, err)
    assert not (tmp_path / "x").exists()


@pytest.fixture
def exported(tmp_path) -> Path:
    return load_scene("box-pickup").export(tmp_path / "scene")


def test_show_malformed_toml(capsys, exported):
    text = (exported / "scene.toml").read_text().replace("[object]", "[object")
    (exported / "scene.toml").write_text(text)
    rc, out, err = run(capsys, "scene", "show", str(exported))
    assert_one_line_error(rc, out, err, "scene.toml", "line")


def test_show_nan_trajectory(capsys, exported):
    with np.load(exported / "trajectories.npz") as data:
        arrays = {k: data[k] for k in data.files}
    arrays["wrist_pose_right"][3, 0, 0] = np.nan
    np.savez(exported / "trajectories.npz", **arrays)
    rc, out, err = run(capsys, "scene", "show", str(exported))
    assert_one_line_error(rc, out, err, "wrist_pose_right", "NaN")


def test_show_missing_mesh(capsys, exported):
    (exported / "object.obj").unlink()
    rc, out, err = run(capsys, "scene", "show", str(exported))
    assert_one_line_error(rc, out, err, "object.obj")


def test_export_from_broken_dir_writes_nothing(capsys, exported, tmp_path):
    (exported / "scene.toml").write_text("format_version = 1\n[scene]\nfps = 0\n")
    rc, out, err = run(capsys, "scene", "export", str(exported), str(tmp_path / "copy"))
    assert_one_line_error(rc, out, err)
    assert not (tmp_path / "copy").exists()


@pytest.mark.parametrize("argv", [["scene"], ["scene", "list"], ["scene", "show"], ["scene", "export"],
                                  ["scene", "import-mocap"]])
def test_help(capsys, argv):
    with pytest.raises(SystemExit) as info:
        main(argv + ["--help"])
    assert info.value.code == 0
    assert "usage:" in capsys.readouterr().out


HAND_BVH = """HIERARCHY
ROOT wrist
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT index1
  {
    OFFSET 0.085 0.024 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0.09 0 0
    }
  }
  JOINT middle1
  {
    OFFSET 0.085 0 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0.1 0 0
    }
  }
  JOINT pinky1
  {
    OFFSET 0.085 -0.038 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0.075 0 0
    }
  }
}
MOTION
Frames: 4
Frame Time: 0.05
0.0 0.0 0.10 0 0 0 0 0 0 0 0 0 0 0 0
0.0 0.0 0.11 5 0 0 0 0 0 0 0 0 0 0 0
0.0 0.0 0.12 10 0 0 0 0 0 0 0 0 0 0 0
0.0 0.0 0.13 15 0 0 0 0 0 0 0 0 0 0 0
"""


@pytest.fixture
def mocap_inputs(tmp_path) -> Path:
    import trimesh

    (tmp_path / "hand.bvh").write_text(HAND_BVH)
    pose = np.tile(np.eye(4), (4, 1, 1))
    pose[:, :3, 3] = [0.15, 0.0, 0.03]
    np.savez(tmp_path / "obj.npz", object_pose=pose)
    trimesh.creation.box(extents=(0.06, 0.06, 0.06)).export(tmp_path / "box.obj")
    return tmp_path


def test_import_mocap(capsys, mocap_inputs):
    d = mocap_inputs
    out_dir = d / "scene"
    rc, out, err = run(capsys, "scene", "import-mocap", "--hand-bvh", str(d / "hand.bvh"), "--object-npz",
                       str(d / "obj.npz"), "--object-mesh", str(d / "box.obj"), "--up-axis", "z",
                       "--mass", "0.2", "--table-height", "0.0", "--out", str(out_dir))
    assert rc == 0, err
    scene = load_scene(out_dir)
    assert scene.T == 4 and scene.fps == 20.0 and scene.sides == ("right",)
    assert scene.environment.table and scene.object.mass == pytest.approx(0.2)


def test_import_mocap_left_side_flag(capsys, mocap_inputs):
    d = mocap_inputs
    rc, _, err = run(capsys, "scene", "import-mocap", "--hand-bvh", f"left={d / 'hand.bvh'}", "--object-npz",
                     str(d / "obj.npz"), "--object-mesh", str(d / "box.obj"), "--up-axis", "z",
                     "--out", str(d / "left"))
    assert rc == 0, err
    assert load_scene(d / "left").sides == ("left",)


def test_import_mocap_malformed_bvh_writes_nothing(capsys, mocap_inputs):
    d = mocap_inputs
    (d / "hand.bvh").write_text(HAND_BVH.replace("0.0 0.0 0.12 10", "0.0 zero 0.12 10"))
    rc, out, err = run(capsys, "scene", "import-mocap", "--hand-bvh", str(d / "hand.bvh"), "--object-npz",
                       str(d / "obj.npz"), "--object-mesh", str(d / "box.obj"), "--out", str(d / "scene"))
    assert_one_line_error(rc, out, err, "hand.bvh:", "zero")
    assert not (d / "scene").exists()


def test_import_mocap_missing_inputs(capsys, mocap_inputs):
    d = mocap_inputs
    rc, out, err = run(capsys, "scene", "import-mocap", "--hand-bvh", str(d / "nope.bvh"), "--object-npz",
                       str(d / "obj.npz"), "--object-mesh", str(d / "box.obj"), "--out", str(d / "scene"))
    assert_one_line_error(rc, out, err, "nope.bvh")
    rc, out, err = run(capsys, "scene", "import-mocap", "--hand-bvh", str(d / "hand.bvh"), "--out", str(d / "s"))
    assert_one_line_error(rc, out, err, "--object-mesh")
    assert not (d / "scene").exists() and not (d / "s").exists()


@pytest.mark.skipif(not (MANIPNET / "rightHand.bvh").is_file(),
                    reason=f"ManipNet mug1 capture not found under {MANIPNET} (set TORCHHAND_SHARED_DATA)")
def test_import_manipnet(capsys, tmp_path):
    rc, out, err = run(capsys, "scene", "import-mocap", "--manipnet", str(MANIPNET), "--frames", "1000:1240",
                       "--fps", "30", "--out", str(tmp_path / "mug"))
    assert rc == 0, err
    scene = load_scene(tmp_path / "mug")
    assert scene.sides == ("right", "left") and scene.fps == 30.0 and scene.T == 60
    assert scene.environment.table
