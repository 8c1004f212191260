"""The band of :func:`torchhand.kernels.dtw.dtw`: allowed columns per row from Majkowska et al.'s band radius,
tolerance and matching points (Eqs. 3-5), per-row column limits, and the normalisation of dtw's per-pair arguments.

Pure tensor math (imports torch and math only).
"""

from __future__ import annotations

import math
from typing import Sequence

import torch

__all__ = ["band_limits"]

_SLACK = 1e-9  # band boundaries are inclusive up to this many frames


def band_limits(n: int, m: int, W: torch.Tensor, T: torch.Tensor, anchors: torch.Tensor | None):
    """Allowed columns per row from the band (Eqs. 3-4), the anchors and the tolerance (Eq. 5).

    Args:
        n, m: sequence lengths
        W: band width per pair, (B,), float64 frames (inf = no band)
        T: tolerance per pair, (B,), float64 frames
        anchors: (B, A, 2) long matching points padded with (-1, -1), or None

    Returns:
        lo, hi: first and last allowed column of every row, (B, n), long (lo > hi: the row is empty)
        exit_lo: the path may leave row i upward only from a column >= exit_lo[i], (B, n), long
        bad: pairs whose anchors are out of range or not strictly increasing, (B,), bool
    """
    B, dev, f64 = W.shape[0], W.device, torch.float64
    rows = torch.arange(n, device=dev).expand(B, n)
    if anchors is None or anchors.shape[1] == 0:
        # One segment, from the virtual (-1, -1) to (n - 1, m - 1): the same arithmetic, fewer ops.
        x0, x1 = torch.full((1, 1), -1, device=dev), torch.full((1, 1), n - 1, device=dev)
        y0, y1 = torch.full((1, 1), -1.0, dtype=f64, device=dev), torch.full((1, 1), m - 1.0, dtype=f64, device=dev)
        bad = torch.zeros(B, dtype=torch.bool, device=dev)
    else:
        x0, x1, y0, y1, bad = _segments(n, m, anchors, rows)
    dx = (x1 - x0).clamp(min=1).to(f64)
    dy = y1 - y0
    centre = y0 + dy / dx * (rows - x0).to(f64)
    delta = W.unsqueeze(1) * torch.sqrt(dx * dx + dy * dy) / dx
    Tc = T.unsqueeze(1)
    lo_f = torch.maximum(torch.maximum(y0 - Tc, centre - delta - _SLACK).ceil(), torch.zeros((), dtype=f64, device=dev))
    hi_f = torch.minimum(torch.minimum(y1 + Tc, centre + delta + _SLACK).floor(),
                         torch.full((), m - 1, dtype=f64, device=dev))
    ex_f = torch.where(rows == x1, (y1 - Tc).ceil(), torch.zeros((), dtype=f64, device=dev))
    lo = lo_f.nan_to_num(0.0).clamp(0, m).long()
    hi = hi_f.nan_to_num(-1.0).clamp(-1, m - 1).long()
    exit_lo = ex_f.nan_to_num(0.0).clamp(0, m).long()
    return lo, hi, exit_lo, bad


def _segments(n: int, m: int, anchors: torch.Tensor, rows: torch.Tensor):
    """Per row, the matching points that bound its segment (Eq. 4): x0, x1 (B, n) long and y0, y1 (B, n) float64
    (x_{k-1} < i <= x_k), and the pairs whose anchors are out of range or not strictly increasing, (B,) bool."""
    B, A, dev = anchors.shape[0], anchors.shape[1], anchors.device
    x, y = anchors[..., 0], anchors[..., 1]
    pad = ((x == -1) & (y == -1)) | ((x == n - 1) & (y == m - 1))     # padding, or the end every path has
    valid = ~pad
    # Segments are made of rows, so a matching point must lie before the last row (the paper's x_l < x_{l+1}).
    out_of_range = valid & ((x < 0) | (x > n - 2) | (y < 0) | (y > m - 1))
    xs, order = torch.where(valid, x, torch.full_like(x, n)).sort(dim=1, stable=True)
    ys = torch.where(valid, y, torch.full_like(y, m)).gather(1, order)
    vs = valid.gather(1, order)
    xs = torch.where(vs, xs, torch.full_like(xs, n - 1))
    ys = torch.where(vs, ys, torch.full_like(ys, m - 1))
    start = torch.full((B, 1), -1, dtype=torch.long, device=dev)
    ext_x = torch.cat([start, xs, torch.full_like(start, n - 1)], 1).contiguous()  # (B, A + 2), non-decreasing
    ext_y = torch.cat([start, ys, torch.full_like(start, m - 1)], 1)
    steps_ok = (ext_x[:, 1:A + 1] > ext_x[:, :A]) & (ext_y[:, 1:A + 1] > ext_y[:, :A])
    bad = (out_of_range | (vs & ~steps_ok)).any(1)
    k = torch.searchsorted(ext_x, rows.contiguous(), side="left").clamp(1, A + 1)   # segment: x_{k-1} < i <= x_k
    x0, x1 = ext_x.gather(1, k - 1), ext_x.gather(1, k)
    y0, y1 = ext_y.gather(1, k - 1).to(torch.float64), ext_y.gather(1, k).to(torch.float64)
    return x0, x1, y0, y1, bad


def _limits(n: int, m: int, band, W: torch.Tensor, T: torch.Tensor, anc, clo, chi):
    """Allowed columns of every row and what the host may know of them without a device sync.

    Returns:
        limits: None (every column), or (lo, hi, exit_lo) on the device: lo, hi (B, n) long, or (1, n) when one
            numeric band holds for every pair; exit_lo (B, n) long with anchors, else None (see band_limits)
        first, last: per row, the first and the last allowed column over all pairs (host lists; first > last: the
            row is empty for every pair), or None when unknown on the host (no limits; per-pair limits off the CPU)
        bad_anchor: pairs whose anchors are out of range or not strictly increasing, (B,) bool
    """
    dev, f64 = W.device, torch.float64
    has_anchors = anc is not None and anc.shape[1] > 0
    if has_anchors or isinstance(band, torch.Tensor) or clo is not None or chi is not None:
        lo, hi, exit_lo, bad_anchor = band_limits(n, m, W, T, anc)
        if clo is not None:
            lo = torch.maximum(lo, clo)
        if chi is not None:
            hi = torch.minimum(hi, chi)
        first = last = None
        if dev.type == "cpu":                                         # elsewhere reading them would sync
            empty = lo > hi
            first = torch.where(empty, m, lo).amin(0).tolist()
            last = torch.where(empty, -1, hi).amax(0).tolist()
        return (lo, hi, exit_lo if has_anchors else None), first, last, bad_anchor
    no_anchor = torch.zeros(W.shape[0], dtype=torch.bool, device=dev)
    if band is None:
        return None, None, None, no_anchor
    # One band for every pair: from n, m and W on the host (no sync on any device).
    lo, hi, _, _ = band_limits(n, m, torch.full((1,), float(band), dtype=f64), torch.zeros(1, dtype=f64), None)
    return (lo.to(dev), hi.to(dev), None), lo[0].tolist(), hi[0].tolist(), no_anchor


def _per_pair(v, name: str, B: int, device, default: float) -> torch.Tensor:
    """A float or (B,) / scalar tensor as a (B,) float64 tensor; None -> ``default``."""
    if v is None:
        return torch.full((B,), default, dtype=torch.float64, device=device)
    if isinstance(v, torch.Tensor):
        if v.dim() == 0:
            v = v.expand(B)
        if v.shape != (B,):
            raise ValueError(f"{name}: expected a number or a tensor of shape ({B},), got {tuple(v.shape)}")
        return v.to(device=device, dtype=torch.float64)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise TypeError(f"{name}: expected a number or a tensor, got {type(v).__name__}")
    if not v >= 0:
        raise ValueError(f"{name}: expected a non-negative number, got {v}")
    return torch.full((B,), float(v), dtype=torch.float64, device=device)


def _anchors_tensor(anchors, B: int, device) -> torch.Tensor | None:
    """Matching points as (B, A, 2) long padded with (-1, -1)."""
    if anchors is None:
        return None
    if isinstance(anchors, torch.Tensor):
        if anchors.dim() != 3 or anchors.shape[0] != B or anchors.shape[2] != 2:
            raise ValueError(f"anchors: expected shape ({B}, A, 2), got {tuple(anchors.shape)}")
        if anchors.is_floating_point() or anchors.is_complex() or anchors.dtype == torch.bool:
            raise TypeError(f"anchors: expected an integer tensor, got {anchors.dtype}")
        return anchors.to(device=device, dtype=torch.long)
    if not isinstance(anchors, Sequence) or len(anchors) != B:
        got = type(anchors).__name__ + (f" of length {len(anchors)}" if isinstance(anchors, Sequence) else "")
        raise ValueError(f"anchors: expected a ({B}, A, 2) tensor or a list of {B} lists of (x, y) pairs, got {got}")
    per = [list(a) if a is not None else [] for a in anchors]
    A = max((len(a) for a in per), default=0)
    out = torch.full((B, A, 2), -1, dtype=torch.long)
    for b, a in enumerate(per):
        for k, p in enumerate(a):
            try:
                xk, yk = (int(v.__index__()) for v in p)
            except (TypeError, ValueError, AttributeError):
                raise ValueError(f"anchors[{b}][{k}]: expected a pair of integer frame indices (x, y), "
                                 f"got {p!r}") from None
            out[b, k, 0], out[b, k, 1] = xk, yk
    return out.to(device)


def _column_limits(v, name: str, B: int, n: int, device) -> torch.Tensor | None:
    """Per-row column limits as (B, n) long; None stays None."""
    if v is None:
        return None
    if not isinstance(v, torch.Tensor):
        raise TypeError(f"{name}: expected a ({B}, {n}) integer tensor or None, got {type(v).__name__}")
    if v.is_floating_point() or v.is_complex() or v.dtype == torch.bool:
        raise TypeError(f"{name}: expected an integer tensor, got {v.dtype}")
    if v.shape != (B, n):
        raise ValueError(f"{name}: expected shape ({B}, {n}), got {tuple(v.shape)}")
    return v.to(device=device, dtype=torch.long)


def _diagonal_weight(v) -> float:
    """The diagonal preference weight as a float >= 0."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise TypeError(f"diagonal: expected a number, got {type(v).__name__}")
    if not (v >= 0 and math.isfinite(v)):
        raise ValueError(f"diagonal: expected a finite number >= 0, got {v}")
    return float(v)
