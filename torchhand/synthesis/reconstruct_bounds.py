"""The table, finger-finger and joint-speed bounds of the spacetime reconstruction (:mod:`.reconstruct`).

None is in Ye & Liu's Eq. 9 (which keeps contacts and removes hand-object penetration); all are what a written
motion is checked against.

* Table: no finger link's collision capsule may reach below the table plane ``z = table``. A capsule whose lowest
  point comes within ``margin`` of the plane gets a one-sided point constraint on its lower segment end:
  ``z(end) >= table + radius + margin`` (normal +z), added in the collision rounds like the object's.
* Fingers: smoothing one finger's trajectory can move it into its neighbour (up to 9 mm on box-turn's paths). Two
  overlapping capsules of different fingers get one-sided constraints that push each one's closest axis point away
  from the other's by half the overlap plus the margin (the fingers are solved independently, so each is pushed
  against where the other is now; the rounds repeat until no pair overlaps).
* Joint speed: ``|q[t+1, j] - q[t, j]| <= step`` for every finger joint, a linear inequality per pair of frames,
  handled with the same augmented Lagrangian as the point constraints: the penalty
  ``rho/2 max(0, lam/rho - g)^2`` for ``g = step -+ (x[t+1] - x[t]) >= 0``, exact in the normal equations since the
  constraint is linear. The bound is applied at ``SPEED_MARGIN`` of the requested step so that the penalty's
  small residual stays inside the requested bound.

Layouts follow :mod:`.reconstruct`: a window's finger-local joints ``xl`` are (F, S, n) (F fingers, S frames, n
joints per finger, time-major index ``t * n + j`` when flat), radians.
"""

from __future__ import annotations

import torch

__all__ = ["SPEED_MARGIN", "table_depth", "table_constraint_parts", "ground_capsule_depth", "ground_constraint_parts",
           "finger_pair_parts", "speed_values", "speed_terms", "speed_penalty", "speed_update"]

SPEED_MARGIN = 0.97
"""The reconstruction bounds joint steps at this fraction of the requested bound."""


def table_depth(hand, poses: torch.Tensor, table: float) -> torch.Tensor:
    """How far each link's capsule reaches below the plane z = ``table``, (T, L) metres (<= 0 above), from link
    poses (T, L, 4, 4)."""
    R, o = poses[..., :3, :3], poses[..., :3, 3]
    za = (R @ hand.capsule_a.unsqueeze(-1)).squeeze(-1)[..., 2] + o[..., 2]
    zb = (R @ hand.capsule_b.unsqueeze(-1)).squeeze(-1)[..., 2] + o[..., 2]
    return table - (torch.minimum(za, zb) - hand.capsule_radius)


def ground_capsule_depth(ground, hand, poses: torch.Tensor):
    """How deep each link's capsule reaches into the table block and under the floor (``ground``, a
    :class:`~torchhand.geometry.ground.Ground`), (T, L) metres (<= 0 clear; -inf without solids), from link poses
    (T, L, 4, 4); with the deepest axis point (T, L, 3) world and the solids' outward normal there (T, L, 3)."""
    R, o = poses[..., :3, :3], poses[..., :3, 3]
    wa = (R @ hand.capsule_a.unsqueeze(-1)).squeeze(-1) + o
    wb = (R @ hand.capsule_b.unsqueeze(-1)).squeeze(-1) + o
    return ground.capsule_depth(wa, wb, hand.capsule_radius)


def ground_constraint_parts(ground, hand, poses: torch.Tensor, links: torch.Tensor, margin: float):
    """One-sided constraints keeping the capsules of ``links`` (M,) out of ``ground``'s solids, for those within
    ``margin`` of them: local point (T, M, 3) (the deepest axis point), target (T, M, 3) world (that point moved
    along the solids' normal to ``radius + margin`` from them), normal (T, M, 3) and mask (T, M) bool."""
    P = poses[:, links]                                                          # (T, M, 4, 4)
    depth, world, normal = ground_capsule_depth(ground, _Links(hand, links), P)
    R, o = P[..., :3, :3], P[..., :3, 3]
    local = (R.transpose(-1, -2) @ (world - o).unsqueeze(-1)).squeeze(-1)
    mask = depth > -margin
    target = world + (depth + margin).clamp_min(0)[..., None] * normal
    return local, target, normal, mask & torch.isfinite(depth)


class _Links:
    """The capsule fields of a subset of a hand's links (for :func:`ground_capsule_depth`)."""

    def __init__(self, hand, links: torch.Tensor):
        self.capsule_a, self.capsule_b = hand.capsule_a[links], hand.capsule_b[links]
        self.capsule_radius = hand.capsule_radius[links]


def table_constraint_parts(hand, poses: torch.Tensor, links: torch.Tensor, table: float, margin: float):
    """One-sided table constraints for the capsules of ``links`` (M,) that come within ``margin`` of the plane:
    local point (T, M, 3) (the lower capsule end), target (T, M, 3) world (that point lifted to
    ``table + radius + margin``), normal (T, M, 3) (+z) and mask (T, M) bool."""
    P = poses[:, links]                                                          # (T, M, 4, 4)
    a, b, r = hand.capsule_a[links], hand.capsule_b[links], hand.capsule_radius[links]
    wa = (P[..., :3, :3] @ a.unsqueeze(-1)).squeeze(-1) + P[..., :3, 3]
    wb = (P[..., :3, :3] @ b.unsqueeze(-1)).squeeze(-1) + P[..., :3, 3]
    low_a = wa[..., 2] <= wb[..., 2]
    local = torch.where(low_a[..., None], a.expand_as(wa), b.expand_as(wb))
    world = torch.where(low_a[..., None], wa, wb)
    mask = world[..., 2] - r < table + margin
    target = world.clone()
    target[..., 2] = table + r + margin
    normal = torch.zeros_like(world)
    normal[..., 2] = 1.0
    return local, target, normal, mask


def speed_values(xl: torch.Tensor, step: float) -> torch.Tensor:
    """Constraint values g (F, S-1, n, 2) >= 0: ``step - d`` and ``step + d`` for d = x[t+1] - x[t]."""
    d = xl[:, 1:] - xl[:, :-1]
    return torch.stack([step - d, step + d], -1)


def speed_terms(xl: torch.Tensor, valid: torch.Tensor, step: float, lam: torch.Tensor, rho: float,
                active: torch.Tensor):
    """Normal-equation terms of the active speed constraints: H (F, S n, S n) and b (F, S n) to add, for the
    quadratic ``rho/2 (d - c)^2`` of each active side with c = step - lam/rho (upper) or -(step - lam/rho) (lower).

    xl (F, S, n); valid (F, n) bool; lam, active (F, S-1, n, 2)."""
    F, S, n = xl.shape
    sign = xl.new_tensor([1.0, -1.0])
    c = (step - lam / rho) * sign                                                 # (F, S-1, n, 2)
    a = (active & valid[:, None, :, None]).to(xl.dtype)
    w = rho * a.sum(-1)                                                           # (F, S-1, n)
    wc = rho * (a * c).sum(-1)                                                    # (F, S-1, n)
    H = xl.new_zeros(F, S, n, S, n)
    t = torch.arange(S - 1, device=xl.device)
    j = torch.arange(n, device=xl.device)
    tt, jj = torch.meshgrid(t, j, indexing="ij")
    H[:, tt, jj, tt, jj] += w
    H[:, tt + 1, jj, tt + 1, jj] += w
    H[:, tt, jj, tt + 1, jj] -= w
    H[:, tt + 1, jj, tt, jj] -= w
    b = xl.new_zeros(F, S, n)
    b[:, 1:] += wc
    b[:, :-1] -= wc
    return H.reshape(F, S * n, S * n), b.reshape(F, S * n)


def speed_penalty(xl: torch.Tensor, valid: torch.Tensor, step: float, lam: torch.Tensor, rho: float) -> torch.Tensor:
    """The augmented-Lagrangian penalty of the speed constraints per finger, (F,)."""
    g = speed_values(xl, step)
    pen = 0.5 * rho * (lam / rho - g).clamp_min(0) ** 2 * valid[:, None, :, None]
    return pen.sum((1, 2, 3))


def speed_update(xl: torch.Tensor, valid: torch.Tensor, step: float, lam: torch.Tensor, rho: float):
    """Multiplier step lam <- max(0, lam - rho g) and each finger's worst violation max(0, -g), (F,) radians."""
    g = speed_values(xl, step)
    worst = (-g * valid[:, None, :, None]).amax((1, 2, 3)).clamp_min(0) if g.numel() else xl.new_zeros(xl.shape[0])
    return (lam - rho * g).clamp_min(0), worst


def finger_pair_parts(hand, poses: torch.Tensor, movable: torch.Tensor, margin: float):
    """One-sided constraints that separate overlapping finger capsules (``hand.collision_pairs``), both links of a
    pair pushed apart along the line between their closest axis points, each by half the overlap plus ``margin``
    (all of it where the other link is not ``movable``).

    poses (T, L, 4, 4); movable (M,) link indices the reconstruction moves
    returns: overlap (T, Q) metres (> 0 overlapping), and for the 2 Q slots (each pair's first links, then its
    second links): link (T, 2Q) long, local (T, 2Q, 3) link frame, target (T, 2Q, 3) world, normal (T, 2Q, 3),
    mask (T, 2Q) bool (slots of overlapping pairs on movable links)
    """
    from torchhand.kernels.penetration import capsule_interpenetration

    pairs = hand.collision_pairs
    T = poses.shape[0]
    res = capsule_interpenetration(poses, hand.capsule_a, hand.capsule_b, hand.capsule_radius, pairs)
    depth, pa, pb = res[0], res[1], res[2]
    d = pa - pb
    n = d / d.norm(dim=-1, keepdim=True).clamp_min(1e-9)                         # (T, Q, 3) from b toward a
    can = torch.zeros(hand.num_links, dtype=torch.bool, device=poses.device)
    can[movable] = True
    ma, mb = can[pairs[:, 0]], can[pairs[:, 1]]                                  # (Q,)
    share_a = torch.where(mb, 0.5, 1.0).to(poses.dtype) * ma
    share_b = torch.where(ma, 0.5, 1.0).to(poses.dtype) * mb
    over = depth > 0
    push = depth.clamp_min(0) + margin
    link = torch.cat([pairs[:, 0], pairs[:, 1]]).expand(T, -1)
    point = torch.cat([pa, pb], 1)
    normal = torch.cat([n, -n], 1)
    target = point + (torch.cat([share_a * push, share_b * push], 1))[..., None] * normal
    P = poses.gather(1, link[..., None, None].expand(T, link.shape[1], 4, 4))
    R, o = P[..., :3, :3], P[..., :3, 3]
    local = (R.transpose(-1, -2) @ (point - o).unsqueeze(-1)).squeeze(-1)
    mask = torch.cat([over & ma, over & mb], 1)
    return depth, link, local, target, normal, mask
