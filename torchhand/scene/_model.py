"""Scenes: an object trajectory, one or two wrist trajectories, and the environment they act in.

A :class:`Scene` is the input of hand-motion synthesis: the object's 6-DOF motion and the wrists' 6-DOF motion are
given; the fingers are what torchhand fills in. Conventions (see :mod:`torchhand.conventions`): world z-up,
metres, seconds, kilograms; poses are 4x4 rigid transforms ``T_world_frame`` (column vectors), float64. The hand
frame of a :class:`HandTrack` has its origin at the wrist joint centre, +x toward the fingertips, the palm facing
-z, +y toward the thumb for a right hand (a left hand is mirrored through the x-z plane: thumb toward -y).

Scenes come from :func:`load_scene` (a built-in name, see :mod:`torchhand.scene.builtin`, or a scene directory, see
``docs/scene_format.md``), from :func:`torchhand.scene.mocap.import_mocap_scene`, or are built directly. Building a
:class:`Scene` runs the cheap checks (types, shapes, ranges); :meth:`Scene.validate` adds the value checks that
force a host sync (finite, rigid transforms) and is run by every loader.

Directory I/O is in :mod:`torchhand.scene._writer` and :mod:`torchhand.scene._reader`, object-table contacts in :mod:`torchhand.scene._contacts`; their public
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

from ..conventions import check_transforms
from ..errors import InputTypeError, InputValueError, UnknownNameError, ShapeError
from ..geometry.objects import RigidObject
from ..geometry.poses import _interpolate_linear, interpolate_poses, smooth_poses
from ._parts import (Environment, HandTrack, MocapSource, _check_number, _check_pose_tensor,
                     _default_gravity)
from ._writer import export_scene_dir

__all__ = ["Scene"]


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
    captured_object_pose: torch.Tensor | None = None

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise InputValueError(f"Scene.name: expected a non-empty str, got {self.name!r}")
        if not isinstance(self.object, RigidObject):
            raise InputTypeError(f"Scene.object: expected a RigidObject, got {type(self.object).__name__}")
        _check_pose_tensor(self.object_pose, "Scene.object_pose")
        if self.captured_object_pose is not None:
            _check_pose_tensor(self.captured_object_pose, "Scene.captured_object_pose", self.T)
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
        if self.captured_object_pose is not None:
            check_transforms(self.captured_object_pose, f"scene '{self.name}': captured_object_pose")
        for h in self.hands:
            check_transforms(h.wrist_pose, f"scene '{self.name}': wrist_pose_{h.side}")
            if h.captured_wrist_pose is not None:
                check_transforms(h.captured_wrist_pose, f"scene '{self.name}': captured_wrist_pose_{h.side}")
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
        hands = tuple(dataclasses.replace(h, wrist_pose=h.wrist_pose[s].clone(), captured_wrist_pose=None
                                          if h.captured_wrist_pose is None else h.captured_wrist_pose[s].clone())
                      for h in self.hands)
        source = None if self.source is None else self.source.shifted(start * self.source.fps / self.fps)
        ext = None if self.external_wrench is None else self.external_wrench[s].clone()
        cap = None if self.captured_object_pose is None else self.captured_object_pose[s].clone()
        return dataclasses.replace(self, object_pose=self.object_pose[s].clone(), hands=hands, source=source,
                                   external_wrench=ext, captured_object_pose=cap)

    def resample(self, fps: float) -> "Scene":
        """The same motion sampled at ``fps``: positions interpolated linearly, rotations by slerp.

        The new frames are at ``k / fps`` for ``k = 0 .. floor(duration * fps)``; the last one is at or before the
        original last frame. An ``external_wrench`` is interpolated linearly.
        """
        fps = _check_number(fps, "fps", low=0.0, strict=True)
        n = int(math.floor(self.duration * fps + 1e-9)) + 1
        times = torch.arange(n, dtype=torch.float64, device=self.object_pose.device) / fps
        src = self.times()
        hands = tuple(dataclasses.replace(h, wrist_pose=interpolate_poses(h.wrist_pose, src, times),
                                          captured_wrist_pose=None if h.captured_wrist_pose is None else
                                          interpolate_poses(h.captured_wrist_pose, src, times))
                      for h in self.hands)
        ext = None if self.external_wrench is None else _interpolate_linear(self.external_wrench, src, times)
        cap = None if self.captured_object_pose is None else interpolate_poses(self.captured_object_pose, src, times)
        return dataclasses.replace(self, fps=fps, object_pose=interpolate_poses(self.object_pose, src, times),
                                   hands=hands, external_wrench=ext, captured_object_pose=cap)

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
