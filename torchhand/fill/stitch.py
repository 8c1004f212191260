"""Stitching windows into one motion per hand, and the free-hand frames between them.

* **Joins**: consecutive windows of a contact phase overlap; over the overlap the joint angles are blended with
  the smoothstep weight ``w(s) = 3 s^2 - 2 s^3`` (s from 0 to 1 across the overlap), whose slope is zero at both
  ends, so positions and velocities are continuous where the blend begins and ends, and frames outside overlaps
  are the windows' own, unchanged.
* **Free hand**: between contact phases (and before the first, after the last) the hand moves from the last
  contact pose to the model's rest pose and back to the next contact pose, each along the same smoothstep, taking
  as long as the joint-speed bound needs (at least ``min_transition`` seconds) and the free frames allow; frames
  further from any contact hold the rest pose.

Shapes: q (T, H, D) radians, H hands of the scene, D joints per hand.
"""

from __future__ import annotations

import math

import numpy as np
import torch

__all__ = ["smoothstep", "blend_windows", "fill_free", "max_speed", "stitch_variants", "clamp_speed"]


def smoothstep(n: int, dtype=torch.float64) -> torch.Tensor:
    """(n,) weights from just above 0 to just below 1 (the n interior points of a [0, 1] smoothstep)."""
    s = (torch.arange(n, dtype=dtype) + 1) / (n + 1)
    return 3 * s ** 2 - 2 * s ** 3


def blend_windows(spans: list[tuple[int, int, torch.Tensor]], start: int, stop: int) -> torch.Tensor:
    """One motion over ``[start, stop)`` from windows ``(a, b, q (b - a, H, D))`` sorted by ``a``, covering it,
    consecutive ones overlapping (or touching). Returns q (stop - start, H, D)."""
    a0, b0, q0 = spans[0]
    out = q0.new_zeros((stop - start,) + tuple(q0.shape[1:]))
    end = start
    for a, b, q in spans:
        lo = max(a, start)
        ov = max(0, end - lo)                                      # frames shared with what is written
        if ov:
            w = smoothstep(ov, q.dtype).reshape(-1, *([1] * (q.dim() - 1)))
            prev = out[lo - start:lo - start + ov]
            out[lo - start:lo - start + ov] = (1 - w) * prev + w * q[lo - a:lo - a + ov]
        out[lo - start + ov:b - start] = q[lo - a + ov:b - a]
        end = max(end, b)
    return out


def fill_free(q: torch.Tensor, known: torch.Tensor, rest: torch.Tensor, fps: float, joint_speed: float,
              min_transition: float = 0.3) -> torch.Tensor:
    """Frames where ``known (T,)`` is False filled by transitions to and from ``rest (H, D)`` (module docstring).
    q (T, H, D) holds the known frames. Returns a new (T, H, D)."""
    T = q.shape[0]
    out = q.clone()
    known = known.bool()
    if not known.any():
        out[:] = rest
        return out
    idx = torch.arange(T)
    runs = _runs(~known)
    for a, b in runs:
        prev = out[a - 1] if a > 0 else None
        nxt = out[b] if b < T else None
        n = b - a
        seg = rest.expand(n, *rest.shape).clone()
        if prev is not None:
            k = min(n if nxt is None else n // 2, _frames(prev, rest, fps, joint_speed, min_transition))
            seg[:k] = _ease(prev, rest, k + 1)[:k] if k else seg[:k]
        if nxt is not None:
            k = min(n if prev is None else n - n // 2, _frames(rest, nxt, fps, joint_speed, min_transition))
            if k:
                seg[n - k:] = _ease(rest, nxt, k + 1)[1:]
        out[a:b] = seg
    del idx
    return out


def _ease(x: torch.Tensor, y: torch.Tensor, n: int) -> torch.Tensor:
    """(n, ...) poses from x (exclusive at the far end: x itself at index 0) toward y along the smoothstep."""
    s = torch.arange(n, dtype=x.dtype) / n
    w = (3 * s ** 2 - 2 * s ** 3).reshape(-1, *([1] * x.dim()))
    return (1 - w) * x + w * y


def _frames(x: torch.Tensor, y: torch.Tensor, fps: float, joint_speed: float, min_transition: float) -> int:
    """Frames for a smoothstep from x to y within the joint-speed bound (its peak slope is 1.5 / duration)."""
    dist = float((y - x).abs().max())
    need = 1.5 * dist / max(joint_speed, 1e-9)
    return max(1, int(math.ceil(max(need, min_transition) * fps)))


def _runs(mask: torch.Tensor) -> list[tuple[int, int]]:
    m = torch.cat([torch.zeros(1, dtype=torch.int8), mask.to(torch.int8), torch.zeros(1, dtype=torch.int8)])
    d = m[1:] - m[:-1]
    return list(zip((d == 1).nonzero().squeeze(1).tolist(), (d == -1).nonzero().squeeze(1).tolist()))


def clamp_speed(q: torch.Tensor, max_step: float) -> torch.Tensor:
    """q (T, ...) with every frame-to-frame step held within ``max_step`` (radians per frame), in one forward
    pass: each frame is clipped to its (already clipped) predecessor's box. The result's speed is at most
    ``max_step * fps`` and so its acceleration at most ``2 max_step * fps^2``; frames already within the bound
    are unchanged."""
    out = q.clone()
    for t in range(1, q.shape[0]):
        out[t] = torch.minimum(torch.maximum(out[t], out[t - 1] - max_step), out[t - 1] + max_step)
    return out


def max_speed(q: torch.Tensor, fps: float) -> float:
    """Largest |dq/dt| of q (T, ...) by forward differences, rad/s."""
    return float((q[1:] - q[:-1]).abs().amax()) * fps if q.shape[0] > 1 else 0.0


def stitch_variants(runs, phases_union, T: int, rest: torch.Tensor, variants: int, joint_speed: float,
                    fps: float) -> tuple[list[torch.Tensor], np.ndarray]:
    """Per variant, the motion (T, H, D) and the frames covered by a solved window, (T,) bool.

    runs: per window its ``window`` (:class:`~torchhand.fill.windows.Window`) and ``qs`` (its solutions' q, each
    (frames, H, D)); phases_union: the phases the windows were planned on; rest: (H, D) radians; variants: motions;
    joint_speed: rad/s; fps: frames per second. Variant v takes solution v mod n of a segment's first window and in
    each next window the solution closest to it over their overlap (mean absolute joint difference).
    """
    H, D = rest.shape
    known = np.zeros(T, dtype=bool)
    out = []
    for v in range(variants):
        q = rest.expand(T, H, D).clone()
        for k, p in enumerate(phases_union):
            mine = _pieces([r for r in runs if r.window.phase == k])
            if not mine:
                continue
            spans, prev = [], None
            for a, b, qs in mine:
                q_w = _pick(a, b, qs, v, prev)
                spans.append((a, b, q_w))
                prev = (a, b, q_w)
            for group in _contiguous(spans):
                a, b = group[0][0], max(s[1] for s in group)
                q[a:b] = blend_windows(group, a, b)
                known[a:b] = True
        out.append(q)
    mask = torch.as_tensor(known)
    out = [fill_free(q, mask, rest, fps, joint_speed) for q in out]
    return out, known


def _pieces(runs) -> list[tuple[int, int, list]]:
    """The spans ``(start, stop, motions)`` of the runs, in order of their first frame, without a span that lies
    inside what the ones before it cover. A run has ``pieces`` (:class:`~torchhand.fill.pieces.Piece`), or a
    window solved whole and its ``qs``."""
    spans = []
    for r in runs:
        if getattr(r, "pieces", None) is not None:
            spans += [(p.start, p.stop, list(p.qs)) for p in r.pieces]
        elif r.qs:
            spans.append((r.window.start, r.window.stop, list(r.qs)))
    spans.sort(key=lambda s: (s[0], -s[1]))
    out, end = [], -1
    for s in spans:
        if s[1] > end:
            out.append(s)
            end = s[1]
    return out


def _pick(start: int, stop: int, qs: list, v: int, prev) -> torch.Tensor:
    """Motion v of the first span; afterwards the motion closest to the previous span over their overlap."""
    if prev is None:
        return qs[v % len(qs)]
    a, b, q_prev = prev
    lo, hi = start, min(b, stop)
    if hi <= lo:
        return qs[v % len(qs)]
    ref = q_prev[lo - a:hi - a]
    cost = [float((q[:hi - lo] - ref).abs().mean()) for q in qs]
    return qs[int(np.argmin(cost))]


def _contiguous(spans):
    groups, cur = [], [spans[0]]
    for s in spans[1:]:
        if s[0] <= max(c[1] for c in cur):
            cur.append(s)
        else:
            groups.append(cur)
            cur = [s]
    groups.append(cur)
    return groups
