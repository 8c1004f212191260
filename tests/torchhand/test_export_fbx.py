"""``torchhand export --format fbx``: the job handed to Blender checked against torchhand's FK (no Blender needed),
how Blender is found and what happens without one (no Blender needed: a stand-in executable plays it), and the
written FBX read back by Blender's own importer (``io_scene_fbx``): fingertips, link origins and the object within
1 mm of the result's FK at the first, middle and last frames, the frame rate and range, metres and z-up; the body
with fingers likewise. The Blender tests need ``bpy`` (``torchhand[blender]``) and are skipped without it.
"""

from __future__ import annotations

import json
import os
import stat
import sys
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from torchhand.cli import main
from torchhand.errors import MissingDependencyError
from torchhand.export import fbx
from torchhand.export.fbx import BlenderError, BlenderRunner, armature_spec, find_blender, frame_rate, write_fbx
from torchhand.export.skeleton import hand_skeleton
from torchhand.io.result import load_result
from torchhand.scene.bvh import read_bvh

from tests.render.fixture_result import write_fixture_result

from .export_fixtures import BODIES, FIRST, body_result
from .test_export import fingertips_world

TOL_M = 1e-3


@pytest.fixture(scope="module")
def box_result(tmp_path_factory):
    return write_fixture_result(tmp_path_factory.mktemp("fbx") / "box-turn", "box-turn", frames=12, solutions=2,
                                q_ramp=0.7)


def link_poses(model, q, root):
    m = model.to(dtype=torch.float64)
    return m.forward_kinematics(torch.as_tensor(q), torch.as_tensor(root)).numpy()


# ---------------------------------------------------------------------------------------------------------------
# the job handed to Blender (no Blender needed)


def test_job_matches_fk(box_result):
    res = load_result(box_result)
    sol, model = res.solution(1), res.hand_models["right"]
    job = fbx.solution_fbx_scene(res, 1)
    assert job.fps == sol.fps and job.frames == sol.T == 12
    (arm,) = job.armatures
    skel = hand_skeleton(model)
    assert arm.name == "right_hand" and arm.bones == skel.names and arm.parents == skel.parents
    J = len(skel.names)
    assert arm.pose.shape == (12, J, 4, 4) and arm.rest.shape == (J, 4, 4) and arm.length.shape == (J,)
    L = link_poses(model, sol.q, sol.root_pose)
    np.testing.assert_allclose(arm.pose[:, : model.num_links, :3, 3], L[..., :3, 3], atol=1e-12)
    np.testing.assert_allclose(arm.pose[:, skel.tip_joint][..., :3, 3], fingertips_world(model, sol.q, sol.root_pose),
                               atol=1e-12)
    # bone = frame @ offset, offset a fixed rotation; rest bones have orthonormal axes, Y along the bone
    np.testing.assert_allclose(arm.pose[:, : model.num_links], L @ arm.offset[: model.num_links], atol=1e-12)
    R = arm.rest[:, :3, :3]
    np.testing.assert_allclose(R.transpose(0, 2, 1) @ R, np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    assert np.allclose(np.linalg.det(R), 1.0) and (arm.length >= 0.002).all()
    mcp = skel.names.index("index_metacarpal")
    child = arm.rest[skel.names.index("index_proximal"), :3, 3] - arm.rest[mcp, :3, 3]
    np.testing.assert_allclose(R[mcp, :, 1], child / np.linalg.norm(child), atol=1e-12)
    (obj,) = job.meshes
    assert obj.name == "object" and obj.vertices.shape[1] == 3 and obj.faces.shape[1] == 3
    np.testing.assert_array_equal(obj.pose, sol.object_pose)
    data = json.loads(json.dumps(job.to_json()))                     # what the Blender-side script reads
    assert data["format"] == "torchhand-fbx" and data["version"] == 1 and data["frames"] == 12
    a = data["armatures"][0]
    assert a["bones"] == list(skel.names) and a["parents"] == list(skel.parents)
    assert np.array(a["pose"]).shape == (12, J, 16) and np.array(a["rest"]).shape == (J, 16)
    np.testing.assert_array_equal(np.array(a["pose"]).reshape(12, J, 4, 4), arm.pose)        # exact floats
    assert np.array(data["meshes"][0]["vertices"]).shape == obj.vertices.shape


def test_job_two_hands(tmp_path):
    res = load_result(write_fixture_result(tmp_path / "two", "two-hand-box", frames=4, solutions=1))
    job = fbx.solution_fbx_scene(res, 0)
    sol = res.solution(0)
    assert [a.name for a in job.armatures] == [f"{h.side}_hand" for h in sol.hands]
    for arm, hand in zip(job.armatures, sol.hands):
        model = res.hand_models[hand.side]
        tips = [arm.bones.index(f"{model.link_names[d]}_end") for d in model.distal_link.tolist()]
        np.testing.assert_allclose(arm.pose[:, tips][..., :3, 3], fingertips_world(model, hand.q, hand.root_pose),
                                   atol=1e-12)


_BVH = """HIERARCHY
ROOT hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT hand
  {
    OFFSET 0 50 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 0 10
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.0333333
0 100 0 0 0 0 0 0 0
10 100 0 0 90 0 0 0 0
20 100 0 0 0 0 0 90 0
"""


def test_body_job_in_metres_z_up(tmp_path):
    """A y-up centimetre body: bones in torchhand's world (x, -z, y) / 100, the BVH frame time as 30 fps."""
    (tmp_path / "b.bvh").write_text(_BVH)
    clip = read_bvh(tmp_path / "b.bvh")
    source = SimpleNamespace(units_scale=0.01, up_axis="y", handedness="right")
    job = fbx.body_fbx_scene(clip, source)
    assert job.fps == 30.0 and job.frames == 3 and job.meshes == ()
    (arm,) = job.armatures
    assert arm.bones == clip.names and arm.parents == clip.parents
    heads = arm.pose[..., :3, 3]
    np.testing.assert_allclose(heads[0], [[0, 0, 1.0], [0, 0, 1.5], [0, -0.1, 1.5]], atol=1e-12)
    np.testing.assert_allclose(heads[1, 1], [0.1, -0.5, 1.0], atol=1e-12)     # hips turned 90 degrees about file x
    np.testing.assert_allclose(heads[2, 2], [0.2, 0, 1.4], atol=1e-12)        # hand turned 90 degrees about file x


def test_frame_rate_and_bad_armatures():
    assert frame_rate(30.00003) == 30.0 and frame_rate(29.97) == 29.97 and frame_rate(0.5) == 0.5
    with pytest.raises(ValueError, match="fps"):
        frame_rate(0.0)
    rest = np.tile(np.eye(4), (2, 1, 1))
    with pytest.raises(ValueError, match="parents precede"):
        armature_spec("a", ["x", "y"], [1, -1], rest[None], rest)
    with pytest.raises(ValueError, match="expected 2 parents"):
        armature_spec("a", ["x", "y"], [-1, 0], rest[None, :1], rest)


# ---------------------------------------------------------------------------------------------------------------
# finding Blender, and running it (a stand-in executable plays Blender)


def test_find_blender_order(tmp_path):
    exe = tmp_path / "blender"
    exe.write_text("#!/bin/sh\n")
    exe.chmod(exe.stat().st_mode | stat.S_IEXEC)
    none = lambda name: None                                                          # noqa: E731
    r = find_blender(env={"TORCHHAND_BLENDER": str(exe)}, which=none, in_process=True)
    assert r == BlenderRunner("blender", (str(exe),), "TORCHHAND_BLENDER")           # the variable comes first
    r = find_blender(env={"TORCHHAND_BLENDER": sys.executable}, which=none, in_process=False)
    assert r.kind == ("python" if "python" in os.path.basename(sys.executable) else "blender")
    assert find_blender(env={}, which=none, in_process=True).kind == "bpy"
    r = find_blender(env={}, which=lambda n: str(exe) if n == "blender" else None, in_process=False)
    assert r == BlenderRunner("blender", (str(exe),), "PATH")
    with pytest.raises(MissingDependencyError) as err:
        find_blender(env={}, which=none, in_process=False)
    msg = str(err.value)
    assert "pip install 'torchhand[blender]'" in msg and "TORCHHAND_BLENDER" in msg and "\n" not in msg
    with pytest.raises(MissingDependencyError, match="not an executable"):
        find_blender(env={"TORCHHAND_BLENDER": str(tmp_path / "nowhere")}, which=none)


def _stand_in(path, body: str):
    path.write_text("#!/bin/sh\n" + body)
    path.chmod(path.stat().st_mode | stat.S_IEXEC)
    return BlenderRunner("blender", (str(path),), "test")


def test_blender_subprocess_command_and_atomic_file(tmp_path):
    """Blender is called as ``blender --background --factory-startup ... --python SCRIPT -- JOB OUT``; its file is
    renamed into place; a failing Blender leaves the earlier file as it was and says why on one line."""
    log = tmp_path / "args.txt"
    ok = _stand_in(tmp_path / "blender", f'echo "$@" > {log}\nshift 7\necho FBX > "$2"\n')
    job = fbx.FbxScene(fps=30.0, frames=1)
    target = tmp_path / "out" / "a.fbx"
    assert write_fbx(job, target, blender=ok) == target and target.read_text() == "FBX\n"
    args = log.read_text().split()
    assert args[:6] == ["--background", "--factory-startup", "--python-exit-code", "1", "--python", str(fbx.SCRIPT)]
    assert args[6] == "--" and args[7].endswith("job.json") and args[8] != str(target)
    bad = _stand_in(tmp_path / "blender-bad", 'echo "Error: no scene" >&2\nexit 3\n')
    with pytest.raises(BlenderError, match="exit 3.*no scene") as err:
        write_fbx(job, target, blender=bad)
    assert "\n" not in str(err.value)
    assert target.read_text() == "FBX\n" and sorted(p.name for p in target.parent.iterdir()) == ["a.fbx"]


def test_cli_without_blender(box_result, tmp_path, capsys, monkeypatch):
    """No bpy, no TORCHHAND_BLENDER, no blender on PATH: exit 2, one line with the install line, nothing written,
    an earlier export left whole."""
    monkeypatch.setattr(fbx, "_bpy_imports", lambda: False)
    monkeypatch.delenv("TORCHHAND_BLENDER", raising=False)
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    out = tmp_path / "out"
    assert main(["export", str(box_result), "--out", str(out), "--format", "fbx", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "pip install 'torchhand[blender]'" in err and "TORCHHAND_BLENDER" in err and err.count("\n") == 1
    assert not out.exists()
    assert main(["export", str(box_result), "--out", str(out), "--format", "bvh", "--no-progress"]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert main(["export", str(box_result), "--out", str(out), "--format", "bvh,fbx", "--overwrite",
                 "--no-progress"]) == 2
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


# ---------------------------------------------------------------------------------------------------------------
# Blender reads the files back


def import_fbx(bpy, path):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assert bpy.ops.import_scene.fbx(filepath=str(path)) == {"FINISHED"}        # defaults: animation offset 1
    return bpy.context.scene


def heads(bpy, name, bones):
    arm = bpy.data.objects[name]
    M = np.array(arm.matrix_world)
    return np.stack([(M @ np.append(np.array(arm.pose.bones[b].head), 1.0))[:3] for b in bones])


def check_solution_fbx(bpy, path, res, index) -> dict:
    """Import ``path`` and compare it with solution ``index`` at the first, middle and last frames; returns the
    largest distances (metres) of fingertips, link origins and object vertices."""
    sol = res.solution(index)
    scene = import_fbx(bpy, path)
    assert scene.render.fps / scene.render.fps_base == pytest.approx(sol.fps, rel=1e-6)
    obj = bpy.data.objects["object"]
    assert obj.type == "MESH" and tuple(obj.animation_data.action.frame_range) == (1.0, float(sol.T))
    verts = np.array([v.co for v in obj.data.vertices], dtype=np.float64)
    mesh = res.scene.object.mesh
    worst = {"fingertips": 0.0, "links": 0.0, "object": 0.0}
    for hand in sol.hands:
        model, arm = res.hand_models[hand.side], bpy.data.objects[f"{hand.side}_hand"]
        assert arm.type == "ARMATURE" and tuple(arm.scale) == (1.0, 1.0, 1.0)
        assert sorted(b.name for b in arm.data.bones) == sorted(hand_skeleton(model).names)
        assert tuple(arm.animation_data.action.frame_range) == (1.0, float(sol.T))
        tips = [f"{model.link_names[d]}_end" for d in model.distal_link.tolist()]
        want_tips = fingertips_world(model, hand.q, hand.root_pose)
        want_links = link_poses(model, hand.q, hand.root_pose)[..., :3, 3]
        for f in (0, sol.T // 2, sol.T - 1):
            scene.frame_set(1 + f)
            worst["fingertips"] = max(worst["fingertips"], np.linalg.norm(heads(bpy, arm.name, tips) - want_tips[f],
                                                                          axis=-1).max())
            got = heads(bpy, arm.name, model.link_names)
            worst["links"] = max(worst["links"], np.linalg.norm(got - want_links[f], axis=-1).max())
            M = np.array(obj.matrix_world)
            want = np.asarray(mesh.vertices) @ sol.object_pose[f, :3, :3].T + sol.object_pose[f, :3, 3]
            got = verts[: len(want)] @ M[:3, :3].T + M[:3, 3]
            worst["object"] = max(worst["object"], np.linalg.norm(got - want, axis=-1).max())
    return worst


@pytest.mark.blender
def test_blender_reads_solution_fbx(bpy, box_result, tmp_path):
    out = tmp_path / "out"
    assert main(["export", str(box_result), "--out", str(out), "--format", "bvh,fbx", "--no-progress"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["export.json", "sol_000.bvh", "sol_000.fbx", "sol_001.bvh",
                                                     "sol_001.fbx"]
    res = load_result(box_result)
    for i in range(2):
        worst = check_solution_fbx(bpy, out / f"sol_{i:03d}.fbx", res, i)
        assert max(worst.values()) < TOL_M, f"solution {i}: {worst} metres"
    # --overwrite with bvh only removes the earlier fbx files
    assert main(["export", str(box_result), "--out", str(out), "--format", "bvh", "--overwrite",
                 "--no-progress"]) == 0
    assert not list(out.glob("*.fbx"))


@pytest.mark.blender
def test_blender_reads_two_hands_through_a_subprocess(bpy, tmp_path, monkeypatch):
    """Two hands and the object, written by a Blender subprocess (this interpreter, which has bpy)."""
    res_dir = write_fixture_result(tmp_path / "two", "two-hand-box", frames=6, solutions=1, q_ramp=0.6)
    monkeypatch.setenv("TORCHHAND_BLENDER", sys.executable)
    out = tmp_path / "out"
    assert main(["export", str(res_dir), "--out", str(out), "--format", "fbx", "--no-progress"]) == 0
    assert json.loads((out / "export.json").read_text())["fbx_blender"] == "TORCHHAND_BLENDER"
    worst = check_solution_fbx(bpy, out / "sol_000.fbx", load_result(res_dir), 0)
    assert {ob.name for ob in bpy.context.scene.objects} == {"object", "right_hand", "left_hand"}
    assert max(worst.values()) < TOL_M, worst


@pytest.mark.blender
@pytest.mark.parametrize("body", sorted(BODIES))
def test_blender_reads_body_with_fingers_fbx(bpy, tmp_path, body):
    """The body with the solution's fingers: every BVH joint a bone, animated over all the body's frames, bone heads
    within 1 mm of the written BVH's joints (in torchhand's world) and fingertips within 5 mm of the solution's
    outside the blends (as the BVH itself)."""
    from torchhand.scene.mocap import convert_transforms
    from torchhand.splice.rigs import detect_rig

    result, body_path = body_result(tmp_path, body)
    out = tmp_path / "out"
    assert main(["export", str(result), "--out", str(out), "--onto", str(body_path), "--format", "fbx",
                 "--no-progress"]) == 0
    assert {"body_with_fingers.bvh", "body_with_fingers.fbx", "sol_000.fbx"} <= {p.name for p in out.iterdir()}
    clip = read_bvh(out / "body_with_fingers.bvh")
    res = load_result(result)
    src, sol, model = res.scene.source, res.solution(0), res.hand_models["right"]
    scene = import_fbx(bpy, out / "body_with_fingers.fbx")
    arm = bpy.data.objects["body"]
    assert sorted(b.name for b in arm.data.bones) == sorted(clip.names)
    assert tuple(arm.animation_data.action.frame_range) == (1.0, float(clip.num_frames))
    assert scene.render.fps == round(clip.fps)
    fingers = detect_rig(clip).finger_joints("right")
    paths = {fc.data_path for fc in fbx_fcurves(arm)}
    assert all(f'pose.bones["{clip.names[j]}"].rotation_quaternion' in paths
               or f'pose.bones["{clip.names[j]}"].rotation_euler' in paths for j in fingers)
    G = convert_transforms(clip.global_transforms(), units_scale=src.units_scale, up_axis=src.up_axis,
                           handedness=src.handedness).numpy()
    tips = detect_rig(clip).tips["right"]
    tip_names = [clip.names[tips[f]] for f in ("thumb", "index", "middle", "ring", "pinky")]
    want_tips = fingertips_world(model, sol.q, sol.root_pose)
    for k in (8, sol.T // 2, sol.T - 9):                   # scene frames outside the 0.2 s blends
        f = FIRST + k
        scene.frame_set(1 + f)
        err = np.linalg.norm(heads(bpy, "body", clip.names) - G[f, :, :3, 3], axis=-1).max()
        assert err < TOL_M, f"{body} frame {f}: bones {1000 * err:.3f} mm from the BVH's joints"
        err = np.linalg.norm(heads(bpy, "body", tip_names) - want_tips[k], axis=-1).max()
        assert err < 0.005, f"{body} frame {f}: fingertips {1000 * err:.2f} mm from the solution's"


def fbx_fcurves(ob):
    """The F-curves of ``ob``'s action, as the Blender-side script reads them (needs bpy)."""
    from torchhand.export._blender_fbx import _fcurves
    return _fcurves(ob)


_CHECK_IN_BLENDER = """
import json, sys
import bpy
from torchhand.io.result import load_result
from tests.torchhand.test_export_fbx import check_solution_fbx
worst = check_solution_fbx(bpy, sys.argv[1], load_result(sys.argv[2]), int(sys.argv[3]))
print(json.dumps(worst))
"""


def test_fbx_through_the_numpy1_environments_blender(box_result, tmp_path, monkeypatch):
    """The main environment (NumPy 2, no bpy) writes FBX through the Blender of the NumPy 1 environment that
    scripts/setup.sh makes (TORCHHAND_BLENDER = its Python), and that Blender reads it back within 1 mm."""
    import subprocess
    from pathlib import Path
    repo = Path(__file__).resolve().parents[2]
    p1 = Path(os.environ.get("TORCHHAND_NUMPY1_ENV", repo / ".venv-numpy1")) / "bin" / "python"
    if not p1.is_file() or subprocess.run([str(p1), "-c", "import bpy"], capture_output=True).returncode:
        pytest.skip(f"no NumPy 1 environment with bpy at {p1.parent.parent} (scripts/setup.sh makes it)")
    monkeypatch.setenv("TORCHHAND_BLENDER", str(p1))
    monkeypatch.setattr(fbx, "_bpy_imports", lambda: False)            # as in an environment without bpy
    out = tmp_path / "out"
    assert main(["export", str(box_result), "--out", str(out), "--solutions", "1", "--format", "fbx",
                 "--no-progress"]) == 0
    run = subprocess.run([str(p1), "-c", _CHECK_IN_BLENDER, str(out / "sol_001.fbx"), str(box_result), "1"],
                         cwd=repo, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    worst = json.loads(run.stdout.strip().splitlines()[-1])
    assert max(worst.values()) < TOL_M, worst
