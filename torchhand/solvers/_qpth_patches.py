"""qpth run per problem: its step-length rule and LU factorisation swapped during our calls (a NaN-free step per
problem, no batch-wide stop on one singular factor), its printing captured, and the differentiable batch solve
(see :mod:`._qpth`'s docstring)."""

from __future__ import annotations

import contextlib
import io

import torch

from ..errors import MissingDependencyError

QPTH_HINT = ("the qpth backend needs the optional extra qpth, which keeps NumPy < 2: pip install 'torchhand[qpth]' "
             "(the default QP path, backend=\"kernel\" / method=\"admm\", needs nothing more)")


def _pdipm():
    """qpth's batched PDIPM module; a MissingDependencyError with the install line when qpth is not installed."""
    try:
        from qpth.solvers.pdipm import batch
    except ImportError as exc:
        raise MissingDependencyError(f"{QPTH_HINT} ({exc})") from None
    return batch


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
    pdipm = _pdipm()
    originals = pdipm.get_step, pdipm.lu_hack
    pdipm.get_step, pdipm.lu_hack = _step_length, _lu_no_raise
    try:
        yield
    finally:
        pdipm.get_step, pdipm.lu_hack = originals


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
            pdipm = _pdipm()
            factors = pdipm.pre_factor_kkt(Q, G, A_)
            z, nu, lam, slack = pdipm.forward(Q, p, G, h, A_, b_, *factors, 1e-12, 1, 3, max_iters)
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
        pdipm = _pdipm()
        pdipm.factor_kkt(S_LU, R, d)
        zeros = z.new_zeros(B, nineq)
        A_ = A if neq else torch.empty(0, dtype=z.dtype, device=z.device)
        ry = z.new_zeros(B, neq) if neq else torch.empty(0, dtype=z.dtype, device=z.device)
        dx, _, dlam, dnu = pdipm.solve_kkt(Q_LU, d, G, A_, S_LU, dz, zeros, zeros, ry)

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
