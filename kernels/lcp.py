"""Batched projected Gauss-Seidel (PGS) for standard linear complementarity problems.

For every problem b of the batch, find x such that

    x >= 0,   w = M x + q >= 0,   x^T w = 0                                   (LCP(M, q))

M (B, n, n) need not be symmetric, but every (active) diagonal entry must be positive: that is what a Gauss-Seidel
step divides by. Convergence is guaranteed for symmetric positive definite M, for symmetric positive semidefinite M
with a solution (slowly when M is far from full rank: thousands of sweeps), and for strictly diagonally dominant
M; otherwise the solver reports what it reached (MAX_ITERATIONS, or UNBOUNDED when the iterate blew up) and never
a silent NaN. Exact reference and fallback: :func:`torchhand.solvers._lemke.lemke` and
:func:`torchhand.solvers.lcp.solve_lcp`.

Method: one sweep updates x_i <- max(0, x_i - omega * w_i / M_ii) for i = 0..n-1 in order, keeping w = M x + q up
to date with one column update per coordinate. The sweep over i is inherently sequential; it is vectorised over
the batch in a structure-of-arrays layout (coordinates leading, problems contiguous). Options:

- ``omega``: successive over-relaxation (1 = plain PGS, the default; 1 < omega < 2 often needs fewer sweeps).
- ``subspace``: at every convergence check, problems not yet converged also try a subspace-minimisation step
  (PGS-SM, Silcowitz, Niebe & Erleben 2010): solve M_FF x_F = -q_F on the free set F = {x_i > 0} estimated by the
  sweeps, project onto x >= 0 and keep it where it lowers the residual. It finishes well-conditioned problems to
  machine precision once PGS has found the active set, at the price of one batched LU per check (on a CPU that
  costs about as much as a dozen sweeps; singular M_FF, e.g. from rank-deficient PSD M, gains nothing).
- ``mixed``: for float64 problems, the sweeps between two checks run in float32 (half the memory traffic, about
  twice as fast per sweep on a CPU) and only their correction x_new - x_check, itself a float32 unknown bounded
  below by -x_check, is added to the float64 iterate; every check recomputes w = M x + q exactly in float64, so
  the rounding of one phase is corrected by the next (iterative refinement) and the returned residual is the exact
  float64 one.

Convergence is decided per problem every ``check_every`` sweeps (the only host syncs), from the exact residual
||min(x, M x + q)||_inf; converged problems are removed from the working set, so stragglers cost little.
Padding: an optional boolean ``mask`` (B, n) marks active entries; padded entries behave as x_i = w_i = 0 and are
ignored by the residual. Pure tensor code: device and dtype come from the inputs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import torch

from .status import SolverStatus

__all__ = ["LCPResult", "LCPTolerances", "lcp_tolerances", "lcp_residual", "solve_lcp_pgs"]


@dataclass(frozen=True)
class LCPTolerances:
    """Per-dtype defaults of the LCP kernels.

    tol: absolute tolerance on the residual ||min(x, w)||_inf (units of x and w) for CONVERGED
    max_iters: default limit on PGS sweeps
    blowup: an iterate entry beyond this magnitude counts as diverged (status UNBOUNDED)
    """

    tol: float
    max_iters: int
    blowup: float


_TOLERANCES: tuple[tuple[torch.dtype, LCPTolerances], ...] = (
    (torch.float64, LCPTolerances(tol=1e-10, max_iters=2000, blowup=1e150)),
    (torch.float32, LCPTolerances(tol=1e-5, max_iters=1000, blowup=1e30)),
)


def lcp_tolerances(dtype: torch.dtype) -> LCPTolerances:
    """The tolerance row of ``dtype`` (float32 or float64)."""
    for d, t in _TOLERANCES:
        if d == dtype:
            return t
    raise ValueError(f"solve_lcp_pgs: dtype must be float32 or float64, got {dtype}")


class LCPResult(NamedTuple):
    """Result of a batched LCP solve (B problems of size n).

    x:          solution, (B, n), >= 0; 0 at padded entries and for INVALID_INPUT problems
    w:          M x + q, (B, n); 0 at padded entries and for INVALID_INPUT problems
    residual:   ||min(x, w)||_inf over the active entries, (B,); +inf for INVALID_INPUT
    status:     (B,), int8 values of :class:`torchhand.kernels.status.SolverStatus`
    iterations: sweeps spent on each problem, (B,), int32 (a multiple of ``check_every`` or ``max_iters``)
    """

    x: torch.Tensor
    w: torch.Tensor
    residual: torch.Tensor
    status: torch.Tensor
    iterations: torch.Tensor


def lcp_residual(x: torch.Tensor, w: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """||min(x, w)||_inf per problem: x, w (B, n); mask (B, n) bool or None -> (B,). 0 for n = 0."""
    r = torch.minimum(x, w).abs()
    if mask is not None:
        r = torch.where(mask, r, torch.zeros_like(r))
    if r.shape[-1] == 0:
        return r.new_zeros(r.shape[:-1])
    return r.amax(-1)


def _check(x, name: str, shape: tuple, *, floating: bool = True) -> None:
    if not isinstance(x, torch.Tensor):
        raise ValueError(f"solve_lcp_pgs: {name} must be a torch.Tensor of shape {shape}, got {type(x).__name__}")
    if tuple(x.shape) != tuple(shape):
        raise ValueError(f"solve_lcp_pgs: {name} must have shape {tuple(shape)}, got {tuple(x.shape)}")
    if floating and not x.is_floating_point():
        raise ValueError(f"solve_lcp_pgs: {name} must be floating point, got {x.dtype}")


def _sweeps(Mc: torch.Tensor, X: torch.Tensor, W: torch.Tensor, neg_step: torch.Tensor, sweeps: int,
            lower: torch.Tensor | None = None) -> None:
    """``sweeps`` PGS sweeps in place. Structure of arrays: Mc (n, n, Bw) with Mc[i] = column i of every problem
    as (n, Bw); X, W (n, Bw) the iterate and M x + q; neg_step (n, Bw) = -omega / M_ii; lower (n, Bw) the bound
    on X (None: 0)."""
    n = X.shape[0]
    cols, xs, ws, steps = Mc.unbind(0), X.unbind(0), W.unbind(0), neg_step.unbind(0)
    lows = lower.unbind(0) if lower is not None else None
    new = torch.empty_like(X[0]) if n else X
    for _ in range(sweeps):
        for i in range(n):
            xi = xs[i]
            torch.addcmul(xi, ws[i], steps[i], out=new)
            if lows is None:
                new.clamp_min_(0)
            else:
                torch.maximum(new, lows[i], out=new)
            xi.sub_(new).neg_()                                    # xi <- the step new - x_i
            W.addcmul_(cols[i], xi)
            xi.copy_(new)


def _exact_w(Mw: torch.Tensor, X: torch.Tensor, Q: torch.Tensor) -> torch.Tensor:
    """M x + q from the row-major Mw (Bw, n, n); X, Q (n, Bw) structure of arrays -> (n, Bw). Computed as the
    row vectors x^T M^T (the fastest batched product here)."""
    Wt = torch.bmm(X.t().contiguous()[:, None, :], Mw.transpose(1, 2)).squeeze(1)
    return Wt.t().add(Q)


def _residual_soa(X: torch.Tensor, W: torch.Tensor, A: torch.Tensor | None) -> torch.Tensor:
    """||min(x, w)||_inf over active entries (A None: all), structure of arrays: X, W, A (n, Bw) -> (Bw,)."""
    r = torch.minimum(X, W).abs_()
    if A is not None:
        r.masked_fill_(~A, 0)
    return r.amax(0) if r.shape[0] else r.new_zeros(r.shape[1:])


def _subspace_step(M: torch.Tensor, X: torch.Tensor, Q: torch.Tensor, A: torch.Tensor | None) -> torch.Tensor:
    """max(0, solution of M_FF x_F = -q_F with x = 0 off F), F = {x > 0} (active); X where the solve fails.
    M (Bw, n, n) row-major; X, Q, A (n, Bw) structure of arrays (A None: all active) -> (n, Bw)."""
    free = (X > 0 if A is None else (X > 0) & A).t()                 # (Bw, n)
    zero = torch.zeros((), dtype=X.dtype, device=X.device)
    K = torch.where(free[:, :, None] & free[:, None, :], M, zero)
    K.diagonal(dim1=1, dim2=2).add_((~free).to(X.dtype))
    sol, info = torch.linalg.solve_ex(K, torch.where(free, -Q.t(), zero))
    ok = (info == 0) & torch.isfinite(sol).all(-1)
    return torch.where(ok[None, :], sol.t().clamp_min(0), X)


def _to_soa(M: torch.Tensor, dtype: torch.dtype | None = None, chunk: int = 256) -> torch.Tensor:
    """(B, n, n) -> (n, n, B) with out[i, j, b] = M[b, j, i] (column i of every problem), in ``dtype`` (default
    M's), transposed in chunks of problems that fit in cache (several times faster than one strided copy)."""
    B, n, _ = M.shape
    out = M.new_empty(n, n, B, dtype=dtype or M.dtype)
    for k in range(0, B, chunk):
        out[:, :, k:k + chunk] = M[k:k + chunk].permute(2, 1, 0)
    return out


def _checked(M, q, x0, mask, check_every, omega, tol, max_iters):
    """:func:`solve_lcp_pgs`'s arguments checked (``ValueError`` naming the argument) and its defaults filled in.
    Returns B, n, dtype, device, the tolerance table, tol, max_iters, check_every."""
    if not isinstance(M, torch.Tensor) or M.dim() != 3 or M.shape[1] != M.shape[2]:
        raise ValueError("solve_lcp_pgs: M must have shape (B, n, n), got "
                         f"{tuple(M.shape) if isinstance(M, torch.Tensor) else type(M).__name__}")
    B, n, _ = M.shape
    if not M.is_floating_point():
        raise ValueError(f"solve_lcp_pgs: M must be floating point, got {M.dtype}")
    dtype, device = M.dtype, M.device
    tab = lcp_tolerances(dtype)
    _check(q, "q", (B, n))
    if x0 is not None:
        _check(x0, "x0", (B, n))
    for name, t in (("q", q), ("x0", x0)):
        if t is not None and (t.dtype != dtype or t.device != device):
            raise ValueError(f"solve_lcp_pgs: {name} must be {dtype} on {device} like M, got {t.dtype} on {t.device}")
    if mask is not None:
        _check(mask, "mask", (B, n), floating=False)
        if mask.dtype != torch.bool or mask.device != device:
            raise ValueError(f"solve_lcp_pgs: mask must be bool on {device}, got {mask.dtype} on {mask.device}")
    if int(check_every) < 1:
        raise ValueError(f"solve_lcp_pgs: check_every must be >= 1, got {check_every}")
    if not 0.0 < float(omega) < 2.0:
        raise ValueError(f"solve_lcp_pgs: omega must lie in (0, 2), got {omega}")
    tol = tab.tol if tol is None else float(tol)
    max_iters = tab.max_iters if max_iters is None else int(max_iters)
    if max_iters < 0:
        raise ValueError(f"solve_lcp_pgs: max_iters must be >= 0, got {max_iters}")
    check_every = int(check_every)
    return B, n, dtype, device, tab, tol, max_iters, check_every


def _start(M, q, x0, mask, max_iters, zero):
    """Padding as identity rows with q = 0, the invalid problems (which never enter the working set), the starting
    point and the initial status and iteration counts. Returns act, Ms, qs, invalid, x, w, status, iterations."""
    B, n, _ = M.shape
    dtype, device = M.dtype, M.device
    if mask is None:
        act = torch.ones(B, n, dtype=torch.bool, device=device)
        Ms, qs = M, q
    else:
        act = mask
        eye = torch.eye(n, dtype=dtype, device=device)
        Ms = torch.where(act[:, :, None] & act[:, None, :], M, eye)
        qs = torch.where(act, q, zero)
    # NaN/inf entries make their row sum non-finite (so does a row whose sum overflows: invalid too)
    invalid = (~torch.isfinite(Ms.sum(-1)).all(-1) | ~torch.isfinite(qs).all(-1)
               | ~(torch.diagonal(Ms, dim1=1, dim2=2) > 0).all(-1))
    if x0 is not None:
        invalid |= (act & ~torch.isfinite(x0)).any(-1)
    x = torch.zeros(B, n, dtype=dtype, device=device)
    if x0 is not None:
        x = torch.where(act & ~invalid[:, None], x0.clamp_min(0), x)
    w = torch.zeros_like(x)
    status = torch.full((B,), int(SolverStatus.MAX_ITERATIONS), dtype=torch.int8, device=device)
    status = torch.where(invalid, torch.full_like(status, int(SolverStatus.INVALID_INPUT)), status)
    iterations = torch.full((B,), max_iters, dtype=torch.int32, device=device)
    iterations = torch.where(invalid, torch.zeros_like(iterations), iterations)
    return act, Ms, qs, invalid, x, w, status, iterations


def solve_lcp_pgs(M: torch.Tensor, q: torch.Tensor, *, x0: torch.Tensor | None = None,
                  mask: torch.Tensor | None = None, tol: float | None = None, max_iters: int | None = None,
                  check_every: int = 10, omega: float = 1.0, subspace: bool = False,
                  mixed: bool = False) -> LCPResult:
    """Projected Gauss-Seidel for a batch of standard LCPs: x >= 0, w = M x + q >= 0, x^T w = 0.

    Args:
        M: LCP matrices, (B, n, n); every active diagonal entry must be > 0 (else that problem is INVALID_INPUT)
        q: LCP vectors, (B, n)
        x0: warm start, (B, n); negative entries are clipped to 0. Default 0
        mask: active entries, (B, n) bool; padded entries (False) are ignored and come back as x = w = 0
        tol: absolute tolerance on ||min(x, w)||_inf; default per dtype (:func:`lcp_tolerances`)
        max_iters: limit on sweeps per problem; default per dtype
        check_every: sweeps between convergence checks (the only host syncs)
        omega: relaxation factor in (0, 2); 1 is plain PGS
        subspace: also try a subspace-minimisation step at every check (PGS-SM, see the module docstring)
        mixed: float64 problems only: run the sweeps in float32 on corrections that every check refines against
            the exact float64 residual (see the module docstring); ignored for float32

    Returns:
        :class:`LCPResult`. Per problem: CONVERGED (residual <= tol), MAX_ITERATIONS (the last iterate is
        returned), UNBOUNDED (the iterate diverged past a huge bound or became non-finite; the last finite
        checkpoint is returned) or INVALID_INPUT (NaN/inf in an active entry, or an active diagonal entry <= 0).
        Raises ``ValueError`` naming the argument on wrong shapes, dtypes or options.
    """
    B, n, dtype, device, tab, tol, max_iters, check_every = _checked(M, q, x0, mask, check_every, omega, tol,
                                                                    max_iters)
    zero = torch.zeros((), dtype=dtype, device=device)
    act, Ms, qs, invalid, x, w, status, iterations = _start(M, q, x0, mask, max_iters, zero)
    codes = {s: torch.tensor(int(s), dtype=torch.int8, device=device) for s in SolverStatus}

    # --- working set: slots -> problems, structure-of-arrays copies (coordinates leading) ----------------------
    # Mc: the sweeps' matrix (columns leading), float32 when mixed; Mw: the row-major matrices (no copy unless
    # some problems are left out) for the exact checks and subspace steps; compacting it is a cheap row gather.
    run = (~invalid).nonzero().squeeze(-1)
    mixed = bool(mixed) and dtype == torch.float64
    Mw = Ms if run.numel() == B else Ms.index_select(0, run)
    Mc = _to_soa(Mw, torch.float32 if mixed else dtype)           # Mc[i, j, b] = M[b, j, i]
    Q, X = qs[run].t().contiguous(), x[run].t().contiguous()
    A = None if mask is None else act[run].t().contiguous()          # active entries (None: all)
    neg_step = (-float(omega) / torch.diagonal(Mc, dim1=0, dim2=1)).t().contiguous()   # (n, Bw); M_ii = 1 if padded
    live = torch.ones(run.numel(), dtype=torch.bool, device=device)
    X_prev = X.clone()
    done = 0
    while run.numel():
        W = _exact_w(Mw, X, Q)                                     # exact w at every check
        res = _residual_soa(X, W, A)
        if subspace and done > 0:
            Xs = _subspace_step(Mw, X, Q, A)
            Ws = _exact_w(Mw, Xs, Q)
            rs = _residual_soa(Xs, Ws, A)
            better = rs < res
            X, W, res = torch.where(better, Xs, X), torch.where(better, Ws, W), torch.where(better, rs, res)
        finite = (X <= tab.blowup).all(0)                          # X >= 0: False for NaN, inf and blow-ups
        conv = finite & (res <= tol)
        stop = live & (conv | ~finite | (done >= max_iters))
        if bool(stop.any()):
            slots = stop.nonzero().squeeze(-1)
            fin = finite[slots]
            probs = run[slots]
            Xs, Ws = X[:, slots], W[:, slots]
            if not bool(fin.all()):                # diverged: back to the last finite checkpoint (rare)
                bad = slots[~fin]
                Xs[:, ~fin] = X_prev[:, bad]
                Ws[:, ~fin] = _exact_w(Mw[bad], X_prev[:, bad], Q[:, bad])
            x[probs], w[probs] = Xs.t(), Ws.t()
            status[probs] = torch.where(conv[slots], codes[SolverStatus.CONVERGED],
                                        torch.where(fin, status[probs], codes[SolverStatus.UNBOUNDED]))
            iterations[probs] = torch.where(conv[slots] | ~fin, torch.full_like(slots, done, dtype=torch.int32),
                                            iterations[probs])
            live = live & ~stop
            n_live = int(live.sum())
            if n_live == 0:
                break
            if n_live <= 0.5 * live.numel():                          # compact the working set
                keep = live.nonzero().squeeze(-1)
                run, Mc, Q, X, W = run[keep], Mc[..., keep], Q[:, keep], X[:, keep], W[:, keep]
                A = None if A is None else A[:, keep]
                neg_step, live = neg_step[:, keep], live[keep]
                Mw = Mw[keep]
        X_prev = X.clone()
        sweeps = min(check_every, max_iters - done)
        if mixed:                          # float32 sweeps on the correction d, x + d >= 0 (d >= -x)
            low = (-X).float()
            d, W32 = torch.zeros_like(low), W.float()
            _sweeps(Mc, d, W32, neg_step, sweeps, lower=low)
            X = torch.where(d <= low, 0.0, X + d.double()).clamp_min_(0)
        else:
            _sweeps(Mc, X, W, neg_step, sweeps)
        done += sweeps

    # padded entries: x = w = 0; invalid problems: x = w = 0, residual inf
    x = torch.where(act & ~invalid[:, None], x, zero)
    w = torch.where(act & ~invalid[:, None], w, zero)
    residual = lcp_residual(x, w, act)
    residual = torch.where(invalid, torch.full_like(residual, math.inf), residual)
    return LCPResult(x, w, residual, status, iterations)
