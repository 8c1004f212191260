"""Blender as the client of ``torchhand export``'s BVH files: a solution's hand and a body with the solution's
fingers, imported with Blender's own BVH importer (``io_anim_bvh``). Fingertips are the tails of the distal bones
(an End Site gives its parent bone's tail); Blender frame ``1 + f`` is BVH frame ``f``.

With ``global_scale = 0.01`` and the importer's y-up axes, Blender's world of an exported hand (centimetres,
y-up) is torchhand's world in metres: ``(x, y, z) -> (x, z, -y) -> (x, y, z)``. The glb export's Blender test is
in test_export_gltf.py. Needs ``bpy`` (``torchhand[blender]``); skipped without it.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torchhand.scene.bvh import read_bvh
from torchhand.cli import main
from torchhand.scene.mocap import convert_transforms
from torchhand.io.result import load_result

from tests.render.fixture_result import write_fixture_result

from .export_fixtures import BODIES, FIRST, body_result
from .test_export import fingertips_world

pytestmark = pytest.mark.blender


def import_bvh(bpy, path, *, scale: float, up: str):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    forward = "-Z" if up == "y" else "Y"
    result = bpy.ops.import_anim.bvh(filepath=str(path), rotate_mode="NATIVE", axis_forward=forward,
                                     axis_up=up.upper(), global_scale=scale, update_scene_fps=True,
                                     use_fps_scale=False)
    assert result == {"FINISHED"}
    arms = [ob for ob in bpy.context.scene.objects if ob.type == "ARMATURE"]
    assert len(arms) == 1
    return arms[0]


def bone_tails(arm, names):
    world = np.array(arm.matrix_world)
    return np.stack([world[:3, :3] @ np.array(arm.pose.bones[n].tail) + world[:3, 3] for n in names])


def test_blender_reads_an_exported_hand(bpy, tmp_path):
    res_dir = write_fixture_result(tmp_path / "r", "box-turn", frames=12, solutions=1, q_ramp=0.7)
    out = tmp_path / "out"
    assert main(["export", str(res_dir), "--out", str(out), "--format", "bvh", "--no-progress"]) == 0
    res = load_result(res_dir)
    sol, model = res.solution(0), res.hand_models["right"]
    arm = import_bvh(bpy, out / "sol_000.bvh", scale=0.01, up="y")
    assert sorted(b.name for b in arm.data.bones) == sorted(model.link_names)     # one bone per link
    assert tuple(arm.animation_data.action.frame_range) == (1.0, float(sol.T))
    scene = bpy.context.scene
    assert scene.render.fps / scene.render.fps_base == pytest.approx(sol.fps, rel=1e-5)
    want = fingertips_world(model, sol.q, sol.root_pose)
    distal = [model.link_names[d] for d in model.distal_link.tolist()]
    for f in (0, sol.T // 2, sol.T - 1):
        scene.frame_set(1 + f)
        got = bone_tails(arm, distal)
        err = np.linalg.norm(got - want[f], axis=-1).max()
        assert err < 1e-3, f"frame {f}: fingertips {1000 * err:.3f} mm from torchhand's FK"
        wrist = np.array(arm.matrix_world) @ np.append(np.array(arm.pose.bones[model.link_names[0]].head), 1.0)
        m64 = model.to(dtype=torch.float64)
        palm = m64.forward_kinematics(torch.as_tensor(sol.q[f:f + 1]), torch.as_tensor(sol.root_pose[f:f + 1]))
        palm = palm[0, 0].numpy()
        assert np.linalg.norm(wrist[:3] - palm[:3, 3]) < 1e-3


@pytest.mark.parametrize("body", sorted(BODIES))
def test_blender_reads_a_body_with_fingers(bpy, tmp_path, body):
    result, body_path = body_result(tmp_path, body)
    out = tmp_path / "out"
    assert main(["export", str(result), "--out", str(out), "--onto", str(body_path), "--no-progress"]) == 0
    _, _, units, up = BODIES[body]
    clip = read_bvh(out / "body_with_fingers.bvh")
    arm = import_bvh(bpy, out / "body_with_fingers.bvh", scale=1.0, up=up)
    joints = [n for n, e in zip(clip.names, clip.is_end_site) if not e]
    assert sorted(b.name for b in arm.data.bones) == sorted(joints)
    assert tuple(arm.animation_data.action.frame_range) == (1.0, float(clip.num_frames))
    res = load_result(result)
    sol, model = res.solution(0), res.hand_models["right"]
    want = fingertips_world(model, sol.q, sol.root_pose)
    from torchhand.splice.rigs import detect_rig

    tips = detect_rig(clip).tips["right"]
    last = [clip.names[clip.parents[tips[f]]] for f in ("thumb", "index", "middle", "ring", "pinky")]
    # Blender's world is the file's axes turned z-up; torchhand's world is the file converted by the scene import
    to_file = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]]) if up == "y" else np.eye(3)
    for k in (8, sol.T // 2, sol.T - 9):                   # outside the 0.2 s blends
        bpy.context.scene.frame_set(1 + FIRST + k)
        file_pts = bone_tails(arm, last) @ to_file.T if up == "y" else bone_tails(arm, last)
        G = np.tile(np.eye(4), (len(last), 1, 1))
        G[:, :3, 3] = file_pts
        got = convert_transforms(torch.as_tensor(G), units_scale=units, up_axis=up).numpy()[:, :3, 3]
        err = np.linalg.norm(got - want[k], axis=-1).max()
        assert err < 0.005, f"{body} frame {FIRST + k}: fingertips {1000 * err:.2f} mm from the solution's"
