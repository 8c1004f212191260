"""The front door for convex QPs ``min 1/2 z^T Q z + p^T z  s.t.  G z <= h, A z = b``, batched over B problems.

The caller names the backend; its options are passed through unchanged and its own result type comes back:

=========  ==========================================================  =========================  ===============
backend    what it is                                                  options (keyword-only)     result
=========  ==========================================================  =========================  ===============
"kernel"   :func:`torchhand.kernels.convex_qp.solve_convex_qp`:         warm_start, tol,           ConvexQPResult
           the batched ADMM / interior-point kernel (CPU or CUDA)      max_iters, check_every,
                                                                       rho, sigma, alpha, polish,
                                                                       reduce, fallback_after,
                                                                       ipm_iters, method
"dense"    :func:`torchhand.solvers._dense.solve_qp_dense`: one        warm_start, tol,           ConvexQPResult
           problem at a time, NumPy / LAPACK, interior point and       ipm_iters, max_iters
           polish (small problems on the CPU)
"qpth"     :func:`torchhand.solvers._qpth.solve_qp`: the qpth          ridge, tol, max_iters,     QPResult
           adapter (differentiable; per-problem screening and          check_infeasible, method
           residual checks); the optional extra ``torchhand[qpth]``
           (qpth declares NumPy < 2): without it, one line saying so
=========  ==========================================================  =========================  ===============

Shapes (all backends): ``Q`` (B, nz, nz), ``p`` (B, nz), ``G`` (B, nineq, nz), ``h`` (B, nineq), ``A`` (B, neq, nz),
``b`` (B, neq); ``G, h`` and ``A, b`` may be None together. The "qpth" backend also accepts shared (unbatched)
``Q, G, h, A, b`` (see its docstring). :func:`lp_feasible` decides whether ``G z <= h, A z = b`` has a point.
"""

from __future__ import annotations

import inspect
from typing import Callable

from ..errors import InputValueError

__all__ = ["BACKENDS", "solve", "lp_feasible"]

BACKENDS = ("kernel", "dense", "qpth")


def _backend(name) -> Callable:
    if name == "kernel":
        from ..kernels.convex_qp import solve_convex_qp

        return solve_convex_qp
    if name == "dense":
        from ._dense import solve_qp_dense

        return solve_qp_dense
    if name == "qpth":
        from ._qpth import solve_qp

        return solve_qp
    raise InputValueError(f"backend: expected one of {', '.join(map(repr, BACKENDS))}, got {name!r}")


def check_options(fn: Callable, where: str, options: dict) -> None:
    """An InputValueError naming the unknown keyword options of ``fn`` (and the known ones)."""
    params = inspect.signature(fn).parameters
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return                                          # a backend that takes any keyword checks its own
    known = [n for n, p in params.items() if p.kind is inspect.Parameter.KEYWORD_ONLY]
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise InputValueError(f"{where}: unknown option(s) {', '.join(unknown)}; its options: {', '.join(known)}")


def solve(Q, p, G=None, h=None, A=None, b=None, *, backend: str, **options):
    """Solve B convex QPs with the named backend (see the module docstring for backends, options and results).

    Raises:
        InputValueError: an unknown backend or option (the message names the choices); the backend's own errors
            for its inputs.
    """
    fn = _backend(backend)
    check_options(fn, f"backend {backend!r}", options)
    return fn(Q, p, G, h, A, b, **options)


def lp_feasible(G, h, A=None, b=None, **options):
    """Is ``{z : G z <= h, A z = b}`` non-empty, per problem? :func:`torchhand.solvers._qpth.lp_feasible` (options
    ``ridge``, ``tol``, ``max_iters``, ``method`` = "admm", the default: the project's convex-QP kernel and its rule,
    or "qpth": the phase-1 QP through qpth, the optional extra ``torchhand[qpth]``)."""
    options.setdefault("method", "admm")
    from ._qpth import lp_feasible as _lp_feasible

    check_options(_lp_feasible, "lp_feasible", options)
    return _lp_feasible(G, h, A, b, **options)
