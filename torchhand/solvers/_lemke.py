"""Lemke's complementary pivoting method: an exact reference solver for small LCPs (CPU, float64, NumPy).

Finds x with x >= 0, w = M x + q >= 0, x^T w = 0 (LCP(M, q)) by pivoting on the tableau of
``w - M x - d x0 = q`` (Lemke 1965; Cottle, Pang & Stone 2009, Algorithm 4.4.5), with the covering vector d = 1
(and, after a ray termination or a terminal basis that does not solve the problem, up to ``restarts`` seeded random
covering vectors d = 1 + U(0, 1)^n: each covering vector follows another complementary path).
Degeneracy is handled by the lexicographic minimum-ratio rule on the rows of [q_bar, B^-1], which rules out
cycling; the artificial variable x0 leaves as soon as it ties for the minimum ratio. At the end the final
complementary basis is re-solved directly (one dense solve) to remove the round-off that pivoting accumulates.

Termination is reported honestly:

- CONVERGED: x0 left the basis and ||min(x, w)||_inf <= tol.
- UNBOUNDED: ray termination (the entering column has no positive entry). For copositive-plus M (for example
  positive semidefinite M) this proves that the LCP has no solution; for other M it means Lemke's method cannot
  find one from this start (a solution may still exist: the Siconos instance lcp_CPS_3, a bimatrix game, is one;
  it needs the Lemke-Howson start instead).
- MAX_ITERATIONS: ``max_pivots`` pivots without termination, or a terminal basis whose residual exceeds ``tol``
  (numerical breakdown on a badly conditioned problem).
- INVALID_INPUT: NaN/inf in M or q (nothing was solved).

Used by the tests as a reference and by :func:`torchhand.solvers.lcp.solve_lcp` as an exact fallback for small problems
that projected Gauss-Seidel cannot finish. Cost: O(n^2) per pivot, in the worst case exponentially many pivots
(Murty's example), typically O(n) pivots.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..errors import InputTypeError, InputValueError, ShapeError
from ..kernels.status import SolverStatus

__all__ = ["LemkeResult", "lemke"]


class LemkeResult(NamedTuple):
    """Result of :func:`lemke` for one LCP of size n.

    x:      solution, (n,) float64, >= 0 (zeros unless CONVERGED or MAX_ITERATIONS after a terminal basis)
    w:      M x + q, (n,) float64
    status: :class:`~torchhand.kernels.status.SolverStatus` (CONVERGED, UNBOUNDED, MAX_ITERATIONS, INVALID_INPUT)
    pivots: number of pivots performed, int
    """

    x: np.ndarray
    w: np.ndarray
    status: SolverStatus
    pivots: int

    @property
    def residual(self) -> float:
        """||min(x, w)||_inf (0 for n = 0)."""
        return float(np.abs(np.minimum(self.x, self.w)).max()) if self.x.size else 0.0


def _as_array(a, name: str, ndim: int) -> np.ndarray:
    try:
        arr = np.asarray(a.detach().cpu() if hasattr(a, "detach") else a, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise InputTypeError(f"lemke: {name} must be a real array, got {type(a).__name__} ({err})") from None
    if arr.ndim != ndim:
        raise ShapeError(f"lemke: {name} must have {ndim} dimension(s), got shape {arr.shape}")
    return arr


def _lexmin_row(rows: np.ndarray, cand: np.ndarray, col: np.ndarray, T: np.ndarray, n: int, tol: float) -> int:
    """Among candidate rows, the lexicographic minimum of [q_bar_i, B^-1_i] / col_i (ties within ``tol``)."""
    keys = np.concatenate([T[cand, -1:], T[cand, :n]], axis=1) / col[cand, None]
    best = 0
    for k in range(1, len(cand)):
        diff = keys[k] - keys[best]
        nz = np.flatnonzero(np.abs(diff) > tol * (1.0 + np.abs(keys[best])))
        if nz.size and diff[nz[0]] < 0:
            best = k
    return int(rows[cand[best]])


def lemke(M, q, max_pivots: int | None = None, tol: float = 1e-9, restarts: int = 2,
          seed: int = 0) -> LemkeResult:
    """Solve LCP(M, q) by Lemke's method with lexicographic degeneracy resolution.

    Args:
        M: LCP matrix, (n, n), array-like or CPU/GPU tensor (converted to float64 NumPy)
        q: LCP vector, (n,)
        max_pivots: pivot limit over all runs; default ``max(1000, 50 n)``
        tol: CONVERGED needs ||min(x, w)||_inf <= tol * max(1, ||M||_inf, ||q||_inf)
        restarts: after any run that does not converge (a ray termination, or a terminal complementary basis whose
            re-solved x misses ``tol``: round-off on a badly conditioned path), retry with up to this many other
            covering vectors d = 1 + u, u ~ U(0, 1)^n (a different complementary path) while pivots remain; the
            last run's status is reported
        seed: seed of the NumPy generator that draws those covering vectors (no global RNG is touched)

    Returns:
        :class:`LemkeResult`; ``pivots`` counts all runs. Raises :class:`~torchhand.errors.ShapeError` for
        inconsistent shapes and :class:`~torchhand.errors.InputValueError` for negative limits.
    """
    M = _as_array(M, "M", 2)
    q = _as_array(q, "q", 1)
    n = q.shape[0]
    if M.shape != (n, n):
        raise ShapeError(f"lemke: M must have shape ({n}, {n}) to match q {q.shape}, got {M.shape}")
    max_pivots = max(1000, 50 * n) if max_pivots is None else int(max_pivots)
    if max_pivots < 0 or restarts < 0:
        raise InputValueError(f"lemke: max_pivots and restarts must be >= 0, got {max_pivots}, {restarts}")
    zeros = np.zeros(n)
    if not (np.isfinite(M).all() and np.isfinite(q).all()):
        return LemkeResult(zeros, zeros.copy(), SolverStatus.INVALID_INPUT, 0)
    if n == 0 or q.min() >= 0:
        return LemkeResult(zeros, M @ zeros + q, SolverStatus.CONVERGED, 0)
    rng = np.random.default_rng(seed)
    d = np.ones(n)
    used = 0
    for attempt in range(restarts + 1):
        out = _lemke_run(M, q, d, max_pivots - used, tol)
        used += out.pivots
        if out.status == SolverStatus.CONVERGED or used >= max_pivots:
            break
        d = 1.0 + rng.uniform(0.0, 1.0, n)
    return out._replace(pivots=used)


def _lemke_run(M: np.ndarray, q: np.ndarray, d: np.ndarray, max_pivots: int, tol: float) -> LemkeResult:
    """One run of Lemke's method with covering vector d > 0 (q has a negative entry)."""
    n = q.shape[0]
    zeros = np.zeros(n)
    scale = max(1.0, float(np.abs(M).max(initial=0.0)), float(np.abs(q).max(initial=0.0)))
    # Tableau columns: w_0..w_{n-1} | x_0..x_{n-1} | x0 (artificial) | rhs.  w - M x - d x0 = q.
    T = np.zeros((n, 2 * n + 2))
    T[:, :n] = np.eye(n)
    T[:, n:2 * n] = -M
    T[:, 2 * n] = -d
    T[:, -1] = q
    basis = np.arange(n)                       # basic variable of each row
    art = 2 * n
    piv_tol = 1e-12 * scale
    rows = np.arange(n)

    def pivot(r: int, e: int) -> None:
        T[r] /= T[r, e]
        col = T[:, e].copy()
        col[r] = 0.0
        T[:] -= np.outer(col, T[r])
        basis[r] = e

    # Initial pivot: x0 enters, the row with the lexicographically smallest (q_i, e_i) / d_i leaves.
    if max_pivots < 1:
        return LemkeResult(zeros, zeros.copy(), SolverStatus.MAX_ITERATIONS, 0)
    ratio = q / d
    cand = np.flatnonzero(ratio <= ratio.min() + 1e-12 * scale)
    r = _lexmin_row(rows, cand, d, T, n, 1e-12)               # -(column of x0) = d
    pivot(r, art)
    entering = n + r                           # w_r left: its complement x_r enters
    pivots = 1
    status = SolverStatus.MAX_ITERATIONS
    while pivots < max_pivots:
        col = T[:, entering]
        pos = col > piv_tol
        if not pos.any():
            status = SolverStatus.UNBOUNDED    # ray termination
            break
        idx = np.flatnonzero(pos)
        ratios = T[idx, -1] / col[idx]
        theta = ratios.min()
        ties = idx[ratios <= theta + 1e-12 * max(1.0, abs(theta))]
        art_row = np.flatnonzero(basis == art)
        if art_row.size and art_row[0] in ties:
            r = int(art_row[0])
        elif ties.size == 1:
            r = int(ties[0])
        else:
            r = _lexmin_row(rows, ties, col, T, n, 1e-12)
        leaving = int(basis[r])
        pivot(r, entering)
        pivots += 1
        if leaving == art:
            status = SolverStatus.CONVERGED
            break
        entering = leaving + n if leaving < n else leaving - n
    if status == SolverStatus.UNBOUNDED:
        return LemkeResult(zeros, zeros.copy(), status, pivots)
    if status != SolverStatus.CONVERGED:
        return LemkeResult(zeros, zeros.copy(), status, pivots)

    x = _refine(M, q, basis, T)
    w = M @ x + q
    res = float(np.abs(np.minimum(x, w)).max())
    if res > tol * scale:
        return LemkeResult(x, w, SolverStatus.MAX_ITERATIONS, pivots)
    return LemkeResult(x, w, SolverStatus.CONVERGED, pivots)


def _refine(M: np.ndarray, q: np.ndarray, basis: np.ndarray, T: np.ndarray) -> np.ndarray:
    """x from the terminal complementary basis: the tableau's values, improved by one direct solve of
    [I, -M]_basis v = q when that is better conditioned than the accumulated pivots."""
    n = q.shape[0]
    x = np.zeros(n)
    is_x = basis >= n
    x[basis[is_x] - n] = T[is_x, -1]
    x = np.maximum(x, 0.0)
    cols = np.concatenate([np.eye(n), -M], axis=1)[:, basis]
    try:
        v = np.linalg.solve(cols, q)
    except np.linalg.LinAlgError:
        return x
    x2 = np.zeros(n)
    x2[basis[is_x] - n] = v[is_x]
    x2 = np.maximum(x2, 0.0)
    r1 = np.abs(np.minimum(x, M @ x + q)).max()
    r2 = np.abs(np.minimum(x2, M @ x2 + q)).max()
    return x2 if r2 <= r1 else x
