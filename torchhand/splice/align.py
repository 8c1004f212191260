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

Modules: ``_align_records`` (:class:`SpliceSettings`, :class:`Alignment`), ``_align_ops`` (the tensor steps),
``_align_merge`` (step 4); this module runs the steps as stages over frozen records (``_Grid``, ``_Turned``,
``_Pass1``, ``_Pass2``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..errors import InputValueError
from torchhand.kernels.dtw import dtw
from torchhand.kernels.splice_cost import (forearm_hand_vectors, gaussian_smooth, palm_cost, sign_cost,
                                           sign_cost_yaw, sign_features, smooth_derivatives, window_yaw)
from torchhand.kernels.status import SolverStatus
from ._align_merge import _honour_anchors, _straighten_holds, hold_mask
from ._align_ops import (_anchors_pass2, _features, _interp_frames, _minimal_rotation_palm, _pass2_signal,
                         _repeat_anchors, _rot_z, band_width, fit_rotation, hand_in_forearm, path_median)
from ._align_records import Alignment, SpliceSettings

__all__ = ["SpliceSettings", "Alignment", "align", "band_width", "path_median", "fit_rotation",
           "hand_in_forearm", "hold_mask"]


@dataclass(frozen=True)
class _Grid:
    """The sizes of one alignment: B pairs, n body frames, m hand frames; DTW band widths W (Eq. 3) and radii r of
    pass 1 (hand frames) and pass 2 (aligned frames); the body markers' dtype and device."""

    B: int
    n: int
    m: int
    W1: float
    r1: float
    W2: float
    r2: float
    dtype: torch.dtype
    device: torch.device


@dataclass(frozen=True)
class _Turned:
    """The hand's features turned into the body's trunk frame: ``Q`` (B, m, 4, 3) and the fitted rotation's
    heading ``yaw`` (B,), radians (``Q`` unchanged and ``yaw`` 0 when no rotation is fitted)."""

    Q: torch.Tensor
    yaw: torch.Tensor


@dataclass(frozen=True)
class _Pass1:
    """Pass 1: its cost matrix ``C`` (B, n, m) before the tie-break, the DTW result ``res`` and ``map1`` (B, n),
    the median hand frame per body frame."""

    C: torch.Tensor
    res: object
    map1: torch.Tensor


@dataclass(frozen=True)
class _Pass2:
    """Pass 2's outcome (the :class:`Alignment` fields of the same names; ``hand_frame`` before merging)."""

    hand_frame: torch.Tensor
    path2: torch.Tensor
    cost2: torch.Tensor | None
    used: torch.Tensor
    notes: tuple[str, ...]


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
    grid = _grid(body, hand, settings)
    s = settings
    if s.features == "paper":                  # the paper: shoulder subtraction, world axes, Eq. 7 per cell
        body_trunk = hand_trunk = None
    P = _features(body, body_shoulder, body_trunk)
    Q = _features(hand, hand_shoulder, hand_trunk)
    if s.features == "trunk" and hand_trunk is None:
        turned = _turn_hand(P, Q, body_fps, hand_fps, anchors, grid, s)
    else:
        turned = _Turned(Q=Q, yaw=torch.zeros(grid.B, dtype=grid.dtype, device=grid.device))
    first = _pass1(P, turned.Q, body_fps, hand_fps, anchors, grid, s)
    second = _pass2(body, hand, first, anchors, grid, s)
    hand_frame = _merge(second.hand_frame, P, body_fps, anchors, grid.m, s)
    return Alignment(hand_frame=hand_frame, hand_time=hand_frame / hand_fps, map1=first.map1, path1=first.res.path,
                     path2=second.path2, cost1=first.C.float(), cost2=second.cost2, status=first.res.status,
                     pass2_used=second.used, pass2_note=second.notes, yaw=turned.yaw, band1_frames=grid.r1,
                     band2_frames=grid.r2 * 1.0)


def _grid(body: torch.Tensor, hand: torch.Tensor, s: SpliceSettings) -> _Grid:
    """The markers' shapes checked; sizes and band widths."""
    if body.dim() != 4 or body.shape[2:] != (4, 3) or hand.dim() != 4 or hand.shape[2:] != (4, 3) \
            or body.shape[0] != hand.shape[0]:
        raise InputValueError(f"markers: expected body (B, n, 4, 3) and hand (B, m, 4, 3), got "
                              f"{tuple(body.shape)} and {tuple(hand.shape)}")
    B, n = body.shape[:2]
    m = hand.shape[1]
    W1, r1 = band_width(s.band1, n, m)
    W2, r2 = band_width(s.band2, n, n)
    return _Grid(B=B, n=n, m=m, W1=W1, r1=r1, W2=W2, r2=r2, dtype=body.dtype, device=body.device)


def _turn_hand(P: torch.Tensor, Q: torch.Tensor, body_fps: float, hand_fps: float, anchors, grid: _Grid,
               s: SpliceSettings) -> _Turned:
    """A hand-only capture: its world frame is its trunk frame up to one rotation. Try yaws 30 deg apart (one
    batched DTW; a swinging arm looks alike turned by 180 deg, so one least-squares fit can land on the wrong one),
    keep the cheapest path, then fit the whole rotation along it (Kabsch)."""
    B, n, m, dev = grid.B, grid.n, grid.m, grid.device
    K = 12
    yaws = torch.arange(K, dtype=grid.dtype, device=dev) * (2 * math.pi / K)
    QK = torch.einsum("kij,btlj->bktli", _rot_z(yaws), Q).reshape(B * K, m, 4, 3)
    fp = sign_features(P, body_fps, s.sigma, s.dead_zone)
    fpK = fp.unsqueeze(1).expand(B, K, *fp.shape[1:]).reshape(B * K, *fp.shape[1:])
    CK = sign_cost(fpK, sign_features(QK, hand_fps, s.sigma, s.dead_zone))
    rK = dtw(CK.double(), band=grid.W1, anchors=_repeat_anchors(anchors, K), tolerance=s.tolerance,
             diagonal=s.tie_break)
    best = rK.distance.view(B, K).argmin(1)                                     # (B,)
    path = rK.path.view(B, K, -1, 2)[torch.arange(B, device=dev), best]
    m1 = path_median(path, n)
    rot = fit_rotation(P.reshape(B, -1, 3), _interp_frames(Q, m1).reshape(B, -1, 3))
    yaw = torch.atan2(rot[:, 1, 0], rot[:, 0, 0])
    return _Turned(Q=torch.einsum("bij,btkj->btki", rot, Q), yaw=yaw)


def _pass1(P: torch.Tensor, Qr: torch.Tensor, body_fps: float, hand_fps: float, anchors, grid: _Grid,
           s: SpliceSettings) -> _Pass1:
    """Eq. 6 with dead-zone signs (``features="paper"``: Eq. 7's local yaw per cell), DTW in band ``band1``."""
    if s.features == "paper":
        theta = window_yaw(P, Qr, s.yaw_frames)
        vp, ap = smooth_derivatives(P, body_fps, s.sigma)
        vq, aq = smooth_derivatives(Qr, hand_fps, s.sigma)
        C = sign_cost_yaw(vp, ap, vq, aq, theta, dead_zone=s.dead_zone)
    else:
        C = sign_cost(sign_features(P, body_fps, s.sigma, s.dead_zone),
                      sign_features(Qr, hand_fps, s.sigma, s.dead_zone))
    res = dtw(C.double(), band=grid.W1, anchors=anchors, tolerance=s.tolerance, diagonal=s.tie_break)
    return _Pass1(C=C, res=res, map1=path_median(res.path, grid.n))


def _pass2(body: torch.Tensor, hand: torch.Tensor, first: _Pass1, anchors, grid: _Grid,
           s: SpliceSettings) -> _Pass2:
    """Eqs. 8-9 on the hand resampled at ``map1``, where pass 1 succeeded and both wrists carry a signal."""
    B, n, dev = grid.B, grid.n, grid.device
    map1 = first.map1
    ok1 = first.res.status == int(SolverStatus.CONVERGED)
    hand_frame = map1.clone()
    path2 = torch.full((B, 2 * n - 1, 2), -1, dtype=torch.long, device=dev)
    cost2 = None
    used = torch.zeros(B, dtype=torch.bool, device=dev)
    notes = [""] * B
    if s.passes == 1:
        return _Pass2(hand_frame=hand_frame, path2=path2, cost2=cost2, used=used,
                      notes=tuple(["pass 2 not requested"] * B))
    ub = hand_in_forearm(body)
    uq = hand_in_forearm(hand)
    want = _pass2_wanted(ub, uq, ok1, notes, s)
    if bool(want.any()):
        D2 = _pass2_cost(body, hand, ub, first, grid, s)
        cost2 = D2.float()
        anc2 = _anchors_pass2(anchors, map1, B, n, dev)
        res2 = dtw(D2.double(), band=grid.W2, anchors=anc2, tolerance=s.tolerance, diagonal=s.tie_break)
        ok2 = want & (res2.status == int(SolverStatus.CONVERGED))
        k_med = path_median(res2.path, n)
        refined = _interp_frames(map1.unsqueeze(-1), k_med).squeeze(-1)
        hand_frame = torch.where(ok2.unsqueeze(1), refined, map1)
        path2 = torch.where(ok2.view(B, 1, 1), res2.path, path2)
        used = ok2
        for b in range(B):
            if bool(want[b]) and not bool(ok2[b]):
                notes[b] = "pass 2 found no alignment within its band; pass 1 kept"
    return _Pass2(hand_frame=hand_frame, path2=path2, cost2=cost2, used=used, notes=tuple(notes))


def _pass2_wanted(ub: torch.Tensor, uq: torch.Tensor, ok1: torch.Tensor, notes: list[str],
                  s: SpliceSettings) -> torch.Tensor:
    """Pairs pass 2 runs for, (B,) bool: pass 1 aligned them and both hand-in-forearm directions ``ub``, ``uq``
    vary beyond their noise; ``notes[b]`` says why not for the others."""
    okb, spb, nzb = _pass2_signal(ub, s.min_pass2_spread)
    okq, spq, nzq = _pass2_signal(uq, s.min_pass2_spread)
    want = okb & okq & ok1
    for b in range(len(notes)):
        if not bool(ok1[b]):
            notes[b] = "pass 1 found no alignment"
        elif not bool(okb[b]) or not bool(okq[b]):
            which = "body" if not bool(okb[b]) else "hand"
            sp, nz = (spb[b], nzb[b]) if which == "body" else (spq[b], nzq[b])
            notes[b] = (f"the {which}'s hand-in-forearm direction varies by {float(sp):.1f} deg (95th percentile; "
                        f"frame-to-frame {float(nz):.2f} deg): no wrist signal for pass 2")
    return want


def _pass2_cost(body: torch.Tensor, hand: torch.Tensor, ub: torch.Tensor, first: _Pass1, grid: _Grid,
                s: SpliceSettings) -> torch.Tensor:
    """Pass 2's cost (B, n, n): the palm angle between body frame i and aligned frame k (Eq. 9), plus
    ``within_phase`` times pass 1's cost increase."""
    B, n, m = grid.B, grid.n, grid.m
    map1 = first.map1
    qa = _interp_frames(hand, map1)                                   # hand markers at map1: (B, n, 4, 3)
    if s.features == "paper":
        fb, hb, _ = forearm_hand_vectors(body)
        fq, hq, _ = forearm_hand_vectors(qa)
        D2 = _minimal_rotation_palm(fb, hb, fq, hq)
    else:
        D2 = palm_cost(ub, hand_in_forearm(qa))                           # (B, n, n)
    if s.within_phase > 0:
        C1 = first.C
        cols = map1.round().long().clamp(0, m - 1)                      # (B, n): column of aligned frame k
        at_k = C1.gather(2, cols.unsqueeze(1).expand(B, n, n))            # C1[i, map1(k)]
        at_i = C1.gather(2, cols.unsqueeze(2))                            # C1[i, map1(i)]
        D2 = D2 + s.within_phase * (at_k - at_i).clamp(min=0)
    return D2


def _merge(hand_frame: torch.Tensor, P: torch.Tensor, body_fps: float, anchors, m: int,
           s: SpliceSettings) -> torch.Tensor:
    """Step 4 (module docstring): non-decreasing, straight inside holds, smoothed, matching points honoured."""
    hand_frame = torch.cummax(hand_frame, dim=1).values
    if s.hold_fraction > 0:
        hand_frame = _straighten_holds(hand_frame, P, body_fps, s, m)
    hand_frame = gaussian_smooth(hand_frame, s.smooth * body_fps).clamp(0, m - 1)
    hand_frame = _honour_anchors(hand_frame, anchors, s.tolerance, m)
    return torch.cummax(hand_frame, dim=1).values
