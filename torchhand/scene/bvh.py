"""Biovision Hierarchy (BVH) motion files: a robust reader, an atomic writer and the Euler-angle conversions.

Format
    ``HIERARCHY`` then one or more ``ROOT name { OFFSET x y z  CHANNELS n ch1 .. chn  JOINT ... / End Site {...} }``
    blocks, then ``MOTION``, ``Frames: F``, ``Frame Time: dt`` and ``F`` lines of ``C`` numbers (C = the sum of
    all ``CHANNELS`` counts, in hierarchy order). Keywords are case-sensitive in the spec; this reader accepts any
    case and any whitespace layout (braces may share a line with other tokens).

Kinematics (what :meth:`BVHClip.global_transforms` computes)
    The local transform of a joint is ``Translate(t) @ R``, with ``R = R(ch1) @ R(ch2) @ R(ch3)`` for its rotation
    channels *in the order they are listed* (intrinsic rotations; e.g. ``Yrotation Xrotation Zrotation`` gives
    ``Ry @ Rx @ Rz``). Angles are degrees in the file and radians in every tensor this module returns. ``t`` is
    the joint's OFFSET, except that a position channel REPLACES that axis of the OFFSET (``Xposition`` sets
    ``t[0]``, and so on), for every joint, the root included. This is the usual BVH convention and Blender's
    importer's: for a root it is the "absolute root position", and the rigs whose non-root joints carry position
    channels (the CMU body in ``cmu_body_frozen_hands``, the Leap Motion exports) write those channels equal to the
    OFFSET. The rest pose (:meth:`BVHClip.rest_transforms`) has every rotation zero and every position channel at
    its OFFSET. The global transform is ``parent_global @ local``; transforms are 4x4, column-vector convention
    (``p_parent = T_parent_joint @ p_joint``), in the file's units and axes (no unit or up-axis conversion happens
    here: see :mod:`torchhand.scene.mocap`).

End Sites
    Each ``End Site`` becomes a joint without channels named ``<parent>_end`` (``is_end_site`` True), so
    fingertip positions are available from :meth:`BVHClip.global_transforms` like any other joint.
    :func:`write_bvh` writes them back as ``End Site`` blocks (their names are not written).

Tolerated quirk
    Some exporters write one more motion line than ``Frames:`` says. Exactly one extra line is dropped
    (``BVHClip.extra_lines_dropped == 1``): the FIRST line when it is all zeros (the Leap Motion gestures in
    ``leap_hand_bvh`` start with an all-zero rest row and end with real data), otherwise the LAST line;
    ``BVHClip.extra_line_dropped_at`` says which (``"first"``, ``"last"``, or None when none was dropped). Any
    other mismatch between ``Frames:`` and the number of motion lines is a
    :class:`~torchhand.errors.FileFormatError`. Blank lines are ignored everywhere.

Writing (:func:`write_bvh`)
    The clip's hierarchy (several ROOTs allowed), names, offsets, channel names and orders as they are, End Sites
    restored, ``Frames:`` equal to the number of motion lines, ``Frame Time:`` and offsets in the shortest decimal
    that reads back to the same float (at least 8 significant digits for the frame time), motion values with
    ``%.{precision}f``. One keyword per line, tab-indented, so line-based readers (Blender's) accept it. The file
    is written to a temporary file in the target folder and moved into place; on error nothing is left behind.

Euler angles
    :func:`euler_to_matrix`, :func:`matrix_to_euler` and :func:`unwrap_euler` use the BVH convention above:
    intrinsic rotations in the order of the letters, radians, for the six orders with three different axes (XYZ,
    XZY, YXZ, YZX, ZXY, ZYX). SciPy's ``Rotation.from_euler`` with the same upper-case order is the same
    rotation. Every Euler triple ``(a, b, c)`` has the twin ``(a + pi, pi - b, c + pi)`` and each angle may be
    shifted by ``2 pi``; :func:`matrix_to_euler` returns ``b`` in ``[-pi/2, pi/2]`` and ``a, c`` in ``(-pi, pi]``
    unless a ``reference`` picks the equivalent triple nearest to it.

Errors
    A missing file raises :class:`~torchhand.errors.MissingFileError`; anything malformed (missing
    ``HIERARCHY``/``MOTION``, unknown channel names, wrong channel counts, unbalanced braces, non-numeric or
    non-finite values, a frame count mismatch) raises :class:`~torchhand.errors.FileFormatError` with
    ``path:line:`` in the message. Bad input to the writer and the conversions raises a one-line
    :class:`~torchhand.errors.TorchhandError` subclass naming the argument.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from .._atomic import atomic_text
from ..geometry.euler import _axis_rotation, euler_to_matrix, matrix_to_euler, unwrap_euler  # noqa: F401 (re-exported)
from ..errors import (FileFormatError, InputTypeError, InputValueError, MissingFileError, ShapeError,
                     UnknownNameError)

__all__ = ["BVHClip", "read_bvh", "write_bvh", "euler_to_matrix", "matrix_to_euler", "unwrap_euler",
           "CHANNEL_NAMES"]

CHANNEL_NAMES = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")
"""The six BVH channel names (matched case-insensitively, stored in this spelling)."""

_CANONICAL = {c.lower(): c for c in CHANNEL_NAMES}


@dataclass(frozen=True, eq=False)
class BVHClip:
    """A parsed BVH file.

    Fields
        path: the file it was read from, str
        names: joint names, tuple of J str (End Sites are ``<parent>_end``)
        parents: parent index of each joint, tuple of J int, -1 for a root; parents precede children
        offsets: rest offsets from the parent, (J, 3), file units, float64
        channels: channel names of each joint in file order, tuple of J tuples (empty for End Sites)
        is_end_site: whether each joint is an End Site, tuple of J bool
        frame_time: seconds per frame, float
        motion: channel values, (F, C), float64; positions in file units, rotations in degrees
        extra_lines_dropped: motion lines beyond ``Frames:`` that were dropped (0, or 1 for the tolerated quirk)
        extra_line_dropped_at: which motion line was dropped: ``"first"`` (an all-zero leading row, the Leap
            gestures), ``"last"``, or None when ``extra_lines_dropped`` is 0
    """

    path: str
    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    is_end_site: tuple[bool, ...]
    frame_time: float
    motion: np.ndarray
    extra_lines_dropped: int = 0
    extra_line_dropped_at: str | None = None

    @property
    def num_frames(self) -> int:
        """F, the number of frames."""
        return int(self.motion.shape[0])

    @property
    def num_joints(self) -> int:
        """J, the number of joints including End Sites."""
        return len(self.names)

    @property
    def fps(self) -> float:
        """Frames per second, ``1 / frame_time``."""
        return 1.0 / self.frame_time

    @property
    def channel_start(self) -> tuple[int, ...]:
        """Column of each joint's first channel in ``motion``, tuple of J int."""
        out, col = [], 0
        for ch in self.channels:
            out.append(col)
            col += len(ch)
        return tuple(out)

    def joint_index(self, name: str) -> int:
        """Index of the joint called ``name``; :class:`UnknownNameError` listing the joints if there is none."""
        try:
            return self.names.index(name)
        except ValueError:
            raise UnknownNameError(
                f"joint: '{name}' is not a joint of {self.path}; joints: {', '.join(self.names)}"
            ) from None

    def children(self, j: int) -> list[int]:
        """Indices of the direct children of joint ``j``."""
        return [i for i, p in enumerate(self.parents) if p == j]

    def rest_transforms(self) -> torch.Tensor:
        """Global transforms of the rest pose (every rotation zero, every position channel at its OFFSET, so each
        joint sits at its OFFSET from its parent), (J, 4, 4), file units, float64."""
        rest = np.zeros((1, self.motion.shape[1]), dtype=np.float64)
        for j, (start, chans) in enumerate(zip(self.channel_start, self.channels)):
            for i, ch in enumerate(chans):
                if ch.endswith("position"):
                    rest[0, start + i] = self.offsets[j, "XYZ".index(ch[0])]
        return self._global(rest)[0]

    def with_motion(self, motion, *, frame_time: float | None = None) -> "BVHClip":
        """A copy of this clip with other channel values (the hierarchy unchanged).

        Args:
            motion: channel values in this clip's column order, (F', C), positions in file units, rotations in
                degrees; array or tensor, stored as a read-only float64 array
            frame_time: seconds per frame of the new motion; None keeps this clip's

        Returns:
            the new :class:`BVHClip` (``extra_lines_dropped`` 0: the motion does not come from a file)

        Raises:
            ShapeError: ``motion`` is not (F', C) with F' >= 1.
            InputValueError: non-finite values, or a ``frame_time`` that is not positive and finite.
        """
        m = motion.detach().cpu().numpy() if isinstance(motion, torch.Tensor) else motion
        m = np.array(m, dtype=np.float64, copy=True)
        C = self.motion.shape[1]
        if m.ndim != 2 or m.shape[1] != C or m.shape[0] < 1:
            raise ShapeError(f"motion: expected shape (F, {C}) with F >= 1 for {self.path}, got {tuple(m.shape)}")
        if not np.isfinite(m).all():
            f, c = (int(v[0]) for v in np.nonzero(~np.isfinite(m)))
            raise InputValueError(f"motion: non-finite value at frame {f}, column {c}")
        ft = self.frame_time if frame_time is None else float(frame_time)
        if not (math.isfinite(ft) and ft > 0):
            raise InputValueError(f"frame_time: expected a positive number of seconds, got {frame_time}")
        m.setflags(write=False)
        return replace(self, motion=m, frame_time=ft, extra_lines_dropped=0, extra_line_dropped_at=None)

    def local_transforms(self, frames=None) -> torch.Tensor:
        """Local transforms ``T_parent_joint``, (F', J, 4, 4), file units, float64.

        Args:
            frames: optional frame selection (slice, int sequence or index array) applied to ``motion``.
        """
        return self._local(self._motion(frames))

    def global_transforms(self, frames=None) -> torch.Tensor:
        """Global transforms ``T_file_joint``, (F', J, 4, 4), file units and axes, float64.

        Args:
            frames: optional frame selection (slice, int sequence or index array) applied to ``motion``.
        """
        return self._global(self._motion(frames))

    # -----------------------------------------------------------------------------------------------------------

    def _motion(self, frames) -> np.ndarray:
        m = self.motion if frames is None else self.motion[frames]
        m = np.asarray(m, dtype=np.float64)
        return m[None] if m.ndim == 1 else m

    def _local_np(self, motion: np.ndarray) -> np.ndarray:
        F, J = motion.shape[0], self.num_joints
        out = np.broadcast_to(np.eye(4), (F, J, 4, 4)).copy()
        out[:, :, :3, 3] = self.offsets
        # one sin/cos over every rotation channel
        rot_cols = [c for c, ch in enumerate(ch for chans in self.channels for ch in chans) if ch.endswith("rotation")]
        rad = np.deg2rad(motion[:, rot_cols])
        cos, sin = np.cos(rad), np.sin(rad)
        k = 0
        for j, (start, chans) in enumerate(zip(self.channel_start, self.channels)):
            R = None
            for i, ch in enumerate(chans):
                axis = "XYZ".index(ch[0])
                if ch.endswith("position"):
                    out[:, j, axis, 3] = motion[:, start + i]        # replaces that axis of the OFFSET
                    continue
                Rk = _axis_rotation_np(cos[:, k], sin[:, k], axis)
                k += 1
                R = Rk if R is None else R @ Rk
            if R is not None:
                out[:, j, :3, :3] = R
        return out

    def _local(self, motion: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(self._local_np(motion))

    def _global(self, motion: np.ndarray) -> torch.Tensor:
        local = self._local_np(motion)
        glob = np.empty_like(local)
        for j, p in enumerate(self.parents):
            glob[:, j] = local[:, j] if p < 0 else glob[:, p] @ local[:, j]
        return torch.from_numpy(glob)


def _axis_rotation_np(c: np.ndarray, s: np.ndarray, axis: int) -> np.ndarray:
    """NumPy rotations about coordinate axis ``axis`` from cosines and sines (F,), (F, 3, 3)."""
    R = np.zeros(c.shape + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R[..., axis, axis] = 1.0
    R[..., i, i] = c
    R[..., j, j] = c
    R[..., i, j] = -s
    R[..., j, i] = s
    return R


# ---------------------------------------------------------------------------------------------------------------
# parsing


class _Tokens:
    """Whitespace tokens of the hierarchy section with their 1-based line numbers."""

    def __init__(self, path: str, lines: list[str], start: int, stop: int):
        self.path = path
        self.items: list[tuple[str, int]] = []
        for i in range(start, stop):
            for tok in lines[i].replace("{", " { ").replace("}", " } ").split():
                self.items.append((tok, i + 1))
        self.pos = 0
        self.end_line = stop

    def error(self, msg: str, line: int | None = None) -> FileFormatError:
        if line is None:
            line = self.items[self.pos][1] if self.pos < len(self.items) else self.end_line
        return FileFormatError(f"{self.path}:{line}: {msg}")

    def next(self, what: str) -> tuple[str, int]:
        if self.pos >= len(self.items):
            raise self.error(f"unexpected end of HIERARCHY, expected {what}")
        tok = self.items[self.pos]
        self.pos += 1
        return tok

    def peek(self) -> str | None:
        return self.items[self.pos][0] if self.pos < len(self.items) else None

    def expect(self, word: str) -> int:
        tok, line = self.next(f"'{word}'")
        if tok.lower() != word.lower():
            raise self.error(f"expected '{word}', got '{tok}'", line)
        return line

    def number(self, what: str) -> float:
        tok, line = self.next(what)
        try:
            value = float(tok)
        except ValueError:
            raise self.error(f"expected a number for {what}, got '{tok}'", line) from None
        if not math.isfinite(value):
            raise self.error(f"non-finite value '{tok}' for {what}", line)
        return value


def read_bvh(path: str | os.PathLike) -> BVHClip:
    """Read a BVH file (see the module docstring for the format, the kinematics and the tolerated quirk).

    Args:
        path: a ``.bvh`` file.

    Returns:
        the parsed :class:`BVHClip`.

    Raises:
        MissingFileError: ``path`` does not exist or is not a file.
        FileFormatError: the file is malformed; the message gives ``path:line``.
    """
    p = Path(path)
    if not p.is_file():
        raise MissingFileError(f"path: BVH file '{p}' does not exist")
    try:
        text = p.read_text(encoding="utf-8", errors="replace")
    except OSError as err:
        raise MissingFileError(f"path: cannot read BVH file '{p}': {err}") from None
    name = str(p)
    lines = text.splitlines()

    first = next((i for i, ln in enumerate(lines) if ln.strip()), None)
    if first is None or lines[first].strip().upper() != "HIERARCHY":
        raise FileFormatError(f"{name}:{(first or 0) + 1}: expected 'HIERARCHY' as the first line")
    motion_at = next((i for i in range(first + 1, len(lines)) if lines[i].strip().upper() == "MOTION"), None)
    if motion_at is None:
        raise FileFormatError(f"{name}:{len(lines)}: no 'MOTION' section")

    toks = _Tokens(name, lines, first + 1, motion_at)
    names: list[str] = []
    parents: list[int] = []
    offsets: list[tuple[float, float, float]] = []
    channels: list[tuple[str, ...]] = []
    end_site: list[bool] = []

    def parse_joint(parent: int, keyword_line: int, is_end: bool, joint_name: str) -> None:
        index = len(names)
        names.append(joint_name)
        parents.append(parent)
        end_site.append(is_end)
        toks.expect("{")
        toks.expect("OFFSET")
        offsets.append(tuple(toks.number(f"OFFSET of '{joint_name}'") for _ in range(3)))
        chans: tuple[str, ...] = ()
        if not is_end:
            if (toks.peek() or "").upper() != "CHANNELS":
                raise toks.error(f"expected 'CHANNELS' for joint '{joint_name}'")
            toks.next("CHANNELS")
            count_tok, count_line = toks.next("a channel count")
            if not count_tok.isdigit():
                raise toks.error(f"expected a channel count for '{joint_name}', got '{count_tok}'", count_line)
            count = int(count_tok)
            got = []
            while len(got) < count and (toks.peek() or "").lower() in _CANONICAL:
                got.append(_CANONICAL[toks.next("a channel")[0].lower()])
            if len(got) != count:
                nxt = toks.peek()
                raise toks.error(
                    f"joint '{joint_name}' declares {count} channels but lists {len(got)}"
                    + (f" (next token '{nxt}' is not a channel name)" if nxt is not None else ""),
                    count_line,
                )
            if len(set(got)) != len(got):
                raise toks.error(f"joint '{joint_name}' lists a channel twice: {' '.join(got)}", count_line)
            chans = tuple(got)
        channels.append(chans)
        while True:
            tok, line = toks.next(f"'}}' closing '{joint_name}'")
            key = tok.upper()
            if tok == "}":
                return
            if is_end:
                raise toks.error(f"unexpected '{tok}' inside End Site of '{names[parent]}'", line)
            if key == "JOINT":
                child, _ = toks.next("a joint name")
                parse_joint(index, line, False, child)
            elif key == "END":
                site, site_line = toks.next("'Site'")
                if site.lower() != "site":
                    raise toks.error(f"expected 'End Site', got 'End {site}'", site_line)
                parse_joint(index, line, True, f"{joint_name}_end")
            else:
                raise toks.error(f"unexpected '{tok}' in joint '{joint_name}' (expected JOINT, End Site or '}}')",
                                 line)

    while toks.peek() is not None:
        tok, line = toks.next("ROOT")
        if tok.upper() != "ROOT":
            raise toks.error(f"expected 'ROOT', got '{tok}'", line)
        root_name, _ = toks.next("a root name")
        parse_joint(-1, line, False, root_name)
    if not names:
        raise FileFormatError(f"{name}:{motion_at + 1}: HIERARCHY declares no ROOT joint")
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise FileFormatError(f"{name}: joint name '{dup}' appears twice in HIERARCHY")

    frames, frame_time, data_start = _parse_motion_header(name, lines, motion_at)
    num_channels = sum(len(c) for c in channels)
    rows = [i for i in range(data_start, len(lines)) if lines[i].strip()]
    extra, dropped_at = 0, None
    if len(rows) == frames + 1:
        if _all_zero(lines[rows[0]]):
            rows, extra, dropped_at = rows[1:], 1, "first"
        else:
            rows, extra, dropped_at = rows[:-1], 1, "last"
    elif len(rows) != frames:
        at = rows[frames + 1] + 1 if len(rows) > frames + 1 else len(lines)
        raise FileFormatError(
            f"{name}:{at}: 'Frames: {frames}' but the file has {len(rows)} motion lines"
        )
    motion = np.empty((frames, num_channels), dtype=np.float64)
    for f, i in enumerate(rows):
        values = lines[i].split()
        if len(values) != num_channels:
            raise FileFormatError(
                f"{name}:{i + 1}: motion line has {len(values)} values, the HIERARCHY declares {num_channels} channels"
            )
        try:
            motion[f] = [float(v) for v in values]
        except ValueError:
            bad = next(v for v in values if not _is_float(v))
            raise FileFormatError(f"{name}:{i + 1}: non-numeric motion value '{bad}'") from None
    if not np.isfinite(motion).all():
        f = int(np.nonzero(~np.isfinite(motion).all(axis=1))[0][0])
        raise FileFormatError(f"{name}:{rows[f] + 1}: non-finite motion value")

    offs = np.asarray(offsets, dtype=np.float64).reshape(-1, 3)
    offs.setflags(write=False)
    motion.setflags(write=False)
    return BVHClip(path=name, names=tuple(names), parents=tuple(parents), offsets=offs,
                   channels=tuple(channels), is_end_site=tuple(end_site), frame_time=frame_time,
                   motion=motion, extra_lines_dropped=extra, extra_line_dropped_at=dropped_at)


def _parse_motion_header(name: str, lines: list[str], motion_at: int) -> tuple[int, float, int]:
    """``Frames:`` and ``Frame Time:`` after ``MOTION``; returns (frames, frame_time, first data line index)."""
    body = [i for i in range(motion_at + 1, len(lines)) if lines[i].strip()]
    if len(body) < 2:
        raise FileFormatError(f"{name}:{len(lines)}: MOTION needs 'Frames:' and 'Frame Time:' lines")
    i_frames, i_time = body[0], body[1]
    head, _, value = lines[i_frames].partition(":")
    if head.strip().lower() != "frames" or not value.strip().isdigit():
        raise FileFormatError(f"{name}:{i_frames + 1}: expected 'Frames: <count>', got '{lines[i_frames].strip()}'")
    frames = int(value)
    head, _, value = lines[i_time].partition(":")
    if " ".join(head.lower().split()) != "frame time":
        raise FileFormatError(f"{name}:{i_time + 1}: expected 'Frame Time: <seconds>', got '{lines[i_time].strip()}'")
    try:
        frame_time = float(value)
    except ValueError:
        raise FileFormatError(f"{name}:{i_time + 1}: 'Frame Time' is not a number: '{value.strip()}'") from None
    if not (math.isfinite(frame_time) and frame_time > 0):
        raise FileFormatError(f"{name}:{i_time + 1}: 'Frame Time' must be positive, got {frame_time}")
    if frames < 1:
        raise FileFormatError(f"{name}:{i_frames + 1}: 'Frames' must be at least 1, got {frames}")
    return frames, frame_time, i_time + 1


def _all_zero(line: str) -> bool:
    """Whether a motion line holds only numbers equal to zero."""
    try:
        return all(float(v) == 0.0 for v in line.split())
    except ValueError:
        return False


def _is_float(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


# ---------------------------------------------------------------------------------------------------------------
# writing


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
    unit = 0.5 * 10.0 ** -precision
    values = np.where(np.abs(motion[:, columns]) < unit, 0.0, motion[:, columns])   # no "-0.000000"
    row = " ".join([f"%.{precision}f"] * values.shape[1])
    out += ["MOTION", f"Frames: {values.shape[0]}", f"Frame Time: {_frame_time_text(ft)}"]
    out += [row % tuple(r) for r in values.tolist()]
    atomic_text(p, "\n".join(out) + "\n")
    return p


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
