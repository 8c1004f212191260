"""The diversity of a synthesis result's solutions (docs/synthesis.md): the mean pairwise distance between their
guiding-point trajectories."""

from __future__ import annotations

import math

__all__ = ["diversity"]


def diversity(solutions: list) -> float:
    """Mean pairwise distance between the guiding-point trajectories of the solutions: the mean over frames and
    fingers of |p_a - p_b| (object frame, metres), a finger counted where either solution guides it (a missing
    guide counts as the object's origin). NaN with fewer than two solutions."""
    if len(solutions) < 2:
        return math.nan
    pts = [s.guide_obj * s.guiding[..., None] for s in solutions]
    on = [s.guiding for s in solutions]
    total, count = 0.0, 0
    for a in range(len(pts)):
        for b in range(a + 1, len(pts)):
            either = on[a] | on[b]
            d = (pts[a] - pts[b]).norm(dim=-1)
            total += float(d[either].mean()) if bool(either.any()) else 0.0
            count += 1
    return total / count
