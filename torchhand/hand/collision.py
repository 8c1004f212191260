"""Hand–object penetration and finger–finger interpenetration for a batch of hand poses.

Thin typed wrappers over :mod:`torchhand.kernels.penetration`: they take a :class:`~torchhand.hand.HandModel`, the
link poses from its forward kinematics, an object's :class:`~torchhand.geometry.sdf.SDFGrid` and the object's world pose.
Conventions: metres; SDF negative inside; link and object poses are world ``(B, 4, 4)`` transforms.
"""

from __future__ import annotations

import torch

from torchhand.kernels.penetration import PenetrationResult, capsule_interpenetration, link_sample_penetration

from ..conventions import check_tensor
from .model import HandModel
from ..geometry.sdf import SDFGrid

__all__ = ["PenetrationResult", "hand_object_penetration", "finger_interpenetration", "rigid_inverse"]


def rigid_inverse(T: torch.Tensor) -> torch.Tensor:
    """Inverse of rigid transforms (..., 4, 4) without a general matrix inverse."""
    R = T[..., :3, :3].transpose(-1, -2)
    out = torch.zeros_like(T)
    out[..., :3, :3] = R
    out[..., :3, 3] = -(R @ T[..., :3, 3:4]).squeeze(-1)
    out[..., 3, 3] = 1
    return out


def hand_object_penetration(hand: HandModel, link_poses: torch.Tensor, sdf: SDFGrid,
                            object_pose: torch.Tensor) -> PenetrationResult:
    """Signed distances of the hand's surface samples to the object and the deepest point of each link.

    link_poses:  T_world_link from ``hand.forward_kinematics``, (B, L, 4, 4)
    sdf:         the object's grid (object frame), same device and dtype as ``link_poses``
    object_pose: T_world_object, (B, 4, 4)
    returns: :class:`PenetrationResult` with ``sd (B, S)`` (negative = inside the object), ``deepest_value (B, L)``,
        ``deepest_index (B, L)``, ``deepest_point (B, L, 3)`` and ``deepest_normal (B, L, 3)`` (world)
    """
    B = link_poses.shape[0]
    check_tensor(link_poses, "link_poses", (B, hand.num_links, 4, 4))
    check_tensor(object_pose, "object_pose", (B, 4, 4))
    return link_sample_penetration(link_poses, hand.sample_points.to(link_poses), hand.sample_link,
                                   rigid_inverse(object_pose), sdf.values, sdf.origin, sdf.voxel_size,
                                   corners=sdf.corners)


def finger_interpenetration(hand: HandModel, link_poses: torch.Tensor) -> torch.Tensor:
    """Interpenetration depth of every finger–finger capsule pair in ``hand.collision_pairs``.

    link_poses: (B, L, 4, 4)
    returns: depth (B, Q), metres; positive where two fingers' capsules overlap
    """
    B = link_poses.shape[0]
    check_tensor(link_poses, "link_poses", (B, hand.num_links, 4, 4))
    depth, _, _ = capsule_interpenetration(link_poses, hand.capsule_a.to(link_poses), hand.capsule_b.to(link_poses),
                                           hand.capsule_radius.to(link_poses), hand.collision_pairs)
    return depth
