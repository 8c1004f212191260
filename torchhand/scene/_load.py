"""``load_scene``: a built-in scene by name, or a scene directory."""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import InputTypeError, MissingFileError, UnknownNameError
from ._model import Scene
from ._reader import load_scene_dir
from .builtin import builtin_scene, list_builtin_scenes

__all__ = ["load_scene"]


def _builtin_over_dir(name_or_dir, p: Path) -> bool:
    """A plain built-in scene name that also names a directory without a ``scene.toml`` in the working directory
    (an output directory named after the scene, ``--out box-turn``) means the built-in scene."""
    if not (isinstance(name_or_dir, str) and p.is_dir()) or (p / "scene.toml").is_file():
        return False
    if any(s in name_or_dir for s in ("/", "\\", os.sep)):
        return False
    return name_or_dir in list_builtin_scenes()


def load_scene(name_or_dir: str | os.PathLike) -> Scene:
    """Load a built-in scene by name or a scene directory (``docs/scene_format.md``), validated.

    A value that names an existing directory (or a ``scene.toml`` file) is read from disk; a plain name (no path
    separator) is looked up among :func:`torchhand.scene.builtin.list_builtin_scenes`. A plain built-in name that is also a
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
        return load_scene_dir(p.parent if p.is_file() else p)
    text = os.fspath(name_or_dir)
    if isinstance(name_or_dir, str) and not any(s in text for s in ("/", "\\", os.sep)) and text not in (".", ".."):
        if text in list_builtin_scenes():
            return builtin_scene(text).validate()
        raise UnknownNameError(
            f"name_or_dir: '{text}' is neither a built-in scene nor a directory; "
            f"built-in scenes: {', '.join(list_builtin_scenes())}"
        )
    raise MissingFileError(f"name_or_dir: scene directory '{text}' does not exist")
