"""Writing BVH files (:func:`write_bvh`; layout in :mod:`torchhand.scene.bvh`): the arguments and the hierarchy
checked, joints in depth-first order with their motion columns, offsets and frame time in exact decimals, written
atomically."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from .._atomic import atomic_text
from ..errors import InputTypeError, InputValueError, MissingFileError, ShapeError
from ._bvh_clip import CHANNEL_NAMES, BVHClip

__all__ = ["write_bvh"]


def write_bvh(clip: BVHClip, path: str | os.PathLike, *, precision: int = 6) -> Path:
    """Write a clip as a BVH file, atomically (see the module docstring for the layout).

    Joints are written depth-first from each root in turn, children in index order (the order :func:`read_bvh`
    gives, so read -> write -> read keeps every field); ``End Site`` joints become ``End Site`` blocks.

    Args:
        clip: the clip; ``motion`` (F, C) in its column order, positions in file units, rotations in degrees
        path: the file to write; its folder must exist; an existing file is replaced
        precision: decimals of the motion values (``%.{precision}f``), 0..17

    Returns:
        the path written.

    Raises:
        InputTypeError: ``clip`` is not a :class:`BVHClip`, or ``precision`` is not an int.
        ShapeError: ``motion`` or ``offsets`` do not match the hierarchy.
        InputValueError: non-finite values, a bad frame time, a hierarchy that cannot be written (a name with
            whitespace, braces or nothing in it, a parent after its child, an End Site with channels or
            children, an unknown channel), ``precision`` out of range, or ``path`` is a folder.
        MissingFileError: the folder of ``path`` does not exist.
    """
    if not isinstance(clip, BVHClip):
        raise InputTypeError(f"clip: expected a BVHClip, got {type(clip).__name__}")
    if isinstance(precision, bool) or not isinstance(precision, int):
        raise InputTypeError(f"precision: expected an int, got {type(precision).__name__}")
    if not 0 <= precision <= 17:
        raise InputValueError(f"precision: expected 0..17 decimals, got {precision}")
    p = Path(path)
    if not p.parent.is_dir():
        raise MissingFileError(f"path: folder '{p.parent}' does not exist")
    if p.is_dir():
        raise InputValueError(f"path: '{p}' is a folder, expected a file name")
    order, columns = _write_order(clip)
    motion = np.asarray(clip.motion, dtype=np.float64)
    if not np.isfinite(motion).all():
        f, c = (int(v[0]) for v in np.nonzero(~np.isfinite(motion)))
        raise InputValueError(f"clip.motion: non-finite value at frame {f}, column {c}")
    if not np.isfinite(clip.offsets).all():
        bad = clip.names[int(np.nonzero(~np.isfinite(clip.offsets).all(axis=1))[0][0])]
        raise InputValueError(f"clip.offsets: non-finite OFFSET of joint '{bad}'")
    ft = float(clip.frame_time)
    if not (math.isfinite(ft) and ft > 0):
        raise InputValueError(f"clip.frame_time: expected a positive number of seconds, got {clip.frame_time}")

    out = _hierarchy_lines(clip, order)
    out += _motion_lines(motion[:, columns], ft, precision)
    atomic_text(p, "\n".join(out) + "\n")
    return p


def _hierarchy_lines(clip: BVHClip, order: list[int]) -> list[str]:
    """``HIERARCHY`` and the joints in ``order``, one keyword per line, tab-indented, End Sites restored."""
    out = ["HIERARCHY"]
    open_joints: list[int] = []                         # the chain from a root to the joint written last
    for j in order + [-1]:                              # -1 closes everything at the end
        parent = clip.parents[j] if j >= 0 else -1
        while open_joints and open_joints[-1] != parent:
            open_joints.pop()
            out.append("\t" * len(open_joints) + "}")
        if j < 0:
            break
        tab = "\t" * len(open_joints)
        if clip.is_end_site[j]:
            out.append(f"{tab}End Site")
        else:
            out.append(f"{tab}{'JOINT' if clip.parents[j] >= 0 else 'ROOT'} {clip.names[j]}")
        out.append(f"{tab}{{")
        out.append(f"{tab}\tOFFSET " + " ".join(_exact(v) for v in clip.offsets[j]))
        if not clip.is_end_site[j]:
            out.append(f"{tab}\tCHANNELS {len(clip.channels[j])}" + "".join(f" {c}" for c in clip.channels[j]))
        open_joints.append(j)
    return out


def _motion_lines(motion: np.ndarray, ft: float, precision: int) -> list[str]:
    """``MOTION``, ``Frames:``, ``Frame Time:`` and the motion values (F, C) in write order, ``%.{precision}f``."""
    unit = 0.5 * 10.0 ** -precision
    values = np.where(np.abs(motion) < unit, 0.0, motion)   # no "-0.000000"
    row = " ".join([f"%.{precision}f"] * values.shape[1])
    out = ["MOTION", f"Frames: {values.shape[0]}", f"Frame Time: {_frame_time_text(ft)}"]
    out += [row % tuple(r) for r in values.tolist()]
    return out


def _write_order(clip: BVHClip) -> tuple[list[int], list[int]]:
    """Depth-first joint order and the matching motion columns; InputValueError/ShapeError for a hierarchy that
    cannot be written."""
    J = len(clip.names)
    if not (len(clip.parents) == len(clip.channels) == len(clip.is_end_site) == J):
        raise ShapeError(f"clip: names, parents, channels and is_end_site must have one entry per joint, got "
                         f"{J}, {len(clip.parents)}, {len(clip.channels)}, {len(clip.is_end_site)}")
    if np.shape(clip.offsets) != (J, 3):
        raise ShapeError(f"clip.offsets: expected shape ({J}, 3), got {np.shape(clip.offsets)}")
    children: list[list[int]] = [[] for _ in range(J)]
    for j, (name, parent, chans, end) in enumerate(zip(clip.names, clip.parents, clip.channels, clip.is_end_site)):
        if not parent < j:
            raise InputValueError(f"clip.parents: joint '{name}' has parent index {parent}, expected -1 or < {j}")
        if not end and (not name or any(ch.isspace() or ch in "{}" for ch in name)):
            raise InputValueError(f"clip.names: joint name '{name}' is empty or holds whitespace or braces")
        if end and (chans or parent < 0):
            raise InputValueError(f"clip.is_end_site: End Site '{name}' must have a parent and no channels")
        if parent >= 0:
            if clip.is_end_site[parent]:
                raise InputValueError(f"clip.is_end_site: End Site '{clip.names[parent]}' cannot have children")
            children[parent].append(j)
        bad = [c for c in chans if c not in CHANNEL_NAMES]
        if bad or len(set(chans)) != len(chans):
            raise InputValueError(f"clip.channels: joint '{name}' has channels {' '.join(chans)}; expected "
                                  f"distinct names from {', '.join(CHANNEL_NAMES)}")
    C = sum(len(c) for c in clip.channels)
    if np.ndim(clip.motion) != 2 or np.shape(clip.motion)[1] != C or np.shape(clip.motion)[0] < 1:
        raise ShapeError(f"clip.motion: expected shape (F, {C}) with F >= 1 (the channels of the hierarchy), "
                         f"got {np.shape(clip.motion)}")
    order: list[int] = []
    stack = [j for j in reversed(range(J)) if clip.parents[j] < 0]
    while stack:
        j = stack.pop()
        order.append(j)
        stack.extend(reversed(children[j]))
    start = clip.channel_start
    columns = [start[j] + i for j in order for i in range(len(clip.channels[j]))]
    return order, columns


def _exact(x: float) -> str:
    """The shortest positional decimal that reads back as the same float (no exponent; -0 written as 0)."""
    return np.format_float_positional(float(x) + 0.0, unique=True, trim="-")


def _frame_time_text(ft: float) -> str:
    """Frame time: the shortest exact decimal, padded to at least 8 significant digits."""
    return np.format_float_positional(ft, unique=True, fractional=False, min_digits=8)
