"""The dense single-problem QP path (torchhand/dense_qp.py: ``solve_qp_dense``, ``solve_dense``).

References nobody here wrote: Clarabel on the Liu 2009 planner's own window QPs (objective within 1e-7 relative,
same solved / infeasible classification), a rank-deficient pinch whose equality rows must be reduced, an
out-of-range pinch twist (the range test's certificate), and the batched torch kernel's statuses on the same
problems (the Maros-Meszaros QPs are in tests/kernels/test_convex_qp.py, run by both solvers). Invariants (KKT residuals, Farkas certificates, no NaN) are measured here from the returned numbers.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from torchhand.solvers._dense import solve_dense, solve_qp_dense
from torchhand.errors import InputValueError, ShapeError
from torchhand.kernels.convex_qp import qp_tolerances, solve_convex_qp
from torchhand.kernels.force_plan import assemble_window_qp
from torchhand.kernels.status import SolverStatus

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "kernels"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_force_plan import window_problems  # noqa: E402
from test_qp import clarabel_qp  # noqa: E402

CONVERGED, INFEASIBLE, MAX_ITERATIONS, INVALID = (int(SolverStatus.CONVERGED), int(SolverStatus.INFEASIBLE),
                                                  int(SolverStatus.MAX_ITERATIONS), int(SolverStatus.INVALID_INPUT))
NAMES = ("Q", "p", "G", "h", "A", "b")

pytestmark = pytest.mark.usefixtures("one_intra_op_thread")


def _args(qp):
    return [getattr(qp, k) for k in NAMES]


@pytest.mark.parametrize("kind,table,kw", [("grasp", False, {}), ("grasp", True, {}), ("pinch", False, {}),
                                           ("pinch_twist", False, {}), ("weak", False, {}),
                                           ("grasp", True, dict(hand_slots=5, table_slots=8))])
def test_window_qps_match_clarabel(kind, table, kw):
    pytest.importorskip("clarabel")
    gen = torch.Generator().manual_seed(11)
    qp = assemble_window_qp(**window_problems(5, gen, kind=kind, table=table, **kw))
    res = solve_qp_dense(*_args(qp))
    kernel = solve_convex_qp(*_args(qp), method="ipm")
    assert res.status.tolist() == kernel.status.tolist()
    for t in res:
        assert not bool(torch.isnan(t.double()).any())
    for i in range(qp.p.shape[0]):
        data = [getattr(qp, k)[i].numpy() for k in NAMES]
        _, obj, st = clarabel_qp(*data)
        if st == "PrimalInfeasible":
            assert int(res.status[i]) == INFEASIBLE
            lam, nu = res.lam[i], res.nu[i]
            e = qp.G[i].T @ lam + qp.A[i].T @ nu
            g = -(qp.h[i] @ lam + qp.b[i] @ nu)
            assert float(g) > 0 and float(lam.min()) >= 0 and float(e.abs().max()) <= 1e-3 * float(g)
            continue
        assert st == "Solved" and int(res.status[i]) == CONVERGED
        assert float(res.objective[i]) == pytest.approx(obj, rel=1e-7, abs=1e-7)
        slack = qp.h[i] - qp.G[i] @ res.z[i]
        assert float(torch.minimum(res.lam[i], slack).abs().max()) <= 1e-8 * (1 + float(qp.h[i].abs().max()))
        assert float(res.residual_primal[i]) <= 1e-8 * (1 + float(qp.b[i].abs().max()))
        assert float(res.residual_dual[i]) <= 1e-7 * (1 + float(qp.p[i].abs().max()))


def test_rank_deficient_pinch_is_reduced():
    """A two-finger pinch cannot make torque about the line through its contacts: A has rank < 6 per frame; the
    dense path reduces the rows (same rank test as the kernel) and solves, or certifies the out-of-range twist."""
    gen = torch.Generator().manual_seed(3)
    qp = assemble_window_qp(**window_problems(3, gen, kind="pinch"))
    A = qp.A[0].numpy()
    assert np.linalg.matrix_rank(A) < A.shape[0]
    t = qp_tolerances(torch.float64)
    sol = solve_dense(*(getattr(qp, k)[0].numpy() for k in NAMES), tol=t.tol, eps_inf=t.eps_inf, delta=t.delta,
                      rank_tol=t.rank, range_tol=t.range)
    _, obj, st = clarabel_qp(*(getattr(qp, k)[0].numpy() for k in NAMES))
    assert st == "Solved" and sol.status == CONVERGED
    Q, p = qp.Q[0].numpy(), qp.p[0].numpy()
    assert 0.5 * sol.z @ Q @ sol.z + p @ sol.z == pytest.approx(obj, rel=1e-7, abs=1e-7)
    assert np.abs(A @ sol.z - qp.b[0].numpy()).max() < 1e-9
    twist = assemble_window_qp(**window_problems(2, gen, kind="pinch_twist"))
    res = solve_qp_dense(*_args(twist))
    assert res.status.tolist() == [INFEASIBLE, INFEASIBLE]
    for i in range(2):                                           # the range test's certificate: A^T nu = 0, b^T nu < 0
        nu = res.nu[i]
        assert float((twist.A[i].T @ nu).abs().max()) < 1e-9 and float(twist.b[i] @ nu) < 0


def test_small_cases_statuses_and_shapes():
    f64 = torch.float64
    # rank-deficient equalities with b in range / out of range, B = 2 (the kernel's test case)
    A = torch.tensor([[[1.0, 1.0, 0.0], [2.0, 2.0, 0.0], [0.0, 0.0, 1.0]]], dtype=f64).expand(2, 3, 3).contiguous()
    b = torch.tensor([[1.0, 2.0, 0.5], [1.0, 2.5, 0.5]], dtype=f64)
    res = solve_qp_dense(torch.eye(3, dtype=f64).expand(2, 3, 3).contiguous(), torch.zeros(2, 3, dtype=f64),
                         A=A, b=b)
    assert res.status.tolist() == [CONVERGED, INFEASIBLE]
    torch.testing.assert_close(res.z[0], torch.tensor([0.5, 0.5, 0.5], dtype=f64), rtol=0, atol=1e-9)
    # an infeasible box (z <= -1 and z >= 1): a Farkas certificate; NaN data: INVALID_INPUT, never NaN out
    G = torch.tensor([[[1.0], [-1.0]]], dtype=f64).expand(3, 2, 1).contiguous()
    h = torch.tensor([[-1.0, -1.0], [1.0, 1.0], [float("nan"), 1.0]], dtype=f64)
    res = solve_qp_dense(torch.ones(3, 1, 1, dtype=f64), torch.tensor([[0.0], [-3.0], [0.0]], dtype=f64), G, h)
    assert res.status.tolist() == [INFEASIBLE, CONVERGED, INVALID]
    assert float(res.z[1, 0]) == pytest.approx(1.0, abs=1e-9)                 # clipped at the bound
    lam = res.lam[0]
    assert float(lam.min()) >= 0 and float(h[0] @ lam) < 0 and float((G[0].T @ lam).abs().max()) < 1e-5
    assert torch.isfinite(res.z).all() and torch.isfinite(res.lam).all() and torch.isfinite(res.nu).all()
    # float32 in, float32 out; a warm start is accepted (and not needed)
    res32 = solve_qp_dense(torch.eye(3).unsqueeze(0), torch.ones(1, 3), A=A[:1].float(), b=b[:1].float(),
                           warm_start=(torch.zeros(1, 3), None, None))
    assert res32.z.dtype == torch.float32 and res32.status.tolist() == [CONVERGED]
    with pytest.raises(ShapeError, match="Q"):
        solve_qp_dense(torch.eye(3), torch.ones(1, 3))
    with pytest.raises(InputValueError, match="warm_start"):
        solve_qp_dense(torch.eye(3).unsqueeze(0), torch.ones(1, 3), warm_start=torch.zeros(1, 3))


def test_warm_start_from_a_neighbouring_window():
    """The planner's use: the previous problem's solution as a warm start of a nearby one (here the same windows
    with the previous-force term shifted). The answer still matches Clarabel; the work does not grow."""
    pytest.importorskip("clarabel")
    gen = torch.Generator().manual_seed(5)
    kw = window_problems(4, gen, table=True)
    qp0 = assemble_window_qp(**kw)
    kw1 = dict(kw, f_prev=kw["f_prev"] * 1.05 + 0.01)
    qp1 = assemble_window_qp(**kw1)
    prev = solve_qp_dense(*_args(qp0))
    cold = solve_qp_dense(*_args(qp1))
    warm = solve_qp_dense(*_args(qp1), warm_start=(prev.z, prev.lam, prev.nu))
    assert warm.status.tolist() == cold.status.tolist()
    assert int(warm.iterations.sum()) <= int(cold.iterations.sum())
    for i in range(4):
        _, obj, st = clarabel_qp(*(getattr(qp1, k)[i].numpy() for k in NAMES))
        if st == "Solved":
            assert int(warm.status[i]) == CONVERGED
            assert float(warm.objective[i]) == pytest.approx(obj, rel=1e-7, abs=1e-7)
