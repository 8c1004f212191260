"""Atomic file writes: a temporary file in the target's folder, flushed and moved into place with ``os.replace``,
so a reader sees the old file or the new one, never a torn one, and an error leaves nothing behind."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

__all__ = ["atomic_bytes", "atomic_json", "atomic_text", "writable_dir"]


def atomic_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (parent folders are created)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_text(path: Path, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    atomic_bytes(path, text.encode("utf-8"))


def atomic_json(path: Path, obj: dict) -> None:
    """Write ``obj`` as indented JSON to ``path`` atomically."""
    atomic_bytes(path, (json.dumps(obj, indent=2) + "\n").encode())


def writable_dir(out: Path) -> Path:
    """Create ``out`` (and its parents) and prove a file can be written there, before any work; a one-line
    InputValueError naming ``--out`` otherwise."""
    from .errors import InputValueError

    out = Path(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / f".probe-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as err:
        raise InputValueError(f"--out {out}: cannot write there ({err.strerror or err})") from None
    return out


def claim_output_dir(out, is_ours, what: str, overwrite: bool) -> tuple[Path, list[Path]]:
    """Check ``--out`` before any work: it must be new, empty, or hold only an earlier output (``is_ours(path)``
    true for every entry), and that only with ``overwrite``. Nothing is created or removed here.

    what: the earlier output's name in messages ("estimate", "inferred interaction")
    returns: (out, the entries of the earlier output); raises InputValueError naming ``--out``
    """
    from .errors import InputValueError

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputValueError(f"--out {out}: exists and is not a directory")
    if not out.is_dir():
        return out, []
    entries = list(out.iterdir())
    ours = [p for p in entries if is_ours(p)]
    foreign = sorted(p.name for p in entries if not is_ours(p))
    if foreign:
        raise InputValueError(f"--out {out}: not empty and not an earlier {what} (holds {foreign[0]!r}"
                              f"{' and more' if len(foreign) > 1 else ''}); choose a new or empty directory")
    if ours and not overwrite:
        raise InputValueError(f"--out {out}: holds an earlier {what}; pass --overwrite to replace it")
    return out, ours
