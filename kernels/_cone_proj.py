"""Euclidean projection onto products of friction cones (private helper of the friction-cone solver)."""

from __future__ import annotations

import torch


def project_cone(w: torch.Tensor, mu: torch.Tensor, inv: torch.Tensor | None = None) -> torch.Tensor:
    """Euclidean projection onto C_i = {(a, t) : ||t|| <= mu_i a} of every contact (branch-free).

    w: (B, 3K) component-major; mu: (B, K) >= 0 (0 projects onto the ray a >= 0, t = 0); inv: optional
    precomputed 1 / (1 + mu^2). Returns (B, 3K). a' = max(a, s) with s = max(0, (a + mu r) / (1 + mu^2)),
    r = ||t||, and t' = t min(1, mu a' / r) cover the three cases (inside: identity, polar cone: 0, otherwise the
    nearest boundary ray).
    """
    B, n = w.shape
    K = n // 3
    if inv is None:
        inv = 1 / (1 + mu * mu)
    a = w[:, :K]
    r = torch.hypot(w[:, K:2 * K], w[:, 2 * K:])
    s = torch.addcmul(a, mu, r).mul_(inv).clamp_min_(0)
    out = torch.empty_like(w)
    a_new = torch.maximum(a, s, out=out[:, :K])
    scale = (mu * a_new).div_(r.clamp_min_(torch.finfo(w.dtype).tiny)).clamp_max_(1)
    torch.mul(w[:, K:].view(B, 2, K), scale.unsqueeze(1), out=out[:, K:].view(B, 2, K))
    return out
