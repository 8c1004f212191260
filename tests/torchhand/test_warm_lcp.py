"""The step LCP's warm start (torchhand.interaction._warm_lcp): from a support it either returns a solution of the
LCP (checked here against the LCP itself and against Lemke's forces) or nothing; and a resynthesis with it follows
the same motion as one that pivots every step."""

from __future__ import annotations

import numpy as np
import torch

from tests.kernels.test_contact_lcp import contact_problem
from torchhand.interaction._warm_lcp import solve_from_support, support_guess
from torchhand.kernels.contact_lcp import build_kry_pai_lcp
from torchhand.kernels.status import SolverStatus
from torchhand.solvers._lemke import lemke

N, M_PAIRS = 5, 4
K = 2 * M_PAIRS + 1
TOL = 1e-7


def _problems(B: int, seed: int):
    D, G, U, sp, mu = contact_problem(B, N, M_PAIRS, torch.Generator().manual_seed(seed))
    lcp = build_kry_pai_lcp(D, G, U, sp, mu)
    return D.numpy(), lcp.M.numpy(), lcp.q.numpy(), mu.numpy()


def _residual(M, q, z) -> float:
    return float(np.abs(np.minimum(z, M @ z + q)).max())


def test_the_solutions_own_support_solves_it_with_lemkes_forces():
    """Lemke's answer's support (as the step would carry it to the next step) gives back a solution at once, with
    the same contact forces D beta (unique where G - U_phi is definite, as here)."""
    D, M, q, mu = _problems(24, 3)
    solved = 0
    for b in range(len(q)):
        ref = lemke(M[b], q[b])
        assert ref.status == SolverStatus.CONVERGED
        beta = ref.x[:N * K].reshape(N, K)
        on, sliding = support_guess(beta, mu[b])
        out = solve_from_support(M[b], q[b], N, K, on, sliding, TOL, rounds=0)
        if out is None:
            continue
        z, residual = out
        assert residual == _residual(M[b], q[b], z)
        solved += 1
        assert z.min() >= 0 and (M[b] @ z + q[b]).min() >= -TOL and _residual(M[b], q[b], z) <= TOL
        f, f_ref = (np.einsum("nrk,nk->nr", D[b], x[:N * K].reshape(N, K)) for x in (z, ref.x))
        np.testing.assert_allclose(f, f_ref, atol=1e-9)
    assert solved >= 20, solved          # degenerate supports (a force exactly on a pyramid edge) may need pivots


def test_a_wrong_support_gives_a_solution_or_nothing():
    """Every support (empty, full, random, another problem's) returns either None or a z that solves the LCP:
    the answer never rests on the guess."""
    D, M, q, mu = _problems(16, 4)
    rng = np.random.default_rng(0)
    answers = 0
    for b in range(len(q)):
        guesses = [(np.zeros((N, K), bool), np.zeros(N, bool)), (np.ones((N, K), bool), np.ones(N, bool)),
                   (rng.random((N, K)) < 0.3, rng.random(N) < 0.5)]
        other = lemke(M[(b + 1) % len(q)], q[(b + 1) % len(q)])
        guesses.append(support_guess(other.x[:N * K].reshape(N, K), mu[(b + 1) % len(q)]))
        for on, sliding in guesses:
            out = solve_from_support(M[b], q[b], N, K, on, sliding, TOL)
            if out is not None:
                z = out[0]
                answers += 1
                assert z.min() >= 0 and (M[b] @ z + q[b]).min() >= -TOL and _residual(M[b], q[b], z) <= TOL
    assert answers >= 3                  # some wrong guesses are corrected into a solution (6 of 64 here)


def test_the_guess_reads_sliding_from_a_force_on_the_cone():
    beta = np.zeros((3, K))
    beta[0, [0, 1]] = [1.0, 0.5]         # mu 0.5: on the pyramid's boundary -> sliding
    beta[1, [0, 1]] = [1.0, 0.2]         # inside
    on, sliding = support_guess(beta, np.array([0.5, 0.5, 0.5]))
    assert sliding.tolist() == [True, False, False]
    assert on[0, :2].all() and on[1, :2].all() and not on[2].any()


def test_pinch_with_and_without_the_warm_start_moves_the_same():
    """A whole pinch-and-lift rollout: the warm start solves most steps without pivoting, and the motion is the
    one of a rollout that pivots every step to round-off (a warm answer is accepted only at round-off level, so
    where the step's forces are not unique it is Lemke's answer or none)."""
    from torchhand.interaction import step as step_module

    from .test_resynth import run_pinch

    calls = {"lemke": 0}
    orig = step_module.lcp_solvers.solve

    def counting(*args, **kwargs):
        calls["lemke"] += 1
        return orig(*args, **kwargs)

    step_module.lcp_solvers.solve = counting
    try:
        cold, _ = run_pinch([0.05], lemke_warm=False, duration=0.6)
        n_cold, calls["lemke"] = calls["lemke"], 0
        warm, _ = run_pinch([0.05], lemke_warm=True, duration=0.6)
        n_warm = calls["lemke"]
    finally:
        step_module.lcp_solvers.solve = orig
    assert int(warm["failed_step"][0]) == -1 and (warm["status"] == int(SolverStatus.CONVERGED)).all()
    assert n_warm < 0.5 * n_cold, (n_warm, n_cold)
    # (measured: 1e-14 with this CPU's default kernels, 2e-9 with others: the accepted residual is 1e-10 relative)
    np.testing.assert_allclose(warm["object_pose"][0].numpy(), cold["object_pose"][0].numpy(), atol=1e-8)
    np.testing.assert_allclose(warm["q"][0].numpy(), cold["q"][0].numpy(), atol=1e-8)
