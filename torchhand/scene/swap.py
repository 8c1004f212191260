"""Object swap (Ye & Liu 2012, Fig. 9): the same wrist and object motion with another object.

:func:`swap_object` returns the scene with a new :class:`~torchhand.geometry.objects.RigidObject` whose mesh is
placed in the old object's frame, so the scene's ``object_pose`` (and every wrist track) stays exactly as it was:
the trajectory drives the new mesh. Everything derived from the object (SDF, contact patches, mass properties,
table contacts, required wrenches) is rebuilt from the new scene by whatever method runs on it.

Placement (``align``):

* ``"rest"`` (default): at the first frame where the old object rests on the table (it has table contacts), the new
  object's centre of mass lies straight above the old one's and its lowest point is as high as the old one's lowest
  point, so it rests on the table where the old one did. A scene whose object never rests on a table falls back to
  ``"com"`` (:attr:`Swap.align` says which was used).
* ``"com"``: the centres of mass coincide.
* ``"frame"``: the mesh's own frame is the old object's frame (no move).

``yaw``: degrees the mesh then turns about the world's vertical (its handle or face another way).

``up``: the mesh axis that points up (``"z"``, ``"y"``, ``"x"`` or negated, ``"-y"``): many meshes are y-up (the
Stanford bunny, the bigym mug's OBJ). The mesh is turned so that this axis points along world +z at the reference
frame (the rest frame, or frame 0), before it is placed.

Conventions: metres, kilograms, world z-up; the new mesh is stored in the object frame.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..errors import InputTypeError, InputValueError

__all__ = ["ALIGNS", "UP_AXES", "Swap", "swap_object", "offset_object"]

ALIGNS = ("rest", "com", "frame")
UP_AXES = ("z", "y", "x", "-z", "-y", "-x")


@dataclass(frozen=True)
class Swap:
    """What :func:`swap_object` did: the placement used (``align``, after any fallback), the reference frame
    (``frame``), the mesh's transform into the object frame (``transform``, (4, 4), applied to the new mesh) and the
    new object's mass (kg)."""

    align: str
    frame: int
    transform: np.ndarray
    mass: float

    def to_json(self) -> dict:
        return {"align": self.align, "frame": self.frame, "transform": self.transform.round(9).tolist(),
                "mass": self.mass}


def _up_rotation(up: str) -> np.ndarray:
    """The rotation (3, 3) that turns the mesh axis ``up`` into +z (a proper rotation)."""
    axis = {"x": 0, "y": 1, "z": 2}[up[-1]]
    sign = -1.0 if up.startswith("-") else 1.0
    a = np.zeros(3)
    a[axis] = sign
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(a, z)
    c = float(a @ z)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + k + k @ k / (1.0 + c)


def _rest_frame(scene) -> int | None:
    from ._contacts import environment_contacts

    if scene.environment.ground().empty:
        return None
    on = environment_contacts(scene).mask.any(-1).nonzero()
    return int(on[0, 0]) if on.numel() else None


def swap_object(scene, mesh, *, scale: float = 1.0, mass: float | None = None, align: str = "rest",
                up: str = "z", yaw: float = 0.0, name: str | None = None) -> tuple:
    """The scene with its object replaced (module docstring). Returns ``(scene, Swap)``.

    Args:
        scene: :class:`~torchhand.scene.Scene`
        mesh: a mesh file (anything :func:`~torchhand.geometry.objects.load_object` reads) or a
            :class:`~torchhand.geometry.objects.RigidObject`
        scale: multiplies the mesh's coordinates (a file's units to metres)
        mass: kg; default the old object's mass
        align: ``"rest"``, ``"com"`` or ``"frame"``; up: the mesh's up axis (:data:`UP_AXES`); yaw: degrees
            the mesh turns about the world's vertical at the reference frame, after ``up``
        name: the new object's name (default the file's stem or the object's name)

    Raises:
        InputValueError: a bad ``align``, ``up``, ``scale`` or ``mass``; MissingFileError, FileFormatError,
        MeshError: the mesh cannot be read or used.
    """
    from ..geometry.objects import RigidObject, load_object

    if align not in ALIGNS:
        raise InputValueError(f"align: expected one of {', '.join(ALIGNS)}, got {align!r}")
    if up not in UP_AXES:
        raise InputValueError(f"up: expected one of {', '.join(UP_AXES)}, got {up!r}")
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not (np.isfinite(scale) and scale > 0):
        raise InputValueError(f"scale: expected a finite positive number, got {scale!r}")
    if mass is not None and not (np.isfinite(mass) and mass > 0):
        raise InputValueError(f"mass: expected a finite positive number of kilograms, got {mass!r}")
    if not np.isfinite(yaw):
        raise InputValueError(f"yaw: expected a finite number of degrees, got {yaw!r}")
    if isinstance(mesh, RigidObject):
        tm = mesh.mesh.copy()
        if scale != 1.0:
            tm.apply_scale(scale)
        label = name or mesh.name
    elif isinstance(mesh, (str, Path)):
        tm = load_object(mesh, scale=scale, mass=1.0).mesh
        label = name or Path(mesh).stem
    else:
        raise InputTypeError(f"mesh: expected a mesh file path or a RigidObject, got {type(mesh).__name__}")
    kg = float(scene.object.mass if mass is None else mass)
    frame = _rest_frame(scene) if align == "rest" else None
    used = align if frame is not None or align != "rest" else "com"
    ref = 0 if frame is None else frame
    pose = scene.object_pose[ref].detach().cpu().double().numpy()
    R, t = pose[:3, :3], pose[:3, 3]
    c, s_ = np.cos(np.radians(yaw)), np.sin(np.radians(yaw))
    Rz = np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])
    Q = R.T @ Rz @ _up_rotation(up)             # mesh axes -> object frame, the up axis along world +z at ref
    probe = RigidObject.from_trimesh(_moved(tm, Q, np.zeros(3)), mass=kg, name=label)
    old_com = np.asarray(scene.object.com, dtype=np.float64)
    if used == "frame":
        delta = np.zeros(3)
    else:
        delta = old_com - np.asarray(probe.com, dtype=np.float64)
        if used == "rest":
            old_low = float((np.asarray(scene.object.mesh.vertices) @ R.T + t)[:, 2].min())
            new_low = float(((np.asarray(probe.mesh.vertices) + delta) @ R.T + t)[:, 2].min())
            delta = delta + (old_low - new_low) * R.T[:, 2]
    obj = RigidObject.from_trimesh(_moved(tm, Q, delta), mass=kg, name=label)
    swapped = dataclasses.replace(scene, object=obj, name=f"{scene.name}-{label}")
    return swapped, Swap(align=used, frame=ref, transform=_affine(Q, delta), mass=kg)


def _affine(Q: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """The (4, 4) transform x -> Q x + delta."""
    A = np.eye(4)
    A[:3, :3], A[:3, 3] = Q, delta
    return A


def _moved(mesh, Q: np.ndarray, delta: np.ndarray):
    out = mesh.copy()
    out.apply_transform(_affine(Q, delta))
    return out


def offset_object(scene, offset, *, side: str | None = None):
    """The scene with its object moved by ``offset`` (3,) metres in the wrist frame of hand ``side`` (default the
    first hand), frame by frame: ``object_pose'(t) = W(t) T(offset) W(t)^-1 object_pose(t)``, so the object sits
    at the same place relative to that wrist, ``offset`` away from where it was (Ye & Liu Fig. 7: toward the palm
    for an envelope grasp, away for a fingertip grip). The wrist tracks and the captured object track stay as they
    were.

    Raises:
        InputValueError: a bad ``offset`` or ``side``, or an object moved more than 1 mm into the table.
    """
    o = np.asarray(offset, dtype=np.float64)
    if o.shape != (3,) or not np.isfinite(o).all():
        raise InputValueError(f"offset: expected three finite numbers (metres), got {offset!r}")
    sides = [t.side for t in scene.hands]
    if side is not None and side not in sides:
        raise InputValueError(f"side: scene '{scene.name}' has no {side} hand (hands: {', '.join(sides)})")
    track = scene.hands[sides.index(side) if side is not None else 0]
    W = track.wrist_pose.detach().cpu().double()
    shift = W[:, :3, :3] @ torch.as_tensor(o)                                  # (T, 3) world
    pose = scene.object_pose.detach().cpu().double().clone()
    pose[:, :3, 3] += shift
    ground = scene.environment.ground()
    if not ground.empty:
        v = torch.as_tensor(np.asarray(scene.object.mesh.convex_hull.vertices))
        world = (pose[:, None, :3, :3] @ v[None, :, :, None]).squeeze(-1) + pose[:, None, :3, 3]
        low = (world[..., 2] - ground.support_height(world)).amin(-1)          # height over the surface below
        under = (low < -1e-3).nonzero().squeeze(-1).tolist()
        if under:
            depth = -1e3 * float(low.min())
            raise InputValueError(f"offset: the object would go {depth:.1f} mm into the table at {len(under)} "
                                  f"frame(s) ({under[0]}-{under[-1]})")
    return dataclasses.replace(scene, object_pose=pose.to(scene.object_pose))
