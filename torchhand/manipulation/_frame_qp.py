"""The dense convex QP of the per-frame synthesis (:mod:`.synth`): a Goldfarb-Idnani dual active-set solver."""

from __future__ import annotations

import numpy as np


# ------------------------------------------------------------------------------------------------ dense QP
def _solve_fn():
    """``solve(S, b)`` for a square float64 S (m, m) and b (m,): the LAPACK gesv gufunc that ``np.linalg.solve`` calls,
    without the wrapper's per-call argument handling (a few dozen microseconds, thousands of calls per motion);
    ``np.linalg.solve`` itself where NumPy does not expose it. Raises ``np.linalg.LinAlgError`` on a singular S."""
    try:
        from numpy.linalg import _umath_linalg
        from numpy.linalg.linalg import (
            _raise_linalgerror_singular,
            get_linalg_error_extobj,
        )

        gufunc = _umath_linalg.solve1
        extobj = get_linalg_error_extobj(_raise_linalgerror_singular)
        probe = gufunc(np.eye(2), np.ones(2), signature="dd->d", extobj=extobj)
        if not np.array_equal(probe, np.ones(2)):
            raise ValueError("probe")
    except (ImportError, AttributeError, TypeError, ValueError):     # another NumPy: the public function
        return np.linalg.solve

    def solve(S, b):
        return gufunc(S, b, signature="dd->d", extobj=extobj)
    return solve


_solve = _solve_fn()


def dense_qp(H: np.ndarray, g: np.ndarray, A: np.ndarray, b: np.ndarray, C: np.ndarray, d: np.ndarray,
             max_iters: int = 200, tol: float = 1e-10):
    """``min 1/2 x^T H x + g^T x  s.t.  A x = b, C x <= d`` for a small dense strictly convex QP (H positive
    definite), by the Goldfarb-Idnani dual active-set method. The KKT system of every active set is solved through
    its Schur complement ``N H^-1 N^T`` (m x m, m the active rows) with H^-1 from one Cholesky factorisation of
    the diagonally scaled H; a badly scaled H (diagonal ratio above 1e8, such as the elastic mode's 1e-9 slack
    weights, where the Schur route loses accuracy) solves the full KKT matrix densely at every change.

    returns: (x (n,), status: 0 solved, 1 infeasible, 2 iteration limit, largest violation left)
    """
    n = H.shape[0]
    act: list[int] = []                                       # active inequality rows
    u = np.zeros(0)                                           # multipliers of act (>= 0)
    Hinv = None
    dg = np.diag(H)
    if n and dg.min() > 0 and dg.max() <= 1e8 * dg.min():
        sc = 1.0 / np.sqrt(dg)
        try:
            Li = np.linalg.inv(np.linalg.cholesky(H * sc[:, None] * sc[None, :])) * sc[None, :]
            Hinv = Li.T @ Li
            WA, WC = A @ Hinv, C @ Hinv                       # rows of N H^-1, each constraint's once
        except np.linalg.LinAlgError:
            Hinv = None

    def kkt_schur(rhs_x, rhs_c):
        """H x - N^T y = rhs_x, -N x = rhs_c: y = -(N H^-1 N^T)^-1 (rhs_c + N H^-1 rhs_x), x = H^-1 (rhs_x + N^T y)."""
        xh = Hinv @ rhs_x
        if not act and A.shape[0] == 0:
            return xh, np.zeros(0)
        Nm = np.concatenate([A, -C[act]], 0) if act else A
        W = np.concatenate([WA, -WC[act]], 0) if act else WA
        S = W @ Nm.T
        rhs = -(rhs_c + Nm @ xh)
        try:
            y = _solve(S, rhs)
        except np.linalg.LinAlgError:
            y = np.linalg.lstsq(S, rhs, rcond=None)[0]
        return xh + W.T @ y, y

    def kkt(rhs_x, rhs_c):
        if Hinv is not None:
            return kkt_schur(rhs_x, rhs_c)
        Nm = np.array([A[i] for i in range(A.shape[0])] + [-C[j] for j in act]).reshape(-1, n)   # n^T x >= b form
        m = Nm.shape[0]
        K = np.zeros((n + m, n + m))
        K[:n, :n], K[:n, n:], K[n:, :n] = H, -Nm.T, -Nm
        try:
            sol = _solve(K, np.concatenate([rhs_x, rhs_c]))
        except np.linalg.LinAlgError:
            sol = np.linalg.lstsq(K, np.concatenate([rhs_x, rhs_c]), rcond=None)[0]
        return sol[:n], sol[n:]

    x, _ = kkt(-g, -b if A.shape[0] else np.zeros(0))
    status = 2
    feas_tol = tol * (1 + np.abs(d).max()) if C.shape[0] else 0.0
    for _ in range(max_iters):
        s = d - C @ x                                          # slack, >= 0 when satisfied
        if C.shape[0] == 0 or s.min() >= -feas_tol:
            status = 0
            break
        p = int(np.argmin(s))
        n_p = -C[p]                                            # n_p^T x >= -d_p
        n_max = np.abs(n_p).max()
        u_p = 0.0
        while True:
            z, r = kkt(n_p, np.zeros(A.shape[0] + len(act)))   # primal direction, multiplier change
            r_act = -r[A.shape[0]:]
            t1, drop = np.inf, -1
            pos = r_act > 1e-14
            if pos.any():                                       # dual step: the first multiplier to reach zero
                ratios = np.where(pos, u / np.where(pos, r_act, 1.0), np.inf)
                drop = int(np.argmin(ratios))
                t1 = float(ratios[drop])
            nz = float(n_p @ z)
            if np.abs(H @ z).max() <= 1e-9 * n_max or nz <= 0:     # dependent on the active set
                if drop < 0:
                    status = 1
                    return x, status, float(max(0.0, -s.min()))
                u = u - t1 * r_act
                u_p += t1
                del act[drop]
                u = np.delete(u, drop)
                continue
            t2 = (C[p] @ x - d[p]) / nz                         # makes row p active
            t = min(t1, t2)
            x = x + t * z
            u = u - t * r_act
            u_p += t
            if t2 <= t1:
                act.append(p)
                u = np.append(u, u_p)
                break
            del act[drop]
            u = np.delete(u, drop)
    viol = 0.0
    if C.shape[0]:
        viol = max(viol, float(max(0.0, (C @ x - d).max())))
    if A.shape[0]:
        viol = max(viol, float(np.abs(A @ x - b).max()))
    return x, status, viol
