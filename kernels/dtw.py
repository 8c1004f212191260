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

Column limits
    ``col_lo``, ``col_hi`` (B, n) restrict row i of pair b to the columns ``col_lo[b, i] <= j <= col_hi[b, i]``,
    intersected with the band and matching-point limits above (any integers: values outside [0, m - 1] clip). They
    express corridors that Eqs. 3-5 cannot, e.g. "within the phases matched by a first pass". A row left without a
    column makes the pair INFEASIBLE. A cell outside the limits still needs a finite cost (an inf cost marks the
    pair INVALID_INPUT): forbid cells with the limits, not with inf.

Diagonal preference
    ``diagonal=eps`` adds ``eps (i/(n-1) - j/(m-1))^2`` (0 when n or m is 1) to ``cost[i, j]`` inside the DP only,
    so that among tied paths the one nearest the diagonal wins (on an all-zero n x n cost: the diagonal). The
    returned ``distance`` is still the caller's cost summed over the returned path. That path minimises cost plus
    penalty, so its cost exceeds the least cost by at most the penalty summed over a least-cost path, which is
    below ``eps (n + m - 1)``: for integer costs any ``eps < 1 / (n + m - 1)`` keeps the distance optimal. With
    ``eps = 0`` (default) ties go to the latest start of a row's horizontal run and, at that start, to the
    vertical step: on an all-zero cost the path runs along row 0 to column m - 1, then down.

Results and status
    ``DTWResult.status`` (``SolverStatus`` values, int8): CONVERGED when a path exists; INFEASIBLE when no monotone
    path fits the band, anchors and column limits (distance = inf, path_length = 0, path all -1; never NaN);
    INVALID_INPUT when the pair's cost has NaN/inf, or its anchors are out of range, not strictly increasing, or
    its W or T are negative or NaN (distance = inf, path_length = 0). These are decided with tensor ops.

Algorithm
    Row i of the DP is a min-plus prefix scan: with ``S = cumsum(cost[i])``,
    ``D[i, j] = S[j] + min_{k<=j} (min(D[i-1, k-1], D[i-1, k]) + cost[i, k] - S[k])``. Interleaving the two
    predecessors as ``w[2k] = D[i-1, k-1] + e[k]``, ``w[2k+1] = D[i-1, k] + e[k]`` makes it one ``cummin`` whose
    argmin ``a`` also says where the horizontal run of row i starts (``a // 2``) and whether row i was entered
    diagonally (even) or vertically (odd): three tensor ops per row (four on rows of ``_SPLIT_CELLS`` cells or
    more, where two strided adds interleave faster than one), batched over pairs, in float64 (the cumulative sums
    would lose digits in float32). Cells outside the limits get ``e = inf`` (no run starts there) and ``S = inf``
    (no path leaves from there). Rows are prepared in chunks of about ``_CHUNK_CELLS`` cells (window copy,
    cumulative sums, masks, the diagonal penalty; reading each chunk's full rows for the NaN/inf check first
    brings them into cache). After each chunk the argmins at the odd positions are packed into one int16 per cell
    (int32 once w plus the largest step between windows reaches 16384): ``v = a - 1 + 2 (starts[i] -
    starts[i-1])``, clipped to [0, 2w). The backtrack reads the previous row's exit column ``v >> 1`` with one
    gather per row and, in bulk, the row's first column ``(v + 1) >> 1`` (both in row i-1's window). Memory beyond
    the input: 2 (or 4) bytes per computed cell (n B w), chunk buffers of about 50 bytes x ``_CHUNK_CELLS`` (7 MiB)
    and two row buffers; for B = 64 pairs of 569 x 2276 full rows that is 170 MiB (the int64 store of both
    parities and the three float64 (B, n, m) arrays kept before took 2.5 GiB).

Windows and host syncs
    When the allowed columns of every row (over all pairs) fit ``starts[i] + [0, w)`` with ``starts``
    non-decreasing and w at most ``_WINDOW_MAX_FRACTION`` m, rows are computed on those w columns only, so the
    work scales with the band's width. The placement is host-side arithmetic: for one numeric band without
    anchors or column limits it comes from n, m and W alone (no device sync on any device); with anchors, a
    per-pair band or column limits it is read from the limits with ``.tolist()`` on CPU only. On other devices
    those cases compute full rows, masked, and ``dtw`` never syncs: every status is a tensor.

Autograd
    ``distance`` is the sum of ``cost`` over the returned path (taken from the input, so it is differentiable in
    ``cost`` with the path's indicator as the (sub)gradient); the DP itself runs without gradient.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import torch

from ._dtw_band import (_anchors_tensor, _column_limits, _diagonal_weight, _limits, _per_pair,
                        band_limits)
from .status import SolverStatus

__all__ = ["DTWResult", "dtw", "pairwise_cost", "band_limits"]

_CHUNK_CELLS = 1 << 17  # rows are prepared and their argmins packed in chunks of about this many cells (pairs x cols)
_WINDOW_MAX_FRACTION = 0.9  # rows are computed on a window of w columns when w <= this fraction of m
_SPLIT_CELLS = 1 << 13  # rows of at least this many cells (pairs x cols) interleave their predecessors in two ops


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
    in_place = not (torch.is_grad_enabled() and (x.requires_grad or y.requires_grad))
    if x.shape[2] == 1:                                  # one feature: one subtraction (5x faster than cdist)
        d = x - y.transpose(1, 2)
        if squared:
            return d.square_() if in_place else d * d
        return d.abs_() if in_place else d.abs()
    # The direct (non-matmul) kernel keeps d(x, x) exactly 0.
    d = torch.cdist(x, y, compute_mode="donot_use_mm_for_euclid_dist")
    if squared:
        return d.square_() if in_place else d * d
    return d


def dtw(
    cost: torch.Tensor,
    *,
    band: float | torch.Tensor | None = None,
    anchors: torch.Tensor | Sequence | None = None,
    tolerance: float | torch.Tensor = 0,
    col_lo: torch.Tensor | None = None,
    col_hi: torch.Tensor | None = None,
    diagonal: float = 0.0,
) -> DTWResult:
    """Dynamic time warping of B pairs with an optional band and matching points (see the module docstring).

    Args:
        cost: frame distances, (B, n, m), float32 or float64, any units; ``cost[b, i, j]`` = distance between
            frame i of sequence 1 and frame j of sequence 2
        band: W of Eq. 3, frames: a float, or a (B,) tensor for one W per pair; None = no band
        anchors: user matching points (x_k, y_k), frame indices (0-based): a long tensor (B, A, 2) padded with
            rows (-1, -1), or a list of B lists of pairs (None or [] for no points)
        tolerance: T of Eq. 5, frames: a float, or a (B,) tensor
        col_lo, col_hi: first and last column row i of pair b may use, (B, n), integer, frame indices of the
            second sequence (inclusive); intersected with the band and anchors; None = no limit
        diagonal: weight of the diagonal preference ``diagonal (i/(n-1) - j/(m-1))^2`` added to every cell's
            cost inside the DP only, cost units, >= 0 (0 = off); ``distance`` stays the caller's cost of the path

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
    clo = _column_limits(col_lo, "col_lo", B, n, dev)
    chi = _column_limits(col_hi, "col_hi", B, n, dev)
    eps = _diagonal_weight(diagonal)

    with torch.no_grad():
        limits, first, last, bad_anchor = _limits(n, m, band, W, T, anc, clo, chi)
        starts, w = _plan_window(n, m, first, last)                  # host ints: row i uses starts[i] + [0, w)
        end, total, store = _scan(cost.detach(), starts, w, limits, eps)
        # A sum is non-finite iff the pair has a NaN/inf (or a chunk's sum overflows: float32 costs beyond ~1e32).
        invalid = ~torch.isfinite(total) | ~(W >= 0) | ~(T >= 0) | bad_anchor
        feasible = torch.isfinite(end) & ~invalid
        path, length = _backtrack(store, starts, feasible, n, m)

    # Distance = cost summed over the path, gathered from the input (differentiable, exactly the path's cost).
    on = path[..., 0] >= 0
    flat = path[..., 0].clamp(min=0) * m + path[..., 1].clamp(min=0)
    picked = cost.reshape(B, n * m).gather(1, flat).to(f64)
    dist = torch.where(on, picked, torch.zeros((), dtype=f64, device=dev)).sum(1)
    dist = torch.where(feasible, dist, torch.full((), math.inf, dtype=f64, device=dev)).to(cost.dtype)
    status = torch.where(invalid, int(SolverStatus.INVALID_INPUT),
                         torch.where(feasible, int(SolverStatus.CONVERGED), int(SolverStatus.INFEASIBLE)))
    return DTWResult(distance=dist, path=path, path_length=length, status=status.to(torch.int8))


def _plan_window(n: int, m: int, first: list[int] | None, last: list[int] | None) -> tuple[list[int], int]:
    """Columns worth computing: row i needs only ``starts[i] + [0, w)`` (host ints, ``starts`` non-decreasing).

    first, last: the first and last allowed column of each row over all pairs (first > last: none), or None
    (no limits known on the host). Full rows (starts = 0, w = m) then, and when the window would be wider than
    ``_WINDOW_MAX_FRACTION`` m.
    """
    if first is None:
        return [0] * n, m
    first, last = list(first), list(last)
    first[-1], last[-1] = min(first[-1], m - 1), m - 1          # the end cell is always computed
    starts = first
    for i in range(n - 2, -1, -1):                    # suffix minimum: non-decreasing and <= every row's first
        starts[i] = min(starts[i], starts[i + 1])
    w = max([1] + [h - s + 1 for s, h in zip(starts, last)])
    if w > _WINDOW_MAX_FRACTION * m:
        return [0] * n, m
    return [min(s, m - w) for s in starts], w


def _scan(cost: torch.Tensor, starts: list[int], w: int, limits,
          eps: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The DP, row by row on windows of w columns (``starts[i]``: absolute column of window column 0 of row i).

    limits: None, or (lo, hi, exit_lo) with lo, hi (B or 1, n) long and exit_lo (B, n) long or None (see
    :func:`band_limits`); eps: the diagonal preference weight. Returns D[n-1, m-1] (B,) float64 (with the
    penalty), the sum of every cost of each pair (B,) float64 (read chunk by chunk, which also brings the rows into
    cache before their windows are copied) and the packed argmins (n, B, w), int16 or int32 (module docstring).
    """
    B, n, m = cost.shape
    dev, f64, inf = cost.device, torch.float64, math.inf
    shifts = [starts[0]] + [starts[i] - starts[i - 1] for i in range(1, n)]
    split = B * w >= _SPLIT_CELLS
    K = max(1, min(n, _CHUNK_CELLS // max(1, B * w)))                  # rows per chunk
    host = torch.tensor([starts, [2 * s - 1 for s in shifts]], dtype=torch.long, device=dev)   # one transfer
    small = 2 * (w + max(shifts)) < 1 << 15                           # every a - 1 + 2 shift fits in int16
    store = torch.empty((n, B, w), dtype=torch.int16 if small else torch.int32, device=dev)
    start_t, code_t = host[0], host[1].view(n, 1, 1).to(store.dtype)

    total = cost.new_zeros((B,), dtype=f64)
    # Chunk buffers, (K, B, w) so that each row's slice is contiguous (the last chunk uses their first rows).
    bufs = _chunk_buffers(cost, K, w, limits, eps > 0 and n > 1 and m > 1)
    arg = torch.empty((K, B, 2 * w), dtype=torch.long, device=dev)   # cummin argmins of the interleaved rows
    arg_rows, arg_odd = arg.unbind(0), arg[:, :, 1::2]

    # Two rolling row buffers; position p of the buffer holding row r is absolute column starts[r] + p - 1 (row -1:
    # starts = 0, so position 0 is D[-1, -1] = 0). Positions past w stay inf.
    rows = cost.new_full((2, B, w + max(shifts) + 2), inf, dtype=f64)
    rows[0, :, 0] = 0.0
    sB = rows.stride(1)
    base = [rows[r].storage_offset() for r in (0, 1)]
    outs = [rows[r, :, 1:w + 1] for r in (0, 1)]
    buf = cost.new_empty((B, w, 2), dtype=f64)
    buf_flat = buf.view(B, 2 * w)
    val = cost.new_empty((B, 2 * w), dtype=f64)
    val_odd = val[:, 1::2]
    views: dict = {}

    def pairs(r: int, d: int) -> torch.Tensor:
        # (B, w, 2) overlapping view [D[i-1, c-1], D[i-1, c]] for the window columns c of row i: interleaved.
        if (r, d) not in views:
            views[(r, d)] = rows[r].as_strided((B, w, 2), (sB, 1, 1), base[r] + d)
        return views[(r, d)]

    for i0 in range(0, n, K):
        i1 = min(n, i0 + K)
        k = i1 - i0
        total += cost[:, i0:i1].sum(dim=(1, 2))           # in the cost's dtype (fast); brings the rows into cache
        E, F = _prepare_rows(cost, starts, w, i0, i1, start_t, limits, eps, bufs)
        Es, Fs = E.unbind(0), F.unbind(0)
        for r in range(k):
            i = i0 + r
            p = pairs(i & 1, shifts[i])
            if split:                                  # long rows: two strided adds beat one with pairs innermost
                torch.add(p[..., 0], Es[r], out=buf[..., 0])
                torch.add(p[..., 1], Es[r], out=buf[..., 1])
            else:
                torch.add(p, Es[r].unsqueeze(-1), out=buf)
            torch.cummin(buf_flat, 1, out=(val, arg_rows[r]))
            torch.add(val_odd, Fs[r], out=outs[(i + 1) & 1])
            if i == 0:
                rows[0, :, 0] = inf                    # from now on nothing lies left of the windows
        # Pack: v = a - 1 + 2 shift (a: argmin at the odd position), clipped to [0, 2w).
        part = store[i0:i1]
        part.copy_(arg_odd[:k])
        part.add_(code_t[i0:i1]).clamp_(0, 2 * w - 1)
    return rows[n & 1, :, m - starts[-1]].clone(), total, store


def _chunk_buffers(cost: torch.Tensor, K: int, w: int, limits, penalty: bool) -> dict:
    """Buffers reused by every chunk of :func:`_prepare_rows` (fresh allocations per chunk cost page faults)."""
    B, _, m = cost.shape
    dev, f64 = cost.device, torch.float64
    own = w < m or cost.dtype != f64 or penalty     # the chunk's costs are copied (window, float64, penalty)
    bufs = {"S": cost.new_empty((K, B, w), dtype=f64), "E": cost.new_empty((K, B, w), dtype=f64),
            "ar": torch.arange(w, device=dev), "cols": torch.empty((K, w), dtype=torch.long, device=dev),
            "c": cost.new_empty((K, B, w), dtype=f64) if own else None, "penalty": penalty}
    if limits is not None:                             # masks: (K, B or 1, w)
        shape = (K, limits[0].shape[0], w)
        bufs.update(outside=torch.empty(shape, dtype=torch.bool, device=dev),
                    other=torch.empty(shape, dtype=torch.bool, device=dev),
                    inf=torch.empty(shape, dtype=f64, device=dev),
                    inf_t=torch.full((), math.inf, dtype=f64, device=dev),
                    zero_t=torch.zeros((), dtype=f64, device=dev))
    return bufs


def _prepare_rows(cost: torch.Tensor, starts: list[int], w: int, i0: int, i1: int, start_t: torch.Tensor, limits,
                  eps: float, bufs: dict) -> tuple[torch.Tensor, torch.Tensor]:
    """E = c - S and F = S for rows i0..i1-1 on their windows, (i1 - i0, B, w) float64, inf outside the limits
    (F also where the path may not leave the row); c = cost (+ the diagonal penalty) in float64, S = cumsum(c)."""
    B, n, m = cost.shape
    k = i1 - i0
    cols = torch.add(start_t[i0:i1, None], bufs["ar"], out=bufs["cols"][:k])    # (k, w) absolute columns
    c = cost[:, i0:i1].transpose(0, 1)
    if w < m:
        c = _windows(cost, starts, w, i0, i1, cols, bufs["c"][:k])
    elif bufs["c"] is not None:
        c = bufs["c"][:k].copy_(c)
    if bufs["penalty"]:
        di = torch.arange(i0, i1, device=cost.device, dtype=torch.float64).div_(n - 1).unsqueeze(1)
        di = di - cols.to(torch.float64).div_(m - 1)
        c.add_(di.square_().mul_(eps).unsqueeze(1))
    S = torch.cumsum(c, -1, out=bufs["S"][:k])
    E = torch.sub(c, S, out=bufs["E"][:k])
    if limits is not None:                             # inf outside the limits, added (cheaper than masked_fill)
        lo, hi, exit_lo = (None if t is None else t[:, i0:i1].t().unsqueeze(-1) for t in limits)
        cc, outside, other, infs = cols.unsqueeze(1), bufs["outside"][:k], bufs["other"][:k], bufs["inf"][:k]
        torch.lt(cc, lo, out=outside)
        outside.logical_or_(torch.gt(cc, hi, out=other))
        E.add_(torch.where(outside, bufs["inf_t"], bufs["zero_t"], out=infs))
        if exit_lo is not None:
            outside.logical_or_(torch.lt(cc, exit_lo, out=other))
            torch.where(outside, bufs["inf_t"], bufs["zero_t"], out=infs)
        S.add_(infs)                                   # S is now F: inf where no path may leave the row
    return E, S


def _windows(cost: torch.Tensor, starts: list[int], w: int, i0: int, i1: int, cols: torch.Tensor,
             out: torch.Tensor) -> torch.Tensor:
    """``out[r] = cost[:, i0 + r, starts[i0 + r] + [0, w)]``, (i1 - i0, B, w). Runs of rows whose starts step
    evenly are one strided view each (one copy); with many uneven steps, one gather (``cols``: (i1 - i0, w))."""
    B = cost.shape[0]
    sB, sR, sC = cost.stride()
    runs, a = [], i0
    while a < i1:
        b = a + 1
        d = starts[b] - starts[a] if b < i1 else 0
        while b < i1 and starts[b] - starts[b - 1] == d:
            b += 1
        runs.append((a, b, d))
        a = b
    if len(runs) > max(2, (i1 - i0) // 8):
        index = cols.unsqueeze(1).expand(i1 - i0, B, w)
        if out.dtype == cost.dtype:
            return torch.gather(cost.transpose(0, 1)[i0:i1], 2, index, out=out)
        return out.copy_(torch.gather(cost.transpose(0, 1)[i0:i1], 2, index))
    off = cost.storage_offset()
    views = [cost.as_strided((b - a, B, w), (sR + d * sC, sB, sC), off + a * sR + starts[a] * sC) for a, b, d in runs]
    return out.copy_(views[0]) if len(views) == 1 else torch.cat(views, 0, out=out)


def _backtrack(store: torch.Tensor, starts: list[int], feasible: torch.Tensor, n: int,
               m: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Path cells (B, n + m - 1, 2) padded with -1 and lengths (B,) from the packed argmins (n, B, w).

    ``starts[i]``: absolute column of window column 0 in row i (host ints).
    """
    _, B, w = store.shape
    dev = store.device
    exit_col = torch.empty((n, B, 1), dtype=torch.long, device=dev)     # last column of the path in row i (window)
    exit_col[n - 1] = m - 1 - starts[n - 1]
    # Walk up in chunks: decode the chunk's exits (v >> 1) into int64, then one gather per row.
    K = max(1, min(n, _CHUNK_CELLS // max(1, B * w)))
    table = torch.empty((K, B, w), dtype=torch.long, device=dev)
    tables, exits = table.unbind(0), exit_col.unbind(0)
    for i1 in range(n, 1, -K):
        i0 = max(1, i1 - K)
        table[:i1 - i0].copy_(store[i0:i1]).bitwise_right_shift_(1)
        for i in range(i1 - 1, i0 - 1, -1):
            torch.gather(tables[i - i0], 1, exits[i], out=exits[i - 1])
    v = store.gather(2, exit_col).squeeze(-1).long()                       # (n, B) packed argmins on the path
    host = torch.tensor([starts, [0] + starts[:-1]], dtype=torch.long, device=dev).view(2, n, 1)
    # Absolute columns, (B, n): where the path leaves row i and where it enters it (row 0: column 0).
    exit_col = (exit_col.squeeze(-1) + host[0]).t().contiguous()
    first_col = ((v + 1).bitwise_right_shift_(1) + host[1]).t().contiguous()
    first_col[:, 0] = 0
    counts = (exit_col - first_col + 1).clamp_(min=1)
    begin = counts.cumsum(1).sub_(counts)                                    # path position of each row's first cell
    L = n + m - 1
    length = torch.where(feasible, (begin[:, -1] + counts[:, -1]).clamp_(max=L), 0)
    # Row of each path position: how many rows after the first begin at or before it.
    row = torch.zeros((B, L + 1), dtype=torch.long, device=dev)
    row.scatter_add_(1, begin[:, 1:].clamp(max=L), torch.ones((B, n - 1), dtype=torch.long, device=dev))
    row = row[:, :L].cumsum(1)
    pos = torch.arange(L, device=dev)
    col = first_col.gather(1, row).add_(pos).sub_(begin.gather(1, row))
    off = pos >= length.unsqueeze(1)
    path = torch.stack([row.masked_fill_(off, -1), col.masked_fill_(off, -1)], -1)
    return path, length
