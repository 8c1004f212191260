"""Variant files of ``torchhand capture resynthesize --variants FILE`` (docs/interaction_capture.md, "Variants").

A TOML file with one ``[[variant]]`` table per rollout; all of them run as rollouts of one batched step, and each
gets its own result directory ``--out DIR/<name>``::

    [[variant]]
    name = "same"                      # required: the result's directory name (letters, digits, - _ .)

    [[variant]]
    name = "smaller"
    object = "smaller.obj"             # a mesh file, or a scene directory (its object); relative to this file
    mass = 0.25                        # kg (default: the object's; a mesh file's object gets the scene's mass)
    friction = 0.6                     # hand-object mu (default: the scene's)
    compliance_scale = 0.5             # multiplies C (default 1)

Every variant's object starts at the scene's frame-0 object pose. Variants that name the same file share one
object. Units: kilograms, metres.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from ..errors import FileFormatError, InputValueError, MissingFileError
from ._resynth_types import Variant

__all__ = ["load_variant_file"]

_KEYS = {"name", "object", "mass", "friction", "compliance_scale"}
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


def load_variant_file(path, scene) -> tuple[tuple[str, Variant], ...]:
    """The (name, :class:`Variant`) pairs of a variant file (module docstring), in file order.

    scene: the :class:`~torchhand.scene.Scene` the variants change (its object's mass is a mesh file's default)
    raises: MissingFileError, FileFormatError (not TOML), InputValueError (a bad or missing entry, named)
    """
    p = Path(path)
    if not p.is_file():
        raise MissingFileError(f"--variants: file '{p}' does not exist")
    try:
        doc = tomllib.loads(p.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise FileFormatError(f"--variants: '{p}' is not a TOML file: {err}") from None
    tables = doc.get("variant")
    if set(doc) - {"variant"} or not isinstance(tables, list) or not tables:
        raise InputValueError(f"--variants: '{p}' needs one or more [[variant]] tables and nothing else")
    objects: dict = {}
    out, names = [], set()
    for i, t in enumerate(tables):
        where = f"--variants: variant {i + 1}"
        if not isinstance(t, dict) or set(t) - _KEYS:
            raise InputValueError(f"{where}: unknown keys {sorted(set(t) - _KEYS)} (allowed: {sorted(_KEYS)})")
        name = t.get("name")
        if not isinstance(name, str) or not _NAME.match(name) or name in names:
            raise InputValueError(f"{where}: name must be a new directory name (letters, digits, - _ .), got "
                                  f"{name!r}")
        names.add(name)
        obj = None
        if "object" in t:
            obj = _object(p.parent, t["object"], scene, objects, f"{where} ({name})")
        out.append((name, Variant(mass=_number(t, "mass", where), friction=_number(t, "friction", where),
                                  compliance_scale=_number(t, "compliance_scale", where, 1.0), object=obj)))
    return tuple(out)


def _number(t: dict, key: str, where: str, default=None):
    v = t.get(key, default)
    if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))):
        raise InputValueError(f"{where}: {key} must be a number, got {v!r}")
    return None if v is None else float(v)


def _object(base: Path, value, scene, cache: dict, where: str):
    """The object a variant names: a mesh file (at the scene's object mass) or a scene directory's object; one
    object per path."""
    from ..geometry.objects import load_object
    from ..scene import load_scene

    if not isinstance(value, str) or not value:
        raise InputValueError(f"{where}: object must be a path, got {value!r}")
    path = (base / value).resolve()
    if path not in cache:
        if path.is_dir():
            cache[path] = load_scene(path).object
        elif path.is_file():
            cache[path] = load_object(path, mass=float(scene.object.mass), repair=True)
        else:
            raise MissingFileError(f"{where}: object '{value}' is neither a mesh file nor a scene directory")
    return cache[path]
