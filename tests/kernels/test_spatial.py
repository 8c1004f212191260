"""Spatial algebra (kernels/spatial.py) against SciPy rotations, matrix exponentials and finite differences."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import torch
from scipy.spatial.transform import Rotation

from torchhand.kernels.spatial import (adjoint, exp_twist, gamma, se3_inverse, shift_wrench, skew, so3_log,
                                       spatial_cross, wrench_from_spatial, wrench_to_spatial)

TOL = {torch.float32: 2e-5, torch.float64: 1e-12}


def _poses(B: int, seed: int, dtype=torch.float64) -> torch.Tensor:
    rng = np.random.default_rng(seed)
    E = np.tile(np.eye(4), (B, 1, 1))
    E[:, :3, :3] = Rotation.random(B, random_state=seed).as_matrix()
    E[:, :3, 3] = rng.normal(0, 0.3, (B, 3))
    return torch.from_numpy(E).to(dtype)


def _randn(*shape, seed: int, dtype=torch.float64) -> torch.Tensor:
    return torch.from_numpy(np.random.default_rng(seed).normal(size=shape)).to(dtype)


@pytest.mark.parametrize("B", [1, 7])
def test_shapes_and_adjoint_group_laws(B, dtype):
    E1, E2 = _poses(B, 0, dtype), _poses(B, 1, dtype)
    A1 = adjoint(E1)
    assert A1.shape == (B, 6, 6) and A1.dtype == dtype
    eye = torch.eye(6, dtype=dtype).expand(B, 6, 6)
    torch.testing.assert_close(adjoint(se3_inverse(E1)) @ A1, eye, atol=10 * TOL[dtype], rtol=0)   # Ad(E^-1) = Ad^-1
    torch.testing.assert_close(adjoint(E1 @ E2), A1 @ adjoint(E2), atol=10 * TOL[dtype], rtol=0)
    r = _randn(B, 4, 3, seed=2, dtype=dtype)
    assert gamma(r).shape == (B, 12, 6)
    assert spatial_cross(_randn(B, 6, seed=3, dtype=dtype)).shape == (B, 6, 6)
    assert exp_twist(_randn(B, 6, seed=3, dtype=dtype), 0.1).shape == (B, 4, 4)


def test_adjoint_maps_point_velocities_between_frames():
    """A body with twist phi_i in frame i moves the point x_i with Gamma(x_i) phi_i; in frame j (E = E_ji from
    SciPy rotations) the same point x_j = E x_i moves with Gamma(x_j) Ad(E) phi_i = Theta Gamma(x_i) phi_i."""
    B = 7
    E = _poses(B, 4)
    phi = _randn(B, 6, seed=5)
    x_i = _randn(B, 5, 3, seed=6)
    x_j = x_i @ E[:, :3, :3].transpose(1, 2) + E[:, None, :3, 3]
    v_i = (gamma(x_i) @ phi[..., None]).reshape(B, 5, 3)
    v_j = (gamma(x_j) @ (adjoint(E) @ phi[..., None])).reshape(B, 5, 3)
    torch.testing.assert_close(v_j, v_i @ E[:, :3, :3].transpose(1, 2), atol=1e-12, rtol=0)


def test_power_is_frame_invariant():
    """phi_j = Ad phi_i, w_i = Ad^T w_j  =>  phi_i^T w_i = phi_j^T w_j; a force f at r is the wrench (r x f, f)."""
    B = 7
    E = _poses(B, 7)
    phi_i, w_j = _randn(B, 6, seed=8), _randn(B, 6, seed=9)
    A = adjoint(E)
    p_j = ((A @ phi_i[..., None]).squeeze(-1) * w_j).sum(-1)
    p_i = (phi_i * (A.transpose(1, 2) @ w_j[..., None]).squeeze(-1)).sum(-1)
    torch.testing.assert_close(p_i, p_j, atol=1e-12, rtol=0)
    r, f = _randn(B, 1, 3, seed=10), _randn(B, 1, 3, seed=11)
    w = (gamma(r).transpose(1, 2) @ f.reshape(B, 3, 1)).squeeze(-1)
    ref = np.concatenate([np.cross(r[:, 0].numpy(), f[:, 0].numpy()), f[:, 0].numpy()], -1)
    np.testing.assert_allclose(w.numpy(), ref, atol=1e-14)
    # shifting the reference point: the power of the twist about p equals that about the origin
    p = _randn(B, 3, seed=12)
    T = torch.eye(4, dtype=torch.float64).repeat(B, 1, 1)
    T[:, :3, 3] = p
    phi_p = (adjoint(se3_inverse(T)) @ phi_i[..., None]).squeeze(-1)       # same motion, frame at p
    torch.testing.assert_close((phi_p * shift_wrench(w_j, p)).sum(-1), (phi_i * w_j).sum(-1), atol=1e-12, rtol=0)


def test_point_displacement_is_h_gamma_ad_phi():
    """E' = E exp(h phi^): a body point r moves by h Gamma(r) Ad(E) phi to first order (central differences)."""
    B = 7
    E = _poses(B, 13)
    phi = _randn(B, 6, seed=14)
    r = _randn(B, 3, 3, seed=15)
    h = 1e-5

    def moved(hh):
        T = E @ exp_twist(phi, hh) @ se3_inverse(E)
        return r @ T[:, :3, :3].transpose(1, 2) + T[:, None, :3, 3]

    fd = (moved(h) - moved(-h)) / 2
    lin = h * (gamma(r) @ adjoint(E) @ phi[..., None]).reshape(B, 3, 3)
    torch.testing.assert_close(fd, lin, atol=1e-14, rtol=1e-8)


@pytest.mark.parametrize("scale", [1e-9, 1e-3, 0.5, 3.0])
def test_exp_twist_matches_matrix_exponential(scale, dtype):
    B = 7
    phi = _randn(B, 6, seed=16) * scale
    h = torch.linspace(0.5, 1.5, B, dtype=torch.float64)
    got = exp_twist(phi.to(dtype), h.to(dtype))
    for b in range(B):
        X = np.zeros((4, 4))
        X[:3, :3] = skew(phi[b, :3]).numpy()
        X[:3, 3] = phi[b, 3:].numpy()
        ref = scipy.linalg.expm(float(h[b]) * X)
        np.testing.assert_allclose(got[b].double().numpy(), ref, atol=50 * TOL[dtype], rtol=0)
        rot = Rotation.from_rotvec(float(h[b]) * phi[b, :3].numpy()).as_matrix()
        np.testing.assert_allclose(got[b, :3, :3].double().numpy(), rot, atol=50 * TOL[dtype], rtol=0)


def test_spatial_cross_is_the_derivative_of_the_adjoint():
    """[phi] = d/dt Ad(exp(t phi^)) at t = 0; and Eq. 3's bias [phi]^T M phi is (-w x I w, -m w x v)."""
    B = 7
    phi = _randn(B, 6, seed=17)
    t = 1e-6
    fd = (adjoint(exp_twist(phi, t)) - adjoint(exp_twist(phi, -t))) / (2 * t)
    torch.testing.assert_close(fd, spatial_cross(phi), atol=1e-8, rtol=0)
    inertia, m = torch.diag(torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)), 0.7
    M = torch.block_diag(inertia, m * torch.eye(3, dtype=torch.float64))
    bias = (spatial_cross(phi).transpose(1, 2) @ (M @ phi[..., None])).squeeze(-1)
    w, v = phi[:, :3], phi[:, 3:]
    ref = torch.cat([-torch.linalg.cross(w, w @ inertia), -m * torch.linalg.cross(w, v)], -1)
    torch.testing.assert_close(bias, ref, atol=1e-12, rtol=0)


def test_so3_log_matches_scipy():
    rv = np.concatenate([np.random.default_rng(18).normal(size=(6, 3)),
                         [[1e-9, 0, 0], [0, 0, 0], [np.pi - 1e-7, 0, 0], [0, 2.0, 1.0]]])
    R = torch.from_numpy(Rotation.from_rotvec(rv).as_matrix())
    got = so3_log(R).numpy()
    ref = Rotation.from_matrix(R.numpy()).as_rotvec()
    # rotation vectors at angle ~pi are defined up to sign: compare the rotations they make
    np.testing.assert_allclose(Rotation.from_rotvec(got).as_matrix(), R.numpy(), atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), np.linalg.norm(ref, axis=1), atol=1e-9)


def test_wrench_order_round_trip():
    w_ft = _randn(7, 6, seed=19)
    w = wrench_to_spatial(w_ft)
    torch.testing.assert_close(w[:, :3], w_ft[:, 3:])
    torch.testing.assert_close(wrench_from_spatial(w), w_ft)


def test_bad_input():
    with pytest.raises(ValueError, match=r"adjoint: E must have shape \(B, 4, 4\)"):
        adjoint(torch.eye(4))
    with pytest.raises(ValueError, match="gamma: r"):
        gamma(torch.zeros(2, 3))
    with pytest.raises(ValueError, match="exp_twist: phi"):
        exp_twist(torch.zeros(2, 3), 0.1)
    with pytest.raises(ValueError, match="floating point"):
        spatial_cross(torch.zeros(2, 6, dtype=torch.long))
