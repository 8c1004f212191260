"""The qpth adapter's result types, tolerances and input preparation (shapes checked, batch made explicit, problems
screened), and the feasibility witness and certificate of its phase-1 LP; shared by :mod:`._qpth` and
:mod:`._qpth_admm`."""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType

import torch

from ..errors import InputTypeError, InputValueError, ShapeError
from ..kernels.status import SolverStatus


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
