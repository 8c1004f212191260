"""Batched convex QP kernel (kernels/convex_qp.py): ADMM with polish, equality reduction with a range test.

References nobody here wrote: Clarabel (random QPs and the planner's own window QPs), the Maros-Meszaros QPs with
their reference objectives in ``../shared/data/qp/maros_meszaros`` (skipped when absent); invariants (KKT
residuals, Farkas certificates) checked here from the returned numbers.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from torchhand.kernels.convex_qp import (ConvexQPResult, qp_tolerances, reduce_equalities, solve_convex_qp)
from torchhand.kernels.force_plan import assemble_window_qp
from torchhand.kernels.status import SolverStatus

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "torchhand"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from conftest import shared_path  # noqa: E402
from test_force_plan import window_problems  # noqa: E402
from test_qp import clarabel_qp, load_maros_meszaros, random_qps  # noqa: E402

CONVERGED, INFEASIBLE, MAX_ITERATIONS, INVALID, UNBOUNDED = (
    int(SolverStatus.CONVERGED), int(SolverStatus.INFEASIBLE), int(SolverStatus.MAX_ITERATIONS),
    int(SolverStatus.INVALID_INPUT), int(SolverStatus.UNBOUNDED))
OBJ_RTOL = {torch.float32: 1e-4, torch.float64: 1e-7}
Z_ATOL = {torch.float32: 1e-2, torch.float64: 1e-5}
NAMES = ("Q", "p", "G", "h", "A", "b")


pytestmark = pytest.mark.usefixtures("one_intra_op_thread")


def _args(prob: dict, dtype=None, device=None):
    return [prob.get(k).to(dtype=dtype, device=device) if prob.get(k) is not None else None for k in NAMES]


def _window_args(qp, dtype=None):
    return [getattr(qp, k).to(dtype=dtype) for k in NAMES]


def _kkt(res, Q, p, G, h, A, b):
    """Stationarity, primal feasibility and complementarity measured here, (B,) each."""
    mv = lambda M, v: (M @ v.unsqueeze(-1)).squeeze(-1)  # noqa: E731
    z, lam, nu = res.z, res.lam, res.nu
    stat = (mv(Q, z) + p + mv(G.transpose(1, 2), lam) + mv(A.transpose(1, 2), nu)).abs().amax(1)
    slack = h - mv(G, z)
    prim = torch.maximum((-slack).clamp_min(0).amax(1), (mv(A, z) - b).abs().amax(1))
    comp = (lam * slack).abs().amax(1)
    return stat, prim, comp


# ---------------------------------------------------------------------------------------------------- basics
@pytest.mark.parametrize("B", [1, 7])
def test_smoke_shapes(B, dtype, device, gen):
    prob = random_qps(B, 6, 10, 2, gen, dtype=dtype, device=device)
    res = solve_convex_qp(*_args(prob))
    assert isinstance(res, ConvexQPResult)
    assert res.z.shape == (B, 6) and res.z.dtype == dtype and res.z.device.type == device
    assert res.lam.shape == (B, 10) and res.nu.shape == (B, 2)
    for t in (res.objective, res.status, res.iterations, res.residual_primal, res.residual_dual):
        assert t.shape == (B,)
    assert res.status.dtype == torch.int8 and res.status.tolist() == [CONVERGED] * B
    assert bool((res.lam >= 0).all()) and bool((res.iterations > 0).all())
    tol = qp_tolerances(dtype).tol
    stat, prim, comp = _kkt(res, *_args(prob))
    scale = 1 + prob["p"].abs().amax(1) + prob["h"].abs().amax(1)
    assert bool((stat <= 100 * tol * scale).all()) and bool((prim <= 100 * tol * scale).all())
    assert bool((comp <= 100 * tol * scale).all())


def test_bad_input_raises(gen):
    Q, p, G, h, A, b = _args(random_qps(2, 3, 4, 1, gen))
    with pytest.raises(ValueError, match=r"p must be a tensor of shape \(B, nz\)"):
        solve_convex_qp(Q, p[0])
    with pytest.raises(ValueError, match=r"Q must have shape \(2, 3, 3\), got \(3, 3\)"):
        solve_convex_qp(Q[0], p)
    with pytest.raises(ValueError, match="h must have shape"):
        solve_convex_qp(Q, p, G, h[:, :3])
    with pytest.raises(ValueError, match="G must be a tensor"):
        solve_convex_qp(Q, p, G[0], h)
    with pytest.raises(ValueError, match="give both G and h"):
        solve_convex_qp(Q, p, G)
    with pytest.raises(ValueError, match="A must have dtype"):
        solve_convex_qp(Q, p, G, h, A.float(), b)
    with pytest.raises(ValueError, match="dtype must be float32 or float64"):
        solve_convex_qp(Q.half(), p.half())
    with pytest.raises(ValueError, match="check_every"):
        solve_convex_qp(Q, p, check_every=0)
    with pytest.raises(ValueError, match="warm_start z"):
        solve_convex_qp(Q, p, G, h, warm_start=(p[:, :2], None, None))
    with pytest.raises(ValueError, match="reduce_equalities: b must have shape"):
        reduce_equalities(A, b[:, :0])


def test_invalid_data_is_a_status_not_a_nan(gen):
    prob = random_qps(4, 5, 8, 2, gen)
    prob["Q"][0, 1, 1] = float("nan")
    prob["h"][2, 3] = float("inf")
    res = solve_convex_qp(*_args(prob))
    assert res.status.tolist() == [INVALID, CONVERGED, INVALID, CONVERGED]
    for t in res:
        assert not bool(torch.isnan(t.double()).any())
    alone = solve_convex_qp(*(t[[1, 3]] for t in _args(prob)))
    torch.testing.assert_close(res.z[[1, 3]], alone.z, rtol=1e-9, atol=1e-10)


# ------------------------------------------------------------------------------------- agreement with Clarabel
def test_random_qps_against_clarabel(dtype, gen):
    pytest.importorskip("clarabel")
    for nz, nineq, neq in [(3, 4, 0), (8, 14, 3), (20, 30, 6)]:
        prob = random_qps(7, nz, nineq, neq, gen, infeasible=[2])
        res = solve_convex_qp(*_args(prob, dtype))
        for i in range(7):
            x, obj, st = clarabel_qp(*(prob[k][i].numpy() if k in prob else None for k in NAMES))
            if st == "PrimalInfeasible":
                assert int(res.status[i]) == INFEASIBLE
                continue
            assert st == "Solved" and int(res.status[i]) == CONVERGED, (nz, i, res.status)
            assert float(res.objective[i]) == pytest.approx(obj, rel=OBJ_RTOL[dtype], abs=OBJ_RTOL[dtype])
            np.testing.assert_allclose(res.z[i].double().numpy(), x, atol=Z_ATOL[dtype] * (1 + np.abs(x).max()))


def test_psd_and_lp_like_problems():
    """Q = 0 (an LP over a box) and a rank-one Q: PSD objectives are solved, not refused."""
    f64 = torch.float64
    G = torch.cat([torch.eye(3, dtype=f64), -torch.eye(3, dtype=f64)]).expand(2, 6, 3)
    h = torch.cat([torch.ones(3, dtype=f64), torch.zeros(3, dtype=f64)]).expand(2, 6)
    Q = torch.stack([torch.zeros(3, 3, dtype=f64), torch.ones(3, 3, dtype=f64)])
    p = torch.tensor([[1.0, -2.0, 0.5], [-1.0, -1.0, -1.0]], dtype=f64)
    res = solve_convex_qp(Q, p, G.contiguous(), h.contiguous())
    assert res.status.tolist() == [CONVERGED, CONVERGED]
    assert float(res.objective[0]) == pytest.approx(-2.0, abs=1e-8)              # z = (0, 1, 0)
    assert float(res.objective[1]) == pytest.approx(-0.5, abs=1e-8)              # sum z = 1 on the box
    # Unbounded: min -z_0 with z_0 free.
    res = solve_convex_qp(torch.zeros(1, 2, 2, dtype=f64), torch.tensor([[-1.0, 0.0]], dtype=f64),
                          torch.tensor([[[0.0, 1.0]]], dtype=f64), torch.tensor([[1.0]], dtype=f64))
    assert res.status.tolist() == [UNBOUNDED] and bool(torch.isinf(res.objective).all())


def _window_batch(gen, kinds, B=3, **kw):
    out = []
    for kind, table in kinds:
        out.append(assemble_window_qp(**window_problems(B, gen, kind=kind, table=table, **kw)))
    return out


@pytest.mark.parametrize("method", ["ipm", "admm"])
def test_window_qps_against_clarabel(gen, method):
    """The planner's own problems: box grasps (3 hand contacts, +- 4 table contacts, n = 6), a rank-deficient
    pinch, an out-of-range pinch twist, a single contact and force limits far below the weight. Both solver
    orders (interior point first, ADMM first) are checked; the first grasp batch holds a window at the edge of
    feasibility (ADMM alone stalls there, its interior-point fallback solves it)."""
    pytest.importorskip("clarabel")
    kinds = [("grasp", False), ("grasp", True), ("pinch", False), ("pinch_twist", False), ("single", False),
             ("weak", False)]
    n_solved = n_infeasible = 0
    for qp in _window_batch(gen, kinds):
        res = solve_convex_qp(*_window_args(qp), method=method)
        for i in range(qp.p.shape[0]):
            x, obj, st = clarabel_qp(*(getattr(qp, k)[i].numpy() for k in NAMES))
            if st == "PrimalInfeasible":
                n_infeasible += 1
                assert int(res.status[i]) == INFEASIBLE
                lam, nu = res.lam[i], res.nu[i]                           # the certificate holds
                e = qp.G[i].T @ lam + qp.A[i].T @ nu
                g = -(qp.h[i] @ lam + qp.b[i] @ nu)
                assert float(g) > 0 and float(lam.min()) >= 0 and float(e.abs().max()) <= 1e-3 * float(g)
                continue
            n_solved += 1
            assert st == "Solved" and int(res.status[i]) == CONVERGED
            assert float(res.objective[i]) == pytest.approx(obj, rel=1e-7, abs=1e-7)
            # CONVERGED includes complementarity: lam^T (h - G z) ~ 0 and, row by row, lam_i = 0 or slack_i = 0
            slack = qp.h[i] - qp.G[i] @ res.z[i]
            scale = 1 + abs(float(res.objective[i])) + float((qp.p[i] * res.z[i]).abs().sum())
            assert abs(float(res.lam[i] @ slack)) <= 1e-9 * scale
            assert float(torch.minimum(res.lam[i], slack).abs().max()) <= 1e-8 * (1 + float(qp.h[i].abs().max()))
            f_ours = (qp.basis[i] @ res.z[i].view(*qp.basis.shape[1:3], 4, 1)).squeeze(-1)
            f_ref = (qp.basis[i] @ torch.from_numpy(x).view(*qp.basis.shape[1:3], 4, 1)).squeeze(-1)
            torch.testing.assert_close(f_ours, f_ref, rtol=0, atol=1e-3)      # forces (lambda is not unique)
            assert float(res.residual_primal[i]) <= 1e-8 * (1 + float(qp.b[i].abs().max()))
    assert n_solved >= 7 and n_infeasible >= 9                              # both classes, every kind


def test_window_qps_float32(gen):
    qp = _window_batch(gen, [("grasp", True), ("pinch", False)])
    for q in qp:
        r64 = solve_convex_qp(*_window_args(q))
        r32 = solve_convex_qp(*_window_args(q, torch.float32))
        ok = r64.status == CONVERGED
        assert bool(ok.any()) and r32.status.tolist() == r64.status.tolist()
        torch.testing.assert_close(r32.objective[ok].double(), r64.objective[ok], rtol=1e-3, atol=1e-3)


# ------------------------------------------------------------------------------ equalities, warm start, data
def test_rank_deficient_equalities_are_reduced_not_failed():
    f64 = torch.float64
    A = torch.tensor([[[1.0, 1.0, 0.0], [2.0, 2.0, 0.0], [0.0, 0.0, 1.0]]], dtype=f64).expand(2, 3, 3)
    b = torch.tensor([[1.0, 2.0, 0.5], [1.0, 2.5, 0.5]], dtype=f64)               # in range | not in range
    red = reduce_equalities(A.contiguous(), b)
    assert red.rank.tolist() == [2, 2] and red.in_range.tolist() == [True, False]
    assert float(red.A[0, 2].abs().max()) == 0.0                                  # dropped row kept as zeros
    res = solve_convex_qp(torch.eye(3, dtype=f64).expand(2, 3, 3).contiguous(), torch.zeros(2, 3, dtype=f64),
                          A=A.contiguous(), b=b)
    assert res.status.tolist() == [CONVERGED, INFEASIBLE]
    torch.testing.assert_close(res.z[0], torch.tensor([0.5, 0.5, 0.5], dtype=f64), rtol=0, atol=1e-9)
    nu = res.nu[1]                                                                # A^T nu = 0, b^T nu < 0
    assert float((A[1].T @ nu).abs().max()) < 1e-12 and float(b[1] @ nu) < 0
    # More equality rows than variables.
    A4 = torch.cat([A[:1], A[:1, :1]], 1).contiguous()
    res = solve_convex_qp(torch.eye(3, dtype=f64).unsqueeze(0), torch.zeros(1, 3, dtype=f64), A=A4,
                          b=torch.tensor([[1.0, 2.0, 0.5, 1.0]], dtype=f64))
    assert res.status.tolist() == [CONVERGED]


def test_warm_start_reduces_iterations(gen):
    qp = assemble_window_qp(**window_problems(4, gen, table=True))
    args = _window_args(qp)
    cold = solve_convex_qp(*args, polish=False, tol=1e-6, method="admm")
    assert cold.status.tolist() == [CONVERGED] * 4
    warm = solve_convex_qp(*args, polish=False, tol=1e-6, warm_start=(cold.z, cold.lam, cold.nu), method="admm")
    assert warm.status.tolist() == [CONVERGED] * 4
    assert bool((warm.iterations < cold.iterations).all()), (warm.iterations, cold.iterations)
    torch.testing.assert_close(warm.objective, cold.objective, rtol=1e-5, atol=1e-5)


MM_SMALL = ["HS21", "HS35", "HS35MOD", "HS51", "HS52", "HS53", "HS76", "HS118", "GENHS28", "ZECEVIC2", "TAME",
            "QAFIRO", "DUALC1"]


@pytest.mark.parametrize("solver", ["kernel", "dense"])
@pytest.mark.parametrize("name", MM_SMALL)
def test_maros_meszaros(name, solver):
    """Small Maros-Meszaros problems against Clarabel's objectives: the batched kernel and the single-problem dense
    path (torchhand.solvers._dense, the Liu planner's solver on the CPU)."""
    from torchhand.solvers._dense import solve_qp_dense

    root = shared_path("qp", "maros_meszaros")
    ref = json.loads((root / "maros_meszaros_reference_objectives.json").read_text())[name]
    P, q, r, G, h, Ae, be = load_maros_meszaros(name, root)
    t = lambda a: torch.from_numpy(np.ascontiguousarray(a, dtype=np.float64)).unsqueeze(0)  # noqa: E731
    args = (t(0.5 * (P + P.T)), t(q), t(G) if len(G) else None, t(h) if len(G) else None,
            t(Ae) if len(Ae) else None, t(be) if len(Ae) else None)
    res = solve_convex_qp(*args, max_iters=20000) if solver == "kernel" else solve_qp_dense(*args)
    assert int(res.status[0]) == CONVERGED, (name, res)
    assert float(res.objective[0]) + r == pytest.approx(ref["clarabel_obj"], rel=1e-7, abs=1e-7)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA not available")
@pytest.mark.parametrize("method", ["ipm", "admm"])
def test_window_qps_cuda_match_cpu(gen, method):
    """The planner's window problems solved on the GPU give the CPU's statuses and objectives (float64)."""
    for qp in _window_batch(gen, [("grasp", False), ("grasp", True), ("pinch", False), ("weak", False)]):
        cpu = solve_convex_qp(*_window_args(qp), method=method)
        gpu = solve_convex_qp(*(a.cuda() for a in _window_args(qp)), method=method)
        assert gpu.z.is_cuda and gpu.status.cpu().tolist() == cpu.status.tolist()
        ok = cpu.status == CONVERGED
        torch.testing.assert_close(gpu.objective.cpu()[ok], cpu.objective[ok], rtol=1e-6, atol=1e-8)
