"""Dense convex QP for one problem at a time on the CPU (NumPy / LAPACK): :func:`solve_qp_dense`.

The problem, statuses, tolerances, result type and equality reduction of the batched kernel
:func:`torchhand.kernels.convex_qp.solve_convex_qp`, one problem at a time (units are the caller's)::

    minimise   1/2 z^T Q z + p^T z      over z (nz,)
    subject to G z <= h                 (nineq rows)
               A z  = b                 (neq rows)

With a batch of one, the batched torch kernel spends most of its time in per-operation overhead (about 20-40 ms
for a Liu 2009 window QP of 72-312 variables); here the same algorithm runs on NumPy arrays and LAPACK
factorisations, 0.1-1 ms per iteration at 72-312 variables. Steps, per problem:

    1. Screening: NaN/inf data give INVALID_INPUT (z = 0, multipliers 0, objective inf).
    2. Equality reduction as :func:`torchhand.kernels.convex_qp.reduce_equalities`: the SVD A = U S V^T, rows
       with a singular value below ``rank`` times the largest dropped, the kept rows replaced by U_r^T A
       (right-hand side U_r^T b); when the range test |b - U_r U_r^T b| <= range |b| fails: INFEASIBLE with the
       certificate nu = -(b - U_r U_r^T b) scaled to |nu|_inf = 1 (A^T nu = 0, b^T nu < 0). Multipliers are
       mapped back as nu = U_r nu_r.
    3. :func:`ipm`: Mehrotra's predictor-corrector interior point (as the kernel's ``_qp_ipm``), first to a stop
       100 times looser than the kernel's (the polish, step 4, usually finds the active set from there), then on
       to the kernel's stop and, when the polish still fails, to the full test of step 5. Each iteration
       factorises H = Q + G^T diag(lam / s) G + delta I = L L^T (LAPACK dpotrf) and the Schur complement W^T W of
       the (independent) equality rows, W = L^-1 A^T; the rows of G with one non-zero (bounds) add to the
       diagonal of H and those with a few (the normal-force rows of a window QP) are scattered into it, instead
       of a dense product. It stops on the relative residual test and a small mean gap s^T lam / m, or on a
       Farkas certificate of the normalised multipliers (g = -(h^T lam + b^T nu) > 0 and
       |G^T lam + A^T nu|_inf <= eps_inf g: every feasible z has |z|_1 >= 1 / eps_inf) -> INFEASIBLE.
    4. :func:`polish`: the equality-constrained KKT solve on the active set lam_i > slack_i (the kernel's
       regularised form (Q + C_a^T C_a / delta + delta I) dx = ..., one refinement step: further steps drift along
       the null directions of Q (the pyramids' (1, 1, -1, -1)) into the bounds of inactive rows), with up to three
       active-set corrections (rows with negative multipliers leave, violated rows join), as
       the kernel's ``_qp_admm._polish_corrected``; at a degenerate optimum (the window QPs' pyramids) the interior
       point's own point has rows with lam and slack both ~sqrt(mu), so its own point rarely passes step 5.
    5. CONVERGED only for a point that passes :func:`converged`, the kernel's full test (unscaled OSQP residuals
       below ``tol (1 + size)``, complementarity and multiplier signs row by row, the gap lam^T (h - G z) small
       relative to the objective's terms): the polished point, else the interior point's.

A problem that :func:`solve_dense` leaves undecided (iteration limit or a failed factorisation) is MAX_ITERATIONS
there; :func:`solve_qp_dense` hands those to the torch kernel (``method="ipm"``: interior point, then ADMM), so
the dense path decides at least what the kernel decides. A warm start (a nearby problem's solution, e.g. the previous
window's) is polished first (step 4 with its active set); when that point fails the full test, steps 3-5 start
from it, its slacks and multipliers raised to a floor (a near-central start: about half the iterations of a cold
start on consecutive window QPs), then from the default point if that ends undecided. Starting points only change
the work, not the answer's test.
Never returns NaN: non-finite iterates end the solve as MAX_ITERATIONS with finite placeholders.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.linalg.lapack import dpotrf, dpotrs, dtrtrs

import torch

from ..errors import InputValueError, ShapeError
from ..kernels.convex_qp import ConvexQPResult, qp_tolerances, solve_convex_qp
from ..kernels.status import SolverStatus

__all__ = ["DenseSolution", "converged", "ipm", "polish", "solve_dense", "solve_qp_dense"]

_CONVERGED = int(SolverStatus.CONVERGED)
_INFEASIBLE = int(SolverStatus.INFEASIBLE)
_MAX_ITERATIONS = int(SolverStatus.MAX_ITERATIONS)
_INVALID = int(SolverStatus.INVALID_INPUT)
_SPARSE_K = 8          # rows of G with at most this many non-zeros are scattered into G^T D G
_POLISH_ROUNDS = 4     # polishes: the first and up to three active-set corrections
_POLISH_REFINE = 1     # iterative-refinement steps of one polish (more drift along the null directions of Q)
_TINY = np.finfo(np.float64).tiny
_EARLY = 100.0         # the first polish is tried when the interior point meets _EARLY * tol
_WARM_FLOOR = 1e-3     # a warm start's slacks and multipliers are raised to at least this (problem units)


class DenseSolution(NamedTuple):
    """One problem's answer (float64 NumPy arrays).

    z:          primal point, (nz,); 0 when INVALID_INPUT or INFEASIBLE by the range test
    lam:        multipliers of G z <= h, (nineq,); the certificate's part when INFEASIBLE
    nu:         multipliers of A z = b, (neq,) (original rows); the certificate's part when INFEASIBLE
    status:     int value of :class:`~.status.SolverStatus`
    iterations: interior-point iterations
    """

    z: np.ndarray
    lam: np.ndarray
    nu: np.ndarray
    status: int
    iterations: int


def _amax(v: np.ndarray) -> float:
    return float(np.abs(v).max()) if v.size else 0.0


def _chol(H: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor of the SPD matrix H (LAPACK dpotrf, no checks); LinAlgError when not SPD."""
    L, info = dpotrf(H, lower=1, clean=0, overwrite_a=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"dpotrf info {info}")
    return L


def _cho_solve(L: np.ndarray, r: np.ndarray) -> np.ndarray:
    x, _ = dpotrs(L, r, lower=1)
    return x


class _Rows:
    """G split for H = Q + G^T diag(D) G: one-non-zero rows (bounds: a diagonal term), rows with at most
    ``_SPARSE_K`` non-zeros (scattered outer products) and dense rows (a matrix product)."""

    def __init__(self, G: np.ndarray):
        n = G.shape[1]
        nz = G != 0
        cnt = nz.sum(1)
        self.n = n
        self.i1 = np.flatnonzero(cnt == 1)
        self.c1 = nz[self.i1].argmax(1)
        self.v1 = G[self.i1, self.c1] ** 2
        self.si, self.di = np.flatnonzero((cnt > 1) & (cnt <= _SPARSE_K)), np.flatnonzero(cnt > _SPARSE_K)
        K = max(int(cnt[self.si].max()) if self.si.size else 1, 1)
        order = np.argsort(~nz[self.si], axis=1, kind="stable")[:, :K]          # non-zero columns first
        self.vals = np.take_along_axis(G[self.si], order, 1)                     # zeros in padded slots
        self.flat = (order[:, :, None] * n + order[:, None, :]).ravel()
        self.Gd = G[self.di]

    def gtdg(self, Q: np.ndarray, D: np.ndarray, delta: float) -> np.ndarray:
        n = self.n
        H = Q.copy()
        diag = np.bincount(self.c1, self.v1 * D[self.i1], n) + delta
        H.ravel()[::n + 1] += diag
        if self.si.size:
            v = self.vals * np.sqrt(D[self.si])[:, None]
            np.add.at(H.ravel(), self.flat, (v[:, :, None] * v[:, None, :]).ravel())
        if self.di.size:
            H += (self.Gd.T * D[self.di]) @ self.Gd
        return H


class IpmPoint(NamedTuple):
    x: np.ndarray
    s: np.ndarray
    lam: np.ndarray
    nu: np.ndarray
    stopped: bool        # residuals and mean gap small (with ``full``: and :func:`converged` holds)
    infeasible: bool     # (lam, nu) is a normalised Farkas certificate
    iterations: int


def ipm(Q, q, G, h, A, b, *, tol: float, eps_inf: float, max_iters: int = 50, delta: float = 1e-10,
        eps: float = 1e-12, rows: _Rows | None = None, start: tuple | None = None, full: bool = False) -> IpmPoint:
    """Mehrotra predictor-corrector on ``min 1/2 x^T Q x + q^T x  s.t.  G x + s = h, s >= 0, A x = b`` with A of
    full row rank (reduced); Q (n, n) symmetric PSD, G (m, n), A (k, n). The stopping and certificate tests of
    the kernel's ``_qp_ipm.ipm`` (see the module docstring); with ``full`` it stops only where :func:`converged`
    holds too (the degenerate rows' lam and slack, both ~sqrt(mu), must fall below the tolerance: about ten more
    iterations). ``start``: (x, s, lam, nu) of an earlier call to continue from (s, lam > 0).
    Each iteration: H = Q + G^T diag(lam / s) G + delta I = L L^T (Cholesky), W = L^-1 A^T, the Schur complement
    W^T W + eps I (Cholesky), then the predictor and the corrector directions by triangular solves."""
    n, m, k = q.shape[0], G.shape[0], A.shape[0]
    rows = _Rows(G) if rows is None else rows
    if start is None:
        x, s, lam, nu = np.zeros(n), np.maximum(h, 1.0), np.ones(m), np.zeros(k)
    else:
        x, s, lam, nu = start
    At = np.asfortranarray(A.T)
    hb, qn = max(_amax(h), _amax(b)), _amax(q)
    it = 0
    for it in range(max_iters + 1):
        Qx, Gx, Gtlam = Q @ x, G @ x, G.T @ lam
        r_d = Qx + q + Gtlam + At @ nu
        r_in = Gx + s - h
        r_eq = A @ x - b
        mu = float(s @ lam) / max(m, 1)
        obj = 0.5 * float(x @ Qx) + float(q @ x)
        r_dn = _amax(r_d)
        if not np.isfinite(obj + mu + r_dn):             # a NaN / inf in x, lam or nu reaches one of them
            break
        if max(_amax(r_in), _amax(r_eq)) <= tol * (1 + max(_amax(Gx), hb)) \
                and r_dn <= tol * (1 + max(_amax(Qx), qn, _amax(Gtlam))) \
                and mu <= tol * (1 + abs(obj)) and (not full or converged(Q, q, G, h, A, b, x, lam, nu, tol)):
            return IpmPoint(x, s, lam, nu, True, False, it)
        g = -(float(h @ lam) + float(b @ nu))
        if g > 0:
            sc = max(_amax(lam), _amax(nu), _TINY)
            if _amax(Gtlam + At @ nu) <= eps_inf * g and np.isfinite(g):
                return IpmPoint(x, s, lam / sc, nu / sc, False, True, it)
        if it == max_iters:
            break
        D = lam / s
        try:
            L = _chol(rows.gtdg(Q, D, delta))
            if k:
                W, _ = dtrtrs(L, At, lower=1)                                  # L^-1 A^T
                S = W.T @ W
                S[np.diag_indices(k)] += eps
                Ls = _chol(S)
        except np.linalg.LinAlgError:
            break

        def solve(r_c):
            # dlam = D (G dx + r_in) + r_c / s;  H dx + A^T dnu = -r_d - G^T (D r_in + r_c / s);  A dx = -r_eq
            Hr = _cho_solve(L, -r_d - G.T @ (D * r_in + r_c / s))
            if k:
                dnu = _cho_solve(Ls, A @ Hr + r_eq)
                dx = Hr - _cho_solve(L, At @ dnu)
            else:
                dnu, dx = nu, Hr
            Gdx = G @ dx
            return dx, -r_in - Gdx, D * (Gdx + r_in) + r_c / s, dnu

        dx, ds, dlam, dnu = solve(-s * lam)                                     # affine (predictor)
        a = min(_max_step(s, ds), _max_step(lam, dlam))
        mu_aff = float((s + a * ds) @ (lam + a * dlam)) / max(m, 1)
        sigma = min(max(mu_aff / max(mu, _TINY), 0.0), 1.0) ** 3
        dx, ds, dlam, dnu = solve(-s * lam + sigma * mu - ds * dlam)            # corrector
        a = 0.99 * min(_max_step(s, ds), _max_step(lam, dlam))
        x, s, lam = x + a * dx, s + a * ds, lam + a * dlam
        if k:
            nu = nu + a * dnu
    fin = lambda v: np.nan_to_num(v, nan=0.0, posinf=0.0, neginf=0.0)  # noqa: E731
    return IpmPoint(fin(x), fin(s), fin(lam), fin(nu), False, False, it)


def _max_step(v: np.ndarray, dv: np.ndarray) -> float:
    """Largest a in (0, 1] with v + a dv >= 0 (v > 0): 1 / max_i(-dv_i / v_i), capped at 1."""
    r = float((dv / v).min()) if v.size else 0.0
    return 1.0 if r >= -1.0 else -1.0 / r


def converged(Q, q, G, h, A, b, x, lam, nu, tol: float) -> bool:
    """The kernel's converged test (``_qp_admm._converged`` on unscaled data) for l <= C x <= u with
    C = [G; A], l = [-inf; b], u = [h; b], y = [lam; nu]: OSQP's relative residual test, and row by row lam_i = 0
    within the dual tolerance or slack_i = 0 within the primal tolerance (a negative lam_i fails unless it is
    negligible), and the gap |lam^T (h - G x)| below tol (1 + the largest term of the objective and of
    lam^T G x, lam^T h)."""
    if not (np.isfinite(x).all() and np.isfinite(lam).all() and np.isfinite(nu).all()):
        return False
    Qx, Gx, Ax = Q @ x, G @ x, A @ x
    Cty = G.T @ lam + A.T @ nu
    r_p = max(_amax(np.maximum(Gx - h, 0.0)), _amax(Ax - b))
    r_d = _amax(Qx + q + Cty)
    size_p = max(_amax(Gx), _amax(np.minimum(Gx, h)), _amax(Ax), _amax(b))
    size_d = max(_amax(Qx), _amax(Cty), _amax(q))
    eps_p, eps_d = tol * (1 + size_p), tol * (1 + size_d)
    if r_p > eps_p or r_d > eps_d:
        return False
    if not lam.size:
        return True
    rown = np.abs(G).max(1) if G.shape[1] else np.zeros_like(h)
    pos, neg = lam > 0, lam < 0
    slack = np.where(pos, h - Gx, 0.0)
    small = np.abs(lam) * rown <= eps_d
    row_ok = np.where(neg, small, (slack <= eps_p) | small)
    if not row_ok.all():
        return False
    fin = ~neg
    ay = np.abs(lam)
    gap = float((ay * slack)[fin].sum())
    scale = max(abs(float(x @ Qx)), abs(float(q @ x)), float((ay * np.abs(Gx))[fin].sum()),
                float((ay * np.abs(np.where(pos, h, 0.0)))[fin].sum()))
    return abs(gap) <= tol * (1 + scale)


def polish(Q, q, G, h, A, b, x, lam, nu, *, tol: float, delta: float, rounds: int = _POLISH_ROUNDS, rows=None):
    """Active-set polish from (x, lam, nu) with active-set corrections (see the module docstring).
    Returns (ok, x, lam, nu): the first polished point that passes :func:`converged`, else ok False."""
    rows = _Rows(G) if rows is None else rows
    QA = Q + (A.T / delta) @ A
    act = np.maximum(h - G @ x, 0.0) < lam
    for _ in range(rounds):
        ia = np.flatnonzero(act)
        Ca = np.vstack([G[ia], A])
        target = np.concatenate([h[ia], b])
        try:
            L = _chol(rows.gtdg(QA, act / delta, delta))
        except np.linalg.LinAlgError:
            return False, x, lam, nu
        xp, yp = x.copy(), np.concatenate([lam[ia], nu])
        for _ in range(_POLISH_REFINE):
            r1 = -q - Q @ xp - Ca.T @ yp
            r2 = target - Ca @ xp
            dx = _cho_solve(L, r1 + Ca.T @ (r2 / delta))
            yp = yp + (Ca @ dx - r2) / delta
            xp = xp + dx
        lp = np.zeros_like(lam)
        lp[ia] = yp[:ia.size]
        np_ = yp[ia.size:]
        if converged(Q, q, G, h, A, b, xp, lp, np_, tol):
            return True, xp, lp, np_
        if not (np.isfinite(xp).all() and np.isfinite(yp).all()):
            return False, x, lam, nu
        wrong = act & (lp < 0)                                           # wrong-sign rows leave
        joins = ~act & (G @ xp > h)                                      # violated rows join
        if not (wrong.any() or joins.any()):
            break
        act = (act & ~wrong) | joins
    return False, x, lam, nu


def _stages(Q, p, G, h, A, b, rows: _Rows, start, tol: float, eps_inf: float, delta: float, ipm_iters: int):
    """Steps 3-5 on the reduced problem, from ``start`` (x, s, lam, nu) or the default point: the interior point in
    stages, each continuing from the last one's point and followed by the polish: a loose stop (the active set is
    usually clear by then), the kernel's stop, then the full test (a degenerate optimum whose active set the
    polish did not find: the rows' lam and slack fall below the tolerance). Returns (x, lam, nu, status,
    iterations)."""
    iters = 0
    x, lam, nu, status = np.zeros(p.shape[0]), np.zeros(h.shape[0]), np.zeros(b.shape[0]), _MAX_ITERATIONS
    for stage_tol, full in ((_EARLY * tol, False), (tol, False), (tol, True)):
        pt = ipm(Q, p, G, h, A, b, tol=stage_tol, eps_inf=eps_inf, max_iters=ipm_iters - iters, rows=rows,
                 start=start, full=full)
        iters += pt.iterations
        x, lam, nu = pt.x, pt.lam, pt.nu
        if pt.infeasible:
            return x, lam, nu, _INFEASIBLE, iters
        if not pt.stopped:
            break
        if full:                                 # stopped on the full test
            return x, lam, nu, _CONVERGED, iters
        ok, xp, lp, np_ = polish(Q, p, G, h, A, b, x, lam, nu, tol=tol, delta=delta, rows=rows)
        if ok:
            return xp, lp, np_, _CONVERGED, iters
        if stage_tol == tol and converged(Q, p, G, h, A, b, x, lam, nu, tol):
            return x, lam, nu, _CONVERGED, iters
        start = (pt.x, pt.s, pt.lam, pt.nu)
    return x, lam, nu, status, iters


def solve_dense(Q, p, G, h, A, b, *, tol: float, eps_inf: float, delta: float, rank_tol: float,
                range_tol: float, ipm_iters: int = 50, warm: tuple | None = None) -> DenseSolution:
    """One QP (float64 NumPy arrays: Q (nz, nz), p (nz,), G (nineq, nz), h (nineq,), A (neq, nz), b (neq,)),
    steps 1-5 of the module docstring. Tolerances as :class:`torchhand.kernels.convex_qp.QPTolerances`.
    warm: (z (nz,), lam (nineq,), nu (neq,)) of a nearby problem (the previous window's solution): its active set
    (lam_i > slack_i) is polished first; when that point passes :func:`converged` it is the answer (iterations 0),
    otherwise the interior point starts from it (slacks and multipliers raised to at least ``_WARM_FLOOR``: about
    half the iterations of a cold start on consecutive windows), and from the default point when that start
    ends undecided."""
    nz, nineq, neq = p.shape[0], h.shape[0], b.shape[0]
    if not all(np.isfinite(t).all() for t in (Q, p, G, h, A, b)):
        return DenseSolution(np.zeros(nz), np.zeros(nineq), np.zeros(neq), _INVALID, 0)
    Q = 0.5 * (Q + Q.T)
    if neq:
        U, S, _ = np.linalg.svd(A, full_matrices=False)
        keep = S > rank_tol * max(float(S[0]) if S.size else 0.0, _TINY)
        Ur = U[:, keep]
        Ar, br = Ur.T @ A, Ur.T @ b
        resid = b - Ur @ br
        if np.linalg.norm(resid) > range_tol * np.linalg.norm(b):
            nu = -resid / max(_amax(resid), _TINY)
            return DenseSolution(np.zeros(nz), np.zeros(nineq), nu, _INFEASIBLE, 0)
    else:
        Ur, Ar, br = np.zeros((0, 0)), A, b
    rows = _Rows(G)
    start = None
    if warm is not None:
        z0, lam0, nu0 = warm
        nu0r = Ur.T @ nu0 if neq else nu0
        ok, xp, lp, np_ = polish(Q, p, G, h, Ar, br, z0, lam0, nu0r, tol=tol, delta=delta, rows=rows, rounds=1)
        if ok:
            return DenseSolution(xp, lp, Ur @ np_ if neq else np_, _CONVERGED, 0)
        start = (z0, np.maximum(h - G @ z0, _WARM_FLOOR), np.maximum(lam0, _WARM_FLOOR), nu0r)
    x, lam, nu_r, status, iters = _stages(Q, p, G, h, Ar, br, rows, start, tol, eps_inf, delta, ipm_iters)
    if status == _MAX_ITERATIONS and start is not None:                # the warm start misled it: cold
        x, lam, nu_r, status, more = _stages(Q, p, G, h, Ar, br, rows, None, tol, eps_inf, delta, ipm_iters)
        iters += more
    nu = Ur @ nu_r if neq else nu_r
    return DenseSolution(x, lam, nu, status, iters)


def _tensor(x, name: str, shape: tuple, dtype, device) -> torch.Tensor:
    if not isinstance(x, torch.Tensor):
        raise ShapeError(f"{name}: expected a tensor of shape {shape}, got {type(x).__name__}")
    if tuple(x.shape) != tuple(shape):
        raise ShapeError(f"{name}: expected shape {tuple(shape)}, got {tuple(x.shape)}")
    if x.dtype != dtype or x.device != device:
        raise InputValueError(f"{name}: expected {dtype} on {device} (as p), got {x.dtype} on {x.device}")
    return x


def solve_qp_dense(Q: torch.Tensor, p: torch.Tensor, G: torch.Tensor | None = None, h: torch.Tensor | None = None,
                   A: torch.Tensor | None = None, b: torch.Tensor | None = None, *,
                   warm_start: tuple | None = None, tol: float | None = None, ipm_iters: int = 50,
                   max_iters: int | None = None) -> ConvexQPResult:
    """Solve B small convex QPs ``min 1/2 z^T Q z + p^T z  s.t.  G z <= h, A z = b`` one at a time on the CPU
    (see the module docstring): the single-problem counterpart of the batched kernel
    :func:`torchhand.kernels.convex_qp.solve_convex_qp`, with its statuses, tolerances and result.

    Args:
        Q: quadratic term, (B, nz, nz), positive semidefinite (symmetrised here)
        p: linear term, (B, nz); fixes B, dtype (float32 or float64; the solve runs in float64) and device
        G: inequality rows, (B, nineq, nz), or None; h: (B, nineq) or None
        A: equality rows, (B, neq, nz), or None (any rank); b: (B, neq) or None
        warm_start: (z (B, nz), lam (B, nineq) or None, nu (B, neq) or None), e.g. the previous window's
            solution shifted: polished first, then the interior point's start (see :func:`solve_dense`)
        tol: relative residual tolerance of CONVERGED (default per dtype, ``qp_tolerances``)
        ipm_iters: interior-point iterations per start
        max_iters: ADMM iteration limit of the kernel that takes the undecided problems (default per dtype)

    Returns:
        :class:`~torchhand.kernels.convex_qp.ConvexQPResult` with leading B, on p's device and dtype;
        ``iterations`` counts interior-point iterations (plus the kernel's for the problems handed to it).
    """
    if not isinstance(p, torch.Tensor) or p.dim() != 2:
        raise ShapeError(f"p: expected shape (B, nz), got "
                         f"{tuple(p.shape) if isinstance(p, torch.Tensor) else type(p).__name__}")
    if p.dtype not in (torch.float32, torch.float64):
        raise InputValueError(f"p: expected float32 or float64, got {p.dtype}")
    if (G is None) != (h is None) or (A is None) != (b is None):
        raise InputValueError("G, h / A, b: give both of a pair or neither")
    B, nz = p.shape
    dt_in, dev = p.dtype, p.device
    nineq = G.shape[1] if isinstance(G, torch.Tensor) and G.dim() == 3 else 0
    neq = A.shape[1] if isinstance(A, torch.Tensor) and A.dim() == 3 else 0
    _tensor(Q, "Q", (B, nz, nz), dt_in, dev)
    G = p.new_zeros(B, 0, nz) if G is None else _tensor(G, "G", (B, nineq, nz), dt_in, dev)
    h = p.new_zeros(B, 0) if h is None else _tensor(h, "h", (B, nineq), dt_in, dev)
    A = p.new_zeros(B, 0, nz) if A is None else _tensor(A, "A", (B, neq, nz), dt_in, dev)
    b = p.new_zeros(B, 0) if b is None else _tensor(b, "b", (B, neq), dt_in, dev)
    warm = None
    if warm_start is not None:
        if not isinstance(warm_start, (tuple, list)) or len(warm_start) != 3:
            raise InputValueError("warm_start: expected a tuple (z, lam or None, nu or None)")
        shapes = ((B, nz), (B, nineq), (B, neq))
        warm = [np.zeros(sh) if t is None else
                _tensor(t, f"warm_start[{i}]", sh, dt_in, dev).detach().to("cpu", torch.float64).numpy()
                for i, (t, sh) in enumerate(zip(warm_start, shapes))]
        warm_ok = np.isfinite(warm[0]).all(1) & np.isfinite(warm[1]).all(1) & np.isfinite(warm[2]).all(1)
    tols = qp_tolerances(dt_in)
    Qn, pn, Gn, hn, An, bn = (t.detach().to("cpu", torch.float64).numpy() for t in (Q, p, G, h, A, b))
    z, lam, nu = np.zeros((B, nz)), np.zeros((B, nineq)), np.zeros((B, neq))
    status, iters = np.zeros(B, np.int8), np.zeros(B, np.int32)
    for i in range(B):
        wi = (warm[0][i], warm[1][i], warm[2][i]) if warm is not None and warm_ok[i] else None
        z[i], lam[i], nu[i], status[i], iters[i] = solve_dense(
            Qn[i], pn[i], Gn[i], hn[i], An[i], bn[i], tol=tols.tol if tol is None else float(tol),
            eps_inf=tols.eps_inf, delta=tols.delta, rank_tol=tols.rank, range_tol=tols.range, ipm_iters=ipm_iters,
            warm=wi)
    open_ = np.flatnonzero(status == _MAX_ITERATIONS)
    if open_.size:                                   # undecided here: the batched kernel, interior point first
        j = torch.from_numpy(open_)
        sub = solve_convex_qp(*(torch.from_numpy(t).index_select(0, j) for t in (Qn, pn, Gn, hn, An, bn)),
                              tol=tol, ipm_iters=ipm_iters, max_iters=max_iters, method="ipm")
        z[open_], lam[open_], nu[open_] = sub.z.numpy(), sub.lam.numpy(), sub.nu.numpy()
        status[open_], iters[open_] = sub.status.numpy(), iters[open_] + sub.iterations.numpy()
    finite = status != _INVALID
    has_sol = (status == _CONVERGED) | (status == _MAX_ITERATIONS)
    lam = np.where(has_sol[:, None], np.maximum(lam, 0.0), lam)
    Qs = 0.5 * (Qn + Qn.transpose(0, 2, 1))
    Qs, pn, Gn, hn, An, bn = (np.where(finite.reshape(-1, *[1] * (t.ndim - 1)), t, 0.0)    # never in place:
                              for t in (Qs, pn, Gn, hn, An, bn))                            # they share memory
    mv = lambda M, v: np.einsum("bij,bj->bi", M, v)  # noqa: E731
    r_g = np.maximum(mv(Gn, z) - hn, 0).max(1) if nineq else np.zeros(B)
    r_a = np.abs(mv(An, z) - bn).max(1) if neq else np.zeros(B)
    r_p = np.where(finite, np.maximum(r_g, r_a), np.inf)
    grad = mv(Qs, z) + pn + mv(Gn.transpose(0, 2, 1), lam) + mv(An.transpose(0, 2, 1), nu)
    r_d = np.where(has_sol, np.abs(grad).max(1) if nz else 0.0, np.inf)
    obj = np.where(has_sol, 0.5 * (z * mv(Qs, z)).sum(1) + (pn * z).sum(1), np.inf)
    out = lambda a: torch.from_numpy(np.ascontiguousarray(a)).to(device=dev, dtype=dt_in)  # noqa: E731
    return ConvexQPResult(z=out(z), lam=out(lam), nu=out(nu), objective=out(obj),
                          status=torch.from_numpy(status).to(dev), iterations=torch.from_numpy(iters).to(dev),
                          residual_primal=out(r_p), residual_dual=out(r_d))
