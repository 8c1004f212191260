"""Reading BVH files (:func:`read_bvh`; format, tolerated quirk and errors in :mod:`torchhand.scene.bvh`).

Stages, each a function of the file's lines: the two sections (``HIERARCHY`` and ``MOTION``), the hierarchy
(:class:`_Hierarchy`, parsed token by token by :class:`_HierarchyParser`), the motion header (``Frames:``,
``Frame Time:``), then the motion lines (:class:`_Motion`), checked against the hierarchy's channel count.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FileFormatError, MissingFileError
from ._bvh_clip import CHANNEL_NAMES, BVHClip

__all__ = ["read_bvh"]

_CANONICAL = {c.lower(): c for c in CHANNEL_NAMES}


@dataclass(frozen=True)
class _Sections:
    """Where the sections of a BVH file start: ``first`` the ``HIERARCHY`` line, ``motion_at`` the ``MOTION``
    line (0-based line indices)."""

    first: int
    motion_at: int


@dataclass(frozen=True)
class _Hierarchy:
    """The parsed ``HIERARCHY`` section (fields as :class:`BVHClip`'s; ``offsets`` as read, J tuples of 3)."""

    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: tuple[tuple[float, float, float], ...]
    channels: tuple[tuple[str, ...], ...]
    is_end_site: tuple[bool, ...]

    @property
    def num_channels(self) -> int:
        """C, the number of motion columns the hierarchy declares."""
        return sum(len(c) for c in self.channels)


@dataclass(frozen=True)
class _MotionHeader:
    """``Frames:`` and ``Frame Time:`` of the ``MOTION`` section; ``data_start``: index of the line after them."""

    frames: int
    frame_time: float
    data_start: int


@dataclass(frozen=True)
class _Motion:
    """The parsed motion: ``values`` (F, C) float64 (writable), the extra line dropped (``BVHClip`` fields)."""

    values: np.ndarray
    extra_lines_dropped: int
    extra_line_dropped_at: str | None


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


class _HierarchyParser:
    """Recursive descent over the ``HIERARCHY`` tokens: joints are appended depth-first, so parents precede
    children and the motion columns follow the joints in index order."""

    def __init__(self, toks: _Tokens):
        self.toks = toks
        self.names: list[str] = []
        self.parents: list[int] = []
        self.offsets: list[tuple[float, float, float]] = []
        self.channels: list[tuple[str, ...]] = []
        self.end_site: list[bool] = []

    def roots(self) -> None:
        """Every ``ROOT`` block up to the end of the section."""
        toks = self.toks
        while toks.peek() is not None:
            tok, line = toks.next("ROOT")
            if tok.upper() != "ROOT":
                raise toks.error(f"expected 'ROOT', got '{tok}'", line)
            root_name, _ = toks.next("a root name")
            self.joint(-1, False, root_name)

    def joint(self, parent: int, is_end: bool, joint_name: str) -> None:
        """One ``{ OFFSET .. CHANNELS .. children }`` block (an End Site has no CHANNELS and no children)."""
        toks = self.toks
        index = len(self.names)
        self.names.append(joint_name)
        self.parents.append(parent)
        self.end_site.append(is_end)
        toks.expect("{")
        toks.expect("OFFSET")
        self.offsets.append(tuple(toks.number(f"OFFSET of '{joint_name}'") for _ in range(3)))
        self.channels.append(() if is_end else self._channels(joint_name))
        self._children(index, parent, is_end, joint_name)

    def _channels(self, joint_name: str) -> tuple[str, ...]:
        toks = self.toks
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
        return tuple(got)

    def _children(self, index: int, parent: int, is_end: bool, joint_name: str) -> None:
        """``JOINT`` and ``End Site`` blocks up to the joint's closing brace."""
        toks = self.toks
        while True:
            tok, line = toks.next(f"'}}' closing '{joint_name}'")
            key = tok.upper()
            if tok == "}":
                return
            if is_end:
                raise toks.error(f"unexpected '{tok}' inside End Site of '{self.names[parent]}'", line)
            if key == "JOINT":
                child, _ = toks.next("a joint name")
                self.joint(index, False, child)
            elif key == "END":
                site, site_line = toks.next("'Site'")
                if site.lower() != "site":
                    raise toks.error(f"expected 'End Site', got 'End {site}'", site_line)
                self.joint(index, True, f"{joint_name}_end")
            else:
                raise toks.error(f"unexpected '{tok}' in joint '{joint_name}' (expected JOINT, End Site or '}}')",
                                 line)

    def result(self) -> _Hierarchy:
        return _Hierarchy(names=tuple(self.names), parents=tuple(self.parents), offsets=tuple(self.offsets),
                          channels=tuple(self.channels), is_end_site=tuple(self.end_site))


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
    name, lines = _read_lines(path)
    sections = _sections(name, lines)
    hierarchy = _parse_hierarchy(name, lines, sections)
    header = _parse_motion_header(name, lines, sections.motion_at)
    motion = _parse_motion(name, lines, header, hierarchy.num_channels)

    offs = np.asarray(hierarchy.offsets, dtype=np.float64).reshape(-1, 3)
    offs.setflags(write=False)
    values = motion.values
    values.setflags(write=False)
    return BVHClip(path=name, names=hierarchy.names, parents=hierarchy.parents, offsets=offs,
                   channels=hierarchy.channels, is_end_site=hierarchy.is_end_site, frame_time=header.frame_time,
                   motion=values, extra_lines_dropped=motion.extra_lines_dropped,
                   extra_line_dropped_at=motion.extra_line_dropped_at)


def _read_lines(path: str | os.PathLike) -> tuple[str, list[str]]:
    """(the path as a str, the file's lines)."""
    p = Path(path)
    if not p.is_file():
        raise MissingFileError(f"path: BVH file '{p}' does not exist")
    try:
        text = p.read_text(encoding="utf-8", errors="replace")
    except OSError as err:
        raise MissingFileError(f"path: cannot read BVH file '{p}': {err}") from None
    return str(p), text.splitlines()


def _sections(name: str, lines: list[str]) -> _Sections:
    first = next((i for i, ln in enumerate(lines) if ln.strip()), None)
    if first is None or lines[first].strip().upper() != "HIERARCHY":
        raise FileFormatError(f"{name}:{(first or 0) + 1}: expected 'HIERARCHY' as the first line")
    motion_at = next((i for i in range(first + 1, len(lines)) if lines[i].strip().upper() == "MOTION"), None)
    if motion_at is None:
        raise FileFormatError(f"{name}:{len(lines)}: no 'MOTION' section")
    return _Sections(first=first, motion_at=motion_at)


def _parse_hierarchy(name: str, lines: list[str], sections: _Sections) -> _Hierarchy:
    """The joints between ``HIERARCHY`` and ``MOTION``: at least one ROOT, names unique."""
    parser = _HierarchyParser(_Tokens(name, lines, sections.first + 1, sections.motion_at))
    parser.roots()
    names = parser.names
    if not names:
        raise FileFormatError(f"{name}:{sections.motion_at + 1}: HIERARCHY declares no ROOT joint")
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise FileFormatError(f"{name}: joint name '{dup}' appears twice in HIERARCHY")
    return parser.result()


def _parse_motion_header(name: str, lines: list[str], motion_at: int) -> _MotionHeader:
    """``Frames:`` and ``Frame Time:`` after ``MOTION``."""
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
    return _MotionHeader(frames=frames, frame_time=frame_time, data_start=i_time + 1)


def _parse_motion(name: str, lines: list[str], header: _MotionHeader, num_channels: int) -> _Motion:
    """The motion lines: ``Frames`` of them (or one more, dropped: the tolerated quirk), C finite numbers each."""
    frames = header.frames
    rows = [i for i in range(header.data_start, len(lines)) if lines[i].strip()]
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
    return _Motion(values=motion, extra_lines_dropped=extra, extra_line_dropped_at=dropped_at)


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
