"""The checker's own geometry of a table with an edge and a floor (``Environment.table_extent``, ``floor``).

Written apart from the synthesis' :mod:`torchhand.geometry.ground`, in float64 NumPy, from the scene's environment
fields alone:

* the table is the block ``[x_min, x_max] x [y_min, y_max] x (-inf, table_height]`` (an unbounded table is the half
  space under its plane), the floor the half space under ``floor_height``;
* a point's distance to the block: outside, the distance to its nearest point (the point clipped to the box);
  inside, minus the distance to the nearest face;
* a capsule's depth: ``radius - min over its axis of the distance to a solid``. For a plane the minimum is at an
  axis end. For the block the distance is convex along the axis, and its minimum is found by ternary search on the
  axis parameter to 1e-12 of the axis length.
"""

from __future__ import annotations

import numpy as np

__all__ = ["environment_point_depth", "environment_capsule_depth", "hand_environment_depth", "support_gap"]

_TERNARY_STEPS = 70


def _box_distance(p: np.ndarray, extent, top: float) -> np.ndarray:
    lo = np.array([extent[0], extent[2], -np.inf])
    hi = np.array([extent[1], extent[3], top])
    clipped = np.clip(p, lo, hi)
    outside = np.linalg.norm(np.where(np.isfinite(clipped), p - clipped, 0.0), axis=-1)
    to_face = np.stack([p[..., 0] - lo[0], hi[0] - p[..., 0], p[..., 1] - lo[1], hi[1] - p[..., 1],
                        hi[2] - p[..., 2]], -1).min(-1)
    return np.where(outside > 0, outside, -np.maximum(to_face, 0.0))


def _solids(env):
    """(kind, parameters) of the environment's solids: ("plane", z) and ("box", (extent, top))."""
    out = []
    if env.table:
        out.append(("plane", float(env.table_height)) if env.table_extent is None
                   else ("box", (tuple(env.table_extent), float(env.table_height))))
    if getattr(env, "floor", False):
        out.append(("plane", float(env.floor_height)))
    return out


def environment_point_depth(env, points: np.ndarray) -> np.ndarray:
    """How deep points (..., 3) lie inside the environment's solids, (...,) metres (negative: clearance; -inf
    without solids)."""
    depth = np.full(points.shape[:-1], -np.inf)
    for kind, par in _solids(env):
        d = par - points[..., 2] if kind == "plane" else -_box_distance(points, *par)
        depth = np.maximum(depth, d)
    return depth


def environment_capsule_depth(env, a: np.ndarray, b: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """How deep capsules (axis ends ``a``, ``b`` (..., 3), ``radius`` broadcastable) reach into the environment's
    solids, (...,) metres (negative: clearance; -inf without solids)."""
    depth = np.full(a.shape[:-1], -np.inf)
    for kind, par in _solids(env):
        if kind == "plane":
            d = par - np.minimum(a[..., 2], b[..., 2]) + radius
        else:
            lo, hi = np.zeros(a.shape[:-1]), np.ones(a.shape[:-1])
            f = lambda u: _box_distance(a + u[..., None] * (b - a), *par)   # noqa: E731
            for _ in range(_TERNARY_STEPS):
                m1, m2 = lo + (hi - lo) / 3.0, hi - (hi - lo) / 3.0
                left = f(m1) <= f(m2)
                lo, hi = np.where(left, lo, m1), np.where(left, m2, hi)
            dist = np.minimum(np.minimum(f(0.5 * (lo + hi)), f(np.zeros_like(lo))), f(np.ones_like(lo)))
            d = radius - dist
        depth = np.maximum(depth, d)
    return depth


def support_gap(env, points: np.ndarray) -> np.ndarray:
    """Height of points (..., 3) above the surface they would rest on (the table top over the table, the floor
    elsewhere), (...,) metres; +inf where there is nothing under them."""
    under = np.full(points.shape[:-1], -np.inf)
    if getattr(env, "floor", False):
        under[...] = float(env.floor_height)
    if env.table:
        if env.table_extent is None:
            over = np.ones(points.shape[:-1], dtype=bool)
        else:
            x0, x1, y0, y1 = env.table_extent
            x, y = points[..., 0], points[..., 1]
            over = (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
        under = np.where(over, float(env.table_height), under)
    return points[..., 2] - under


def hand_environment_depth(hand, env) -> np.ndarray | None:
    """Depth of a posed hand's capsules (``check.penetration.PosedHand``) in the environment's table and floor,
    (T, L) metres, NaN for links without geometry; None without a table or floor."""
    if not (env.table or getattr(env, "floor", False)):
        return None
    depth = environment_capsule_depth(env, hand.a, hand.b, hand.radius)
    return np.where(hand.radius > 0, depth, np.nan)
