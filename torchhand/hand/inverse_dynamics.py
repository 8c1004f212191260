"""Inverse dynamics of the hand on a floating root: ``u = M(q) nu_dot + C(q, nu) + n(q)`` (Liu 2009, Eq. 5).

Coordinates are those of :mod:`torchhand.hand.dynamics`: generalized velocity ``nu = (w, v, qdot)`` (world angular
velocity of the root frame, world velocity of the root origin ``o = root[:, :3, 3]``, joint rates), its time
derivative ``nu_dot = (alpha, a, qddot)`` (world angular acceleration, world acceleration of ``o``, joint
accelerations) and generalized forces ``u = (torque about o, force, joint torques)``, all world frame, with power
``u . nu``. MuJoCo's free joint uses ``qvel = (v, R^T w)`` and ``qacc = (a, R^T alpha)`` (``R = root[:, :3, :3]``);
then ``u = S^T qfrc_inverse`` with ``nu_mj = S nu``.

Method: recursive Newton-Euler written over the whole tree at once (no loop over links or the batch), in spatial
(Plucker) vectors ``(angular, linear)`` about the point fixed in space where ``o`` is at this instant (positions
relative to ``o`` keep float32 accurate far from the world origin):

    S_j       joint axis: hinge ``(a_j, (r_j - o) x a_j)``, slide ``(0, a_j)``    (a_j world axis, r_j anchor)
    V_l       = V_root + sum_{j moves l} S_j qdot_j,           V_root = (w, v)
    A_l       = A_root + sum_{j moves l} S_j qddot_j + (V_pre(j) x S_j) qdot_j,   A_root = (alpha, a - w x v)
    F_l       wrench of link l about o: f = m (a_com - g), n = I alpha + w x I w + (com - o) x f
    u_j       = S_j . sum_{l moved by j} F_l;      (torque, force) = sum_l F_l

``V_pre(j)`` is the spatial velocity of the frame that carries joint j's axis (the link's parent and the joints
before j on its link). Cost grows as B (L + D) D; float32 and float64, CPU and CUDA, device and dtype from ``q``.
Conventions: metres, kilograms, seconds, newtons, radians; column-vector 4x4 transforms.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from torchhand.kernels import kinematics as _kin
from torchhand.kernels.kinematics import JOINT_HINGE

from ..conventions import check_finite, check_tensor
from ..errors import InputValueError
from .dynamics import _gravity

if TYPE_CHECKING:  # pragma: no cover
    from .model import HandModel

__all__ = ["inverse_dynamics"]


def inverse_dynamics(hand: HandModel, q: torch.Tensor, root: torch.Tensor | None, nu: torch.Tensor,
                     nu_dot: torch.Tensor, gravity=(0.0, 0.0, -9.81), *, check: bool = False) -> torch.Tensor:
    """Generalized force that moves the hand with velocity ``nu`` and acceleration ``nu_dot`` (no contacts).

    hand:    HandModel (its inertials; joints independent, no armature, damping or springs)
    q:       joint values, (B, D), radians (hinge) / metres (slide)
    root:    world pose of the root link's parent frame (the wrist), (B, 4, 4); None = identity
    nu:      generalized velocity (w rad/s, v m/s, qdot), (B, 6 + D), world frame (module docstring)
    nu_dot:  its time derivative (alpha rad/s^2, a m/s^2, qddot), (B, 6 + D)
    gravity: world gravity, (3,) or (B, 3), m/s^2
    check:   also check q, nu, nu_dot for NaN and root for rigidity (forces a host sync)
    returns: u = M nu_dot + C + n, (B, 6 + D): torque about the root origin (world, N m), force (world, N), joint
        torques (N m or N); equals :func:`~torchhand.hand.dynamics.gravity_torques` at nu = nu_dot = 0
    raises:  ShapeError, InputTypeError, InputValueError (dtype mismatch, NaN with ``check``)
    """
    q, root = hand._inputs(q, root, check)
    nu, nu_dot = _rates(nu, "nu", q, check), _rates(nu_dot, "nu_dot", q, check)
    g = _gravity(gravity, q)
    chain = hand._chain(q)
    T, axis, anchor = _kin.joint_frames(chain, q, root)
    o = root[:, :3, 3]
    S = _joint_axes(chain, axis, anchor - o.unsqueeze(1))
    V, A = _link_motion(chain, S, nu, nu_dot)
    F = _link_wrenches(hand, T, o, V, A, g)
    subtree = torch.einsum("ld,blk->bdk", chain.support.to(q.dtype), F)  # wrench carried by each joint
    return torch.cat([F.sum(1), (S * subtree).sum(-1)], dim=-1)


def _rates(x: torch.Tensor, name: str, q: torch.Tensor, check: bool) -> torch.Tensor:
    """Check a generalized velocity or acceleration against q: shape (B, 6 + D), dtype and device."""
    check_tensor(x, name, (q.shape[0], 6 + q.shape[1]))
    if x.dtype != q.dtype:
        raise InputValueError(f"{name}: dtype {x.dtype} differs from q's {q.dtype}")
    if x.device != q.device:
        raise InputValueError(f"{name}: on {x.device}, q on {q.device}")
    if check:
        check_finite(x, name)
    return x


def _cross(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return torch.linalg.cross(a, b, dim=-1)


def _cross_motion(V: torch.Tensor, X: torch.Tensor) -> torch.Tensor:
    """Spatial motion cross product V x X of (..., 6) vectors (angular, linear): the rate of a spatial axis X fixed
    in a body that moves with V."""
    w, v = V[..., :3], V[..., 3:]
    xw, xv = X[..., :3], X[..., 3:]
    return torch.cat([_cross(w, xw), _cross(w, xv) + _cross(v, xw)], dim=-1)


def _joint_axes(chain, axis: torch.Tensor, anchor: torch.Tensor) -> torch.Tensor:
    """Spatial axes (B, D, 6) of the joints about o, from world axes (B, D, 3) and anchors relative to o."""
    hinge = (chain.joint_type == JOINT_HINGE).to(axis.dtype).unsqueeze(-1)  # (D, 1)
    return torch.cat([axis * hinge, _cross(anchor, axis) * hinge + axis * (1 - hinge)], dim=-1)


def _predecessors(chain, dtype: torch.dtype) -> torch.Tensor:
    """(D, D): entry (j, i) is 1 when joint i moves the frame that carries joint j's axis (every joint of the
    parent link's path, and the joints before j on its own link)."""
    D = chain.joint_link.shape[0]
    parent = chain.link_parent[chain.joint_link]  # (D,)
    P = chain.support[parent.clamp(min=0)] & (parent >= 0).unsqueeze(-1)
    idx = torch.arange(D, device=chain.joint_link.device)
    slot = (chain.link_joints[chain.joint_link] == idx.unsqueeze(-1)).to(torch.long).argmax(-1)  # (D,)
    same = chain.joint_link.unsqueeze(-1) == chain.joint_link.unsqueeze(0)
    return (P | (same & (slot.unsqueeze(0) < slot.unsqueeze(-1)))).to(dtype)


def _link_motion(chain, S: torch.Tensor, nu: torch.Tensor, nu_dot: torch.Tensor):
    """Spatial velocities and accelerations (B, L, 6) of the links about o (module docstring)."""
    w, v = nu[:, :3], nu[:, 3:6]
    qdot, qddot = nu[:, 6:].unsqueeze(-1), nu_dot[:, 6:].unsqueeze(-1)
    V_root = nu[:, :6]
    A_root = torch.cat([nu_dot[:, :3], nu_dot[:, 3:6] - _cross(w, v)], dim=-1)
    Sq = S * qdot  # (B, D, 6) each joint's share of the velocity
    V_pre = V_root.unsqueeze(1) + torch.einsum("ji,bik->bjk", _predecessors(chain, nu.dtype), Sq)
    joint_acc = S * qddot + _cross_motion(V_pre, Sq)
    support = chain.support.to(nu.dtype)
    V = V_root.unsqueeze(1) + torch.einsum("ld,bdk->blk", support, Sq)
    A = A_root.unsqueeze(1) + torch.einsum("ld,bdk->blk", support, joint_acc)
    return V, A


def _link_wrenches(hand: HandModel, T: torch.Tensor, o: torch.Tensor, V: torch.Tensor, A: torch.Tensor,
                   g: torch.Tensor) -> torch.Tensor:
    """Wrench (B, L, 6) = (moment about o, force) that gives each link its motion against gravity (Newton-Euler)."""
    R = T[..., :3, :3]
    com = (R @ hand.link_com.to(o).unsqueeze(-1)).squeeze(-1) + T[..., :3, 3] - o.unsqueeze(1)  # (B, L, 3)
    w, alpha = V[..., :3], A[..., :3]
    v_com = V[..., 3:] + _cross(w, com)
    a_com = A[..., 3:] + _cross(alpha, com) + _cross(w, v_com)  # classical acceleration of the centre of mass
    f = hand.link_mass.to(o).view(1, -1, 1) * (a_com - g.unsqueeze(1))
    I = R @ hand.link_inertia.to(o) @ R.transpose(-1, -2)  # world axes, about each centre of mass
    Iw = (I @ w.unsqueeze(-1)).squeeze(-1)
    n = (I @ alpha.unsqueeze(-1)).squeeze(-1) + _cross(w, Iw) + _cross(com, f)
    return torch.cat([n, f], dim=-1)
