"""DTW with Majkowska's band and matching points (kernels/dtw.py).

References nobody here wrote: tslearn and dtaidistance (skipped when absent), a naive numpy DP and an exhaustive
enumeration of monotone paths written plainly below; plus invariants in seeded loops. The input builders
(:func:`random_pairs`, :func:`warped_pairs`) are shared with ``scripts/bench_dtw.py``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from torchhand.kernels.dtw import DTWResult, dtw, pairwise_cost
from torchhand.kernels.status import SolverStatus

CONVERGED, INFEASIBLE, INVALID = (int(SolverStatus.CONVERGED), int(SolverStatus.INFEASIBLE),
                                  int(SolverStatus.INVALID_INPUT))
RTOL = {torch.float32: 2e-6, torch.float64: 1e-12}


pytestmark = pytest.mark.usefixtures("one_intra_op_thread")


# ----------------------------------------------------------------------------------------------- input builders
def random_pairs(B: int, n: int, m: int, d: int, gen: torch.Generator, *, dtype=torch.float64, device="cpu"):
    """B pairs of random-walk sequences (B, n, d) and (B, m, d): smooth like motion features, no ties."""
    x = torch.randn(B, n, d, generator=gen, dtype=torch.float64).cumsum(1) * 0.1
    y = torch.randn(B, m, d, generator=gen, dtype=torch.float64).cumsum(1) * 0.1
    return x.to(device=device, dtype=dtype), y.to(device=device, dtype=dtype)


def warped_pairs(B: int, n: int, m: int, d: int, gen: torch.Generator, *, dtype=torch.float64, device="cpu"):
    """B pairs where y is a monotone time warp of x plus noise (the splicing use case)."""
    x = torch.randn(B, n, d, generator=gen, dtype=torch.float64).cumsum(1) * 0.1
    speed = torch.rand(B, m, generator=gen, dtype=torch.float64) + 0.5
    t = speed.cumsum(1)
    t = (t - t[:, :1]) / (t[:, -1:] - t[:, :1]) * (n - 1)                   # monotone map [0, m-1] -> [0, n-1]
    i0 = t.floor().long().clamp(max=n - 2) if n > 1 else t.long() * 0
    a = (t - i0).unsqueeze(-1)
    x0 = x.gather(1, i0.unsqueeze(-1).expand(B, m, d))
    x1 = x.gather(1, (i0 + 1).clamp(max=n - 1).unsqueeze(-1).expand(B, m, d))
    y = (1 - a) * x0 + a * x1 + 0.01 * torch.randn(B, m, d, generator=gen, dtype=torch.float64)
    return x.to(device=device, dtype=dtype), y.to(device=device, dtype=dtype)


def random_corridors(B: int, n: int, m: int, rng: np.random.Generator, *, monotone: bool = True):
    """Column limits (col_lo, col_hi), (B, n) long. monotone: around a random increasing line from (0, 0) to
    (n-1, m-1), wide enough for a path; otherwise independent random intervals (rows may be empty or disjoint)."""
    lo, hi = np.empty((B, n), dtype=np.int64), np.empty((B, n), dtype=np.int64)
    for b in range(B):
        if monotone:
            steps = rng.uniform(0.2, 1.0, size=n)
            t = np.concatenate([[0.0], np.cumsum(steps[1:])])
            centre = np.round(t / max(t[-1], 1e-12) * (m - 1)) if n > 1 else np.zeros(1)
            reach = int(math.ceil(m / n))
            lo[b] = np.maximum(centre - reach - rng.integers(0, 3, size=n), 0)
            hi[b] = np.minimum(centre + reach + rng.integers(0, 3, size=n), m - 1)
        else:
            lo[b] = rng.integers(-2, m, size=n)
            hi[b] = lo[b] + rng.integers(-1, m // 2 + 2, size=n)
    return torch.from_numpy(lo), torch.from_numpy(hi)


# ------------------------------------------------------------------------------------------ plain references
def paper_mask(n, m, W=None, anchors=(), T=0.0):
    """Allowed cells, straight from Eq. 3 / Algorithm 1 with 1-based (i, j); bounds read in absolute columns."""
    mask = np.zeros((n, m), dtype=bool)
    xs = [0] + [a[0] + 1 for a in anchors] + [n]
    ys = [0] + [a[1] + 1 for a in anchors] + [m]
    for k in range(1, len(xs)):
        dx, dy = xs[k] - xs[k - 1], ys[k] - ys[k - 1]
        for i in range(xs[k - 1] + 1, xs[k] + 1):
            ik = i - xs[k - 1]
            lb, ub = max(1, ys[k - 1] - T), min(m, ys[k] + T)
            if W is not None:
                delta = W * math.sqrt(dx * dx + dy * dy) / dx
                lb = max(lb, ys[k - 1] + dy / dx * ik - delta - 1e-9)
                ub = min(ub, ys[k - 1] + dy / dx * ik + delta + 1e-9)
            for j in range(1, m + 1):
                if lb <= j <= ub:
                    mask[i - 1, j - 1] = True
    return mask


def limits_mask(lo, hi, m):
    """Cells allowed by per-row column limits (1-D sequences of length n, inclusive)."""
    j = np.arange(m)
    return (j[None, :] >= np.asarray(lo)[:, None]) & (j[None, :] <= np.asarray(hi)[:, None])


def naive_dtw(c, mask=None, anchors=(), T=0.0):
    """Plain O(n m) DP with loops; from an anchor row x the path must leave at a column >= y - T. Returns (D, path)."""
    n, m = c.shape
    mask = np.ones((n, m), dtype=bool) if mask is None else mask
    exit_lo = np.zeros(n)
    for x, y in anchors:
        exit_lo[x] = y - T
    D = np.full((n, m), np.inf)
    for i in range(n):
        for j in range(m):
            if not mask[i, j]:
                continue
            if i == 0 and j == 0:
                D[i, j] = c[i, j]
                continue
            best = np.inf
            if i > 0 and j > 0 and j - 1 >= exit_lo[i - 1]:
                best = min(best, D[i - 1, j - 1])
            if i > 0 and j >= exit_lo[i - 1]:
                best = min(best, D[i - 1, j])
            if j > 0:
                best = min(best, D[i, j - 1])
            D[i, j] = c[i, j] + best
    return D[n - 1, m - 1]


def brute_force_dtw(c, mask, anchors=(), T=0.0):
    """Least cost over ALL monotone paths inside ``mask`` that meet each anchor row within T of the anchor."""
    n, m = c.shape
    best = np.inf

    def walk(i, j, acc, cells):
        nonlocal best
        if not mask[i, j]:
            return
        acc += c[i, j]
        cells = cells + [(i, j)]
        if (i, j) == (n - 1, m - 1):
            if all(any(ci == x and abs(cj - y) <= T for ci, cj in cells) for x, y in anchors):
                best = min(best, acc)
            return
        for di, dj in ((1, 1), (1, 0), (0, 1)):
            if i + di < n and j + dj < m:
                walk(i + di, j + dj, acc, cells)

    walk(0, 0, 0.0, [])
    return best


def check_path(res: DTWResult, cost: torch.Tensor, anchors=None, T=0.0, col_lo=None, col_hi=None):
    """Monotone, contiguous, from (0,0) to (n-1,m-1), padded with -1, inside the column limits; its cost equals the
    distance."""
    B, n, m = cost.shape
    for b in range(B):
        L = int(res.path_length[b])
        p = res.path[b].cpu()
        if int(res.status[b]) != CONVERGED:
            assert L == 0 and bool((p == -1).all()) and math.isinf(float(res.distance[b]))
            continue
        assert max(n, m) <= L <= n + m - 1
        assert bool((p[L:] == -1).all())
        q = p[:L]
        assert q[0].tolist() == [0, 0] and q[-1].tolist() == [n - 1, m - 1]
        steps = q[1:] - q[:-1]
        assert bool(((steps >= 0) & (steps <= 1)).all()) and bool((steps.sum(1) >= 1).all())
        pc = cost[b].double().cpu()[q[:, 0], q[:, 1]].sum()
        rel = 1e-12 if cost.dtype == torch.float64 else 1e-6
        assert float(pc) == pytest.approx(float(res.distance[b]), rel=rel, abs=1e-9)
        if col_lo is not None:
            assert bool((q[:, 1] >= col_lo[b].cpu()[q[:, 0]]).all() and (q[:, 1] <= col_hi[b].cpu()[q[:, 0]]).all())
        for x, y in (anchors[b] if anchors is not None else []):
            cols = q[q[:, 0] == x, 1]
            assert bool(((cols - y).abs() <= T).any()), (b, x, y, cols.tolist())


# --------------------------------------------------------------------------------------------------- tests
@pytest.mark.parametrize("B", [1, 7])
def test_smoke_shapes(B, dtype, device, gen):
    x, y = random_pairs(B, 11, 16, 3, gen, dtype=dtype, device=device)
    cost = pairwise_cost(x, y)
    assert cost.shape == (B, 11, 16) and cost.dtype == dtype
    res = dtw(cost, band=3.0)
    assert isinstance(res, DTWResult)
    assert res.distance.shape == (B,) and res.distance.dtype == dtype and res.distance.device.type == device
    assert res.path.shape == (B, 11 + 16 - 1, 2) and res.path.dtype == torch.long
    assert res.path_length.shape == (B,) and res.status.shape == (B,) and res.status.dtype == torch.int8
    assert bool((res.status == CONVERGED).all())
    check_path(res, cost)


@pytest.mark.parametrize("d", [1, 3])
def test_pairwise_cost(d, dtype, gen):
    """Against numpy (the 1-feature case has its own code path); exact zeros; gradients in float64."""
    x, y = random_pairs(2, 5, 7, d, gen, dtype=dtype)
    ref = np.sqrt(((x.double().numpy()[:, :, None] - y.double().numpy()[:, None]) ** 2).sum(-1))
    tol = dict(rtol=1e-12, atol=1e-14) if dtype == torch.float64 else dict(rtol=1e-5, atol=1e-6)
    for squared in (False, True):
        c = pairwise_cost(x, y, squared=squared)
        assert c.shape == (2, 5, 7) and c.dtype == dtype
        np.testing.assert_allclose(c.double().numpy(), ref ** 2 if squared else ref, **tol)
    assert bool((pairwise_cost(x, x).diagonal(dim1=1, dim2=2) == 0).all())
    xg, yg = x.double().requires_grad_(), y.double().requires_grad_()
    for squared in (False, True):
        assert torch.autograd.gradcheck(lambda a, b: pairwise_cost(a, b, squared=squared), (xg, yg))


def test_against_naive_dp_unconstrained(dtype, gen):
    for n, m in [(1, 1), (1, 6), (6, 1), (2, 9), (13, 7), (20, 20), (31, 17)]:
        x, y = random_pairs(5, n, m, 2, gen, dtype=dtype)
        cost = pairwise_cost(x, y)
        res = dtw(cost)
        ref = [naive_dtw(cost[b].double().numpy()) for b in range(5)]
        torch.testing.assert_close(res.distance.double(), torch.tensor(ref, dtype=torch.float64),
                                   rtol=RTOL[dtype], atol=1e-12)
        check_path(res, cost)


def test_against_naive_dp_band(gen):
    rng = np.random.default_rng(0)
    for trial in range(25):
        n, m = int(rng.integers(1, 25)), int(rng.integers(1, 25))
        W = float(rng.uniform(0.0, 6.0))
        cost = torch.rand(3, n, m, generator=gen, dtype=torch.float64)
        res = dtw(cost, band=W)
        mask = paper_mask(n, m, W)
        ref = np.array([naive_dtw(cost[b].numpy(), mask) for b in range(3)])
        np.testing.assert_allclose(res.distance.numpy(), ref, rtol=1e-12)   # inf where the band blocks every path
        assert bool(((res.status == INFEASIBLE) == torch.from_numpy(np.isinf(ref))).all())
        assert not bool(torch.isnan(res.distance).any())
        check_path(res, cost)


def _random_anchors(rng, n, m, A):
    xs = np.sort(rng.choice(np.arange(0, n - 1), size=min(A, n - 1), replace=False)) if n > 1 else []
    ys = np.sort(rng.choice(np.arange(0, m - 1), size=min(A, m - 1), replace=False)) if m > 1 else []
    k = min(len(xs), len(ys))
    return [(int(a), int(b)) for a, b in zip(xs[:k], ys[:k])]


def test_against_naive_dp_anchors(gen):
    rng = np.random.default_rng(1)
    for trial in range(30):
        n, m = int(rng.integers(2, 22)), int(rng.integers(2, 22))
        W = None if trial % 3 == 0 else float(rng.uniform(0.5, 6.0))
        T = int(rng.integers(0, 3))
        anchors = [_random_anchors(rng, n, m, int(rng.integers(0, 4))) for _ in range(3)]
        cost = torch.rand(3, n, m, generator=gen, dtype=torch.float64)
        res = dtw(cost, band=W, anchors=anchors, tolerance=T)
        for b in range(3):
            mask = paper_mask(n, m, W, anchors[b], T)
            ref = naive_dtw(cost[b].numpy(), mask, anchors[b], T)
            assert float(res.distance[b]) == pytest.approx(ref, rel=1e-12) or (math.isinf(ref) and
                                                                                 math.isinf(res.distance[b]))
            assert int(res.status[b]) == (INFEASIBLE if math.isinf(ref) else CONVERGED)
        check_path(res, cost, anchors, T)


def test_against_exhaustive_enumeration(gen):
    """Every monotone path of small matrices: the DP's semantics of band + anchors + tolerance, independently."""
    rng = np.random.default_rng(2)
    for trial in range(40):
        n, m = int(rng.integers(2, 7)), int(rng.integers(2, 7))
        W = None if trial % 2 else float(rng.uniform(0.3, 3.0))
        T = int(rng.integers(0, 2))
        anchors = _random_anchors(rng, n, m, int(rng.integers(0, 3)))
        cost = torch.rand(1, n, m, generator=gen, dtype=torch.float64)
        res = dtw(cost, band=W, anchors=[anchors], tolerance=T)
        ref = brute_force_dtw(cost[0].numpy(), paper_mask(n, m, W, anchors, T), anchors, T)
        if math.isinf(ref):
            assert int(res.status[0]) == INFEASIBLE and math.isinf(res.distance[0])
        else:
            assert float(res.distance[0]) == pytest.approx(ref, rel=1e-12)
        check_path(res, cost, [anchors], T)


def test_against_tslearn(gen):
    tsm = pytest.importorskip("tslearn.metrics")
    for n, m, r in [(9, 9, None), (17, 23, None), (40, 40, None), (30, 30, 0), (30, 30, 2), (41, 41, 7)]:
        x, y = random_pairs(4, n, m, 3, gen)
        cost = pairwise_cost(x, y, squared=True)
        W = None if r is None else (r + 0.5) / math.sqrt(2.0)     # n = m: Eq. 3 is |i - j| <= floor(W sqrt 2) = r
        res = dtw(cost, band=W)
        for b in range(4):
            kw = {} if r is None else dict(global_constraint="sakoe_chiba", sakoe_chiba_radius=r)
            path, d = tsm.dtw_path_from_metric(cost[b].numpy(), metric="precomputed", **kw)
            assert float(res.distance[b]) == pytest.approx(d, rel=1e-12)
            assert res.path[b, : int(res.path_length[b])].tolist() == [list(p) for p in path]


def test_against_dtaidistance(gen):
    dnd = pytest.importorskip("dtaidistance.dtw_ndim")
    for n, m, r in [(12, 12, None), (25, 19, None), (50, 50, 3), (64, 64, 10)]:
        x, y = warped_pairs(3, n, m, 2, gen)
        cost = pairwise_cost(x, y, squared=True)
        res = dtw(cost, band=None if r is None else (r + 0.5) / math.sqrt(2.0))
        for b in range(3):
            kw = {} if r is None else dict(window=r + 1)                  # dtaidistance: |i - j| < window
            d = dnd.distance(x[b].numpy(), y[b].numpy(), use_c=True, **kw)
            assert math.sqrt(float(res.distance[b])) == pytest.approx(d, rel=1e-10)
            path = dnd.warping_path(x[b].numpy(), y[b].numpy(), **kw)
            assert res.path[b, : int(res.path_length[b])].tolist() == [list(p) for p in path]


def test_invariants_seeded(gen):
    for trial in range(10):
        B, n, m = 4, 5 + 3 * trial, 7 + 2 * trial
        x, y = warped_pairs(B, n, m, 3, gen)
        cost = pairwise_cost(x, y)
        # dtw(x, x) = 0 along the diagonal.
        self_res = dtw(pairwise_cost(x, x), band=1.0)
        assert bool((self_res.distance == 0).all())
        assert bool((self_res.path_length == n).all())
        assert torch.equal(self_res.path[:, :n], torch.arange(n).view(1, n, 1).expand(B, n, 2))
        free = dtw(cost)
        check_path(free, cost)
        # Constraints only remove paths: distances can only grow.
        W = 0.3 * max(n, m)
        banded = dtw(cost, band=W)
        assert bool((banded.distance >= free.distance - 1e-12).all())
        rng = np.random.default_rng(trial)
        anchors = [_random_anchors(rng, n, m, 2) for _ in range(B)]
        for T in (0, 1, 3):
            anch = dtw(cost, band=W, anchors=anchors, tolerance=T)
            check_path(anch, cost, anchors, T)
            assert bool((anch.distance >= banded.distance - 1e-12).all())      # inf when infeasible
        # The distance is symmetric under swapping the sequences (transposed cost).
        swapped = dtw(cost.transpose(1, 2).contiguous())
        torch.testing.assert_close(swapped.distance, free.distance, rtol=1e-12, atol=0)


def test_code_paths_agree(gen, monkeypatch):
    """Window vs full rows, one numeric band vs a per-pair tensor band, chunk sizes, one or two ops to interleave
    the predecessors: identical results."""
    import torchhand.kernels.dtw as dtw_module

    x, y = warped_pairs(6, 40, 33, 3, gen)
    cost = pairwise_cost(x, y)
    for W in (None, 1.5, 4.0):
        ref = dtw(cost, band=W)
        as_tensor = dtw(cost, band=None if W is None else torch.full((6,), W, dtype=torch.float64))
        assert torch.equal(ref.path, as_tensor.path) and torch.equal(ref.distance, as_tensor.distance)
        for name, value in (("_CHUNK_CELLS", 1), ("_CHUNK_CELLS", 7 * 6 * 33), ("_WINDOW_MAX_FRACTION", 0.0),
                            ("_SPLIT_CELLS", 0)):
            monkeypatch.setattr(dtw_module, name, value)           # 1 row per chunk, 7 rows, full rows, two adds
            other = dtw(cost, band=W)
            monkeypatch.undo()
            assert torch.equal(ref.path, other.path) and torch.equal(ref.status, other.status)
            torch.testing.assert_close(other.distance, ref.distance, rtol=1e-14, atol=0)


@pytest.mark.parametrize("B", [1, 7])
def test_column_limits_against_naive_dp(B, dtype, gen, monkeypatch):
    """Per-row column limits (monotone corridors and arbitrary intervals), alone and with a band, n != m."""
    import torchhand.kernels.dtw as dtw_module

    rng = np.random.default_rng(3)
    feasible = 0
    for trial in range(16):
        n, m = int(rng.integers(2, 28)), int(rng.integers(2, 28))
        m += m == n
        W = None if trial % 3 == 0 else float(rng.uniform(1.0, 8.0))
        lo, hi = random_corridors(B, n, m, rng, monotone=trial % 4 != 3)
        cost = torch.rand(B, n, m, generator=gen, dtype=torch.float64).to(dtype)
        res = dtw(cost, band=W, col_lo=lo, col_hi=hi)
        band_mask = paper_mask(n, m, W) if W is not None else np.ones((n, m), dtype=bool)
        ref = np.array([naive_dtw(cost[b].double().numpy(), band_mask & limits_mask(lo[b], hi[b], m))
                        for b in range(B)])
        inf = torch.from_numpy(np.isinf(ref))
        assert res.status.tolist() == torch.where(inf, INFEASIBLE, CONVERGED).tolist()
        assert not bool(torch.isnan(res.distance).any()) and bool(torch.isinf(res.distance[inf]).all())
        torch.testing.assert_close(res.distance.double()[~inf], torch.from_numpy(ref)[~inf], rtol=RTOL[dtype],
                                   atol=0)
        check_path(res, cost, col_lo=lo, col_hi=hi)
        feasible += int((~inf).sum())
        # Full rows (no window) give the same result.
        monkeypatch.setattr(dtw_module, "_WINDOW_MAX_FRACTION", 0.0)
        full = dtw(cost, band=W, col_lo=lo, col_hi=hi)
        monkeypatch.undo()
        assert torch.equal(full.status, res.status)
        torch.testing.assert_close(full.distance, res.distance, rtol=RTOL[dtype], atol=0)
    assert feasible >= 8 * B


def test_column_limits_edge_cases(gen):
    cost = torch.rand(3, 9, 14, generator=gen, dtype=torch.float64)
    lo = torch.zeros(3, 9, dtype=torch.long)
    hi = torch.full((3, 9), 13, dtype=torch.long)
    # Limits that allow everything (also beyond the matrix) change nothing; only one of the two may be given.
    free = dtw(cost)
    for kw in (dict(col_lo=lo - 5, col_hi=hi + 5), dict(col_lo=lo), dict(col_hi=hi)):
        res = dtw(cost, **kw)
        assert torch.equal(res.path, free.path) and torch.equal(res.distance, free.distance)
    # An empty row (pair 0), limits that exclude the start (pair 1) or the end (pair 2): infeasible, never NaN.
    lo2, hi2 = lo.clone(), hi.clone()
    lo2[0, 4], hi2[0, 4] = 7, 6
    lo2[1, 0] = 1
    hi2[2, 8] = 12
    res = dtw(cost, col_lo=lo2, col_hi=hi2)
    assert res.status.tolist() == [INFEASIBLE] * 3 and bool(torch.isinf(res.distance).all())
    assert bool((res.path == -1).all()) and bool((res.path_length == 0).all())
    # Limits combine with anchors (intersection): a corridor through the matching point keeps it.
    anchors = [[(4, 6)], [], [(2, 3)]]
    lo3, hi3 = random_corridors(3, 9, 14, np.random.default_rng(4))
    res = dtw(cost, anchors=anchors, tolerance=1, col_lo=lo3, col_hi=hi3)
    for b in range(3):
        mask = paper_mask(9, 14, None, anchors[b], 1) & limits_mask(lo3[b], hi3[b], 14)
        ref = naive_dtw(cost[b].numpy(), mask, anchors[b], 1)
        assert float(res.distance[b]) == pytest.approx(ref, rel=1e-12) or (math.isinf(ref) and
                                                                            int(res.status[b]) == INFEASIBLE)
    check_path(res, cost, anchors, 1, col_lo=lo3, col_hi=hi3)


def test_wide_rows_use_the_int32_store(gen):
    """Windows over 16384 columns pack the argmins in int32 instead of int16."""
    n, m = 3, 17000
    cost = torch.rand(1, n, m, generator=gen, dtype=torch.float64)
    res = dtw(cost)
    assert float(res.distance[0]) == pytest.approx(naive_dtw(cost[0].numpy()), rel=1e-12)
    check_path(res, cost)


def test_diagonal_preference_breaks_ties(gen):
    zero = torch.zeros(1, 6, 6, dtype=torch.float64)
    corner = [[0, j] for j in range(6)] + [[i, 5] for i in range(1, 6)]
    assert dtw(zero).path[0].tolist() == corner                          # documented default tie-breaking
    res = dtw(zero, diagonal=1e-3)
    assert res.path[0, :6].tolist() == [[i, i] for i in range(6)] and int(res.path_length[0]) == 6
    assert float(res.distance[0]) == 0.0                                  # the caller's cost, not the penalty
    # With a band the path no longer hugs the band's edge.
    res = dtw(torch.zeros(2, 30, 30, dtype=torch.float64), band=4.0, diagonal=1e-3)
    assert torch.equal(res.path[:, :30], torch.arange(30).view(1, 30, 1).expand(2, 30, 2))
    # n != m: the path minimises the penalty alone (naive DP on the penalty as a cost).
    n, m = 7, 12
    i, j = np.meshgrid(np.arange(n) / (n - 1), np.arange(m) / (m - 1), indexing="ij")
    pen = 0.5 * (i - j) ** 2
    res = dtw(torch.zeros(1, n, m, dtype=torch.float64), diagonal=0.5)
    q = res.path[0, : int(res.path_length[0])].numpy()
    assert pen[q[:, 0], q[:, 1]].sum() == pytest.approx(naive_dtw(pen), rel=1e-12)
    # Integer costs with many ties: eps < 1 / (n + m - 1) keeps the least distance; paths stay valid.
    for B, n, m in [(1, 15, 15), (7, 20, 31)]:
        cost = torch.randint(0, 3, (B, n, m), generator=gen).double()
        plain = dtw(cost, band=6.0)
        tied = dtw(cost, band=6.0, diagonal=0.9 / (n + m - 1))
        assert torch.equal(tied.distance, plain.distance)
        check_path(tied, cost)
    # n or m = 1: no penalty, nothing to break.
    one = torch.rand(2, 1, 5, generator=gen, dtype=torch.float64)
    assert torch.equal(dtw(one, diagonal=1.0).path, dtw(one).path)


def test_anchor_exactly_on_path_with_zero_tolerance(gen):
    cost = torch.rand(2, 30, 40, generator=gen, dtype=torch.float64)
    anchors = torch.tensor([[[5, 30], [20, 32]], [[10, 3], [-1, -1]]])
    res = dtw(cost, anchors=anchors, tolerance=0)
    for b, pts in enumerate([[(5, 30), (20, 32)], [(10, 3)]]):
        cells = set(map(tuple, res.path[b, : int(res.path_length[b])].tolist()))
        assert all(p in cells for p in pts)
    # A list and a padded tensor (in any order of points) mean the same thing.
    res2 = dtw(cost, anchors=[[(20, 32), (5, 30)], [(10, 3)]], tolerance=0)
    assert torch.equal(res.path, res2.path) and torch.equal(res.distance, res2.distance)


def test_infeasible_is_inf_not_nan(gen):
    cost = torch.rand(3, 5, 12, generator=gen, dtype=torch.float64)
    res = dtw(cost, band=0.0)                  # slope 12/5 off-integer: no monotone path along the line
    assert bool((res.status == INFEASIBLE).all()) and bool(torch.isinf(res.distance).all())
    assert bool((res.path_length == 0).all()) and bool((res.path == -1).all())
    # A steep first segment (slope 5.5) with W = 0 leaves row 0 without an integer column; (4, 11) is the end
    # point (ignored); a matching point on the last row is outside the paper's domain (invalid).
    res = dtw(cost, band=0.0, anchors=[[(1, 10)], [], [(4, 3)]], tolerance=1)
    assert res.status.tolist() == [INFEASIBLE, INFEASIBLE, INVALID]
    res = dtw(cost, anchors=[[(1, 10)], [(4, 11)], [(2, 3)]], tolerance=1)
    assert res.status.tolist() == [CONVERGED] * 3
    assert torch.equal(res.distance[1], dtw(cost[1:2]).distance[0])
    assert not bool(torch.isnan(res.distance).any())


def test_invalid_inputs_are_flagged_per_pair(gen):
    cost = torch.rand(4, 8, 9, generator=gen, dtype=torch.float64)
    cost[1, 3, 4] = float("nan")
    cost[2, 0, 0] = float("inf")
    res = dtw(cost)
    assert res.status.tolist() == [CONVERGED, INVALID, INVALID, CONVERGED]
    assert not bool(torch.isnan(res.distance).any()) and bool(torch.isinf(res.distance[1:3]).all())
    ok = dtw(cost[[0, 3]])
    torch.testing.assert_close(res.distance[[0, 3]], ok.distance)            # one bad pair poisons nothing
    cost = torch.rand(4, 8, 9, generator=gen, dtype=torch.float64)
    # x repeated; y repeated; x out of range (n = 8); a negative index that is not the (-1, -1) padding.
    anchors = [[(3, 3), (3, 5)], [(3, 3), (5, 3)], [(8, 2)], [(-2, 1)]]
    res = dtw(cost, anchors=anchors)
    assert res.status.tolist() == [INVALID] * 4
    res = dtw(cost, band=torch.tensor([1.0, -1.0, float("nan"), 2.0]), tolerance=torch.tensor([0.0, 0, 0, -1]))
    assert res.status.tolist() == [CONVERGED, INVALID, INVALID, INVALID]


def test_bad_arguments_raise():
    c = torch.rand(2, 4, 5)
    with pytest.raises(ValueError, match="cost"):
        dtw(torch.rand(4, 5))
    with pytest.raises(TypeError, match="cost"):
        dtw(torch.ones(2, 4, 5, dtype=torch.long))
    with pytest.raises(TypeError, match="cost"):
        dtw(np.zeros((2, 4, 5)))
    with pytest.raises(ValueError, match="band"):
        dtw(c, band=-1.0)
    with pytest.raises(ValueError, match="band"):
        dtw(c, band=torch.ones(3))
    with pytest.raises(TypeError, match="tolerance"):
        dtw(c, tolerance="1")
    with pytest.raises(ValueError, match="anchors"):
        dtw(c, anchors=torch.zeros(2, 3, 3, dtype=torch.long))
    with pytest.raises(TypeError, match="anchors"):
        dtw(c, anchors=torch.zeros(2, 3, 2))
    with pytest.raises(ValueError, match="anchors"):
        dtw(c, anchors=[[(1, 1)]])
    with pytest.raises(ValueError, match="anchors"):
        dtw(c, anchors=[[(1, 1, 1)], []])
    with pytest.raises(ValueError, match="x, y"):
        pairwise_cost(torch.rand(2, 4, 3), torch.rand(2, 5, 2))
    lim = torch.zeros(2, 4, dtype=torch.long)
    with pytest.raises(TypeError, match="col_lo"):
        dtw(c, col_lo=lim.float())
    with pytest.raises(TypeError, match="col_hi"):
        dtw(c, col_hi=[[0, 1, 2, 3], [0, 1, 2, 3]])
    with pytest.raises(ValueError, match="col_lo"):
        dtw(c, col_lo=torch.zeros(2, 5, dtype=torch.long))
    with pytest.raises(ValueError, match="col_hi"):
        dtw(c, col_hi=torch.zeros(4, dtype=torch.long))
    with pytest.raises(ValueError, match="diagonal"):
        dtw(c, diagonal=-1e-3)
    with pytest.raises(ValueError, match="diagonal"):
        dtw(c, diagonal=float("nan"))
    with pytest.raises(TypeError, match="diagonal"):
        dtw(c, diagonal="1")


def test_float32_accumulates_in_float64(gen):
    x, y = random_pairs(2, 569, 569, 4, gen)
    c64 = pairwise_cost(x, y)
    r64 = dtw(c64, band=40.0)
    r32 = dtw(c64.float(), band=40.0)
    assert r32.distance.dtype == torch.float32
    torch.testing.assert_close(r32.distance.double(), r64.distance, rtol=2e-6, atol=0)
    check_path(r32, c64.float())


def test_gradient_is_path_indicator(gen):
    cost = torch.rand(2, 9, 7, generator=gen, dtype=torch.float64, requires_grad=True)
    res = dtw(cost, band=2.0)
    res.distance.sum().backward()
    ind = torch.zeros(2, 9, 7, dtype=torch.float64)
    for b in range(2):
        q = res.path[b, : int(res.path_length[b])]
        ind[b, q[:, 0], q[:, 1]] = 1.0
    assert torch.equal(cost.grad, ind)
