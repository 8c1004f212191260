"""The default 36-DOF hand: structure after Ye & Liu's Figure 4, geometry, samples, mirroring, scaling, errors."""

from __future__ import annotations

import math

import pytest
import torch

import torchhand
from torchhand.hand import FINGER_NAMES


def test_structure_matches_figure_4():
    hand = torchhand.default_hand()
    assert hand.num_joints == 30 and hand.num_links == 20
    assert hand.finger_names == FINGER_NAMES
    assert hand.joint_limits.shape == (30, 2)
    assert len(set(hand.joint_names)) == 30 and len(set(hand.link_names)) == 20
    for f in FINGER_NAMES:
        assert sum(n.startswith(f + "_") for n in hand.joint_names) == 6  # 6 DOF per digit
    # Fingers: 2-DOF palm joint, 2-DOF MCP, 1-DOF PIP, 1-DOF DIP. Thumb: 3-DOF CMC, 2-DOF MCP, 1-DOF IP.
    per_link = {}
    for d, name in enumerate(hand.joint_names):
        per_link.setdefault(hand.link_names[int(hand.chain.joint_link[d])], []).append(name)
    for f in ("index", "middle", "ring", "little"):
        assert [len(per_link[f"{f}_{seg}"]) for seg in ("metacarpal", "proximal", "middle", "distal")] == [2, 2, 1, 1]
    assert [len(per_link[f"thumb_{seg}"]) for seg in ("metacarpal", "proximal", "distal")] == [3, 2, 1]
    assert "palm" not in per_link  # the wrist's 6 DOF are the root pose


def test_limits_and_rest_pose():
    hand = torchhand.default_hand()
    lo, hi = hand.joint_limits.unbind(-1)
    assert (lo < hi).all()
    assert ((hand.q_rest >= lo) & (hand.q_rest <= hi)).all()
    assert hand.joint_limits[hand.joint_index("index_pip"), 1] > math.radians(100)
    q = torch.full((1, 30), 10.0, dtype=torch.float64)
    assert torch.equal(hand.clamp_to_limits(q)[0], hi)


def test_length_scaling_and_fingertip_reach():
    for length in (0.16, 0.19, 0.22):
        hand = torchhand.default_hand(length=length)
        T = hand.forward_kinematics(torch.zeros(1, 30, dtype=torch.float64))
        d = hand.distal_link[FINGER_NAMES.index("middle")]
        # Straight middle finger: the distal capsule's far end plus its radius is the hand length.
        b, r = hand.capsule_b[d], hand.capsule_radius[d]
        tip = T[0, d, :3, :3] @ b + T[0, d, :3, 3]
        assert abs(float(tip[0] + r) - length) < 1e-9


def test_surface_samples_lie_on_capsules():
    hand = torchhand.default_hand()
    a, b, r = hand.capsule_a, hand.capsule_b, hand.capsule_radius
    finger_samples = hand.link_finger[hand.sample_link] >= 0
    p = hand.sample_points[finger_samples]
    l = hand.sample_link[finger_samples]
    ab = b[l] - a[l]
    t = ((p - a[l]) * ab).sum(-1) / (ab * ab).sum(-1)
    closest = a[l] + t.clamp(0, 1).unsqueeze(-1) * ab
    assert torch.allclose((p - closest).norm(dim=-1), r[l], atol=1e-12)
    n = hand.sample_normals[finger_samples]
    assert torch.allclose(n.norm(dim=-1), torch.ones(len(n), dtype=n.dtype))
    assert ((n * (p - closest)).sum(-1) > 0).all()  # outward
    counts = torch.bincount(hand.sample_link, minlength=hand.num_links)
    assert (counts >= 24).all()


def test_fingers_and_collision_pairs():
    hand = torchhand.default_hand()
    assert torch.allclose(hand.nail_normal.norm(dim=-1), torch.ones(5, dtype=torch.float64))
    for f, name in enumerate(FINGER_NAMES):
        assert hand.link_names[int(hand.distal_link[f])] == f"{name}_distal"
    lf = hand.link_finger[hand.collision_pairs]
    assert (lf[:, 0] != lf[:, 1]).all() and (lf >= 0).all()
    # Straight rest hand: no finger-finger interpenetration between neighbours' capsules.
    T = hand.forward_kinematics(torch.zeros(1, 30, dtype=torch.float64))[0]
    A = (T[:, :3, :3] @ hand.capsule_a.unsqueeze(-1)).squeeze(-1) + T[:, :3, 3]
    B = (T[:, :3, :3] @ hand.capsule_b.unsqueeze(-1)).squeeze(-1) + T[:, :3, 3]
    for i, j in hand.collision_pairs.tolist():
        s = torch.linspace(0, 1, 50, dtype=torch.float64).unsqueeze(-1)
        pi, pj = A[i] + s * (B[i] - A[i]), A[j] + s * (B[j] - A[j])
        dmin = torch.cdist(pi, pj).min()
        assert dmin > hand.capsule_radius[i] + hand.capsule_radius[j] - 1e-9, (hand.link_names[i], hand.link_names[j])
    # E2 coupling triples are flexion joints of one finger.
    assert (hand.flexion_joints >= 0).all()
    assert hand.joint_names[int(hand.flexion_joints[1, 0])] == "index_mcp_flex"


def test_left_is_mirror_of_right(gen):
    right, left = torchhand.default_hand("right"), torchhand.default_hand("left")
    assert right.joint_names == left.joint_names and right.link_names == left.link_names
    q = right.random_q(7, gen)
    M = torch.diag(torch.tensor([1.0, -1.0, 1.0, 1.0], dtype=torch.float64))
    assert torch.allclose(M @ right.forward_kinematics(q) @ M, left.forward_kinematics(q), atol=1e-15)
    # Thumb on +y for the right hand and -y for the left at rest.
    t = right.link_index("thumb_distal")
    yr = right.forward_kinematics(right.q_rest.unsqueeze(0))[0, t, 1, 3]
    yl = left.forward_kinematics(left.q_rest.unsqueeze(0))[0, t, 1, 3]
    assert yr > 0.03 and torch.isclose(yl, -yr)


def test_to_moves_floats_and_keeps_indices():
    h = torchhand.default_hand().to(dtype=torch.float32)
    assert h.joint_limits.dtype == torch.float32 and h.chain.link_offset.dtype == torch.float32
    assert h.chain.link_parent.dtype == torch.long and h.sample_link.dtype == torch.long
    assert h.chain.support.dtype == torch.bool
    h2 = torchhand.default_hand(dtype=torch.float32)
    assert torch.equal(h2.sample_points, h.sample_points)


def test_bad_arguments():
    with pytest.raises(torchhand.InputValueError, match="side"):
        torchhand.default_hand("middle")
    with pytest.raises(torchhand.InputValueError, match="length"):
        torchhand.default_hand(length=3.0)
    hand = torchhand.default_hand()
    with pytest.raises(torchhand.UnknownNameError, match="unknown joint 'index_xyz'"):
        hand.joint_index("index_xyz")
    with pytest.raises(KeyError):
        hand.link_index("wrist")
