"""Tensor steps of the time alignment (:mod:`torchhand.splice.align`), B pairs at once: band widths, the median
of a DTW path per row, the Kabsch fit, the feature frames (shoulder-relative, trunk axes), the hand vector in the
forearm frame and whether it carries a signal, Eq. 9 with the minimal rotation, and matching points carried
through pass 1."""

from __future__ import annotations

import math

import torch

from torchhand.kernels.splice_cost import forearm_hand_vectors

__all__ = ["band_width", "path_median", "fit_rotation", "hand_in_forearm"]


def band_width(fraction: float, n: int, m: int) -> tuple[float, float]:
    """W of Eq. 3 for a band of radius ``fraction`` of the body length: ``|j - (m/n) i| <= fraction * m``.

    Returns (W, radius in hand frames)."""
    radius = fraction * m
    return radius * n / math.sqrt(n * n + m * m), radius


def path_median(path: torch.Tensor, n: int) -> torch.Tensor:
    """Median matched column per row of DTW paths: the midpoint of the path's run of columns in each row.

    Args:
        path: (B, L, 2) long cells padded with -1
        n: number of rows

    Returns:
        (B, n) float64 fractional columns (NaN-free: rows without cells, only in invalid paths, get 0)
    """
    B = path.shape[0]
    rows, cols = path[..., 0], path[..., 1]
    valid = rows >= 0
    r = rows.clamp(min=0)
    big = torch.iinfo(torch.long).max
    first = torch.full((B, n), big, dtype=torch.long, device=path.device)
    last = torch.full((B, n), -1, dtype=torch.long, device=path.device)
    first.scatter_reduce_(1, r, torch.where(valid, cols, torch.full_like(cols, big)), reduce="amin")
    last.scatter_reduce_(1, r, torch.where(valid, cols, torch.full_like(cols, -1)), reduce="amax")
    ok = last >= 0
    mid = (first.to(torch.float64) + last.to(torch.float64)) * 0.5
    return torch.where(ok, mid, torch.zeros((), dtype=torch.float64, device=path.device))


def fit_rotation(P: torch.Tensor, Q: torch.Tensor) -> torch.Tensor:
    """The proper rotation R minimising sum |(P - mean P) - R (Q - mean Q)|^2 (Kabsch), (B, 3, 3).

    Args:
        P, Q: (B, N, 3) corresponding points
    """
    Pc = P - P.mean(1, keepdim=True)
    Qc = Q - Q.mean(1, keepdim=True)
    H = Qc.transpose(1, 2) @ Pc                                                     # (B, 3, 3)
    U, _, Vh = torch.linalg.svd(H)
    d = torch.sign(torch.linalg.det(Vh.transpose(1, 2) @ U.transpose(1, 2)))
    D = torch.diag_embed(torch.stack([torch.ones_like(d), torch.ones_like(d), d], -1))
    return Vh.transpose(1, 2) @ D @ U.transpose(1, 2)


def _repeat_anchors(anchors, K: int):
    if anchors is None:
        return None
    if isinstance(anchors, torch.Tensor):
        return anchors.repeat_interleave(K, dim=0)
    return [a for a in anchors for _ in range(K)]


def _rot_z(theta: torch.Tensor) -> torch.Tensor:
    c, s = torch.cos(theta), torch.sin(theta)
    z, o = torch.zeros_like(theta), torch.ones_like(theta)
    return torch.stack([torch.stack([c, -s, z], -1), torch.stack([s, c, z], -1), torch.stack([z, z, o], -1)], -2)


def _interp_frames(x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Linear interpolation of (B, m, ...) at fractional frames t (B, n) -> (B, n, ...)."""
    m = x.shape[1]
    t = t.clamp(0, m - 1)
    i0 = t.floor().long().clamp(max=m - 1)
    i1 = (i0 + 1).clamp(max=m - 1)
    w = (t - i0.to(t.dtype)).to(x.dtype)
    shape = (x.shape[0], t.shape[1]) + (1,) * (x.dim() - 2)
    idx0 = i0.view(shape).expand((x.shape[0], t.shape[1]) + x.shape[2:])
    idx1 = i1.view(shape).expand_as(idx0)
    return x.gather(1, idx0) * (1 - w.view(shape)) + x.gather(1, idx1) * w.view(shape)


def hand_in_forearm(markers: torch.Tensor) -> torch.Tensor:
    """The hand vector h (Eq. 8) in the forearm frame (axes f, p1 - p2 made orthogonal, their cross), unit length.

    Args:
        markers: (B, T, 4, 3)

    Returns:
        (B, T, 3)
    """
    f, h, w = forearm_hand_vectors(markers)
    e1 = f / f.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    e2 = w - e1 * (w * e1).sum(-1, keepdim=True)
    e2 = e2 / e2.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    e3 = torch.linalg.cross(e1, e2)
    local = torch.stack([(h * e1).sum(-1), (h * e2).sum(-1), (h * e3).sum(-1)], -1)
    return local / local.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def _pass2_signal(u: torch.Tensor, min_spread_deg: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Whether unit vectors u (B, T, 3) move beyond their noise: (ok (B,), spread deg (B,), noise deg (B,))."""
    mean = u.mean(1, keepdim=True)
    mean = mean / mean.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    ang = torch.rad2deg(torch.acos((u * mean).sum(-1).clamp(-1, 1)))
    spread = torch.quantile(ang, 0.95, dim=1)
    if u.shape[1] > 1:
        step = torch.rad2deg(torch.acos((u[:, 1:] * u[:, :-1]).sum(-1).clamp(-1, 1)))
        noise = step.median(dim=1).values
    else:
        noise = torch.zeros_like(spread)
    return (spread > min_spread_deg) & (spread > 3 * noise), spread, noise


def _minimal_rotation_palm(fp, hp, fq, hq) -> torch.Tensor:
    """Eq. 9 with the minimal rotation taking each f' onto f: (B, n, k) radians.

    fp, hp: (B, n, 3); fq, hq: (B, k, 3)."""
    a = (fp / fp.norm(dim=-1, keepdim=True).clamp_min(1e-12)).unsqueeze(2)          # (B, n, 1, 3)
    b = (fq / fq.norm(dim=-1, keepdim=True).clamp_min(1e-12)).unsqueeze(1)          # (B, 1, k, 3)
    h = hq.unsqueeze(1).expand(-1, a.shape[1], -1, -1)                              # (B, n, k, 3)
    v = torch.linalg.cross(b.expand_as(h), a.expand_as(h))
    c = (a * b).sum(-1, keepdim=True)
    # Rodrigues for the rotation taking b to a: R h = h c + (v x h) + v (v.h) / (1 + c)
    Rh = h * c + torch.linalg.cross(v, h) + v * (v * h).sum(-1, keepdim=True) / (1 + c).clamp_min(1e-9)
    hp_ = hp.unsqueeze(2)
    cos = (hp_ * Rh).sum(-1) / (hp_.norm(dim=-1) * Rh.norm(dim=-1)).clamp_min(1e-12)
    return torch.acos(cos.clamp(-1, 1))


def _features(markers: torch.Tensor, shoulder, trunk) -> torch.Tensor:
    """Shoulder-relative markers in the trunk frame where those exist: (B, T, 4, 3)."""
    x = markers
    if shoulder is not None:
        x = x - shoulder.unsqueeze(2)
    if trunk is not None:
        x = torch.einsum("btji,btkj->btki", trunk, x)          # R_trunk^T (p - s)
    return x


def _anchors_pass2(anchors, map1: torch.Tensor, B: int, n: int, dev):
    """Matching points mapped through pass 1: hand frame y -> the first aligned frame whose map1 reaches y."""
    if anchors is None:
        return None
    if not isinstance(anchors, torch.Tensor):
        A = max((len(a) if a else 0) for a in anchors) if len(anchors) else 0
        t = torch.full((B, A, 2), -1, dtype=torch.long)
        for b, a in enumerate(anchors):
            for k, (x, y) in enumerate(a or []):
                t[b, k, 0], t[b, k, 1] = int(x), int(y)
        anchors = t.to(dev)
    if anchors.shape[1] == 0:
        return None
    x, y = anchors[..., 0], anchors[..., 1]
    pad = (x < 0) & (y < 0)
    k = torch.searchsorted(map1.contiguous(), y.to(map1.dtype).contiguous(), side="left").clamp(0, n - 1)
    return torch.where(pad.unsqueeze(-1), anchors, torch.stack([x, k], -1))
