"""Every robot hand file under ../shared/data/hands (MJCF and URDF, as published) loads through MuJoCo's compiler:
forward kinematics equal to MuJoCo's body poses on 64 random poses to 1e-12 m, and the palm, fingers, thumb and side
found by topology, asserted per hand; MJCF ``<include>`` and an arm above the hand."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tests.conftest import shared_path
from torchhand.errors import FileFormatError, MissingFileError
from torchhand.hand import HandModel
from torchhand.hand._compile import compile_file
from torchhand.hand.mount import thumb_index
from torchhand.scene.builtin.ycb import arm_file as _arm_file

mujoco = pytest.importorskip("mujoco")

TOL = 1e-12  # metres and rotation-matrix entries
N_POSES = 64

# file under hands/, side, number of fingers, palm body, the thumb's links (proximal -> distal)
HANDS = {
    "shadow_right": ("shadow_hand/right_hand.xml", "right", 5, "rh_palm", "rh_thdistal"),
    "shadow_left": ("shadow_hand/left_hand.xml", "left", 5, "lh_palm", "lh_thdistal"),
    "allegro_right": ("allegro_hand/right_hand.xml", "right", 4, "palm", "th_tip"),
    "allegro_left": ("allegro_hand/left_hand.xml", "left", 4, "palm", "th_tip"),
    "leap_urdf": ("urdf/leap_hand/leap_hand_right.urdf", "right", 4, "palm_lower", "thumb_fingertip"),
    "allegro_urdf": ("urdf/allegro_hand/allegro_hand_right.urdf", "right", 4, "base_link", "link_15.0_tip"),
}


def _pose(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


@pytest.mark.parametrize("key", sorted(HANDS))
def test_fk_equals_mujoco_on_random_poses(key):
    path = shared_path("hands", HANDS[key][0])
    hand = HandModel.from_file(path)
    m = compile_file(path)
    d = mujoco.MjData(m)
    ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n) for n in hand.link_names]
    assert min(ids) >= 0
    jadr = [int(m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n)]) for n in hand.joint_names]
    q = hand.random_q(N_POSES, torch.Generator().manual_seed(7))
    worst = 0.0
    for b in range(N_POSES):
        d.qpos[:] = m.qpos0
        d.qpos[jadr] = q[b].numpy()
        mujoco.mj_kinematics(m, d)
        ref = np.stack([_pose(d.xmat[i].reshape(3, 3), d.xpos[i]) for i in ids])
        # the root input: the root body's world pose before its own joints (it has none in these files)
        ours = hand.forward_kinematics(q[b:b + 1], torch.as_tensor(ref[:1]))[0].numpy()
        worst = max(worst, float(np.abs(ours - ref).max()))
    assert worst <= TOL, f"{key}: FK differs from MuJoCo by {worst:.3g}"


@pytest.mark.parametrize("key", sorted(HANDS))
def test_fingers_thumb_side_by_topology(key):
    rel, side, n_fingers, palm, thumb_tip = HANDS[key]
    hand = HandModel.from_file(shared_path("hands", rel))
    assert hand.side == side
    assert hand.num_fingers == n_fingers
    th = thumb_index(hand)
    assert th is not None and hand.link_names[int(hand.distal_link[th])] == thumb_tip
    # every finger hangs from the palm; nothing from the palm up belongs to a finger
    parents = hand.chain.link_parent.tolist()
    p = hand.link_names.index(palm)
    for f in range(hand.num_fingers):
        a = int(hand.finger_links[f, 0])
        while a >= 0 and a != p:
            a = parents[a]
        assert a == p
    assert int(hand.link_finger[p]) == -1
    # three flexion joints on long fingers, at least two on the thumb
    flex = (hand.flexion_joints >= 0).sum(1).tolist()
    assert all(n == 3 for f, n in enumerate(flex) if f != th) and flex[th] >= 2
    assert 0.12 < hand.length < 0.25


def test_side_follows_the_geometry_not_the_name(tmp_path):
    """A right hand file renamed "left" is still found right: the side comes from the thumb's position."""
    src = shared_path("hands", "allegro_hand", "right_hand.xml")
    text = src.read_text().replace('meshdir="assets"', f'meshdir="{src.parent / "assets"}"')
    (tmp_path / "left_hand.xml").write_text(text.replace('model="allegro_right"', 'model="allegro_left"'))
    assert HandModel.from_file(tmp_path / "left_hand.xml").side == "right"


def test_include_and_an_arm_above_the_hand(tmp_path):
    """MJCF ``<include>`` (the shipped Shadow hand included by a file of our own) and a 6-joint arm above it: the
    arm's joints are not any finger's, slide limits stay in metres, FK still equals MuJoCo's."""
    hand_xml = shared_path("hands", "shadow_hand", "right_hand.xml")
    arm = _arm_file(tmp_path, hand_xml)
    hand = HandModel.from_file(arm)
    assert hand.link_names[0] == "arm_base"
    arm_joints = [n for n in hand.joint_names if n.startswith("arm_")]
    assert len(arm_joints) == 6
    for n in arm_joints:
        assert int(hand.link_finger[int(hand.chain.joint_link[hand.joint_index(n)])]) == -1
    lim = hand.joint_limits[hand.joint_index("arm_tx")].tolist()
    assert lim == pytest.approx([-0.3, 0.3])
    assert thumb_index(hand) is not None and hand.side == "right" and hand.num_fingers == 5


def test_grasp_from_qpos_on_an_arm_then_manipulate(tmp_path):
    """``grasp from-qpos`` on the arm-mounted Shadow hand, its qpos holding the arm's joints: the grasp puts the
    fingertips where the packaged liu-shadow-lift grasp does (the arm's motion goes into the wrist pose), and
    ``manipulate`` runs from it to a result that passes ``torchhand check``."""
    from scipy.spatial.transform import Rotation

    import torchhand
    from torchhand.cli import main
    from torchhand.manipulation import grasp_from_qpos, grasp_hand
    from torchhand.manipulation.grasp import load_packaged_grasp

    arm = _arm_file(tmp_path, shared_path("hands", "shadow_hand", "right_hand.xml"), reach=2.0)
    scene = torchhand.load_scene("liu-shadow-lift")
    g = load_packaged_grasp("liu-shadow-lift")
    hand = grasp_hand(g)
    T_wo = scene.object_pose[g.frame].double().numpy()
    W = T_wo @ g.wrist_in_object @ hand.chain.link_offset[0].double().numpy()  # the forearm body in the world
    m = compile_file(arm)
    fid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "rh_forearm")
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, m.body_quat[fid])
    A = W @ np.linalg.inv(_pose(R.reshape(3, 3), m.body_pos[fid]))  # the arm's last body in the world
    adr = {mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j): int(m.jnt_qposadr[j]) for j in range(m.njnt)}
    qpos = m.qpos0.copy()
    qpos[[adr["arm_tx"], adr["arm_ty"], adr["arm_tz"]]] = A[:3, 3]
    qpos[[adr["arm_rx"], adr["arm_ry"], adr["arm_rz"]]] = Rotation.from_matrix(A[:3, :3]).as_euler("XYZ")
    for n, v in zip(g.joint_names, g.q):
        qpos[adr[n]] = v
    gq = grasp_from_qpos(arm, qpos, scene, frame=g.frame)
    arm_hand = grasp_hand(gq)

    def tips(h, q, w):
        T = h.forward_kinematics(torch.as_tensor(q)[None], torch.as_tensor(w)[None])[0]
        return (T[h.distal_link, :3, :3] @ h.fingertip[:, :, None]).squeeze(-1) + T[h.distal_link, :3, 3]

    assert float((tips(hand, g.q, g.wrist_in_object) - tips(arm_hand, gq.q, gq.wrist_in_object)).abs().max()) < 1e-9
    np.save(tmp_path / "qpos.npy", qpos)
    assert main(["grasp", "from-qpos", str(arm), "--qpos", str(tmp_path / "qpos.npy"), "--scene", "liu-shadow-lift",
                 "--frame", str(g.frame), "--out", str(tmp_path / "g.npz")]) == 0
    assert main(["manipulate", "liu-shadow-lift", "--grasp", str(tmp_path / "g.npz"), "--out", str(tmp_path / "m"),
                 "--no-progress"]) == 0
    assert main(["check", str(tmp_path / "m")]) == 0


def test_bad_files_are_one_line(tmp_path):
    with pytest.raises(MissingFileError, match="not found"):
        HandModel.from_file(tmp_path / "none.urdf")
    bad = tmp_path / "bad.urdf"
    bad.write_text('<robot name="r"><link name="a"/><joint name="j" type="revolute"><parent link="a"/>'
                   '<child link="zz"/></joint></robot>')
    with pytest.raises(FileFormatError) as err:
        HandModel.from_file(bad)
    assert "MuJoCo cannot compile it" in str(err.value) and "\n" not in str(err.value)
