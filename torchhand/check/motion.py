"""Figures of the motion: the object's Newton-Euler balance, the joints' limits, speeds and accelerations, and
how far a solution is from the earlier ones.

Balance: the object's centre of mass ``c`` and inertia ``I`` come from its MESH (:func:`.geometry.object_mesh`,
scaled to the scene's mass); the scene's own ``com`` and ``inertia`` are not used. The linear acceleration ``a``
is the central second difference of ``c`` over the frames; the angular velocity ``omega`` the mean of the two
adjacent relative rotations' rotation vectors (SciPy ``Rotation``) times fps, the angular acceleration ``alpha``
their difference times fps; the first and last frames copy their neighbours (one-sided). Per frame::

    force error  = |sum f_hand + sum f_table + m g + f_ext - m a| / (m |g|)
    torque error = |sum (p - c) x f + tau_ext - (I_w alpha + omega x I_w omega)| / (m |g| extent)

with ``I_w = R I R^T``, ``extent`` the largest side of the mesh's bounding box and ``(f_ext, tau_ext)`` the scene's
external wrench on the object (force, torque about the centre of mass, world; zero when the scene has none).

Joints (hand.xml's limits, radians): the violation ``max(lo - q, q - hi, 0)``; the speed ``|q[t] - q[t-1]| fps``
(reported at frame t); the acceleration ``|q[t+1] - 2 q[t] + q[t-1]| fps^2`` (at frame t).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import ShapeError
from .geometry import ObjectMesh

__all__ = ["object_dynamics", "balance_errors", "joint_limit_violation", "joint_speed", "joint_acceleration",
           "mean_joint_difference"]


def object_dynamics(pose: np.ndarray, com_local: np.ndarray, fps: float):
    """Centre of mass (T, 3), its acceleration (T, 3), angular velocity (T, 3) and acceleration (T, 3), world.

    pose: ``T_world_object``, (T, 4, 4); com_local: (3,), object frame, metres; fps: frames per second
    """
    T = pose.shape[0]
    R = pose[:, :3, :3]
    com = np.einsum("tij,j->ti", R, com_local) + pose[:, :3, 3]
    acc, omega, alpha = np.zeros((T, 3)), np.zeros((T, 3)), np.zeros((T, 3))
    if T >= 3:
        acc[1:-1] = (com[2:] - 2 * com[1:-1] + com[:-2]) * fps ** 2
        acc[0], acc[-1] = acc[1], acc[-2]
    if T >= 2:
        w_mid = (Rotation.from_matrix(R[1:]) * Rotation.from_matrix(R[:-1]).inv()).as_rotvec() * fps
        omega[1:-1] = 0.5 * (w_mid[1:] + w_mid[:-1])
        omega[0], omega[-1] = w_mid[0], w_mid[-1]
        if T >= 3:
            alpha[1:-1] = (w_mid[1:] - w_mid[:-1]) * fps
            alpha[0], alpha[-1] = alpha[1], alpha[-2]
    return com, acc, omega, alpha


def balance_errors(sol, obj: ObjectMesh, mass: float, gravity: np.ndarray,
                   external: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Relative force and torque errors of every frame, (T,) each (see the module docstring).

    sol: a :class:`torchhand.io.result.Solution`; mass: kg; gravity: (3,), m/s^2; external: the external wrench on
    the object (:attr:`torchhand.scene.Scene.external_wrench`), (T, 6), force (N) and torque about the object's
    centre of mass (N m), world, or None. (The torque is taken about this mesh-derived centre of mass.)
    """
    pose = sol.object_pose
    com, acc, omega, alpha = object_dynamics(pose, obj.com, sol.fps)
    mask, emask = sol.contact_mask[..., None], sol.env_contact_mask[..., None]
    cf, ef = sol.contact_force * mask, sol.env_contact_force * emask
    force = cf.sum(1) + ef.sum(1) + mass * gravity
    torque = np.cross(sol.contact_point - com[:, None], cf).sum(1) + \
        np.cross(sol.env_contact_point - com[:, None], ef).sum(1)
    R = pose[:, :3, :3]
    I_w = np.einsum("tij,jk,tlk->til", R, obj.inertia, R)
    L = np.einsum("tij,tj->ti", I_w, omega)
    torque_req = np.einsum("tij,tj->ti", I_w, alpha) + np.cross(omega, L)
    if external is not None:
        ext = np.asarray(external, dtype=np.float64)
        if ext.shape != (pose.shape[0], 6):
            raise ShapeError(f"external: expected shape ({pose.shape[0]}, 6) (the solution's T), got {ext.shape}")
        force = force + ext[:, :3]
        torque = torque + ext[:, 3:]
    weight = mass * float(np.linalg.norm(gravity))
    weight = weight if weight > 0 else mass * 9.81  # zero gravity: still relative to a weight
    f_err = np.linalg.norm(force - mass * acc, axis=-1) / weight
    t_err = np.linalg.norm(torque - torque_req, axis=-1) / (weight * obj.extent)
    return f_err, t_err


def joint_limit_violation(q: np.ndarray, limits: np.ndarray) -> np.ndarray:
    """``max(lo - q, q - hi, 0)`` per frame and joint, (T, D), radians; q (T, D), limits (D, 2)."""
    return np.maximum(np.maximum(limits[:, 0] - q, q - limits[:, 1]), 0.0)


def joint_speed(q: np.ndarray, fps: float) -> np.ndarray:
    """``|q[t] - q[t-1]| fps``, (T, D), rad/s, NaN at frame 0."""
    out = np.full(q.shape, np.nan)
    out[1:] = np.abs(np.diff(q, axis=0)) * fps
    return out


def joint_acceleration(q: np.ndarray, fps: float) -> np.ndarray:
    """``|q[t+1] - 2 q[t] + q[t-1]| fps^2``, (T, D), rad/s^2, NaN at the first and last frames."""
    out = np.full(q.shape, np.nan)
    if q.shape[0] >= 3:
        out[1:-1] = np.abs(q[2:] - 2 * q[1:-1] + q[:-2]) * fps ** 2
    return out


def mean_joint_difference(qa: np.ndarray, qb: np.ndarray) -> float:
    """Mean over frames and joints of ``|qa - qb|``, degrees; qa, qb (T, D) radians (all hands side by side)."""
    return float(np.degrees(np.abs(qa - qb).mean()))
