"""The solver front doors (torchhand.solvers.qp.solve, torchhand.solvers.lcp.solve) return exactly what the
backend they name returns, and refuse unknown backends and options with a line naming the choices."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from torchhand.errors import InputValueError
from torchhand.kernels.convex_qp import solve_convex_qp
from torchhand.solvers import lcp, qp
from torchhand.solvers._dense import solve_qp_dense
from torchhand.solvers._lemke import lemke
from torchhand.solvers._qpth import lp_feasible, solve_qp
from torchhand.solvers.lcp import random_lcp, solve_lcp

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from conftest import requires_qpth  # noqa: E402


def _qps(B=5, nz=6, nineq=8, neq=2, seed=0):
    g = torch.Generator().manual_seed(seed)
    R = torch.randn(B, nz, nz, generator=g, dtype=torch.float64)
    Q = R @ R.transpose(1, 2) + 0.1 * torch.eye(nz, dtype=torch.float64)
    p = torch.randn(B, nz, generator=g, dtype=torch.float64)
    G = torch.randn(B, nineq, nz, generator=g, dtype=torch.float64)
    h = torch.rand(B, nineq, generator=g, dtype=torch.float64) + 0.1
    A = torch.randn(B, neq, nz, generator=g, dtype=torch.float64)
    b = torch.zeros(B, neq, dtype=torch.float64)
    return Q, p, G, h, A, b


def _fields(r):
    if dataclasses.is_dataclass(r):
        return {f.name: getattr(r, f.name) for f in dataclasses.fields(r)}
    return r._asdict()


def _same(a, b):
    fa, fb = _fields(a), _fields(b)
    assert fa.keys() == fb.keys()
    for k in fa:
        x, y = fa[k], fb[k]
        if isinstance(x, torch.Tensor):
            assert torch.equal(x, y), k
        elif isinstance(x, np.ndarray):
            assert np.array_equal(x, y), k
        else:
            assert x == y, k


@pytest.mark.parametrize("backend, fn, options", [
    ("kernel", solve_convex_qp, {}),
    ("kernel", solve_convex_qp, {"method": "admm", "tol": 1e-7}),
    ("dense", solve_qp_dense, {}),
    pytest.param("qpth", solve_qp, {"max_iters": 30}, marks=requires_qpth),
])
def test_qp_front_door_is_its_backend(backend, fn, options):
    for seed in range(3):
        data = _qps(seed=seed)
        ours = qp.solve(*data, backend=backend, **options)
        _same(ours, fn(*data, **options))
        assert type(ours).__name__ in ("ConvexQPResult", "QPResult")
        assert int((ours.status == 0).sum()) >= 1            # the problems are solvable: something converged


def test_qp_front_door_without_inequalities_or_equalities():
    Q, p, G, h, A, b = _qps(seed=4)
    _same(qp.solve(Q, p, backend="kernel"), solve_convex_qp(Q, p))
    _same(qp.solve(Q, p, G, h, backend="dense"), solve_qp_dense(Q, p, G, h))


@pytest.mark.parametrize("method", [pytest.param("qpth", marks=requires_qpth), "admm"])
def test_lp_feasible_front_door(method):
    _, _, G, h, A, b = _qps(seed=5)
    _same(qp.lp_feasible(G, h, A, b, method=method), lp_feasible(G, h, A, b, method=method))


def test_lp_feasible_front_door_defaults_to_the_kernel():
    """The default feasibility path needs no optional extra: the front door's default method is "admm"."""
    _, _, G, h, A, b = _qps(seed=5)
    _same(qp.lp_feasible(G, h, A, b), lp_feasible(G, h, A, b, method="admm"))


def test_qpth_backend_without_qpth_is_one_line(monkeypatch):
    """Asking for qpth where it is not installed: one line with the install command, for solve and lp_feasible."""
    from torchhand.errors import MissingDependencyError
    for name in ("qpth", "qpth.solvers", "qpth.solvers.pdipm"):
        monkeypatch.setitem(sys.modules, name, None)      # import raises ImportError, as when not installed
    Q, p, G, h, A, b = _qps(seed=5)
    for call in (lambda: qp.solve(Q, p, G, h, backend="qpth"), lambda: qp.lp_feasible(G, h, A, b, method="qpth")):
        with pytest.raises(MissingDependencyError) as err:
            call()
        msg = str(err.value)
        assert "\n" not in msg and "pip install 'torchhand[qpth]'" in msg


def test_lcp_front_door_is_its_backend():
    g = torch.Generator().manual_seed(1)
    prob = random_lcp(6, 12, generator=g)
    _same(lcp.solve(prob.M, prob.q, backend="pgs", max_iters=300), solve_lcp(prob.M, prob.q, max_iters=300))
    M, q = prob.M[0].numpy(), prob.q[0].numpy()
    _same(lcp.solve(M, q, backend="lemke"), lemke(M, q))
    _same(lcp.solve(M, q, backend="lemke", max_pivots=50, tol=1e-10), lemke(M, q, max_pivots=50, tol=1e-10))


@pytest.mark.parametrize("call, words", [
    (lambda d: qp.solve(*d, backend="osqp"), ["'kernel'", "'dense'", "'qpth'", "'osqp'"]),
    (lambda d: qp.solve(*d, backend="dense", rho=0.1), ["rho", "warm_start"]),
    (lambda d: qp.lp_feasible(d[2], d[3], solver="x"), ["solver", "method"]),
    (lambda d: lcp.solve(d[0], d[1], backend="lemkee"), ["'pgs'", "'lemke'"]),
    (lambda d: lcp.solve(d[0], d[1], backend="pgs", pivots=3), ["pivots", "lemke_max_n"]),
])
def test_unknown_backends_and_options_are_named(call, words):
    with pytest.raises(InputValueError) as err:
        call(_qps())
    message = str(err.value)
    assert "\n" not in message
    for w in words:
        assert w in message, (w, message)
