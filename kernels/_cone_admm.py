"""Batched ADMM (Douglas-Rachford) with exact second-order-cone projections for the friction-cone problem.

Private core of :mod:`.friction_cone`. It works on the normalised problem built there: for every problem of the
batch

    minimise  c^T x   subject to  A x = b,  x_i in C_i = {(a, t) : ||t|| <= mu_i a}   (i = 1..K)

with ``x`` the contact forces in each contact's local frame (e0, t1, t2), stored component-major
(``x = [a_1..a_K, t1_1..t1_K, t2_1..t2_K]``, n = 3K), ``A`` (B, m, n) the row-scaled wrench map (m = 6 for a
rigid body; the core takes any m), ``||b|| = 1`` (or 0). ``mu_i = 0`` is the ray of a sliding contact; inactive
contacts have zero columns and stay at 0. The dual is the m-variable problem

    maximise  b^T y   subject to  c_i - A_i^T y in C_i* = {(s_n, s_t) : s_n >= mu_i ||s_t||}.

Iteration (OSQP-style splitting x = z, written on the governing sequence w = z + u): z = Pi_C(w),
x = Pi_{Ax=b}(2z - w - c/rho), w <- w + alpha (x - z). The affine projection is a precomputed (n, n) projector P
plus an offset; it does not depend on rho, so rho adapts (OSQP's residual balancing) without refactoring.
Every ``check_every`` iterations (the only host syncs) each problem is tested, with masks:

* converged: ||A z - b|| <= eps max(1, ||z||) and c^T z - b^T (theta y) <= eps (1 + |c^T z|), y the dual estimate
  and theta in [0, 1] scales it into the dual-feasible set, so the gap bounds the objective error (weak duality);
* infeasible: a direction d in R^m with b^T d > 0 and h_i(d) = g_n + mu_i ||g_t|| <= eps_cert b^T d for
  g = A_i^T d (from the dual growth, the dual itself, or the primal residual), which proves that every solution
  needs a total normal force of at least 1 / eps_cert (normalised units; h <= 0 proves plain infeasibility);
* polished: where the pattern of projection pieces (inside / boundary / polar per contact, read off w) has been
  stable for a check interval and the residual is small, safeguarded semismooth-Newton steps on the fixed-point
  residual (:mod:`._cone_polish`) move w; where a certificate candidate is close, Newton steps on the
  nearest-point map produce a sharper certificate. Both results pass the same tests before they count. After
  ``tail_from`` iterations every open problem gets Newton steps at every check (Newton-accelerated ADMM).

Finished problems leave the working set (compaction at the checks), and the check interval grows with the
iteration count, so the late iterations cost only the few stragglers.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from ._cone_polish import newton_fixed_point, newton_nearest_point
from ._cone_proj import project_cone
from ._rows import at_least_two
from .graphs import replayed
from .status import SolverStatus

_CONVERGED = int(SolverStatus.CONVERGED)
_INFEASIBLE = int(SolverStatus.INFEASIBLE)
_MAX_ITERATIONS = int(SolverStatus.MAX_ITERATIONS)


class NormalisedProblem(NamedTuple):
    """The scaled problem (B problems of the working set, K contacts, n = 3K, component-major variables).

    A: (B, m, n) wrench map; P: (B, n, n) projector onto null(A) (zero rows/columns for inactive contacts);
    M: (B, n, m) = A^T (A A^T)^+; Gp: (B, m, m) = (A A^T)^+; b: (B, m); c: (B, n) objective; cn: (B, K) its
    normal part (the dual's right-hand side); mu: (B, K) cone slopes (0 = ray); active: (B, K) bool.
    """

    A: torch.Tensor
    P: torch.Tensor
    M: torch.Tensor
    Gp: torch.Tensor
    b: torch.Tensor
    c: torch.Tensor
    cn: torch.Tensor
    mu: torch.Tensor
    active: torch.Tensor


class AdmmSettings(NamedTuple):
    eps: float                  # primal residual and relative gap tolerance (normalised units)
    eps_cert: float             # infeasibility certificate tolerance
    max_iters: int
    check_every: int
    alpha: float = 1.6          # over-relaxation
    rho: float = 1.0            # initial penalty (normalised units)
    adapt_factor: float = 3.0   # rho changes when the residual balance is off by more than this factor
    polish: bool = True
    polish_from: int = 20       # first iteration at which polishing is tried
    polish_retry: int = 50      # iterations before a failed polish is retried with the same pattern
    polish_steps: int = 4       # Newton steps per polish
    tail_from: int = 200        # from here on every check polishes every open problem (Newton-accelerated ADMM)
    tail_steps: int = 4         # Newton steps per check in the tail
    cert_polish: float = 0.1    # a certificate margin below this triggers the distance polish
    polish_below: float = 0.1   # optimality polish only once the primal residual is below this


class AdmmOutput(NamedTuple):
    z: torch.Tensor             # (B, n) cone-feasible iterate (normalised, component-major)
    status: torch.Tensor        # (B,) int8
    iterations: torch.Tensor    # (B,) int32


def regions(w: torch.Tensor, mu: torch.Tensor) -> torch.Tensor:
    """Which piece of the cone projection each contact's w_i is in: 0 polar cone, 1 boundary, 2 inside. (B, K)."""
    K = mu.shape[-1]
    a = w[:, :K]
    r = torch.hypot(w[:, K:2 * K], w[:, 2 * K:])
    return torch.where(r <= mu * a, 2, torch.where(a + mu * r <= 0, 0, 1))


def cone_support(g: torch.Tensor, mu: torch.Tensor, active: torch.Tensor) -> torch.Tensor:
    """h_i(g) = g_n + mu_i ||g_t|| (the largest x . g over members of C_i with unit normal part); -inf if inactive.

    g: (B, 3K) component-major. Returns (B, K).
    """
    K = mu.shape[-1]
    h = torch.addcmul(g[:, :K], mu, torch.hypot(g[:, K:2 * K], g[:, 2 * K:]))
    return torch.where(active, h, torch.full_like(h, -torch.inf))


def _At(A: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    return torch.bmm(A.transpose(1, 2), d.unsqueeze(-1)).squeeze(-1)


def certificate_margin(d: torch.Tensor, prob: NormalisedProblem) -> torch.Tensor:
    """max_i h_i(A_i^T d) / (b^T d) for candidate directions d (B, m); +inf unless b^T d > 0. Returns (B,).

    A value <= eps_cert proves that any solution needs sum_i a_i >= 1/eps_cert; a value <= 0 proves infeasibility.
    """
    h = cone_support(_At(prob.A, d), prob.mu, prob.active).amax(-1).clamp_min(0)
    bd = (prob.b * d).sum(-1)
    guard = 100 * torch.finfo(d.dtype).eps
    ok = bd > guard * torch.linalg.vector_norm(d, dim=-1) * torch.linalg.vector_norm(prob.b, dim=-1)
    return torch.where(ok, h / bd.clamp_min(torch.finfo(d.dtype).tiny), torch.full_like(bd, torch.inf))


def dual_lower_bound(y: torch.Tensor, prob: NormalisedProblem) -> torch.Tensor:
    """b^T (theta y) with the largest theta in [0, 1] keeping c - A^T (theta y) dual feasible: a certified lower
    bound on the optimal objective (weak duality). y: (B, m). Returns (B,)."""
    h = cone_support(_At(prob.A, y), prob.mu, prob.active)
    theta_i = torch.where(h > 0, prob.cn / h.clamp_min(torch.finfo(y.dtype).tiny), torch.full_like(h, torch.inf))
    return theta_i.amin(-1).clamp(0, 1) * (prob.b * y).sum(-1)


_EIGH_CHUNK = 16384


def _batched_eigh(G: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """torch.linalg.eigh of (B, m, m) in chunks of at most ``_EIGH_CHUNK`` problems on CUDA: cuSOLVER's batched
    eigensolver fails (an internal error at B = 65536, an out-of-memory workspace request beyond) on large batches
    of small matrices."""
    if G.device.type != "cuda" or G.shape[0] <= _EIGH_CHUNK:
        return torch.linalg.eigh(G)
    parts = [torch.linalg.eigh(g) for g in G.split(_EIGH_CHUNK)]
    return torch.cat([e for e, _ in parts]), torch.cat([v for _, v in parts])


def build_problem(A: torch.Tensor, b: torch.Tensor, c: torch.Tensor, mu: torch.Tensor, active: torch.Tensor,
                  rank_tol: float, eps_cert: float) -> tuple[NormalisedProblem, torch.Tensor]:
    """The :class:`NormalisedProblem` of (A (B, m, 3K), b (B, m), c (B, 3K), mu, active (B, K)), all already scaled
    and component-major, plus a (B,) bool flag of problems whose b leaves the range of A (infeasible, certified
    by the out-of-range part of b). (A A^T)^+ drops eigenvalues below rank_tol times the largest."""
    B, m, n = A.shape
    # The small factorisation is done in float64 whatever the working dtype: a float32 eigh would blur the
    # rank decision of nearly degenerate grasps.
    A64, b64 = A.double(), b.double()
    evals, evecs = _batched_eigh(A64 @ A64.transpose(1, 2))
    keep = evals > rank_tol * evals[:, -1:].clamp_min(torch.finfo(torch.float64).tiny)
    inv = torch.where(keep, 1.0 / torch.where(keep, evals, torch.ones_like(evals)), 0.0)
    Gp = (evecs * inv[:, None, :]) @ evecs.transpose(1, 2)
    M = A64.transpose(1, 2) @ Gp
    var = active.repeat(1, 3).double()
    P = (torch.eye(n, dtype=torch.float64, device=A.device) - M @ A64) * var[:, :, None] * var[:, None, :]
    b_perp = b64 - ((evecs * keep.double()[:, None, :]) @ (evecs.transpose(1, 2) @ b64[..., None])).squeeze(-1)
    K = n // 3
    prob = NormalisedProblem(A=A, P=P.to(A.dtype), M=M.to(A.dtype), Gp=Gp.to(A.dtype), b=b, c=c, cn=c[:, :K], mu=mu,
                             active=active)
    prob64 = NormalisedProblem(A64, P, M, Gp, b64, c.double(), c[:, :K].double(), mu.double(), active)
    return prob, certificate_margin(b_perp, prob64) <= eps_cert


def _offset(p: NormalisedProblem, rho: torch.Tensor) -> torch.Tensor:
    """Affine offset of the x-step, M b - P c / rho, (B, n)."""
    return torch.baddbmm(torch.bmm(p.M, p.b.unsqueeze(-1)), p.P, (p.c / rho).unsqueeze(-1), alpha=-1).squeeze(-1)


def _step(w, p: NormalisedProblem, q, alpha: float, inv=None):
    """One iteration: z = Pi_C(w), x = P (2z - w) + q, w + alpha (x - z). Returns the new w, z and x."""
    z = project_cone(w, p.mu, inv)
    x = torch.baddbmm(q.unsqueeze(-1), p.P, (2 * z - w).unsqueeze(-1)).squeeze(-1)
    return torch.add(w, x - z, alpha=alpha), z, x


def _fast_step(w, mu, inv, A, M, aq, alpha: float):
    """The same update without forming x, using P = I - M A (rank n - m):
    w <- (1 - alpha) w + alpha z - alpha M A (2z - w) + alpha q with z = Pi_C(w); aq = alpha q, (B, n, 1)."""
    z = project_cone(w, mu, inv)
    v = torch.add(-w, z, alpha=2)
    r = torch.baddbmm(aq, M, torch.bmm(A, v.unsqueeze(-1)), alpha=-alpha).squeeze(-1)
    return r.add_(w, alpha=1 - alpha).add_(z, alpha=alpha)


def _fast_steps(steps: int, alpha: float, w, q, inv, *prob):
    """``steps`` of :func:`_fast_step` from w (B, n), then one :func:`_step` (offset q (B, n); ``prob``: the fields
    of a :class:`NormalisedProblem`). Returns the last step's (w, z, x)."""
    p = NormalisedProblem(*prob)
    aq = (alpha * q).unsqueeze(-1)
    for _ in range(steps):
        w = _fast_step(w, p.mu, inv, p.A, p.M, aq, alpha)
    return _step(w, p, q, alpha, inv)


def _optimality(z, y, p: NormalisedProblem, eps: float):
    """Certified convergence test of a cone-feasible z and a dual estimate y: ||A z - b|| <= eps max(1, ||z||)
    (||b|| = 1) and a weak-duality gap <= eps (1 + |c^T z|). Returns (ok (B,), residual vector (B, m))."""
    r_vec = p.b - torch.bmm(p.A, z.unsqueeze(-1)).squeeze(-1)
    obj = (p.c * z).sum(-1)
    gap = obj - dual_lower_bound(y, p)
    size = torch.linalg.vector_norm(z, dim=-1).clamp_min(1)
    ok = (torch.linalg.vector_norm(r_vec, dim=-1) <= eps * size) & (gap <= eps * (1 + obj.abs()))
    return ok, r_vec


def _check_values(eps: float, eps_cert: float, w, rho, y_prev, *prob):
    """The quantities of a check (no host sync): z = Pi_C(w) and u = w - z (B, n), the dual estimate y (B, m),
    converged (B,), the residual vector (B, m), the certificate margin (B,), infeasible (B,) and the projection
    regions (B, K) of w; ``prob``: the fields of a :class:`NormalisedProblem`."""
    p = NormalisedProblem(*prob)
    z = project_cone(w, p.mu)
    u = w - z
    # Dual estimate: the slack s = c - A^T y is -rho u (u lies in the polar cone), so A^T y = c + rho u.
    y = torch.bmm(p.M.transpose(1, 2), (p.c + rho * u).unsqueeze(-1)).squeeze(-1)
    converged, r_vec = _optimality(z, y, p, eps)
    cert = torch.minimum(certificate_margin(y - y_prev, p), certificate_margin(y, p))
    cert = torch.minimum(cert, certificate_margin(torch.bmm(p.Gp, r_vec.unsqueeze(-1)).squeeze(-1), p))
    infeasible = ~converged & (cert <= eps_cert)
    return z, u, y, converged, r_vec, cert, infeasible, regions(w, p.mu)


class _Work(NamedTuple):
    """Per-problem iteration state of the working set."""

    w: torch.Tensor            # (B, n) governing sequence
    rho: torch.Tensor          # (B, 1)
    q: torch.Tensor            # (B, n) affine offset
    y_prev: torch.Tensor       # (B, 6) dual estimate at the previous check
    kind_prev: torch.Tensor    # (B, K) active-set guess at the previous check
    polish_kind: torch.Tensor  # (B, K) active set of the last polish attempt
    polish_it: torch.Tensor    # (B,) iteration of the last optimality polish
    dist_it: torch.Tensor      # (B,) iteration of the last distance (certificate) polish


# long function: one ADMM loop whose iterate, penalty, active-set memory, per-problem freezing and convergence
# checks share the working set that shrinks as problems finish; split, every stage would pass it all back
def admm(prob: NormalisedProblem, w0: torch.Tensor, settings: AdmmSettings,
         decided: torch.Tensor | None = None, check_first: bool = False) -> AdmmOutput:
    """Run the batched solver from the governing points w0 (B, n) on every problem of ``prob`` not ``decided``
    (B,) bool already (those keep status MAX_ITERATIONS and 0 iterations here; the caller sets their status).
    ``check_first`` tests (and polishes) w0 before the first iteration, for warm starts."""
    B, n = w0.shape
    K = n // 3
    dtype, device = w0.dtype, w0.device
    z_out = project_cone(w0, prob.mu)
    status_out = torch.full((B,), _MAX_ITERATIONS, dtype=torch.int8, device=device)
    iters_out = torch.full((B,), settings.max_iters, dtype=torch.int32, device=device)
    small = torch.tensor(1e-6, dtype=dtype, device=device)

    idx = torch.arange(B, device=device)
    if decided is not None:
        iters_out = torch.where(decided, 0, iters_out)
        idx = at_least_two((~decided).nonzero().squeeze(-1))              # host sync (a check at iteration 0)
        prob, w0 = NormalisedProblem(*(t.index_select(0, idx) for t in prob)), w0.index_select(0, idx)
        B = idx.numel()
    p = prob
    rho = torch.full((B, 1), settings.rho, dtype=dtype, device=device)
    no_kind = torch.full((B, K), -1, dtype=torch.long, device=device)
    never = torch.full((B,), -(10 ** 9), dtype=torch.long, device=device)
    st = _Work(w0, rho, _offset(p, rho), w0.new_zeros(B, p.A.shape[1]), no_kind, no_kind, never, never)
    alpha = settings.alpha
    inv = 1 / (1 + p.mu * p.mu)
    it = 0
    iterate = not check_first
    while idx.numel() > 0:
        w, rho, q = st.w, st.rho, st.q
        if iterate:
            if it >= settings.max_iters:
                break
            # Checks every check_every iterations, then every ~20% of the iterations done (stragglers are few).
            interval = max(settings.check_every, (it // (5 * settings.check_every)) * settings.check_every)
            steps = min(interval, settings.max_iters - it)
            # the steps between two checks: one graph replay on CUDA (.graphs)
            w, z_prev, x = replayed(("cone", steps - 1, alpha), lambda *t: _fast_steps(steps - 1, alpha, *t),
                                    w, q, inv, *p, rows=w.shape[0])
            it += steps
        iterate = True

        # --- check (the only host syncs): convergence, infeasibility, polishing, rho, compaction -------------
        z, u, y, converged, r_vec, cert, infeasible, kind = replayed(
            ("cone check", settings.eps, settings.eps_cert),
            lambda *t: _check_values(settings.eps, settings.eps_cert, *t), w, rho, st.y_prev, *p, rows=w.shape[0])
        polish_kind, polish_it, dist_it = st.polish_kind, st.polish_it, st.dist_it
        if settings.polish and (it >= settings.polish_from or it == 0):
            # Newton polish of the fixed point where the region pattern has been stable for a check interval;
            # Newton on the nearest-point map (an infeasibility certificate) where a certificate is close.
            open_ = ~converged & ~infeasible
            fresh = (kind != polish_kind).any(-1) | (it - polish_it >= max(settings.polish_retry, it // 2))
            ready = torch.linalg.vector_norm(r_vec, dim=-1) < settings.polish_below
            tail = it >= settings.tail_from
            stable = (kind == st.kind_prev).all(-1) | (it == 0)
            sel = at_least_two((open_ & (tail | (fresh & ready & stable))).nonzero().squeeze(-1))  # host sync
            if sel.numel():
                ps = NormalisedProblem(*(t.index_select(0, sel) for t in p))
                rs = rho[sel]
                wp = newton_fixed_point(w[sel].double(), ps.P.double(), q[sel].double(), ps.mu.double(), ps.active,
                                        settings.tail_steps if tail else settings.polish_steps,
                                        backtrack=3 if tail else 0).to(dtype)
                zp = project_cone(wp, ps.mu)
                yp = torch.bmm(ps.M.transpose(1, 2), (ps.c + rs * (wp - zp)).unsqueeze(-1)).squeeze(-1)
                ok, _ = _optimality(zp, yp, ps, settings.eps)
                # The safeguarded Newton never increases ||F||: its point also becomes the ADMM's new iterate.
                z = z.index_copy(0, sel, zp)
                u = u.index_copy(0, sel, wp - zp)
                converged = converged.index_copy(0, sel, ok)
                polish_kind = polish_kind.index_copy(0, sel, kind[sel])
                polish_it = polish_it.index_copy(0, sel, torch.full_like(sel, it))
            sel = (open_ & ~converged & (tail | ((cert < settings.cert_polish)
                   & (it - dist_it >= max(settings.polish_retry, it // 2))))
                   ).nonzero().squeeze(-1)
            sel = at_least_two(sel)
            if sel.numel():
                ps = NormalisedProblem(*(t.index_select(0, sel) for t in p))
                q0 = torch.bmm(ps.M, ps.b.unsqueeze(-1)).squeeze(-1)
                zd = newton_nearest_point(z[sel].double(), ps.P.double(), q0.double(), ps.mu.double(),
                                          settings.tail_steps if tail else settings.polish_steps).to(dtype)
                d = torch.bmm(ps.Gp, (ps.b - torch.bmm(ps.A, zd.unsqueeze(-1)).squeeze(-1)).unsqueeze(-1)).squeeze(-1)
                bad = certificate_margin(d, ps) <= settings.eps_cert
                infeasible = infeasible.index_copy(0, sel, bad | infeasible[sel])
                dist_it = dist_it.index_copy(0, sel, torch.full_like(sel, it))
        done = converged | infeasible

        # rho adaptation (OSQP): balance the consensus residual against the dual residual.
        new_rho = rho
        if it > 0:
            rp = torch.linalg.vector_norm(x - z_prev, dim=-1) / torch.maximum(
                torch.maximum(torch.linalg.vector_norm(x, dim=-1), torch.linalg.vector_norm(z_prev, dim=-1)), small)
            rd = torch.linalg.vector_norm(z - z_prev, dim=-1) / torch.maximum(
                torch.linalg.vector_norm(u, dim=-1), torch.linalg.vector_norm(p.c, dim=-1) / rho.squeeze(-1))
            ratio = (rp / rd.clamp_min(1e-12)).sqrt().clamp(1e-3, 1e3).unsqueeze(-1)
            change = (ratio > settings.adapt_factor) | (ratio < 1 / settings.adapt_factor)
            new_rho = torch.where(change, (rho * ratio).clamp(1e-4, 1e4), rho)
        st = _Work(z + u * (rho / new_rho), new_rho, _offset(p, new_rho), y, kind, polish_kind, polish_it, dist_it)

        n_done = int(done.sum())  # host sync
        if n_done:
            gidx = idx[done]
            z_out[gidx] = z[done]
            status_out[gidx] = torch.where(converged[done], _CONVERGED, _INFEASIBLE).to(torch.int8)
            iters_out[gidx] = it
            keep = at_least_two((~done).nonzero().squeeze(-1))
            idx = idx.index_select(0, keep)
            p = NormalisedProblem(*(t.index_select(0, keep) for t in p))
            st = _Work(*(t.index_select(0, keep) for t in st))
            inv = inv.index_select(0, keep)
    if idx.numel():
        z_out[idx] = project_cone(st.w, p.mu)
    return AdmmOutput(z_out, status_out, iters_out)
