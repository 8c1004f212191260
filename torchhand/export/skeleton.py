"""A hand model as a BVH skeleton, and a hand motion as that skeleton's channels.

Skeleton
    One BVH joint per link of the :class:`~torchhand.hand.HandModel`, named as the link (the MJCF body of
    ``hand.xml``), the root link as ``ROOT``. A BVH joint's frame is aligned with the file's axes in the rest pose
    (every channel zero), while a link frame need not be, so the exported skeleton's rest pose is the hand at
    ``q = 0`` with its wrist at the identity, and each joint sits at its link's origin:

    * ``OFFSET`` of link ``l`` = ``s C (p_l - p_parent)``, the rest origins ``p`` (hand frame, metres) in file
      axes and units (``C``: the axis change, ``s``: file units per metre);
    * an ``End Site`` below each finger's distal link at the fingertip pad point (``HandModel.fingertip``);
    * a link with no child link and no fingertip (a forearm stub, say) gets an End Site along its collision
      capsule, or 1 cm along its rest x axis when it has no geometry, so every leaf bone has a length.

Motion
    With ``T_l(t)`` the link poses from forward kinematics (world, metres) and ``Rrest_l`` the rest rotations,
    the joint's world rotation in the file is ``W_l = C R_l Rrest_lᵀ Cᵀ`` (identity at rest) and its channels
    hold ``W_parentᵀ W_l`` as ``Zrotation Xrotation Yrotation`` (``R = Rz Rx Ry``, degrees, unwrapped along time).
    The root joint has ``Xposition Yposition Zposition`` first: its world position ``s C p_root(t)``, with an
    ``OFFSET`` of zero (so readers that add the channels to the OFFSET and readers that replace it agree). A
    joint whose origin moves relative to its parent (a slide joint, or a hinge whose MJCF anchor is off the body
    origin; none in the built-in, Shadow or Allegro hands) also gets position channels, holding its full local
    position (Blender's importer and :mod:`torchhand.scene.bvh` read a position channel as replacing the OFFSET).

Axes and units: ``up="z"`` keeps torchhand's world axes; ``up="y"`` (the usual BVH convention) maps torchhand's
``(x, y, z)`` to ``(x, z, -y)``, the inverse of the y-up conversion of :mod:`torchhand.scene.mocap`. ``units`` is
``"cm"`` (default, s = 100) or ``"m"`` (s = 1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..scene.bvh import BVHClip
from ..errors import InputValueError, ShapeError
from ..geometry.euler import matrix_to_euler, unwrap_euler

__all__ = ["UNITS", "UP_AXES", "axis_change", "HandSkeleton", "hand_skeleton", "skeleton_motion",
           "skeleton_channels", "hand_motion_clip", "rotation_channels", "to_file"]

UNITS = {"m": 1.0, "cm": 100.0}
"""File units per metre of each ``units`` choice."""

UP_AXES = ("y", "z")
_ROT = ("Zrotation", "Xrotation", "Yrotation")
_POS = ("Xposition", "Yposition", "Zposition")
_MOVE_TOL = 1e-7  # metres: a joint origin moving more than this relative to its parent gets position channels


def axis_change(up: str) -> np.ndarray:
    """``C``, (3, 3): file coordinates of torchhand's world axes for ``up`` ("y" or "z")."""
    if up not in UP_AXES:
        raise InputValueError(f"up: expected 'y' or 'z', got {up!r}")
    if up == "z":
        return np.eye(3)
    return np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True, eq=False)
class HandSkeleton:
    """The BVH skeleton of a hand model (module docstring).

    Fields
        names: BVH joint names, link names then End Sites (``<link>_end``), tuple of J str
        parents: parent of each joint, tuple of J int (-1 for the root link)
        link_of: hand link index of each joint, (J,) int64; the End Site's link for End Sites
        is_end_site: tuple of J bool
        end_point: End Site point in its link's frame, metres, (J, 3) (zero for link joints)
        rest_origin: rest position of each link joint's origin, hand frame, metres, (L, 3)
        rest_rotation: rest rotation of each link, hand frame, (L, 3, 3)
        tip_joint: joint index of each finger's End Site, (F,) int64
    """

    names: tuple
    parents: tuple
    link_of: np.ndarray
    is_end_site: tuple
    end_point: np.ndarray
    rest_origin: np.ndarray
    rest_rotation: np.ndarray
    tip_joint: np.ndarray

    @property
    def num_links(self) -> int:
        return int(self.rest_origin.shape[0])


def hand_skeleton(model) -> HandSkeleton:
    """The BVH skeleton of ``model`` (a :class:`~torchhand.hand.HandModel`), from its rest pose ``q = 0``."""
    m = model.to(device="cpu", dtype=torch.float64)
    L = m.num_links
    rest = m.forward_kinematics(torch.zeros(1, m.num_joints, dtype=torch.float64))[0].numpy()
    parents = [int(p) for p in m.chain.link_parent.tolist()]
    names = list(m.link_names)
    link_of = list(range(L))
    is_end = [False] * L
    end_point = [np.zeros(3)] * L
    tip_joint = []
    distal = m.distal_link.tolist()
    tips = m.fingertip.numpy()
    for f, d in enumerate(distal):
        tip_joint.append(len(names))
        names.append(f"{m.link_names[d]}_end")
        parents.append(int(d))
        link_of.append(int(d))
        is_end.append(True)
        end_point.append(tips[f].copy())
    has_child = set(parents[:L]) | set(distal)
    for l in range(L):
        if l in has_child:
            continue
        names.append(f"{m.link_names[l]}_end")
        parents.append(l)
        link_of.append(l)
        is_end.append(True)
        end_point.append(_leaf_end(m, l))
    return HandSkeleton(tuple(names), tuple(parents), np.array(link_of), tuple(is_end), np.stack(end_point),
                        rest[:, :3, 3].copy(), rest[:, :3, :3].copy(), np.array(tip_joint, dtype=np.int64))


def _leaf_end(m, l: int) -> np.ndarray:
    """A point in link ``l``'s frame for the End Site of a leaf link: the capsule end farther from the origin."""
    a, b = m.capsule_a[l].numpy(), m.capsule_b[l].numpy()
    if float(m.capsule_radius[l]) > 0:
        far = a if np.linalg.norm(a) > np.linalg.norm(b) else b
        if np.linalg.norm(far) > 1e-6:
            return far.copy()
    return np.array([0.01, 0.0, 0.0])


def rotation_channels(R: torch.Tensor) -> np.ndarray:
    """``Zrotation Xrotation Yrotation`` degrees of local rotations ``R`` (T, J, 3, 3), unwrapped along time,
    (T, J, 3)."""
    ang = matrix_to_euler(R, "ZXY")
    ang = torch.stack([unwrap_euler(ang[:, j], "ZXY") for j in range(ang.shape[1])], dim=1)
    return np.rad2deg(ang.numpy())


def skeleton_motion(skeleton: HandSkeleton, X: np.ndarray, X_rest: np.ndarray, point_map: np.ndarray, *,
                    attached: bool = False):
    """Offsets and local channels of ``skeleton`` for link poses given in the output file's coordinates.

    Args:
        skeleton: :func:`hand_skeleton`
        X: link poses in file coordinates, (T, L, 4, 4): rotation = the link's axes in file axes, translation in
            file units; relative to the root's parent frame (the file's world, or the joint the hand hangs from)
        X_rest: the same for the rest pose ``q = 0``, (L, 4, 4)
        point_map: (3, 3) map of link-frame points (metres) to file units and axes (End Sites)
        attached: the root link hangs from a parent joint (its OFFSET is its rest position, no position channels
            unless it moves); otherwise the root carries its world position in channels with a zero OFFSET

    Returns:
        offsets (J, 3) file units; local rotations (T, L, 3, 3); local positions (T, L, 3) file units;
        moving (L,) bool: joints whose local position is not constant (they need position channels)
    """
    L = skeleton.num_links
    parents = np.array(skeleton.parents[:L])
    par = np.where(parents < 0, 0, parents)
    Rr = X_rest[:, :3, :3]
    W = np.einsum("tlab,lcb->tlac", X[:, :, :3, :3], Rr)                           # R_l R_rest_lᵀ
    P = X[:, :, :3, 3]
    local_R = np.einsum("tlba,tlbc->tlac", W[:, par], W)                             # W_parentᵀ W
    local_p = np.einsum("tlba,tlb->tla", W[:, par], P - P[:, par])                   # W_parentᵀ (p - p_parent)
    root = parents < 0
    local_R[:, root], local_p[:, root] = W[:, root], P[:, root]
    offsets = np.zeros((len(skeleton.names), 3))
    rest_o = X_rest[:, :3, 3]
    offsets[:L] = rest_o - rest_o[par]
    offsets[:L][root] = rest_o[root] if attached else 0.0
    for j in range(L, len(skeleton.names)):
        l = int(skeleton.link_of[j])
        offsets[j] = Rr[l] @ (point_map @ skeleton.end_point[j])
    scale = max(float(np.abs(point_map).max()), 1e-12)
    moving = np.abs(local_p - offsets[None, :L]).max(axis=0).max(axis=-1) > _MOVE_TOL * scale
    if not attached:
        moving[root] = True
    return offsets, local_R, local_p, moving


def skeleton_channels(skeleton: HandSkeleton, local_R: np.ndarray, local_p: np.ndarray, moving: np.ndarray):
    """Channel names per joint and the motion (T, C): position channels (for ``moving`` joints) then
    ``Zrotation Xrotation Yrotation`` degrees, End Sites without channels."""
    rot = rotation_channels(torch.from_numpy(np.ascontiguousarray(local_R)))          # (T, L, 3)
    channels, columns = [], []
    for j in range(len(skeleton.names)):
        if skeleton.is_end_site[j]:
            channels.append(())
        elif moving[j]:
            channels.append(_POS + _ROT)
            columns += [local_p[:, j], rot[:, j]]
        else:
            channels.append(_ROT)
            columns.append(rot[:, j])
    return tuple(channels), np.concatenate(columns, axis=1)


def hand_motion_clip(model, skeleton: HandSkeleton, q: np.ndarray, root_pose: np.ndarray | None, fps: float, *,
                     units: str = "cm", up: str = "y", path: str = "") -> BVHClip:
    """The hand motion as a :class:`~torchhand.scene.bvh.BVHClip` of ``skeleton`` (module docstring).

    Args:
        model: the :class:`~torchhand.hand.HandModel` the skeleton was built from
        skeleton: :func:`hand_skeleton` of ``model``
        q: joint angles, (T, D), radians, in ``model.joint_names`` order
        root_pose: wrist poses ``T_world_hand``, (T, 4, 4), world, metres; None: the wrist at the identity
        fps: frames per second, > 0
        units: "cm" or "m"; up: "y" or "z"
        path: the ``path`` field of the clip (where it will be written)

    Returns:
        the clip; joints in ``skeleton.names`` order, root channels ``X/Y/Zposition Z/X/Yrotation``.
    """
    if units not in UNITS:
        raise InputValueError(f"units: expected 'm' or 'cm', got {units!r}")
    if not (np.isfinite(fps) and fps > 0):
        raise InputValueError(f"fps: expected a positive frame rate, got {fps}")
    m = model.to(device="cpu", dtype=torch.float64)
    q = np.asarray(q, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != m.num_joints:
        raise ShapeError(f"q: expected shape (T, {m.num_joints}), got {q.shape}")
    T = q.shape[0]
    root = None if root_pose is None else torch.as_tensor(np.asarray(root_pose, dtype=np.float64))
    if root is not None and tuple(root.shape) != (T, 4, 4):
        raise ShapeError(f"root_pose: expected shape ({T}, 4, 4), got {tuple(root.shape)}")
    C, s = axis_change(up), UNITS[units]
    X = to_file(m.forward_kinematics(torch.from_numpy(q), root).numpy(), C, s)
    X_rest = to_file(m.forward_kinematics(torch.zeros(1, m.num_joints, dtype=torch.float64)).numpy()[0], C, s)
    offsets, local_R, local_p, moving = skeleton_motion(skeleton, X, X_rest, s * C)
    channels, motion = skeleton_channels(skeleton, local_R, local_p, moving)
    motion.setflags(write=False)
    return BVHClip(path=path, names=skeleton.names, parents=skeleton.parents, offsets=offsets, channels=channels,
                   is_end_site=skeleton.is_end_site, frame_time=1.0 / float(fps), motion=motion)


def to_file(T: np.ndarray, C: np.ndarray, s: float) -> np.ndarray:
    """Poses (..., 4, 4) in torchhand's world re-expressed in file axes ``C`` (3, 3) and units ``s`` per metre:
    rotation ``C R Cᵀ``, translation ``s C t``."""
    out = np.array(T, dtype=np.float64, copy=True)
    out[..., :3, :3] = C @ T[..., :3, :3] @ C.T
    out[..., :3, 3] = s * (T[..., :3, 3] @ C.T)
    return out
