"""Batched OSQP-style ADMM with polishing: the warm-start solver of :mod:`.convex_qp` (whose polish also
finishes the interior point's answers).

It works on B problems of one shape, already validated and with reduced equality rows::

    minimise  1/2 x^T Q x + q^T x   subject to  l <= C x <= u        (C (B, m, n); l may be -inf)

Method (Stellato et al. 2020, "OSQP: an operator splitting solver for quadratic programs", Alg. 1 and Sec. 5):

* Ruiz equilibration of the KKT matrix [[Q, C^T], [C, 0]] (``ruiz_iters`` sweeps, zero rows and columns keep
  scale 1) and a cost scale c, so x = D x', y = E y' / c, C' = E C D, Q' = c D Q D.
* Iteration on the scaled problem with per-row penalties rho_i (1e3 rho on equality rows l = u), sigma > 0:
  x~ = (Q + sigma I + C^T R C)^{-1} (sigma x - q + C^T (R z - y)), z~ = C x~, then relaxation alpha,
  z = clip(alpha z~ + (1 - alpha) z + y / rho, l, u), y += rho (alpha z~ + (1 - alpha) z_old - z).
  The (n, n) matrix is factorised once per problem and inverted (Cholesky); it changes only when rho does.
* Every ``check_every`` iterations (the only host syncs), per problem, with masks:
  - converged: OSQP's test on the unscaled residuals, r_p <= tol (1 + max(|Cx|, |z|)) and
    r_d <= tol (1 + max(|Qx|, |C^T y|, |q|)) (infinity norms), plus complementarity and multiplier signs row by
    row and the complementarity gap (:func:`_complementary`; ADMM's own iterates satisfy it by construction,
    an interior point or a polished point need not);
  - polished: an active set guessed from (z, y) (row i active when u_i - z_i < y_i, l_i - z_i > y_i, or
    l_i = u_i), then the equality-constrained KKT system [[Q, C_a^T], [C_a, 0]] solved by iterative refinement
    around a delta-regularised factorisation (Schur complement Q + delta I + C_a^T C_a / delta, so only an
    (n, n) Cholesky), started at the ADMM point. The polished point counts only when it passes the converged test
    above (which includes the sign conditions of the multipliers); otherwise ADMM goes on (no harm done);
  - primal infeasible: OSQP's certificate dy = y_k - y_{k-1} (signs projected: dy_i >= 0 where l_i = -inf),
    |C^T dy| <= eps_inf |dy| and u^T dy_+ + l^T dy_- <= -eps_inf |dy| on the scaled problem;
  - unbounded (dual infeasible): dx = x_k - x_{k-1} with |Q dx| <= eps_inf |dx|, q^T dx <= -eps_inf |dx| and
    C dx in the recession cone of [l, u] up to eps_inf |dx|;
  - rho update (OSQP's residual balancing, per problem) when it would change by more than ``adapt_factor``;
    only the problems whose rho changed are refactorised.
* Finished problems leave the working set at the checks, so the late iterations cost only the stragglers.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from .status import SolverStatus

_CONVERGED = int(SolverStatus.CONVERGED)
_INFEASIBLE = int(SolverStatus.INFEASIBLE)
_MAX_ITERATIONS = int(SolverStatus.MAX_ITERATIONS)
_UNBOUNDED = int(SolverStatus.UNBOUNDED)


class AdmmSettings(NamedTuple):
    tol: float                  # relative residual tolerance of the converged test (unscaled)
    eps_inf: float              # infeasibility / unboundedness certificate tolerance (scaled)
    delta: float                # polish regularisation (scaled units)
    max_iters: int
    check_every: int = 25
    rho: float = 0.1
    sigma: float = 1e-6
    alpha: float = 1.6
    adapt_factor: float = 2.0
    polish: bool = True
    polish_refine: int = 4      # iterative-refinement steps of a polish
    ruiz_iters: int = 6


class AdmmOutput(NamedTuple):
    x: torch.Tensor             # (B, n) primal solution (unscaled)
    y: torch.Tensor             # (B, m) multipliers of l <= Cx <= u (unscaled); the certificate when INFEASIBLE
    status: torch.Tensor        # (B,) int8
    iterations: torch.Tensor    # (B,) int32


def _mv(M: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    return torch.bmm(M, v.unsqueeze(-1)).squeeze(-1)


def _mtv(M: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    return torch.bmm(v.unsqueeze(1), M).squeeze(1)


def _amax(v: torch.Tensor) -> torch.Tensor:
    return v.abs().amax(-1) if v.shape[-1] else v.new_zeros(v.shape[:-1])


def ruiz(Q: torch.Tensor, q: torch.Tensor, C: torch.Tensor, iters: int):
    """Ruiz equilibration of [[Q, C^T], [C, 0]] and a cost scale. Returns (D (B, n), E (B, m), c (B,))."""
    B, n = q.shape
    D = q.new_ones(B, n)
    E = q.new_ones(B, C.shape[1])
    # |Q D D| = |Q| D D exactly (D, E > 0; rounding is sign-symmetric): the absolute values are taken once.
    Qa, Ca = Q.abs(), C.abs()
    Qs, Cs = Qa, Ca
    for _ in range(iters):
        col = torch.maximum(Qs.amax(1), Cs.amax(1) if Cs.shape[1] else Qs.new_zeros(B, n))
        row = Cs.amax(2)
        dc = torch.where(col > 1e-4, col, torch.ones_like(col)).rsqrt().clamp(1e-4, 1e4)
        dr = torch.where(row > 1e-4, row, torch.ones_like(row)).rsqrt().clamp(1e-4, 1e4)
        D, E = D * dc, E * dr
        Qs = Qa * D.unsqueeze(2) * D.unsqueeze(1)
        Cs = Ca * E.unsqueeze(2) * D.unsqueeze(1)
    qs = q * D
    scale = torch.maximum(Qs.amax(1).mean(1), qs.abs().amax(1))
    c = torch.where(scale > 1e-4, scale, torch.ones_like(scale)).reciprocal().clamp(1e-4, 1e4)
    return D, E, c


class _Scaled(NamedTuple):
    """The scaled problems of the working set (B problems)."""

    Q: torch.Tensor    # (B, n, n)
    q: torch.Tensor    # (B, n)
    C: torch.Tensor    # (B, m, n)
    l: torch.Tensor    # (B, m), -inf allowed
    u: torch.Tensor    # (B, m)
    eq: torch.Tensor   # (B, m) bool, l == u
    D: torch.Tensor    # (B, n)
    E: torch.Tensor    # (B, m)
    c: torch.Tensor    # (B,)


def _factor(P: _Scaled, rho: torch.Tensor, sigma: float) -> torch.Tensor:
    """(Q + sigma I + C^T diag(rho) C)^{-1}, (B, n, n), factorised and inverted in float64 (an inaccurate float32
    inverse would blur the infeasibility certificates), returned in the working dtype."""
    n = P.q.shape[1]
    f64 = torch.float64
    C, Q = P.C.to(f64), P.Q.to(f64)
    K = Q + torch.bmm(C.transpose(1, 2) * rho.to(f64).unsqueeze(1), C)
    K = K + sigma * torch.eye(n, dtype=f64, device=K.device)
    L, _ = torch.linalg.cholesky_ex(K)
    return torch.cholesky_inverse(L).to(P.q.dtype)


def _residuals(P: _Scaled, x, z, y, Cx=None, Qx=None):
    """Unscaled OSQP residuals and their reference sizes. Returns (r_p, r_d, size_p, size_d), each (B,).
    Cx, Qx: the products C x and Q x when the caller has them (B, m), (B, n)."""
    Cx = _mv(P.C, x) if Cx is None else Cx
    Qx = _mv(P.Q, x) if Qx is None else Qx
    Cty = _mtv(P.C, y)
    Einv, Dinv, cinv = 1 / P.E, 1 / P.D, (1 / P.c).unsqueeze(-1)
    r_p = _amax((Cx - z) * Einv)
    r_d = _amax((Qx + P.q + Cty) * Dinv * cinv)
    size_p = torch.maximum(_amax(Cx * Einv), _amax(z * Einv))
    size_d = torch.maximum(torch.maximum(_amax(Qx * Dinv), _amax(Cty * Dinv)), _amax(P.q * Dinv)) * cinv.squeeze(-1)
    return r_p, r_d, size_p, size_d


def _complementary(P: _Scaled, x, y, tol: float, s_p, s_d, Cx=None, Qx=None):
    """Complementarity and multiplier signs at (x, y), unscaled, per problem (B,) bool.

    With slacks s_u = u - Cx and s_l = Cx - l (inf where the bound is absent) and the multiplier's size in gradient
    units |y_i| |C_i|_inf: every one-sided or two-sided row must have y_i = 0 within the dual tolerance
    (|y_i| |C_i|_inf <= tol (1 + size_d)) or sit at the bound its sign pushes on within the primal tolerance
    (y_i > 0: s_u <= tol (1 + size_p); y_i < 0: s_l <= tol (1 + size_p)); a wrong-sign multiplier (y_i > 0 on a
    row without upper bound) has infinite slack and fails. And the complementarity gap
    |sum_i y_i^+ s_u,i + y_i^- s_l,i| (the IPM's lam^T (h - G z)) must be below tol (1 + the largest of
    |x^T Q x|, |q^T x|, sum_i |y_i (Cx)_i|, sum_i |y_i b_i|), b_i the bound y_i pushes on. Equality rows
    (l = u) are exempt. The residual tests alone miss a point whose lam and slack are both ~sqrt(mu).
    Cx, Qx: the products C x and Q x when the caller has them."""
    Einv = 1 / P.E
    cinv = (1 / P.c).unsqueeze(-1)
    Cx, u, l = (_mv(P.C, x) if Cx is None else Cx) * Einv, P.u * Einv, P.l * Einv
    yu = y * P.E * cinv
    rown = (P.C.abs() / P.D.unsqueeze(1)).amax(-1) * Einv if P.C.shape[2] else torch.zeros_like(u)
    pos, neg = yu > 0, yu < 0
    inf = torch.full_like(u, float("inf"))
    bound = torch.where(pos, u, torch.where(neg, l, torch.zeros_like(u)))
    slack = torch.where(pos, u - Cx, torch.where(neg, Cx - l, torch.zeros_like(u)))
    slack = torch.where(torch.isfinite(bound), slack, inf)
    eps_p, eps_d = (tol * (1 + s_p)).unsqueeze(-1), (tol * (1 + s_d)).unsqueeze(-1)
    row_ok = P.eq | (slack <= eps_p) | (yu.abs() * rown <= eps_d)
    ay = yu.abs()
    fin = torch.isfinite(slack) & ~P.eq
    gap = torch.where(fin, ay * slack, torch.zeros_like(u)).sum(-1)
    Qx = _mv(P.Q, x) if Qx is None else Qx
    scale = torch.maximum(torch.maximum((x * Qx).sum(-1).abs(), (P.q * x).sum(-1).abs()) * cinv.squeeze(-1),
                          torch.maximum(torch.where(fin, ay * Cx.abs(), torch.zeros_like(u)).sum(-1),
                                        torch.where(fin, ay * bound.abs(), torch.zeros_like(u)).sum(-1)))
    return row_ok.all(-1) & (gap.abs() <= tol * (1 + scale))


def _converged(P: _Scaled, x, z, y, tol: float):
    """The converged test: OSQP's residual test plus :func:`_complementary`, per problem (B,) bool."""
    Cx, Qx = _mv(P.C, x), _mv(P.Q, x)
    r_p, r_d, s_p, s_d = _residuals(P, x, z, y, Cx, Qx)
    return (r_p <= tol * (1 + s_p)) & (r_d <= tol * (1 + s_d)) & _complementary(P, x, y, tol, s_p, s_d, Cx, Qx)


def _active(P: _Scaled, z, y):
    """Active-set guess: (act, lower-active, upper-active), each (B, m) bool."""
    lo = torch.isfinite(P.l) & ((z - P.l) < -y)
    up = (P.u - z) < y
    return P.eq | lo | up, lo, up


def _polish(P: _Scaled, x, y, act, lo, up, s: AdmmSettings):
    """Active-set polish (see the module docstring). Returns (ok (B,), x, z, y) of the polished points."""
    n = x.shape[1]
    d = s.delta
    a = act.to(x.dtype)
    target = torch.where(P.eq | up, P.u, torch.where(lo, P.l, torch.zeros_like(P.u)))
    H = P.Q + torch.bmm(P.C.transpose(1, 2) * (a / d).unsqueeze(1), P.C)
    H = H + d * torch.eye(n, dtype=x.dtype, device=x.device)
    L, info = torch.linalg.cholesky_ex(H)
    yp = y * a
    xp = x
    for _ in range(s.polish_refine):
        r1 = -P.q - _mv(P.Q, xp) - _mtv(P.C, yp)
        r2 = a * (target - _mv(P.C, xp))
        dx = torch.cholesky_solve((r1 + _mtv(P.C, a * r2 / d)).unsqueeze(-1), L).squeeze(-1)
        dy = a * (_mv(P.C, dx) - r2) / d
        xp, yp = xp + dx, yp + dy
    Cx = _mv(P.C, xp)
    zp = torch.minimum(torch.maximum(Cx, P.l), P.u)
    # Multiplier signs: y >= 0 on upper-active rows, <= 0 on lower-active rows (equality rows free), in the
    # dual tolerance; then the same converged test as ADMM's.
    ok = (info == 0) & _converged(P, xp, zp, yp, s.tol)
    ok &= torch.isfinite(xp).all(-1) & torch.isfinite(yp).all(-1)
    return ok, xp, zp, yp


def _polish_corrected(P: _Scaled, x, y, act, lo, up, s: AdmmSettings, rounds: int):
    """:func:`_polish` with up to ``rounds - 1`` active-set corrections, for guesses from an interior point (whose
    degenerate rows have lam and slack both ~sqrt(mu), so lam > slack is a coin flip there): after a polish that
    fails, upper-active rows with y < 0 (lower-active with y > 0) leave the active set and inactive rows that the
    polished point violates join it (a primal-dual active-set step), then the polish is repeated on those
    problems only. The first polished point that passes :func:`_converged` is kept. One host sync per round.
    Returns (ok (B,), x, z, y)."""
    ok, bx, bz, by = _polish(P, x, y, act, lo, up, s)
    j = torch.arange(x.shape[0], device=x.device)
    okj, xp, yp = ok, bx, by
    for _ in range(rounds - 1):
        k = (~okj).nonzero().squeeze(-1)                         # host sync: once per round
        if k.numel() == 0:
            break
        j, Pk = j.index_select(0, k), _Scaled(*(t.index_select(0, k) for t in P))
        xp, yp, act, lo, up = (t.index_select(0, k) for t in (xp, yp, act, lo, up))
        Cx = _mv(Pk.C, xp)
        one = ~Pk.eq
        wrong_up, wrong_lo = up & one & (yp < 0), lo & one & (yp > 0)
        up = (up & ~wrong_up) | (~act & (Cx > Pk.u))
        lo = (lo & ~wrong_lo) | (~act & (Cx < Pk.l))
        act = Pk.eq | up | lo
        xs = torch.where(torch.isfinite(xp), xp, x.index_select(0, j))
        ys = torch.where(torch.isfinite(yp), yp, y.index_select(0, j))
        okj, xp, zp, yp = _polish(Pk, xs, ys, act, lo, up, s)
        ok = ok.index_copy(0, j, okj)
        m = okj.unsqueeze(-1)
        bx = bx.index_copy(0, j, torch.where(m, xp, bx.index_select(0, j)))
        bz = bz.index_copy(0, j, torch.where(m, zp, bz.index_select(0, j)))
        by = by.index_copy(0, j, torch.where(m, yp, by.index_select(0, j)))
    return ok, bx, bz, by


def _primal_infeasible(P: _Scaled, dy: torch.Tensor, eps: float):
    """OSQP's primal infeasibility test on dy (B, m) (projected onto the admissible signs). Returns (ok, dy)."""
    dy = torch.where(torch.isfinite(P.l), dy, dy.clamp_min(0))
    dy = torch.where(torch.isfinite(P.u), dy, dy.clamp_max(0))
    norm = _amax(dy)
    Ctdy = _amax(_mtv(P.C, dy))
    zero = torch.zeros_like(dy)
    supp = (torch.where(dy > 0, P.u, zero) * dy.clamp_min(0)).sum(-1) \
        + (torch.where(dy < 0, P.l, zero) * dy.clamp_max(0)).sum(-1)
    ok = (norm > 0) & (Ctdy <= eps * norm) & (supp <= -eps * norm)
    return ok, dy


def _unbounded(P: _Scaled, dx: torch.Tensor, eps: float):
    """OSQP's dual infeasibility (unboundedness) test on dx (B, n). Returns (B,) bool."""
    norm = _amax(dx)
    Cdx = _mv(P.C, dx)
    tol = (eps * norm).unsqueeze(-1)
    in_rec = torch.where(torch.isfinite(P.u), Cdx <= tol, torch.ones_like(Cdx, dtype=torch.bool)) \
        & torch.where(torch.isfinite(P.l), Cdx >= -tol, torch.ones_like(Cdx, dtype=torch.bool))
    return (norm > 0) & (_amax(_mv(P.Q, dx)) <= eps * norm) & ((P.q * dx).sum(-1) <= -eps * norm) & in_rec.all(-1)


# long function: one ADMM loop whose iterate, duals, penalty updates, infeasibility certificates and the shrinking
# set of unfinished problems share state across every iteration; split, each stage would pass it all back
def admm(Q, q, C, l, u, x0, y0, s: AdmmSettings) -> AdmmOutput:
    """Solve the B problems (see the module docstring) from the unscaled warm start (x0 (B, n), y0 (B, m))."""
    B, n = q.shape
    m = C.shape[1]
    dtype, device = q.dtype, q.device
    D, E, c = ruiz(Q, q, C, s.ruiz_iters)
    cu = c.unsqueeze(-1)
    P = _Scaled(Q=Q * D.unsqueeze(2) * D.unsqueeze(1) * c.view(B, 1, 1), q=q * D * cu,
                C=C * E.unsqueeze(2) * D.unsqueeze(1), l=l * E, u=u * E, eq=(l == u), D=D, E=E, c=c)
    x = x0 / D
    y = y0 * cu / E
    z = torch.minimum(torch.maximum(_mv(P.C, x), P.l), P.u)
    rho_base = torch.full((B, 1), s.rho, dtype=dtype, device=device)
    rho_row = lambda rb, eq: torch.where(eq, 1e3 * rb, rb)  # noqa: E731
    rho = rho_row(rho_base, P.eq)
    Kinv = _factor(P, rho, s.sigma)

    x_out, y_out = x0.clone(), y0.clone()
    status_out = torch.full((B,), _MAX_ITERATIONS, dtype=torch.int8, device=device)
    iters_out = torch.full((B,), s.max_iters, dtype=torch.int32, device=device)
    idx = torch.arange(B, device=device)
    last_act = torch.zeros(B, m, dtype=torch.bool, device=device)
    tried = torch.zeros(B, dtype=torch.bool, device=device)
    alpha = s.alpha
    it = 0
    while idx.numel() > 0 and it < s.max_iters:
        steps = min(s.check_every, s.max_iters - it)
        # Column-vector state (B, k, 1) and fused ops: the iteration is about a dozen kernel launches.
        Ct, Cm, ql, ll, ul = P.C.transpose(1, 2).contiguous(), P.C, (-P.q).unsqueeze(-1), P.l.unsqueeze(-1), \
            P.u.unsqueeze(-1)
        r3, ir3 = rho.unsqueeze(-1), (1 / rho).unsqueeze(-1)
        xc, zc, yc = x.unsqueeze(-1), z.unsqueeze(-1), y.unsqueeze(-1)
        x_start, y_start = x, y
        for k in range(steps):
            if k == steps - 1:
                x_old, y_old = xc.squeeze(-1), yc.squeeze(-1)
            rhs = torch.baddbmm(torch.add(ql, xc, alpha=s.sigma), Ct, torch.addcmul(-yc, r3, zc))
            xt = torch.bmm(Kinv, rhs)
            zr = torch.lerp(zc, torch.bmm(Cm, xt), alpha)
            xc = torch.lerp(xc, xt, alpha)
            z_new = torch.clamp(torch.addcmul(zr, yc, ir3), min=ll, max=ul)
            yc = torch.addcmul(yc, r3, zr - z_new)
            zc = z_new
        x, z, y = xc.squeeze(-1), zc.squeeze(-1), yc.squeeze(-1)
        it += steps
        conv = _converged(P, x, z, y, s.tol)
        xf, yf = x, y
        if s.polish:
            # Polish the open problems whose active-set guess changed since their last attempt.
            act, lo, up = _active(P, z, y)
            fresh = (~tried | (act != last_act).any(-1)) & ~conv
            if bool(fresh.any()):                              # host sync: once per check
                j = fresh.nonzero().squeeze(-1)
                Pj = _Scaled(*(t.index_select(0, j).to(torch.float64) if t.is_floating_point() else
                               t.index_select(0, j) for t in P))           # the polish runs in float64
                ok, xp, _, yp = _polish(Pj, x.index_select(0, j).double(), y.index_select(0, j).double(),
                                        act.index_select(0, j), lo.index_select(0, j), up.index_select(0, j), s)
                xp, yp = xp.to(dtype), yp.to(dtype)
                okf = torch.zeros_like(conv).index_copy(0, j, ok)
                xf = x.index_copy(0, j, torch.where(ok.unsqueeze(-1), xp, x.index_select(0, j)))
                yf = y.index_copy(0, j, torch.where(ok.unsqueeze(-1), yp, y.index_select(0, j)))
                conv = conv | okf
                last_act = torch.where(fresh.unsqueeze(-1), act, last_act)
                tried = tried | fresh
        # Certificate candidates: the last increment and the mean increment over the check interval (less
        # rounding noise once y has grown large).
        if bool(conv.all()):                                   # host sync: once per check; no certificate needed
            pinf, unb, cert = torch.zeros_like(conv), torch.zeros_like(conv), y
        else:
            pinf1, cert1 = _primal_infeasible(P, y - y_old, s.eps_inf)
            pinf2, cert2 = _primal_infeasible(P, y - y_start, s.eps_inf)
            pinf = (pinf1 | pinf2) & ~conv
            cert = torch.where(pinf1.unsqueeze(-1), cert1, cert2)
            unb = (_unbounded(P, x - x_old, s.eps_inf) | _unbounded(P, x - x_start, s.eps_inf)) & ~conv & ~pinf
        done = conv | pinf | unb
        st = torch.where(conv, _CONVERGED, torch.where(pinf, _INFEASIBLE, torch.where(unb, _UNBOUNDED,
                                                                                   _MAX_ITERATIONS)))
        # Unscaled outputs of every problem of the working set (the open ones are overwritten later).
        cert_u = cert * P.E
        cert_u = cert_u / _amax(cert_u).clamp_min(torch.finfo(dtype).tiny).unsqueeze(-1)
        x_out = x_out.index_copy(0, idx, xf * P.D)
        y_out = y_out.index_copy(0, idx, torch.where(pinf.unsqueeze(-1), cert_u, yf * P.E / cu))
        status_out = status_out.index_copy(0, idx, st.to(torch.int8))
        iters_out = iters_out.index_copy(0, idx, torch.full_like(idx, it, dtype=torch.int32))
        keep = ~done
        if bool(keep.all()):                                   # host sync: once per check
            pass
        else:
            j = keep.nonzero().squeeze(-1)
            idx = idx.index_select(0, j)
            P = _Scaled(*(t.index_select(0, j) for t in P))
            x, y, z = x.index_select(0, j), y.index_select(0, j), z.index_select(0, j)
            last_act, tried = last_act.index_select(0, j), tried.index_select(0, j)
            rho, rho_base, Kinv = rho.index_select(0, j), rho_base.index_select(0, j), Kinv.index_select(0, j)
            cu = P.c.unsqueeze(-1)
        if idx.numel() == 0 or it >= s.max_iters:
            break
        # Residual balancing of rho (OSQP Sec. 5.2), refactorising only the problems whose rho moved enough.
        r_p, r_d, s_p, s_d = _residuals(P, x, z, y)
        tiny = torch.finfo(dtype).tiny
        # Relative to 1 + size, as the converged test: a pure feasibility problem (Q = 0, q = 0) has
        # r_d = |C^T y| = size_d, and OSQP's plain ratio would then shrink rho while the primal residual stalls.
        ratio = (r_p / (1 + s_p)) / (r_d / (1 + s_d)).clamp_min(tiny)
        new = (rho_base.squeeze(-1) * ratio.clamp_min(tiny).sqrt()).clamp(1e-6, 1e6)
        new = torch.where(torch.isfinite(new), new, rho_base.squeeze(-1))
        change = (new > s.adapt_factor * rho_base.squeeze(-1)) | (new < rho_base.squeeze(-1) / s.adapt_factor)
        if bool(change.any()):                                 # host sync: once per check
            j = change.nonzero().squeeze(-1)
            rho_base = rho_base.index_copy(0, j, new.index_select(0, j).unsqueeze(-1))
            rho = rho_row(rho_base, P.eq)
            Pj = _Scaled(*(t.index_select(0, j) for t in P))
            Kinv = Kinv.index_copy(0, j, _factor(Pj, rho.index_select(0, j), s.sigma))
    return AdmmOutput(x=x_out, y=y_out, status=status_out, iterations=iters_out)
