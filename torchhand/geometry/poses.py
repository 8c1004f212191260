"""Pose trajectories: interpolation at new times, Gaussian smoothing, quaternion helpers.

Poses are (T, 4, 4) rigid transforms, float64; quaternions are (..., 4) in kornia's (w, x, y, z) order.
"""

from __future__ import annotations

import math

import torch
from kornia.geometry.conversions import quaternion_to_rotation_matrix, rotation_matrix_to_quaternion


__all__ = ["interpolate_poses", "smooth_poses", "matrix_to_quat", "quat_to_matrix", "slerp"]


def _interpolate_linear(x: torch.Tensor, times: torch.Tensor, new_times: torch.Tensor) -> torch.Tensor:
    """Linear interpolation of samples ``x (T, C)`` at increasing ``times (T,)`` to ``new_times (N,)`` (clamped to
    the sampled range). Returns (N, C), dtype and device of ``x``."""
    T = x.shape[0]
    new_times = new_times.to(dtype=x.dtype, device=x.device)
    times = times.to(dtype=x.dtype, device=x.device)
    if T == 1:
        return x.expand(new_times.shape[0], x.shape[1]).clone()
    t = new_times.clamp(times[0], times[-1])
    i0 = (torch.searchsorted(times, t, right=True) - 1).clamp(0, T - 2)
    w = ((t - times[i0]) / (times[i0 + 1] - times[i0])).clamp(0.0, 1.0)[:, None]
    return x[i0] + w * (x[i0 + 1] - x[i0])


def interpolate_poses(poses: torch.Tensor, times: torch.Tensor, new_times: torch.Tensor) -> torch.Tensor:
    """Sample rigid poses at ``new_times``: positions linearly, rotations by quaternion slerp.

    Args:
        poses: poses at ``times``, (T, 4, 4)
        times: increasing sample times, (T,), seconds
        new_times: query times, (N,), seconds; clamped to ``[times[0], times[-1]]``

    Returns:
        poses at ``new_times``, (N, 4, 4), dtype and device of ``poses``
    """
    T = poses.shape[0]
    new_times = new_times.to(dtype=poses.dtype, device=poses.device)
    times = times.to(dtype=poses.dtype, device=poses.device)
    if T == 1:
        return poses.expand(new_times.shape[0], 4, 4).clone()
    t = new_times.clamp(times[0], times[-1])
    i0 = (torch.searchsorted(times, t, right=True) - 1).clamp(0, T - 2)
    w = ((t - times[i0]) / (times[i0 + 1] - times[i0])).clamp(0.0, 1.0)
    p0, p1 = poses[i0, :3, 3], poses[i0 + 1, :3, 3]
    q = slerp(matrix_to_quat(poses[i0, :3, :3]), matrix_to_quat(poses[i0 + 1, :3, :3]), w)
    out = torch.zeros(new_times.shape[0], 4, 4, dtype=poses.dtype, device=poses.device)
    out[:, :3, :3] = quat_to_matrix(q)
    out[:, :3, 3] = p0 + w[:, None] * (p1 - p0)
    out[:, 3, 3] = 1.0
    return out


def smooth_poses(poses: torch.Tensor, sigma_frames: float) -> torch.Tensor:
    """Gaussian low-pass filter of a pose trajectory: positions averaged with the weights, rotations by the
    normalised weighted sum of quaternions sign-aligned to the centre frame's (the chordal mean, accurate for the
    small spread within a few frames). The kernel spans +-3 sigma and is renormalised at the ends of the clip.

    Args:
        poses: (T, 4, 4) rigid poses
        sigma_frames: standard deviation in frames (> 0)

    Returns:
        (T, 4, 4) smoothed poses, dtype and device of ``poses``
    """
    T = poses.shape[0]
    half = max(1, int(math.ceil(3.0 * sigma_frames)))
    k = torch.arange(-half, half + 1, dtype=poses.dtype, device=poses.device)
    kernel = torch.exp(-0.5 * (k / sigma_frames) ** 2)                             # (W,)
    idx = torch.arange(T, device=poses.device)[:, None] + k.long()[None]           # (T, W)
    valid = (idx >= 0) & (idx < T)
    w = kernel[None] * valid.to(poses.dtype)
    w = w / w.sum(-1, keepdim=True)
    idx = idx.clamp(0, T - 1)
    p = (w[..., None] * poses[idx, :3, 3]).sum(1)
    q = matrix_to_quat(poses[:, :3, :3])                                         # (T, 4)
    qn = q[idx]                                                                   # (T, W, 4)
    sign = torch.where((qn * q[:, None]).sum(-1, keepdim=True) < 0, -1.0, 1.0).to(poses.dtype)
    qm = (w[..., None] * sign * qn).sum(1)
    out = torch.zeros_like(poses)
    out[:, :3, :3] = quat_to_matrix(qm / qm.norm(dim=-1, keepdim=True))
    out[:, :3, 3] = p
    out[:, 3, 3] = 1.0
    return out


def matrix_to_quat(R: torch.Tensor) -> torch.Tensor:
    """Unit quaternions (w, x, y, z) of rotation matrices (..., 3, 3), by kornia."""
    eps = 1e-12 if R.dtype == torch.float64 else 1e-7
    q = rotation_matrix_to_quaternion(R.contiguous(), eps=eps)
    return q / q.norm(dim=-1, keepdim=True)


def quat_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (..., 3, 3) of quaternions (w, x, y, z), normalised first, by kornia."""
    return quaternion_to_rotation_matrix(q / q.norm(dim=-1, keepdim=True))


def slerp(q0: torch.Tensor, q1: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Shortest-arc spherical interpolation of unit quaternions (N, 4) with weights (N,)."""
    dot = (q0 * q1).sum(-1)
    q1 = torch.where(dot[:, None] < 0, -q1, q1)
    dot = dot.abs().clamp(max=1.0)
    theta = torch.acos(dot)
    s = torch.sin(theta)
    near = s < 1e-6
    s_safe = torch.where(near, torch.ones_like(s), s)
    a = torch.where(near, 1 - w, torch.sin((1 - w) * theta) / s_safe)
    b = torch.where(near, w, torch.sin(w * theta) / s_safe)
    q = a[:, None] * q0 + b[:, None] * q1
    return q / q.norm(dim=-1, keepdim=True)
