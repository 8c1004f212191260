"""Generalized velocities and accelerations of a written motion by finite differences (NumPy, float64).

The rates are in the coordinates of :mod:`torchhand.hand.dynamics` and :mod:`torchhand.hand.inverse_dynamics`:
``nu = (w, v, qdot)`` (world angular velocity of the root frame, world velocity of the root origin, joint rates)
and ``nu_dot = (alpha, a, qddot)``, so that ``inverse_dynamics(hand, q, root, nu, nu_dot)`` gives the generalized
force that plays the motion back. With ``dt = 1 / fps``:

    half steps   x_{t+1/2} = (x[t+1] - x[t]) / dt               joints and root origin
                 w_{t+1/2} = log(R[t+1] R[t]^T) / dt             rotation vector of the relative rotation, world axes
    frames       rate_t = (rate_{t-1/2} + rate_{t+1/2}) / 2,  acc_t = (rate_{t+1/2} - rate_{t-1/2}) / dt   (interior)
    ends         rate_0 = rate_{1/2},  rate_{T-1} = rate_{T-3/2};  acc_0 = acc_1,  acc_{T-1} = acc_{T-2}

Interior rates and accelerations are second-order accurate (error O(dt^2)); a constant world angular velocity is
recovered exactly. Two frames give accelerations of zero, one frame gives zeros throughout. The root must turn by
less than pi radians between frames (the logarithm takes the shorter rotation).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import InputValueError, ShapeError

__all__ = ["motion_rates"]

_ROTATION_TOL = 1e-6  # largest |R^T R - I| and |det R - 1| accepted for a root rotation


def motion_rates(q, root, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """Generalized velocity and acceleration at every frame of a motion (module docstring for the formulas).

    q:    joint values per frame, (T, D), radians (hinge) / metres (slide); T >= 1
    root: world pose of the root link's parent frame per frame, (T, 4, 4), metres
    fps:  frames per second, > 0
    returns: (nu, nu_dot), each (T, 6 + D) float64: (w rad/s, v m/s, qdot) and (alpha rad/s^2, a m/s^2, qddot),
        world frame
    raises: ShapeError (shapes), InputValueError (fps not a positive number, non-finite values, a root rotation
        that is not one)
    """
    q, root, dt = _inputs(q, root, fps)
    T, N = q.shape[0], 6 + q.shape[1]
    if T == 1:
        return np.zeros((1, N)), np.zeros((1, N))
    half = _half_steps(q, root, dt)  # (T - 1, N): rate_{t+1/2}
    nu = np.empty((T, N))
    nu[0], nu[-1] = half[0], half[-1]
    nu[1:-1] = (half[:-1] + half[1:]) / 2
    nu_dot = np.zeros((T, N))
    if T > 2:
        nu_dot[1:-1] = (half[1:] - half[:-1]) / dt
        nu_dot[0], nu_dot[-1] = nu_dot[1], nu_dot[-2]
    return nu, nu_dot


def _half_steps(q: np.ndarray, root: np.ndarray, dt: float) -> np.ndarray:
    """Rates between consecutive frames, (T - 1, 6 + D): (w world, v, qdot)."""
    R = root[:, :3, :3]
    rel = R[1:] @ R[:-1].transpose(0, 2, 1)  # R[t+1] R[t]^T
    w = Rotation.from_matrix(rel).as_rotvec() / dt
    v = np.diff(root[:, :3, 3], axis=0) / dt
    qdot = np.diff(q, axis=0) / dt
    return np.concatenate([w.reshape(-1, 3), v, qdot], axis=1)


def _inputs(q, root, fps):
    """q (T, D) and root (T, 4, 4) as float64 arrays, and dt; raises with one line naming the argument."""
    if isinstance(fps, bool) or not isinstance(fps, (int, float, np.integer, np.floating)) \
            or not math.isfinite(fps) or fps <= 0:
        raise InputValueError(f"fps: expected a positive finite number, got {fps!r}")
    q = _array(q, "q")
    root = _array(root, "root")
    if q.ndim != 2 or q.shape[0] < 1:
        raise ShapeError(f"q: expected shape (T, D) with T >= 1, got {q.shape}")
    if root.shape != (q.shape[0], 4, 4):
        raise ShapeError(f"root: expected shape ({q.shape[0]}, 4, 4), got {root.shape}")
    R = root[:, :3, :3]
    err = np.abs(R.transpose(0, 2, 1) @ R - np.eye(3)).max(axis=(1, 2))
    bad = (err > _ROTATION_TOL) | (np.abs(np.linalg.det(R) - 1) > _ROTATION_TOL)
    if bad.any():
        raise InputValueError(f"root: frame {int(np.flatnonzero(bad)[0])} does not hold a rotation")
    return q, root, 1.0 / float(fps)


def _array(x, name: str) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise InputValueError(f"{name}: expected numbers, got {type(x).__name__} ({err})") from None
    if not np.isfinite(a).all():
        raise InputValueError(f"{name}: contains NaN or inf")
    return a
