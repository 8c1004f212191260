"""The rotation conversions torchhand takes from kornia are exact in float64 against SciPy's (a reference nobody
here wrote). kornia 0.8.3, which pip picks beside torch < 2.5.1, was 1e-6 off in axis-angle to matrix (and 1e-8 in
the inverse), which made float64 FK rotations non-orthonormal by 1e-6; pyproject.toml asks for kornia >= 0.9."""

from __future__ import annotations

import numpy as np
import torch
from kornia.geometry.conversions import axis_angle_to_rotation_matrix, rotation_matrix_to_axis_angle
from scipy.spatial.transform import Rotation

import torchhand
from torchhand.geometry.poses import matrix_to_quat, quat_to_matrix

TOL = 1e-13


def _rotations(n=500, seed=3):
    R = Rotation.random(n, random_state=seed)
    small = Rotation.from_rotvec(np.random.default_rng(seed).normal(size=(20, 3)) * 1e-9)   # near identity
    return Rotation.concatenate([R, small])


def test_axis_angle_both_ways_match_scipy():
    R = _rotations()
    rv = torch.tensor(R.as_rotvec())
    M = torch.tensor(R.as_matrix())
    assert (axis_angle_to_rotation_matrix(rv) - M).abs().max() < TOL
    back = rotation_matrix_to_axis_angle(M)
    keep = rv.norm(dim=-1) < np.pi - 1e-6                         # away from the half-turn ambiguity
    assert (back[keep] - rv[keep]).abs().max() < TOL


def test_quaternions_both_ways_match_scipy():
    R = _rotations()
    M = torch.tensor(R.as_matrix())
    q_ref = torch.tensor(R.as_quat()[:, [3, 0, 1, 2]])            # SciPy (x, y, z, w) -> (w, x, y, z)
    q = matrix_to_quat(M)
    q = q * torch.sign((q * q_ref).sum(-1, keepdim=True))         # q and -q are one rotation
    assert (q - q_ref).abs().max() < TOL
    assert (quat_to_matrix(q_ref) - M).abs().max() < TOL


def test_float64_fk_rotations_are_orthonormal():
    hand = torchhand.default_hand("right").to(dtype=torch.float64)
    g = torch.Generator().manual_seed(0)
    q = hand.q_rest.double() + 0.3 * torch.randn(16, hand.q_rest.shape[-1], generator=g, dtype=torch.float64)
    R = hand.forward_kinematics(q)[..., :3, :3]
    assert (R.transpose(-1, -2) @ R - torch.eye(3, dtype=torch.float64)).abs().max() < 1e-14
