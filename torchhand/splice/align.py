"""Two-pass time alignment of body and hand captures (Majkowska, Zordan & Faloutsos 2006, Sec. 3-4).

Steps, each a pure function of tensors (B pairs batched; rows = body frames i < n, columns = hand frames j < m):

1. **Features.** ``features="trunk"`` (default): body markers relative to the shoulder (Sec. 4's shoulder
   subtraction) and expressed in the trunk's frame, which is the paper's own alternative to Eq. 7 ("an angle
   difference between the trunk orientations"); a hand clip with a trunk is treated the same way, a hand-only
   capture's world frame is its trunk frame up to one rotation, found once: pass 1 is run for 12 yaws 30 deg apart
   (one batched DTW call) and the cheapest kept, then the whole rotation is fitted along its path (Kabsch) and
   pass 1 recomputed.
   ``features="paper"``: shoulder-relative world markers and Eq. 7's local yaw per cell (``kernels.splice_cost``).
2. **Pass 1** (Eq. 6 with dead-zone signs, ``kernels.splice_cost``): DTW with a band of radius ``band1`` of the
   body's length measured along the hand axis, i.e. ``|j - (m/n) i| <= band1 * m`` (the design note's reading of
   "30 % ... of the full-body motion length": a radius, not a full width; ``dtw``'s W is derived from it). User
   matching points with tolerance (Eqs. 4-5). A tie-break ``tie_break * (i/(n-1) - j/(m-1))^2`` is added to the
   integer costs so that among equal paths the one nearest the diagonal wins instead of one hugging the band's
   edge (a deviation: the paper does not say how ties fall). ``map1[i]``: the median hand frame matched to body
   frame i (the midpoint of the path's run in row i).
3. **Pass 2** (Eqs. 8-9): the hand resampled at ``map1`` (an n x n grid, "within each matched phase"), cost
   = the angle between the hand vectors h expressed in each clip's forearm frame (axes f and p1 - p2): Eq. 9's R
   is any rotation taking f' onto f, which is under-determined (any twist about f also aligns); the forearm frame
   fixes it without depending on either capture's yaw (``features="paper"`` uses the minimal rotation instead).
   To keep pass 1's phase correspondence, ``within_phase * max(0, C1[i, map1(k)] - C1[i, map1(i)])`` is added,
   so pass 2 moves frames only among cells pass 1 rated alike; band radius ``band2`` of the body length. Pass 2 is
   skipped (and the reason reported) when the hand-in-forearm direction does not vary beyond its frame-to-frame
   noise in either clip (a still wrist gives no signal: then pass 2 could only add error).
4. **Merge** (Sec. 4, "Merging and smoothing"): the paper takes the median marker position over the hand frames
   matched to one body frame; with joint angles a per-channel median fails at +-180 deg wraps, so the median
   matched *time* is taken instead, made non-decreasing and smoothed with a Gaussian of ``smooth`` seconds; the
   caller resamples every joint at that time (slerp). This is the "blend discontinuities" step. Inside body holds
   the map is the straight line between the hold's aligned ends; at matching points it is corrected to the
   requested hand frame (within the tolerance) and the correction spread linearly to the neighbouring points.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from ..errors import InputValueError
from torchhand.kernels.dtw import dtw
from torchhand.kernels.splice_cost import (forearm_hand_vectors, gaussian_smooth, palm_cost, sign_cost,
                                           sign_cost_yaw,
                                           sign_features, smooth_derivatives, window_yaw)
from torchhand.kernels.status import SolverStatus

__all__ = ["SpliceSettings", "Alignment", "align", "band_width", "path_median", "fit_rotation",
           "hand_in_forearm", "hold_mask"]


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


def align(body: torch.Tensor, hand: torch.Tensor, *, body_fps: float, hand_fps: float,
          body_shoulder: torch.Tensor | None = None, body_trunk: torch.Tensor | None = None,
          hand_shoulder: torch.Tensor | None = None, hand_trunk: torch.Tensor | None = None,
          anchors: torch.Tensor | list | None = None, settings: SpliceSettings = SpliceSettings()) -> Alignment:
    """Align B hand clips to B body clips (module docstring).

    Args:
        body: body markers p1..p4, (B, n, 4, 3), metres, z up
        hand: hand markers, (B, m, 4, 3), metres, z up
        body_fps, hand_fps: frame rates
        body_shoulder, hand_shoulder: shoulder centres, (B, n, 3) / (B, m, 3), or None
        body_trunk, hand_trunk: trunk rotations, (B, n, 3, 3) / (B, m, 3, 3), or None
        anchors: matching points (body frame, hand frame), (B, A, 2) long padded with -1, or B lists of pairs
        settings: :class:`SpliceSettings`

    Returns:
        :class:`Alignment`
    """
    if body.dim() != 4 or body.shape[2:] != (4, 3) or hand.dim() != 4 or hand.shape[2:] != (4, 3) \
            or body.shape[0] != hand.shape[0]:
        raise InputValueError(f"markers: expected body (B, n, 4, 3) and hand (B, m, 4, 3), got "
                              f"{tuple(body.shape)} and {tuple(hand.shape)}")
    B, n = body.shape[:2]
    m = hand.shape[1]
    dev = body.device
    s = settings
    W1, r1 = band_width(s.band1, n, m)
    W2, r2 = band_width(s.band2, n, n)
    if s.features == "paper":                  # the paper: shoulder subtraction, world axes, Eq. 7 per cell
        body_trunk = hand_trunk = None
    P = _features(body, body_shoulder, body_trunk)
    Q = _features(hand, hand_shoulder, hand_trunk)
    yaw = torch.zeros(B, dtype=body.dtype, device=dev)

    def pass1(Qr: torch.Tensor):
        if s.features == "paper":
            theta = window_yaw(P, Qr, s.yaw_frames)
            vp, ap = smooth_derivatives(P, body_fps, s.sigma)
            vq, aq = smooth_derivatives(Qr, hand_fps, s.sigma)
            C = sign_cost_yaw(vp, ap, vq, aq, theta, dead_zone=s.dead_zone)
        else:
            C = sign_cost(sign_features(P, body_fps, s.sigma, s.dead_zone),
                          sign_features(Qr, hand_fps, s.sigma, s.dead_zone))
        res = dtw(C.double(), band=W1, anchors=anchors, tolerance=s.tolerance, diagonal=s.tie_break)
        return C, res

    Qr = Q
    rot = torch.eye(3, dtype=body.dtype, device=dev).expand(B, 3, 3)
    if s.features == "trunk" and hand_trunk is None:
        # A hand-only capture: its world frame is its trunk frame up to one rotation. Try yaws 30 deg apart (one
        # batched DTW; a swinging arm looks alike turned by 180 deg, so one least-squares fit can land on the
        # wrong one), keep the cheapest path, then fit the whole rotation along it (Kabsch) and align again.
        K = 12
        yaws = torch.arange(K, dtype=body.dtype, device=dev) * (2 * math.pi / K)
        QK = torch.einsum("kij,btlj->bktli", _rot_z(yaws), Q).reshape(B * K, m, 4, 3)
        fp = sign_features(P, body_fps, s.sigma, s.dead_zone)
        fpK = fp.unsqueeze(1).expand(B, K, *fp.shape[1:]).reshape(B * K, *fp.shape[1:])
        CK = sign_cost(fpK, sign_features(QK, hand_fps, s.sigma, s.dead_zone))
        rK = dtw(CK.double(), band=W1, anchors=_repeat_anchors(anchors, K), tolerance=s.tolerance,
                 diagonal=s.tie_break)
        best = rK.distance.view(B, K).argmin(1)                                     # (B,)
        path = rK.path.view(B, K, -1, 2)[torch.arange(B, device=dev), best]
        m1 = path_median(path, n)
        rot = fit_rotation(P.reshape(B, -1, 3), _interp_frames(Q, m1).reshape(B, -1, 3))
        yaw = torch.atan2(rot[:, 1, 0], rot[:, 0, 0])
        Qr = torch.einsum("bij,btkj->btki", rot, Q)
    C1, res1 = pass1(Qr)
    map1 = path_median(res1.path, n)
    ok1 = res1.status == int(SolverStatus.CONVERGED)

    hand_frame = map1.clone()
    path2 = torch.full((B, 2 * n - 1, 2), -1, dtype=torch.long, device=dev)
    cost2 = None
    used = torch.zeros(B, dtype=torch.bool, device=dev)
    notes = [""] * B
    if s.passes == 2:
        ub = hand_in_forearm(body)
        uq = hand_in_forearm(hand)
        okb, spb, nzb = _pass2_signal(ub, s.min_pass2_spread)
        okq, spq, nzq = _pass2_signal(uq, s.min_pass2_spread)
        want = okb & okq & ok1
        for b in range(B):
            if not bool(ok1[b]):
                notes[b] = "pass 1 found no alignment"
            elif not bool(okb[b]) or not bool(okq[b]):
                which = "body" if not bool(okb[b]) else "hand"
                sp, nz = (spb[b], nzb[b]) if which == "body" else (spq[b], nzq[b])
                notes[b] = (f"the {which}'s hand-in-forearm direction varies by {float(sp):.1f} deg (95th percentile; "
                            f"frame-to-frame {float(nz):.2f} deg): no wrist signal for pass 2")
        if bool(want.any()):
            qa = _interp_frames(hand, map1)                                   # hand markers at map1: (B, n, 4, 3)
            if s.features == "paper":
                fb, hb, _ = forearm_hand_vectors(body)
                fq, hq, _ = forearm_hand_vectors(qa)
                D2 = _minimal_rotation_palm(fb, hb, fq, hq)
            else:
                D2 = palm_cost(ub, hand_in_forearm(qa))                           # (B, n, n)
            if s.within_phase > 0:
                cols = map1.round().long().clamp(0, m - 1)                      # (B, n): column of aligned frame k
                at_k = C1.gather(2, cols.unsqueeze(1).expand(B, n, n))            # C1[i, map1(k)]
                at_i = C1.gather(2, cols.unsqueeze(2))                            # C1[i, map1(i)]
                D2 = D2 + s.within_phase * (at_k - at_i).clamp(min=0)
            cost2 = D2.float()
            anc2 = _anchors_pass2(anchors, map1, B, n, dev)
            res2 = dtw(D2.double(), band=W2, anchors=anc2, tolerance=s.tolerance, diagonal=s.tie_break)
            ok2 = want & (res2.status == int(SolverStatus.CONVERGED))
            k_med = path_median(res2.path, n)
            refined = _interp_frames(map1.unsqueeze(-1), k_med).squeeze(-1)
            hand_frame = torch.where(ok2.unsqueeze(1), refined, map1)
            path2 = torch.where(ok2.view(B, 1, 1), res2.path, path2)
            used = ok2
            for b in range(B):
                if bool(want[b]) and not bool(ok2[b]):
                    notes[b] = "pass 2 found no alignment within its band; pass 1 kept"
    elif s.passes == 1:
        notes = ["pass 2 not requested"] * B

    hand_frame = torch.cummax(hand_frame, dim=1).values
    if s.hold_fraction > 0:
        hand_frame = _straighten_holds(hand_frame, P, body_fps, s, m)
    hand_frame = gaussian_smooth(hand_frame, s.smooth * body_fps).clamp(0, m - 1)
    hand_frame = _honour_anchors(hand_frame, anchors, s.tolerance, m)
    hand_frame = torch.cummax(hand_frame, dim=1).values
    return Alignment(hand_frame=hand_frame, hand_time=hand_frame / hand_fps, map1=map1, path1=res1.path,
                     path2=path2, cost1=C1.float(), cost2=cost2, status=res1.status, pass2_used=used,
                     pass2_note=tuple(notes), yaw=yaw, band1_frames=r1, band2_frames=r2 * 1.0)


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
