"""The per-frame synthesis' fast paths (torchhand/manipulation/synth.py, torque_derivs.py): the Goldfarb-Idnani QP
against Clarabel on QPs shaped like the synthesis' steps (many active step bounds, equalities, constraints that
leave the active set), its square solve against NumPy's, the
u-only torques against the torch path (itself checked against MuJoCo in test_manipulate.py) and the direct SDF
query against the grid's public query and trimesh. (The sparse joint columns of the point Jacobian are checked
against MuJoCo's ``mj_jac`` in test_synth_derivs.py.)"""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from torchhand.hand import default_hand
from torchhand.manipulation.synth import SynthContext, _solve, dense_qp, torques
from torchhand.manipulation.torque_derivs import static_torques, tree_order, tree_state


def _synthesis_like_qp(rng, n=40, me=10, mi=50):
    """A strictly convex QP like a Gauss-Newton step: a rank-deficient Gauss-Newton Hessian plus small damping,
    equalities, general inequalities and tight step bounds (+-I rows), most of them active at the solution."""
    J = rng.normal(size=(n // 2, n))
    H = 2 * J.T @ J + np.diag(rng.uniform(1e-3, 1e-1, n))
    g = rng.normal(size=n) * 10
    A = rng.normal(size=(me, n))
    C0 = rng.normal(size=(mi, n))
    x0 = rng.uniform(-0.05, 0.05, n)                   # a feasible point inside the bounds
    b = A @ x0
    d0 = C0 @ x0 + rng.uniform(0, 0.05, mi)
    lo, hi = -0.1 * np.ones(n), 0.1 * np.ones(n)
    C = np.concatenate([C0, np.eye(n), -np.eye(n)])
    d = np.concatenate([d0, hi, -lo])
    return H, g, A, b, C, d


def test_dense_qp_on_synthesis_like_steps_against_clarabel():
    clarabel = pytest.importorskip("clarabel")
    import scipy.sparse as sp

    rng = np.random.default_rng(3)
    active = 0
    for _ in range(12):
        H, g, A, b, C, d = _synthesis_like_qp(rng)
        x, status, viol = dense_qp(H, g, A, b, C, d)
        s = clarabel.DefaultSettings()
        s.verbose = False
        s.tol_gap_abs = s.tol_gap_rel = s.tol_feas = 1e-12
        ref = clarabel.DefaultSolver(sp.csc_matrix(np.triu(H)), g, sp.csc_matrix(np.vstack([A, C])),
                                     np.concatenate([b, d]), [clarabel.ZeroConeT(A.shape[0]),
                                                              clarabel.NonnegativeConeT(C.shape[0])], s).solve()
        xr = np.array(ref.x)
        f, fr = 0.5 * x @ H @ x + g @ x, 0.5 * xr @ H @ xr + g @ xr
        assert status == 0 and viol < 1e-9
        assert abs(f - fr) <= 1e-8 * (1 + abs(fr))
        assert np.abs(x - xr).max() < 1e-6
        active += int((np.abs(C @ x - d) < 1e-9).sum())
    assert active >= 12 * 10                            # active sets well past a few rows


def test_dense_qp_reports_infeasible():
    n = 6
    H, g = np.eye(n), np.zeros(n)
    C = np.stack([np.eye(n)[0], -np.eye(n)[0]])        # x0 <= -1 and x0 >= 1
    d = np.array([-1.0, -1.0])
    x, status, viol = dense_qp(H, g, np.zeros((0, n)), np.zeros(0), C, d)
    assert status == 1 and viol > 0.5 and np.isfinite(x).all()


def test_square_solve_matches_numpy_bitwise_and_raises_on_singular():
    rng = np.random.default_rng(0)
    for m in (1, 4, 17, 40):
        S, r = rng.normal(size=(m, m)), rng.normal(size=m)
        assert np.array_equal(_solve(S, r), np.linalg.solve(S, r))
    with pytest.raises(np.linalg.LinAlgError):
        _solve(np.zeros((3, 3)), np.ones(3))


@pytest.fixture(scope="module")
def hand():
    return default_hand().to("cpu", torch.float64)


def test_static_torques_match_the_torch_path(hand):
    rng = np.random.default_rng(1)
    order = tree_order(hand)
    lim = hand.joint_limits.numpy()
    for _ in range(3):
        q = rng.uniform(lim[:, 0], lim[:, 1])
        root = np.eye(4)
        root[:3, :3] = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        if np.linalg.det(root[:3, :3]) < 0:
            root[:3, 0] *= -1
        root[:3, 3] = rng.normal(size=3) * 0.1
        links = rng.choice(hand.num_links, 4, replace=False)
        h, f = rng.normal(size=(4, 3)) * 0.01, rng.normal(size=(4, 3))
        u = static_torques(order, tree_state(order, q, root), links, h, f)
        u_ref = torques(hand, q[None], root[None], links, h[None], f)[0]
        assert np.abs(u - u_ref).max() <= 1e-12 * (1 + np.abs(u_ref).max())


def test_direct_sdf_query_equals_the_grid_and_trimesh(hand):
    mesh = trimesh.creation.box((0.08, 0.06, 0.04))
    ctx = SynthContext(hand, mesh, np.zeros(6 + hand.num_joints), 30.0, None)
    rng = np.random.default_rng(4)
    lo, hi = (t.numpy() for t in ctx.sdf.box)
    p = rng.uniform(lo, hi, (200, 3))                          # inside the grid (outside it: box distance only)
    sd, grad = ctx.sdf_with_grad(p)
    sd_ref, grad_ref = ctx.sdf.query_with_grad(torch.as_tensor(p)[None])
    assert np.array_equal(sd, sd_ref[0].numpy()) and np.array_equal(grad, grad_ref[0].numpy())
    exact = -trimesh.proximity.signed_distance(mesh, p)        # trimesh: positive inside
    assert np.abs(sd - exact).max() < 1e-3                     # the 1 mm grid's trilinear interpolation
