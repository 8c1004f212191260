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

__all__ = ["Chain", "JOINT_HINGE", "JOINT_SLIDE", "forward_kinematics", "joint_frames", "point_jacobian",
           "fk_and_point_jacobian", "Frames", "frames", "frames_point_jacobian"]

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
    slot_links:   for k = 0, 1, ...: the links that have a k-th joint, tuple of (m_k,) long tensors
    slot_joints:  the matching k-th joints, tuple of (m_k,) long tensors
    support_joints: the joints that move each link, (L, S), long, padded with -1
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
    slot_links: tuple
    slot_joints: tuple
    support_joints: torch.Tensor


# Internally every quantity is laid out batch-LAST: rotations (..., 3, 3, B), vectors (..., 3, B). Products of
# 3x3 blocks are then three broadcast multiply-adds over contiguous length-B rows, which vectorises well on CPUs
# (tiny batched matmuls do not) and is just as good on GPUs. The public functions take and return batch-first.


def _mm(Ra: torch.Tensor, Rb: torch.Tensor) -> torch.Tensor:
    """Ra @ Rb for batch-last rotations (..., 3, 3, B) (either may broadcast over B with size 1)."""
    return Ra[..., :, 0:1, :] * Rb[..., 0:1, :, :] + Ra[..., :, 1:2, :] * Rb[..., 1:2, :, :] \
        + Ra[..., :, 2:3, :] * Rb[..., 2:3, :, :]


def _mv(R: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """R @ v for batch-last R (..., 3, 3, B) and v (..., 3, B)."""
    return R[..., :, 0, :] * v[..., 0:1, :] + R[..., :, 1, :] * v[..., 1:2, :] + R[..., :, 2, :] * v[..., 2:3, :]


def _joint_transforms(chain: Chain, qT: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Rotation (D, 3, 3, B) and translation (D, 3, B) of every joint for batch-last values ``qT (D, B)``."""
    axis = chain.joint_axis.to(qT)  # (D, 3)
    D = axis.shape[0]
    hinge = (chain.joint_type == JOINT_HINGE).to(qT.dtype).view(D, 1, 1, 1)
    # Rodrigues: R = I + sin [a]x + (1 - cos) (a a^T - I); the two constant matrices are zeroed for slide joints,
    # whose rotation is then exactly I.
    x, y, z = axis.unbind(-1)
    zero = torch.zeros_like(x)
    eye = torch.eye(3, dtype=qT.dtype, device=qT.device)
    K = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).reshape(D, 3, 3, 1) * hinge
    K2 = (axis.unsqueeze(-1) * axis.unsqueeze(-2) - eye).unsqueeze(-1) * hinge
    s = torch.sin(qT).view(D, 1, 1, -1)
    omc = (1 - torch.cos(qT)).view(D, 1, 1, -1)
    R = s * K + omc * K2 + eye.view(1, 3, 3, 1)
    # Hinge about an axis through ``anchor``: t = anchor - R anchor; slide: t = axis * q (R = I there, so the first
    # term vanishes and one formula serves both).
    a = chain.joint_anchor.to(qT).unsqueeze(-1)  # (D, 3, 1)
    slide = (1 - hinge).view(D, 1, 1)
    t = a - _mv(R, a) + slide * axis.unsqueeze(-1) * qT.unsqueeze(1)
    return R, t


def _kinematics(chain: Chain, q: torch.Tensor, root: torch.Tensor, need_joints: bool):
    """Batch-last world rotations (L, 3, 3, B), translations (L, 3, B) and, if asked, each joint's world axis and
    anchor (D, 3, B)."""
    B, D = q.shape
    L = chain.link_parent.shape[0]
    Rj, tj = _joint_transforms(chain, q.t())
    offset = chain.link_offset.to(q)
    # Local transform of every link: its fixed offset followed by its joints, slot by slot.
    R_loc = offset[:, :3, :3].unsqueeze(-1).expand(L, 3, 3, B).contiguous()
    t_loc = offset[:, :3, 3].unsqueeze(-1).expand(L, 3, B).contiguous()
    if need_joints:
        # Each joint's axis and anchor in its link's parent frame (the frame just before the joint moves).
        axis_p = q.new_empty(D, 3, B)
        anchor_p = q.new_empty(D, 3, B)
        axis = chain.joint_axis.to(q).unsqueeze(-1)
        anchor = chain.joint_anchor.to(q).unsqueeze(-1)
    for links, joints in zip(chain.slot_links, chain.slot_joints):
        Rl, tl = R_loc[links], t_loc[links]
        if need_joints:
            axis_p.index_copy_(0, joints, _mv(Rl, axis[joints]))
            anchor_p.index_copy_(0, joints, _mv(Rl, anchor[joints]) + tl)
        R_loc.index_copy_(0, links, _mm(Rl, Rj[joints]))
        t_loc.index_copy_(0, links, tl + _mv(Rl, tj[joints]))

    R_root = root[:, :3, :3].permute(1, 2, 0)  # (3, 3, B)
    t_root = root[:, :3, 3].t()  # (3, B)
    R_world = q.new_empty(L, 3, 3, B)
    t_world = q.new_empty(L, 3, B)
    # Walk the tree level by level (level 0 is the root link); each level is one broadcast compose.
    for depth, level in enumerate(chain.levels):
        if depth == 0:
            Rp, tp = R_root.unsqueeze(0), t_root.unsqueeze(0)
        else:
            parent = chain.link_parent[level]
            Rp, tp = R_world[parent], t_world[parent]
        R_world.index_copy_(0, level, _mm(Rp, R_loc[level]))
        t_world.index_copy_(0, level, tp + _mv(Rp, t_loc[level]))
    if not need_joints:
        return R_world, t_world, None, None
    parent_of_joint = chain.link_parent[chain.joint_link]  # (D,)
    is_root = (parent_of_joint < 0).to(q.dtype).view(D, 1, 1)
    pj = parent_of_joint.clamp(min=0)
    # Joints on the root link hang off the root pose, the others off their link's parent.
    Rp = R_world[pj] * (1 - is_root.unsqueeze(-1)) + R_root.unsqueeze(0) * is_root.unsqueeze(-1)
    tp = t_world[pj] * (1 - is_root) + t_root.unsqueeze(0) * is_root
    axis_w = _mv(Rp, axis_p)
    anchor_w = _mv(Rp, anchor_p) + tp
    return R_world, t_world, axis_w, anchor_w


def _homogeneous(R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Batch-last (L, 3, 3, B), (L, 3, B) -> batch-first (B, L, 4, 4)."""
    L, B = R.shape[0], R.shape[-1]
    top = torch.cat([R, t.unsqueeze(2)], dim=2)  # (L, 3, 4, B)
    bottom = R.new_zeros(L, 1, 4, B)
    bottom[:, :, 3] = 1
    return torch.cat([top, bottom], dim=1).permute(3, 0, 1, 2).contiguous()


# On CPUs large batches run in chunks of this many columns so the batch-last working set stays in cache; measured
# on a 2-core machine at B = 65536 this is several times faster than one pass. GPUs take the whole batch at once.
CPU_CHUNK = 1024


def _chunked(fn, q: torch.Tensor, root: torch.Tensor, *rest):
    B = q.shape[0]
    if q.device.type != "cpu" or B <= CPU_CHUNK:
        return fn(q, root, *rest)
    parts = [fn(q[i:i + CPU_CHUNK], root[i:i + CPU_CHUNK], *[r[i:i + CPU_CHUNK] if _per_batch(r, B) else r
                                                               for r in rest])
             for i in range(0, B, CPU_CHUNK)]
    if isinstance(parts[0], torch.Tensor):
        return torch.cat(parts)
    return tuple(torch.cat(z) for z in zip(*parts))


def _per_batch(x, B: int) -> bool:
    return isinstance(x, torch.Tensor) and x.dim() == 3 and x.shape[0] == B


def forward_kinematics(chain: Chain, q: torch.Tensor, root: torch.Tensor) -> torch.Tensor:
    """World poses of all links.

    q:    joint values, (B, D), radians (hinge) or metres (slide)
    root: world pose of the root's parent frame, (B, 4, 4)
    returns: T_world_link, (B, L, 4, 4)
    """
    def one(q, root):
        R, t, _, _ = _kinematics(chain, q, root, need_joints=False)
        return _homogeneous(R, t)

    return _chunked(one, q, root)


def joint_frames(chain: Chain, q: torch.Tensor, root: torch.Tensor):
    """Link poses plus the world axis and anchor of every joint.

    returns: (T_world_link (B, L, 4, 4), axis_world (B, D, 3) unit, anchor_world (B, D, 3) metres)
    """
    def one(q, root):
        R, t, axis, anchor = _kinematics(chain, q, root, need_joints=True)
        return _homogeneous(R, t), axis.permute(2, 0, 1), anchor.permute(2, 0, 1)

    return _chunked(one, q, root)


def fk_and_point_jacobian(
    chain: Chain,
    q: torch.Tensor,
    root: torch.Tensor,
    link_index: torch.Tensor,
    points_local: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Link poses, world positions of link-fixed points and their analytic Jacobian, in one pass.

    q:            (B, D), radians / metres
    root:         (B, 4, 4)
    link_index:   link of each point, (P,), long
    points_local: points in their link's frame, (P, 3) or (B, P, 3), metres
    returns: (T_world_link (B, L, 4, 4), points_world (B, P, 3) metres,
              jacobian (B, P, 3, D) metres per radian (hinge) / per metre (slide))
    """
    return _chunked(lambda q, root, p: _fk_and_point_jacobian(chain, q, root, link_index, p), q, root, points_local)


def _fk_and_point_jacobian(chain, q, root, link_index, points_local):
    R, t, axis, anchor = _kinematics(chain, q, root, need_joints=True)  # batch-last
    x, J = _points_and_jacobian(chain, R, t, axis, anchor, link_index, points_local)
    return _homogeneous(R, t), x, J


def _points_and_jacobian(chain, R, t, axis, anchor, link_index, points_local):
    """World points (B, P, 3) and their Jacobian (B, P, 3, D) from batch-last frames (:func:`_kinematics`)."""
    B, D = R.shape[-1], axis.shape[0]
    p = points_local.to(R)
    p = p.unsqueeze(-1) if p.dim() == 2 else p.permute(1, 2, 0)  # (P, 3, 1 | B)
    x = _mv(R[link_index], p) + t[link_index]  # (P, 3, B)
    # Only the joints that move a point's link contribute: gather those (S per point), fill the rest with zeros.
    sj = chain.support_joints[link_index]  # (P, S), -1 = padding
    valid = (sj >= 0).to(R.dtype).view(*sj.shape, 1, 1)
    sjc = sj.clamp(min=0)
    a = axis[sjc] * valid  # (P, S, 3, B)
    r = x.unsqueeze(1) - anchor[sjc]
    cross = torch.stack([a[:, :, 1] * r[:, :, 2] - a[:, :, 2] * r[:, :, 1],
                         a[:, :, 2] * r[:, :, 0] - a[:, :, 0] * r[:, :, 2],
                         a[:, :, 0] * r[:, :, 1] - a[:, :, 1] * r[:, :, 0]], dim=2)
    hinge = (chain.joint_type[sjc] == JOINT_HINGE).to(R.dtype).view(*sj.shape, 1, 1)
    cols = cross * hinge + a * (1 - hinge)  # (P, S, 3, B)
    P, S = sj.shape
    J = R.new_zeros(B, P, 3, D)
    index = sjc.view(1, P, 1, S).expand(B, P, 3, S)
    J = J.scatter_add(3, index, cols.permute(3, 0, 2, 1))
    return x.permute(2, 0, 1), J


class Frames(NamedTuple):
    """One forward-kinematics pass kept for later point Jacobians (:func:`frames`, :func:`frames_point_jacobian`).

    poses: T_world_link, (B, L, 4, 4); the rest batch-last: R (L, 3, 3, B), t (L, 3, B), axis and anchor of every
    joint in the world (D, 3, B)
    """

    poses: torch.Tensor
    R: torch.Tensor
    t: torch.Tensor
    axis: torch.Tensor
    anchor: torch.Tensor


def frames(chain: Chain, q: torch.Tensor, root: torch.Tensor) -> Frames:
    """Link poses and joint axes in one pass, for several :func:`frames_point_jacobian` calls at one configuration.

    q: (B, D); root: (B, 4, 4). Not chunked (meant for the small batches of a simulation step).
    """
    R, t, axis, anchor = _kinematics(chain, q, root, need_joints=True)
    return Frames(_homogeneous(R, t), R, t, axis, anchor)


def frames_point_jacobian(chain: Chain, fr: Frames, link_index: torch.Tensor,
                          points_local: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`point_jacobian` at the configuration of ``fr`` (:func:`frames`), without repeating the kinematics:
    (points_world (B, P, 3), jacobian (B, P, 3, D)); the same arithmetic, so the same values."""
    return _points_and_jacobian(chain, fr.R, fr.t, fr.axis, fr.anchor, link_index, points_local)


def point_jacobian(
    chain: Chain,
    q: torch.Tensor,
    root: torch.Tensor,
    link_index: torch.Tensor,
    points_local: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Analytic Jacobian of points fixed on links: (points_world (B, P, 3), jacobian (B, P, 3, D)).

    See :func:`fk_and_point_jacobian` for the arguments.
    """
    _, x, J = fk_and_point_jacobian(chain, q, root, link_index, points_local)
    return x, J
