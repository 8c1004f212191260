"""Batched dynamic time warping with Majkowska et al.'s band and user matching points.

Pure tensor math (imports torch and math only). Reference: Majkowska, Zordan & Faloutsos, "Automatic splicing for
hand and body animations" (SCA 2006), Sec. 3, Eqs. 1-5 and Algorithm 1.

Cost convention
    ``cost[b, i, j]`` is the distance between frame ``i`` of the first sequence (length n) and frame ``j`` of the
    second (length m) of pair ``b``, in the caller's units (``pairwise_cost`` builds it from features). The
    distance of a warping path is the sum of ``cost`` over its cells; ``dtw`` returns the least one (Eqs. 1-2)::

        D[i, j] = cost[i, j] + min(D[i-1, j-1], D[i-1, j], D[i, j-1]),   D[-1, -1] = 0, other D[-1, .] = D[., -1] = inf

    A path is a list of cells ``(i, j)`` that starts at ``(0, 0)``, ends at ``(n-1, m-1)`` and moves by one of
    (1, 1), (1, 0), (0, 1) at each step (monotone and contiguous), so its length is between max(n, m) and n + m - 1.

Band (Eq. 3)
    With ``band=W`` a cell is allowed when ``|j' - (m/n) i'| <= Delta``, ``Delta = W sqrt(n^2 + m^2) / n``, using
    the paper's 1-based indices ``i' = i + 1``, ``j' = j + 1`` (the centre line runs from the virtual origin to the
    last cell). W is in frames (units of the second sequence's axis, measured across the diagonal): for n = m this
    is the Sakoe-Chiba band ``|i - j| <= floor(W sqrt(2))``. Boundary cells are included (1e-9 slack).

Matching points (Eqs. 4-5, Algorithm 1)
    ``anchors`` are frame pairs ``(x_k, y_k)`` (0-based) with x and y strictly increasing, ``x_k <= n - 2`` and
    ``y_k <= m - 1`` (the point ``(n - 1, m - 1)`` itself is accepted and ignored: every path ends there);
    ``tolerance=T`` frames.
    Segment k holds the rows ``x_{k-1} < i <= x_k`` (with the virtual ``(x_0, y_0) = (-1, -1)`` and the last
    anchor ``(n-1, m-1)``). In segment k a column is allowed when it lies within ``Delta_k`` of the line from
    ``(x_{k-1}, y_{k-1})`` to ``(x_k, y_k)`` (``Delta_k = W sqrt(|x_k|^2 + |y_k|^2) / |x_k|``; no such limit
    without a band) and in ``[y_{k-1} - T, y_k + T]``. Algorithm 1 writes the comparison as
    ``lb <= j - y_{k-1} <= ub`` with absolute bounds ``y_{k-1} - T`` and ``m``; we read all bounds in absolute
    column numbers, which is what its Fig. 2(b) draws. To make "the path passes the matching point within T"
    exact (a diagonal step from row x_k could otherwise leave it one column early) the path must also leave row
    ``x_k`` from a column ``>= y_k - T``. So every returned path contains a cell ``(x_k, j)`` with
    ``|j - y_k| <= T``; with T = 0 it goes through ``(x_k, y_k)``.

Results and status
    ``DTWResult.status`` (``SolverStatus`` values, int8): CONVERGED when a path exists; INFEASIBLE when no monotone
    path fits the band and anchors (distance = inf, path_length = 0, path all -1; never NaN); INVALID_INPUT when
    the pair's cost has NaN/inf, or its anchors are out of range, not strictly increasing, or its W or T are
    negative or NaN (distance = inf, path_length = 0). These are decided with tensor ops, no host sync.

Algorithm
    Row i of the DP is a min-plus prefix scan: with ``S = cumsum(cost[i])``,
    ``D[i, j] = S[j] + min_{k<=j} (min(D[i-1, k-1], D[i-1, k]) + cost[i, k] - S[k])``. Interleaving the two
    predecessors as ``w[2k] = D[i-1, k-1] + e[k]``, ``w[2k+1] = D[i-1, k] + e[k]`` makes it one ``cummin`` whose
    argmin also says where the horizontal run of row i starts (``idx // 2``) and whether row i was entered
    diagonally (even) or vertically (odd): three tensor ops per row, batched over pairs, in float64 (the
    cumulative sums would lose digits in float32). The path is read back with one gather per row.
    When every pair has the same band (``band`` a number, no anchors) the rows are computed on a window of w
    columns that covers the band (its placement comes from n, m and W on the host, no device sync), so the work
    scales with the band's width; otherwise (per-pair bands, anchors) full rows are computed and masked.

Autograd
    ``distance`` is the sum of ``cost`` over the returned path (taken from the input, so it is differentiable in
    ``cost`` with the path's indicator as the (sub)gradient); the DP itself runs without gradient.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import torch

from .status import SolverStatus

__all__ = ["DTWResult", "dtw", "pairwise_cost", "band_limits"]

_SLACK = 1e-9  # band boundaries are inclusive up to this many frames
_BULK_BACKTRACK = 1 << 20  # arg tensors up to this many elements are transformed in bulk before the backtrack


@dataclass(frozen=True)
class DTWResult:
    """Result of :func:`dtw` for B pairs of sequences of lengths n and m.

    distance:    least path cost, (B,), cost units, dtype of ``cost``; inf when infeasible or invalid
    path:        cells (i, j) of the optimal path in order, (B, n + m - 1, 2), long, padded with -1
    path_length: number of valid cells in ``path``, (B,), long; 0 when infeasible or invalid
    status:      ``SolverStatus`` per pair, (B,), int8: CONVERGED, INFEASIBLE or INVALID_INPUT
    """

    distance: torch.Tensor
    path: torch.Tensor
    path_length: torch.Tensor
    status: torch.Tensor


def pairwise_cost(x: torch.Tensor, y: torch.Tensor, *, squared: bool = False) -> torch.Tensor:
    """Euclidean distance between every frame of ``x`` and every frame of ``y``.

    Args:
        x: first sequences, (B, n, d), any units
        y: second sequences, (B, m, d), same units, dtype and device
        squared: return squared distances (the cost tslearn and dtaidistance sum; their DTW is the square root
            of the DTW distance of this cost)

    Returns:
        cost: (B, n, m); ``cost[b, i, j] = |x[b, i] - y[b, j]|`` (exactly 0 for identical frames)
    """
    if not isinstance(x, torch.Tensor) or not isinstance(y, torch.Tensor):
        raise TypeError(f"x, y: expected tensors, got {type(x).__name__}, {type(y).__name__}")
    if x.dim() != 3 or y.dim() != 3 or x.shape[0] != y.shape[0] or x.shape[2] != y.shape[2]:
        raise ValueError(f"x, y: expected shapes (B, n, d) and (B, m, d), got {tuple(x.shape)} and {tuple(y.shape)}")
    if not x.is_floating_point() or x.dtype != y.dtype:
        raise TypeError(f"x, y: expected the same floating dtype, got {x.dtype} and {y.dtype}")
    # The direct (non-matmul) kernel keeps d(x, x) exactly 0.
    d = torch.cdist(x, y, compute_mode="donot_use_mm_for_euclid_dist")
    return d * d if squared else d


def dtw(
    cost: torch.Tensor,
    *,
    band: float | torch.Tensor | None = None,
    anchors: torch.Tensor | Sequence | None = None,
    tolerance: float | torch.Tensor = 0,
) -> DTWResult:
    """Dynamic time warping of B pairs with an optional band and matching points (see the module docstring).

    Args:
        cost: frame distances, (B, n, m), float32 or float64, any units; ``cost[b, i, j]`` = distance between
            frame i of sequence 1 and frame j of sequence 2
        band: W of Eq. 3, frames: a float, or a (B,) tensor for one W per pair; None = no band
        anchors: user matching points (x_k, y_k), frame indices (0-based): a long tensor (B, A, 2) padded with
            rows (-1, -1), or a list of B lists of pairs (None or [] for no points)
        tolerance: T of Eq. 5, frames: a float, or a (B,) tensor

    Returns:
        DTWResult(distance (B,), path (B, n + m - 1, 2) long padded with -1, path_length (B,) long, status (B,))
    """
    if not isinstance(cost, torch.Tensor):
        raise TypeError(f"cost: expected a tensor, got {type(cost).__name__}")
    if cost.dim() != 3 or cost.shape[1] < 1 or cost.shape[2] < 1:
        raise ValueError(f"cost: expected shape (B, n, m) with n, m >= 1, got {tuple(cost.shape)}")
    if cost.dtype not in (torch.float32, torch.float64):
        raise TypeError(f"cost: expected float32 or float64, got {cost.dtype}")
    B, n, m = cost.shape
    dev = cost.device
    f64 = torch.float64
    W = _per_pair(band, "band", B, dev, default=math.inf)
    T = _per_pair(tolerance, "tolerance", B, dev, default=0.0)
    anc = _anchors_tensor(anchors, B, dev)

    with torch.no_grad():
        # A sum is non-finite iff the pair has a NaN/inf (or the sum overflows the dtype: costs beyond ~1e33).
        invalid = ~torch.isfinite(cost.detach().sum(dim=(1, 2))) | ~(W >= 0) | ~(T >= 0)
        lo, hi, exit_lo, bad_anchor = band_limits(n, m, W, T, anc)
        invalid = invalid | bad_anchor
        starts, w = _shared_window(n, m, band, anc)                  # host ints: row i uses columns starts[i] + [0, w)
        s = torch.tensor(starts, dtype=torch.long, device=dev)
        cols = s.unsqueeze(1) + torch.arange(w, device=dev)           # (n, w) absolute columns of the window
        src = cost.detach() if w == m else cost.detach().gather(2, cols.expand(B, n, w))
        c = src.to(f64)
        S = c.cumsum(-1)                                              # row-constant offsets cancel in the scan
        # E = cost - S where a horizontal run of row i may start, F = S where the path may leave row i; inf
        # elsewhere. Big (B, n, w) passes dominate large batches, so work in place and skip needless masks.
        E = c.sub_(S) if c is not src else c - S
        F = S
        no_anchors = anc is None or anc.shape[1] == 0
        if band is not None or not no_anchors:
            if no_anchors and not isinstance(band, torch.Tensor):    # the same band for every pair: (1, n, w)
                lo, hi, exit_lo = lo[:1], hi[:1], None
            outside = (cols < lo.unsqueeze(-1)) | (cols > hi.unsqueeze(-1))
            E.masked_fill_(outside, math.inf)
            if exit_lo is not None:
                outside |= cols < exit_lo.unsqueeze(-1)
            F.masked_fill_(outside, math.inf)
            del outside
        del c, S
        shifts = [starts[0]] + [starts[i] - starts[i - 1] for i in range(1, n)]
        last, arg = _scan_rows(E, F, shifts, m - 1 - starts[-1])
        del E, F
        feasible = torch.isfinite(last) & ~invalid
        path, length = _backtrack(arg, starts, feasible, n, m)

    # Distance = cost summed over the path, gathered from the input (differentiable, exactly the path's cost).
    on = path[..., 0] >= 0
    flat = path[..., 0].clamp(min=0) * m + path[..., 1].clamp(min=0)
    picked = cost.reshape(B, n * m).gather(1, flat).to(f64)
    dist = torch.where(on, picked, torch.zeros((), dtype=f64, device=dev)).sum(1)
    dist = torch.where(feasible, dist, torch.full((), math.inf, dtype=f64, device=dev)).to(cost.dtype)
    status = torch.where(invalid, int(SolverStatus.INVALID_INPUT),
                         torch.where(feasible, int(SolverStatus.CONVERGED), int(SolverStatus.INFEASIBLE)))
    return DTWResult(distance=dist, path=path, path_length=length, status=status.to(torch.int8))


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
    if anchors is None or anchors.shape[1] == 0:
        anchors = torch.full((B, 0, 2), -1, dtype=torch.long, device=dev)
    A = anchors.shape[1]
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

    rows = torch.arange(n, device=dev).expand(B, n).contiguous()
    k = torch.searchsorted(ext_x, rows, side="left").clamp(1, A + 1)   # segment: x_{k-1} < i <= x_k
    x0, x1 = ext_x.gather(1, k - 1), ext_x.gather(1, k)
    y0, y1 = ext_y.gather(1, k - 1).to(f64), ext_y.gather(1, k).to(f64)
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


def _shared_window(n: int, m: int, band, anchors) -> tuple[list[int], int]:
    """Columns worth computing, when every pair has the same band (a number, no anchors): row i needs only
    ``starts[i] + [0, w)``. Otherwise the full rows (starts = 0, w = m). Computed on the host from the shapes and the
    band number alone (no device sync), with the same arithmetic as :func:`band_limits`."""
    full = [0] * n, m
    if band is None or isinstance(band, torch.Tensor) or (anchors is not None and anchors.shape[1] > 0):
        return full
    one = torch.full((1,), float(band), dtype=torch.float64)
    lo, hi, _, _ = band_limits(n, m, one, torch.zeros(1, dtype=torch.float64), None)
    lo, hi = lo[0].tolist(), hi[0].tolist()
    w = max(1, max(h - l + 1 for l, h in zip(lo, hi)))
    if 2 * w > m:                                    # not worth the gather
        return full
    starts = [min(max(l, 0), m - w) for l in lo]
    if any(b < a for a, b in zip(starts, starts[1:])):
        return full
    return starts, w


def _scan_rows(E: torch.Tensor, F: torch.Tensor, shifts: list[int],
               last_col: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The DP, one ``cummin`` per row, in window coordinates.

    E = masked ``cost - S``, F = masked ``S``, both (B, n, w) float64, where window column t of row i is the
    absolute column ``starts[i] + t`` and ``shifts[i] = starts[i] - starts[i-1] >= 0`` (``starts[-1] = 0``);
    ``last_col`` is the window column of m - 1 in the last row. Returns D[n-1, m-1] (B,) and, per row, the
    argmin of the interleaved scan, (n, B, w) long: the row's horizontal run starts at window column ``a // 2``;
    the previous row is left at its window column ``(a - 1) // 2 + shifts[i]``.
    """
    B, n, w = E.shape
    dmax = max(shifts)
    # Two rolling buffers; position p of the buffer holding row r is absolute column starts[r] + p - 1, so
    # position 0 is left of the window (and, for the virtual row -1, D[-1, -1] = 0). Positions past w stay inf.
    rows = E.new_full((2, B, w + dmax + 2), math.inf)
    rows[0, :, 0] = 0.0
    sB = rows.stride(1)
    base = [rows[r].storage_offset() for r in (0, 1)]
    views = {}

    def pairs(r: int, d: int) -> torch.Tensor:
        # (B, w, 2) overlapping view [D[i-1, c-1], D[i-1, c]] for the window columns c of row i: interleaved.
        if (r, d) not in views:
            views[(r, d)] = rows[r].as_strided((B, w, 2), (sB, 1, 1), base[r] + d)
        return views[(r, d)]

    outs = [rows[r, :, 1:w + 1] for r in (0, 1)]
    arg = torch.empty((n, B, 2 * w), dtype=torch.long, device=E.device)   # cummin writes its indices here
    buf = E.new_empty((B, w, 2))
    buf_flat = buf.view(B, 2 * w)
    val = E.new_empty((B, 2 * w))
    val_odd = val[:, 1::2]
    Es = E.unsqueeze(-1).expand(B, n, w, 2).unbind(1)
    Fs = F.unbind(1)
    args = arg.unbind(0)
    for i in range(n):
        torch.add(pairs(i & 1, shifts[i]), Es[i], out=buf)
        torch.cummin(buf_flat, 1, out=(val, args[i]))
        torch.add(val_odd, Fs[i], out=outs[(i + 1) & 1])
        if i == 0:
            rows[0, :, 0] = math.inf                   # from now on nothing lies left of the windows
    return rows[n & 1, :, last_col + 1].clone(), arg[:, :, 1::2]


def _backtrack(arg: torch.Tensor, starts: list[int], feasible: torch.Tensor, n: int,
               m: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Path cells (B, n + m - 1, 2) padded with -1 and lengths (B,) from the scan's argmins (n, B, w).

    ``starts[i]``: absolute column of window column 0 in row i (host ints).
    """
    _, B, w = arg.shape
    dev = arg.device
    shifts = [starts[0]] + [starts[i] - starts[i - 1] for i in range(1, n)]
    exit_col = torch.empty((n, B, 1), dtype=torch.long, device=dev)          # last column of the path in row i
    exit_col[n - 1] = m - 1 - starts[n - 1]
    if n * B * w <= _BULK_BACKTRACK:
        # Previous row's exit (window column in row i - 1) for every cell at once, then one gather per row.
        d = torch.tensor(shifts, dtype=torch.long, device=dev).view(n, 1, 1)
        prev_exit = (arg - 1).bitwise_right_shift_(1).add_(d).clamp_(0, w - 1)
        for i in range(n - 1, 0, -1):
            torch.gather(prev_exit[i], 1, exit_col[i], out=exit_col[i - 1])
    else:
        # Large batches: whole passes over (n, B, w) cost more than a few small ops per row.
        for i in range(n - 1, 0, -1):
            a = arg[i].gather(1, exit_col[i])
            exit_col[i - 1] = (a - 1).bitwise_right_shift_(1).add_(shifts[i]).clamp_(0, w - 1)
    off = torch.tensor(starts, dtype=torch.long, device=dev).view(n, 1)
    first_col = arg.gather(2, exit_col) >> 1                                  # (n, B, 1) first column in row i
    exit_col, first_col = (exit_col.squeeze(-1) + off).t(), (first_col.squeeze(-1) + off).t()   # (B, n) absolute
    counts = (exit_col - first_col + 1).clamp(min=1)
    ends = counts.cumsum(1)                                                   # (B, n)
    L = n + m - 1
    pos = torch.arange(L, device=dev).expand(B, L).contiguous()
    row = torch.searchsorted(ends, pos, right=True).clamp(max=n - 1)
    col = first_col.gather(1, row) + pos - (ends - counts).gather(1, row)
    length = torch.where(feasible, ends[:, -1].clamp(max=L), torch.zeros((), dtype=torch.long, device=dev))
    on = pos < length.unsqueeze(1)
    path = torch.stack([row, col], -1)
    path = torch.where(on.unsqueeze(-1), path, torch.full((), -1, dtype=torch.long, device=dev))
    return path, length


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
