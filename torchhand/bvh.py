"""A robust reader for Biovision Hierarchy (BVH) motion files.

Format
    ``HIERARCHY`` then one or more ``ROOT name { OFFSET x y z  CHANNELS n ch1 .. chn  JOINT ... / End Site {...} }``
    blocks, then ``MOTION``, ``Frames: F``, ``Frame Time: dt`` and ``F`` lines of ``C`` numbers (C = the sum of
    all ``CHANNELS`` counts, in hierarchy order). Keywords are case-sensitive in the spec; this reader accepts any
    case and any whitespace layout (braces may share a line with other tokens).

Kinematics (what :meth:`BVHClip.global_transforms` computes)
    The local transform of a joint is ``Translate(OFFSET + position channels) @ R``, with
    ``R = R(ch1) @ R(ch2) @ R(ch3)`` for its rotation channels *in the order they are listed* (intrinsic
    rotations; e.g. ``Yrotation Xrotation Zrotation`` gives ``Ry @ Rx @ Rz``). Angles are degrees in the file and
    radians in every tensor this module returns. Position channels add to the offset (this matches rigs whose
    non-root joints carry zero-valued position channels, such as the Leap Motion exports; for a root with zero
    offset it is the usual "absolute root position"). The global transform is ``parent_global @ local``;
    transforms are 4x4, column-vector convention (``p_parent = T_parent_joint @ p_joint``), in the file's units
    and axes (no unit or up-axis conversion happens here: see :mod:`torchhand.mocap`).

End Sites
    Each ``End Site`` becomes a joint without channels named ``<parent>_end`` (``is_end_site`` True), so
    fingertip positions are available from :meth:`BVHClip.global_transforms` like any other joint.

Tolerated quirk
    Some exporters (the Leap Motion gestures in ``leap_hand_bvh``) write one more motion line than ``Frames:``
    says. Exactly one extra line is dropped (``BVHClip.extra_lines_dropped == 1``); any other mismatch between
    ``Frames:`` and the number of motion lines is a :class:`~torchhand.errors.FileFormatError`. Blank lines are
    ignored everywhere.

Errors
    A missing file raises :class:`~torchhand.errors.MissingFileError`; anything malformed (missing
    ``HIERARCHY``/``MOTION``, unknown channel names, wrong channel counts, unbalanced braces, non-numeric or
    non-finite values, a frame count mismatch) raises :class:`~torchhand.errors.FileFormatError` with
    ``path:line:`` in the message.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .errors import FileFormatError, InputValueError, MissingFileError, UnknownNameError

__all__ = ["BVHClip", "read_bvh", "euler_to_matrix", "CHANNEL_NAMES"]

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
        extra_lines_dropped: motion lines beyond ``Frames:`` that were dropped (0, or 1 for the Leap quirk)
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
        """Global transforms with every channel zero (the rest pose), (J, 4, 4), file units, float64."""
        return self._global(np.zeros((1, self.motion.shape[1]), dtype=np.float64))[0]

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
                    out[:, j, axis, 3] += motion[:, start + i]
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


def euler_to_matrix(angles: torch.Tensor, order: str) -> torch.Tensor:
    """Rotation matrices from intrinsic Euler angles.

    Args:
        angles: rotation angles in the order of ``order``, (..., 3), radians
        order: three axis letters, e.g. ``"YXZ"``: ``R = Ry(a0) @ Rx(a1) @ Rz(a2)`` (BVH channel order)

    Returns:
        R: rotation matrices, (..., 3, 3)
    """
    order = order.upper()
    if len(order) != 3 or any(c not in "XYZ" for c in order):
        raise InputValueError(f"order: expected three letters from X, Y, Z, got '{order}'")
    if angles.shape[-1:] != (3,):
        raise InputValueError(f"angles: expected shape (..., 3), got {tuple(angles.shape)}")
    R = _axis_rotation(angles[..., 0], "XYZ".index(order[0]))
    for k in (1, 2):
        R = R @ _axis_rotation(angles[..., k], "XYZ".index(order[k]))
    return R


def _axis_rotation(angle: torch.Tensor, axis: int) -> torch.Tensor:
    """Rotation by ``angle (...)`` radians about coordinate axis ``axis`` (0, 1, 2), (..., 3, 3)."""
    c, s = torch.cos(angle), torch.sin(angle)
    one, zero = torch.ones_like(angle), torch.zeros_like(angle)
    if axis == 0:
        rows = ((one, zero, zero), (zero, c, -s), (zero, s, c))
    elif axis == 1:
        rows = ((c, zero, s), (zero, one, zero), (-s, zero, c))
    else:
        rows = ((c, -s, zero), (s, c, zero), (zero, zero, one))
    return torch.stack([torch.stack(r, dim=-1) for r in rows], dim=-2)


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
    extra = 0
    if len(rows) == frames + 1:
        rows, extra = rows[:-1], 1
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
                   motion=motion, extra_lines_dropped=extra)


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


def _is_float(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True
