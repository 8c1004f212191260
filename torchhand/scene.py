"""Scenes: an object trajectory, one or two wrist trajectories, and the environment they act in.

A :class:`Scene` is the input of hand-motion synthesis: the object's 6-DOF motion and the wrists' 6-DOF motion are
given; the fingers are what torchhand fills in. Conventions (see :mod:`torchhand.conventions`): world z-up,
metres, seconds, kilograms; poses are 4x4 rigid transforms ``T_world_frame`` (column vectors), float64. The hand
frame of a :class:`HandTrack` has its origin at the wrist joint centre, +x toward the fingertips, the palm facing
-z, +y toward the thumb for a right hand (a left hand is mirrored through the x-z plane: thumb toward -y).

Scenes come from :func:`load_scene` (a built-in name, see :mod:`torchhand.scenes`, or a scene directory, see
``docs/scene_format.md``), from :func:`torchhand.mocap.import_mocap_scene`, or are built directly. Building a
:class:`Scene` runs the cheap checks (types, shapes, ranges); :meth:`Scene.validate` adds the value checks that
force a host sync (finite, rigid transforms) and is run by every loader.

Directory I/O is in :mod:`torchhand.scene_io` and object-table contacts in :mod:`torchhand.contacts_env`; their public
names (:class:`EnvContacts`, :func:`environment_contacts`) are re-exported here.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from kornia.geometry.conversions import quaternion_to_rotation_matrix, rotation_matrix_to_quaternion

from .contacts_env import EnvContacts, environment_contacts
from .conventions import check_transforms
from .errors import InputTypeError, InputValueError, MissingFileError, ShapeError, UnknownNameError
from .objects import RigidObject

__all__ = [
    "SIDES",
    "FORMAT_VERSION",
    "HandTrack",
    "Environment",
    "MocapSource",
    "Scene",
    "EnvContacts",
    "environment_contacts",
    "load_scene",
    "interpolate_poses",
    "smooth_poses",
]

SIDES = ("right", "left")
"""Hand sides, in the order hands are stored in a scene file."""

FORMAT_VERSION = 2
"""Version of the scene directory format written by :meth:`Scene.export` (``docs/scene_format.md``). Version 2
added the optional ``[source]`` table; version-1 files still load."""

DEFAULT_GRAVITY = (0.0, 0.0, -9.81)
"""Gravity, (3,), world, m/s^2."""


def _default_gravity() -> torch.Tensor:
    return torch.tensor(DEFAULT_GRAVITY, dtype=torch.float64)


def _check_pose_tensor(x, name: str, T: int | None = None) -> None:
    if not isinstance(x, torch.Tensor):
        raise InputTypeError(f"{name}: expected a torch.Tensor (T, 4, 4), got {type(x).__name__}")
    if x.dim() != 3 or tuple(x.shape[1:]) != (4, 4) or x.shape[0] < 1:
        raise ShapeError(f"{name}: expected shape (T, 4, 4) with T >= 1, got {tuple(x.shape)}")
    if T is not None and x.shape[0] != T:
        raise ShapeError(f"{name}: expected T = {T} frames (as object_pose), got {x.shape[0]}")
    if not x.is_floating_point():
        raise InputTypeError(f"{name}: expected a floating-point tensor, got dtype {x.dtype}")


def _check_number(value, name: str, *, low: float | None = None, strict: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InputTypeError(f"{name}: expected a number, got {type(value).__name__}")
    v = float(value)
    if not math.isfinite(v) or (low is not None and (v <= low if strict else v < low)):
        bound = "" if low is None else f" {'>' if strict else '>='} {low:g}"
        raise InputValueError(f"{name}: expected a finite number{bound}, got {value}")
    return v


@dataclass(frozen=True, eq=False)
class HandTrack:
    """The given motion of one wrist.

    Fields
        side: "right" or "left"
        wrist_pose: hand (wrist) frame poses ``T_world_hand``, (T, 4, 4), world, metres, float64
        length: hand length, wrist joint centre to middle fingertip, float, metres (default 0.19); scales the
            built-in hand, informational for an MJCF hand
        model: "default" (the built-in human hand scaled by ``length``) or the path of an MJCF hand (absolute once
            loaded from a scene directory; :func:`torchhand.hand.mount.track_hand` builds the model)
    """

    side: str
    wrist_pose: torch.Tensor
    length: float = 0.19
    model: str = "default"

    def __post_init__(self):
        if self.side not in SIDES:
            raise InputValueError(f"HandTrack.side: expected 'right' or 'left', got {self.side!r}")
        _check_pose_tensor(self.wrist_pose, f"HandTrack.wrist_pose ({self.side})")
        object.__setattr__(self, "length", _check_number(self.length, "HandTrack.length", low=0.0, strict=True))
        if not isinstance(self.model, str) or not self.model:
            raise InputValueError(f"HandTrack.model: expected 'default' or an MJCF path, got {self.model!r}")

    @property
    def T(self) -> int:
        """Number of frames."""
        return int(self.wrist_pose.shape[0])


@dataclass(frozen=True)
class Environment:
    """What the object can touch besides the hands.

    Fields
        table: whether there is a horizontal table plane, bool
        table_height: z of the table plane, float, world, metres (ignored when ``table`` is False)
        friction: object-table Coulomb friction coefficient, float, >= 0
    """

    table: bool = False
    table_height: float = 0.0
    friction: float = 0.5

    def __post_init__(self):
        if not isinstance(self.table, (bool, np.bool_)):
            raise InputTypeError(f"Environment.table: expected a bool, got {type(self.table).__name__}")
        object.__setattr__(self, "table", bool(self.table))
        object.__setattr__(self, "table_height", _check_number(self.table_height, "Environment.table_height"))
        object.__setattr__(self, "friction", _check_number(self.friction, "Environment.friction", low=0.0))


@dataclass(frozen=True)
class MocapSource:
    """Where the wrist tracks of a scene imported from motion capture came from (``scene import-mocap``), so that
    results can be written back onto the captured file (``torchhand export --onto``).

    Fields
        kind: "body" (a body BVH with a wrist joint per side) or "hand" (a hand BVH per side)
        wrists: ``(side, file, joint)`` per hand: the BVH file (absolute path at import time) and its wrist joint
        fps: the source's frame rate, 1/s
        frames: the number of frames of the source file
        first_frame: the source frame (fractional after resampling) at the scene's frame 0
        units_scale: metres per source unit; up_axis: "y" or "z"; handedness: "right" or "left"
        hand_rotation: ``(side, R_fix)`` per hand: the fixed rotation (3, 3), row-major nested tuples, from the
            wrist joint's local axes to the hand frame (:func:`torchhand.mocap.hand_frame_rotation`)

    The scene's frame ``k`` is the source's frame ``first_frame + k * fps / scene.fps``.
    """

    kind: str
    wrists: tuple
    fps: float
    frames: int
    first_frame: float = 0.0
    units_scale: float = 1.0
    up_axis: str = "y"
    handedness: str = "right"
    hand_rotation: tuple = ()

    def __post_init__(self):
        if self.kind not in ("body", "hand"):
            raise InputValueError(f"MocapSource.kind: expected 'body' or 'hand', got {self.kind!r}")
        if self.up_axis not in ("y", "z"):
            raise InputValueError(f"MocapSource.up_axis: expected 'y' or 'z', got {self.up_axis!r}")
        if self.handedness not in ("right", "left"):
            raise InputValueError(f"MocapSource.handedness: expected 'right' or 'left', got {self.handedness!r}")
        _check_number(self.fps, "MocapSource.fps", low=0.0, strict=True)
        _check_number(self.units_scale, "MocapSource.units_scale", low=0.0, strict=True)
        _check_number(self.first_frame, "MocapSource.first_frame", low=0.0)
        wrists = tuple(tuple(w) for w in self.wrists)
        if not wrists or any(len(w) != 3 or w[0] not in SIDES for w in wrists):
            raise InputValueError(f"MocapSource.wrists: expected (side, file, joint) per hand, got {self.wrists!r}")
        object.__setattr__(self, "wrists", wrists)
        rot = tuple((side, tuple(tuple(float(v) for v in row) for row in R)) for side, R in self.hand_rotation)
        if any(np.shape(R) != (3, 3) for _, R in rot):
            raise ShapeError("MocapSource.hand_rotation: expected a (3, 3) rotation per side")
        object.__setattr__(self, "hand_rotation", rot)

    def wrist(self, side: str) -> tuple[str, str]:
        """``(file, joint)`` of ``side``'s wrist; :class:`UnknownNameError` when the source has no such hand."""
        for s, f, j in self.wrists:
            if s == side:
                return f, j
        raise UnknownNameError(f"side: the mocap source has no {side!r} wrist; wrists: "
                               f"{', '.join(w[0] for w in self.wrists)}")

    def rotation(self, side: str) -> np.ndarray:
        """``R_fix`` of ``side``, (3, 3); the identity when it was not recorded."""
        for s, R in self.hand_rotation:
            if s == side:
                return np.array(R, dtype=np.float64)
        return np.eye(3)

    def shifted(self, frames: float) -> "MocapSource":
        """The same source with the scene starting ``frames`` source frames later."""
        return dataclasses.replace(self, first_frame=self.first_frame + float(frames))


@dataclass(frozen=True, eq=False)
class Scene:
    """An object trajectory, one or two wrist trajectories and their environment.

    Fields
        name: scene name, str
        object: the manipulated rigid object (mesh in the object frame, metres; mass, kg), RigidObject
        object_pose: object frame poses ``T_world_object``, (T, 4, 4), world, metres, float64
        fps: frames per second, float, > 0
        hands: the wrist tracks, tuple of 1 or 2 HandTrack with distinct sides, each with T frames
        friction: hand-object Coulomb friction coefficient, float, >= 0
        environment: table and its friction, Environment
        gravity: gravitational acceleration, (3,), world, m/s^2, default (0, 0, -9.81)
        description: free text, str
        source: the motion capture the wrists came from (``scene import-mocap``), :class:`MocapSource` or None
        external_wrench: a known wrench applied to the object by something other than the hands, the table and
            gravity (a push, a spring, a tool), (T, 6): force (N) and torque about the object's centre of mass
            (N m), world, float64; or None (default: no external wrench). It acts ON the object: the contacts
            supply ``m a - m g - external`` (force) and ``I alpha + omega x I omega - external`` (torque).

    ``T``, ``dt`` and ``duration`` are derived. Update with ``dataclasses.replace``; tensor fields follow
    :mod:`torchhand._tree` (``tree_to`` moves them to a device).
    """

    name: str
    object: RigidObject
    object_pose: torch.Tensor
    fps: float
    hands: tuple[HandTrack, ...]
    friction: float
    environment: Environment = field(default_factory=Environment)
    gravity: torch.Tensor = field(default_factory=_default_gravity)
    description: str = ""
    source: MocapSource | None = None
    external_wrench: torch.Tensor | None = None

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise InputValueError(f"Scene.name: expected a non-empty str, got {self.name!r}")
        if not isinstance(self.object, RigidObject):
            raise InputTypeError(f"Scene.object: expected a RigidObject, got {type(self.object).__name__}")
        _check_pose_tensor(self.object_pose, "Scene.object_pose")
        object.__setattr__(self, "fps", _check_number(self.fps, "Scene.fps", low=0.0, strict=True))
        object.__setattr__(self, "friction", _check_number(self.friction, "Scene.friction", low=0.0))
        hands = tuple(self.hands) if isinstance(self.hands, (list, tuple)) else self.hands
        if not isinstance(hands, tuple) or not all(isinstance(h, HandTrack) for h in hands):
            raise InputTypeError("Scene.hands: expected a tuple of HandTrack")
        if not 1 <= len(hands) <= 2:
            raise InputValueError(f"Scene.hands: expected 1 or 2 hands, got {len(hands)}")
        if len({h.side for h in hands}) != len(hands):
            raise InputValueError(f"Scene.hands: sides must be distinct, got {[h.side for h in hands]}")
        for h in hands:
            _check_pose_tensor(h.wrist_pose, f"Scene.hands[{h.side}].wrist_pose", self.T)
        object.__setattr__(self, "hands", hands)
        if not isinstance(self.environment, Environment):
            raise InputTypeError(f"Scene.environment: expected an Environment, got {type(self.environment).__name__}")
        g = self.gravity
        if not isinstance(g, torch.Tensor):
            g = torch.as_tensor(np.asarray(g, dtype=np.float64))
            object.__setattr__(self, "gravity", g)
        if tuple(g.shape) != (3,):
            raise ShapeError(f"Scene.gravity: expected shape (3,), got {tuple(g.shape)}")
        if not isinstance(self.description, str):
            raise InputTypeError(f"Scene.description: expected a str, got {type(self.description).__name__}")
        if self.source is not None and not isinstance(self.source, MocapSource):
            raise InputTypeError(f"Scene.source: expected a MocapSource or None, got {type(self.source).__name__}")
        if self.external_wrench is not None:
            _check_external_wrench(self.external_wrench, self.T)

    # -- derived ------------------------------------------------------------------------------------------------

    @property
    def T(self) -> int:
        """Number of frames."""
        return int(self.object_pose.shape[0])

    @property
    def dt(self) -> float:
        """Time step, ``1 / fps``, seconds."""
        return 1.0 / self.fps

    @property
    def duration(self) -> float:
        """Time from the first to the last frame, ``(T - 1) / fps``, seconds."""
        return (self.T - 1) / self.fps

    @property
    def sides(self) -> tuple[str, ...]:
        """Sides of the hands, in the order of ``hands``."""
        return tuple(h.side for h in self.hands)

    def times(self) -> torch.Tensor:
        """Frame times ``t_k = k / fps``, (T,), seconds, float64."""
        return torch.arange(self.T, dtype=torch.float64, device=self.object_pose.device) / self.fps

    def hand(self, side: str) -> HandTrack:
        """The track of the ``side`` hand; :class:`UnknownNameError` if the scene has no such hand."""
        for h in self.hands:
            if h.side == side:
                return h
        raise UnknownNameError(f"side: scene '{self.name}' has no {side!r} hand; hands: {', '.join(self.sides)}")

    # -- checks -------------------------------------------------------------------------------------------------

    def validate(self) -> "Scene":
        """Value checks that force a host sync: finite rigid poses, finite gravity. Returns ``self``.

        Raises:
            InputValueError: a pose has NaN/inf or a non-orthonormal rotation (message names the field and frame).
        """
        check_transforms(self.object_pose, f"scene '{self.name}': object_pose")
        for h in self.hands:
            check_transforms(h.wrist_pose, f"scene '{self.name}': wrist_pose_{h.side}")
        if not bool(torch.isfinite(self.gravity).all()):
            raise InputValueError(f"scene '{self.name}': gravity must be finite, got {self.gravity.tolist()}")
        if self.external_wrench is not None:
            bad = ~torch.isfinite(self.external_wrench).all(-1)
            if bool(bad.any()):
                raise InputValueError(f"scene '{self.name}': external_wrench must be finite; frame "
                                      f"{int(bad.nonzero()[0, 0])} has {self.external_wrench[bad][0].tolist()}")
        return self

    # -- editing ------------------------------------------------------------------------------------------------

    def with_frames(self, start: int, stop: int) -> "Scene":
        """The frames ``start <= k < stop`` (Python slice semantics, no negative indices), as a new Scene.

        Raises:
            InputValueError: unless ``0 <= start < stop <= T``.
        """
        for label, v in (("start", start), ("stop", stop)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                raise InputTypeError(f"{label}: expected an int, got {type(v).__name__}")
        if not 0 <= start < stop <= self.T:
            raise InputValueError(f"start, stop: expected 0 <= start < stop <= T = {self.T}, got {start}, {stop}")
        s = slice(int(start), int(stop))
        hands = tuple(dataclasses.replace(h, wrist_pose=h.wrist_pose[s].clone()) for h in self.hands)
        source = None if self.source is None else self.source.shifted(start * self.source.fps / self.fps)
        ext = None if self.external_wrench is None else self.external_wrench[s].clone()
        return dataclasses.replace(self, object_pose=self.object_pose[s].clone(), hands=hands, source=source,
                                   external_wrench=ext)

    def resample(self, fps: float) -> "Scene":
        """The same motion sampled at ``fps``: positions interpolated linearly, rotations by slerp.

        The new frames are at ``k / fps`` for ``k = 0 .. floor(duration * fps)``; the last one is at or before the
        original last frame. An ``external_wrench`` is interpolated linearly.
        """
        fps = _check_number(fps, "fps", low=0.0, strict=True)
        n = int(math.floor(self.duration * fps + 1e-9)) + 1
        times = torch.arange(n, dtype=torch.float64, device=self.object_pose.device) / fps
        src = self.times()
        hands = tuple(dataclasses.replace(h, wrist_pose=interpolate_poses(h.wrist_pose, src, times))
                      for h in self.hands)
        ext = None if self.external_wrench is None else _interpolate_linear(self.external_wrench, src, times)
        return dataclasses.replace(self, fps=fps, object_pose=interpolate_poses(self.object_pose, src, times),
                                   hands=hands, external_wrench=ext)

    def smoothed(self, sigma: float) -> "Scene":
        """The same scene with every pose trajectory (object and wrists) low-pass filtered: a Gaussian of standard
        deviation ``sigma`` seconds (:func:`smooth_poses`). Motion capture jitters by millimetres and a degree
        from frame to frame; the synthesis reads accelerations (the required wrench) and hand-object sliding
        speeds from these trajectories, and both amplify that noise. ``sigma = 0`` returns the scene unchanged.
        An ``external_wrench`` is given data, not a measurement of the motion: it is kept as it is.
        """
        sigma = _check_number(sigma, "sigma", low=0.0)
        if sigma == 0.0:
            return self
        frames = sigma * self.fps
        hands = tuple(dataclasses.replace(h, wrist_pose=smooth_poses(h.wrist_pose, frames)) for h in self.hands)
        return dataclasses.replace(self, object_pose=smooth_poses(self.object_pose, frames), hands=hands)

    def export(self, directory: str | os.PathLike, *, overwrite: bool = False) -> Path:
        """Write the scene as a scene directory (``docs/scene_format.md``) and return its path.

        Everything is written into a temporary directory beside ``directory`` first and then moved in with
        ``os.replace``, file by file, ``scene.toml`` last; on any failure nothing already in ``directory`` is
        changed. The mesh is written in metres (scale 1) with the object's mass.

        Args:
            directory: target directory; created (with parents) if missing.
            overwrite: replace the scene files already there; without it an existing ``scene.toml``,
                ``object.obj`` or ``trajectories.npz`` is an :class:`InputValueError`.

        Raises:
            InputValueError: files already there without ``overwrite``, ``directory`` is a file, or the operating
                system refused a write (the message carries its reason).
        """
        from .scene_io import export_scene_dir

        return export_scene_dir(self, directory, overwrite=overwrite)


def _check_external_wrench(x, T: int) -> None:
    """Cheap checks of ``Scene.external_wrench`` (type, shape, dtype); finiteness is in :meth:`Scene.validate`."""
    if not isinstance(x, torch.Tensor):
        raise InputTypeError(f"Scene.external_wrench: expected a torch.Tensor (T, 6) or None, got {type(x).__name__}")
    if x.dim() != 2 or x.shape[1] != 6:
        raise ShapeError(f"Scene.external_wrench: expected shape (T, 6) (force N, torque N m about the centre of "
                         f"mass, world), got {tuple(x.shape)}")
    if x.shape[0] != T:
        raise ShapeError(f"Scene.external_wrench: expected T = {T} frames (as object_pose), got {x.shape[0]}")
    if not x.is_floating_point():
        raise InputTypeError(f"Scene.external_wrench: expected a floating-point tensor, got dtype {x.dtype}")


# ---------------------------------------------------------------------------------------------------------------
# pose interpolation


def _interpolate_linear(x: torch.Tensor, times: torch.Tensor, new_times: torch.Tensor) -> torch.Tensor:
    """Linear interpolation of samples ``x (T, C)`` at increasing ``times (T,)`` to ``new_times (N,)`` (clamped to
    the sampled range). Returns (N, C), dtype and device of ``x``."""
    T = x.shape[0]
    new_times = new_times.to(dtype=x.dtype, device=x.device)
    times = times.to(dtype=x.dtype, device=x.device)
    if T == 1:
        return x.expand(new_times.shape[0], x.shape[1]).clone()
    t = new_times.clamp(times[0], times[-1])
    i0 = (torch.searchsorted(times, t, right=True) - 1).clamp(0, T - 2)
    w = ((t - times[i0]) / (times[i0 + 1] - times[i0])).clamp(0.0, 1.0)[:, None]
    return x[i0] + w * (x[i0 + 1] - x[i0])


def interpolate_poses(poses: torch.Tensor, times: torch.Tensor, new_times: torch.Tensor) -> torch.Tensor:
    """Sample rigid poses at ``new_times``: positions linearly, rotations by quaternion slerp.

    Args:
        poses: poses at ``times``, (T, 4, 4)
        times: increasing sample times, (T,), seconds
        new_times: query times, (N,), seconds; clamped to ``[times[0], times[-1]]``

    Returns:
        poses at ``new_times``, (N, 4, 4), dtype and device of ``poses``
    """
    T = poses.shape[0]
    new_times = new_times.to(dtype=poses.dtype, device=poses.device)
    times = times.to(dtype=poses.dtype, device=poses.device)
    if T == 1:
        return poses.expand(new_times.shape[0], 4, 4).clone()
    t = new_times.clamp(times[0], times[-1])
    i0 = (torch.searchsorted(times, t, right=True) - 1).clamp(0, T - 2)
    w = ((t - times[i0]) / (times[i0 + 1] - times[i0])).clamp(0.0, 1.0)
    p0, p1 = poses[i0, :3, 3], poses[i0 + 1, :3, 3]
    q = _slerp(_matrix_to_quat(poses[i0, :3, :3]), _matrix_to_quat(poses[i0 + 1, :3, :3]), w)
    out = torch.zeros(new_times.shape[0], 4, 4, dtype=poses.dtype, device=poses.device)
    out[:, :3, :3] = _quat_to_matrix(q)
    out[:, :3, 3] = p0 + w[:, None] * (p1 - p0)
    out[:, 3, 3] = 1.0
    return out


def smooth_poses(poses: torch.Tensor, sigma_frames: float) -> torch.Tensor:
    """Gaussian low-pass filter of a pose trajectory: positions averaged with the weights, rotations by the
    normalised weighted sum of quaternions sign-aligned to the centre frame's (the chordal mean, accurate for the
    small spread within a few frames). The kernel spans +-3 sigma and is renormalised at the ends of the clip.

    Args:
        poses: (T, 4, 4) rigid poses
        sigma_frames: standard deviation in frames (> 0)

    Returns:
        (T, 4, 4) smoothed poses, dtype and device of ``poses``
    """
    T = poses.shape[0]
    half = max(1, int(math.ceil(3.0 * sigma_frames)))
    k = torch.arange(-half, half + 1, dtype=poses.dtype, device=poses.device)
    kernel = torch.exp(-0.5 * (k / sigma_frames) ** 2)                             # (W,)
    idx = torch.arange(T, device=poses.device)[:, None] + k.long()[None]           # (T, W)
    valid = (idx >= 0) & (idx < T)
    w = kernel[None] * valid.to(poses.dtype)
    w = w / w.sum(-1, keepdim=True)
    idx = idx.clamp(0, T - 1)
    p = (w[..., None] * poses[idx, :3, 3]).sum(1)
    q = _matrix_to_quat(poses[:, :3, :3])                                         # (T, 4)
    qn = q[idx]                                                                   # (T, W, 4)
    sign = torch.where((qn * q[:, None]).sum(-1, keepdim=True) < 0, -1.0, 1.0).to(poses.dtype)
    qm = (w[..., None] * sign * qn).sum(1)
    out = torch.zeros_like(poses)
    out[:, :3, :3] = _quat_to_matrix(qm / qm.norm(dim=-1, keepdim=True))
    out[:, :3, 3] = p
    out[:, 3, 3] = 1.0
    return out


def _matrix_to_quat(R: torch.Tensor) -> torch.Tensor:
    """Unit quaternions (w, x, y, z) of rotation matrices (..., 3, 3), by kornia."""
    eps = 1e-12 if R.dtype == torch.float64 else 1e-7
    q = rotation_matrix_to_quaternion(R.contiguous(), eps=eps)
    return q / q.norm(dim=-1, keepdim=True)


def _quat_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (..., 3, 3) of quaternions (w, x, y, z), normalised first, by kornia."""
    return quaternion_to_rotation_matrix(q / q.norm(dim=-1, keepdim=True))


def _slerp(q0: torch.Tensor, q1: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Shortest-arc spherical interpolation of unit quaternions (N, 4) with weights (N,)."""
    dot = (q0 * q1).sum(-1)
    q1 = torch.where(dot[:, None] < 0, -q1, q1)
    dot = dot.abs().clamp(max=1.0)
    theta = torch.acos(dot)
    s = torch.sin(theta)
    near = s < 1e-6
    s_safe = torch.where(near, torch.ones_like(s), s)
    a = torch.where(near, 1 - w, torch.sin((1 - w) * theta) / s_safe)
    b = torch.where(near, w, torch.sin(w * theta) / s_safe)
    q = a[:, None] * q0 + b[:, None] * q1
    return q / q.norm(dim=-1, keepdim=True)


# ---------------------------------------------------------------------------------------------------------------
# loading


def _builtin_over_dir(name_or_dir, p: Path) -> bool:
    """A plain built-in scene name that also names a directory without a ``scene.toml`` in the working directory
    (an output directory named after the scene, ``--out box-turn``) means the built-in scene."""
    if not (isinstance(name_or_dir, str) and p.is_dir()) or (p / "scene.toml").is_file():
        return False
    if any(s in name_or_dir for s in ("/", "\\", os.sep)):
        return False
    from .scenes import list_builtin_scenes

    return name_or_dir in list_builtin_scenes()


def load_scene(name_or_dir: str | os.PathLike) -> Scene:
    """Load a built-in scene by name or a scene directory (``docs/scene_format.md``), validated.

    A value that names an existing directory (or a ``scene.toml`` file) is read from disk; a plain name (no path
    separator) is looked up among :func:`torchhand.scenes.list_builtin_scenes`. A plain built-in name that is also a
    directory without a ``scene.toml`` (say an output directory named after the scene) is the built-in scene.

    Raises:
        UnknownNameError: neither a directory nor a built-in scene name (the message lists the known names).
        MissingFileError: a path (or a file named in ``scene.toml``) that does not exist.
        FileFormatError: malformed TOML (file, line, column), a missing or mistyped field, an unreadable npz.
        ShapeError: a trajectory that is not (T, 4, 4) or whose T differs from ``object_pose``.
        InputValueError: NaN / non-rigid poses, fps <= 0, negative friction, mass <= 0 (field and file named).
    """
    if not isinstance(name_or_dir, (str, os.PathLike)):
        raise InputTypeError(f"name_or_dir: expected a str or path, got {type(name_or_dir).__name__}")
    p = Path(name_or_dir)
    if (p.is_dir() or p.is_file()) and not _builtin_over_dir(name_or_dir, p):
        from .scene_io import load_scene_dir

        return load_scene_dir(p.parent if p.is_file() else p)
    text = os.fspath(name_or_dir)
    from .scenes import builtin_scene, list_builtin_scenes

    if isinstance(name_or_dir, str) and not any(s in text for s in ("/", "\\", os.sep)) and text not in (".", ".."):
        if text in list_builtin_scenes():
            return builtin_scene(text).validate()
        raise UnknownNameError(
            f"name_or_dir: '{text}' is neither a built-in scene nor a directory; "
            f"built-in scenes: {', '.join(list_builtin_scenes())}"
        )
    raise MissingFileError(f"name_or_dir: scene directory '{text}' does not exist")
