"""Blender as the client of :func:`torchhand.scene.bvh.write_bvh`: files written by torchhand are imported with Blender's
own BVH importer (``io_anim_bvh``, shipped in the ``bpy`` wheel) and the posed armature is compared with torchhand's
FK (``BVHClip.global_transforms``).

What Blender does with a BVH (``io_anim_bvh/import_bvh.py``, Blender 4.5): one bone per ROOT/JOINT, End Sites make
no bone but give the tail of their parent's bone; a position channel replaces the OFFSET (pose location
``channels - OFFSET``); the armature is rotated by ``axis_conversion(from_forward, from_up)`` and scaled by
``global_scale``; BVH frame ``f`` (0-based) is Blender frame ``1 + f`` with ``use_fps_scale=False``.

Needs ``bpy`` (the optional extra ``torchhand[blender]``); skipped without it.
"""

from __future__ import annotations

import numpy as np
import pytest

from torchhand.scene.bvh import read_bvh, write_bvh

from tests.conftest import shared_data_dir

pytestmark = pytest.mark.blender

MOCAP = shared_data_dir() / "mocap"
# file, a few bones to name explicitly (wrists, a fingertip's parent, the root)
CLIPS = {
    "cmu": (MOCAP / "cmu_body_frozen_hands" / "01-01_v01.bvh", ("pelvis", "hand_L", "hand_R", "index03_R")),
    "mixamo": (MOCAP / "bvh_python_tests" / "test_freebvh.bvh",
               ("mixamorig:Hips", "mixamorig:LeftHand", "mixamorig:RightHand", "mixamorig:RightHandIndex3")),
}
# the importer's default axes: the file's -Z forward becomes Blender's +Y, the file's Y up becomes Blender's Z
AXES = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
TOL = 1e-4                                   # file units (Blender poses in float32)


def import_with_blender(bpy, path):
    """Import ``path`` into an empty Blender scene; returns the armature object."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    result = bpy.ops.import_anim.bvh(filepath=str(path), rotate_mode="NATIVE", axis_forward="-Z", axis_up="Y",
                                     global_scale=1.0, update_scene_fps=True, use_fps_scale=False)
    assert result == {"FINISHED"}
    armatures = [ob for ob in bpy.context.scene.objects if ob.type == "ARMATURE"]
    assert len(armatures) == 1
    return armatures[0]


@pytest.mark.parametrize("rig", sorted(CLIPS))
def test_blender_imports_written_bvh(bpy, tmp_path, rig):
    path, named = CLIPS[rig]
    if not path.is_file():
        pytest.skip(f"reference data not found: {path} (set TORCHHAND_SHARED_DATA)")
    from bpy_extras.io_utils import axis_conversion

    np.testing.assert_allclose(np.array(axis_conversion(from_forward="-Z", from_up="Y")), AXES, atol=1e-12)

    clip = read_bvh(path)
    written = write_bvh(clip, tmp_path / path.name)
    arm = import_with_blender(bpy, written)
    scene = bpy.context.scene

    # one bone per joint; End Sites make none
    joints = [n for n, end in zip(clip.names, clip.is_end_site) if not end]
    assert len(arm.data.bones) == len(joints)
    assert sorted(b.name for b in arm.data.bones) == sorted(joints)
    for j, name in enumerate(clip.names):                      # NATIVE: each bone keeps its channel order
        rot = "".join(c[0] for c in clip.channels[j] if c.endswith("rotation"))
        if len(rot) == 3:
            assert arm.pose.bones[name].rotation_mode == rot
    # frames and rate
    action = arm.animation_data.action
    assert tuple(action.frame_range) == (1.0, float(clip.num_frames))
    assert {len(fc.keyframe_points) for fc in action.fcurves} == {clip.num_frames}
    assert scene.render.fps / scene.render.fps_base == pytest.approx(clip.fps, rel=1e-5)

    # world head positions against torchhand's FK, in Blender's axes; End Sites longer than Blender's
    # zero-length limit (0.001 file units) are the tails of their parents' bones
    assert set(named) <= set(joints)
    tails = [j for j in range(clip.num_joints)
             if clip.is_end_site[j] and np.linalg.norm(clip.offsets[j]) > 0.001]
    frames = [0, clip.num_frames // 2, clip.num_frames - 1]
    G = clip.global_transforms(frames).numpy()
    world = np.array(arm.matrix_world)
    for k, f in enumerate(frames):
        scene.frame_set(1 + f)
        expected = G[k, :, :3, 3] @ AXES.T
        heads = {n: world[:3, :3] @ np.array(arm.pose.bones[n].head) + world[:3, 3] for n in joints}
        for name in named:
            np.testing.assert_allclose(heads[name], expected[clip.joint_index(name)], rtol=0, atol=TOL,
                                       err_msg=f"{rig} {name} frame {f}")
        got = np.stack([heads[n] for n in joints])
        np.testing.assert_allclose(got, expected[[clip.joint_index(n) for n in joints]], rtol=0, atol=TOL,
                                   err_msg=f"{rig} heads, frame {f}")
        tail = np.stack([world[:3, :3] @ np.array(arm.pose.bones[clip.names[clip.parents[j]]].tail) + world[:3, 3]
                         for j in tails])
        np.testing.assert_allclose(tail, expected[tails], rtol=0, atol=TOL, err_msg=f"{rig} End Sites, frame {f}")


def test_blender_imports_a_spliced_file(bpy, tmp_path):
    """``torchhand splice``'s output (a finger-less body given Leap fingers under its wrist) opens in Blender with
    one bone per joint, every frame, and the wrist and finger joints where torchhand's FK puts them."""
    from torchhand.cli import main

    body, hand = MOCAP / "bvh_python_tests" / "test_mocapbank.bvh", MOCAP / "leap_hand_bvh" / "hello-world.bvh"
    for p in (body, hand):
        if not p.is_file():
            pytest.skip(f"reference data not found: {p} (set TORCHHAND_SHARED_DATA)")
    out = tmp_path / "out"
    assert main(["splice", "--body", str(body), "--hand", str(hand), "--out", str(out), "--no-progress"]) == 0
    clip = read_bvh(out / "spliced.bvh")
    arm = import_with_blender(bpy, out / "spliced.bvh")
    joints = [n for n, end in zip(clip.names, clip.is_end_site) if not end]
    assert sorted(b.name for b in arm.data.bones) == sorted(joints)
    assert tuple(arm.animation_data.action.frame_range) == (1.0, float(clip.num_frames))
    fingers = [n for n in joints if n.startswith("r") and n[1:2].isupper()]       # Leap's rThumb1 .. rPinky3
    assert len(fingers) >= 15
    named = ["RightWrist"] + fingers
    frames = [0, clip.num_frames // 2, clip.num_frames - 1]
    G = clip.global_transforms(frames).numpy()
    world = np.array(arm.matrix_world)
    for k, f in enumerate(frames):
        bpy.context.scene.frame_set(1 + f)
        expected = G[k, :, :3, 3] @ AXES.T
        for name in named:
            head = world[:3, :3] @ np.array(arm.pose.bones[name].head) + world[:3, 3]
            np.testing.assert_allclose(head, expected[clip.joint_index(name)], rtol=0, atol=TOL,
                                       err_msg=f"{name} frame {f}")
