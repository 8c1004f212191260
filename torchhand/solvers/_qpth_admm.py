"""The kernel route of the qpth adapter's front (``method="admm"``): :func:`solve_qp` and :func:`lp_feasible` with
:func:`torchhand.kernels.convex_qp.solve_convex_qp` behind the same validation and result types (see
:mod:`._qpth`'s docstring)."""

from __future__ import annotations


import torch

from ._qp_records import (_CONVERGED, _INFEASIBLE, _INVALID, _MAX_ITERATIONS, FeasibilityResult, QPResult, _prepare,
                          _witness_and_certificate)


def _solve_qp_admm(Q, p, G, h, A, b, *, ridge: float, tol: float | None) -> QPResult:
    """``solve_qp(..., method="admm")``: the batched ADMM kernel behind the same validation and result type.

    Inputs are validated and expanded as for qpth (more equality rows than variables and rank-deficient ``A``
    are accepted: the kernel reduces them with a range test), ``ridge`` is added to Q (optional here: PSD Q is
    fine). Statuses come from :func:`torchhand.kernels.convex_qp.solve_convex_qp` (CONVERGED, INFEASIBLE with a
    Farkas certificate, UNBOUNDED, MAX_ITERATIONS, INVALID_INPUT for NaN/inf data); ``tol`` is passed to the
    kernel (default: its per-dtype table, 1e-9 relative for float64). For INFEASIBLE problems (lam, nu) hold the
    kernel's certificate (lam >= 0, G^T lam + A^T nu ~ 0, h^T lam + b^T nu < 0) and z its last iterate. Results
    are detached (the ADMM path is not differentiable); ``iterations`` counts ADMM iterations.
    """
    from ..kernels.convex_qp import solve_convex_qp

    Q, p, G, h, A, b, finite = _prepare(Q, p, G, h, A, b, ridge, qpth=False)
    B, nz = p.shape
    with torch.no_grad():
        res = solve_convex_qp(Q.detach().contiguous(), p.detach(), G.detach().contiguous() if G.shape[1] else None,
                              h.detach().contiguous() if G.shape[1] else None,
                              A.detach().contiguous() if A.shape[1] else None,
                              b.detach().contiguous() if A.shape[1] else None, tol=tol)
        z, lam, nu = res.z, res.lam, res.nu
        if G.shape[1] == 0:
            lam = p.new_zeros(B, 0)
        if A.shape[1] == 0:
            nu = p.new_zeros(B, 0)
        mv = lambda M, v: (M @ v.unsqueeze(-1)).squeeze(-1)  # noqa: E731
        solved = (res.status == _CONVERGED) | (res.status == _MAX_ITERATIONS)
        Q0 = Q - ridge * torch.eye(nz, dtype=p.dtype, device=p.device) if ridge else Q
        objective = 0.5 * (z * mv(Q0, z)).sum(1) + (p * z).sum(1)
        inf = torch.full((), float("inf"), dtype=p.dtype, device=p.device)
        objective = torch.where(solved, objective, inf)
        gap = (z * mv(Q, z)).sum(1) + (p * z).sum(1) + (h * lam).sum(1) + (b * nu).sum(1)
        gap = torch.where(solved, gap.abs(), inf)
    return QPResult(z=z, objective=objective, lam=lam, nu=nu, residual_primal=res.residual_primal,
                    residual_dual=res.residual_dual, gap=gap, status=res.status, iterations=res.iterations.long())


def _lp_feasible_admm(Gn, hn, An, bn, finite, tol: float, dt) -> FeasibilityResult:
    """``lp_feasible(..., method="admm")`` on the unit-row float64 data (B, nineq, nz), (B, neq, nz).

    The kernel solves ``min 0  s.t.  Gn z <= hn, An z = bn`` (equality rows reduced with its range test). Decision,
    per problem, with the data's scale ``S = 1 + |hn|_inf + |bn|_inf`` (unit rows: hn, bn and the violation are
    distances in the units of z):

    * feasible (status CONVERGED) iff the largest unit-row violation at the kernel's z is <= tol S, measured here,
      whatever the kernel's status (z is the witness). The bound does not grow with z: on a nearly infeasible
      system the kernel's iterate drifts far out along the set's recession directions (|z| ~ 1e11 on the
      planner's frames), and a bound tol (1 + |z|_inf) then accepted violations of millimetres;
    * INFEASIBLE iff the kernel returned INFEASIBLE with a Farkas pair (lam >= 0, nu) whose
      ``g = -(hn^T lam + bn^T nu) > 0``; then ``certified_radius = g / |Gn^T lam + An^T nu|_2`` (inf when that
      is 0, e.g. the range test's certificate): no feasible point is closer to the origin;
    * neither: solved once more, with twice ADMM's iterations: where the kernel said MAX_ITERATIONS, interior point
      first with four times its iterations; where it said CONVERGED at a point that fails the bound above (its
      test is relative to the size of the point, and the polish of an interior point that drifted far out can
      pass it on an infeasible system), ADMM alone without the polish, whose iterates yield the Farkas pair. Then
      MAX_ITERATIONS (feasible False) for what stays undecided.

    ``z`` is the kernel's last iterate (not the least-violation point of the qpth method).
    """
    from ..kernels.convex_qp import qp_tolerances, solve_convex_qp

    B, nineq, nz = Gn.shape
    f64, dev = Gn.dtype, Gn.device
    neq = An.shape[1]
    mv = lambda M, v: (M @ v.unsqueeze(-1)).squeeze(-1)  # noqa: E731
    zero = torch.zeros((), dtype=f64, device=dev)
    scale = 1 + (hn.abs().amax(1) if nineq else zero) + (bn.abs().amax(1) if neq else zero)

    def decide(G_, h_, A_, b_, sc, fin, **kw):
        b_n = G_.shape[0]
        res = solve_convex_qp(G_.new_zeros(b_n, nz, nz), G_.new_zeros(b_n, nz), G_ if nineq else None,
                              h_ if nineq else None, A_ if neq else None, b_ if neq else None, tol=min(tol, 1e-6),
                              **{"method": "ipm", **kw})
        viol, _ = _witness_and_certificate(G_, h_, A_, b_, res.z)
        feas = fin & (viol <= tol * sc)
        lam, nu = res.lam.clamp_min(0), res.nu
        e = mv(G_.transpose(1, 2), lam) + mv(A_.transpose(1, 2), nu)
        g = -((h_ * lam).sum(1) + (b_ * nu).sum(1))
        cert = fin & ~feas & (res.status == _INFEASIBLE) & (g > 0)
        radius = torch.where(cert, g / e.norm(dim=1), zero)
        status = torch.where(feas, _CONVERGED, torch.where(cert, _INFEASIBLE, _MAX_ITERATIONS))
        return feas, res.z, viol, radius, status, res.iterations.long(), res.status == _CONVERGED

    with torch.no_grad():
        feas, z, viol, radius, status, iters, claimed = decide(Gn, hn, An, bn, scale, finite)
        open_ = finite & (status == _MAX_ITERATIONS)
        if bool(open_.any()):                                     # host sync: once
            longer = 2 * qp_tolerances(f64).max_iters
            for rows, kw in ((open_ & ~claimed, dict(ipm_iters=200, max_iters=longer)),
                             (open_ & claimed, dict(method="admm", polish=False, max_iters=longer,
                                                    fallback_after=longer))):
                j = rows.nonzero().squeeze(1)
                if not j.numel():
                    continue
                sel = lambda t: t.index_select(0, j)  # noqa: E731
                more = decide(sel(Gn), sel(hn), sel(An), sel(bn), sel(scale), sel(finite), **kw)
                feas, z, viol, radius, status = (t.index_copy(0, j, m) for t, m in
                                                  zip((feas, z, viol, radius, status), more[:5]))
                iters = iters.index_copy(0, j, sel(iters) + more[5])
        status = torch.where(finite, status, _INVALID).to(torch.int8)
    return FeasibilityResult(feasible=feas, z=z.to(dt), violation=viol.to(dt), certified_radius=radius.to(dt),
                             status=status, iterations=iters)
