"""Step 4 of the time alignment (:mod:`torchhand.splice.align`, "Merge"): the time map made straight inside body
holds and corrected to honour the matching points."""

from __future__ import annotations

import numpy as np
import torch

from torchhand.kernels.splice_cost import smooth_derivatives
from ._align_records import SpliceSettings

__all__ = ["hold_mask"]


def _runs(flags: list) -> list[tuple[int, int]]:
    """First and last index of every run of True in ``flags``."""
    out, start = [], None
    for k, f in enumerate(flags + [False]):
        if f and start is None:
            start = k
        elif not f and start is not None:
            out.append((start, k - 1))
            start = None
    return out


def hold_mask(P: torch.Tensor, fps: float, settings: SpliceSettings) -> torch.Tensor:
    """Body holds (``SpliceSettings.hold_fraction``): (B, n) bool, True in runs of at least ``min_hold`` seconds
    whose mean marker speed stays below ``hold_fraction`` of its 95th percentile."""
    v, _ = smooth_derivatives(P, fps, settings.sigma)
    speed = v.norm(dim=-1).mean(-1)                                                # (B, n)
    slow = speed < settings.hold_fraction * torch.quantile(speed, 0.95, dim=1, keepdim=True)
    need = max(1, int(round(settings.min_hold * fps)))
    out = torch.zeros_like(slow)
    for b in range(slow.shape[0]):                 # run lengths on the host: n is a few thousand at most
        for i, j in _runs(slow[b].tolist()):
            if j - i + 1 >= need:
                out[b, i:j + 1] = True
    return out


def _straighten_holds(hand_frame: torch.Tensor, P: torch.Tensor, fps: float, settings: SpliceSettings,
                      m: int) -> torch.Tensor:
    """Inside body holds, replace the time map by the straight line between the frames either side (the ends of
    the clips count as aligned: DTW pins them). While the body holds still, arm data cannot time the hand, and
    DTW's choice among tied cells is arbitrary; constant speed through the hold is the least-assuming guess."""
    hold = hold_mask(P, fps, settings)
    out = hand_frame.clone()
    n = hand_frame.shape[1]
    for b in range(hold.shape[0]):
        for i, j in _runs(hold[b].tolist()):
            x0, y0 = (i - 1, float(hand_frame[b, i - 1])) if i > 0 else (0, 0.0)
            x1, y1 = (j + 1, float(hand_frame[b, j + 1])) if j + 1 < n else (n - 1, float(m - 1))
            if x1 > x0:
                xs = torch.arange(i, j + 1, dtype=hand_frame.dtype, device=hand_frame.device)
                out[b, i:j + 1] = y0 + (y1 - y0) * (xs - x0) / (x1 - x0)
    return out


def _honour_anchors(hand_frame: torch.Tensor, anchors, T: float, m: int) -> torch.Tensor:
    """Make the final map show hand frame y_k (within T) at body frame x_k: the path passes there, but the median of
    its run in row x_k, pass 2 and the smoothing may not. The correction at each matching point is spread linearly
    to the neighbouring points (zero at the clips' ends), so the map stays smooth."""
    if anchors is None:
        return hand_frame
    B, n = hand_frame.shape
    out = hand_frame.clone()
    for b in range(B):
        pts = anchors[b].tolist() if isinstance(anchors, torch.Tensor) else list(anchors[b] or [])
        pts = [(int(x), int(y)) for x, y in pts if x >= 0 and y >= 0 and x < n - 1]
        if not pts:
            continue
        xs, corr = [0], [0.0]
        for x, y in sorted(pts):
            v = float(hand_frame[b, x])
            corr.append(min(max(v, y - T), y + T) - v)
            xs.append(x)
        xs.append(n - 1)
        corr.append(0.0)
        grid = torch.arange(n, dtype=torch.float64)
        c = np.interp(grid.numpy(), np.array(xs, dtype=np.float64), np.array(corr))
        out[b] = (hand_frame[b] + torch.from_numpy(c).to(hand_frame)).clamp(0, m - 1)
    return out
