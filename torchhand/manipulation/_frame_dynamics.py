"""Liu 2009 Eq. 5's inertial term ``M(q) nu_dot + C(q, nu)`` in the manipulation loop.

* On a written motion (:func:`inertial_torques`): exact, with the rates of the written frames by central
  differences (:func:`torchhand.hand.motion_rates.motion_rates`, one-sided at the ends) and the hand's recursive
  Newton-Euler (:func:`torchhand.hand.inverse_dynamics.inverse_dynamics`, gravity left out: ``n(q)`` is in the
  quasi-static part). The stored torques are ``u = M nu_dot + C + n + sum_i J_i^T f_i``.
* In frame k's objective (:func:`frame_inertia`): frame k+1 is not known yet, so the rates are backward
  differences over frames k-2, k-1 and k; the term is linearised at the frame's starting guess x0,
  ``I(x) = I(x0) + M(q0) delta(x) / dt^2`` with ``delta = (rotvec(R R0^T), p - p0, q - q0)`` (nu_dot is linear in
  delta; the change of M and of the velocity terms within one frame's iterations is left out).

Coordinates (those of :mod:`torchhand.hand.dynamics`): nu = (world angular velocity of the root, world velocity of
the root origin, joint rates); generalised forces (torque about the root origin, force, joint torques), world, N m
and N. NumPy float64 at the boundary.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..hand.dynamics import mass_matrix
from ..hand.inverse_dynamics import inverse_dynamics
from ..hand.motion_rates import motion_rates
from ._frame_geometry import rotvec

__all__ = ["FrameInertia", "frame_inertia", "inertial_torques"]

_NO_GRAVITY = (0.0, 0.0, 0.0)


def inertial_torques(hand, q: np.ndarray, root: np.ndarray, fps: float) -> np.ndarray:
    """``M(q) nu_dot + C(q, nu)`` of a written motion, (T, 6 + D): q (T, D) rad, root T_world_hand (T, 4, 4),
    fps frames per second; rates by central differences of the frames."""
    nu, nu_dot = motion_rates(q, root, fps)
    t = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float64))  # noqa: E731
    return inverse_dynamics(hand, t(q), t(root), t(nu), t(nu_dot), gravity=_NO_GRAVITY).numpy()


def _twist(q1, root1, q0, root0) -> np.ndarray:
    """(rotvec(R1 R0^T), p1 - p0, q1 - q0), (6 + D,): the displacement from frame 0 to frame 1 in nu's coordinates."""
    return np.concatenate([rotvec(root1[:3, :3] @ root0[:3, :3].T), root1[:3, 3] - root0[:3, 3],
                           np.asarray(q1) - np.asarray(q0)])


@dataclass(frozen=True, eq=False)
class FrameInertia:
    """The inertial term of one frame's objective, linearised at the frame's start (module docstring).

    i0: I(x0), (N,) with N = 6 + D; m_dt2: M(q0) / dt^2, (N, N); q0 (D,), root0 (4, 4): the start
    """

    i0: np.ndarray
    m_dt2: np.ndarray
    q0: np.ndarray
    root0: np.ndarray

    def residual(self, q: np.ndarray, root: np.ndarray) -> np.ndarray:
        """I(x) at joint angles q (D,) and root pose (4, 4), (N,)."""
        return self.i0 + self.m_dt2 @ _twist(q, root, self.q0, self.root0)


def frame_inertia(hand, start, prev, before, dt: float) -> FrameInertia:
    """The linearised inertial term of frame k: ``start``, ``prev`` and ``before`` are the hand (objects with ``q``
    (D,) and ``root`` (4, 4)) at the frame's starting guess, at k-1 and at k-2; dt the frame time, s."""
    nu = _twist(start.q, start.root, prev.q, prev.root) / dt
    nu_prev = _twist(prev.q, prev.root, before.q, before.root) / dt
    t = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float64))[None]  # noqa: E731
    q0, r0 = t(start.q), t(start.root)
    i0 = inverse_dynamics(hand, q0, r0, t(nu), t((nu - nu_prev) / dt), gravity=_NO_GRAVITY)[0].numpy()
    m = mass_matrix(hand, q0, r0)[0].numpy()
    return FrameInertia(i0=i0, m_dt2=m / dt ** 2, q0=np.asarray(start.q, dtype=np.float64).copy(),
                        root0=np.asarray(start.root, dtype=np.float64).copy())
