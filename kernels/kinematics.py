"""Batched forward kinematics and analytic point Jacobians of a kinematic tree.

Pure tensor math: imports torch only. The tree is described by plain tensors (see :class:`Chain`); the typed
model that builds them lives in ``torchhand.hand``.

Model of a link ``l`` (MJCF's body semantics)::

    T_world_l = T_world_parent(l) @ offset[l] @ J(joint_0) @ J(joint_1) @ ...     (joints of l, in order)

    hinge joint:  J = Trans(anchor) @ Rot(axis, q) @ Trans(-anchor)
    slide joint:  J = Trans(axis * q)

with ``axis`` and ``anchor`` in the link's frame. The root link (index 0) has parent -1 and its parent transform is
the given root pose. Conventions: metres, radians, column-vector 4x4 transforms (``p_world = T @ p_link``).
"""

from __future__ import annotations

from typing import NamedTuple

import torch

__all__ = ["Chain", "JOINT_HINGE", "JOINT_SLIDE", "forward_kinematics", "joint_frames", "point_jacobian"]

JOINT_HINGE = 0
JOINT_SLIDE = 1


class Chain(NamedTuple):
    """Tensors describing a kinematic tree of L links and D joints (links in topological order).

    link_parent:  parent link index, (L,), long; -1 for the root (link 0 only)
    link_offset:  fixed transform parent -> link at q = 0, (L, 4, 4), metres
    link_joints:  joint indices of each link in application order, (L, J), long; padding = D
    joint_link:   link each joint moves, (D,), long
    joint_type:   JOINT_HINGE or JOINT_SLIDE, (D,), long
    joint_axis:   unit axis in the joint's link frame, (D, 3)
    joint_anchor: point on the axis in the link frame, (D, 3), metres
    support:      support[l, j] is True when joint j moves link l, (L, D), bool
    levels:       link indices grouped by depth in the tree, tuple of (n_k,) long tensors, root level first
    """

    link_parent: torch.Tensor
    link_offset: torch.Tensor
    link_joints: torch.Tensor
    joint_link: torch.Tensor
    joint_type: torch.Tensor
    joint_axis: torch.Tensor
    joint_anchor: torch.Tensor
    support: torch.Tensor
    levels: tuple


def _joint_transforms(chain: Chain, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Rotation (B, D, 3, 3) and translation (B, D, 3) of every joint's motion for angles/offsets ``q (B, D)``."""
    axis = chain.joint_axis.to(q)  # (D, 3)
    anchor = chain.joint_anchor.to(q)
    hinge = (chain.joint_type == JOINT_HINGE).unsqueeze(-1)  # (D, 1)
    # Rodrigues: R = I + sin K + (1 - cos) K^2, evaluated with outer products to stay batched.
    s = torch.sin(q).unsqueeze(-1).unsqueeze(-1)  # (B, D, 1, 1)
    c = torch.cos(q).unsqueeze(-1).unsqueeze(-1)
    x, y, z = axis.unbind(-1)
    zero = torch.zeros_like(x)
    K = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).reshape(-1, 3, 3)  # (D, 3, 3)
    K2 = axis.unsqueeze(-1) * axis.unsqueeze(-2) - torch.eye(3, dtype=q.dtype, device=q.device)
    R_hinge = torch.eye(3, dtype=q.dtype, device=q.device) + s * K + (1 - c) * K2  # (B, D, 3, 3)
    eye = torch.eye(3, dtype=q.dtype, device=q.device).expand_as(R_hinge)
    R = torch.where(hinge.unsqueeze(-1), R_hinge, eye)
    t_hinge = anchor - (R_hinge @ anchor.unsqueeze(-1)).squeeze(-1)
    t_slide = axis * q.unsqueeze(-1)
    t = torch.where(hinge, t_hinge, t_slide)
    return R, t


def _compose(Ra, ta, Rb, tb):
    """(Ra, ta) @ (Rb, tb) for rigid transforms split into rotation (..., 3, 3) and translation (..., 3)."""
    return Ra @ Rb, ta + (Ra @ tb.unsqueeze(-1)).squeeze(-1)


def _kinematics(chain: Chain, q: torch.Tensor, root: torch.Tensor, need_joints: bool):
    B, D = q.shape
    L = chain.link_parent.shape[0]
    dtype, device = q.dtype, q.device
    Rj, tj = _joint_transforms(chain, q)
    # Pad with an identity joint at index D so padded entries of link_joints compose to nothing.
    Rj = torch.cat([Rj, torch.eye(3, dtype=dtype, device=device).expand(B, 1, 3, 3)], dim=1)
    tj = torch.cat([tj, q.new_zeros(B, 1, 3)], dim=1)

    offset = chain.link_offset.to(q)
    R_loc = offset[:, :3, :3].expand(B, L, 3, 3)
    t_loc = offset[:, :3, 3].expand(B, L, 3)
    # Transform from the link's parent frame to just before each joint: (B, D, ...), filled per joint slot.
    R_pre = t_pre = None
    if need_joints:
        R_pre = q.new_zeros(B, D + 1, 3, 3)
        t_pre = q.new_zeros(B, D + 1, 3)
    for k in range(chain.link_joints.shape[1]):
        idx = chain.link_joints[:, k]  # (L,)
        if need_joints:
            R_pre = R_pre.index_copy(1, idx, R_loc)
            t_pre = t_pre.index_copy(1, idx, t_loc)
        R_loc, t_loc = _compose(R_loc, t_loc, Rj[:, idx], tj[:, idx])

    R_root = root[:, :3, :3]
    t_root = root[:, :3, 3]
    # Walk the tree level by level; each level is one batched compose over its links. Level 0 is the root.
    R_world = q.new_zeros(B, L, 3, 3)
    t_world = q.new_zeros(B, L, 3)
    for depth, level in enumerate(chain.levels):
        if depth == 0:
            Rp, tp = R_root.unsqueeze(1), t_root.unsqueeze(1)
        else:
            parent = chain.link_parent[level]
            Rp, tp = R_world[:, parent], t_world[:, parent]
        Rl, tl = _compose(Rp, tp, R_loc[:, level], t_loc[:, level])
        R_world = R_world.index_copy(1, level, Rl)
        t_world = t_world.index_copy(1, level, tl)
    if not need_joints:
        return R_world, t_world, None, None
    # World frame of each joint just before its own motion (the axis and anchor are fixed in it).
    parent_of_joint = chain.link_parent[chain.joint_link]  # (D,)
    is_root = parent_of_joint < 0
    pj = parent_of_joint.clamp(min=0)
    Rp = torch.where(is_root.view(1, -1, 1, 1), R_root.unsqueeze(1), R_world[:, pj])
    tp = torch.where(is_root.view(1, -1, 1), t_root.unsqueeze(1), t_world[:, pj])
    Rjw, tjw = _compose(Rp, tp, R_pre[:, :D], t_pre[:, :D])
    return R_world, t_world, Rjw, tjw


def _homogeneous(R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    bottom = torch.zeros(R.shape[:-2] + (1, 4), dtype=R.dtype, device=R.device)
    bottom[..., 0, 3] = 1
    return torch.cat([torch.cat([R, t.unsqueeze(-1)], dim=-1), bottom], dim=-2)


def forward_kinematics(chain: Chain, q: torch.Tensor, root: torch.Tensor) -> torch.Tensor:
    """World poses of all links.

    q:    joint values, (B, D), radians (hinge) or metres (slide)
    root: world pose of the root's parent frame, (B, 4, 4)
    returns: T_world_link, (B, L, 4, 4)
    """
    R, t, _, _ = _kinematics(chain, q, root, need_joints=False)
    return _homogeneous(R, t)


def joint_frames(chain: Chain, q: torch.Tensor, root: torch.Tensor):
    """Link poses plus the world axis and anchor of every joint.

    returns: (T_world_link (B, L, 4, 4), axis_world (B, D, 3) unit, anchor_world (B, D, 3) metres)
    """
    R, t, Rj, tj = _kinematics(chain, q, root, need_joints=True)
    axis = (Rj @ chain.joint_axis.to(q).unsqueeze(-1)).squeeze(-1)
    anchor = (Rj @ chain.joint_anchor.to(q).unsqueeze(-1)).squeeze(-1) + tj
    return _homogeneous(R, t), axis, anchor


def point_jacobian(
    chain: Chain,
    q: torch.Tensor,
    root: torch.Tensor,
    link_index: torch.Tensor,
    points_local: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Analytic Jacobian of points fixed on links with respect to the joint values.

    q:            (B, D), radians / metres
    root:         (B, 4, 4)
    link_index:   link of each point, (P,), long
    points_local: points in their link's frame, (P, 3) or (B, P, 3), metres
    returns: (points_world (B, P, 3) metres, jacobian (B, P, 3, D) metres per radian / per metre)
    """
    T, axis, anchor = joint_frames(chain, q, root)
    T_l = T[:, link_index]  # (B, P, 4, 4)
    p = points_local.to(q)
    if p.dim() == 2:
        p = p.unsqueeze(0)
    x = (T_l[..., :3, :3] @ p.unsqueeze(-1)).squeeze(-1) + T_l[..., :3, 3]  # (B, P, 3)
    hinge = (chain.joint_type == JOINT_HINGE).view(1, 1, -1, 1)
    a = axis.unsqueeze(1)  # (B, 1, D, 3)
    lin = torch.where(hinge, torch.linalg.cross(a.expand(-1, x.shape[1], -1, -1), x.unsqueeze(2) - anchor.unsqueeze(1)),
                      a.expand(-1, x.shape[1], -1, -1))  # (B, P, D, 3)
    mask = chain.support[link_index].to(q.dtype).unsqueeze(-1)  # (P, D, 1)
    return x, (lin * mask).transpose(-1, -2)
