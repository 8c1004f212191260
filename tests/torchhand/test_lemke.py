"""Lemke's method, the PGS + Lemke orchestration and the Siconos reader.

References: an exhaustive enumeration of complementary bases (below, independent of the pivoting code) on small
random LCPs, and the Siconos LCP test instances (skipped when ../shared/data is absent).
"""

from __future__ import annotations

import itertools
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from torchhand.errors import FileFormatError, InputValueError, MissingFileError, ShapeError
from torchhand.kernels.status import SolverStatus
from torchhand.solvers.lcp import random_lcp, read_siconos_lcp, solve_lcp
from torchhand.solvers._lemke import lemke

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from conftest import shared_path  # noqa: E402

SICONOS = [
    "lcp_CPS_1", "lcp_CPS_2", "lcp_CPS_3", "lcp_CPS_4", "lcp_CPS_4bis", "lcp_CPS_5", "lcp_Pang_isolated_sol",
    "lcp_Pang_isolated_sol_perturbed", "lcp_deudeu", "lcp_deudeu_block", "lcp_enum_fails", "lcp_exp_murty",
    "lcp_exp_murty2", "lcp_inf_sol_perturbed", "lcp_mmc", "lcp_ortiz", "lcp_ortiz_block", "lcp_tobenna",
    "lcp_trivial", "lcp_trivial_block",
]
NO_SOLUTION = {"lcp_Pang_isolated_sol_perturbed"}   # w_0 = -x_1 - x_2 - 1e-4 < 0 for every x >= 0
LEMKE_HOWSON = {"lcp_CPS_3"}   # bimatrix game: Lemke's start ray-terminates (Siconos marks LEMKE as failing)


def enumerate_lcp(M: np.ndarray, q: np.ndarray, tol: float = 1e-9) -> list[np.ndarray]:
    """All solutions x of LCP(M, q) with a nonsingular complementary basis: for every index set a, solve
    M_aa x_a = -q_a, x = 0 elsewhere, and keep x when x >= 0 and M x + q >= 0."""
    n = q.shape[0]
    sols = []
    for bits in itertools.product((False, True), repeat=n):
        a = np.array(bits, dtype=bool)
        x = np.zeros(n)
        if a.any():
            sub = M[np.ix_(a, a)]
            if abs(np.linalg.det(sub)) < 1e-12:
                continue
            x[a] = np.linalg.solve(sub, -q[a])
        w = M @ x + q
        if x.min() >= -tol and w.min() >= -tol:
            sols.append(np.maximum(x, 0))
    return sols


def check_solution(x: np.ndarray, M: np.ndarray, q: np.ndarray, tol: float) -> None:
    w = M @ x + q
    assert x.min() >= 0
    assert w.min() >= -tol
    assert np.abs(np.minimum(x, w)).max() <= tol


def murty(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Murty's (1978) example on which Lemke's method takes 2^n pivots: M = I + 2 (strict upper triangle of ones),
    q_i = -(2^(n+1) - 2^(i+1))."""
    return np.eye(n) + 2 * np.triu(np.ones((n, n)), 1), -(2.0 ** (n + 1) - 2.0 ** np.arange(1, n + 1))


def p_matrix(n: int, rng: np.random.Generator) -> np.ndarray:
    """A non-symmetric P-matrix (strictly diagonally dominant with positive diagonal)."""
    A = rng.standard_normal((n, n))
    return A + np.diag(np.abs(A).sum(1) + 0.5)


# --- Lemke against the exhaustive enumeration --------------------------------------------------------------


def test_lemke_matches_enumeration_on_small_random_lcps():
    rng = np.random.default_rng(7)
    gen = torch.Generator().manual_seed(7)
    n_infeasible = 0
    for trial in range(60):
        n = int(rng.integers(1, 9))
        kind = trial % 4
        if kind == 0:                                           # unique solution (symmetric positive definite)
            M, q, _ = (t[0].numpy() for t in random_lcp(1, n, generator=gen, kind="pd"))
        elif kind == 1:                                         # unique solution (monotone, non-symmetric)
            M, q, _ = (t[0].numpy() for t in random_lcp(1, n, generator=gen, kind="monotone"))
        elif kind == 2:                                         # unique solution (P-matrix)
            M, q = p_matrix(n, rng), rng.standard_normal(n)
        else:                                                   # PSD of low rank, random q: often no solution
            A = rng.standard_normal((n, max(n // 3, 1)))
            M, q = A @ A.T, rng.standard_normal(n)
        sols = enumerate_lcp(M, q)
        out = lemke(M, q)
        if kind < 3:
            assert len(sols) == 1, (trial, len(sols))
            assert out.status == SolverStatus.CONVERGED, (trial, out.status)
            np.testing.assert_allclose(out.x, sols[0], atol=1e-8)
        elif sols:
            # copositive-plus M: Lemke must find a solution whenever one exists
            assert out.status == SolverStatus.CONVERGED, (trial, out.status)
        else:
            assert out.status == SolverStatus.UNBOUNDED, (trial, out.status)
            n_infeasible += 1
        if out.status == SolverStatus.CONVERGED:
            check_solution(out.x, M, q, 1e-9)
            np.testing.assert_allclose(out.w, M @ out.x + q, atol=1e-12)
    assert n_infeasible >= 3                                    # ray termination was exercised


def test_lemke_degenerate_ties():
    """Integer data with a degenerate planted solution (x_i = w_i = 0 for some i) makes the ratio test tie; the
    lexicographic rule must still terminate with a solution."""
    rng = np.random.default_rng(3)
    for _ in range(30):
        n = int(rng.integers(2, 8))
        A = rng.integers(-2, 3, size=(n, n)).astype(float)
        M = A @ A.T + np.eye(n)
        z = rng.integers(-1, 2, size=n).astype(float)          # -1, 0, 1: zeros are degenerate
        q = np.maximum(-z, 0) - M @ np.maximum(z, 0)
        out = lemke(M, q)
        assert out.status == SolverStatus.CONVERGED
        check_solution(out.x, M, q, 1e-9)
    # all-equal q and a rank-one M (CPS 2009, Remark 4.1.14): a continuum of solutions
    out = lemke(np.ones((2, 2)), -np.ones(2))
    assert out.status == SolverStatus.CONVERGED and abs(out.x.sum() - 1) < 1e-12


def test_lemke_ray_termination_and_limits():
    # PSD and w_0 + w_1 = -2 for every x: no solution, ray termination
    out = lemke(np.array([[1.0, -1.0], [-1.0, 1.0]]), np.array([-1.0, -1.0]))
    assert out.status == SolverStatus.UNBOUNDED and out.pivots >= 1
    # q >= 0: x = 0 without pivots
    out = lemke(np.eye(3), np.ones(3))
    assert out.status == SolverStatus.CONVERGED and out.pivots == 0 and not out.x.any()
    # Murty's example (Lemke needs 2^n pivots): solved, and a pivot limit is reported as such
    M, q = murty(6)
    full = lemke(M, q)
    assert full.status == SolverStatus.CONVERGED and full.pivots == 2 ** 6
    check_solution(full.x, M, q, 1e-9)
    limited = lemke(M, q, max_pivots=1)
    assert limited.status == SolverStatus.MAX_ITERATIONS and limited.pivots <= 1
    # n = 0 and NaN data
    assert lemke(np.zeros((0, 0)), np.zeros(0)).status == SolverStatus.CONVERGED
    assert lemke(np.array([[np.nan]]), np.array([-1.0])).status == SolverStatus.INVALID_INPUT


def test_lemke_restarts_after_a_terminal_basis_that_is_not_a_solution():
    """A Kry & Pai step LCP (130 unknowns: 13 contacts x 9 pyramid directions + 13 slip multipliers, a 0.75 kg box
    in the resynthesis demo) on which the first covering vector d = 1 ends on a complementary basis whose solution
    misses the tolerance (round-off along the path): Lemke restarts with another covering vector and solves it.
    Reference: the LCP's definition (x >= 0, M x + q >= 0, x^T (M x + q) = 0) evaluated here; the problem is too
    large to enumerate and its M is singular on the support, so no basis re-solve is possible."""
    data = np.load(Path(__file__).resolve().parents[1] / "data" / "lemke_restart_lcp.npz")
    M, q, tol = data["M"], data["q"], 1e-7
    first = lemke(M, q, tol=tol, restarts=0)
    assert first.status == SolverStatus.MAX_ITERATIONS and first.pivots < max(1000, 50 * len(q))
    assert first.residual > 100 * tol                     # a terminal basis that is not a solution
    out = lemke(M, q, tol=tol)
    assert out.status == SolverStatus.CONVERGED and out.pivots > first.pivots
    check_solution(out.x, M, q, 1e-9)
    w = M @ out.x + q                                     # recomputed here, not the solver's w
    assert abs(float(out.x @ w)) <= 1e-12 and w.min() >= -1e-9


def test_lemke_bad_input():
    with pytest.raises(ShapeError, match="M must have shape"):
        lemke(np.eye(3), np.ones(2))
    with pytest.raises(ShapeError, match="q must have 1"):
        lemke(np.eye(2), np.ones((2, 1)))
    with pytest.raises(InputValueError, match="max_pivots"):
        lemke(np.eye(2), -np.ones(2), max_pivots=-1)
    # torch tensors are accepted (converted to float64 NumPy)
    out = lemke(torch.eye(2), -torch.ones(2))
    np.testing.assert_allclose(out.x, [1.0, 1.0])


# --- Siconos instances ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", SICONOS)
def test_siconos_lemke(name):
    path = shared_path("lcp", "siconos_lcp", f"{name}.dat")
    M, q = read_siconos_lcp(path)
    n = q.shape[0]
    out = lemke(M, q)
    sols = enumerate_lcp(M, q) if n <= 12 else None
    if name in NO_SOLUTION:
        assert sols == []                                       # the enumeration confirms: no solution
        assert out.status == SolverStatus.UNBOUNDED
    elif name in LEMKE_HOWSON:
        # Known limitation, reported honestly: the instance has solutions, Lemke's method terminates on a ray
        assert sols
        assert out.status == SolverStatus.UNBOUNDED
    else:
        assert out.status == SolverStatus.CONVERGED, out.status
        assert out.residual <= 1e-8
        check_solution(out.x, M, q, 1e-8)
        if sols is not None:
            assert sols, "enumeration found no solution but Lemke did"


@pytest.mark.parametrize("dense,block", [("lcp_deudeu", "lcp_deudeu_block"), ("lcp_ortiz", "lcp_ortiz_block"),
                                         ("lcp_trivial", "lcp_trivial_block")])
def test_siconos_block_format_matches_dense(dense, block):
    Md, qd = read_siconos_lcp(shared_path("lcp", "siconos_lcp", f"{dense}.dat"))
    Mb, qb = read_siconos_lcp(shared_path("lcp", "siconos_lcp", f"{block}.dat"))
    np.testing.assert_array_equal(Md, Mb)
    np.testing.assert_array_equal(qd, qb)


def test_siconos_exp_murty2_is_exponential():
    M, q = read_siconos_lcp(shared_path("lcp", "siconos_lcp", "lcp_exp_murty2.dat"))
    Mm, qm = murty(6)
    np.testing.assert_array_equal(M, Mm)                   # stored column by column: upper triangular
    np.testing.assert_array_equal(q, qm)
    out = lemke(M, q)
    assert out.status == SolverStatus.CONVERGED and out.pivots == 2 ** 6


def test_read_siconos_errors(tmp_path: Path):
    with pytest.raises(MissingFileError, match="not found"):
        read_siconos_lcp(tmp_path / "absent.dat")
    bad = tmp_path / "bad.dat"
    bad.write_text("3\n0\n3\n3\n3 3\n1 2 3\n")
    with pytest.raises(FileFormatError, match="bad.dat"):
        read_siconos_lcp(bad)
    odd = tmp_path / "odd.dat"
    odd.write_text("2\n0\n2\n3\n2 3\n1 0 0 1 0 0\n1 1\n")
    with pytest.raises(FileFormatError, match="does not match"):
        read_siconos_lcp(odd)


# --- solve_lcp: PGS then Lemke for what PGS cannot finish --------------------------------------------------


def test_solve_lcp_falls_back_to_lemke():
    gen = torch.Generator().manual_seed(11)
    M, q, x_star = random_lcp(4, 5, generator=gen, kind="pd")
    # problem 1: zero diagonal (PGS cannot divide by it), a solvable CPS 2009 example 4.4.7
    M[1] = torch.tensor([[0.0, -1.0, 2.0, 0, 0], [2.0, 0.0, -2.0, 0, 0], [-1.0, 1.0, 0.0, 0, 0],
                         [0, 0, 0, 1.0, 0], [0, 0, 0, 0, 1.0]], dtype=torch.float64)
    q[1] = torch.tensor([-3.0, 6.0, -1.0, 1.0, 1.0], dtype=torch.float64)
    # problem 2: PSD with w_0 + w_1 = -2: no solution; PGS diverges or stalls, Lemke reports the ray
    M[2] = torch.eye(5, dtype=torch.float64)
    M[2, :2, :2] = torch.tensor([[1.0, -1.0], [-1.0, 1.0]])
    q[2] = torch.tensor([-1.0, -1.0, 1.0, 1.0, 1.0], dtype=torch.float64)
    out = solve_lcp(M, q, max_iters=3, check_every=1)
    status = out.status.tolist()
    assert status[1] == SolverStatus.CONVERGED and bool(out.lemke[1]) and out.pivots[1] > 0
    assert status[2] == SolverStatus.UNBOUNDED and bool(out.lemke[2])
    for b in (0, 1, 3):
        assert status[b] == SolverStatus.CONVERGED and out.residual[b] <= 1e-10
        assert out.x[b].min() >= 0
        torch.testing.assert_close(out.w[b], M[b] @ out.x[b] + q[b], atol=1e-12, rtol=0)
    torch.testing.assert_close(out.x[[0, 3]], x_star[[0, 3]], atol=1e-8, rtol=0)
    # without the fallback the same problems stay unfinished / invalid
    off = solve_lcp(M, q, max_iters=3, check_every=1, lemke_max_n=0)
    assert off.status[1] == SolverStatus.INVALID_INPUT and not bool(off.lemke.any())


def test_solve_lcp_with_mask_and_float32():
    gen = torch.Generator().manual_seed(5)
    M, q, x_star = random_lcp(7, 6, generator=gen, kind="pd", dtype=torch.float32)
    mask = torch.ones(7, 6, dtype=torch.bool)
    mask[3, 4:] = False
    M[3, 4:, :] = float("nan")
    M[3, :, 4:] = float("nan")
    out = solve_lcp(M, q, mask=mask, max_iters=2, check_every=1)   # too few sweeps: Lemke finishes them all
    assert (out.status == SolverStatus.CONVERGED).all()
    assert out.x.dtype == torch.float32 and torch.isfinite(out.x).all()
    assert (out.x[3, 4:] == 0).all() and (out.w[3, 4:] == 0).all()
    keep = [0, 1, 2, 4, 5, 6]
    torch.testing.assert_close(out.x[keep], x_star[keep], atol=1e-4, rtol=0)


def test_solve_lcp_bad_input():
    M = torch.eye(3, dtype=torch.float64).expand(2, 3, 3)
    q = torch.ones(2, 3, dtype=torch.float64)
    with pytest.raises(ShapeError, match="q: expected shape"):
        solve_lcp(M, q[:, :2])
    with pytest.raises(ShapeError, match="M: expected shape"):
        solve_lcp(M[0], q)
    with pytest.raises(ShapeError, match="M: expected shape"):
        solve_lcp(M[:, :2], q)
    with pytest.raises(TypeError, match="mask"):
        solve_lcp(M, q, mask=torch.ones(2, 3))
    with pytest.raises(TypeError, match="dtype"):
        solve_lcp(M, q.float())
    with pytest.raises(InputValueError, match="omega"):
        solve_lcp(M, q, omega=2.5)


def test_random_lcp_planted_solution():
    gen = torch.Generator().manual_seed(0)
    for kind in ("pd", "psd", "monotone"):
        M, q, x = random_lcp(3, 7, generator=gen, kind=kind)
        w = (M @ x[..., None]).squeeze(-1) + q
        assert x.min() >= 0 and w.min() >= -1e-12
        assert (x * w).abs().max() <= 1e-12
    with pytest.raises(InputValueError, match="kind"):
        random_lcp(1, 2, generator=gen, kind="other")
