"""Spatial (screw) algebra of Kry & Pai (2006) §6.1: adjoints, point maps, spatial cross products, the SE(3) map.

Pure batched tensor math (imports torch and math only). Every function takes one leading batch dimension ``B``;
dtype and device come from the inputs.

Conventions (the paper's, used by the quasi-static step)
    twist    phi = (omega, v), (B, 6): angular velocity (rad/s) first, then the linear velocity (m/s) of the body
             point that is at the ORIGIN of the frame the twist is written in.
    wrench   w = (tau, f), (B, 6): torque (N m) about that origin first, then force (N). The pairing phi^T w is
             power and is the same in every frame.
    pose     E = (Theta p; 0 1), (B, 4, 4), column-vector transforms: ``x_j = E_ji x_i``.
    adjoint  Ad(E_ji) = (Theta 0; [p]x Theta  Theta) maps twists from frame i to frame j; wrenches go the other way
             with its transpose: w_i = Ad(E_ji)^T w_j.

This module is the only place where the paper's (tau, f) / (omega, v) order meets torchhand's wrench order
(force, torque) about the object's centre of mass in world coordinates (:mod:`torchhand.conventions`):
:func:`wrench_to_spatial` and :func:`wrench_from_spatial` reorder, and :func:`shift_wrench` moves the reference
point. The root columns of ``torchhand.hand.dynamics.point_jacobian`` already use the paper's twist order
(angular, linear) about the root origin.
"""

from __future__ import annotations

import torch

__all__ = ["skew", "adjoint", "gamma", "spatial_cross", "exp_twist", "se3_inverse", "so3_log",
           "wrench_to_spatial", "wrench_from_spatial", "shift_wrench"]


def _check(fn: str, x, name: str, tail: tuple) -> None:
    if not isinstance(x, torch.Tensor) or x.dim() != len(tail) + 1 or tuple(x.shape[1:]) != tail:
        got = tuple(x.shape) if isinstance(x, torch.Tensor) else type(x).__name__
        raise ValueError(f"{fn}: {name} must have shape (B, {', '.join(map(str, tail))}), got {got}")
    if not x.is_floating_point():
        raise ValueError(f"{fn}: {name} must be floating point, got {x.dtype}")


def skew(v: torch.Tensor) -> torch.Tensor:
    """Cross-product matrix [v]x with [v]x a = v x a.

    v: vectors, (..., 3)
    returns: (..., 3, 3)
    """
    x, y, z = v.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack([torch.stack([o, -z, y], -1), torch.stack([z, o, -x], -1),
                        torch.stack([-y, x, o], -1)], -2)


def adjoint(E: torch.Tensor) -> torch.Tensor:
    """Adjoint Ad(E) = (Theta 0; [p]x Theta  Theta) of rigid transforms (§6.1).

    E: rigid transforms E_ji = (Theta p; 0 1), (B, 4, 4)
    returns: Ad, (B, 6, 6): phi_j = Ad phi_i for twists (omega, v); w_i = Ad^T w_j for wrenches (tau, f)
    """
    _check("adjoint", E, "E", (4, 4))
    R, p = E[:, :3, :3], E[:, :3, 3]
    top = torch.cat([R, torch.zeros_like(R)], -1)
    bottom = torch.cat([skew(p) @ R, R], -1)
    return torch.cat([top, bottom], -2)


def gamma(r: torch.Tensor) -> torch.Tensor:
    """Stacked point maps Gamma(r_i) = ([-r_i]x  I3) (§6.1): r_dot_i = Gamma(r_i) phi, w = Gamma(r_i)^T f_i.

    r: points, (B, N, 3), metres, in the frame of the twist (world for the quasi-static step)
    returns: Gamma, (B, 3N, 6); block rows i = 3i .. 3i + 2
    """
    if not isinstance(r, torch.Tensor) or r.dim() != 3 or r.shape[-1] != 3 or not r.is_floating_point():
        got = tuple(r.shape) if isinstance(r, torch.Tensor) else type(r).__name__
        raise ValueError(f"gamma: r must be a floating point tensor of shape (B, N, 3), got {got}")
    B, N, _ = r.shape
    eye = torch.eye(3, dtype=r.dtype, device=r.device).expand(B, N, 3, 3)
    return torch.cat([-skew(r), eye], -1).reshape(B, 3 * N, 6)


def spatial_cross(phi: torch.Tensor) -> torch.Tensor:
    """Spatial cross-product matrix [phi] = ([omega]x 0; [v]x [omega]x) of a twist (§6.1).

    phi: twists (omega, v), (B, 6), rad/s and m/s
    returns: (B, 6, 6); the Newton-Euler equation in body coordinates reads w = M phi_dot - [phi]^T M phi (Eq. 3)
    """
    _check("spatial_cross", phi, "phi", (6,))
    W, V = skew(phi[:, :3]), skew(phi[:, 3:])
    return torch.cat([torch.cat([W, torch.zeros_like(W)], -1), torch.cat([V, W], -1)], -2)


def exp_twist(phi: torch.Tensor, h) -> torch.Tensor:
    """Exact SE(3) exponential exp(h [phi]^) of twists held for a time h.

    phi: twists (omega, v), (B, 6), rad/s and m/s (body coordinates for E_{k+1} = E_k exp(h phi^))
    h:   time, float or (B,) tensor, seconds
    returns: (B, 4, 4) rigid transforms: rotation exp(h [omega]x), translation V(h omega) h v with
        V = I + (1 - cos t)/t^2 [w]x + (t - sin t)/t^3 [w]x^2 (t = |h omega|; Taylor series below t = 1e-2)
    """
    _check("exp_twist", phi, "phi", (6,))
    B = phi.shape[0]
    hh = torch.as_tensor(h, dtype=phi.dtype, device=phi.device).reshape(-1, 1).expand(B, 1)
    w, u = phi[:, :3] * hh, phi[:, 3:] * hh
    t2 = (w * w).sum(-1)
    t = t2.sqrt()
    small = t < 1e-2
    ts = torch.where(small, torch.ones_like(t), t)
    a = torch.where(small, 1 - t2 / 6 + t2 * t2 / 120, torch.sin(ts) / ts)
    b = torch.where(small, 0.5 - t2 / 24 + t2 * t2 / 720, (1 - torch.cos(ts)) / (ts * ts))
    c = torch.where(small, 1.0 / 6 - t2 / 120 + t2 * t2 / 5040, (ts - torch.sin(ts)) / (ts * ts * ts))
    W = skew(w)
    W2 = W @ W
    eye = torch.eye(3, dtype=phi.dtype, device=phi.device).expand(B, 3, 3)
    R = eye + a[:, None, None] * W + b[:, None, None] * W2
    V = eye + b[:, None, None] * W + c[:, None, None] * W2
    out = torch.zeros(B, 4, 4, dtype=phi.dtype, device=phi.device)
    out[:, :3, :3] = R
    out[:, :3, 3] = (V @ u[..., None]).squeeze(-1)
    out[:, 3, 3] = 1
    return out


def se3_inverse(E: torch.Tensor) -> torch.Tensor:
    """Inverse of rigid transforms without a general matrix inverse.

    E: (B, 4, 4) rigid transforms
    returns: (B, 4, 4); adjoint(se3_inverse(E)) = adjoint(E)^-1
    """
    _check("se3_inverse", E, "E", (4, 4))
    R = E[:, :3, :3].transpose(-1, -2)
    out = torch.zeros_like(E)
    out[:, :3, :3] = R
    out[:, :3, 3] = -(R @ E[:, :3, 3:4]).squeeze(-1)
    out[:, 3, 3] = 1
    return out


def so3_log(R: torch.Tensor) -> torch.Tensor:
    """Rotation vectors of rotation matrices (the inverse of exp([r]x) for angles below pi).

    R: rotations, (B, 3, 3)
    returns: r, (B, 3), radians; |r| in [0, pi]
    """
    _check("so3_log", R, "R", (3, 3))
    tr = R[:, 0, 0] + R[:, 1, 1] + R[:, 2, 2]
    cos = ((tr - 1) / 2).clamp(-1, 1)
    vee = torch.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], -1)   # 2 sin t u
    sin = 0.5 * torch.linalg.vector_norm(vee, dim=-1)
    t = torch.atan2(sin, cos)
    small = t < 1e-4
    scale = torch.where(small, 0.5 + t * t / 12, t / (2 * torch.where(small, torch.ones_like(sin), sin)))
    r = scale[:, None] * vee
    # near pi: the axis from the symmetric part (sin t -> 0 loses it)
    near_pi = cos < -0.99
    S = (R + R.transpose(-1, -2)) / 2 - cos[:, None, None] * torch.eye(3, dtype=R.dtype, device=R.device)
    k = torch.diagonal(S, dim1=-2, dim2=-1).argmax(-1)
    col = S[torch.arange(R.shape[0], device=R.device), :, k]
    axis = col / torch.linalg.vector_norm(col, dim=-1, keepdim=True).clamp_min(torch.finfo(R.dtype).tiny)
    axis = torch.where(((axis * vee).sum(-1, keepdim=True) < 0), -axis, axis)
    return torch.where(near_pi[:, None], t[:, None] * axis, r)


def wrench_to_spatial(w_ft: torch.Tensor) -> torch.Tensor:
    """torchhand's (force, torque) order to the paper's (tau, f) order; the reference point is unchanged.

    w_ft: wrenches (f, tau), (B, 6), newtons and N m
    returns: (tau, f), (B, 6)
    """
    _check("wrench_to_spatial", w_ft, "w_ft", (6,))
    return torch.cat([w_ft[:, 3:], w_ft[:, :3]], -1)


def wrench_from_spatial(w: torch.Tensor) -> torch.Tensor:
    """The paper's (tau, f) order to torchhand's (force, torque) order; the reference point is unchanged.

    w: wrenches (tau, f), (B, 6), N m and newtons
    returns: (f, tau), (B, 6)
    """
    _check("wrench_from_spatial", w, "w", (6,))
    return torch.cat([w[:, 3:], w[:, :3]], -1)


def shift_wrench(w: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """Re-express a wrench (tau, f) about a point p (same axes): tau_p = tau_o - p x f.

    w: wrenches (tau, f) about the origin o, (B, 6); p: new reference points, (B, 3), metres, relative to o
    returns: (tau - p x f, f), (B, 6)
    """
    _check("shift_wrench", w, "w", (6,))
    _check("shift_wrench", p, "p", (3,))
    return torch.cat([w[:, :3] - torch.linalg.cross(p, w[:, 3:], dim=-1), w[:, 3:]], -1)
