"""Small frame helpers shared by the contact kernels (pure tensor math)."""

from __future__ import annotations

import torch

__all__ = ["tangent_frame"]


def tangent_frame(e0: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Two unit vectors completing the unit vectors e0 (..., 3) to a right-handed frame (Duff et al. 2017,
    branch-free). Returns (t1, t2), each (..., 3)."""
    x, y, z = e0.unbind(-1)
    sign = torch.where(z >= 0, torch.ones_like(z), -torch.ones_like(z))
    a = -1.0 / (sign + z)
    b = x * y * a
    t1 = torch.stack([1 + sign * x * x * a, sign * b, -sign * x], -1)
    t2 = torch.stack([b, sign + y * y * a, -y], -1)
    return t1, t2
