"""Batched FK and analytic point Jacobians (kernels/kinematics.py), through the default hand and a textbook arm."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from kornia.geometry.conversions import axis_angle_to_rotation_matrix

import torchhand
from torchhand.conventions import tolerances
from torchhand.hand import GeomSpec, JointSpec, LinkSpec, build_hand_model


def random_root(B: int, gen: torch.Generator, dtype=torch.float64) -> torch.Tensor:
    T = torch.eye(4, dtype=dtype).repeat(B, 1, 1)
    T[:, :3, :3] = axis_angle_to_rotation_matrix(torch.randn(B, 3, generator=gen, dtype=torch.float64)).to(dtype)
    T[:, :3, 3] = torch.randn(B, 3, generator=gen, dtype=torch.float64).to(dtype) * 0.3
    return T


def planar_arm(l1=0.3, l2=0.2):
    """Two hinge joints about z, links along x: the textbook planar arm with closed-form FK and Jacobian."""
    off = np.eye(4)
    off2 = np.eye(4)
    off2[0, 3] = l1
    z = np.array([0.0, 0.0, 1.0])
    links = [LinkSpec("base", None, off), LinkSpec("upper", "base", off), LinkSpec("fore", "upper", off2)]
    joints = [JointSpec("j1", "upper", "hinge", z, np.zeros(3), np.array([-3.0, 3.0])),
              JointSpec("j2", "fore", "hinge", z, np.zeros(3), np.array([-3.0, 3.0]))]
    geoms = [GeomSpec("fore", "sphere", np.array([0.01, 0, 0]), np.eye(4))]
    return build_hand_model("arm", links, joints, geoms)


@pytest.mark.parametrize("B", [1, 7])
def test_fk_shapes_and_dtypes(B, dtype, device, gen):
    hand = torchhand.default_hand().to(device=device, dtype=dtype)
    q = hand.random_q(B, gen).to(device)
    T = hand.forward_kinematics(q)
    assert T.shape == (B, hand.num_links, 4, 4) and T.dtype == dtype and T.device.type == device
    J = hand.point_jacobian(q, hand.sample_link[:5], hand.sample_points[:5])
    assert J.shape == (B, 5, 3, hand.num_joints)
    # Rigid transforms out.
    R = T[..., :3, :3]
    eye = torch.eye(3, dtype=dtype, device=device)
    assert torch.allclose(R.transpose(-1, -2) @ R, eye.expand_as(R), atol=50 * tolerances(dtype).eps)
    assert torch.equal(T[..., 3, :], torch.tensor([0, 0, 0, 1], dtype=dtype, device=device).expand(B, hand.num_links, 4))


def test_root_link_is_root_pose(gen):
    hand = torchhand.default_hand()
    root = random_root(5, gen)
    T = hand.forward_kinematics(hand.random_q(5, gen), root)
    assert torch.allclose(T[:, 0], root, atol=1e-15)
    T0 = hand.forward_kinematics(torch.zeros(2, hand.num_joints, dtype=torch.float64))
    assert torch.equal(T0[:, 0], torch.eye(4, dtype=torch.float64).expand(2, 4, 4))


def test_root_equivariance(gen):
    """FK(q, A) = A @ FK(q, I) for any rigid A."""
    hand = torchhand.default_hand()
    q = hand.random_q(7, gen)
    A = random_root(7, gen)
    assert torch.allclose(hand.forward_kinematics(q, A), A.unsqueeze(1) @ hand.forward_kinematics(q), atol=1e-14)


def test_planar_arm_closed_form(gen):
    arm = planar_arm()
    q = (torch.rand(64, 2, generator=gen, dtype=torch.float64) - 0.5) * 6
    pts = torch.tensor([[0.2, 0.0, 0.0]], dtype=torch.float64)  # the end effector on link "fore"
    x, J = arm.points_and_jacobian(q, torch.tensor([2]), pts)
    a, b = q[:, 0], q[:, 1]
    ex = 0.3 * torch.cos(a) + 0.2 * torch.cos(a + b)
    ey = 0.3 * torch.sin(a) + 0.2 * torch.sin(a + b)
    assert torch.allclose(x[:, 0, 0], ex, atol=1e-15) and torch.allclose(x[:, 0, 1], ey, atol=1e-15)
    J_ref = torch.stack([
        torch.stack([-ey, -0.2 * torch.sin(a + b)], -1),
        torch.stack([ex, 0.2 * torch.cos(a + b)], -1),
        torch.zeros(64, 2, dtype=torch.float64),
    ], -2)
    assert torch.allclose(J[:, 0], J_ref, atol=1e-14)


def test_slide_joint_jacobian():
    off = np.eye(4)
    links = [LinkSpec("base", None, off), LinkSpec("carriage", "base", off)]
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    joints = [JointSpec("s", "carriage", "slide", axis, np.zeros(3), np.array([-1.0, 1.0]))]
    m = build_hand_model("slider", links, joints, [])
    q = torch.tensor([[0.5]], dtype=torch.float64)
    x, J = m.points_and_jacobian(q, torch.tensor([1]), torch.zeros(1, 3, dtype=torch.float64))
    assert torch.allclose(x[0, 0], torch.as_tensor(axis) * 0.5)
    assert torch.allclose(J[0, 0, :, 0], torch.as_tensor(axis))


@pytest.mark.parametrize("side", ["right", "left"])
def test_jacobian_matches_autograd_float64(side, gen):
    hand = torchhand.default_hand(side)
    B = 7
    q = hand.random_q(B, gen)
    root = random_root(B, gen)
    sel = torch.randperm(hand.sample_link.numel(), generator=gen)[:96]
    link, pts = hand.sample_link[sel], hand.sample_points[sel]
    _, J = hand.points_and_jacobian(q, link, pts, root)

    def f(qq):
        return hand.points_and_jacobian(qq, link, pts, root)[0]

    Ja = torch.autograd.functional.jacobian(f, q)  # (B, P, 3, B, D)
    Ja = torch.stack([Ja[b, :, :, b] for b in range(B)])
    assert J.abs().max() > 0.05  # the selection covers moving links
    assert (Ja - J).abs().max() <= 1e-8


def test_float32_agrees_with_float64(gen):
    h64 = torchhand.default_hand()
    h32 = h64.to(dtype=torch.float32)
    q = h64.random_q(7, gen)
    root = random_root(7, gen)
    T64 = h64.forward_kinematics(q, root)
    T32 = h32.forward_kinematics(q.float(), root.float())
    assert (T32.double() - T64).abs().max() < 1e-5


def test_bad_inputs():
    hand = torchhand.default_hand()
    with pytest.raises(torchhand.ShapeError, match="q: expected shape"):
        hand.forward_kinematics(torch.zeros(3, 29, dtype=torch.float64))
    with pytest.raises(torchhand.ShapeError, match="root"):
        hand.forward_kinematics(torch.zeros(3, 30, dtype=torch.float64), torch.eye(4, dtype=torch.float64))
    q = torch.zeros(2, 30, dtype=torch.float64)
    q[1, 3] = math.nan
    with pytest.raises(torchhand.InputValueError, match="NaN"):
        hand.forward_kinematics(q, check=True)
    bad = torch.eye(4, dtype=torch.float64).repeat(1, 1, 1)
    bad[0, 0, 0] = 2.0
    with pytest.raises(torchhand.InputValueError, match="not rigid"):
        hand.forward_kinematics(torch.zeros(1, 30, dtype=torch.float64), bad, check=True)
    with pytest.raises(torchhand.InputValueError, match="link_index"):
        hand.point_jacobian(torch.zeros(1, 30, dtype=torch.float64), torch.tensor([99]),
                            torch.zeros(1, 3, dtype=torch.float64))
    with pytest.raises(torchhand.InputTypeError):
        hand.forward_kinematics(torch.zeros(1, 30, dtype=torch.long))


def test_gradients_flow_through_fk(gen):
    hand = torchhand.default_hand()
    q = hand.random_q(3, gen).requires_grad_(True)
    T = hand.forward_kinematics(q)
    T[:, hand.distal_link, :3, 3].sum().backward()
    assert q.grad is not None and torch.isfinite(q.grad).all() and q.grad.abs().max() > 0


def test_frames_point_jacobian_equals_a_fresh_pass(gen):
    """One kinematics pass (``kinematic_frames``) serves any later point Jacobians at that configuration: the same
    values, bit for bit, as ``point_jacobian``'s own pass, for any subset of points (here two disjoint ones)."""
    from torchhand.hand.dynamics import kinematic_frames, point_jacobian, point_jacobian_at

    hand = torchhand.default_hand()
    q, root = hand.random_q(5, gen), random_root(5, gen)
    sel = torch.randperm(hand.sample_link.numel(), generator=gen)[:40]
    link, pts = hand.sample_link[sel], hand.sample_points[sel]
    fr = kinematic_frames(hand, q, root)
    assert torch.equal(fr.poses, hand.forward_kinematics(q, root))
    for part in (slice(0, 17), slice(17, 40)):
        want = point_jacobian(hand, q, link[part], pts[part], root)
        got = point_jacobian_at(hand, fr, root, link[part], pts[part])
        assert want.abs().max() > 0.05
        assert torch.equal(got, want)
