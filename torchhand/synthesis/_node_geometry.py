"""Geometry of the node test (:mod:`.node_test`): rigid transforms of points, the hand's pad points, contact slots,
edge proxies of fingertips, and penetration of the table and of finger capsules."""

from __future__ import annotations


import torch

from torchhand.kernels.frames import tangent_frame

from .reconstruct_bounds import ground_capsule_depth
from .reconstruct_bounds import table_depth as capsule_table_depth
from .problem import SynthesisProblem

from ._node_records import NodeTestSettings


def _transform(T: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """T (..., 4, 4) applied to points p (..., 3)."""
    return (T[..., :3, :3] @ p.unsqueeze(-1)).squeeze(-1) + T[..., :3, 3]


def _rotate(T: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    return (T[..., :3, :3] @ v.unsqueeze(-1)).squeeze(-1)


def pad_points(hand) -> torch.Tensor:
    """The fingertip pads on the collision surface: ``hand.fingertip`` projected onto its distal link's capsule,
    (F, 3), distal-link frame, metres. The search guides these points, so a guided fingertip touches the object
    with the same surface the contact checks see."""
    a, b = hand.capsule_a[hand.distal_link], hand.capsule_b[hand.distal_link]
    r = hand.capsule_radius[hand.distal_link]
    tip = hand.fingertip
    u = (((tip - a) * (b - a)).sum(-1) / ((b - a) * (b - a)).sum(-1).clamp_min(1e-12)).clamp(0, 1)
    axis = a + u[:, None] * (b - a)
    d = tip - axis
    return axis + r[:, None] * d / d.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def contact_slots(problem: SynthesisProblem) -> tuple[torch.Tensor, torch.Tensor]:
    """The hand-contact slots of a node test's outputs: K = H L + H F. Slot ``h L + l`` is link l of hand h (its
    closest surface sample); slot ``H L + h F + f`` is the area-contact proxy of finger f's fingertip on hand h.
    Returns (hand (K,) long, link (K,) long: the link within its hand)."""
    F = problem.F
    hands, links = [], []
    for h, hand in enumerate(problem.hands):
        L = hand.num_links
        hands.append(torch.full((L,), h, dtype=torch.long))
        links.append(torch.arange(L))
    for h, hand in enumerate(problem.hands):
        hands.append(torch.full((F,), h, dtype=torch.long))
        links.append(hand.distal_link.cpu())
    return torch.cat(hands).to(problem.device), torch.cat(links).to(problem.device)


def _edge_proxies(problem: SynthesisProblem, t: torch.Tensor, hand, poses: torch.Tensor, on: torch.Tensor,
                  point: torch.Tensor, normal: torch.Tensor, s: NodeTestSettings):
    """Area-contact proxies near sharp edges (Ye & Liu §7): "forces on a few proxy points in the neighborhood of
    an actual contact point, capturing the local features of geometry".

    For each fingertip contact (on (N, F), point and normal (N, F, 3) world, normal into the object), four points
    ``proxy_radius`` away along the surface's tangent directions are projected onto the surface (the grid's exact
    query near the surface, :meth:`~torchhand.geometry.sdf.SDFGrid.query_surface`); one
    counts where its normal turns by more than acos(``proxy_cos``) from the contact's (an edge or a corner is
    under the pad: on a flat face a proxy would add nothing) and the fingertip's capsule is within ``proxy_dist``
    of it (the pad covers it). The one whose normal turns most is kept. Returns mask (N, F), point (N, F, 3)
    world, normal (N, F, 3) into the object, local (N, F, 3) in the distal link's frame."""
    N, F = on.shape
    dl = hand.distal_link
    T_inv, T_obj = problem.object_inv[t], problem.object_pose[t]
    p0 = _transform(T_inv[:, None], point)                                  # object frame
    n0 = _rotate(T_inv[:, None], normal)
    t1, t2 = tangent_frame(n0 / n0.norm(dim=-1, keepdim=True).clamp_min(1e-9))
    x = p0[:, :, None] + s.proxy_radius * torch.stack([t1, -t1, t2, -t2], 2)    # (N, F, 4, 3)
    _, g, x = problem.sdf.query_surface(x.reshape(N, -1, 3))                # onto the surface (exact near it)
    x = x.reshape(N, F, 4, 3)
    sd, _, _ = problem.sdf.query_surface(x.reshape(N, -1, 3))               # ~0 unless the projection was a grid's
    # the normal where the pushed point projects: the direction from the surface to it (at an edge or a corner,
    # the one of its normal cone facing the push, e.g. the side face beyond a box's edge), not the cone's middle
    n_in = -g.reshape(x.shape)
    cos = (n_in * n0[:, :, None]).sum(-1)                                  # (N, F, 4)
    xw = _transform(T_obj[:, None, None], x)
    T_d = poses[:, dl]                                                      # (N, F, 4, 4)
    R_d, o_d = T_d[..., :3, :3], T_d[..., :3, 3]
    local = (R_d.transpose(-1, -2)[:, :, None] @ (xw - o_d[:, :, None]).unsqueeze(-1)).squeeze(-1)   # (N, F, 4, 3)
    a, b = hand.capsule_a[dl][:, None], hand.capsule_b[dl][:, None]         # (F, 1, 3)
    u = (((local - a) * (b - a)).sum(-1) / ((b - a) * (b - a)).sum(-1).clamp_min(1e-12)).clamp(0, 1)
    gap = (local - (a + u[..., None] * (b - a))).norm(dim=-1) - hand.capsule_radius[dl][:, None]
    ok = on[..., None] & (cos < s.proxy_cos) & (gap <= s.proxy_dist) & (gap >= -s.pen_tol) \
        & (sd.reshape(cos.shape).abs() <= 1e-4)
    pick = torch.where(ok, cos, torch.full_like(cos, 2.0)).argmin(-1, keepdim=True)   # (N, F, 1)
    mask = ok.any(-1)
    take = lambda v: v.gather(2, pick[..., None].expand(N, F, 1, 3)).squeeze(2)
    m3 = mask[..., None].to(point.dtype)
    return mask, take(xw) * m3, _rotate(T_obj[:, None], take(n_in)) * m3, take(local) * m3


def surface_contacts(problem: SynthesisProblem, t: torch.Tensor, point: torch.Tensor
                     ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Exact signed distance, closest surface point and inward normal of the object at world points ``point``
    (N, K, 3) of candidates at frames ``t`` (N,): the grid's exact query near the surface
    (:meth:`~torchhand.geometry.sdf.SDFGrid.query_surface`: the mesh's face normal on a face, the normal cone's
    direction toward the point at an edge). Returns sd (N, K) metres, surface point (N, K, 3) world, normal
    (N, K, 3) world, into the object."""
    sd, normal, closest = problem.sdf.query_surface(_transform(problem.object_inv[t][:, None], point))
    T = problem.object_pose[t][:, None]
    return sd, _transform(T, closest), -_rotate(T, normal)


def table_depth(problem: SynthesisProblem, hand, poses: torch.Tensor) -> torch.Tensor:
    """How far each link's collision capsule reaches below the table plane (or into the table block and under the
    floor, ``problem.ground``), (N, L) metres (<= 0 clear of them), from link poses (N, L, 4, 4). Zero everywhere
    without a table or floor."""
    if problem.ground is not None:
        return ground_capsule_depth(problem.ground, hand, poses)[0]
    if problem.table_height is None:
        return poses.new_zeros(poses.shape[:2])
    return capsule_table_depth(hand, poses, problem.table_height)


def _finger_depth(hand, deepest_value: torch.Tensor) -> torch.Tensor:
    """Deepest penetration of each finger's links, (N, F) metres (>= 0), from a link's smallest signed distance
    ``deepest_value`` (N, L). A float scatter (CUDA has no scatter_reduce for bool)."""
    lf = hand.link_finger
    N = deepest_value.shape[0]
    depth = (-deepest_value).clamp_min(0) * (lf >= 0).to(deepest_value.dtype)
    return deepest_value.new_zeros(N, hand.num_fingers).scatter_reduce(1, lf.clamp_min(0).expand(N, -1), depth,
                                                                       reduce="amax")


def _axis_points(hand, per_link: int = 4):
    """Points along the capsule axis of every finger link: (link (P,) long, local (P, 3), radius (P,))."""
    links = hand.finger_links[hand.finger_links >= 0]
    u = torch.linspace(0, 1, per_link, dtype=hand.dtype, device=hand.device)
    a, b = hand.capsule_a[links], hand.capsule_b[links]                      # (M, 3)
    local = a[:, None] + u[None, :, None] * (b - a)[:, None]                 # (M, n, 3)
    return (links[:, None].expand(-1, per_link).reshape(-1), local.reshape(-1, 3),
            hand.capsule_radius[links][:, None].expand(-1, per_link).reshape(-1))


def capsule_point_facing(hand, poses: torch.Tensor, link: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """The point of each link's capsule that faces a world point: the capsule axis point closest to it, moved one
    radius toward it (a rolling contact's hand point, :class:`~._node_records.Guides`).

    poses: link poses (N, L, 4, 4); link: (N, M) long; target: (N, M, 3) world. Returns (N, M, 3) in each link's
    frame; where the target lies on the axis, the axis point (the point is then undefined)."""
    N, M = link.shape
    T = poses.gather(1, link[..., None, None].expand(N, M, 4, 4))
    R, p = T[..., :3, :3], T[..., :3, 3]
    tl = (R.transpose(-1, -2) @ (target - p).unsqueeze(-1)).squeeze(-1)
    a, b, r = hand.capsule_a[link], hand.capsule_b[link], hand.capsule_radius[link]
    ab = b - a
    s = (((tl - a) * ab).sum(-1) / (ab * ab).sum(-1).clamp_min(1e-18)).clamp(0, 1)
    c = a + s[..., None] * ab
    d = tl - c
    return c + r[..., None] * d / d.norm(dim=-1, keepdim=True).clamp_min(1e-12)
