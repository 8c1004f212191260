"""Batched convex QPs (interior point and ADMM with polishing), with equality rows reduced by a range test.

For every problem of the batch (units are the caller's)::

    minimise   1/2 z^T Q z + p^T z      over z (B, nz)
    subject to G z <= h                 (nineq rows)
               A z  = b                 (neq rows)

``Q`` only needs to be positive semidefinite (Liu 2009's window QP has the null direction (1, 1, -1, -1) of every
friction pyramid); ``A`` may be rank deficient (a two-finger pinch cannot make torque about the line through its
contacts).

Steps
    1. Screening: problems with NaN/inf data get INVALID_INPUT and are replaced by a harmless dummy inside the
       batch (no host sync).
    2. :func:`reduce_equalities` (applied by default): per problem, the SVD A = U S V^T; rows whose singular value
       is below ``rank`` times the largest are dropped, the kept ones are replaced by the orthogonal rows
       U_r^T A with right-hand side U_r^T b (same feasible set when b is in the range of A). The range test
       |b - U_r U_r^T b| <= range * |b| decides whether b is in the range; problems whose b is not get status
       INFEASIBLE at once, with the certificate nu = -(b - U_r U_r^T b) (A^T nu = 0, b^T nu < 0). Dropped rows
       stay in the batch as zero rows (fixed shapes); the multipliers are mapped back as nu = U_r nu_r.
    3. The solvers, on l <= C z <= u with C = [G; U_r^T A]:

       * :mod:`._qp_ipm`: a batched Mehrotra predictor-corrector interior-point method (10-20 iterations on the
         window QPs, also at the edge of feasibility), whose growing multipliers give Farkas certificates on
         infeasible problems; its point is then polished (below, with active-set corrections);
       * :mod:`._qp_admm`: OSQP-style ADMM (Stellato et al. 2020) with per-problem convergence, infeasibility and
         unboundedness tests every ``check_every`` iterations, residual balancing of rho, and an active-set
         polish (equality-constrained KKT solve by iterative refinement), so converged answers are accurate to
         about 1e-9 relative in float64, not to ADMM's slow tail. ADMM is the one that uses warm starts.

       ``method="ipm"`` (cold-start default): interior point, then ADMM for the problems it leaves undecided.
       ``method="admm"`` (warm-start default): ADMM, then after ``fallback_after`` iterations the interior point
       for the open problems (thin feasible sets stall ADMM), then ADMM again for the rest of ``max_iters``.

Statuses (per problem, :class:`~.status.SolverStatus`)
    * CONVERGED: unscaled residuals r_p = |Cz - proj(Cz)|_inf and r_d = |Qz + p + G^T lam + A^T nu|_inf are
      below ``tol * (1 + size)`` (OSQP's relative test, ``tol`` per dtype in :func:`qp_tolerances`) AND
      complementarity holds (:func:`._qp_admm._complementary`): row by row, lam_i |G_i|_inf <= tol (1 + size_d)
      or the slack h_i - G_i z <= tol (1 + size_p) (so a wrong-sign multiplier fails), and
      |lam^T (G z - h)| <= tol (1 + the largest term of the objective and of lam^T G z, lam^T h). This holds for
      every path: the polished point, the ADMM point, or the interior point itself. The interior point stops on
      residuals and the mean gap s^T lam / m; at a degenerate optimum (the window QPs' pyramids) some rows then
      have lam and slack both ~sqrt(mu), which the residuals and that gap do not see, so its point goes to the
      polish, whose active set (lam_i > slack_i) is corrected up to four times (rows with wrong-sign multipliers
      leave, violated rows join); when that fails too, ADMM continues from the interior point.
    * INFEASIBLE: the range test failed, or a Farkas certificate was found: (lam, nu) are then that certificate,
      scaled to |.|_inf = 1, with lam >= 0 and h^T lam + b^T nu < 0 (for any feasible z,
      (G^T lam + A^T nu)^T z <= h^T lam + b^T nu). From the interior point: |G^T lam + A^T nu|_inf <=
      eps_inf * (-(h^T lam + b^T nu)), so every feasible z has |z|_1 >= 1 / eps_inf; from ADMM: OSQP's test on
      the equilibrated problem (|C^T dy| <= eps_inf |dy|, support <= -eps_inf |dy|).
    * UNBOUNDED: a primal recession direction with negative cost (ADMM's test; only possible with singular Q).
    * MAX_ITERATIONS: the last iterate (finite) and its residuals.
    * INVALID_INPUT: NaN/inf data; z = 0, multipliers 0, objective inf.

Results are never NaN: non-finite outcomes are reported by status, with finite placeholders (objective inf for
problems without a solution). Pure tensor code: device and dtype come from the inputs; host syncs happen at the
interior point's iterations and ADMM's checks. The solve runs in float64 whatever the input dtype (in float32 the
growing multipliers of an infeasible problem drown its certificate in rounding noise); float32 inputs get float32
results, with the rank and range thresholds of float32 data.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import torch

from ._qp_admm import AdmmOutput, AdmmSettings, _active, _converged, _polish_corrected, _Scaled, admm
from ._qp_ipm import ipm
from .status import SolverStatus

__all__ = ["ConvexQPResult", "QPTolerances", "qp_tolerances", "reduce_equalities", "solve_convex_qp",
           "ReducedEqualities"]

_CONVERGED = int(SolverStatus.CONVERGED)
_INFEASIBLE = int(SolverStatus.INFEASIBLE)
_INVALID = int(SolverStatus.INVALID_INPUT)
_POLISH_ROUNDS = 4        # active-set corrections of the interior point's polish


@dataclass(frozen=True)
class QPTolerances:
    """Per-dtype tolerances of :func:`solve_convex_qp`.

    tol:      relative residual tolerance of CONVERGED (OSQP's eps_abs = eps_rel), measured in float64
    eps_inf:  infeasibility / unboundedness certificate tolerance (equilibrated units)
    delta:    regularisation of the polish's KKT factorisation (equilibrated units)
    rank:     singular values of A below ``rank`` times the largest count as zero
    range:    b is in the range of A when |b - U_r U_r^T b| <= range * |b|
    max_iters: default ADMM iteration limit
    """

    tol: float
    eps_inf: float
    delta: float
    rank: float
    range: float
    max_iters: int


_TOLERANCES: tuple[tuple[torch.dtype, QPTolerances], ...] = (
    (torch.float64, QPTolerances(tol=1e-9, eps_inf=1e-5, delta=1e-7, rank=1e-10, range=1e-8, max_iters=4000)),
    (torch.float32, QPTolerances(tol=1e-7, eps_inf=1e-5, delta=1e-7, rank=1e-5, range=1e-4, max_iters=4000)),
)


def qp_tolerances(dtype: torch.dtype) -> QPTolerances:
    """The tolerance row of ``dtype`` (float32 or float64)."""
    for d, t in _TOLERANCES:
        if d == dtype:
            return t
    raise ValueError(f"solve_convex_qp: dtype must be float32 or float64, got {dtype}")


class ConvexQPResult(NamedTuple):
    """Result of :func:`solve_convex_qp` (B problems).

    z:               primal solution, (B, nz); last iterate when MAX_ITERATIONS / INFEASIBLE, 0 when INVALID_INPUT
    lam:             multipliers of G z <= h, (B, nineq), >= 0 (the certificate's part when INFEASIBLE)
    nu:              multipliers of A z = b, (B, neq) (the certificate's part when INFEASIBLE)
    objective:       1/2 z^T Q z + p^T z, (B,); inf unless CONVERGED or MAX_ITERATIONS
    status:          (B,), int8 values of :class:`~.status.SolverStatus`
    iterations:      ADMM iterations spent on each problem, (B,), int32
    residual_primal: max(|max(Gz - h, 0)|_inf, |Az - b|_inf) with the original rows, (B,); inf for INVALID_INPUT
    residual_dual:   |Qz + p + G^T lam + A^T nu|_inf, (B,); inf unless CONVERGED or MAX_ITERATIONS
    """

    z: torch.Tensor
    lam: torch.Tensor
    nu: torch.Tensor
    objective: torch.Tensor
    status: torch.Tensor
    iterations: torch.Tensor
    residual_primal: torch.Tensor
    residual_dual: torch.Tensor


class ReducedEqualities(NamedTuple):
    """Output of :func:`reduce_equalities` (B problems, neq rows).

    A:        independent rows U_r^T A, dropped rows zero, (B, neq, nz)
    b:        U_r^T b, dropped rows zero, (B, neq)
    U:        left singular vectors with dropped columns zeroed, (B, neq, neq): nu = U nu_r maps multipliers back
    rank:     number of kept rows, (B,), long
    in_range: b lies in the range of A (range test passed), (B,), bool
    residual: out-of-range part b - U_r U_r^T b, (B, neq) (a certificate direction when not in range)
    """

    A: torch.Tensor
    b: torch.Tensor
    U: torch.Tensor
    rank: torch.Tensor
    in_range: torch.Tensor
    residual: torch.Tensor


def reduce_equalities(A: torch.Tensor, b: torch.Tensor, *, rank_tol: float | None = None,
                      range_tol: float | None = None) -> ReducedEqualities:
    """Reduce A z = b to independent orthogonal rows and test whether b lies in the range of A, per problem.

    Args:
        A: equality rows, (B, neq, nz)
        b: right-hand sides, (B, neq)
        rank_tol: relative singular-value threshold (default per dtype, :func:`qp_tolerances`)
        range_tol: relative range-test threshold on |b - U_r U_r^T b| / |b| (default per dtype)

    Returns:
        :class:`ReducedEqualities`; computed in float64, returned in A's dtype.
    """
    if not isinstance(A, torch.Tensor) or A.dim() != 3:
        raise ValueError(f"reduce_equalities: A must be a tensor of shape (B, neq, nz), got "
                         f"{tuple(A.shape) if isinstance(A, torch.Tensor) else type(A).__name__}")
    if not isinstance(b, torch.Tensor) or tuple(b.shape) != tuple(A.shape[:2]):
        raise ValueError(f"reduce_equalities: b must have shape {tuple(A.shape[:2])}, got "
                         f"{tuple(b.shape) if isinstance(b, torch.Tensor) else type(b).__name__}")
    tols = qp_tolerances(A.dtype)
    rank_tol = tols.rank if rank_tol is None else rank_tol
    range_tol = tols.range if range_tol is None else range_tol
    B, neq, nz = A.shape
    A64, b64 = A.double(), b.double()
    if neq == 0:
        z = A.new_zeros(B, 0)
        return ReducedEqualities(A, b, A.new_zeros(B, 0, 0), torch.zeros(B, dtype=torch.long, device=A.device),
                                 torch.ones(B, dtype=torch.bool, device=A.device), z)
    U, S, _ = torch.linalg.svd(A64, full_matrices=True)                  # U (B, neq, neq), S (B, k)
    k = S.shape[1]
    keep = S > rank_tol * S[:, :1].clamp_min(torch.finfo(torch.float64).tiny)
    keep = torch.cat([keep, keep.new_zeros(B, neq - k)], 1)              # (B, neq)
    Ur = U * keep.unsqueeze(1).double()
    Ar = Ur.transpose(1, 2) @ A64
    br = (Ur.transpose(1, 2) @ b64.unsqueeze(-1)).squeeze(-1)
    resid = b64 - (Ur @ br.unsqueeze(-1)).squeeze(-1)
    in_range = resid.norm(dim=1) <= range_tol * b64.norm(dim=1)
    dt = A.dtype
    return ReducedEqualities(Ar.to(dt), br.to(dt), Ur.to(dt), keep.sum(1), in_range, resid.to(dt))


def _check(x, name: str, shape: tuple, dtype, device) -> None:
    if not isinstance(x, torch.Tensor):
        raise ValueError(f"solve_convex_qp: {name} must be a torch.Tensor of shape {shape}, got {type(x).__name__}")
    if tuple(x.shape) != tuple(shape):
        raise ValueError(f"solve_convex_qp: {name} must have shape {tuple(shape)}, got {tuple(x.shape)}")
    if x.dtype != dtype:
        raise ValueError(f"solve_convex_qp: {name} must have dtype {dtype} (the dtype of p), got {x.dtype}")
    if x.device != device:
        raise ValueError(f"solve_convex_qp: {name} must be on {device} (the device of p), got {x.device}")


def _rows(M, name: str, B: int, nz: int) -> int:
    if M is None:
        return 0
    if not isinstance(M, torch.Tensor) or M.dim() != 3:
        raise ValueError(f"solve_convex_qp: {name} must be a tensor of shape ({B}, rows, {nz}), got "
                         f"{tuple(M.shape) if isinstance(M, torch.Tensor) else type(M).__name__}")
    return int(M.shape[1])


def _ipm_then_polish(Q, q, C, lo, up, nineq: int, s: AdmmSettings, ipm_iters: int):
    """Interior point on (Q, q, C, lo, up), then the active-set polish from its point (with active-set
    corrections, :func:`._qp_admm._polish_corrected`).

    CONVERGED only for a point that passes the full test of :func:`._qp_admm._converged` (residuals,
    complementarity, multiplier signs): the polished point, or else the interior point itself. The interior point
    stops on residuals and a small duality gap; at a degenerate optimum (the window QPs' pyramids leave faces of
    optimal points) some rows then have lam and slack both ~sqrt(mu), so its own point usually fails that test
    and the polish decides.
    Returns (x, y, status (int8), iterations, close (B,) bool: the interior point stopped near an optimum, a
    good ADMM start when the polish failed)."""
    res = ipm(Q, q, C[:, :nineq], up[:, :nineq], C[:, nineq:], up[:, nineq:], tol=s.tol, eps_inf=s.eps_inf,
              max_iters=ipm_iters)
    x, y = res.x, torch.cat([res.lam, res.nu], 1)
    one = torch.ones_like
    P = _Scaled(Q=Q, q=q, C=C, l=lo, u=up, eq=lo == up, D=one(q), E=one(lo), c=one(q[:, 0]))
    z = torch.minimum(torch.maximum(torch.bmm(C, x.unsqueeze(-1)).squeeze(-1), lo), up)
    raw = res.stopped & _converged(P, x, z, y, s.tol)
    act, lo_a, up_a = _active(P, z, y)
    ok, xp, _, yp = _polish_corrected(P, x, y, act, lo_a, up_a, s, _POLISH_ROUNDS)
    ok = ok & ~res.infeasible
    x = torch.where(ok.unsqueeze(-1), xp, x)
    y = torch.where(ok.unsqueeze(-1), yp, y)
    st = torch.where(ok | raw, int(SolverStatus.CONVERGED),
                     torch.where(res.infeasible, int(SolverStatus.INFEASIBLE), int(SolverStatus.MAX_ITERATIONS)))
    return x, y, st.to(torch.int8), res.iterations, res.stopped & ~(ok | raw)


def _solve(Q, q, C, lo, up, nineq: int, x0, y0, s: AdmmSettings, warm: bool, fallback_after: int,
           ipm_iters: int) -> AdmmOutput:
    """Cold start: interior point first (:mod:`._qp_ipm`, ``ipm_iters`` iterations, then the polish); the
    problems it leaves undecided go to ADMM for ``s.max_iters``. Warm start: ADMM first for ``fallback_after``
    iterations, then the interior point for the problems still open, then ADMM again for the rest of the budget."""
    MAXIT = int(SolverStatus.MAX_ITERATIONS)
    if warm:
        out = admm(Q, q, C, lo, up, x0, y0, s._replace(max_iters=min(fallback_after, s.max_iters)))
        if fallback_after >= s.max_iters:
            return out
        rest_iters = s.max_iters - fallback_after
    else:
        x, y, st, it, close = _ipm_then_polish(Q, q, C, lo, up, nineq, s, ipm_iters)
        out = AdmmOutput(x=x, y=y, status=st, iterations=it)
        rest_iters = s.max_iters
        # ADMM continues from the interior point where it stopped near an optimum (its polish failed)
        cl = close.unsqueeze(-1)
        x0, y0 = torch.where(cl, x, x0), torch.where(cl, y, y0)
    pending = out.status == MAXIT
    if not bool(pending.any()):                                     # host sync: once
        return out
    j = pending.nonzero().squeeze(-1)
    x_all, y_all, status, iters = out.x, out.y, out.status, out.iterations
    if warm:
        x, y, st, it, close = _ipm_then_polish(*(t.index_select(0, j) for t in (Q, q, C, lo, up)), nineq, s,
                                               ipm_iters)
        keep = ((st == MAXIT) & ~close).unsqueeze(-1)      # ADMM goes on from the interior point when it is close
        x_all = x_all.index_copy(0, j, torch.where(keep, x_all.index_select(0, j), x))
        y_all = y_all.index_copy(0, j, torch.where(keep, y_all.index_select(0, j), y))
        status = status.index_copy(0, j, st)
        iters = iters.index_copy(0, j, iters.index_select(0, j) + it)
        j = j.index_select(0, (st == MAXIT).nonzero().squeeze(-1))
        x0j, y0j = x_all.index_select(0, j), y_all.index_select(0, j)
    else:
        x0j, y0j = x0.index_select(0, j), y0.index_select(0, j)
    if j.numel():
        more = admm(*(t.index_select(0, j) for t in (Q, q, C, lo, up)), x0j, y0j, s._replace(max_iters=rest_iters))
        x_all, y_all = x_all.index_copy(0, j, more.x), y_all.index_copy(0, j, more.y)
        status = status.index_copy(0, j, more.status)
        iters = iters.index_copy(0, j, iters.index_select(0, j) + more.iterations)
    return AdmmOutput(x=x_all, y=y_all, status=status, iterations=iters)


def _check_settings(method, check_every, rho, sigma, alpha) -> None:
    """The solver settings of :func:`solve_convex_qp`; ``ValueError`` naming the bad one."""
    if method not in ("auto", "ipm", "admm"):
        raise ValueError(f"solve_convex_qp: method must be 'auto', 'ipm' or 'admm', got {method!r}")
    if check_every < 1:
        raise ValueError(f"solve_convex_qp: check_every must be >= 1, got {check_every}")
    if not (rho > 0 and sigma > 0 and 0 < alpha < 2):
        raise ValueError(f"solve_convex_qp: need rho > 0, sigma > 0, 0 < alpha < 2, got {rho}, {sigma}, {alpha}")


def _warm_start(warm_start, p, B, nz, nineq, neq, dt, dev):
    """The starting point (z, lam, nu) of :func:`solve_convex_qp`: zeros, or the checked parts of ``warm_start``."""
    z0, lam0, nu0 = p.new_zeros(B, nz), p.new_zeros(B, nineq), p.new_zeros(B, neq)
    if warm_start is not None:
        if not isinstance(warm_start, (tuple, list)) or len(warm_start) != 3:
            raise ValueError("solve_convex_qp: warm_start must be a tuple (z, lam or None, nu or None)")
        _check(warm_start[0], "warm_start z", (B, nz), dt, dev)
        z0 = warm_start[0]
        if warm_start[1] is not None:
            _check(warm_start[1], "warm_start lam", (B, nineq), dt, dev)
            lam0 = warm_start[1]
        if warm_start[2] is not None:
            _check(warm_start[2], "warm_start nu", (B, neq), dt, dev)
            nu0 = warm_start[2]
    return z0, lam0, nu0


def _with_residuals(p, Qc, pc, Gc, hc, Ac, bc, z, lam, nu, status, iters, finite, has_sol, nineq, neq, dt_in):
    """The result with its residuals and objective measured on the original rows, in the input dtype."""
    B, dt, dev = pc.shape[0], pc.dtype, pc.device
    inf = torch.full((), float("inf"), dtype=dt, device=dev)
    mv = lambda M, v: (M @ v.unsqueeze(-1)).squeeze(-1)  # noqa: E731
    r_g = (mv(Gc, z) - hc).clamp_min(0).amax(1) if nineq else p.new_zeros(B)
    r_a = (mv(Ac, z) - bc).abs().amax(1) if neq else p.new_zeros(B)
    r_p = torch.where(finite, torch.maximum(r_g, r_a), inf)
    grad = mv(Qc, z) + pc + mv(Gc.transpose(1, 2), lam) + mv(Ac.transpose(1, 2), nu)
    r_d = torch.where(has_sol, grad.abs().amax(1), inf)
    obj = 0.5 * (z * mv(Qc, z)).sum(1) + (pc * z).sum(1)
    obj = torch.where(has_sol, obj, inf)
    z, lam, nu, obj, r_p, r_d = (t.to(dt_in) for t in (z, lam, nu, obj, r_p, r_d))
    return ConvexQPResult(z=z, lam=lam, nu=nu, objective=obj, status=status, iterations=iters,
                          residual_primal=r_p, residual_dual=r_d)


def _checked_data(Q, p, G, h, A, b):
    """The problem data of :func:`solve_convex_qp` checked (``ValueError`` naming the argument), absent rows as
    empty tensors. Returns G, h, A, b, nineq, neq."""
    if not isinstance(p, torch.Tensor) or p.dim() != 2:
        raise ValueError(f"solve_convex_qp: p must be a tensor of shape (B, nz), got "
                         f"{tuple(p.shape) if isinstance(p, torch.Tensor) else type(p).__name__}")
    B, nz = p.shape
    dt, dev = p.dtype, p.device
    if (G is None) != (h is None):
        raise ValueError("solve_convex_qp: give both G and h or neither")
    if (A is None) != (b is None):
        raise ValueError("solve_convex_qp: give both A and b or neither")
    _check(Q, "Q", (B, nz, nz), dt, dev)
    nineq, neq = _rows(G, "G", B, nz), _rows(A, "A", B, nz)
    G = p.new_zeros(B, 0, nz) if G is None else G
    h = p.new_zeros(B, 0) if h is None else h
    A = p.new_zeros(B, 0, nz) if A is None else A
    b = p.new_zeros(B, 0) if b is None else b
    for x, name, shape in ((G, "G", (B, nineq, nz)), (h, "h", (B, nineq)), (A, "A", (B, neq, nz)),
                           (b, "b", (B, neq))):
        _check(x, name, shape, dt, dev)
    return G, h, A, b, nineq, neq


def solve_convex_qp(Q: torch.Tensor, p: torch.Tensor, G: torch.Tensor | None = None, h: torch.Tensor | None = None,
                    A: torch.Tensor | None = None, b: torch.Tensor | None = None, *,
                    warm_start: tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None] | None = None,
                    tol: float | None = None, max_iters: int | None = None, check_every: int = 25,
                    rho: float = 0.1, sigma: float = 1e-6, alpha: float = 1.6, polish: bool = True,
                    reduce: bool = True, fallback_after: int = 500, ipm_iters: int = 50,
                    method: str = "auto") -> ConvexQPResult:
    """Solve B convex QPs ``min 1/2 z^T Q z + p^T z  s.t.  G z <= h, A z = b`` (see the module docstring).

    Args:
        Q: quadratic term, (B, nz, nz), positive semidefinite (symmetrised here: (Q + Q^T) / 2)
        p: linear term, (B, nz); fixes B, dtype and device
        G: inequality rows, (B, nineq, nz), or None; h: (B, nineq) or None
        A: equality rows, (B, neq, nz), or None (any rank); b: (B, neq) or None
        warm_start: (z (B, nz), lam (B, nineq) or None, nu (B, neq) or None), e.g. the previous window's
            solution shifted; None starts from zero
        tol: relative residual tolerance of CONVERGED (default per dtype, :func:`qp_tolerances`)
        max_iters: ADMM iteration limit (default per dtype)
        check_every: iterations between the per-problem tests (the only host syncs)
        rho, sigma, alpha: ADMM's initial penalty, proximal weight and relaxation (equilibrated units)
        polish: try the active-set polish at every check
        reduce: apply :func:`reduce_equalities` (recommended; without it a rank-deficient A still works, but an
            inconsistent b is only found by ADMM's certificate)
        fallback_after: with a warm start, ADMM iterations after which the problems still open go to the
            interior-point method; those it does not decide continue ADMM up to ``max_iters``
        ipm_iters: interior-point iterations (cold start: before ADMM takes the undecided problems)
        method: which solver goes first: "ipm" (interior point, then ADMM for undecided problems), "admm" (ADMM,
            the interior point after ``fallback_after`` iterations, then ADMM again) or "auto" ("admm" with a
            warm start, which only ADMM can use, "ipm" without)

    Returns:
        :class:`ConvexQPResult` with leading B.
    """
    G, h, A, b, nineq, neq = _checked_data(Q, p, G, h, A, b)
    tols = qp_tolerances(p.dtype)
    B, nz = p.shape
    dt, dev = p.dtype, p.device
    _check_settings(method, check_every, rho, sigma, alpha)
    z0, lam0, nu0 = _warm_start(warm_start, p, B, nz, nineq, neq, dt, dev)

    # 1. Screening of non-finite data, per problem, without a host sync.
    finite = torch.ones(B, dtype=torch.bool, device=dev)
    for t in (Q, p, G, h, A, b):
        if t[0].numel():
            finite &= torch.isfinite(t).flatten(1).all(1)
    ws_ok = torch.isfinite(z0).all(1) & torch.isfinite(lam0).all(1) & torch.isfinite(nu0).all(1)
    f3, f2 = finite.view(B, 1, 1), finite.view(B, 1)
    zero = p.new_zeros(())
    eye = torch.eye(nz, dtype=dt, device=dev)
    Qc = torch.where(f3, 0.5 * (Q + Q.transpose(1, 2)), eye)
    pc, Gc, hc = torch.where(f2, p, zero), torch.where(f3, G, zero), torch.where(f2, h, zero.abs() + 1)
    Ac, bc = torch.where(f3, A, zero), torch.where(f2, b, zero)
    w2 = (finite & ws_ok).view(B, 1)
    z0, lam0, nu0 = (torch.where(w2, t, zero) for t in (z0, lam0, nu0))
    # The solve runs in float64 whatever the input dtype (a float32 iteration cannot produce clean
    # infeasibility certificates: y grows without bound there); results are returned in the input dtype.
    Qc, pc, Gc, hc, Ac, bc, z0, lam0, nu0 = (t.double() for t in (Qc, pc, Gc, hc, Ac, bc, z0, lam0, nu0))
    dt_in, dt = dt, torch.float64

    # 2. Equality rows reduced with a range test.
    if reduce and neq:
        red = reduce_equalities(Ac, bc, rank_tol=tols.rank, range_tol=tols.range)
        Ar, br, U, in_range = red.A, red.b, red.U, red.in_range
        nu0r = (U.transpose(1, 2) @ nu0.unsqueeze(-1)).squeeze(-1)
    else:
        Ar, br, U, nu0r = Ac, bc, None, nu0
        in_range = torch.ones(B, dtype=torch.bool, device=dev)

    # 3. ADMM on l <= C z <= u.
    C = torch.cat([Gc, Ar], 1)
    inf = torch.full((), float("inf"), dtype=dt, device=dev)
    lo = torch.cat([(-inf).expand(B, nineq), br], 1)
    up = torch.cat([hc, br], 1)
    settings = AdmmSettings(tol=tols.tol if tol is None else tol, eps_inf=tols.eps_inf, delta=tols.delta,
                            max_iters=tols.max_iters if max_iters is None else int(max_iters),
                            check_every=int(check_every), rho=rho, sigma=sigma, alpha=alpha, polish=polish)
    out = _solve(Qc, pc, C, lo, up, nineq, z0, torch.cat([lam0, nu0r], 1), settings,
                 method == "admm" or (method == "auto" and warm_start is not None),
                 int(fallback_after), int(ipm_iters))
    z, lam, nu_r = out.x, out.y[:, :nineq], out.y[:, nineq:]
    nu = (U @ nu_r.unsqueeze(-1)).squeeze(-1) if U is not None else nu_r

    status = out.status
    bad = ~(torch.isfinite(z).all(1) & torch.isfinite(lam).all(1) & torch.isfinite(nu).all(1))
    status = torch.where(bad, torch.full_like(status, int(SolverStatus.MAX_ITERATIONS)), status)
    z, lam, nu = (torch.nan_to_num(t, nan=0.0, posinf=0.0, neginf=0.0) for t in (z, lam, nu))
    status = torch.where(in_range, status, torch.full_like(status, _INFEASIBLE))
    if U is not None:                                      # the range test's certificate: A^T nu = 0, b^T nu < 0
        r = -red.residual
        r = r / r.abs().amax(1, keepdim=True).clamp_min(torch.finfo(dt).tiny)
        nu = torch.where(in_range.view(B, 1), nu, r)
        lam = torch.where(in_range.view(B, 1), lam, zero)
    status = torch.where(finite, status, torch.full_like(status, _INVALID))
    iters = torch.where(finite & in_range, out.iterations, torch.zeros_like(out.iterations))
    has_sol = (status == _CONVERGED) | (status == int(SolverStatus.MAX_ITERATIONS))
    lam = torch.where(has_sol.view(B, 1), lam.clamp_min(0), lam)
    z = torch.where(f2, z, zero)
    lam, nu = torch.where(f2, lam, zero), torch.where(f2, nu, zero)
    return _with_residuals(p, Qc, pc, Gc, hc, Ac, bc, z, lam, nu, status, iters, finite, has_sol, nineq, neq, dt_in)
