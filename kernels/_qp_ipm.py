"""Batched primal-dual interior-point method (Mehrotra predictor-corrector): the cold-start solver of
:mod:`.convex_qp`. ::

    minimise  1/2 x^T Q x + q^T x   subject to  G x + s = h, s >= 0,  A x = b

(A with orthogonal rows, possibly zero rows, as :func:`.convex_qp.reduce_equalities` leaves it). Each iteration
solves the Newton system reduced to (Q + G^T diag(lam / s) G + delta I) dx + A^T dnu = r, A dx = r_eq by a
Cholesky factorisation and a Schur complement on the equality rows (with a small ``eps`` on its diagonal, so zero
rows give dnu = 0), once for the affine (predictor) and once for the centred (corrector) direction (Mehrotra
1992; as in CVXOPT's coneqp and qpth). Rows of G with few non-zeros in the same columns across the batch (bounds,
the normal-force rows of a window QP) are kept sparse: G x, G^T v and G^T D G are formed by gather / scatter, not
by dense products. It stops on the relative residual test of :mod:`._qp_admm` plus a duality gap test
(``stopped``); whether its point, or the polish started from it, is CONVERGED is decided by :mod:`.convex_qp`
with the full test (complementarity row by row, multiplier signs). Infeasibility: a Farkas test on the normalised
multipliers (see :func:`ipm`). One host sync per iteration;
decided problems leave the working set. Takes about 10-20 iterations on the window QPs, also at the edge of
feasibility where ADMM stalls; it cannot use warm starts (ADMM does).
"""

from __future__ import annotations

from typing import NamedTuple

import torch


class IpmOutput(NamedTuple):
    x: torch.Tensor           # (B, n)
    lam: torch.Tensor         # (B, nineq) >= 0; the certificate's part (|(lam, nu)|_inf = 1) when infeasible
    nu: torch.Tensor          # (B, neq)
    stopped: torch.Tensor     # (B,) bool: residuals and duality gap small (not yet the full test: see :func:`ipm`)
    infeasible: torch.Tensor  # (B,) bool: (lam, nu) is a Farkas certificate (see :func:`ipm`)
    iterations: torch.Tensor  # (B,) int32


def _mv(M, v):
    return torch.bmm(M, v.unsqueeze(-1)).squeeze(-1)


def _amax(v):
    return v.abs().amax(-1) if v.shape[-1] else v.new_zeros(v.shape[:-1])


def _max_step(v, dv):
    """Largest a in (0, 1] with v + a dv >= 0 (v > 0), per problem."""
    if not v.shape[-1]:
        return v.new_ones(v.shape[:-1])
    ratio = torch.where(dv < 0, v / (-dv), 1.0)             # -dv > 0 where selected; 1.0 elsewhere caps at 1
    return ratio.amin(-1).clamp(max=1.0)


_SPARSE_K = 8      # rows of G with at most this many non-zeros (same columns in every problem) are scattered


class _SparseRows(NamedTuple):
    """G split for forming G^T diag(d) G: sparse rows (same pattern in every problem) and dense rows."""

    si: torch.Tensor    # (R,) indices of the sparse rows
    cols: torch.Tensor  # (R, K) their non-zero columns (padded)
    flat: torch.Tensor  # (R * K * K,) flat (n * n) positions of their outer products
    vals: torch.Tensor  # (B, R, K) their non-zeros (0 in padded slots)
    di: torch.Tensor    # (R2,) indices of the dense rows
    Gd: torch.Tensor    # (B, R2, n) the dense rows


def _sparse_rows(G: torch.Tensor) -> _SparseRows:
    """Find the rows of G (B, m, n) with at most ``_SPARSE_K`` non-zero columns over the whole batch (bounds, the
    normal-force rows of a window QP); one host sync."""
    B, m, n = G.shape
    pattern = (G != 0).any(0)                                                  # (m, n)
    cnt = pattern.sum(-1)
    sparse = cnt <= _SPARSE_K
    si, di = sparse.nonzero().squeeze(-1), (~sparse).nonzero().squeeze(-1)    # host sync: once
    K = max(int(cnt.index_select(0, si).max()) if si.numel() else 1, 1)
    # Column indices of each sparse row's non-zeros, padded with the row's first column and a zero value.
    order = torch.sort(pattern.index_select(0, si).to(torch.int8), dim=-1, descending=True, stable=True).indices
    cols = order[:, :K]                                                        # (R, K)
    valid = pattern.index_select(0, si).gather(1, cols)
    vals = G.index_select(1, si).gather(2, cols.unsqueeze(0).expand(B, -1, -1)) * valid.to(G.dtype)
    flat = (cols.unsqueeze(-1) * n + cols.unsqueeze(-2)).reshape(-1)
    return _SparseRows(si=si, cols=cols, flat=flat, vals=vals, di=di, Gd=G.index_select(1, di))


def _gx(sp: _SparseRows, x: torch.Tensor, m: int) -> torch.Tensor:
    """G x, (B, m)."""
    B = x.shape[0]
    xs = x[:, sp.cols]                                                         # (B, R, K)
    out = x.new_zeros(B, m).index_copy(1, sp.si, (sp.vals * xs).sum(-1))
    if sp.di.numel():
        out = out.index_copy(1, sp.di, _mv(sp.Gd, x))
    return out


def _gtv(sp: _SparseRows, v: torch.Tensor, n: int) -> torch.Tensor:
    """G^T v, (B, n)."""
    B = v.shape[0]
    contrib = (sp.vals * v.index_select(1, sp.si).unsqueeze(-1)).reshape(B, -1)
    out = v.new_zeros(B, n).index_add(1, sp.cols.reshape(-1), contrib)
    if sp.di.numel():
        out = out + torch.bmm(v.index_select(1, sp.di).unsqueeze(1), sp.Gd).squeeze(1)
    return out


def _gtdg(sp: _SparseRows, D: torch.Tensor, Q: torch.Tensor, delta: float) -> torch.Tensor:
    """Q + G^T diag(D) G + delta I, (B, n, n), with the sparse rows scattered."""
    B, n = Q.shape[0], Q.shape[-1]
    v = sp.vals * D.index_select(1, sp.si).sqrt().unsqueeze(-1)                # (B, R, K)
    outer = (v.unsqueeze(-1) * v.unsqueeze(-2)).reshape(B, -1)
    H = Q.reshape(B, n * n).index_add(1, sp.flat, outer).reshape(B, n, n)
    if sp.di.numel():
        Gd = sp.Gd
        H = H + torch.bmm(Gd.transpose(1, 2) * D.index_select(1, sp.di).unsqueeze(1), Gd)
    return H + delta * torch.eye(n, dtype=Q.dtype, device=Q.device)


def ipm(Q, q, G, h, A, b, *, tol: float, eps_inf: float, max_iters: int = 50, delta: float = 1e-10,
        eps: float = 1e-12) -> IpmOutput:
    """Iterate the B problems until the relative residual test of :mod:`._qp_admm` (tolerance ``tol``) holds and the
    mean complementarity s^T lam / m is below ``tol (1 + |objective|)`` (``stopped``). That is not the full
    converged test: at a degenerate optimum (several optimal points, or rows with lam = slack = 0) some rows then
    still have lam and slack both ~sqrt(mu), so lam^T (G x - h) is far from 0 relative to the objective; the
    caller polishes (:func:`.convex_qp._ipm_then_polish`) and applies the full test.

    Infeasibility: on an infeasible problem the multipliers grow along a Farkas direction. Every iteration the
    normalised (lam, nu) is tested: with e = G^T lam + A^T nu and g = -(h^T lam + b^T nu), ``g > 0`` and
    ``|e|_inf <= eps_inf g`` prove that every feasible x has |x|_1 >= g / |e|_inf >= 1 / eps_inf (since
    e^T x <= -g for feasible x). Problems that are decided leave the working set.
    """
    return _ipm(Q, q, G, h, A, b, tol, eps_inf, max_iters, delta, eps)


def _ipm(Q, q, G, h, A, b, tol, eps_inf, max_iters, delta, eps) -> IpmOutput:
    B0 = q.shape[0]
    out_x, out_lam = q.new_zeros(q.shape), q.new_zeros(h.shape)
    out_nu = q.new_zeros(b.shape)
    out_conv = torch.zeros(B0, dtype=torch.bool, device=q.device)
    out_inf = torch.zeros_like(out_conv)
    out_it = torch.zeros(B0, dtype=torch.int32, device=q.device)
    idx = torch.arange(B0, device=q.device)
    B, n = q.shape
    m, neq = G.shape[1], A.shape[1]
    eye_e = torch.eye(neq, dtype=q.dtype, device=q.device)
    At = A.transpose(1, 2)
    sp = _sparse_rows(G)
    x = q.new_zeros(B, n)
    s = h.clamp_min(1.0)
    lam = torch.ones_like(s)
    nu = q.new_zeros(B, neq)
    for it in range(max_iters + 1):
        Qx = _mv(Q, x)
        Gtlam = _gtv(sp, lam, n)
        Gx = _gx(sp, x, m)
        r_d = Qx + q + Gtlam + _mv(At, nu)
        r_in = Gx + s - h
        r_eq = _mv(A, x) - b
        mu = (s * lam).sum(-1) / max(m, 1)
        size_p = torch.maximum(torch.maximum(_amax(Gx), _amax(h)), _amax(b))
        size_d = torch.maximum(torch.maximum(_amax(Qx), _amax(q)), _amax(Gtlam))
        obj = 0.5 * (x * Qx).sum(-1) + (q * x).sum(-1)
        ok = (torch.maximum(_amax(r_in), _amax(r_eq)) <= tol * (1 + size_p)) & (_amax(r_d) <= tol * (1 + size_d)) \
            & (mu <= tol * (1 + obj.abs())) & torch.isfinite(x).all(-1)
        sc = torch.maximum(_amax(lam), _amax(nu)).clamp_min(torch.finfo(q.dtype).tiny).unsqueeze(-1)
        lc, nc = lam / sc, nu / sc
        e = _amax(Gtlam / sc + _mv(At, nc))
        g = -((h * lc).sum(-1) + (b * nc).sum(-1))
        cert = ~ok & (g > 0) & (e <= eps_inf * g) & torch.isfinite(g)
        done = ok | cert
        if it == max_iters:
            done = torch.ones_like(done)
        if bool(done.any()):                                    # host sync: once per iteration
            j = done.nonzero().squeeze(-1)
            jj = idx.index_select(0, j)
            c = cert.index_select(0, j).unsqueeze(-1)
            out_x = out_x.index_copy(0, jj, x.index_select(0, j))
            out_lam = out_lam.index_copy(0, jj, torch.where(c, lc.index_select(0, j), lam.index_select(0, j)))
            out_nu = out_nu.index_copy(0, jj, torch.where(c, nc.index_select(0, j), nu.index_select(0, j)))
            out_conv = out_conv.index_copy(0, jj, ok.index_select(0, j))
            out_inf = out_inf.index_copy(0, jj, cert.index_select(0, j))
            out_it = out_it.index_copy(0, jj, torch.full_like(jj, it, dtype=torch.int32))
            k = (~done).nonzero().squeeze(-1)
            if k.numel() == 0:
                break
            idx = idx.index_select(0, k)
            Q, q, h, A, b, x, s, lam, nu = (t.index_select(0, k) for t in (Q, q, h, A, b, x, s, lam, nu))
            sp = sp._replace(vals=sp.vals.index_select(0, k), Gd=sp.Gd.index_select(0, k))
            At = A.transpose(1, 2)
            r_d, r_in, r_eq, mu = (t.index_select(0, k) for t in (r_d, r_in, r_eq, mu))
        D = lam / s
        H = _gtdg(sp, D, Q, delta)
        L, _ = torch.linalg.cholesky_ex(H)
        HiAt = torch.cholesky_solve(At, L) if neq else At
        S = torch.bmm(A, HiAt) + eps * eye_e
        Ls, _ = torch.linalg.cholesky_ex(S)

        def solve(r_c):
            # dlam = D (G dx + r_in) + r_c / s;  (H) dx + A^T dnu = -r_d - G^T (D r_in + r_c / s);  A dx = -r_eq
            rhs = -r_d - _gtv(sp, D * r_in + r_c / s, n)
            Hr = torch.cholesky_solve(rhs.unsqueeze(-1), L).squeeze(-1)
            if neq:
                dnu = torch.cholesky_solve((_mv(A, Hr) + r_eq).unsqueeze(-1), Ls).squeeze(-1)
                dx = Hr - _mv(HiAt, dnu)
            else:
                dnu, dx = nu, Hr
            Gdx = _gx(sp, dx, m)
            dlam = D * (Gdx + r_in) + r_c / s
            ds = -r_in - Gdx
            return dx, ds, dlam, dnu

        dx, ds, dlam, dnu = solve(-s * lam)                      # affine (predictor) direction
        a = torch.minimum(_max_step(s, ds), _max_step(lam, dlam))
        mu_aff = ((s + a[:, None] * ds) * (lam + a[:, None] * dlam)).sum(-1) / max(m, 1)
        sigma = (mu_aff / mu.clamp_min(torch.finfo(q.dtype).tiny)).clamp(0, 1) ** 3
        dx, ds, dlam, dnu = solve(-s * lam + (sigma * mu)[:, None] - ds * dlam)   # corrector
        a = (0.99 * torch.minimum(_max_step(s, ds), _max_step(lam, dlam))).unsqueeze(-1)
        x, s, lam = x + a * dx, s + a * ds, lam + a * dlam
        nu = nu + a * dnu if neq else nu
    bad = ~(torch.isfinite(out_x).all(-1) & torch.isfinite(out_lam).all(-1) & torch.isfinite(out_nu).all(-1))
    out_x, out_lam, out_nu = (torch.nan_to_num(t, nan=0.0, posinf=0.0, neginf=0.0) for t in (out_x, out_lam, out_nu))
    return IpmOutput(x=out_x, lam=out_lam, nu=out_nu, stopped=out_conv & ~bad, infeasible=out_inf & ~bad,
                     iterations=out_it)
