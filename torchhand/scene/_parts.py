"""The parts of a scene: hand tracks, the environment, the mocap source, and the checks they share.

Conventions (see :mod:`torchhand.conventions`): world z-up, metres, seconds, kilograms; poses are 4x4 rigid
transforms ``T_world_frame`` (column vectors), float64.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import torch

from ..errors import InputTypeError, InputValueError, ShapeError, UnknownNameError
from ..geometry.ground import Ground

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
        model: "default" (the built-in human hand scaled by ``length``) or the path of an MJCF or URDF hand
            (absolute once loaded from a scene directory; :func:`torchhand.hand.mount.track_hand` builds the model)
        mount: None, or 6 floats: the hand model moved on the track by a shift (metres, x y z in the hand frame)
            and a rotation vector (degrees, hand frame), on top of its hand frame; the synthesis' mount fit sets
            it for a robot hand (docs/hand_model.md, "Mounting without tuning")
        rest: None (the model's own rest pose), "zero" or "relaxed": the rest pose a robot hand starts its
            inverse kinematics from (:func:`torchhand.hand.mount.with_rest`); the mount fit sets it
        captured_wrist_pose: None, or the wrist track as captured, (T, 4, 4), world, float64, when ``wrist_pose``
            was moved from it within capture noise (:mod:`torchhand.fill.wrist`); results store it as
            ``root_pose_captured`` and the checker reports the deviation
    """

    side: str
    wrist_pose: torch.Tensor
    length: float = 0.19
    model: str = "default"
    mount: tuple | None = None
    rest: str | None = None
    captured_wrist_pose: torch.Tensor | None = None

    def __post_init__(self):
        if self.side not in SIDES:
            raise InputValueError(f"HandTrack.side: expected 'right' or 'left', got {self.side!r}")
        _check_pose_tensor(self.wrist_pose, f"HandTrack.wrist_pose ({self.side})")
        if self.captured_wrist_pose is not None:
            _check_pose_tensor(self.captured_wrist_pose, f"HandTrack.captured_wrist_pose ({self.side})",
                               int(self.wrist_pose.shape[0]))
        object.__setattr__(self, "length", _check_number(self.length, "HandTrack.length", low=0.0, strict=True))
        if not isinstance(self.model, str) or not self.model:
            raise InputValueError(f"HandTrack.model: expected 'default' or an MJCF path, got {self.model!r}")
        if self.mount is not None:
            m = tuple(self.mount) if isinstance(self.mount, (tuple, list)) else ()
            if len(m) != 6 or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                                      for v in m):
                raise InputValueError(f"HandTrack.mount ({self.side}): expected 6 finite numbers (shift metres, "
                                      f"rotation vector degrees), got {self.mount!r}")
            object.__setattr__(self, "mount", tuple(float(v) for v in m))
        if self.rest not in (None, "zero", "relaxed"):
            raise InputValueError(f"HandTrack.rest ({self.side}): expected 'zero' or 'relaxed', got {self.rest!r}")

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
        friction: object-table (and object-floor) Coulomb friction coefficient, float, >= 0
        table_extent: ``(x_min, x_max, y_min, y_max)`` of the table top, world, metres, or None (an unbounded
            plane); with an extent the table is a block under that rectangle
        floor: whether there is a floor plane below the table (needs a ``table_extent``, or no table)
        floor_height: z of the floor plane, float, world, metres (ignored when ``floor`` is False)

    :meth:`ground` gives the solids as a :class:`~torchhand.geometry.ground.Ground`. Synthesis and the checker
    handle every environment; interaction capture, manipulation and fill handle only a ``plain`` one (an unbounded
    table or nothing).
    """

    table: bool = False
    table_height: float = 0.0
    friction: float = 0.5
    table_extent: tuple | None = None
    floor: bool = False
    floor_height: float = 0.0

    def __post_init__(self):
        for name in ("table", "floor"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise InputTypeError(f"Environment.{name}: expected a bool, got {type(getattr(self, name)).__name__}")
            object.__setattr__(self, name, bool(getattr(self, name)))
        object.__setattr__(self, "table_height", _check_number(self.table_height, "Environment.table_height"))
        object.__setattr__(self, "floor_height", _check_number(self.floor_height, "Environment.floor_height"))
        object.__setattr__(self, "friction", _check_number(self.friction, "Environment.friction", low=0.0))
        if self.table_extent is not None:
            object.__setattr__(self, "table_extent", tuple(self.table_extent)
                               if isinstance(self.table_extent, (tuple, list)) else self.table_extent)
        try:
            g = self.ground()
        except InputValueError as e:
            raise InputValueError(str(e).replace("Ground", "Environment", 1)) from None
        if g.table_extent is not None:
            object.__setattr__(self, "table_extent", g.table_extent)

    def ground(self) -> Ground:
        """The table and floor as solids (:class:`~torchhand.geometry.ground.Ground`)."""
        return Ground(table_height=self.table_height if self.table else None,
                      table_extent=self.table_extent if self.table else None,
                      floor_height=self.floor_height if self.floor else None)

    @property
    def plain(self) -> bool:
        """No floor and no table edge: an unbounded table plane or nothing."""
        return not self.floor and (not self.table or self.table_extent is None)

    def require_plain(self, method: str) -> None:
        """Raise :class:`InputValueError` naming ``method`` when the environment has a table edge or a floor."""
        if not self.plain:
            raise InputValueError(f"{method}: the scene's environment has a table edge or a floor; {method} supports "
                                  f"only an unbounded table plane (torchhand synthesize handles both)")


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
            wrist joint's local axes to the hand frame (:func:`torchhand.scene.mocap.hand_frame_rotation`)

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
