"""The six compliant root coordinates: a root pose's displacement from its reference root pose, and back.

Coordinates (6,): rotation vector of R R_r^T (radians, applied on the left, about the root origin), then the
translation p - p_r (metres), the first six of the 6 + D generalized coordinates of
``torchhand.hand.dynamics.point_jacobian(..., wrt_root=True)``.
"""

from __future__ import annotations

import torch

from torchhand.kernels.spatial import exp_twist, so3_log

__all__ = ["root_displacement", "displace_root"]


def root_displacement(root: torch.Tensor, root_r: torch.Tensor) -> torch.Tensor:
    """The six root coordinates of ``root`` relative to ``root_r``: (rotation vector of R R_r^T, p - p_r), (B, 6)."""
    R = root[:, :3, :3] @ root_r[:, :3, :3].transpose(-1, -2)
    return torch.cat([so3_log(R), root[:, :3, 3] - root_r[:, :3, 3]], -1)


def displace_root(root_r: torch.Tensor, delta: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`root_displacement`: R = exp([d_omega]x) R_r, p = p_r + d_v. delta (B, 6) -> (B, 4, 4)."""
    rot = exp_twist(torch.cat([delta[:, :3], torch.zeros_like(delta[:, :3])], -1), 1.0)[:, :3, :3]
    out = root_r.clone()
    out[:, :3, :3] = rot @ root_r[:, :3, :3]
    out[:, :3, 3] = root_r[:, :3, 3] + delta[:, 3:]
    return out
