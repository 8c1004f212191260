"""Shared by the MJCF reader and writer (:mod:`torchhand.hand.mjcf`): rotations and reserved names.

Rotations are NumPy, float64, quaternions wxyz (see :mod:`torchhand.conventions`).
"""

from __future__ import annotations

import math

import numpy as np

_ROOT_WRAPPER = "torchhand_root"
"""Name of the extra top body that carries the free joint when the root link has joints of its own."""


# ----------------------------------------------------------------------------------------------------------------
# Rotations (NumPy, float64, wxyz quaternions)
# ----------------------------------------------------------------------------------------------------------------
def _quat_to_mat(q) -> np.ndarray:
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _mat_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix (Shepperd's method: stable for every angle)."""
    tr = np.trace(R)
    k = int(np.argmax([tr, R[0, 0], R[1, 1], R[2, 2]]))
    if k == 0:
        s = 2 * math.sqrt(max(1 + tr, 0.0))
        q = np.array([s / 4, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s])
    else:
        i, j, l = k - 1, k % 3, (k + 1) % 3
        s = 2 * math.sqrt(max(1 + R[i, i] - R[j, j] - R[l, l], 0.0))
        q = np.empty(4)
        q[0] = (R[l, j] - R[j, l]) / s
        q[1 + i] = s / 4
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + l] = (R[l, i] + R[i, l]) / s
    q = q / np.linalg.norm(q)
    return -q if q[0] < 0 else q


def _axis_angle(axis, angle: float) -> np.ndarray:
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    return _quat_to_mat(np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * a]))


def _z_to_vec(v) -> np.ndarray:
    """MuJoCo's ``mju_quatZ2Vec``: the minimal rotation taking +z to ``v`` (pi about x when v is -z)."""
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v)
    if n < 1e-15:
        return np.eye(3)
    v = v / n
    ax = np.cross([0.0, 0.0, 1.0], v)
    s = np.linalg.norm(ax)
    if s < 1e-15:
        return np.eye(3) if v[2] > 0 else _quat_to_mat([0.0, 1.0, 0.0, 0.0])
    return _axis_angle(ax / s, math.atan2(s, v[2]))


def _pose(R=None, p=None) -> np.ndarray:
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if p is not None:
        T[:3, 3] = p
    return T
