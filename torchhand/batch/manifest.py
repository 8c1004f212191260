"""Batch manifests (``batch.toml``, docs/batch.md): parsing, validation, expansion into jobs, and job ids.

A manifest has a ``[defaults]`` table and one or more ``[[jobs]]`` tables. Each jobs table, merged over the
defaults, names a ``method`` (``"synthesize"``), lists of ``scenes``, ``seeds`` and ``hands`` that expand as a
product (scene-major), and the method's options, named as the ``torchhand synthesize`` flags with ``_`` for ``-``
(``max_nodes = 400`` is ``--max-nodes 400``). Relative paths (scene directories, hand files) are relative to the
manifest's directory.

A job's id is ``<scene>_s<seed>_<hand>_<hash10>``: a readable prefix and the first 10 hex digits of the SHA-256 of
what the job computes: its method, its inputs (a built-in scene's name or the content of a scene directory; the
content of the hand's MJCF file and its sidecar) and every option, with the defaults filled in (so ``epsilon =
10.0`` written out and left out give the same id). How a job runs (``--threads``, ``--device``, ``--workers``,
Ray or not) is not part of the id. Everything here is validated before any work: a bad manifest is one
:class:`~torchhand.errors.TorchhandError` naming the table and the key.
"""

from __future__ import annotations

import hashlib
import json
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path

from ..errors import FileFormatError, InputTypeError, InputValueError, MissingFileError, UnknownNameError

__all__ = ["METHODS", "FUTURE_METHODS", "OPTIONS", "Job", "Manifest", "load_manifest", "parse_manifest"]

METHODS = ("synthesize",)
"""Methods a batch runs."""

FUTURE_METHODS = {
    "splice": "run `torchhand splice --body B --hand H --out DIR` for each pair",
    "capture": "interaction capture has no command yet",
    "manipulate": "manipulation from a grasping pose has no command yet",
}
"""Methods of torchhand that batch manifests do not run yet, with what to do instead."""


@dataclass(frozen=True)
class _Option:
    flag: str                 # the synthesize flag
    kind: str                 # "int", "float", "str", "bool", "frames"
    default: object           # the flag's default (None: the flag is left out)
    low: float | None = None  # least value (ints and floats)
    strict: bool = False      # value must exceed ``low``
    choices: tuple = ()


OPTIONS = {
    "solutions": _Option("--solutions", "int", 10, 1),
    "max_nodes": _Option("--max-nodes", "int", 60000, 0),
    "time_budget": _Option("--time-budget", "float", None, 0, strict=True),
    "epsilon": _Option("--epsilon", "float", 10.0, 0, strict=True),
    "strategy": _Option("--strategy", "str", "mixed", choices=("static", "sliding", "relocating", "mixed")),
    "frames": _Option("--frames", "frames", None),
    "slide_speed": _Option("--slide-speed", "float", 0.02, 0, strict=True),
    "smooth": _Option("--smooth", "float", 0.0, 0),
    "max_joint_speed": _Option("--max-joint-speed", "float", 8.0, 0, strict=True),
    "keep_unsmoothed": _Option("--keep-unsmoothed", "bool", False),
    "no_reconstruct": _Option("--no-reconstruct", "bool", False),
    "trees": _Option("--trees", "int", 16, 1),
    "candidates": _Option("--candidates", "int", 16, 1),
    "dtype": _Option("--dtype", "str", "float32", choices=("float32", "float64")),
}
"""Options of a ``synthesize`` job: manifest key -> flag, type, default (the flag's own default; a test holds the
two together), range. ``seed`` is not an option: seeds are listed as ``seeds = [...]``."""

_LISTS = ("scenes", "seeds", "hands")
_TABLE_KEYS = ("method",) + _LISTS
_SIDES = ("right", "left")


@dataclass(frozen=True)
class Job:
    """One run of a batch: one method on one scene with one seed, one hand choice and fixed options.

    id: ``<scene>_s<seed>_<hand>_<hash10>``, the name of its result directory ``DIR/jobs/<id>/``
    method: ``"synthesize"``
    scene: a built-in scene name, or the absolute path of a scene directory
    seed: the random seed
    hand: ``"default"`` (the scene's own hands) or ``"SIDE=ABSOLUTE_PATH.xml"``
    options: (name, value) pairs in :data:`OPTIONS` order, every option with its default filled in
    inputs: what was hashed for the scene and the hand (built-in name or SHA-256 of the content)
    """

    id: str
    method: str
    scene: str
    seed: int
    hand: str
    options: tuple[tuple[str, object], ...]
    inputs: tuple[tuple[str, str], ...]

    def argv(self) -> list[str]:
        """The ``torchhand`` command line of the job, without ``--out``, ``--threads``, ``--device`` and
        ``--no-progress`` (the runner adds them). Every option is passed explicitly."""
        args = [self.method, self.scene, "--seed", str(self.seed)]
        for name, value in self.options:
            spec = OPTIONS[name]
            if spec.kind == "bool":
                args += [spec.flag] if value else []
            elif value is not None:
                args += [spec.flag, str(value)]
        if self.hand != "default":
            args += ["--hand", self.hand]
        return args

    def to_dict(self) -> dict:
        return {"id": self.id, "method": self.method, "scene": self.scene, "seed": self.seed, "hand": self.hand,
                "options": dict(self.options), "inputs": dict(self.inputs), "argv": self.argv()}


@dataclass(frozen=True)
class Manifest:
    """A parsed, validated manifest.

    path: the manifest file, absolute; text: its text, as read
    jobs: the expanded jobs in manifest order (table by table, scene-major, then seeds, then hands), each once
    """

    path: Path
    text: str
    jobs: tuple[Job, ...]

    @property
    def ids(self) -> tuple[str, ...]:
        return tuple(j.id for j in self.jobs)


def load_manifest(path, *, check_inputs: bool = True) -> Manifest:
    """Read, validate and expand the manifest at ``path``.

    check_inputs: also load every scene and hand once (a bad scene directory, an unknown built-in scene, a hand
        for a side the scene lacks, ``frames`` beyond the scene, an unreadable MJCF fail here, before any work)
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
    _check_keys(defaults, "[defaults]")
    scenes_seen: dict[str, tuple] = {}
    jobs: dict[str, Job] = {}
    for i, table in enumerate(tables, 1):
        where = f"[[jobs]] #{i}"
        _check_keys(table, where)
        merged = {**defaults, **table}
        method = merged.get("method", "synthesize")
        _check_method(method, where)
        options = _options(merged, where)
        scenes = _list(merged, "scenes", str, where, None)
        seeds = _list(merged, "seeds", int, where, [0])
        hands = _list(merged, "hands", str, where, ["default"])
        for scene_entry in scenes:
            scene, scene_key = _scene(scene_entry, path.parent, where, scenes_seen)
            for seed in seeds:
                for hand_entry in hands:
                    hand, hand_key = _hand(hand_entry, path.parent, where)
                    if check_inputs:
                        _check_inputs(scene, hand, dict(options), where, scenes_seen)
                    job = _make_job(method, scene, scene_key, seed, hand, hand_key, options)
                    jobs.setdefault(job.id, job)
    return Manifest(path=path, text=text, jobs=tuple(jobs.values()))


def _check_keys(table: dict, where: str) -> None:
    for key in table:
        if key in _TABLE_KEYS or key in OPTIONS:
            continue
        hint = "; list seeds as seeds = [0, 1]" if key == "seed" else \
            "; --threads and --device are options of `torchhand batch`" if key in ("threads", "device") else \
            f"; known: {', '.join(_TABLE_KEYS + tuple(OPTIONS))}"
        raise UnknownNameError(f"{where}: unknown key '{key}'{hint}")


def _check_method(method, where: str) -> None:
    if method in METHODS:
        return
    if method in FUTURE_METHODS:
        raise InputValueError(f"{where}: method '{method}' is not available in batch manifests yet "
                              f"({FUTURE_METHODS[method]}); available: {', '.join(METHODS)}")
    raise UnknownNameError(f"{where}: unknown method {method!r}; available: {', '.join(METHODS)}")


def _options(merged: dict, where: str) -> tuple[tuple[str, object], ...]:
    out = []
    for name, spec in OPTIONS.items():
        value = merged.get(name, spec.default)
        if name in merged:
            value = _option_value(name, spec, merged[name], where)
        out.append((name, value))
    return tuple(out)


def _option_value(name: str, spec: _Option, value, where: str):
    bad = lambda what: InputValueError(f"{where}: {name}: expected {what}, got {value!r}")  # noqa: E731
    if spec.kind == "bool":
        if not isinstance(value, bool):
            raise bad("true or false")
        return value
    if spec.kind in ("str", "frames"):
        if not isinstance(value, str):
            raise bad("a string")
        if spec.choices and value not in spec.choices:
            raise bad(f"one of {', '.join(spec.choices)}")
        if spec.kind == "frames":
            m = re.fullmatch(r"\s*(\d+)\s*:\s*(\d+)\s*", value)
            if not m or int(m[1]) >= int(m[2]):
                raise bad('"START:STOP" with integers 0 <= START < STOP')
            return f"{int(m[1])}:{int(m[2])}"
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (spec.kind == "int" and
                                                                           not isinstance(value, int)):
        raise bad("an integer" if spec.kind == "int" else "a number")
    value = int(value) if spec.kind == "int" else float(value)
    if spec.low is not None and (value <= spec.low if spec.strict else value < spec.low) or value != value:
        raise bad(f"a number {'>' if spec.strict else '>='} {spec.low:g}")
    return value


def _list(merged: dict, key: str, kind: type, where: str, default):
    value = merged.get(key, default)
    if value is None:
        raise InputValueError(f"{where}: no '{key}' (a list, here or in [defaults])")
    if not isinstance(value, list) or not value or not all(isinstance(v, kind) and not isinstance(v, bool)
                                                           for v in value):
        raise InputValueError(f"{where}: {key}: expected a non-empty list of "
                              f"{'integers' if kind is int else 'strings'}, got {value!r}")
    return value


def _scene(entry: str, base: Path, where: str, seen: dict) -> tuple[str, str]:
    """(scene argument, hashed key): a built-in name, or an absolute directory with its content hash."""
    candidate = (base / entry)
    if candidate.is_dir():
        d = str(candidate.resolve())
        if d not in seen:
            seen[d] = ("dir", _tree_hash(Path(d)))
        return d, f"sha256:{seen[d][1]}"
    if any(s in entry for s in ("/", "\\")) or entry in (".", ".."):
        raise MissingFileError(f"{where}: scenes: scene directory '{entry}' ({candidate}) does not exist")
    from ..scenes import list_builtin_scenes

    if entry not in list_builtin_scenes():
        raise UnknownNameError(f"{where}: scenes: '{entry}' is neither a built-in scene nor a directory beside the "
                               f"manifest; built-in scenes: {', '.join(list_builtin_scenes())}")
    return entry, f"builtin:{entry}"


def _hand(entry: str, base: Path, where: str) -> tuple[str, str]:
    """(``"default"`` or ``"SIDE=ABSPATH"``, hashed key)."""
    if entry == "default":
        return "default", "default"
    side, sep, rest = entry.partition("=")
    if sep and side in _SIDES:
        path_text = rest
    elif sep and "/" not in side:
        raise InputValueError(f"{where}: hands: '{entry}': expected \"default\", SIDE=PATH.xml with SIDE right or "
                              f"left, or a path")
    else:
        side, path_text = "right", entry
    path = (base / path_text)
    if not path.is_file():
        raise MissingFileError(f"{where}: hands: MJCF file '{path_text}' ({path.resolve()}) does not exist")
    from ..hand.mount import sidecar_path

    digest = hashlib.sha256(path.read_bytes())
    car = sidecar_path(path)
    if car.is_file():
        digest.update(b"\0sidecar\0" + car.read_bytes())
    return f"{side}={path.resolve()}", f"{side}:sha256:{digest.hexdigest()}"


def _tree_hash(directory: Path) -> str:
    """SHA-256 over the relative paths and bytes of every file under ``directory`` (hidden names skipped)."""
    h = hashlib.sha256()
    for p in sorted(directory.rglob("*")):
        rel = p.relative_to(directory)
        if p.is_file() and not any(part.startswith(".") for part in rel.parts):
            h.update(rel.as_posix().encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()


def _check_inputs(scene: str, hand: str, options: dict, where: str, seen: dict) -> None:
    """Load the scene (once) and the hand; frames within the scene; the hand's side in the scene."""
    from ..errors import TorchhandError
    from ..scene import load_scene

    key = ("loaded", scene)
    if key not in seen:
        try:
            sc = load_scene(scene)
        except TorchhandError as err:
            raise type(err)(f"{where}: scenes: {scene}: {err}") from None
        seen[key] = (sc.T, tuple(sc.sides), sc)
    T, sides, sc = seen[key]
    frames = options.get("frames")
    if frames is not None and int(frames.split(":")[1]) > T:
        raise InputValueError(f"{where}: frames: {frames!r} goes beyond scene {scene}'s {T} frames")
    if hand != "default":
        side, _, path = hand.partition("=")
        if side not in sides:
            raise InputValueError(f"{where}: hands: scene {scene} has no {side} hand (hands: {', '.join(sides)})")
        import dataclasses

        from ..hand.mount import track_hand

        track = next(t for t in sc.hands if t.side == side)
        try:
            track_hand(dataclasses.replace(track, model=path))
        except TorchhandError as err:
            raise type(err)(f"{where}: hands: {path}: {err}") from None


def _make_job(method, scene, scene_key, seed, hand, hand_key, options) -> Job:
    inputs = (("scene", scene_key), ("hand", hand_key))
    canonical = json.dumps({"method": method, "inputs": dict(inputs), "seed": seed, "options": dict(options)},
                           sort_keys=True, separators=(",", ":"))
    digest = hashlib.sha256(canonical.encode()).hexdigest()[:10]
    prefix = f"{_label(scene_key, scene)}_s{seed}_{_hand_label(hand)}"
    return Job(id=f"{prefix}_{digest}", method=method, scene=scene, seed=seed, hand=hand, options=options,
               inputs=inputs)


def _clean(text: str, limit: int = 32) -> str:
    return re.sub(r"[^A-Za-z0-9-]+", "-", text).strip("-")[:limit] or "x"


def _label(key: str, scene: str) -> str:
    return _clean(scene if key.startswith("builtin:") else Path(scene).name)


def _hand_label(hand: str) -> str:
    if hand == "default":
        return "default"
    side, _, path = hand.partition("=")
    p = Path(path)
    name = p.parent.name if p.stem in ("right_hand", "left_hand", "hand", "model") else p.stem
    return _clean(name) if side == "right" else f"{side}-{_clean(name)}"
