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

import contextlib
import io
from dataclasses import dataclass
from types import MappingProxyType

import torch
from qpth.solvers.pdipm import batch as _pdipm

from ..errors import InputTypeError, InputValueError, ShapeError
from ..kernels.status import SolverStatus

__all__ = ["QPResult", "FeasibilityResult", "QP_TOLERANCES", "solve_qp", "lp_feasible"]

#: Relative tolerance of the residual checks per dtype (see the module docstring).
QP_TOLERANCES = MappingProxyType({torch.float32: 1e-3, torch.float64: 1e-6})

_RIDGE_STEPS = 3          # lp_feasible: phase-1 ridges ridge, ridge * 1e-3, ridge * 1e-6 for undecided problems
_RIDGE_SHRINK = 1e-3
_CERTAIN = 100.0          # lp_feasible: infeasible when nothing feasible lies within 100 (1 + |z|_2) of the origin
_CONVERGED = int(SolverStatus.CONVERGED)
_INFEASIBLE = int(SolverStatus.INFEASIBLE)
_MAX_ITERATIONS = int(SolverStatus.MAX_ITERATIONS)
_INVALID = int(SolverStatus.INVALID_INPUT)


@dataclass(frozen=True)
class QPResult:
    """Solution of B QPs ``min 1/2 z^T Q z + p^T z  s.t.  G z <= h, A z = b`` (units are the caller's).

    z:               primal solution, (B, nz); qpth's best iterate when MAX_ITERATIONS (may be NaN then), the
                     least-violation point when INFEASIBLE, 0 when INVALID_INPUT
    objective:       1/2 z^T Q z + p^T z with the given Q (without the ridge), (B,); inf when INFEASIBLE/INVALID
    lam:             multipliers of G z <= h, (B, nineq), >= 0
    nu:              multipliers of A z = b, (B, neq)
    residual_primal: max(|max(Gz - h, 0)|_inf, |Az - b|_inf), (B,), units of h and b
    residual_dual:   |(Q + ridge I) z + p + G^T lam + A^T nu|_inf, (B,), units of p
    gap:             |z^T (Q + ridge I) z + p^T z + h^T lam + b^T nu|, primal minus dual objective, (B,)
    status:          SolverStatus per problem, (B,), int8: CONVERGED / INFEASIBLE / MAX_ITERATIONS / INVALID_INPUT
    iterations:      interior-point iterations of the qpth passes this problem took part in, (B,), long (qpth
                     iterates a batch together: the first pass counts for all, a second pass for its problems)
    """

    z: torch.Tensor
    objective: torch.Tensor
    lam: torch.Tensor
    nu: torch.Tensor
    residual_primal: torch.Tensor
    residual_dual: torch.Tensor
    gap: torch.Tensor
    status: torch.Tensor
    iterations: torch.Tensor


@dataclass(frozen=True)
class FeasibilityResult:
    """Feasibility of B polyhedra ``{z : G z <= h, A z = b}`` decided by :func:`lp_feasible`.

    feasible:         (B,) bool; True iff ``violation <= tol * (1 + |z|_inf)`` (method "qpth": z is the ridge-
                      regularised least-violation point) or ``violation <= tol * (1 + |h|_inf + |b|_inf)`` with
                      unit rows (method "admm": a bound that does not grow with the iterate); z is the witness
    z:                least-violation point of the phase-1 QP, (B, nz), units of z
    violation:        largest violation of a unit-normalised row at z, (B,), units of z
    certified_radius: no feasible point has |z'|_2 below this, (B,), units of z; 0 when feasible or
                      uncertified, inf for an exact Farkas certificate
    status:           SolverStatus per problem, (B,), int8: CONVERGED (feasible) / INFEASIBLE / MAX_ITERATIONS
                      (undecided: the phase-1 QP did not converge or the certificate stayed weak at every
                      ridge) / INVALID_INPUT (NaN/inf data)
    iterations:       interior-point iterations of the phase-1 solves, (B,), long
    """

    feasible: torch.Tensor
    z: torch.Tensor
    violation: torch.Tensor
    certified_radius: torch.Tensor
    status: torch.Tensor
    iterations: torch.Tensor


# ------------------------------------------------------------------------------------------------ validation
def _batched(x, name: str, B: int, tail: tuple, dtype, device) -> torch.Tensor:
    """Expand ``x`` of shape ``tail`` or ``(B, *tail)`` to ``(B, *tail)`` (explicitly), checking shape and dtype."""
    if not isinstance(x, torch.Tensor):
        raise InputTypeError(f"{name}: expected a torch.Tensor, got {type(x).__name__}")
    if x.dtype != dtype:
        raise InputTypeError(f"{name}: expected dtype {dtype} (the dtype of p), got {x.dtype}")
    if x.device != device:
        raise InputValueError(f"{name}: expected device {device} (the device of p), got {x.device}")
    if tuple(x.shape) == tail:
        return x.unsqueeze(0).expand(B, *tail)
    if tuple(x.shape) == (B, *tail):
        return x
    want = ", ".join(str(s) for s in tail)
    raise ShapeError(f"{name}: expected shape ({B}, {want}) or ({want}), got {tuple(x.shape)}")


def _rows(G, name: str, B: int, nz: int, dtype, device) -> int:
    if G is None:
        return 0
    if not isinstance(G, torch.Tensor):
        raise InputTypeError(f"{name}: expected a torch.Tensor, got {type(G).__name__}")
    if G.dim() not in (2, 3) or G.shape[-1] != nz:
        raise ShapeError(f"{name}: expected shape ({B}, rows, {nz}) or (rows, {nz}), got {tuple(G.shape)}")
    return int(G.shape[-2])


def _prepare(Q, p, G, h, A, b, ridge, qpth: bool = True):
    """Validated, explicitly batched, symmetrised (Q, p, G, h, A, b) and a per-problem finite-data mask."""
    if not isinstance(p, torch.Tensor):
        raise InputTypeError(f"p: expected a torch.Tensor, got {type(p).__name__}")
    if p.dim() != 2:
        raise ShapeError(f"p: expected shape (B, nz), got {tuple(p.shape)}")
    if p.dtype not in QP_TOLERANCES:
        raise InputTypeError(f"p: expected float32 or float64, got {p.dtype}")
    if (G is None) != (h is None):
        raise InputValueError("G, h: give both or neither")
    if (A is None) != (b is None):
        raise InputValueError("A, b: give both or neither")
    B, nz = p.shape
    dt, dev = p.dtype, p.device
    Q = _batched(Q, "Q", B, (nz, nz), dt, dev)
    nineq = _rows(G, "G", B, nz, dt, dev)
    neq = _rows(A, "A", B, nz, dt, dev)
    if qpth and neq > nz:
        raise ShapeError(f"A: expected at most nz = {nz} rows (qpth needs full row rank), got {neq}")
    G = _batched(G, "G", B, (nineq, nz), dt, dev) if nineq else p.new_zeros(B, 0, nz)
    h = _batched(h, "h", B, (nineq,), dt, dev) if nineq else p.new_zeros(B, 0)
    A = _batched(A, "A", B, (neq, nz), dt, dev) if neq else p.new_zeros(B, 0, nz)
    b = _batched(b, "b", B, (neq,), dt, dev) if neq else p.new_zeros(B, 0)
    if not isinstance(ridge, (int, float)) or isinstance(ridge, bool) or not ridge >= 0:
        raise InputValueError(f"ridge: expected a non-negative number, got {ridge!r}")
    Q = 0.5 * (Q + Q.transpose(1, 2))
    if ridge:
        Q = Q + ridge * torch.eye(nz, dtype=dt, device=dev)
    finite = torch.ones(B, dtype=torch.bool, device=dev)
    for t in (Q, p, G, h, A, b):
        if t.shape[1]:
            finite &= torch.isfinite(t.detach()).flatten(1).all(1)
    return Q, p, G, h, A, b, finite


def _well_posed(Q: torch.Tensor, A: torch.Tensor, finite: torch.Tensor) -> torch.Tensor:
    """Q positive definite (Cholesky succeeds) and A of full row rank, per problem (non-finite ones excluded)."""
    safe = finite.view(-1, 1, 1)
    eye = torch.eye(Q.shape[-1], dtype=Q.dtype, device=Q.device)
    _, info = torch.linalg.cholesky_ex(torch.where(safe, Q, eye))
    ok = finite & (info == 0)
    if A.shape[1]:
        s = torch.linalg.svdvals(torch.where(safe, A, torch.zeros((), dtype=A.dtype, device=A.device)))
        eps = torch.finfo(A.dtype).eps
        ok &= s[:, -1] > 10 * max(A.shape[1:]) * eps * s[:, 0]
    return ok


# ------------------------------------------------------------------------------------------------- the solve
def _step_length(v: torch.Tensor, dv: torch.Tensor) -> torch.Tensor:
    """Largest t with ``v + t dv >= 0`` per problem, (B,); inf when no component decreases.

    Replaces qpth 0.0.18's ``get_step`` during our calls. Its rule ``a = -v / dv; a[dv > 0] = max(1, a.max())``
    turns an exactly zero direction component into ``-inf`` (then NaN iterates: this happens whenever its first
    iterate is already optimal in z, e.g. an equality-constrained QP whose inequalities are inactive) and takes
    the max over the whole batch, so one diverging problem poisons every other problem's step.
    """
    neg = dv < 0
    ratio = torch.where(neg, -v / torch.where(neg, dv, -torch.ones((), dtype=dv.dtype, device=dv.device)),
                        torch.full((), float("inf"), dtype=v.dtype, device=v.device))
    return ratio.amin(1)


def _lu_no_raise(x: torch.Tensor):
    """qpth's ``lu_hack`` without the error on a singular matrix.

    qpth factorises the whole batch at once and answers a singular factor (a diverging, infeasible problem) by
    returning its best iterates so far for every problem. Without the error that problem's numbers just become
    non-finite, which the per-problem step length keeps to itself, and the others go on converging.
    """
    data, pivots, _ = torch.linalg.lu_factor_ex(x, pivot=not x.is_cuda)
    if x.is_cuda:                      # as qpth: no pivoting on CUDA, identity pivots
        n = x.size(-1)
        pivots = torch.arange(1, 1 + n, dtype=torch.int32, device=x.device).expand(*x.shape[:-2], n).contiguous()
    return data, pivots


@contextlib.contextmanager
def _per_problem_steps():
    """Swap qpth's step-length rule and LU wrapper for :func:`_step_length` and :func:`_lu_no_raise`.

    Module attributes of qpth are swapped for the duration of our call and restored after it: another thread
    calling qpth directly at the same moment would see them too (same results for well-posed problems).
    """
    originals = _pdipm.get_step, _pdipm.lu_hack
    _pdipm.get_step, _pdipm.lu_hack = _step_length, _lu_no_raise
    try:
        yield
    finally:
        _pdipm.get_step, _pdipm.lu_hack = originals


def _qpth_forward(Q, p, G, h, A, b, max_iters: int):
    """qpth's batched PDIPM, silenced. G has at least one row.

    Returns z (B, nz), nu (B, neq), lam (B, nineq), slack (B, nineq), qpth's KKT factors (for the backward; None
    if qpth failed before its first iterate) and the number of iterations it ran.
    """
    neq = A.shape[1]
    A_, b_ = (A, b) if neq else (torch.empty(0, dtype=Q.dtype, device=Q.device),) * 2
    out = io.StringIO()
    try:
        with contextlib.redirect_stdout(out), _per_problem_steps():
            factors = _pdipm.pre_factor_kkt(Q, G, A_)
            z, nu, lam, slack = _pdipm.forward(Q, p, G, h, A_, b_, *factors, 1e-12, 1, 3, max_iters)
    except RuntimeError:       # a singular factorisation that the screening did not foresee
        z = None
    iters = sum(1 for line in out.getvalue().splitlines() if line.startswith("iter:"))
    B, nz = p.shape
    if z is None:              # qpth gives up before its first iterate: report NaN, the checks say MAX_ITERATIONS
        factors = None
        z = p.new_full((B, nz), float("nan"))
        lam, slack, nu = p.new_zeros(B, G.shape[1]), p.new_ones(B, G.shape[1]), p.new_zeros(B, neq)
    if nu is None:
        nu = p.new_zeros(B, 0)
    return z, nu, lam, slack, factors, iters


class _QPFunction(torch.autograd.Function):
    """qpth's PDIPM forward; backward = ``qpth.qp.QPFunction.backward`` (implicit KKT differentiation), per problem.

    Outputs z (differentiable), nu and lam (not differentiable) and the iteration count.
    """

    @staticmethod
    def forward(ctx, Q, p, G, h, A, b, max_iters):
        z, nu, lam, slack, factors, iters = _qpth_forward(Q, p, G, h, A, b, max_iters)
        ctx.save_for_backward(z, G, A, lam, slack, nu)
        ctx.factors = factors
        ctx.mark_non_differentiable(nu, lam)
        return z, nu, lam, torch.full((p.shape[0],), iters, dtype=torch.long, device=p.device)

    @staticmethod
    def backward(ctx, dz, _dnu, _dlam, _diters):
        z, G, A, lam, slack, nu = ctx.saved_tensors
        if ctx.factors is None:    # the forward failed (NaN z): no gradient information
            return None, None, None, None, None, None, None
        Q_LU, S_LU, R = ctx.factors
        B, nineq = lam.shape
        neq = A.shape[1]
        d = lam.clamp(min=1e-8) / slack.clamp(min=1e-8)
        _pdipm.factor_kkt(S_LU, R, d)
        zeros = z.new_zeros(B, nineq)
        A_ = A if neq else torch.empty(0, dtype=z.dtype, device=z.device)
        ry = z.new_zeros(B, neq) if neq else torch.empty(0, dtype=z.dtype, device=z.device)
        dx, _, dlam, dnu = _pdipm.solve_kkt(Q_LU, d, G, A_, S_LU, dz, zeros, zeros, ry)

        def outer(u, v):
            return u.unsqueeze(2) * v.unsqueeze(1)

        dQ = 0.5 * (outer(dx, z) + outer(z, dx))
        dG = outer(dlam, z) + outer(lam, dx)
        dA = outer(dnu, z) + outer(nu, dx) if neq else torch.zeros_like(A)
        db = -dnu if neq else z.new_zeros(B, 0)
        return dQ, dx, dG, -dlam, dA, db, None


def _solve_batch(Q, p, G, h, A, b, max_iters: int):
    """Solve the (valid, dummy-filled) batch; G gets one dummy row ``0 z <= 1`` when empty (qpth needs rows)."""
    B, nz = p.shape
    dummy_row = G.shape[1] == 0
    if dummy_row:
        G = p.new_zeros(B, 1, nz)
        h = p.new_ones(B, 1)
    grad = torch.is_grad_enabled() and any(t.requires_grad for t in (Q, p, G, h, A, b))
    if grad:
        z, nu, lam, iters = _QPFunction.apply(Q, p, G, h, A, b, max_iters)
    else:
        with torch.no_grad():
            z, nu, lam, _, _, it = _qpth_forward(Q, p, G, h, A, b, max_iters)
        iters = torch.full((B,), it, dtype=torch.long, device=p.device)
    if dummy_row:
        lam = lam[:, :0]
    return z, nu, lam, iters


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


def _witness_and_certificate(Gn, hn, An, bn, z):
    """Largest unit-row violation at z, and the radius ``g / |e|`` excluded by the Farkas pair built from z."""
    mv = lambda M, v: (M @ v.unsqueeze(-1)).squeeze(-1)  # noqa: E731
    zero = z.new_zeros(())
    yG = (mv(Gn, z) - hn).clamp(min=0)
    yA = mv(An, z) - bn
    viol = torch.maximum(yG.amax(1) if yG.shape[1] else zero.expand(z.shape[0]),
                         yA.abs().amax(1) if yA.shape[1] else zero.expand(z.shape[0]))
    e = mv(Gn.transpose(1, 2), yG) + mv(An.transpose(1, 2), yA)
    g = -((hn * yG).sum(1) + (bn * yA).sum(1))
    radius = torch.where(g > 0, g / e.norm(dim=1), zero)      # g / 0 = inf: an exact certificate
    return viol, radius


# ------------------------------------------------------------------------------------------ method="admm"
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
    * neither: solved once more (interior point first, with four times its iterations and twice ADMM's), then
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
                              method="ipm", **kw)
        viol, _ = _witness_and_certificate(G_, h_, A_, b_, res.z)
        feas = fin & (viol <= tol * sc)
        lam, nu = res.lam.clamp_min(0), res.nu
        e = mv(G_.transpose(1, 2), lam) + mv(A_.transpose(1, 2), nu)
        g = -((h_ * lam).sum(1) + (b_ * nu).sum(1))
        cert = fin & ~feas & (res.status == _INFEASIBLE) & (g > 0)
        radius = torch.where(cert, g / e.norm(dim=1), zero)
        status = torch.where(feas, _CONVERGED, torch.where(cert, _INFEASIBLE, _MAX_ITERATIONS))
        return feas, res.z, viol, radius, status, res.iterations.long()

    with torch.no_grad():
        feas, z, viol, radius, status, iters = decide(Gn, hn, An, bn, scale, finite)
        open_ = finite & (status == _MAX_ITERATIONS)
        if bool(open_.any()):                                     # host sync: once
            j = open_.nonzero().squeeze(1)
            sel = lambda t: t.index_select(0, j)  # noqa: E731
            more = decide(sel(Gn), sel(hn), sel(An), sel(bn), sel(scale), sel(finite), ipm_iters=200,
                          max_iters=2 * qp_tolerances(f64).max_iters)
            feas, z, viol, radius, status = (t.index_copy(0, j, m) for t, m in
                                              zip((feas, z, viol, radius, status), more[:5]))
            iters = iters.index_copy(0, j, sel(iters) + more[5])
        status = torch.where(finite, status, _INVALID).to(torch.int8)
    return FeasibilityResult(feasible=feas, z=z.to(dt), violation=viol.to(dt), certified_radius=radius.to(dt),
                             status=status, iterations=iters)
