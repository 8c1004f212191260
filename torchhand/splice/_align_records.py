"""The settings (:class:`SpliceSettings`) and the result (:class:`Alignment`) of the two-pass time alignment
(:mod:`torchhand.splice.align`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from ..errors import InputValueError

__all__ = ["SpliceSettings", "Alignment"]


@dataclass(frozen=True)
class SpliceSettings:
    """Settings of the alignment (defaults: the paper's where it gives them, the design note's otherwise).

    band1, band2: band radius of pass 1 and pass 2 as a fraction of the body's length (0.30, 0.10: the paper)
    passes: 1 or 2
    features: "trunk" (trunk-frame markers, default) or "paper" (Eq. 7 local yaw per cell, minimal-rotation Eq. 9)
    sigma: marker smoothing before derivatives, seconds
    dead_zone: fraction of each clip's 95th-percentile derivative magnitude counted as zero
    yaw_frames: Eq. 7's window, frames (5 frames x 4 markers = the paper's 20 points)
    within_phase: weight of pass 1's cost increase in pass 2 (0 = the paper's plain 10 % band)
    tie_break: weight of the squared distance from the diagonal added to integer pass-1 costs
    smooth: Gaussian smoothing of the final hand time, seconds
    tolerance: matching-point tolerance T of Eq. 5, body frames
    hold_fraction, min_hold: a body hold is a run of at least ``min_hold`` seconds in which the markers' mean speed
        (in the feature frame) stays below ``hold_fraction`` of its 95th percentile; inside it the time map is
        replaced by the straight line between the aligned frames either side (0 disables)
    min_pass2_spread: pass 2 runs only when the hand-in-forearm direction spreads by more than this many degrees
        (95th percentile from its mean) and more than 3 times its median frame-to-frame change, in both clips
    """

    band1: float = 0.30
    band2: float = 0.10
    passes: int = 2
    features: str = "trunk"
    sigma: float = 0.05
    dead_zone: float = 0.05
    yaw_frames: int = 5
    within_phase: float = 0.1
    tie_break: float = 1e-3
    smooth: float = 0.1
    tolerance: float = 0.0
    min_pass2_spread: float = 3.0
    hold_fraction: float = 0.1
    min_hold: float = 0.3

    def __post_init__(self) -> None:
        for name in ("band1", "band2"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0 < v <= 1):
                raise InputValueError(f"{name}: expected a fraction of the body length in (0, 1], got {v!r}")
        if self.passes not in (1, 2):
            raise InputValueError(f"passes: expected 1 or 2, got {self.passes!r}")
        if self.features not in ("trunk", "paper"):
            raise InputValueError(f"features: expected 'trunk' or 'paper', got {self.features!r}")
        for name in ("sigma", "dead_zone", "within_phase", "tie_break", "smooth", "tolerance", "min_pass2_spread",
                     "hold_fraction", "min_hold"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputValueError(f"{name}: expected a non-negative number, got {v!r}")
        if not (isinstance(self.yaw_frames, int) and self.yaw_frames >= 1):
            raise InputValueError(f"yaw_frames: expected a positive integer, got {self.yaw_frames!r}")


@dataclass(frozen=True)
class Alignment:
    """Result of :func:`align` for B pairs (n body frames, m hand frames).

    hand_frame: the hand frame shown at each body frame, (B, n), fractional hand frames, non-decreasing
    hand_time: the same in seconds of the hand clip, (B, n)
    map1: pass 1's median hand frame per body frame, (B, n), fractional
    path1: pass 1's path, (B, n + m - 1, 2) long, padded with -1 (cells (body frame, hand frame))
    path2: pass 2's path on the aligned grid, (B, 2n - 1, 2) long padded with -1 (cells (body frame, aligned
        frame)); all -1 where pass 2 did not run
    cost1: pass 1's cost matrix (Eq. 6, before the tie-break), (B, n, m), float32
    cost2: pass 2's cost matrix, (B, n, n), float32, or None when pass 2 ran for no pair
    status: ``SolverStatus`` of pass 1 per pair, (B,), int8 (CONVERGED, INFEASIBLE, INVALID_INPUT)
    pass2_used: (B,) bool
    pass2_note: per pair, why pass 2 was skipped ("" when it ran)
    yaw: the heading of the rotation fitted between a hand-only clip's world frame and the body's trunk frame,
        (B,), radians (0 when not fitted)
    band1_frames, band2_frames: band radii in hand frames / aligned frames
    """

    hand_frame: torch.Tensor
    hand_time: torch.Tensor
    map1: torch.Tensor
    path1: torch.Tensor
    path2: torch.Tensor
    cost1: torch.Tensor
    cost2: torch.Tensor | None
    status: torch.Tensor
    pass2_used: torch.Tensor
    pass2_note: tuple[str, ...]
    yaw: torch.Tensor
    band1_frames: float
    band2_frames: float
    extra: dict = field(default_factory=dict)
