"""Newton polishing for the friction-cone ADMM (private): semismooth Newton steps on the ADMM's own fixed point.

The ADMM of :mod:`._cone_admm` is the fixed-point iteration w <- w - alpha F(w) with

    F(w) = z - x,    z = Pi_C(w),    x = P (2z - w) + q          (P, q: the affine projection of the x-step),

so a solution is a zero of F. Near it F is smooth almost everywhere (the cone projection is piecewise smooth), and
its generalised Jacobian is J = D - P (2D - I) with D = dPi_C/dw, block-diagonal with one closed-form 3 x 3 block
per contact. A few Newton steps w <- w - J^-1 F(w) (an (n, n) solve per problem, n = 3K) then land on the fixed
point to machine precision once the ADMM has found the right region, the conic analogue of OSQP's polishing
[Ali, Wong, Kolter 2017 apply the same idea to SCS]. For infeasible problems the same is done on the alternating
projection map, F(z) = z - Pi_C(P z + M b), whose fixed point is the point of the cones nearest to the affine set;
its residual gives the infeasibility certificate.

Results are only candidates: the caller accepts them through the same certified tests as the ADMM iterates, so a
Newton step from the wrong region costs time, never correctness.
"""

from __future__ import annotations

import math

import torch

from ._cone_proj import project_cone
from ._rows import at_least_two


def project_cone_with_jacobian(w: torch.Tensor, mu: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Projection onto C_i = {||t|| <= mu_i a} and its Jacobian. w: (B, 3K) component-major, mu: (B, K).

    Returns z (B, 3K) and the Jacobian's 3 x 3 blocks (B, K, 3, 3), one per contact (component order: normal,
    t1, t2; in the component-major variable order they sit at rows/columns j K + i). On the boundary
    region, D = u u^T / (1 + mu^2) + (mu s / r) [[0, 0], [0, I - e e^T]] with u = (1, mu e), e the unit tangential
    direction, r = ||w_t|| and s = (a + mu r) / (1 + mu^2); D = I inside the cone and 0 in its polar cone.
    """
    B, n = w.shape
    K = n // 3
    a, t1, t2 = w[:, :K], w[:, K:2 * K], w[:, 2 * K:]
    r = torch.hypot(t1, t2)
    inv = 1 / (1 + mu * mu)
    s = ((a + mu * r) * inv).clamp_min(0)
    inside = r <= mu * a
    rr = r.clamp_min(torch.finfo(w.dtype).tiny)
    scale = torch.where(inside, torch.ones_like(r), s * mu / rr)
    z = torch.cat([torch.where(inside, a, s), t1 * scale, t2 * scale], 1)
    e = torch.stack([t1, t2], -1) / rr.unsqueeze(-1)                           # (B, K, 2)
    u = torch.cat([torch.ones_like(r).unsqueeze(-1), mu.unsqueeze(-1) * e], -1)  # (B, K, 3)
    blk = u.unsqueeze(-1) * (u * inv.unsqueeze(-1)).unsqueeze(-2)
    blk[..., 1:, 1:] -= scale[..., None, None] * e.unsqueeze(-1) * e.unsqueeze(-2)
    blk[..., 1, 1] += scale
    blk[..., 2, 2] += scale
    keep = (~inside & (s > 0)).to(w.dtype)[..., None, None]
    blk = blk * keep + inside.to(w.dtype)[..., None, None] * torch.eye(3, dtype=w.dtype, device=w.device)
    return z, blk


def _times_blocks(P: torch.Tensor, blk: torch.Tensor) -> torch.Tensor:
    """P D for D block-diagonal with blocks blk (B, K, 3, 3) in component-major order; P: (B, n, n).
    (Three broadcast products: a batched matmul of that many 3 x 3 blocks is slower on the CPU.)"""
    B, n, _ = P.shape
    K = n // 3
    Pv = P.view(B, n, 3, 1, K)                                                  # [b, r, j, ., i]
    bt = blk.permute(0, 2, 3, 1).unsqueeze(1)                                   # [b, ., j, l, i]
    out = Pv[:, :, 0] * bt[:, :, 0] + Pv[:, :, 1] * bt[:, :, 1] + Pv[:, :, 2] * bt[:, :, 2]   # [b, r, l, i]
    return out.reshape(B, n, n)


def _blocks_times(blk: torch.Tensor, P: torch.Tensor) -> torch.Tensor:
    """D P for D block-diagonal with blocks blk (B, K, 3, 3) in component-major order; P: (B, n, n)."""
    B, n, _ = P.shape
    K = n // 3
    Pv = P.view(B, 1, 3, K, n)                                                  # [b, ., l, i, c]
    bt = blk.permute(0, 2, 3, 1).unsqueeze(-1)                                  # [b, j, l, i, .]
    out = bt[:, :, 0] * Pv[:, :, 0] + bt[:, :, 1] * Pv[:, :, 1] + bt[:, :, 2] * Pv[:, :, 2]   # [b, j, i, c]
    return out.reshape(B, n, n)


def _add_blocks(J: torch.Tensor, blk: torch.Tensor) -> torch.Tensor:
    """J + D in place (D block-diagonal as above). Returns J."""
    B, n, _ = J.shape
    K = n // 3
    J.view(B, 3, K, 3, K).diagonal(dim1=2, dim2=4).add_(blk.permute(0, 2, 3, 1))
    return J


def _solve(J: torch.Tensor, rhs: torch.Tensor, chunk: int = 512) -> torch.Tensor:
    """Batched solve J x = rhs (B, n), zero where J is singular or the result is not finite. Solved in chunks:
    LAPACK's batched LU slows down far more than linearly once the batch leaves the cache."""
    out = []
    for i in range(0, J.shape[0], chunk):
        x, info = torch.linalg.solve_ex(J[i:i + chunk], rhs[i:i + chunk].unsqueeze(-1))
        out.append(torch.where((info == 0)[:, None, None] & torch.isfinite(x), x, 0).squeeze(-1))
    return torch.cat(out) if len(out) != 1 else out[0]


def _fixed_point_residual(w, P, q, mu):
    z = project_cone(w, mu)
    return z - torch.baddbmm(q.unsqueeze(-1), P, (2 * z - w).unsqueeze(-1)).squeeze(-1)


def _newton(x: torch.Tensor, data: tuple, residual_and_step, steps: int, ftol: float, give_up: float):
    """Shared driver: ``steps`` Newton steps x <- step(x) on the problems still worth it. A problem leaves once
    ||F|| <= ftol (done) or, from the third step on, when ||F|| is still above ``give_up`` times its first value
    (wrong region: more steps would be wasted). The compaction reads a count (a host sync), which is fine here:
    polishing only ever runs at a convergence check. data: per-problem tensors indexed along dim 0."""
    if ftol <= 0 and give_up == math.inf:                                     # no exits: no syncs
        for _ in range(steps):
            F, step = residual_and_step(x, *data)
            x = step(F)
        return x
    out = x.clone()
    idx = torch.arange(x.shape[0], device=x.device)
    f0 = None
    for k in range(steps):
        F, step = residual_and_step(x, *data)
        fn = torch.linalg.vector_norm(F, dim=-1)
        f0 = fn if f0 is None else f0
        stop = fn <= ftol
        if k >= 2:
            stop |= fn > give_up * f0
        if bool(stop.any()):                                                  # host sync (at a check only)
            out[idx[stop]] = x[stop]
            keep = at_least_two((~stop).nonzero().squeeze(-1))
            idx, x, f0 = idx[keep], x[keep], f0[keep]
            data = tuple(t.index_select(0, keep) for t in data)
            if not idx.numel():
                return out
            F, step = residual_and_step(x, *data)
        x = step(F)
    out[idx] = x
    return out


def newton_fixed_point(w: torch.Tensor, P: torch.Tensor, q: torch.Tensor, mu: torch.Tensor, active: torch.Tensor,
                       steps: int, backtrack: int = 0, alpha: float = 1.6, ftol: float = 0.0,
                       give_up: float = math.inf) -> torch.Tensor:
    """Safeguarded Newton steps on F(w) = Pi_C(w) - (P (2 Pi_C(w) - w) + q). w, q: (B, n); P: (B, n, n);
    mu, active: (B, K). Each step tries t = 1, 1/2, ... (``backtrack`` halvings) along the Newton direction and
    keeps the first t that reduces ||F||; where none does, it takes the plain ADMM step w - alpha F instead
    (which never increases ||F||). Early exits as in :func:`_newton`. Returns w."""
    pinned = (~active).repeat(1, 3).to(w.dtype)                               # inactive variables: F = w there

    def residual_and_step(w, P, q, mu, pinned):
        z, blk = project_cone_with_jacobian(w, mu)
        F = z - torch.baddbmm(q.unsqueeze(-1), P, (2 * z - w).unsqueeze(-1)).squeeze(-1)

        def step(F):
            fn = torch.linalg.vector_norm(F, dim=-1, keepdim=True)
            J = _add_blocks(P - 2 * _times_blocks(P, blk) + torch.diag_embed(pinned), blk)   # D - P (2D - I)
            dw = _solve(J, F)
            # Trust region: near-singular Jacobians (internal-force directions of the grasp leave F unchanged)
            # give huge steps that a residual test alone would not stop; a step may at most double ||w||.
            wn = torch.linalg.vector_norm(w, dim=-1, keepdim=True).clamp_min(1)
            dw = dw * (wn / torch.linalg.vector_norm(dw, dim=-1, keepdim=True).clamp_min(1e-300)).clamp(max=1)
            best = w - alpha * F
            found = torch.zeros_like(fn, dtype=torch.bool)
            t = 1.0
            for _ in range(backtrack + 1):
                cand = w - t * dw
                ok = ~found & (torch.linalg.vector_norm(_fixed_point_residual(cand, P, q, mu), dim=-1, keepdim=True)
                               < (1 - 1e-4 * t) * fn)
                best = torch.where(ok, cand, best)
                found = found | ok
                t *= 0.5
            return best

        return F, step

    return _newton(w, (P, q, mu, pinned), residual_and_step, steps, ftol, give_up)


def newton_nearest_point(z: torch.Tensor, P: torch.Tensor, q0: torch.Tensor, mu: torch.Tensor, steps: int,
                         ftol: float = 0.0, give_up: float = math.inf) -> torch.Tensor:
    """Newton steps on F(z) = z - Pi_C(P z + q0) (alternating projections between the cones and the affine set
    {A x = b}, q0 = M b). Returns Pi_C(P z + q0) (B, n): a cone point nearest to the affine set when the steps
    converge. Early exits as in :func:`_newton`."""
    n = z.shape[1]
    eye = torch.eye(n, dtype=z.dtype, device=z.device)

    def residual_and_step(z, P, q0, mu):
        v = torch.baddbmm(q0.unsqueeze(-1), P, z.unsqueeze(-1)).squeeze(-1)
        pz, blk = project_cone_with_jacobian(v, mu)

        def step(F):
            dz = _solve(eye - _blocks_times(blk, P), F)
            zn = torch.linalg.vector_norm(z, dim=-1, keepdim=True).clamp_min(1)
            return z - dz * (zn / torch.linalg.vector_norm(dz, dim=-1, keepdim=True).clamp_min(1e-300)).clamp(max=1)

        return z - pz, step

    z = _newton(z, (P, q0, mu), residual_and_step, steps, ftol, give_up)
    return project_cone(torch.baddbmm(q0.unsqueeze(-1), P, z.unsqueeze(-1)).squeeze(-1), mu)


def warm_point(z0: torch.Tensor, A: torch.Tensor, c: torch.Tensor, mu: torch.Tensor, active: torch.Tensor,
               rho: torch.Tensor) -> torch.Tensor:
    """A governing point w = z0 - s / rho for a warm start from forces z0 alone (B, 3K component-major, in C).

    The slack s = c - A^T y needs a dual y, which a parent node does not pass on: y is the least-squares fit of
    the complementarity conditions z0 implies, per contact s_i = 0 (strictly inside its cone), s_i parallel to
    (mu, -t/|t|) (on the boundary), s_n = 0 (an active sliding ray), nothing (zero force):
    y = argmin sum_i ||Q_i (c_i - A_i^T y)||^2 (+ a tiny ridge), then s is projected onto the dual cones.
    A: (B, m, 3K); c: (B, 3K); mu, active: (B, K); rho: (B, 1). Returns w (B, 3K).
    """
    B, n = z0.shape
    K = n // 3
    x = z0.view(B, 3, K).transpose(1, 2)                                           # (B, K, 3)
    a = x[..., 0]
    r = torch.hypot(x[..., 1], x[..., 2])
    big = a.abs().amax(-1, keepdim=True).clamp_min(torch.finfo(z0.dtype).tiny)
    on = active & (a > 1e-6 * big)
    inside = on & (r < (1 - 1e-6) * mu * a)
    rdir = torch.stack([mu, -x[..., 1] / r.clamp_min(1e-300), -x[..., 2] / r.clamp_min(1e-300)], -1)
    rdir = rdir / torch.linalg.vector_norm(rdir, dim=-1, keepdim=True)
    eye = torch.eye(3, dtype=z0.dtype, device=z0.device)
    Q = torch.where(inside[..., None, None], eye, eye - rdir.unsqueeze(-1) * rdir.unsqueeze(-2))
    ray = (mu == 0)[..., None, None]
    Q = torch.where(ray, torch.diag(eye.new_tensor([1.0, 0, 0])), Q) * on[..., None, None].to(z0.dtype)
    m = A.shape[1]
    Ac = A.view(B, m, 3, K).permute(0, 3, 1, 2)                                    # (B, K, m, 3)
    AQ = Ac @ Q                                                                    # (B, K, m, 3)
    H = (AQ @ Ac.transpose(-1, -2)).sum(1)                                         # (B, m, m)
    g = (AQ @ c.view(B, 3, K).transpose(1, 2).unsqueeze(-1)).sum(1).squeeze(-1)    # (B, m)
    ridge = 1e-9 * H.diagonal(dim1=1, dim2=2).sum(-1).clamp_min(1e-12)
    y = _solve(H + ridge[:, None, None] * torch.eye(m, dtype=z0.dtype, device=z0.device), g)
    s = c - torch.bmm(A.transpose(1, 2), y.unsqueeze(-1)).squeeze(-1)
    s = s + project_cone(-s, mu)                                                   # onto the dual cones (Moreau)
    return z0 - s / rho
