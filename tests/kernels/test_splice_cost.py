"""Splicing costs (Majkowska et al. 2006, Eqs. 6-9) against direct per-cell computations and invariants."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from torchhand.kernels.splice_cost import (forearm_hand_vectors, palm_cost, sign_cost, sign_cost_yaw,
                                           sign_features, signs_from_derivatives, smooth_derivatives, window_yaw)


def _tracks(B, T, seed, K=4):
    g = torch.Generator().manual_seed(seed)
    t = torch.linspace(0, 4, T, dtype=torch.float64)
    freq = torch.rand(B, 1, K, 3, generator=g, dtype=torch.float64) * 2 + 0.5
    phase = torch.rand(B, 1, K, 3, generator=g, dtype=torch.float64) * 6.28
    return 0.2 * torch.sin(freq * t.view(1, T, 1, 1) + phase)


def _rot_z(a: float) -> torch.Tensor:
    c, s = math.cos(a), math.sin(a)
    return torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)


def test_derivatives_of_a_parabola():
    t = torch.arange(50, dtype=torch.float64) / 25.0                       # 25 fps
    x = torch.zeros(1, 50, 1, 3, dtype=torch.float64)
    x[0, :, 0, 0] = t * t
    v, a = smooth_derivatives(x, 25.0, sigma=0.0)
    assert torch.allclose(v[0, 1:-1, 0, 0], 2 * t[1:-1], atol=1e-12)
    assert torch.allclose(a[0, 2:-2, 0, 0], torch.full((46,), 2.0, dtype=torch.float64), atol=1e-9)


def test_dead_zone_makes_holds_zero():
    x = _tracks(1, 120, 0)
    x[:, 40:80] = x[:, 40:41]                                              # a hold
    s = sign_features(x, 30.0, sigma=0.0, dead_zone=0.05)
    assert s.dtype == torch.int8 and s.shape == (1, 120, 4, 6)
    assert (s[0, 43:77, :, :3] == 0).all()                                 # velocity signs vanish inside the hold
    assert (s[0, :30] != 0).any()


def test_sign_cost_equals_cellwise_sum():
    fp = sign_features(_tracks(3, 40, 1), 30.0)
    fq = sign_features(_tracks(3, 55, 2), 60.0)
    C = sign_cost(fp, fq)
    a = fp.reshape(3, 40, -1).double()
    b = fq.reshape(3, 55, -1).double()
    ref = ((a.unsqueeze(2) - b.unsqueeze(1)) ** 2).sum(-1)
    assert C.shape == (3, 40, 55)
    assert torch.equal(C.double(), ref)
    assert C.min() >= 0 and C.max() <= 96


def test_window_yaw_recovers_a_known_turn_against_a_grid_search():
    P = _tracks(1, 30, 3)
    for angle in (0.3, -2.5, 3.0):
        Q = torch.einsum("ij,btkj->btki", _rot_z(-angle), P) + torch.tensor([0.1, -0.2, 0.05], dtype=torch.float64)
        theta = window_yaw(P, Q, frames=5)
        diag = torch.diagonal(theta[0])
        err = torch.remainder(diag - angle + math.pi, 2 * math.pi) - math.pi
        assert err.abs().max() < 1e-9
    # an off-diagonal cell: the least-squares yaw over the 20 points, by brute force
    Q = _tracks(1, 30, 4)
    theta = window_yaw(P, Q, frames=5)[0, 10, 17].item()
    Pw = P[0, 8:13].reshape(-1, 3).numpy()
    Qw = Q[0, 15:20].reshape(-1, 3).numpy()
    Pc, Qc = Pw - Pw.mean(0), Qw - Qw.mean(0)
    grid = np.linspace(-math.pi, math.pi, 200001)
    c, s = np.cos(grid), np.sin(grid)
    # sum |P - R Q|^2 over x, y for each yaw
    rx = c[:, None] * Qc[None, :, 0] - s[:, None] * Qc[None, :, 1]
    ry = s[:, None] * Qc[None, :, 0] + c[:, None] * Qc[None, :, 1]
    err = ((Pc[None, :, 0] - rx) ** 2 + (Pc[None, :, 1] - ry) ** 2).sum(1)
    best = grid[err.argmin()]
    assert abs(math.remainder(theta - best, 2 * math.pi)) < 1e-4


def test_sign_cost_yaw_is_yaw_invariant_and_reduces_to_sign_cost():
    P, Q = _tracks(2, 30, 5), _tracks(2, 44, 6)
    vp, ap = smooth_derivatives(P, 30.0)
    vq, aq = smooth_derivatives(Q, 30.0)
    zero = torch.zeros(2, 30, 44, dtype=torch.float64)
    C0 = sign_cost_yaw(vp, ap, vq, aq, zero, block=7)
    ref = sign_cost(signs_from_derivatives(vp, ap), signs_from_derivatives(vq, aq))
    assert torch.equal(C0, ref)
    # turn the hand clip by -psi and compensate with theta = psi: the same cost (thresholds are yaw-invariant)
    psi = 0.7
    R = _rot_z(-psi)
    Cr = sign_cost_yaw(vp, ap, vq @ R.T, aq @ R.T, zero + psi, block=64)
    assert (Cr != C0).double().mean() < 0.01                                # float ties at the dead-zone edge only


def test_palm_cost_is_the_angle():
    hp = torch.randn(2, 6, 3, dtype=torch.float64)
    hq = torch.randn(2, 9, 3, dtype=torch.float64) * 3
    C = palm_cost(hp, hq)
    for b, i, j in ((0, 1, 2), (1, 5, 8), (1, 0, 0)):
        u, v = hp[b, i].numpy(), hq[b, j].numpy()
        ref = math.acos(float(np.clip(u @ v / np.linalg.norm(u) / np.linalg.norm(v), -1, 1)))
        assert abs(C[b, i, j].item() - ref) < 1e-12


def test_forearm_hand_vectors_follow_eq8():
    x = torch.randn(1, 3, 4, 3, dtype=torch.float64)
    f, h, w = forearm_hand_vectors(x)
    mid = (x[:, :, 0] + x[:, :, 1]) / 2
    assert torch.allclose(f, x[:, :, 2] - mid) and torch.allclose(h, x[:, :, 3] - mid)
    assert torch.allclose(w, x[:, :, 0] - x[:, :, 1])


def test_batch_rows_are_independent():
    P7, Q7 = _tracks(7, 25, 8), _tracks(7, 31, 9)
    C7 = sign_cost(sign_features(P7, 30.0), sign_features(Q7, 30.0))
    C1 = sign_cost(sign_features(P7[3:4], 30.0), sign_features(Q7[3:4], 30.0))
    assert torch.equal(C7[3:4], C1)
    T7 = window_yaw(P7.float(), Q7.float())
    assert T7.dtype == torch.float32 and T7.shape == (7, 25, 31)


def test_bad_shapes_raise():
    with pytest.raises(ValueError, match="P: expected marker positions"):
        window_yaw(torch.zeros(2, 5, 3), torch.zeros(2, 5, 4, 3))
    with pytest.raises(TypeError, match="x: expected a floating dtype"):
        smooth_derivatives(torch.zeros(1, 5, 4, 3, dtype=torch.long), 30.0)
