"""The static solids of a scene: a table (an unbounded plane, or a block under a rectangular top) and a floor.

A :class:`Ground` answers three questions, batched over any leading shape, in the tensors' dtype and device:

- where a point may rest (:meth:`Ground.support_height`): on the table top (inside its rectangle) or on the floor;
- how far a point is from the solids (:meth:`Ground.point_distance`): the signed distance to their union (negative
  inside) and the outward normal of the nearest one;
- how deep a capsule reaches into them (:meth:`Ground.capsule_depth`), with the point of its axis that reaches
  deepest: the least signed distance along a segment, found exactly for the planes (at an end) and by a golden-
  section search for the block (the signed distance of a convex set is convex along a segment).

The block under a rectangular top reaches down without end (or to the floor, which the union covers), so the
signed distance of a point to it is that of the box ``[x_min, x_max] x [y_min, y_max] x (-inf, table_height]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..errors import InputValueError

__all__ = ["Ground", "GOLDEN_ITERS"]

GOLDEN_ITERS = 48
"""Golden-section steps of the capsule-block search: the axis point is found to 0.618^48 (2e-10) of its length."""


def _finite(x, name: str) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
        raise InputValueError(f"Ground.{name}: expected a finite number, got {x!r}")
    return float(x)


@dataclass(frozen=True)
class Ground:
    """A table and a floor, world frame, metres, z up.

    Fields
        table_height: z of the table top, or None (no table)
        table_extent: ``(x_min, x_max, y_min, y_max)`` of the table top, or None (an unbounded plane: the table of
            every scene before floors existed)
        floor_height: z of the floor, or None (no floor); below the table top when both are given
    """

    table_height: float | None = None
    table_extent: tuple | None = None
    floor_height: float | None = None

    def __post_init__(self):
        if self.table_height is not None:
            object.__setattr__(self, "table_height", _finite(self.table_height, "table_height"))
        if self.floor_height is not None:
            object.__setattr__(self, "floor_height", _finite(self.floor_height, "floor_height"))
        if self.table_extent is not None:
            e = tuple(self.table_extent) if isinstance(self.table_extent, (tuple, list)) else ()
            if len(e) != 4:
                raise InputValueError(f"Ground.table_extent: expected (x_min, x_max, y_min, y_max), got "
                                      f"{self.table_extent!r}")
            e = tuple(_finite(v, "table_extent") for v in e)
            if not (e[0] < e[1] and e[2] < e[3]):
                raise InputValueError(f"Ground.table_extent: expected x_min < x_max and y_min < y_max, got {e}")
            if self.table_height is None:
                raise InputValueError("Ground.table_extent: given without a table_height")
            object.__setattr__(self, "table_extent", e)
        if self.table_height is not None and self.floor_height is not None:
            if self.table_extent is None:
                raise InputValueError("Ground: a floor needs a table with a table_extent (an unbounded table plane "
                                      "hides the floor)")
            if not self.floor_height < self.table_height:
                raise InputValueError(f"Ground.floor_height: expected below the table top {self.table_height}, "
                                      f"got {self.floor_height}")

    @property
    def plain(self) -> bool:
        """Only an unbounded table plane (or nothing): the case every method supports."""
        return self.table_extent is None and self.floor_height is None

    @property
    def empty(self) -> bool:
        return self.table_height is None and self.floor_height is None

    # -- points ---------------------------------------------------------------------------------------------------
    def on_table_top(self, p: torch.Tensor) -> torch.Tensor:
        """Whether points (..., 3) lie over the table top (inside its rectangle, edges included), (...,) bool."""
        if self.table_height is None:
            return torch.zeros(p.shape[:-1], dtype=torch.bool, device=p.device)
        if self.table_extent is None:
            return torch.ones(p.shape[:-1], dtype=torch.bool, device=p.device)
        x0, x1, y0, y1 = self.table_extent
        x, y = p[..., 0], p[..., 1]
        return (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)

    def support_height(self, p: torch.Tensor) -> torch.Tensor:
        """The height of the surface a point (..., 3) could rest on: the table top over the table, the floor
        elsewhere, -inf where there is neither, (...,)."""
        out = torch.full(p.shape[:-1], -math.inf, dtype=p.dtype, device=p.device)
        if self.floor_height is not None:
            out = torch.full_like(out, self.floor_height)
        if self.table_height is not None:
            out = torch.where(self.on_table_top(p), torch.full_like(out, self.table_height), out)
        return out

    def point_distance(self, p: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Signed distance (...,) of points (..., 3) to the union of the solids (negative inside; +inf without
        any) and the outward unit normal (..., 3) of the nearest solid there (its gradient)."""
        up = torch.zeros_like(p)
        up[..., 2] = 1.0
        sd = torch.full(p.shape[:-1], math.inf, dtype=p.dtype, device=p.device)
        normal = up
        if self.floor_height is not None:
            sd = p[..., 2] - self.floor_height
        if self.table_height is not None:
            if self.table_extent is None:
                st, nt = p[..., 2] - self.table_height, up
            else:
                st, nt = _block_distance(p, self.table_extent, self.table_height)
            nearer = st < sd
            sd, normal = torch.where(nearer, st, sd), torch.where(nearer[..., None], nt, normal)
        return sd, normal

    # -- capsules -------------------------------------------------------------------------------------------------
    def capsule_depth(self, a: torch.Tensor, b: torch.Tensor, radius: torch.Tensor):
        """How deep capsules (axis ``a``-``b`` (..., 3), ``radius`` broadcastable to (...)) reach into the solids,
        (...,) metres (<= 0: clearance), with the axis point (..., 3) that reaches deepest and the outward normal
        (..., 3) there. Without solids the depth is -inf."""
        best = torch.full(a.shape[:-1], -math.inf, dtype=a.dtype, device=a.device)
        point, normal = a, torch.zeros_like(a)
        normal[..., 2] = 1.0
        for height in (self.floor_height, self.table_height if self.table_extent is None else None):
            if height is None:
                continue
            low = torch.where((a[..., 2] <= b[..., 2])[..., None], a, b)
            d = height - low[..., 2] + radius
            deeper = d > best
            best, point = torch.where(deeper, d, best), torch.where(deeper[..., None], low, point)
        if self.table_extent is not None:
            s = _golden_min(lambda u: _block_distance(a + u[..., None] * (b - a), self.table_extent,
                                                      self.table_height)[0], a.shape[:-1], a)
            x = a + s[..., None] * (b - a)
            sd, nt = _block_distance(x, self.table_extent, self.table_height)
            d = radius - sd
            deeper = d > best
            best, point = torch.where(deeper, d, best), torch.where(deeper[..., None], x, point)
            normal = torch.where(deeper[..., None], nt, normal)
        return best, point, normal


def _block_distance(p: torch.Tensor, extent: tuple, top: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Signed distance (...,) and outward normal (..., 3) of points (..., 3) to the box ``extent`` x (-inf, top]."""
    x0, x1, y0, y1 = extent
    cx, cy, hx, hy = 0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.5 * (x1 - x0), 0.5 * (y1 - y0)
    dx, dy = p[..., 0] - cx, p[..., 1] - cy
    q = torch.stack([dx.abs() - hx, dy.abs() - hy, p[..., 2] - top], -1)          # (..., 3)
    sign = torch.stack([torch.where(dx < 0, -1.0, 1.0).to(p.dtype), torch.where(dy < 0, -1.0, 1.0).to(p.dtype),
                        torch.ones_like(dx)], -1)
    outside = q.clamp_min(0)
    out_len = outside.norm(dim=-1)
    inner = q.amax(-1)
    sd = out_len + inner.clamp_max(0)
    # gradient: outside, the direction from the nearest box point; inside, the axis of the nearest face
    # (a comparison, not one_hot: one_hot checks its indices on the host)
    face = (q.argmax(-1, keepdim=True) == torch.arange(3, device=p.device)).to(p.dtype)
    n_out = outside / out_len.clamp_min(1e-300)[..., None]
    normal = torch.where((out_len > 0)[..., None], n_out, face) * sign
    return sd, normal


def _golden_min(f, shape, like: torch.Tensor) -> torch.Tensor:
    """argmin over u in [0, 1] of a convex f (batched: f maps (shape) -> (shape)), by golden-section search."""
    g = (math.sqrt(5.0) - 1.0) / 2.0
    lo = torch.zeros(shape, dtype=like.dtype, device=like.device)
    hi = torch.ones_like(lo)
    for _ in range(GOLDEN_ITERS):
        m1, m2 = hi - g * (hi - lo), lo + g * (hi - lo)
        left = f(m1) <= f(m2)
        lo, hi = torch.where(left, lo, m1), torch.where(left, m2, hi)
    u = 0.5 * (lo + hi)
    # the ends themselves (a search on a flat stretch may stop short of a lower end)
    fu, f0, f1 = f(u), f(torch.zeros_like(u)), f(torch.ones_like(u))
    u = torch.where(f0 < fu, torch.zeros_like(u), u)
    return torch.where(f1 < torch.minimum(fu, f0), torch.ones_like(u), u)
