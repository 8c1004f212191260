"""The Kry & Pai (2006) quasi-static contact LCP (§7.1.1-7.1.3) and its projected Gauss-Seidel solver.

Per contact i (N contacts, m pyramid direction pairs, K = 2m + 1 directions), in the paper's symbols:

    D_i = (d_i0, d_i1, ..., d_i(2m))   d_i0 the outward unit normal (the direction of the force the object exerts
                                       on the hand), d_ij unit tangents in pairs d_i(2j-1) = -d_i(2j)
    f_i = D_i beta_i,  beta_i >= 0     contact force on the hand (beta_i0 = normal force), newtons
    E_i = (0, -1, ..., -1),  F_i = (mu_i, -1, ..., -1)     (friction pyramid: sigma_i = F_i beta_i >= 0)
    nu_i = D_i^T du_i - E_i^T lambda_i + s_i  (separation nu_i0 and the maximal-dissipation multipliers)

With du = G df + J dtheta_r - (U_phi f^{k+1} + u_phi) (Eq. 10) the system is the LCP (§7.1.3)

    ( D^T (G - U_phi) D   -E^T ) (beta  )   ( s' )   ( nu    )      ( beta   )
    (        F             0   ) (lambda) + ( 0  ) = ( sigma )  _|_ ( lambda ),
    s' = s + D^T (J dtheta_r - G f^k - u_phi),  s_i = (s_i0, 0, ..., 0),

in z = (beta_1, ..., beta_N, lambda_1, ..., lambda_N), n = N K + N unknowns. :func:`build_kry_pai_lcp` assembles
this explicit (M, q); :func:`solve_contact_lcp` solves it. Plain PGS cannot: the lambda block has a zero diagonal.
Instead, per contact and sweep:

1. normal update  beta_i0 <- max(0, beta_i0 - nu_i0 / A_i00)  (A = D^T (G - U_phi) D);
2. tangential part: with beta_i0 fixed, (beta_i*, lambda_i) is exactly the KKT system of
   min 1/2 b^T A_i** b + c^T b over the friction pyramid {b >= 0, sum b <= mu_i beta_i0}; it is solved exactly by
   enumerating its candidate optima (each supported on at most two directions, since the tangential forces span a
   plane: the pyramid vertices, the edges between direction pairs and the 2-direction interior stationary points);
3. lambda_i = max(0, max_j -(A beta + s')_ij), j >= 1, recovered from maximal dissipation: the largest sliding
   displacement against a pyramid direction (0 when sticking).

A fixed point of these updates is a solution of the explicit LCP. Convergence is checked every ``check_every``
sweeps on the residual ||min(z, M z + q)||_inf of the explicit LCP. Units: metres (s, nu, lambda), newtons (beta),
metres per newton (G, U_phi). The project's usual contact normals point INTO the object: d_i0 = -normal.

The LCP's inputs: :func:`effective_compliance` (G = J C J^T, Eq. 5) and :func:`rigid_body_terms` (U_phi, u_phi of
a free body, §7.1.2), with :func:`integrate_object` for the body's update; their spatial algebra (twists (omega, v),
wrenches (tau, f), the paper's order) is :mod:`.spatial`'s.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch

from ._contact_checks import _check, _err
from .contact_body import RigidBodyStep, effective_compliance, integrate_object, rigid_body_terms
from .frames import tangent_frame

from .lcp import lcp_residual, lcp_tolerances
from .status import SolverStatus

__all__ = ["KryPaiLCP", "ContactLCPResult", "RigidBodyStep", "friction_pyramid", "kry_pai_s_prime",
           "build_kry_pai_lcp", "solve_contact_lcp", "effective_compliance", "rigid_body_terms", "integrate_object"]


class KryPaiLCP(NamedTuple):
    """The explicit Kry & Pai LCP of B problems with N contact slots and K = 2m + 1 directions each.

    M:    LCP matrix ((D^T (G - U_phi) D, -E^T), (F, 0)), (B, N K + N, N K + N); padded contacts have identity
          rows and columns
    q:    (s', 0), (B, N K + N), metres
    D:    direction matrices D_i, (B, N, 3, K), unit vectors (column 0 the outward normal d_i0)
    mu:   friction coefficients, (B, N)
    mask: active contacts, (B, N) bool
    """

    M: torch.Tensor
    q: torch.Tensor
    D: torch.Tensor
    mu: torch.Tensor
    mask: torch.Tensor


class ContactLCPResult(NamedTuple):
    """Result of :func:`solve_contact_lcp`.

    beta:       (B, N, K), newtons: normal (column 0) and pyramid-direction force magnitudes
    lam:        lambda, (B, N), metres: maximal-dissipation multiplier (sliding displacement, 0 when sticking)
    forces:     f^{k+1} = D beta, (B, N, 3), world, newtons, force of the object on the hand
    nu:         (B, N, K), metres: separation nu_i0 and tangential slacks (the first block of M z + q)
    sigma:      F beta = mu beta_0 - sum_j beta_j, (B, N), newtons: room left inside the friction pyramid
    residual:   ||min(z, M z + q)||_inf of the explicit LCP, z = (beta, lambda), (B,); +inf for INVALID_INPUT
    status:     (B,), int8 values of :class:`torchhand.kernels.status.SolverStatus`
    iterations: sweeps, (B,), int32
    """

    beta: torch.Tensor
    lam: torch.Tensor
    forces: torch.Tensor
    nu: torch.Tensor
    sigma: torch.Tensor
    residual: torch.Tensor
    status: torch.Tensor
    iterations: torch.Tensor


def friction_pyramid(d0: torch.Tensor, m: int) -> torch.Tensor:
    """Direction matrices D_i of a friction pyramid with 2m evenly spaced tangents (Fig. 11).

    Args:
        d0: outward contact normals d_i0, (B, N, 3) (normalised here)
        m: number of tangent pairs, >= 1

    Returns:
        D, (B, N, 3, 2m + 1): column 0 = d_i0; columns 2j-1, 2j = +-(cos(pi (j-1)/m) t1 + sin(pi (j-1)/m) t2)
        for j = 1..m, with (t1, t2) a tangent frame of d_i0.
    """
    if not isinstance(d0, torch.Tensor) or d0.dim() != 3 or d0.shape[-1] != 3:
        raise _err("friction_pyramid", "d0", "(B, N, 3)", d0)
    if int(m) < 1:
        raise ValueError(f"friction_pyramid: m must be >= 1, got {m}")
    e0 = d0 / torch.linalg.vector_norm(d0, dim=-1, keepdim=True).clamp_min(torch.finfo(d0.dtype).tiny)
    t1, t2 = tangent_frame(e0)
    cols = [e0]
    for j in range(int(m)):
        th = math.pi * j / int(m)
        t = math.cos(th) * t1 + math.sin(th) * t2
        cols += [t, -t]
    return torch.stack(cols, -1)


def kry_pai_s_prime(D: torch.Tensor, s: torch.Tensor, *, G: torch.Tensor | None = None,
                    f_k: torch.Tensor | None = None, J: torch.Tensor | None = None,
                    dtheta_r: torch.Tensor | None = None, u_phi: torch.Tensor | None = None) -> torch.Tensor:
    """s' = s + D^T (J dtheta_r - G f^k - u_phi) (§7.1.3), with s_i = (s_i0, 0, ..., 0).

    Args:
        D: direction matrices, (B, N, 3, K)
        s: normal distances s_i0 between closest points, (B, N), metres (negative when interpenetrating)
        G: effective endpoint compliance J C J^T (Eq. 5), (B, 3N, 3N), m/N; needed with ``f_k``
        f_k: current contact forces f^k (stacked f_i), (B, 3N), newtons
        J: contact Jacobian (stacked J_i, Eq. 4), (B, 3N, n_dof), metres per radian; together with ``dtheta_r``
        dtheta_r: change of the reference angles theta_r^{k+1} - theta_r^k, (B, n_dof), radians
        u_phi: contact motion from the body's velocity and external forces (§7.1.2), (B, 3N), metres

    Returns:
        s', (B, N, K), metres. Omitted terms count as zero.
    """
    fn = "kry_pai_s_prime"
    if not isinstance(D, torch.Tensor) or D.dim() != 4 or D.shape[2] != 3:
        raise _err(fn, "D", "(B, N, 3, K)", D)
    B, N, _, K = D.shape
    _check(fn, s, "s", (B, N), D)
    du = torch.zeros(B, 3 * N, dtype=D.dtype, device=D.device)
    if (G is None) != (f_k is None):
        raise ValueError(f"{fn}: G and f_k must be given together")
    if (J is None) != (dtheta_r is None):
        raise ValueError(f"{fn}: J and dtheta_r must be given together")
    if G is not None:
        _check(fn, G, "G", (B, 3 * N, 3 * N), D)
        _check(fn, f_k, "f_k", (B, 3 * N), D)
        du = du - (G @ f_k[..., None]).squeeze(-1)
    if J is not None:
        if not isinstance(J, torch.Tensor) or J.dim() != 3 or J.shape[:2] != (B, 3 * N):
            raise _err(fn, "J", f"({B}, {3 * N}, n_dof)", J)
        _check(fn, J, "J", tuple(J.shape), D)
        _check(fn, dtheta_r, "dtheta_r", (B, J.shape[2]), D)
        du = du + (J @ dtheta_r[..., None]).squeeze(-1)
    if u_phi is not None:
        _check(fn, u_phi, "u_phi", (B, 3 * N), D)
        du = du - u_phi
    sp = torch.einsum("bnrk,bnr->bnk", D, du.reshape(B, N, 3))
    return sp + torch.nn.functional.pad(s[..., None], (0, K - 1))


def build_kry_pai_lcp(D: torch.Tensor, G: torch.Tensor, U_phi: torch.Tensor, s_prime: torch.Tensor,
                      mu: torch.Tensor, *, mask: torch.Tensor | None = None) -> KryPaiLCP:
    """Assemble the explicit LCP ((D^T (G - U_phi) D, -E^T), (F, 0)), (s', 0) of §7.1.3.

    Args:
        D: direction matrices D_i (see :func:`friction_pyramid`), (B, N, 3, K), K = 2m + 1 odd >= 3
        G: effective endpoint compliance J C J^T (Eq. 5), (B, 3N, 3N), metres per newton
        U_phi: contact motion per unit contact force through the rigid body,
            -h^2 Gamma Ad M^-1 Ad^T Gamma^T (§7.1.2), (B, 3N, 3N), metres per newton (negative semidefinite)
        s_prime: s' (see :func:`kry_pai_s_prime`), (B, N, K), metres
        mu: friction coefficients mu_i, (B, N), >= 0
        mask: active contacts, (B, N) bool; padded contacts (False) get identity rows/columns and q = 0

    Returns:
        :class:`KryPaiLCP`. Raises ``ValueError`` naming the argument on wrong shapes.
    """
    fn = "build_kry_pai_lcp"
    if not isinstance(D, torch.Tensor) or D.dim() != 4 or D.shape[2] != 3 or D.shape[3] < 3 or D.shape[3] % 2 == 0:
        raise _err(fn, "D", "(B, N, 3, K) with K = 2m + 1 >= 3", D)
    if not D.is_floating_point():
        raise ValueError(f"{fn}: D must be floating point, got {D.dtype}")
    B, N, _, K = D.shape
    _check(fn, G, "G", (B, 3 * N, 3 * N), D)
    _check(fn, U_phi, "U_phi", (B, 3 * N, 3 * N), D)
    _check(fn, s_prime, "s_prime", (B, N, K), D)
    _check(fn, mu, "mu", (B, N), D)
    if mask is None:
        mask = torch.ones(B, N, dtype=torch.bool, device=D.device)
    elif not isinstance(mask, torch.Tensor) or tuple(mask.shape) != (B, N) or mask.dtype != torch.bool:
        raise ValueError(f"{fn}: mask must be a bool tensor of shape {(B, N)}, got "
                         f"{tuple(mask.shape) if isinstance(mask, torch.Tensor) else type(mask).__name__}")
    dtype, device = D.dtype, D.device
    zero = torch.zeros((), dtype=dtype, device=device)
    Kb = (G - U_phi).reshape(B, N, 3, N, 3)
    A = torch.einsum("bira,birjs,bjsc->biajc", D, Kb, D)                       # (B, N, K, N, K)
    pair = mask[:, :, None, None, None] & mask[:, None, None, :, None]
    A = torch.where(pair, A, zero)
    NK = N * K
    n = NK + N
    Mx = torch.zeros(B, n, n, dtype=dtype, device=device)
    Mx[:, :NK, :NK] = A.reshape(B, NK, NK)
    eyeN = torch.eye(N, dtype=dtype, device=device)
    tang = torch.ones(K, dtype=dtype, device=device)
    tang[0] = 0.0
    actf = mask.to(dtype)
    # -E^T: column lambda_i has +1 on rows (i, j >= 1);  F: row lambda_i = (mu_i, -1, ..., -1) on (i, :)
    minus_Et = (eyeN[:, None, :] * tang[None, :, None]).reshape(NK, N)
    Mx[:, :NK, NK:] = minus_Et * actf[:, None, :]
    Frow = torch.cat([mu[..., None], -torch.ones(B, N, K - 1, dtype=dtype, device=device)], -1)   # (B, N, K)
    Fblk = (eyeN[None, :, :, None] * Frow[:, :, None, :]).reshape(B, N, NK)
    Mx[:, NK:, :NK] = Fblk * actf[:, :, None]
    # padded contacts: identity rows and columns, q = 0
    diag_pad = torch.cat([(~mask)[..., None].expand(B, N, K).reshape(B, NK), ~mask], -1).to(dtype)
    Mx = Mx + torch.diag_embed(diag_pad)
    q = torch.cat([torch.where(mask[..., None], s_prime, zero).reshape(B, NK), torch.zeros(B, N, dtype=dtype,
                                                                                             device=device)], -1)
    return KryPaiLCP(Mx, q, D, torch.where(mask, mu, zero), mask)


def _pyramid_qp(H: torch.Tensor, c: torch.Tensor, rho: torch.Tensor, Sj: torch.Tensor,
                Sk: torch.Tensor) -> torch.Tensor:
    """Exact minimiser of 1/2 b^T H b + c^T b over {b >= 0, sum b <= rho} when the quadratic depends on b only
    through a planar force D_* b (H = D_*^T K D_*, c in the range of D_*^T): the minimum is attained with at most
    two nonzero directions, so it is the best of the candidates {0}, the single-direction segments, the pyramid
    edges between two directions and the interior stationary points of direction pairs.

    H (Bw, P, P), c (Bw, P), rho (Bw,) >= 0; Sj, Sk (Np, P) one-hot rows of the direction pairs j < k.
    Returns b (Bw, P)."""
    Bw, P = c.shape
    tiny = torch.finfo(c.dtype).tiny
    eps = torch.finfo(c.dtype).eps
    Hd = torch.diagonal(H, dim1=1, dim2=2)
    r = rho[:, None]
    single = torch.minimum((-c / Hd.clamp_min(tiny)).clamp_min(0), r)                       # (Bw, P)
    Hjj, Hkk = Hd @ Sj.t(), Hd @ Sk.t()                                                      # (Bw, Np)
    Hjk = ((H @ Sk.t()) * Sj.t()[None]).sum(1)
    cj, ck = c @ Sj.t(), c @ Sk.t()
    den = r * (Hjj - 2 * Hjk + Hkk)
    num = r * (Hjj - Hjk) + cj - ck
    tau = torch.where(den > eps * r * (Hjj + Hkk) + tiny, num / torch.where(den > 0, den, 1.0), 0.0).clamp(0, 1)
    det = Hjj * Hkk - Hjk * Hjk
    ok = det > 1e-9 * Hjj * Hkk + tiny
    safe = torch.where(ok, det, torch.ones_like(det))
    ia = torch.where(ok, (Hjk * ck - Hkk * cj) / safe, -1.0)
    ib = torch.where(ok, (Hjk * cj - Hjj * ck) / safe, -1.0)
    inside = (ia >= 0) & (ib >= 0) & (ia + ib <= r)
    cands = torch.cat([c.new_zeros(Bw, 1, P), torch.diag_embed(single),
                       (r * (1 - tau))[..., None] * Sj + (r * tau)[..., None] * Sk,
                       ia.clamp_min(0)[..., None] * Sj + ib.clamp_min(0)[..., None] * Sk], 1)      # (Bw, C, P)
    phi = 0.5 * ((cands @ H) * cands).sum(-1) + (cands * c[:, None, :]).sum(-1)
    n_fixed = 1 + P + Sj.shape[0]
    phi = torch.cat([phi[:, :n_fixed], torch.where(inside, phi[:, n_fixed:], math.inf)], 1)
    best = phi.argmin(1)
    return cands[torch.arange(Bw, device=c.device), best]


def _explicit(M: torch.Tensor, q: torch.Tensor, beta: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """z = (beta, lambda) with lambda recovered from maximal dissipation, and w = M z + q.
    M (Bw, n, n), q (Bw, n), beta (Bw, N, K) -> z, w (Bw, n)."""
    Bw, N, K = beta.shape
    NK = N * K
    r = torch.baddbmm(q[:, :NK, None], M[:, :NK, :NK], beta.reshape(Bw, NK, 1)).reshape(Bw, N, K)
    lam = (-r[..., 1:]).amax(-1).clamp_min(0) + 0.0                     # + 0.0: no -0.0
    z = torch.cat([beta.reshape(Bw, NK), lam], -1)
    w = torch.baddbmm(q[..., None], M, z[..., None]).squeeze(-1)
    return z, w


def _checked(lcp, beta0, tol, max_iters, check_every):
    """:func:`solve_contact_lcp`'s arguments checked (``ValueError`` naming the argument), defaults filled in.
    Returns M, q, D, mu, mask, the tolerance table, tol, max_iters, check_every."""
    fn = "solve_contact_lcp"
    if not isinstance(lcp, tuple) or len(lcp) != 5:
        raise ValueError(f"{fn}: lcp must be a KryPaiLCP from build_kry_pai_lcp, got {type(lcp).__name__}")
    M, q, D, mu, mask = lcp
    if not isinstance(D, torch.Tensor) or D.dim() != 4:
        raise _err(fn, "lcp.D", "(B, N, 3, K)", D)
    B, N, _, K = D.shape
    n = N * K + N
    _check(fn, M, "lcp.M", (B, n, n), D)
    _check(fn, q, "lcp.q", (B, n), D)
    _check(fn, mu, "lcp.mu", (B, N), D)
    if beta0 is not None:
        _check(fn, beta0, "beta0", (B, N, K), D)
    if int(check_every) < 1:
        raise ValueError(f"{fn}: check_every must be >= 1, got {check_every}")
    tab = lcp_tolerances(D.dtype)
    tol = tab.tol if tol is None else float(tol)
    max_iters = tab.max_iters if max_iters is None else int(max_iters)
    if max_iters < 0:
        raise ValueError(f"{fn}: max_iters must be >= 0, got {max_iters}")
    check_every = int(check_every)
    return M, q, D, mu, mask, tab, tol, max_iters, check_every


def solve_contact_lcp(lcp: KryPaiLCP, *, beta0: torch.Tensor | None = None, tol: float | None = None,
                      max_iters: int | None = None, check_every: int = 10) -> ContactLCPResult:
    """Projected Gauss-Seidel over contacts for the Kry & Pai LCP (module docstring), batched over problems.

    Args:
        lcp: the explicit problem from :func:`build_kry_pai_lcp`
        beta0: warm start, (B, N, K), newtons (e.g. the previous step's beta). Default 0
        tol: absolute tolerance on ||min(z, M z + q)||_inf of the explicit LCP; default per dtype
            (:func:`torchhand.kernels.lcp.lcp_tolerances`)
        max_iters: limit on sweeps; default per dtype
        check_every: sweeps between convergence checks (the only host syncs)

    Returns:
        :class:`ContactLCPResult`. INVALID_INPUT for NaN/inf data, mu < 0 or a non-positive normal compliance
        d_i0^T (G - U_phi)_ii d_i0 of an active contact; MAX_ITERATIONS when the sweeps stall (Coulomb friction
        makes the LCP non-monotone: solve those with :func:`torchhand.solvers._lemke.lemke` on ``lcp.M, lcp.q``);
        UNBOUNDED when the iterate diverged (the last finite checkpoint is returned).
    """
    M, q, D, mu, mask, tab, tol, max_iters, check_every = _checked(lcp, beta0, tol, max_iters, check_every)
    B, N, _, K = D.shape
    NK, n = N * K, N * K + N
    dtype, device = D.dtype, D.device
    zero = torch.zeros((), dtype=dtype, device=device)

    A = M[:, :NK, :NK].reshape(B, N, K, N, K)
    a00 = torch.diagonal(A[:, :, 0, :, 0], dim1=1, dim2=2)
    invalid = (~torch.isfinite(M.sum(-1)).all(-1) | ~torch.isfinite(q).all(-1) | (mask & ~(a00 > 0)).any(-1)
               | (mask & ~(mu >= 0)).any(-1))
    beta = torch.zeros(B, N, K, dtype=dtype, device=device)
    if beta0 is not None:
        invalid |= ~torch.isfinite(beta0).flatten(1).all(-1)
        beta = torch.where(mask[..., None] & ~invalid[:, None, None], beta0.clamp_min(0), beta)
    status = torch.full((B,), int(SolverStatus.MAX_ITERATIONS), dtype=torch.int8, device=device)
    status = torch.where(invalid, torch.full_like(status, int(SolverStatus.INVALID_INPUT)), status)
    iterations = torch.where(invalid, 0, torch.full((B,), max_iters, dtype=torch.int32, device=device))
    iterations = iterations.to(torch.int32)

    pj, pk = torch.triu_indices(K - 1, K - 1, 1, device=device)
    eyeP = torch.eye(K - 1, dtype=dtype, device=device)
    Sj, Sk = eyeP[pj], eyeP[pk]
    run = (~invalid).nonzero().squeeze(-1)
    Mw, qw, muw, bw = M[run], q[run], mu[run], beta[run].clone()
    Aw = Mw[:, :NK, :NK].reshape(-1, N, K, N, K)
    Acol = Aw.permute(3, 0, 1, 2, 4).contiguous()                 # Acol[i] = columns of contact i, (Bw, N, K, K)
    Adiag = [Aw[:, i, :, i, :].contiguous() for i in range(N)]
    b_prev = bw.clone()
    done = 0
    while run.numel():
        z, w = _explicit(Mw, qw, bw)
        res = lcp_residual(z, w)
        finite = torch.isfinite(bw).flatten(1).all(-1) & (bw.abs() <= tab.blowup).flatten(1).all(-1)
        finite &= torch.isfinite(res)
        conv = finite & (res <= tol)
        stop = conv | ~finite | (done >= max_iters)
        if bool(stop.any()):
            probs = run[stop]
            fin = finite[stop]
            beta[probs] = torch.where(fin[:, None, None], bw[stop], b_prev[stop])
            status[probs] = torch.where(conv[stop], int(SolverStatus.CONVERGED),
                                        torch.where(fin, status[probs], int(SolverStatus.UNBOUNDED))).to(torch.int8)
            iterations[probs] = torch.where(conv[stop] | ~fin, done, iterations[probs]).to(torch.int32)
            keep = ~stop
            if not bool(keep.any()):
                break
            run, Mw, qw, muw, bw = run[keep], Mw[keep], qw[keep], muw[keep], bw[keep]
            Acol, Adiag = Acol[:, keep], [a[keep] for a in Adiag]
        b_prev = bw.clone()
        Bw = run.numel()
        r = torch.baddbmm(qw[:, :NK, None], Mw[:, :NK, :NK], bw.reshape(Bw, NK, 1)).reshape(Bw, N, K)
        for _ in range(min(check_every, max_iters - done)):
            for i in range(N):
                Ai, Ci = Adiag[i], Acol[i]
                # 1. normal update
                b0 = bw[:, i, 0]
                new0 = (b0 - r[:, i, 0] / Ai[:, 0, 0]).clamp_min(0)
                r += Ci[..., 0] * (new0 - b0)[:, None, None]
                bw[:, i, 0] = new0
                # 2. tangential part: exact QP over the friction pyramid of radius mu_i beta_i0
                bt = bw[:, i, 1:]
                H = Ai[:, 1:, 1:]
                c = r[:, i, 1:] - (H @ bt[..., None]).squeeze(-1)
                newt = _pyramid_qp(H, c, muw[:, i] * new0, Sj, Sk)
                r += (Ci[..., 1:] @ (newt - bt)[:, None, :, None]).squeeze(-1)
                bw[:, i, 1:] = newt
        done += min(check_every, max_iters - done)

    beta = torch.where(mask[..., None] & ~invalid[:, None, None], beta, zero)
    z, w = _explicit(torch.where(invalid[:, None, None], torch.eye(n, dtype=dtype, device=device), M),
                     torch.where(invalid[:, None], zero, q), beta)
    residual = torch.where(invalid, math.inf, lcp_residual(z, w))
    lam = z[:, NK:]
    forces = torch.einsum("bnrk,bnk->bnr", D, beta)
    forces = torch.where(mask[..., None] & ~invalid[:, None, None], forces, zero)
    return ContactLCPResult(beta, lam, forces, w[:, :NK].reshape(B, N, K), w[:, NK:], residual, status, iterations)
