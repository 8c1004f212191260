"""Environment contacts: where a scene's object rests on the table or the floor, frame by frame.

:func:`environment_contacts` derives padded object-table support contacts (:class:`EnvContacts`) from a
:class:`~torchhand.scene.Scene`; both are re-exported by :mod:`torchhand.scene`. Conventions (see
:mod:`torchhand.conventions`): world z-up, metres, seconds; contact normals point into the object.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch

if TYPE_CHECKING:
    from ._model import Scene

__all__ = ["EnvContacts", "environment_contacts"]


@dataclass(frozen=True, eq=False)
class EnvContacts:
    """Object-table support contacts per frame, padded to ``E`` with ``mask``.

    Fields
        points: contact points on the table (or floor) plane below the supporting object points, (T, E, 3), world,
            metres
        mask: which entries are real contacts, (T, E), bool
        sliding_velocity: tangential velocity of the object's material point at each contact, (T, E, 3), world,
            m/s; exactly zero for a static contact (speed below ``static_speed``) and for padding
        support_index: index into the object's convex-hull vertices, (T, E), int64, -1 for padding
        normal: contact normal, (3,), world, pointing into the object (+z for a table)
    """

    points: torch.Tensor
    mask: torch.Tensor
    sliding_velocity: torch.Tensor
    support_index: torch.Tensor
    normal: torch.Tensor

    @property
    def count(self) -> torch.Tensor:
        """Number of contacts per frame, (T,), int64."""
        return self.mask.sum(dim=-1)


def environment_contacts(scene: Scene, tol: float = 0.003, static_speed: float = 1e-3) -> EnvContacts:
    """Where the object rests on the table (or the floor) in each frame.

    The supporting points are the vertices of the object mesh's convex hull (object frame) whose world height is at
    most ``tol`` above the surface under them (or below it): the table plane, or with a table edge
    (``Environment.table_extent``) the table top inside its rectangle and the floor elsewhere. Velocities are
    central finite differences of their world positions (one-sided at the ends), with the normal (z) component
    removed.

    Args:
        scene: the scene; without a table and a floor every frame has no contact (E = 0).
        tol: height above the table plane that still counts as contact, metres.
        static_speed: tangential speeds below this are reported as exactly zero (static), m/s.

    Returns:
        the padded contacts, E = the largest contact count over the frames.
    """
    from ._parts import _check_number

    tol = _check_number(tol, "tol", low=0.0)
    static_speed = _check_number(static_speed, "static_speed", low=0.0)
    pose = scene.object_pose
    T, dtype, device = scene.T, pose.dtype, pose.device
    normal = torch.tensor([0.0, 0.0, 1.0], dtype=dtype, device=device)
    ground = scene.environment.ground()
    if ground.empty:
        return EnvContacts(pose.new_zeros(T, 0, 3), torch.zeros(T, 0, dtype=torch.bool, device=device),
                           pose.new_zeros(T, 0, 3), torch.zeros(T, 0, dtype=torch.long, device=device), normal)
    hull = np.asarray(scene.object.mesh.convex_hull.vertices, dtype=np.float64)
    V = torch.as_tensor(hull, dtype=dtype, device=device)
    P = torch.einsum("tij,nj->tni", pose[:, :3, :3], V) + pose[:, None, :3, 3]  # (T, N, 3)
    if ground.plain:
        h = scene.environment.table_height
    else:  # the table top inside its rectangle, the floor elsewhere (-inf: nothing to rest on)
        h = ground.support_height(P)
    touching = P[..., 2] - h <= tol
    vel = torch.zeros_like(P)
    if T > 1:
        vel[1:-1] = (P[2:] - P[:-2]) * (0.5 * scene.fps)
        vel[0] = (P[1] - P[0]) * scene.fps
        vel[-1] = (P[-1] - P[-2]) * scene.fps
    vel[..., 2] = 0.0
    vel = torch.where(vel.norm(dim=-1, keepdim=True) < static_speed, torch.zeros_like(vel), vel)
    E = int(touching.sum(dim=-1).max()) if T else 0
    order = torch.sort((~touching).to(torch.int8), dim=-1, stable=True).indices[:, :E]  # contacts first
    mask = torch.gather(touching, 1, order)
    pts = torch.gather(P, 1, order[..., None].expand(-1, -1, 3)).clone()
    pts[..., 2] = h if ground.plain else torch.gather(h, 1, order)
    vel = torch.gather(vel, 1, order[..., None].expand(-1, -1, 3))
    m3 = mask[..., None]
    return EnvContacts(points=torch.where(m3, pts, torch.zeros_like(pts)), mask=mask,
                       sliding_velocity=torch.where(m3, vel, torch.zeros_like(vel)),
                       support_index=torch.where(mask, order, torch.full_like(order, -1)), normal=normal)
