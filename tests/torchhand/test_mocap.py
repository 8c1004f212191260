"""Motion-capture import: conversions and hand-frame rules on synthetic BVHs, and the shared ManipNet capture."""

from __future__ import annotations


import numpy as np
import pytest
import torch
import trimesh

from torchhand.scene.bvh import read_bvh
from torchhand.errors import FileFormatError, InputValueError, ShapeError, UnknownNameError
from torchhand.scene.mocap import convert_transforms, hand_frame_rotation, import_mocap_scene, manipnet_scene
from torchhand.scene import environment_contacts

from tests.conftest import shared_data_dir as shared_data


MANIPNET = shared_data() / "mocap" / "manipnet" / "mug1"
MOCAP = shared_data() / "mocap"
needs_manipnet = pytest.mark.skipif(not (MANIPNET / "rightHand.bvh").is_file(),
                                    reason=f"ManipNet mug1 capture not found under {MANIPNET} "
                                           "(set TORCHHAND_SHARED_DATA)")

# a right hand in torchhand's own hand-frame geometry (metres, z-up, right-handed): R_fix must be the identity
FINGERS = {"thumb": (0.025, 0.022, -0.012), "index": (0.085, 0.024, 0.0), "middle": (0.085, 0.0, 0.0),
           "ring": (0.085, -0.020, 0.0), "pinky": (0.085, -0.038, 0.0)}


def hand_bvh_text(frames: np.ndarray, mirror_y: bool = False, frame_time: float = 0.01) -> str:
    s = -1.0 if mirror_y else 1.0
    lines = ["HIERARCHY", "ROOT wrist", "{", "  OFFSET 0 0 0",
             "  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation"]
    for name, (x, y, z) in FINGERS.items():
        lines += [f"  JOINT {name}1", "  {", f"    OFFSET {x} {s * y} {z}",
                  "    CHANNELS 3 Zrotation Xrotation Yrotation",
                  f"    JOINT {name}2", "    {", "      OFFSET 0.05 0 0",
                  "      CHANNELS 3 Zrotation Xrotation Yrotation",
                  "      End Site", "      {", "        OFFSET 0.04 0 0", "      }", "    }", "  }"]
    lines += ["}", "MOTION", f"Frames: {len(frames)}", f"Frame Time: {frame_time}"]
    lines += [" ".join(f"{v:.9f}" for v in row) for row in frames]
    return "\n".join(lines) + "\n"


def hand_motion(F: int, seed: int = 0) -> np.ndarray:
    g = torch.Generator().manual_seed(seed)
    m = torch.zeros(F, 6 + 6 * 5, dtype=torch.float64)
    t = torch.linspace(0, 1, F, dtype=torch.float64)
    m[:, 0:3] = torch.stack([0.1 + 0.2 * t, -0.05 * t, 0.3 + 0.1 * t], -1)
    m[:, 3:6] = torch.stack([40 * t, -20 * t, 10 * t], -1) + torch.rand(3, generator=g, dtype=torch.float64) * 5
    m[:, 6:] = 30 * torch.rand(F, 30, generator=g, dtype=torch.float64)  # finger motion
    return m.numpy()


@pytest.fixture
def synthetic(tmp_path):
    F = 12
    motion = hand_motion(F)
    (tmp_path / "right.bvh").write_text(hand_bvh_text(motion))
    (tmp_path / "left.bvh").write_text(hand_bvh_text(hand_motion(F, seed=1), mirror_y=True))
    pose = np.tile(np.eye(4), (F, 1, 1))
    pose[:, :3, 3] = [[0.2 + 0.01 * k, 0.0, 0.3] for k in range(F)]
    np.savez(tmp_path / "object.npz", object_pose=pose)
    trimesh.creation.box(extents=(0.06, 0.06, 0.06)).export(tmp_path / "box.obj")
    return tmp_path


def test_identity_mapping_for_a_hand_in_our_frame(synthetic):
    clip = read_bvh(synthetic / "right.bvh")
    R, length, rule = hand_frame_rotation(clip, 0, "right", up_axis="z")
    assert rule == "fingers"
    np.testing.assert_allclose(R, np.eye(3), atol=1e-12)
    assert length == pytest.approx(np.hypot(0.085 + 0.09, 0.0))
    scene = import_mocap_scene(hand_bvh=synthetic / "right.bvh", object_npz=synthetic / "object.npz",
                               object_mesh=synthetic / "box.obj", up_axis="z", mass=0.2)
    G = clip.global_transforms()[:, 0]
    torch.testing.assert_close(scene.hands[0].wrist_pose, G, atol=1e-12, rtol=0)
    assert scene.sides == ("right",) and scene.fps == 100.0 and scene.T == 12
    assert scene.hands[0].length == pytest.approx(0.175)
    assert scene.object.mass == pytest.approx(0.2)
    assert not scene.environment.table


def test_left_hand_mapping(synthetic):
    clip = read_bvh(synthetic / "left.bvh")
    R, _, _ = hand_frame_rotation(clip, 0, "left", up_axis="z")
    np.testing.assert_allclose(R, np.eye(3), atol=1e-12)  # thumb side is -y for a left hand
    R_wrong, _, _ = hand_frame_rotation(clip, 0, "right", up_axis="z")
    np.testing.assert_allclose(R_wrong, np.diag([1.0, -1.0, -1.0]), atol=1e-12)


def test_two_hands_units_up_axis_and_resampling(synthetic):
    scene = import_mocap_scene(hand_bvh={"right": synthetic / "right.bvh", "left": synthetic / "left.bvh"},
                               object_npz=synthetic / "object.npz", object_mesh=synthetic / "box.obj",
                               units_scale=0.5, mesh_scale=1.0, up_axis="y", frame_range=(2, 12), fps=50.0,
                               table_height="auto", name="synthetic")
    assert scene.sides == ("right", "left") and scene.name == "synthetic"
    assert scene.fps == 50.0 and scene.T == 5  # 10 frames at 100 Hz -> 0.09 s -> 5 frames at 50 Hz
    G = read_bvh(synthetic / "right.bvh").global_transforms()[2:12:2, 0]
    C = torch.tensor([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]], dtype=torch.float64)
    expected = G.clone()
    expected[:, :3, 3] *= 0.5
    torch.testing.assert_close(scene.hands[0].wrist_pose, C @ expected, atol=1e-12, rtol=0)
    # y-up source: the object's source y (0) becomes world z, its source z (0.3) becomes world -y
    torch.testing.assert_close(scene.object_pose[0, :3, 3],
                               torch.tensor([0.5 * 0.22, -0.5 * 0.3, 0.0], dtype=torch.float64))
    assert scene.environment.table
    assert scene.environment.table_height == pytest.approx(-0.03)  # the box's lowest point
    assert int(environment_contacts(scene).count[0]) == 4


def test_convert_transforms():
    G = torch.eye(4, dtype=torch.float64).repeat(2, 1, 1)
    G[0, :3, 3] = torch.tensor([1.0, 2.0, 3.0])
    G[1, :3, :3] = torch.tensor([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])  # 90 deg about z
    y_up = convert_transforms(G, units_scale=0.1, up_axis="y")
    torch.testing.assert_close(y_up[0, :3, 3], torch.tensor([0.1, -0.3, 0.2], dtype=torch.float64))
    mirrored = convert_transforms(G, up_axis="z", handedness="left")
    torch.testing.assert_close(mirrored[0, :3, 3], torch.tensor([-1.0, 2.0, 3.0], dtype=torch.float64))
    assert torch.allclose(torch.linalg.det(mirrored[:, :3, :3]), torch.ones(2, dtype=torch.float64))
    torch.testing.assert_close(mirrored[1, :3, :3], G[1, :3, :3].T)  # a mirrored rotation turns the other way
    with pytest.raises(InputValueError):
        convert_transforms(G, up_axis="x")


def test_fallback_rule_for_body_wrists(tmp_path):
    def body(arm_dir):
        return "\n".join([
            "HIERARCHY", "ROOT Hips", "{", "OFFSET 0 0 0", "CHANNELS 6 Xposition Yposition Zposition Zrotation "
            "Xrotation Yrotation", "JOINT RightArm", "{", "OFFSET -0.2 0 0", "CHANNELS 3 Zrotation Xrotation Yrotation",
            "JOINT RightWrist", "{", f"OFFSET {0.25 * arm_dir[0]} {0.25 * arm_dir[1]} 0",
            "CHANNELS 3 Zrotation Xrotation Yrotation", "End Site", "{",
            f"OFFSET {0.08 * arm_dir[0]} {0.08 * arm_dir[1]} 0", "}", "}", "}", "}",
            "MOTION", "Frames: 1", "Frame Time: 0.04", " ".join(["0"] * 12), ""])

    (tmp_path / "tpose.bvh").write_text(body((-1, 0)))
    clip = read_bvh(tmp_path / "tpose.bvh")
    R, length, rule = hand_frame_rotation(clip, clip.joint_index("RightWrist"), "right", up_axis="y")
    assert rule == "fallback" and length is None
    np.testing.assert_allclose(R, np.array([[-1.0, 0, 0], [0, 0, 1], [0, 1, 0]]).T, atol=1e-12)  # palm down
    (tmp_path / "hanging.bvh").write_text(body((0, -1)))
    clip = read_bvh(tmp_path / "hanging.bvh")
    R, _, _ = hand_frame_rotation(clip, clip.joint_index("RightWrist"), "right", up_axis="y")
    np.testing.assert_allclose(R[:, 0], [0, -1, 0], atol=1e-12)   # fingers down
    np.testing.assert_allclose(R[:, 2], [-1, 0, 0], atol=1e-12)   # back of the hand outward, palm to the thigh
    np.testing.assert_allclose(R[:, 1], [0, 0, 1], atol=1e-12)    # thumb forward


def test_import_errors(synthetic, tmp_path):
    common = dict(object_npz=synthetic / "object.npz", object_mesh=synthetic / "box.obj")
    with pytest.raises(InputValueError, match="exactly one"):
        import_mocap_scene(**common)
    with pytest.raises(InputValueError, match="exactly one"):
        import_mocap_scene(hand_bvh=synthetic / "right.bvh", object_mesh=synthetic / "box.obj")
    with pytest.raises(InputValueError, match="wrist_joint"):
        import_mocap_scene(body_bvh=synthetic / "right.bvh", **common)
    with pytest.raises(UnknownNameError, match="middle1"):
        import_mocap_scene(body_bvh=synthetic / "right.bvh", wrist_joint="Wrist", **common)
    with pytest.raises(InputValueError, match="frame_range"):
        import_mocap_scene(hand_bvh=synthetic / "right.bvh", frame_range=(5, 50), **common)
    with pytest.raises(InputValueError, match="side"):
        import_mocap_scene(hand_bvh=synthetic / "right.bvh", side="middle", **common)
    (tmp_path / "short.bvh").write_text(hand_bvh_text(hand_motion(5)))
    with pytest.raises(ShapeError, match="5 frames"):
        import_mocap_scene(hand_bvh=tmp_path / "short.bvh", **common)
    (tmp_path / "bad.bvh").write_text(hand_bvh_text(hand_motion(12)).replace("Frames: 12", "Frames: 3"))
    with pytest.raises(FileFormatError, match="bad.bvh"):
        import_mocap_scene(hand_bvh=tmp_path / "bad.bvh", **common)
    np.savez(tmp_path / "nopose.npz", something=np.zeros(3))
    with pytest.raises(FileFormatError, match="object_pose"):
        import_mocap_scene(hand_bvh=synthetic / "right.bvh", object_npz=tmp_path / "nopose.npz",
                           object_mesh=synthetic / "box.obj")


# ---------------------------------------------------------------------------------------------------------------
# shared reference data


@pytest.mark.skipif(not (MOCAP / "bvh_python_tests" / "test_freebvh.bvh").is_file(), reason="Mixamo BVH absent")
def test_mixamo_finger_rule_palms_down():
    clip = read_bvh(MOCAP / "bvh_python_tests" / "test_freebvh.bvh")
    for side, joint, x_sign in (("right", "mixamorig:RightHand", -1), ("left", "mixamorig:LeftHand", 1)):
        R, length, rule = hand_frame_rotation(clip, clip.joint_index(joint), side, up_axis="y")
        assert rule == "fingers"
        assert R[0, 0] * x_sign > 0.95        # fingers along the arm in the T-pose
        assert R[1, 2] > 0.95                 # back of the hand up: palms down
        assert 10 < length < 30               # centimetres


@pytest.mark.skipif(not (MOCAP / "bvh_python_tests" / "test_mocapbank.bvh").is_file(), reason="mocapbank absent")
def test_body_bvh_without_fingers(tmp_path):
    path = MOCAP / "bvh_python_tests" / "test_mocapbank.bvh"
    F = read_bvh(path).num_frames
    pose = np.tile(np.eye(4), (F, 1, 1))
    pose[:, :3, 3] = [0.0, 100.0, 30.0]
    np.savez(tmp_path / "obj.npz", object_pose=pose)
    trimesh.creation.box(extents=(6.0, 6.0, 6.0)).export(tmp_path / "box.obj")
    scene = import_mocap_scene(body_bvh=path, wrist_joint={"right": "RightWrist", "left": "LeftWrist"},
                               object_npz=tmp_path / "obj.npz", object_mesh=tmp_path / "box.obj",
                               units_scale=0.01, frame_range=(0, 60), fps=30.0)
    assert scene.sides == ("right", "left") and scene.T == 60
    assert all(h.length == 0.19 for h in scene.hands)
    assert scene.object.mesh.extents.max() == pytest.approx(0.06)


@pytest.fixture(scope="module")
def mug_scene():
    return manipnet_scene(MANIPNET, frame_range=(0, 4000), fps=30.0)


@needs_manipnet
def test_manipnet_mug_scene(mug_scene):
    s = mug_scene
    assert s.sides == ("right", "left") and s.fps == 30.0 and s.T == 1000
    size = float(np.max(s.object.mesh.extents))
    assert 0.08 <= size <= 0.15, f"mug size {size} m"
    assert s.object.watertight
    for h in s.hands:
        assert 0.15 < h.length < 0.22
    # held = lifted off the table; both wrists stay within 0.4 m of the mug while it is held
    V = torch.as_tensor(np.asarray(s.object.mesh.convex_hull.vertices))
    low = (torch.einsum("tj,nj->tn", s.object_pose[:, 2, :3], V) + s.object_pose[:, 2, 3, None]).amin(-1)
    held = low > s.environment.table_height + 0.01
    assert 0.2 < float(held.double().mean()) < 0.8
    query = trimesh.proximity.ProximityQuery(s.object.mesh)
    for h in s.hands:
        rel = torch.linalg.inv(s.object_pose[held]) @ h.wrist_pose[held]
        dist = -query.signed_distance(rel[:, :3, 3].numpy())
        assert dist.max() < 0.4 and dist.min() > 0.0
    # the right hand holds it: the mug lies on the palm side (-z) in front of the wrist (+x)
    right = s.hand("right")
    c = torch.tensor(np.array(s.object.mesh.centroid))
    inv = torch.linalg.inv(right.wrist_pose[held]) @ s.object_pose[held]
    centre = (inv[:, :3, :3] @ c + inv[:, :3, 3]).median(dim=0).values
    assert centre[0] > 0.05 and centre[2] < 0.0
    # at rest the mug stands on the (auto) table
    assert abs(float(low[0]) - s.environment.table_height) < 0.01


@needs_manipnet
@pytest.mark.parametrize("side", ["right", "left"])
def test_manipnet_hand_frame_matches_anatomy(side):
    """Fingertips flex toward the palm (-z), lie ahead of the wrist (+x), the thumb is on the +y side of a right
    hand and the -y side of a left hand: checks the mirror of the left-handed source and the fixed rotation."""
    clip = read_bvh(MANIPNET / f"{side}Hand.bvh")
    R, _, _ = hand_frame_rotation(clip, 0, side, handedness="left")
    fix = torch.eye(4, dtype=torch.float64)
    fix[:3, :3] = torch.as_tensor(R)
    G = convert_transforms(clip.global_transforms(slice(0, 4000, 40)), units_scale=0.1, handedness="left")
    hand = G[:, 0] @ fix
    local = torch.linalg.inv(hand)[:, None] @ G  # every joint in the hand frame
    tips = [clip.names.index(n) for n in clip.names if n.endswith("_DIP_FE_end")]
    p = local[:, tips, :3, 3]
    assert float(p[..., 0].median()) > 0.1
    assert float(p[..., 2].median()) < -0.01
    thumb = local[:, clip.names.index("THUMB_IP_FE_end"), :3, 3]
    sign = 1.0 if side == "right" else -1.0
    assert float((sign * thumb[:, 1]).median()) > 0.02


@needs_manipnet
def test_manipnet_native_rate_and_one_hand():
    s = manipnet_scene(MANIPNET, frame_range=(600, 840), hands=("left",))
    assert s.fps == 120.0 and s.T == 240 and s.sides == ("left",)
    s.validate()
