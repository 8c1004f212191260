"""The sources of a motion-capture scene (:func:`torchhand.scene.mocap.import_mocap_scene`): the wrist joints of
hand or body BVHs, the object's trajectory from a BVH joint or an npz of poses, and the timing they share (frame
count, source frame rate, the frame range kept)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..errors import FileFormatError, InputValueError, MissingFileError, ShapeError
from ._bvh_clip import BVHClip
from ._bvh_read import read_bvh
from ._parts import SIDES


@dataclass(frozen=True)
class _Wrist:
    """One hand's source: the clip and the index of its wrist joint."""

    clip: BVHClip
    joint: int


@dataclass(frozen=True)
class _ObjectSource:
    """The object's trajectory: an object BVH's ``clip`` and ``joint``, or (``clip`` None, ``joint`` -1) the npz's
    ``poses`` (F, 4, 4) float64 in source units and axes; ``frames`` F; ``frame_time`` seconds, None for an npz."""

    clip: BVHClip | None
    joint: int
    poses: torch.Tensor | None
    frames: int
    frame_time: float | None


@dataclass(frozen=True)
class _Timing:
    """What the sources share: ``frames`` F (source frames), ``fps`` the source rate (rounded to an integer within
    1e-3 of one), and the kept source frames ``start <= k < stop``."""

    frames: int
    fps: float
    start: int
    stop: int


def _read_wrists(hand_bvh, body_bvh, wrist_joint, side: str, tick) -> dict[str, _Wrist]:
    """side -> wrist source: each hand BVH's root (or named joint), or the named joints of one body BVH."""
    sources: dict[str, _Wrist] = {}
    if hand_bvh is not None:
        paths = _per_side(hand_bvh, side, "hand_bvh")
        joints = _per_side(wrist_joint, side, "wrist_joint") if wrist_joint is not None else {}
        for s, path in paths.items():
            tick(f"reading {Path(path).name}")
            clip = read_bvh(path)
            sources[s] = _Wrist(clip, clip.joint_index(joints[s]) if s in joints else _first_root(clip))
    else:
        if wrist_joint is None:
            raise InputValueError("wrist_joint: required with body_bvh (a joint name, or a mapping side -> name)")
        tick(f"reading {Path(body_bvh).name}")
        clip = read_bvh(body_bvh)
        for s, jname in _per_side(wrist_joint, side, "wrist_joint").items():
            sources[s] = _Wrist(clip, clip.joint_index(jname))
    return sources


def _read_object(object_bvh, object_joint: str | None, object_npz, tick) -> _ObjectSource:
    """The object's trajectory from ``object_bvh`` (its root, or ``object_joint``) or ``object_npz``."""
    if object_bvh is not None:
        tick(f"reading {Path(object_bvh).name}")
        oclip = read_bvh(object_bvh)
        oj = oclip.joint_index(object_joint) if object_joint is not None else _first_root(oclip)
        return _ObjectSource(clip=oclip, joint=oj, poses=None, frames=oclip.num_frames,
                             frame_time=oclip.frame_time)
    raw_obj = _read_object_npz(Path(object_npz))
    return _ObjectSource(clip=None, joint=-1, poses=raw_obj, frames=raw_obj.shape[0], frame_time=None)


def _timing(wrists: dict[str, _Wrist], obj: _ObjectSource, frame_range) -> _Timing:
    """Every clip with the object's frame count and one frame time; the source rate; the frame range."""
    F_obj = obj.frames
    clips = [w.clip for w in wrists.values()] + ([obj.clip] if obj.clip is not None else [])
    for c in clips:
        if c.num_frames != F_obj:
            raise ShapeError(f"{c.path}: has {c.num_frames} frames, the object trajectory has {F_obj}")
    frame_time = obj.frame_time if obj.frame_time is not None else clips[0].frame_time
    for c in clips:
        if abs(c.frame_time - frame_time) > 1e-6 * frame_time:
            raise InputValueError(f"{c.path}: frame time {c.frame_time} differs from {frame_time}")
    src_fps = 1.0 / frame_time
    if abs(src_fps - round(src_fps)) < 1e-3:
        src_fps = float(round(src_fps))
    start, stop = _frame_range(frame_range, F_obj)
    return _Timing(frames=F_obj, fps=src_fps, start=start, stop=stop)


def _positive(value, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise InputValueError(f"{name}: expected a finite positive number, got {value!r}")
    return float(value)


def _per_side(value, side: str, name: str) -> dict[str, object]:
    if isinstance(value, Mapping):
        out = dict(value)
        if not out or any(k not in SIDES for k in out):
            raise InputValueError(f"{name}: mapping keys must be 'right' and/or 'left', got {list(out)}")
        return out
    return {side: value}


def _first_root(clip: BVHClip) -> int:
    return clip.parents.index(-1)


def _frame_range(frame_range, F: int) -> tuple[int, int]:
    if frame_range is None:
        return 0, F
    try:
        start, stop = (int(v) for v in frame_range)
    except (TypeError, ValueError):
        raise InputValueError(f"frame_range: expected (start, stop), got {frame_range!r}") from None
    if not 0 <= start < stop <= F:
        raise InputValueError(f"frame_range: expected 0 <= start < stop <= {F} (source frames), got {frame_range}")
    if stop - start < 2:
        raise InputValueError(f"frame_range: needs at least 2 frames, got {frame_range}")
    return start, stop


def _read_object_npz(path: Path) -> torch.Tensor:
    import zipfile

    if not path.is_file():
        raise MissingFileError(f"object_npz: '{path}' does not exist")
    try:
        with np.load(path, allow_pickle=False) as data:
            if "object_pose" not in data.files:
                raise FileFormatError(f"{path}: missing array 'object_pose'; has {', '.join(data.files)}")
            a = data["object_pose"]
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as err:
        raise FileFormatError(f"{path}: cannot read npz: {type(err).__name__}: {err}") from None
    if a.dtype.kind not in "fiu" or a.ndim != 3 or a.shape[1:] != (4, 4):
        raise ShapeError(f"{path}: object_pose: expected a numeric (F, 4, 4) array, got {a.dtype} {a.shape}")
    return torch.tensor(a, dtype=torch.float64)
