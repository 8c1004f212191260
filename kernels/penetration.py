"""Hand-object penetration by SDF sampling and finger-finger interpenetration of capsules.

Pure tensor math (imports torch and math, plus the sibling kernel :mod:`.sdf`). Conventions: metres;
column-vector 4x4 transforms ``p_world = T_world_link @ p_link``; the SDF is negative inside the object and its
gradient points out of the object. Every function takes one explicit leading batch dimension ``B``.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from .sdf import sdf_trilinear_with_grad

__all__ = [
    "PenetrationResult",
    "CapsuleResult",
    "link_sample_penetration",
    "capsule_interpenetration",
    "closest_points_segment_segment",
]


class PenetrationResult(NamedTuple):
    """Signed distances of link samples to an object, and the deepest sample of every link.

    sd: signed distance of every sample, (B, S), metres, negative inside the object
    deepest_value: smallest ``sd`` over each link's samples, (B, L), metres; +inf for links without samples
    deepest_index: sample index of that minimum, (B, L), long; -1 for links without samples
    deepest_point: world position of that sample, (B, L, 3), metres; 0 for links without samples
    deepest_normal: unit SDF gradient there, rotated to world, (B, L, 3); points out of the object; 0 for links
        without samples
    """

    sd: torch.Tensor
    deepest_value: torch.Tensor
    deepest_index: torch.Tensor
    deepest_point: torch.Tensor
    deepest_normal: torch.Tensor


class CapsuleResult(NamedTuple):
    """Interpenetration of capsule pairs.

    depth: r_i + r_j - segment distance, (B, Q), metres; positive = interpenetrating
    point_i: closest point on the axis segment of capsule i, (B, Q, 3), world, metres
    point_j: closest point on the axis segment of capsule j, (B, Q, 3), world, metres
    """

    depth: torch.Tensor
    point_i: torch.Tensor
    point_j: torch.Tensor


def link_sample_penetration(
    link_poses: torch.Tensor,
    sample_points: torch.Tensor,
    sample_link: torch.Tensor,
    T_obj_world: torch.Tensor,
    sdf_values: torch.Tensor,
    sdf_origin: torch.Tensor,
    voxel_size: float,
    *,
    corners: torch.Tensor | None = None,
) -> PenetrationResult:
    """Signed distances of link surface samples to an object, and each link's deepest sample.

    Args:
        link_poses: link poses ``T_world_link``, (B, L, 4, 4), world, metres
        sample_points: sample positions in their link's frame, (S, 3), metres
        sample_link: link index of every sample, (S,), long in [0, L)
        T_obj_world: inverse object pose (world -> object frame), (B, 4, 4)
        sdf_values, sdf_origin, voxel_size: the object's SDF grid in the object frame (see
            :func:`torchhand.kernels.sdf.sdf_trilinear`): (Nx, Ny, Nz) metres, (3,) metres, float metres
        corners: optional ``pack_corners(sdf_values)`` for a faster query

    Returns:
        :class:`PenetrationResult`. ``sd`` and ``deepest_value`` are differentiable w.r.t. ``link_poses`` and
        ``T_obj_world``; indices, points and normals are not meant for gradients.
    """
    if link_poses.dim() != 4 or tuple(link_poses.shape[-2:]) != (4, 4):
        raise ValueError(f"link_poses: expected shape (B, L, 4, 4), got {tuple(link_poses.shape)}")
    b, n_links = link_poses.shape[:2]
    if sample_points.dim() != 2 or sample_points.shape[-1] != 3:
        raise ValueError(f"sample_points: expected shape (S, 3), got {tuple(sample_points.shape)}")
    s = sample_points.shape[0]
    if tuple(sample_link.shape) != (s,) or sample_link.dtype != torch.long:
        raise ValueError(f"sample_link: expected a long tensor of shape ({s},), got {tuple(sample_link.shape)} "
                         f"{sample_link.dtype}")
    if tuple(T_obj_world.shape) != (b, 4, 4):
        raise ValueError(f"T_obj_world: expected shape ({b}, 4, 4), got {tuple(T_obj_world.shape)}")

    if s and bool((sample_link[1:] >= sample_link[:-1]).all()):
        return _sorted_link_penetration(link_poses, sample_points, sample_link, T_obj_world, sdf_values,
                                        sdf_origin, voxel_size, corners)
    R_link = link_poses[:, sample_link, :3, :3]                    # (B, S, 3, 3)
    p_world = (R_link @ sample_points.unsqueeze(-1)).squeeze(-1) + link_poses[:, sample_link, :3, 3]
    R_ow, t_ow = T_obj_world[:, None, :3, :3], T_obj_world[:, None, :3, 3]
    p_obj = (R_ow @ p_world.unsqueeze(-1)).squeeze(-1) + t_ow       # (B, S, 3)
    sd, grad_obj = sdf_trilinear_with_grad(sdf_values, sdf_origin, voxel_size, p_obj, corners=corners)

    index = sample_link.expand(b, s)
    inf = torch.full((b, n_links), float("inf"), dtype=sd.dtype, device=sd.device)
    deepest_value = inf.scatter_reduce(1, index, sd, reduce="amin", include_self=True)
    # argmin per link: smallest sample index whose sd equals its link's minimum (S = none)
    is_min = sd.detach() == deepest_value.detach().gather(1, index)
    arange = torch.arange(s, device=sd.device).expand(b, s)
    candidate = torch.where(is_min, arange, torch.full_like(arange, s))
    first = torch.full((b, n_links), s, dtype=torch.long, device=sd.device)
    first = first.scatter_reduce(1, index, candidate, reduce="amin", include_self=True)
    has = first < s
    deepest_index = torch.where(has, first, torch.full_like(first, -1))
    safe = torch.where(has, first, torch.zeros_like(first))
    mask = has.unsqueeze(-1).to(sd.dtype)
    gather3 = safe.unsqueeze(-1).expand(b, n_links, 3)
    deepest_point = p_world.detach().gather(1, gather3) * mask
    g = grad_obj.gather(1, gather3)
    n_world = (T_obj_world[:, None, :3, :3].detach().transpose(-1, -2) @ g.unsqueeze(-1)).squeeze(-1)
    norm = torch.linalg.vector_norm(n_world, dim=-1, keepdim=True)
    deepest_normal = n_world / norm.clamp_min(torch.finfo(sd.dtype).tiny) * mask
    return PenetrationResult(sd, deepest_value, deepest_index, deepest_point, deepest_normal)


def _sorted_link_penetration(link_poses, sample_points, sample_link, T_obj_world, sdf_values, sdf_origin,
                             voxel_size, corners) -> PenetrationResult:
    """:func:`link_sample_penetration` for samples stored link by link (``sample_link`` non-decreasing, as hand
    models store them): each link's samples are a contiguous slice, transformed by one batched matrix product
    with the composed object-from-link pose, and reduced per slice; no (B, S, 3, 3) gather of rotations and no
    scatter over all samples. Same results (ties of the minimum resolve to the first sample, as there)."""
    b, n_links = link_poses.shape[:2]
    M = T_obj_world[:, None] @ link_poses                          # (B, L, 4, 4) object <- link
    counts = torch.bincount(sample_link, minlength=n_links).tolist()
    chunks, start = [], 0
    for link, n in enumerate(counts):
        if n:
            pts = sample_points[start:start + n]                   # (n, 3)
            chunks.append(pts @ M[:, link, :3, :3].transpose(-1, -2) + M[:, link, None, :3, 3])
        start += n
    p_obj = torch.cat(chunks, 1)                                   # (B, S, 3)
    sd, grad_obj = sdf_trilinear_with_grad(sdf_values, sdf_origin, voxel_size, p_obj, corners=corners)
    values, index, start = [], [], 0
    inf = torch.full((b,), float("inf"), dtype=sd.dtype, device=sd.device)
    minus = torch.full((b,), -1, dtype=torch.long, device=sd.device)
    for n in counts:
        if n:
            v, i = sd[:, start:start + n].min(dim=1)
            values.append(v)
            index.append(i + start)
        else:
            values.append(inf)
            index.append(minus)
        start += n
    deepest_value = torch.stack(values, 1)                         # (B, L)
    deepest_index = torch.stack(index, 1)
    has = deepest_index >= 0
    safe = deepest_index.clamp_min(0)
    mask = has.unsqueeze(-1).to(sd.dtype)
    local = sample_points[safe]                                    # (B, L, 3)
    deepest_point = ((link_poses[..., :3, :3].detach() @ local.unsqueeze(-1)).squeeze(-1)
                     + link_poses[..., :3, 3].detach()) * mask
    g = grad_obj.gather(1, safe.unsqueeze(-1).expand(b, n_links, 3))
    n_world = (T_obj_world[:, None, :3, :3].detach().transpose(-1, -2) @ g.unsqueeze(-1)).squeeze(-1)
    norm = torch.linalg.vector_norm(n_world, dim=-1, keepdim=True)
    deepest_normal = n_world / norm.clamp_min(torch.finfo(sd.dtype).tiny) * mask
    return PenetrationResult(sd, deepest_value, deepest_index, deepest_point, deepest_normal)


def capsule_interpenetration(
    link_poses: torch.Tensor,
    capsule_a: torch.Tensor,
    capsule_b: torch.Tensor,
    capsule_radius: torch.Tensor,
    pairs: torch.Tensor,
) -> CapsuleResult:
    """Interpenetration depth of capsule pairs (finger-finger collisions).

    Args:
        link_poses: link poses ``T_world_link``, (B, L, 4, 4), world, metres
        capsule_a: first end of each link's capsule axis, (L, 3), link frame, metres
        capsule_b: second end of each link's capsule axis, (L, 3), link frame, metres (may equal ``capsule_a``:
            a sphere)
        capsule_radius: capsule radii, (L,), metres
        pairs: link index pairs (i, j) to test, (Q, 2), long

    Returns:
        :class:`CapsuleResult` (depth (B, Q) positive when interpenetrating, closest axis points (B, Q, 3) each);
        differentiable w.r.t. ``link_poses`` (piecewise: the closest-point parameters switch between clamped
        and interior cases).
    """
    if link_poses.dim() != 4 or tuple(link_poses.shape[-2:]) != (4, 4):
        raise ValueError(f"link_poses: expected shape (B, L, 4, 4), got {tuple(link_poses.shape)}")
    n_links = link_poses.shape[1]
    for name, t in (("capsule_a", capsule_a), ("capsule_b", capsule_b)):
        if tuple(t.shape) != (n_links, 3):
            raise ValueError(f"{name}: expected shape ({n_links}, 3), got {tuple(t.shape)}")
    if tuple(capsule_radius.shape) != (n_links,):
        raise ValueError(f"capsule_radius: expected shape ({n_links},), got {tuple(capsule_radius.shape)}")
    if pairs.dim() != 2 or pairs.shape[-1] != 2 or pairs.dtype != torch.long:
        raise ValueError(f"pairs: expected a long tensor of shape (Q, 2), got {tuple(pairs.shape)} {pairs.dtype}")

    R, t = link_poses[..., :3, :3], link_poses[..., :3, 3]
    a_w = (R @ capsule_a.unsqueeze(-1)).squeeze(-1) + t              # (B, L, 3)
    b_w = (R @ capsule_b.unsqueeze(-1)).squeeze(-1) + t
    i, j = pairs[:, 0], pairs[:, 1]
    c1, c2 = closest_points_segment_segment(a_w[:, i], b_w[:, i], a_w[:, j], b_w[:, j])
    dist = torch.linalg.vector_norm(c1 - c2, dim=-1)
    depth = capsule_radius[i] + capsule_radius[j] - dist
    return CapsuleResult(depth, c1, c2)


def closest_points_segment_segment(
    p1: torch.Tensor, q1: torch.Tensor, p2: torch.Tensor, q2: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Closest points between segments [p1, q1] and [p2, q2], all (..., 3) -> two (..., 3).

    Ericson, Real-Time Collision Detection, 5.1.9, branch-free: degenerate segments (points) and parallel
    segments (any closest pair is returned) are handled; the result is never NaN for finite input.
    """
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a = (d1 * d1).sum(-1)
    e = (d2 * d2).sum(-1)
    f = (d2 * r).sum(-1)
    c = (d1 * r).sum(-1)
    bb = (d1 * d2).sum(-1)
    eps = torch.finfo(a.dtype).eps
    tiny = torch.finfo(a.dtype).tiny
    deg1 = a <= eps * (a + e) + tiny
    deg2 = e <= eps * (a + e) + tiny
    a_safe = torch.where(deg1, torch.ones_like(a), a)
    e_safe = torch.where(deg2, torch.ones_like(e), e)
    denom = a * e - bb * bb
    parallel = denom <= eps * a * e * 16
    s = torch.where(parallel, torch.zeros_like(a), ((bb * f - c * e) / torch.where(parallel, torch.ones_like(a), denom)))
    s = s.clamp(0.0, 1.0)
    t = (bb * s + f) / e_safe
    # t outside [0, 1]: clamp t and recompute s for the clamped t
    t_c = t.clamp(0.0, 1.0)
    s_re = ((bb * t_c - c) / a_safe).clamp(0.0, 1.0)
    s = torch.where((t < 0) | (t > 1), s_re, s)
    t = t_c
    # degenerate cases
    s = torch.where(deg1, torch.zeros_like(s), s)
    t = torch.where(deg1 & ~deg2, (f / e_safe).clamp(0.0, 1.0), t)
    s = torch.where(deg2 & ~deg1, (-c / a_safe).clamp(0.0, 1.0), s)
    t = torch.where(deg2, torch.zeros_like(t), t)
    return p1 + d1 * s.unsqueeze(-1), p2 + d2 * t.unsqueeze(-1)
