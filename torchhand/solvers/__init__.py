"""Solver front doors over :mod:`torchhand.kernels`: one per kind of problem, the backend named by the caller.

Modules
    ``qp``      :func:`torchhand.solvers.qp.solve`: convex QPs (backends ``"kernel"``, ``"dense"``, ``"qpth"``)
                and LP feasibility
    ``lcp``     :func:`torchhand.solvers.lcp.solve`: LCPs (backends ``"pgs"``, ``"lemke"``)
    ``_qpth``   the qpth adapter; ``_dense`` the single-problem dense QP solver; ``_lemke`` Lemke's method

docs/architecture.md.
"""
