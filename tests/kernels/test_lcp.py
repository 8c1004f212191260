"""Batched projected Gauss-Seidel for standard LCPs (kernels/lcp.py).

References nobody here wrote: Lemke's method (torchhand/lemke.py, checked itself against an exhaustive
enumeration in tests/torchhand/test_lemke.py), planted solutions of positive definite problems (unique), the
Siconos LCP instances (skipped when ../shared/data is absent), and invariants in seeded loops.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from torchhand.kernels.lcp import LCPResult, lcp_tolerances, solve_lcp_pgs
from torchhand.kernels.status import SolverStatus
from torchhand.solvers.lcp import random_lcp, read_siconos_lcp
from torchhand.solvers._lemke import lemke

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from conftest import shared_path  # noqa: E402

CONVERGED, MAX_ITERATIONS, INVALID, UNBOUNDED = (int(SolverStatus.CONVERGED), int(SolverStatus.MAX_ITERATIONS),
                                                 int(SolverStatus.INVALID_INPUT), int(SolverStatus.UNBOUNDED))
X_ATOL = {torch.float32: 2e-4, torch.float64: 1e-8}         # agreement of solutions, per dtype
# plain PGS, SOR, PGS with subspace minimisation, SOR with float32 sweeps refined in float64
VARIANTS = [dict(), dict(omega=1.3), dict(subspace=True), dict(omega=1.2, mixed=True)]


def w_of(M, q, x):
    return (M @ x[..., None]).squeeze(-1) + q


@pytest.mark.parametrize("B", [1, 7])
@pytest.mark.parametrize("kw", VARIANTS, ids=["pgs", "sor", "pgs_sm", "sor_mixed"])
def test_smoke_shapes_and_planted_solution(B, kw, dtype, device):
    gen = torch.Generator().manual_seed(B)
    M, q, x_star = random_lcp(B, 6, generator=gen, kind="pd", dtype=dtype, device=device)
    out = solve_lcp_pgs(M, q, **kw)
    assert isinstance(out, LCPResult)
    assert out.x.shape == out.w.shape == (B, 6)
    assert out.residual.shape == out.status.shape == out.iterations.shape == (B,)
    assert out.status.dtype == torch.int8 and out.iterations.dtype == torch.int32
    assert out.x.dtype == dtype and out.x.device.type == torch.device(device).type
    assert (out.status == CONVERGED).all()
    assert (out.residual <= lcp_tolerances(dtype).tol).all()
    torch.testing.assert_close(out.x, x_star, atol=X_ATOL[dtype], rtol=0)
    torch.testing.assert_close(out.w, w_of(M, q, out.x), atol=X_ATOL[dtype], rtol=0)
    assert (out.iterations % 10 == 0).all()                 # convergence is read only at checks


def test_invariants_seeded_loop():
    """Complementarity, x >= 0, w >= 0 and w = M x + q on random problems of random size. PGS converges on
    symmetric PD and PSD problems with a solution; on monotone non-symmetric ones it may stall or diverge, and
    must then say so (MAX_ITERATIONS or UNBOUNDED with a finite iterate), never claim convergence."""
    gen = torch.Generator().manual_seed(2024)
    kinds = ["pd", "psd", "monotone"]
    stalled = 0
    for trial in range(24):
        dtype = (torch.float64, torch.float32)[trial % 2]
        n = int(torch.randint(1, 13, (1,), generator=gen))
        kind = kinds[trial % 3]
        M, q, _ = random_lcp(7, n, generator=gen, kind=kind, dtype=dtype)
        max_iters = 1000 if kind == "monotone" else 10000    # rank-deficient PSD can take thousands of sweeps
        out = solve_lcp_pgs(M, q, max_iters=max_iters, **VARIANTS[trial % 4])
        tol = lcp_tolerances(dtype).tol
        conv = out.status == CONVERGED
        if kind == "monotone":                              # stalled (MAX_ITERATIONS) or diverged (UNBOUNDED)
            maxed = out.status == MAX_ITERATIONS
            assert (maxed | (out.status == UNBOUNDED) | conv).all()
            assert (out.residual[~conv] > tol).all() and (out.iterations[maxed] == 1000).all()
            assert torch.isfinite(out.x).all()
            stalled += int((~conv).sum())
        else:
            assert conv.all(), (trial, kind, out.status, out.residual)
        assert (out.residual[conv] <= tol).all()
        assert out.x.min() >= 0
        x, w = out.x[conv], out.w[conv]
        assert (w >= -tol).all()
        assert ((x * w).abs() <= tol * (1 + x.abs() + w.abs())).all()
        torch.testing.assert_close(out.w, w_of(M, q, out.x), atol=10 * tol, rtol=0)
    assert stalled > 0                                      # the honest MAX_ITERATIONS path was exercised


def test_mixed_precision_sweeps_reach_float64_accuracy():
    """Float32 sweeps on corrections, refined against the exact float64 residual at every check, must reach the
    float64 tolerance (not float32's), in the same number of sweeps as float64 sweeps here."""
    gen = torch.Generator().manual_seed(9)
    M, q, x_star = random_lcp(64, 20, generator=gen, kind="pd")
    ref = solve_lcp_pgs(M, q, omega=1.2)
    out = solve_lcp_pgs(M, q, omega=1.2, mixed=True)
    assert (out.status == CONVERGED).all() and (out.residual <= 1e-10).all()
    torch.testing.assert_close(out.x, x_star, atol=1e-9, rtol=0)
    assert (out.iterations - ref.iterations).abs().max() <= 10
    assert out.x.dtype == torch.float64


def test_pgs_agrees_with_lemke_on_symmetric_pd():
    gen = torch.Generator().manual_seed(3)
    M, q, _ = random_lcp(7, 8, generator=gen, kind="pd")
    q = torch.randn(7, 8, generator=gen, dtype=torch.float64)          # a fresh q: the solution is still unique
    out = solve_lcp_pgs(M, q)
    for b in range(7):
        ref = lemke(M[b].numpy(), q[b].numpy())
        assert ref.status == SolverStatus.CONVERGED
        np.testing.assert_allclose(out.x[b].numpy(), ref.x, atol=1e-8)


def test_mask_padding_matches_unpadded(dtype):
    gen = torch.Generator().manual_seed(4)
    M, q, _ = random_lcp(7, 5, generator=gen, kind="pd", dtype=dtype)
    Mp = torch.full((7, 8, 8), float("nan"), dtype=dtype)
    qp = torch.full((7, 8), float("nan"), dtype=dtype)
    perm = torch.tensor([6, 0, 3, 1, 7])                   # active entries scattered among the padding
    Mp[:, perm[:, None], perm[None, :]] = M
    qp[:, perm] = q
    mask = torch.zeros(7, 8, dtype=torch.bool)
    mask[:, perm] = True
    ref = solve_lcp_pgs(M, q)
    out = solve_lcp_pgs(Mp, qp, mask=mask)
    assert (out.status == CONVERGED).all()
    torch.testing.assert_close(out.x[:, perm], ref.x, atol=X_ATOL[dtype], rtol=0)
    assert (out.x[~mask] == 0).all() and (out.w[~mask] == 0).all()
    torch.testing.assert_close(out.residual, ref.residual, atol=lcp_tolerances(dtype).tol, rtol=0)


def test_warm_start_and_max_iterations():
    gen = torch.Generator().manual_seed(5)
    M, q, x_star = random_lcp(7, 10, generator=gen, kind="pd")
    warm = solve_lcp_pgs(M, q, x0=x_star)
    assert (warm.status == CONVERGED).all() and (warm.iterations == 0).all()
    short = solve_lcp_pgs(M, q, max_iters=3, check_every=2)
    assert (short.status == MAX_ITERATIONS).all() and (short.iterations == 3).all()
    assert (short.residual > lcp_tolerances(torch.float64).tol).all()
    assert torch.isfinite(short.x).all() and short.x.min() >= 0
    torch.testing.assert_close(short.w, w_of(M, q, short.x), atol=1e-12, rtol=0)
    torch.testing.assert_close(short.residual, torch.minimum(short.x, short.w).abs().amax(-1), atol=0, rtol=0)
    again = solve_lcp_pgs(M, q, x0=short.x)                  # resuming from where it stopped
    assert (again.status == CONVERGED).all()
    torch.testing.assert_close(again.x, x_star, atol=1e-8, rtol=0)


def test_per_problem_invalid_and_diverged():
    gen = torch.Generator().manual_seed(6)
    M, q, x_star = random_lcp(7, 2, generator=gen, kind="pd")
    M[1, 0, 1] = float("nan")                              # NaN entry
    M[2, 1, 1] = 0.0                                       # zero diagonal: PGS cannot divide by it
    q[3, 0] = float("inf")
    # no solution (w_0 + w_1 = -2 - 2 (x_0 + x_1)); PGS iterates grow without bound
    M[4] = torch.tensor([[1.0, -3.0], [-3.0, 1.0]], dtype=torch.float64)
    q[4] = torch.tensor([-1.0, -1.0], dtype=torch.float64)
    out = solve_lcp_pgs(M, q)
    assert out.status.tolist() == [CONVERGED, INVALID, INVALID, INVALID, UNBOUNDED, CONVERGED, CONVERGED]
    for b in (1, 2, 3):
        assert out.residual[b] == float("inf") and (out.x[b] == 0).all() and (out.w[b] == 0).all()
    assert torch.isfinite(out.x[4]).all() and torch.isfinite(out.w[4]).all()    # the last finite checkpoint
    assert lemke(M[4].numpy(), q[4].numpy()).status == SolverStatus.UNBOUNDED
    torch.testing.assert_close(out.x[[0, 5, 6]], x_star[[0, 5, 6]], atol=1e-8, rtol=0)


def test_empty_problems():
    out = solve_lcp_pgs(torch.zeros(3, 0, 0), torch.zeros(3, 0))
    assert out.x.shape == (3, 0) and (out.status == CONVERGED).all() and (out.residual == 0).all()
    out = solve_lcp_pgs(torch.zeros(0, 4, 4), torch.zeros(0, 4))
    assert out.x.shape == (0, 4) and out.status.shape == (0,)


def test_bad_input():
    M = torch.eye(3).expand(2, 3, 3)
    q = torch.ones(2, 3)
    with pytest.raises(ValueError, match=r"M must have shape \(B, n, n\), got \(3, 3\)"):
        solve_lcp_pgs(M[0], q)
    with pytest.raises(ValueError, match=r"M must have shape \(B, n, n\), got \(2, 2, 3\)"):
        solve_lcp_pgs(M[:, :2], q)
    with pytest.raises(ValueError, match=r"q must have shape \(2, 3\), got \(2, 4\)"):
        solve_lcp_pgs(M, torch.ones(2, 4))
    with pytest.raises(ValueError, match=r"x0 must have shape \(2, 3\)"):
        solve_lcp_pgs(M, q, x0=torch.ones(3))
    with pytest.raises(ValueError, match="mask must be bool"):
        solve_lcp_pgs(M, q, mask=torch.ones(2, 3))
    with pytest.raises(ValueError, match="q must be torch.float32"):
        solve_lcp_pgs(M, q.double())
    with pytest.raises(ValueError, match="M must be floating point"):
        solve_lcp_pgs(M.long(), q)
    with pytest.raises(ValueError, match="omega"):
        solve_lcp_pgs(M, q, omega=2.0)
    with pytest.raises(ValueError, match="check_every"):
        solve_lcp_pgs(M, q, check_every=0)
    with pytest.raises(ValueError, match="max_iters"):
        solve_lcp_pgs(M, q, max_iters=-1)


SICONOS = ["lcp_CPS_1", "lcp_CPS_5", "lcp_deudeu", "lcp_deudeu_block", "lcp_exp_murty", "lcp_exp_murty2",
           "lcp_mmc", "lcp_ortiz", "lcp_ortiz_block", "lcp_trivial", "lcp_trivial_block",
           # zero or negative diagonal entries: PGS must refuse them as INVALID_INPUT
           "lcp_CPS_2", "lcp_CPS_3", "lcp_CPS_4", "lcp_CPS_4bis", "lcp_Pang_isolated_sol",
           "lcp_Pang_isolated_sol_perturbed", "lcp_enum_fails", "lcp_inf_sol_perturbed", "lcp_tobenna"]


@pytest.mark.parametrize("name", SICONOS)
def test_siconos_pgs_converges_or_reports(name):
    M, q = read_siconos_lcp(shared_path("lcp", "siconos_lcp", f"{name}.dat"))
    Mt, qt = torch.from_numpy(M)[None], torch.from_numpy(q)[None]
    out = solve_lcp_pgs(Mt, qt, max_iters=5000)
    status = int(out.status[0])
    if not (np.diag(M) > 0).all():
        assert status == INVALID
        return
    tol = lcp_tolerances(torch.float64).tol
    if status == CONVERGED:
        x = out.x[0].numpy()
        w = M @ x + q
        assert x.min() >= 0 and w.min() >= -tol and np.abs(np.minimum(x, w)).max() <= tol
    else:                                                   # an honest report, never a fake success
        assert status == MAX_ITERATIONS and out.residual[0] > tol
        assert lemke(M, q).status == SolverStatus.CONVERGED


@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA not available")
def test_cuda_matches_cpu():
    gen = torch.Generator().manual_seed(8)
    M, q, _ = random_lcp(7, 9, generator=gen, kind="psd")
    mask = torch.rand(7, 9, generator=gen) > 0.2
    cpu = solve_lcp_pgs(M, q, mask=mask, subspace=True)
    gpu = solve_lcp_pgs(M.cuda(), q.cuda(), mask=mask.cuda(), subspace=True)
    assert gpu.x.is_cuda
    torch.testing.assert_close(gpu.status.cpu(), cpu.status)
    torch.testing.assert_close(gpu.x.cpu(), cpu.x, atol=1e-8, rtol=0)
