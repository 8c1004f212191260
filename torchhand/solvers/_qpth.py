"""Batched convex QPs through qpth, with our own residual checks, and LP feasibility through a phase-1 QP.

One adapter over qpth (Amos & Kolter's batched primal-dual interior-point method, dense KKT factorisations)::

    minimise   1/2 z^T Q z + p^T z      over z (B, nz)
    subject to G z <= h                 (nineq rows)
               A z  = b                 (neq rows)

What the adapter adds to qpth
    * Explicit batch: ``p`` is (B, nz) and fixes B; ``Q``, ``G``, ``h``, ``A``, ``b`` are either per problem
      (leading B) or shared (no batch dimension) and are expanded explicitly. Shapes are checked and a
      :class:`~torchhand.errors.ShapeError` names the argument, the expected and the actual shape.
    * ``Q`` is symmetrised (``(Q + Q^T) / 2``, which leaves the objective unchanged); ``ridge`` adds ``ridge * I``
      for positive semidefinite ``Q`` (qpth factorises ``Q``, so it must be positive definite).
    * Per-problem screening before the solve: problems with NaN/inf data, a ``Q`` that is not positive definite
      or an ``A`` without full row rank get ``INVALID_INPUT`` and are replaced by a harmless dummy inside the
      batch, so they cannot disturb the others.
    * Our own residuals at the returned point, with qpth's multipliers ``lam >= 0`` (rows of G) and ``nu``
      (rows of A): primal ``max(|max(Gz - h, 0)|_inf, |Az - b|_inf)``, dual
      ``|Qz + p + G^T lam + A^T nu|_inf`` and gap ``|z^T Q z + p^T z + h^T lam + b^T nu|`` (primal minus dual
      objective). A problem is CONVERGED when each is below ``tol`` times ``1 +`` the largest term it is made of
      (``tol`` per dtype in :data:`QP_TOLERANCES`). The others are INFEASIBLE when the phase-1 problem of
      :func:`lp_feasible` finds their constraints infeasible, else MAX_ITERATIONS.
    * Per-problem robustness inside qpth, by swapping two of its helpers during our calls (restored after):
      its step-length rule yields NaN iterates on easy problems (an exactly zero direction component) and takes a
      batch-wide max, and its LU raises on one singular factor, upon which qpth stops the whole batch (see
      :func:`_step_length`, :func:`_lu_no_raise`). So one diverging (infeasible) problem no longer stops or
      spoils the others.
    * Nothing is printed: qpth's per-iteration lines and its "inaccurate solution" warning are captured (the
      iteration lines give ``iterations``: qpth iterates the whole batch together and keeps each problem's best
      iterate, so the count is the batch's).
    * Differentiable in all inputs through qpth's implicit KKT differentiation (``backward`` as in
      ``qpth.qp.QPFunction``, per problem, no averaging over shared inputs: autograd sums the expanded ones).

LP feasibility (Liu 2009, Sec. 4.3: "is this set of contacts feasible" = Eq. 4 without the objective)
    qpth cannot solve LPs, and a QP over an infeasible set gives no certificate, so :func:`lp_feasible` solves a
    phase-1 QP that is always feasible: with the rows of ``G`` and ``A`` scaled to unit norm,
    ``min_z,u 1/2 |u|^2 + 1/2 |A z - b|^2 + ridge/2 |z|^2  s.t.  G z - u <= h``, i.e. the least squared
    constraint violation (``u = max(Gz - h, 0)`` at the optimum), regularised by the ridge so that its Hessian
    is positive definite. It is solved in float64 whatever the input dtype. At its solution z:

    * ``violation``: ``max`` over rows of ``max(G_i z - h_i, 0)`` and ``|A_i z - b_i|`` (unit rows: a distance
      in the units of z), measured by us at z;
    * ``feasible = violation <= tol * (1 + |z|_inf)``; then z itself is the witness (status CONVERGED);
    * otherwise ``y_G = max(Gz - h, 0)``, ``y_A = Az - b`` form a Farkas certificate: for any feasible z',
      ``e^T z' <= -g`` with ``e = G^T y_G + A^T y_A``, ``g = -(h^T y_G + b^T y_A)``, so no feasible point has
      ``|z'|_2 < certified_radius = g / |e|`` (inf for an exact certificate). This holds whatever the solver did:
      it is computed by us from z. For a truly infeasible system it is about ``|violation|^2 / (ridge |z|)``.
    * Status INFEASIBLE when the phase-1 QP converged and ``certified_radius > 100 (1 + |z|_2)``: nothing
      feasible lies within a hundred times the least-violation point's distance from the origin. A smaller
      radius means the set may be a thin or far sliver that the ridge pulled z away from, so the problem is
      solved again with ridge * 1e-3 and ridge * 1e-6; still undecided then: MAX_ITERATIONS (feasible False).
      A caller that knows a bound R on its variables (Liu's force limits) can instead require
      ``certified_radius > R``, which depends on no solver tolerance.

A faster path: ``method="admm"``
    :func:`solve_qp` and :func:`lp_feasible` take ``method="qpth"`` (the default, everything above) or
    ``method="admm"``, which uses the batched kernel :func:`torchhand.kernels.convex_qp.solve_convex_qp` (interior
    point and OSQP-style ADMM with polishing; positive semidefinite ``Q`` and rank-deficient ``A``
    accepted, the latter reduced with a range test) behind the same validation and result types. It is much
    faster than qpth at the sizes of Liu 2009's window QPs, is not differentiable (results are detached) and
    decides INFEASIBLE from the kernel's Farkas certificates; its feasibility witness must violate no unit row by
    more than ``tol * (1 + |h|_inf + |b|_inf)``, a bound that does not grow with the iterate (see
    :func:`_solve_qp_admm`, :func:`_lp_feasible_admm`).
"""

from __future__ import annotations


import torch

from ..errors import InputTypeError, InputValueError, ShapeError
from ._qp_records import (_CERTAIN, _CONVERGED, _INFEASIBLE, _INVALID, _MAX_ITERATIONS, _RIDGE_SHRINK, _RIDGE_STEPS,
                          QP_TOLERANCES, FeasibilityResult, QPResult, _prepare, _well_posed,
                          _witness_and_certificate)
from ._qpth_admm import _lp_feasible_admm, _solve_qp_admm
from ._qpth_patches import _pdipm, _solve_batch

__all__ = ["QPResult", "FeasibilityResult", "QP_TOLERANCES", "solve_qp", "lp_feasible"]


def _residuals(Q, p, G, h, A, b, z, lam, nu):
    """Absolute residuals and their scales (see the module docstring)."""
    mv = lambda M, v: (M @ v.unsqueeze(-1)).squeeze(-1)  # noqa: E731
    amax = lambda t: t.abs().amax(1) if t.shape[1] else t.new_zeros(t.shape[0])  # noqa: E731
    Qz, Gz, Az = mv(Q, z), mv(G, z), mv(A, z)
    GTl = mv(G.transpose(1, 2), lam)
    ATn = mv(A.transpose(1, 2), nu)
    r_p = torch.maximum(amax((Gz - h).clamp(min=0)), amax(Az - b))
    s_p = 1 + torch.stack([amax(Gz), amax(h), amax(Az), amax(b)]).amax(0)
    r_d = amax(Qz + p + GTl + ATn)
    s_d = 1 + torch.stack([amax(Qz), amax(p), amax(GTl), amax(ATn)]).amax(0)
    zQz = (z * Qz).sum(1)
    pz = (p * z).sum(1)
    gap = (zQz + pz + (h * lam).sum(1) + (b * nu).sum(1)).abs()
    s_g = 1 + (0.5 * zQz + pz).abs()
    return r_p, s_p, r_d, s_d, gap, s_g


def _converged(data, z, lam, nu, tol: float):
    """Per-problem convergence from our own residuals; returns (mask, (primal, dual, gap) absolute residuals)."""
    with torch.no_grad():
        r_p, s_p, r_d, s_d, gap, s_g = _residuals(*data, z.detach(), lam.clamp(min=0), nu)
        ok = torch.isfinite(z).all(1) & torch.isfinite(r_p) & torch.isfinite(r_d) & torch.isfinite(gap)
        ok &= (r_p <= tol * s_p) & (r_d <= tol * s_d) & (gap <= tol * s_g)
    return ok, (r_p, r_d, gap)


def solve_qp(
    Q: torch.Tensor,
    p: torch.Tensor,
    G: torch.Tensor | None = None,
    h: torch.Tensor | None = None,
    A: torch.Tensor | None = None,
    b: torch.Tensor | None = None,
    *,
    ridge: float = 0.0,
    tol: float | None = None,
    max_iters: int = 25,
    check_infeasible: bool = True,
    method: str = "qpth",
) -> QPResult:
    """Solve B convex QPs ``min 1/2 z^T Q z + p^T z  s.t.  G z <= h, A z = b`` with qpth (see the module docstring).

    Args:
        Q: (B, nz, nz) or shared (nz, nz); positive definite after symmetrisation and ``ridge``
        p: (B, nz), float32 or float64; fixes B, dtype and device
        G, h: (B, nineq, nz) / (B, nineq), or shared (nineq, nz) / (nineq,); None for no inequalities
        A, b: (B, neq, nz) / (B, neq), or shared; None for no equalities; neq <= nz, full row rank
        ridge: added to Q's diagonal (>= 0), for a positive semidefinite Q
        tol: relative tolerance of the residual checks; default ``QP_TOLERANCES[dtype]``
        max_iters: interior-point iterations per pass (qpth's ``maxIter``); problems that have not converged get
            a second pass of their own (at most 2 * max_iters in all)
        check_infeasible: classify the problems that did not converge with :func:`lp_feasible`
            (INFEASIBLE or MAX_ITERATIONS); if False they are all MAX_ITERATIONS
        method: "qpth" (the default, as described above) or "admm" (see :func:`_solve_qp_admm`: the batched
            ADMM kernel :func:`torchhand.kernels.convex_qp.solve_convex_qp`; positive semidefinite Q and any rank
            of A accepted; ``max_iters`` and ``check_infeasible`` do not apply; not differentiable)

    Returns:
        QPResult (see its fields). INVALID_INPUT problems: z = 0, lam = nu = 0, objective and residuals inf.
        INFEASIBLE problems: z = the least-violation point of :func:`lp_feasible` (residual_primal measures its
        violation), lam = nu = 0, objective, residual_dual and gap inf.
    """
    if method == "admm":
        return _solve_qp_admm(Q, p, G, h, A, b, ridge=ridge, tol=tol)
    if method != "qpth":
        raise InputValueError(f"method: expected 'qpth' or 'admm', got {method!r}")
    Q, p, G, h, A, b, finite = _prepare(Q, p, G, h, A, b, ridge)
    if not isinstance(max_iters, int) or max_iters < 1:
        raise InputValueError(f"max_iters: expected a positive int, got {max_iters!r}")
    _pdipm()                   # the optional extra: one line saying how to install it, before any work
    tol = QP_TOLERANCES[p.dtype] if tol is None else float(tol)
    B, nz = p.shape
    valid = _well_posed(Q.detach(), A.detach(), finite)
    # Invalid problems are swapped for a dummy (Q = I, p = 0, 0 z <= 1, A = [I 0], b = 0) so they cannot upset qpth.
    v2, v3 = valid.view(B, 1), valid.view(B, 1, 1)
    eye = torch.eye(nz, dtype=p.dtype, device=p.device)
    Qs = torch.where(v3, Q, eye)
    ps = torch.where(v2, p, torch.zeros_like(p))
    Gs = torch.where(v3, G, torch.zeros_like(G))
    hs = torch.where(v2, h, torch.ones_like(h))
    As = torch.where(v3, A, eye[: A.shape[1]])
    bs = torch.where(v2, b, torch.zeros_like(b))
    data = (Qs, ps, Gs, hs, As, bs)
    z, nu, lam, iters = _solve_batch(*data, max_iters)
    conv, res = _converged(data, z, lam, nu, tol)
    infeasible = torch.zeros_like(valid)
    pending = valid & ~conv
    if bool(pending.any()):
        # qpth iterates the batch under one stopping rule. Classify the stragglers with the phase-1 problem,
        # then give the feasible (or undecided) ones a pass of their own.
        if check_infeasible:
            idx = pending.nonzero().squeeze(1)
            eq = A.shape[1] > 0
            feas = lp_feasible(Gs[idx], hs[idx], As[idx] if eq else None, bs[idx] if eq else None)
            bad = feas.status == _INFEASIBLE
            infeasible = infeasible.index_put((idx,), bad)
            # An infeasible problem reports the least-violation point of its constraints instead of qpth's iterate.
            z = z.index_put((idx[bad],), feas.z[bad].to(p.dtype))
        retry = pending & ~infeasible
        if bool(retry.any()):
            j = retry.nonzero().squeeze(1)
            z2, nu2, lam2, it2 = _solve_batch(*(t[j] for t in data), max_iters)
            z, nu, lam = z.index_put((j,), z2), nu.index_put((j,), nu2), lam.index_put((j,), lam2)
            iters = iters.index_put((j,), iters[j] + it2)
        conv, res = _converged(data, z, lam, nu, tol)
    zero = torch.zeros((), dtype=p.dtype, device=p.device)
    inf = torch.full((), float("inf"), dtype=p.dtype, device=p.device)
    with torch.no_grad():
        r_p, r_d, gap = res
        status = torch.where(conv, _CONVERGED, torch.where(infeasible, _INFEASIBLE, _MAX_ITERATIONS))
        status = torch.where(valid, status, _INVALID).to(torch.int8)
        r_p = torch.where(valid, r_p, inf)
        r_d, gap = (torch.where(valid & ~infeasible, r, inf) for r in (r_d, gap))
    keep = (valid & ~infeasible).view(B, 1)
    z = torch.where(v2, z, zero)
    lam = torch.where(keep, lam.clamp(min=0), zero)
    nu = torch.where(keep, nu, zero)
    Q0 = Q - ridge * torch.eye(nz, dtype=p.dtype, device=p.device) if ridge else Q
    objective = 0.5 * (z * (Q0 @ z.unsqueeze(-1)).squeeze(-1)).sum(1) + (p * z).sum(1)
    objective = torch.where(keep.squeeze(1), objective, inf)
    return QPResult(z=z, objective=objective, lam=lam, nu=nu, residual_primal=r_p, residual_dual=r_d, gap=gap,
                    status=status, iterations=iters)


# ------------------------------------------------------------------------------------------ LP feasibility
def lp_feasible(
    G: torch.Tensor,
    h: torch.Tensor,
    A: torch.Tensor | None = None,
    b: torch.Tensor | None = None,
    *,
    ridge: float = 1e-8,
    tol: float = 1e-6,
    max_iters: int = 25,
    method: str = "qpth",
) -> FeasibilityResult:
    """Is ``{z : G z <= h, A z = b}`` non-empty, per problem? Phase-1 QP through qpth (see the module docstring).

    Args:
        G: (B, nineq, nz); h: (B, nineq) (units of G z)
        A: (B, neq, nz) or None; b: (B, neq) or None
        ridge: weight of ``|z|^2 / 2`` in the phase-1 objective (> 0; with unit-norm rows)
        tol: violation tolerance: feasible iff violation <= tol * (1 + |z|_inf) (qpth) or
            tol * (1 + |h|_inf + |b|_inf) on the unit-row data (admm)
        max_iters: interior-point iterations (method "qpth")
        method: "qpth" (the phase-1 QP of the module docstring) or "admm" (:func:`_lp_feasible_admm`)

    Returns:
        FeasibilityResult(feasible, z, violation, certified_radius, status, iterations), all with leading B.
    """
    if not isinstance(G, torch.Tensor) or G.dim() != 3:
        raise ShapeError(f"G: expected shape (B, nineq, nz), got "
                         f"{tuple(G.shape) if isinstance(G, torch.Tensor) else type(G).__name__}")
    if G.dtype not in QP_TOLERANCES:
        raise InputTypeError(f"G: expected float32 or float64, got {G.dtype}")
    B, nineq, nz = G.shape
    if not isinstance(h, torch.Tensor) or tuple(h.shape) != (B, nineq):
        raise ShapeError(f"h: expected shape ({B}, {nineq}), got "
                         f"{tuple(h.shape) if isinstance(h, torch.Tensor) else type(h).__name__}")
    if (A is None) != (b is None):
        raise InputValueError("A, b: give both or neither")
    if A is not None:
        if not isinstance(A, torch.Tensor) or A.dim() != 3 or A.shape[0] != B or A.shape[2] != nz:
            raise ShapeError(f"A: expected shape ({B}, neq, {nz}), got "
                             f"{tuple(A.shape) if isinstance(A, torch.Tensor) else type(A).__name__}")
        if not isinstance(b, torch.Tensor) or tuple(b.shape) != (B, A.shape[1]):
            raise ShapeError(f"b: expected shape ({B}, {A.shape[1]}), got "
                             f"{tuple(b.shape) if isinstance(b, torch.Tensor) else type(b).__name__}")
    if not isinstance(ridge, (int, float)) or not ridge > 0:
        raise InputValueError(f"ridge: expected a positive number, got {ridge!r}")
    if method not in ("qpth", "admm"):
        raise InputValueError(f"method: expected 'qpth' or 'admm', got {method!r}")
    if method == "qpth":
        _pdipm()
    dt, dev, f64 = G.dtype, G.device, torch.float64
    Gd, hd = G.detach().to(f64), h.detach().to(f64)
    Ad = A.detach().to(f64) if A is not None else Gd.new_zeros(B, 0, nz)
    bd = b.detach().to(f64) if b is not None else Gd.new_zeros(B, 0)
    finite = torch.ones(B, dtype=torch.bool, device=dev)
    for t in (Gd, hd, Ad, bd):
        if t.shape[1]:
            finite &= torch.isfinite(t).flatten(1).all(1)
    zero = torch.zeros((), dtype=f64, device=dev)
    Gd, hd, Ad, bd = (torch.where(finite.view(-1, *([1] * (t.dim() - 1))), t, zero) for t in (Gd, hd, Ad, bd))
    # Unit rows: the feasible set is unchanged and violations become distances in z's units.
    gn = Gd.norm(dim=2).clamp(min=1e-300)
    an = Ad.norm(dim=2).clamp(min=1e-300)
    gz, az = Gd.norm(dim=2) > 0, Ad.norm(dim=2) > 0
    Gn, hn = torch.where(gz.unsqueeze(-1), Gd / gn.unsqueeze(-1), Gd), torch.where(gz, hd / gn, hd)
    An, bn = torch.where(az.unsqueeze(-1), Ad / an.unsqueeze(-1), Ad), torch.where(az, bd / an, bd)
    if method == "admm":
        return _lp_feasible_admm(Gn, hn, An, bn, finite, tol, dt)
    z = Gd.new_zeros(B, nz)
    viol = torch.full((B,), float("inf"), dtype=f64, device=dev)
    radius = torch.zeros(B, dtype=f64, device=dev)
    status = torch.full((B,), _MAX_ITERATIONS, dtype=torch.long, device=dev)
    iters = torch.zeros(B, dtype=torch.long, device=dev)
    todo = finite.clone()
    for k in range(_RIDGE_STEPS):
        if not bool(todo.any()):
            break
        j = todo.nonzero().squeeze(1)
        zj, solved, it = _phase1(Gn[j], hn[j], An[j], bn[j], ridge * _RIDGE_SHRINK ** k, max_iters)
        vj, rj = _witness_and_certificate(Gn[j], hn[j], An[j], bn[j], zj)
        feas = vj <= tol * (1 + zj.abs().amax(1))
        # Infeasible only when the certificate excludes far more than the least-violation point's distance;
        # otherwise the set may be a far or thin sliver that the ridge pulled us away from: retry with less ridge.
        sure = solved & (rj > _CERTAIN * (1 + zj.norm(dim=1)))
        st = torch.where(feas, _CONVERGED, torch.where(sure, _INFEASIBLE, _MAX_ITERATIONS))
        z, viol, radius = z.index_put((j,), zj), viol.index_put((j,), vj), radius.index_put((j,), rj)
        status, iters = status.index_put((j,), st), iters.index_put((j,), iters[j] + it)
        todo = todo.index_put((j,), st == _MAX_ITERATIONS)
    feasible = finite & (status == _CONVERGED)
    radius = torch.where(feasible | ~finite, torch.zeros((), dtype=f64, device=dev), radius)
    status = torch.where(finite, status, _INVALID).to(torch.int8)
    return FeasibilityResult(feasible=feasible, z=z.to(dt), violation=viol.to(dt), certified_radius=radius.to(dt),
                             status=status, iterations=iters)


def _phase1(Gn, hn, An, bn, ridge: float, max_iters: int):
    """Least-violation point of unit-row constraints: ``min 1/2 |u|^2 + 1/2 |An z - bn|^2 + ridge/2 |z|^2``
    s.t. ``Gn z - u <= hn``, as a QP in w = (z, u) with Q = blkdiag(An^T An + ridge I, I), p = (-An^T bn, 0).
    Returns z (B, nz), whether the QP converged (B,), iterations (B,)."""
    B, nineq, nz = Gn.shape
    f64, dev = Gn.dtype, Gn.device
    eye_u = torch.eye(nineq, dtype=f64, device=dev)
    Qw = torch.zeros(B, nz + nineq, nz + nineq, dtype=f64, device=dev)
    Qw[:, :nz, :nz] = An.transpose(1, 2) @ An + ridge * torch.eye(nz, dtype=f64, device=dev)
    Qw[:, nz:, nz:] = eye_u
    pw = torch.cat([-(An.transpose(1, 2) @ bn.unsqueeze(-1)).squeeze(-1), Gn.new_zeros(B, nineq)], 1)
    Gw = torch.cat([Gn, -eye_u.expand(B, nineq, nineq)], 2)
    res = solve_qp(Qw, pw, Gw if nineq else None, hn if nineq else None, check_infeasible=False,
                   max_iters=max_iters)
    return res.z[:, :nz], res.status == _CONVERGED, res.iterations
