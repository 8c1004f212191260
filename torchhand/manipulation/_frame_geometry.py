"""Small geometry of the per-frame synthesis (:mod:`.synth`): rotation vectors and matrices, closest points of
segment pairs, a capsule axis's parameter, tangent frames, zero-padding of Jacobians."""

from __future__ import annotations

import math

import numpy as np


# ------------------------------------------------------------------------------------------------ rotations
def exp_rot(w: np.ndarray) -> np.ndarray:
    """Rotation matrices of rotation vectors, (..., 3) -> (..., 3, 3) (Rodrigues)."""
    w = np.asarray(w, dtype=np.float64)
    th = np.linalg.norm(w, axis=-1)[..., None, None]
    K = np.zeros(w.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -w[..., 2], w[..., 1], -w[..., 0]
    K = K - np.swapaxes(K, -1, -2)
    small = th < 1e-8
    a = np.where(small, 1.0, np.sin(th) / np.where(small, 1.0, th))
    b = np.where(small, 0.5, (1 - np.cos(th)) / np.where(small, 1.0, th * th))
    return np.eye(3) + a * K + b * (K @ K)


def rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation vector of a rotation matrix (3, 3) -> (3,): the angle from atan2(|w| / 2, (tr R - 1) / 2), w the
    skew part (accurate at small angles); beyond about 154 degrees, where the skew part loses the axis, SciPy's."""
    R = np.asarray(R, dtype=np.float64)
    c = 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0)
    if c > -0.9:
        w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
        sn = 0.5 * math.sqrt(w @ w)
        return w * (0.5 / c if sn < 1e-12 else math.atan2(sn, c) / (2.0 * sn))
    from scipy.spatial.transform import Rotation
    return Rotation.from_matrix(R).as_rotvec()


def _closest_segment_points(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray):
    """Closest points of segment pairs [p1, q1] and [p2, q2], (P, 3) each (Ericson, Real-Time Collision Detection,
    5.1.9; degenerate segments are points). Returns (c1 (P, 3), c2 (P, 3))."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e = (d1 * d1).sum(-1), (d2 * d2).sum(-1)
    f, c, b = (d2 * r).sum(-1), (d1 * r).sum(-1), (d1 * d2).sum(-1)
    eps = 1e-18
    denom = a * e - b * b
    s = np.where(denom > eps, np.clip((b * f - c * e) / np.where(denom > eps, denom, 1.0), 0.0, 1.0), 0.0)
    t = np.where(e > eps, (b * s + f) / np.where(e > eps, e, 1.0), 0.0)
    s = np.where(t < 0.0, np.clip(-c / np.where(a > eps, a, 1.0), 0.0, 1.0), s)
    s = np.where(t > 1.0, np.clip((b - c) / np.where(a > eps, a, 1.0), 0.0, 1.0), s)
    t = np.clip(t, 0.0, 1.0)
    s = np.where(a > eps, s, 0.0)
    return p1 + s[:, None] * d1, p2 + t[:, None] * d2


def _axis_param(a: np.ndarray, seg: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Position in [0, 1] along each capsule axis (a + s seg) of the points h (H, 3), link frame."""
    return np.clip(((h - a) * seg).sum(-1) / np.maximum((seg * seg).sum(-1), 1e-18), 0.0, 1.0)


def _pad(J: np.ndarray, nv: int) -> np.ndarray:
    out = np.zeros(J.shape[:-1] + (nv,))
    out[..., :J.shape[-1]] = J
    return out


def _tangents(n: np.ndarray):
    """Two unit tangents (t1, t2) of a unit normal n (3,): t1 = n x a / |n x a| (a = x, or y when n is near x),
    t2 = n x t1 (written out: np.cross's overhead dominates at this size)."""
    n0, n1, n2 = float(n[0]), float(n[1]), float(n[2])
    if abs(n0) < 0.9:                                     # n x (1, 0, 0)
        t1 = np.array([0.0, n2, -n1])
    else:                                                 # n x (0, 1, 0)
        t1 = np.array([-n2, 0.0, n0])
    t1 /= math.sqrt(t1 @ t1)
    a0, a1, a2 = t1
    return t1, np.array([n1 * a2 - n2 * a1, n2 * a0 - n0 * a2, n0 * a1 - n1 * a0])
