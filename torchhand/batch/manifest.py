"""Batch manifests (``batch.toml``, docs/batch.md): parsing, validation, expansion into jobs, and job ids.

A manifest has a ``[defaults]`` table and one or more ``[[jobs]]`` tables. Each jobs table, merged over the
defaults, names a ``method`` and the lists and options of that method, named as its flags with ``_`` for ``-``
(``max_nodes = 400`` is ``--max-nodes 400``):

=============== ======================================= ============================================================
method          lists (expanded as a product, in order) command of each job
=============== ======================================= ============================================================
``synthesize``  ``scenes`` x ``seeds`` x ``hands``      ``torchhand synthesize SCENE --seed S [--hand H] ...``
``manipulate``  ``scenes`` x ``grasps``                 ``torchhand manipulate SCENE [--grasp G] ...``
``capture``     ``interactions`` x ``scenes``           ``torchhand capture resynthesize INTERACTION --scene S ...``
=============== ======================================= ============================================================

A ``[[jobs]]`` table may hold only its method's keys; ``[defaults]`` may hold the keys of any method, and a table
takes from it only the keys of its own method. Relative paths (scene directories, hand, grasp and interaction
files) are relative to the manifest's directory.

A job's id is a readable prefix and the first 10 hex digits of the SHA-256 of what the job computes: its method,
its inputs (a built-in scene's name or the content of a scene directory; the content of the hand's MJCF file and
its sidecar, of the grasp file, of the interaction file), its seed (synthesize) and every option, with the defaults
filled in (so ``epsilon = 10.0`` written out and left out give the same id). Prefixes:
``<scene>_s<seed>_<hand>`` (synthesize), ``<scene>_<grasp>`` (manipulate), ``<scene>_<interaction>`` (capture).
How a job runs (``--threads``, ``--device``, ``--workers``, Ray or not) is not part of the id. Everything here is
validated before any work: a bad manifest is one :class:`~torchhand.errors.TorchhandError` naming the table and
the key.

Modules: ``_schema`` (methods, lists, options, the validation of a table), ``_job`` (:class:`Job`), ``_expand``
(a table's jobs, inputs resolved and hashed, ids); this module reads the document and ties them together.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

from ..errors import FileFormatError, InputTypeError, InputValueError, MissingFileError, UnknownNameError
from ._expand import _table_jobs
from ._job import Job
from ._schema import (CAPTURE_OPTIONS, FUTURE_METHODS, MANIPULATE_OPTIONS, METHOD_LISTS, METHOD_OPTIONS, METHODS,
                      OPTIONS, _check_keys, _table)

__all__ = ["METHODS", "FUTURE_METHODS", "OPTIONS", "MANIPULATE_OPTIONS", "CAPTURE_OPTIONS", "METHOD_OPTIONS",
           "METHOD_LISTS", "Job", "Manifest", "load_manifest", "parse_manifest"]


@dataclass(frozen=True)
class Manifest:
    """A parsed, validated manifest.

    path: the manifest file, absolute; text: its text, as read
    jobs: the expanded jobs in manifest order (table by table, each table's lists in :data:`METHOD_LISTS` order,
        the first outermost), each once
    """

    path: Path
    text: str
    jobs: tuple[Job, ...]

    @property
    def ids(self) -> tuple[str, ...]:
        return tuple(j.id for j in self.jobs)


@dataclass(frozen=True)
class _Document:
    """The TOML document of a manifest, its top level checked: ``defaults`` (key -> value) and the ``[[jobs]]``
    ``tables`` in file order."""

    defaults: dict
    tables: tuple[dict, ...]


def load_manifest(path, *, check_inputs: bool = True) -> Manifest:
    """Read, validate and expand the manifest at ``path``.

    check_inputs: also load every scene, hand, grasp and interaction once (a bad scene directory, an unknown
        built-in scene, a hand for a side the scene lacks, ``frames`` beyond the scene, an unreadable MJCF, a grasp
        that does not fit its hand or whose side the scene lacks, an interaction whose joints are not the scene
        hand's fail here, before any work)
    Raises MissingFileError, FileFormatError (malformed TOML), InputValueError / InputTypeError /
    UnknownNameError naming the table and the key.
    """
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"MANIFEST: {path} does not exist or is not a file")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise FileFormatError(f"{path}: cannot read: {err}") from None
    return parse_manifest(text, path.resolve(), check_inputs=check_inputs)


def parse_manifest(text: str, path: Path, *, check_inputs: bool = True) -> Manifest:
    """:func:`load_manifest` of ``text``; relative paths are taken relative to ``path.parent``."""
    doc = _document(text, path)
    seen: dict = {}
    jobs: dict[str, Job] = {}
    used: list[str] = []
    for i, entry in enumerate(doc.tables, 1):
        where = f"[[jobs]] #{i}"
        table = _table(doc.defaults, entry, where)
        used.append(table.method)
        for job in _table_jobs(table, path.parent, where, seen, check_inputs):
            jobs.setdefault(job.id, job)
    _check_defaults_used(doc.defaults, used)
    return Manifest(path=path, text=text, jobs=tuple(jobs.values()))


def _document(text: str, path: Path) -> _Document:
    """The TOML of ``text``: only ``[defaults]`` and at least one ``[[jobs]]`` table, every default known."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise FileFormatError(f"{path}: malformed TOML: {err}") from None
    for key in doc:
        if key not in ("defaults", "jobs"):
            raise UnknownNameError(f"{path.name}: unknown key '{key}' at the top level; expected [defaults] and "
                                   f"[[jobs]] tables")
    defaults = doc.get("defaults", {})
    tables = doc.get("jobs", [])
    if not isinstance(defaults, dict):
        raise InputTypeError(f"{path.name}: 'defaults' must be a table ([defaults])")
    if not isinstance(tables, list) or not tables or not all(isinstance(t, dict) for t in tables):
        raise InputValueError(f"{path.name}: expected at least one [[jobs]] table")
    _check_keys(defaults, "[defaults]", None)
    return _Document(defaults=defaults, tables=tuple(tables))


def _check_defaults_used(defaults: dict, used: list[str]) -> None:
    """A default no table takes is a mistake (a typo'd method, ...)."""
    for key in defaults:
        if key != "method" and not any(key in METHOD_LISTS[m] or key in METHOD_OPTIONS[m] for m in used):
            raise InputValueError(f"[defaults]: key '{key}' applies to no [[jobs]] table of this manifest (methods: "
                                  f"{', '.join(dict.fromkeys(used))})")
