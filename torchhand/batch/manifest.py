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
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path

from ..errors import FileFormatError, InputTypeError, InputValueError, MissingFileError, UnknownNameError
from .inputs import check_capture, check_manipulate, check_synthesize

__all__ = ["METHODS", "FUTURE_METHODS", "OPTIONS", "MANIPULATE_OPTIONS", "CAPTURE_OPTIONS", "METHOD_OPTIONS",
           "METHOD_LISTS", "Job", "Manifest", "load_manifest", "parse_manifest"]

METHODS = ("synthesize", "manipulate", "capture")
"""Methods a batch runs (``capture`` is ``torchhand capture resynthesize``)."""

FUTURE_METHODS = {
    "splice": "run `torchhand splice --body B --hand H --out DIR` for each pair",
}
"""Methods of torchhand that batch manifests do not run, with what to do instead."""


@dataclass(frozen=True)
class _Option:
    flag: str                 # the command's flag
    kind: str                 # "int", "float", "floats" (a list, passed comma-separated), "str", "bool", "frames"
    default: object           # the flag's default (None: the flag is left out)
    low: float | None = None  # least value (ints and floats)
    strict: bool = False      # value must exceed ``low``
    choices: tuple = ()
    high: float | None = None  # greatest value (inclusive)


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

MANIPULATE_OPTIONS = {
    "window": _Option("--window", "int", 6, 1),
    "max_force": _Option("--max-force", "float", 30.0, 0, strict=True),
    "frames": _Option("--frames", "frames", None),
    "no_objective": _Option("--no-objective", "bool", False),
}
"""Options of a ``manipulate`` job (``torchhand manipulate``'s flags and defaults; a test holds them together)."""

CAPTURE_OPTIONS = {
    "dt": _Option("--dt", "float", None, 0, strict=True),
    "mass": _Option("--mass", "floats", None, 0, strict=True),
    "compliance_scale": _Option("--compliance-scale", "floats", (1.0,), 0, strict=True),
    "friction": _Option("--friction", "floats", None, 0),
    "grip": _Option("--grip", "str", "none", choices=("none", "delayed", "imminent")),
    "slip_ratio": _Option("--slip-ratio", "float", 0.9, 0, strict=True),
    "min_force": _Option("--min-force", "float", 0.2, 0),
    "tighten": _Option("--tighten", "float", 0.95, 0, strict=True, high=1.0),
    "grip_floor": _Option("--grip-floor", "float", 0.2, 0, strict=True, high=1.0),
    "grip_delay": _Option("--grip-delay", "float", 0.1, 0),
    "pyramid_m": _Option("--pyramid-m", "int", 4, 1),
    "solver": _Option("--solver", "str", None, choices=("lemke", "pgs", "auto")),
    "settle_steps": _Option("--settle-steps", "int", 0, 0),
    "dtype": _Option("--dtype", "str", "float64", choices=("float64", "float32")),
    "object_contacts": _Option("--object-contacts", "str", "mesh", choices=("mesh", "sdf")),
    "sdf_voxel": _Option("--sdf-voxel", "float", 0.001, 0, strict=True),
}
"""Options of a ``capture`` job (``torchhand capture resynthesize``'s flags and defaults; a test holds them
together). ``mass``, ``compliance_scale`` and ``friction`` are lists (one rollout per combination) or one number."""

METHOD_OPTIONS = {"synthesize": OPTIONS, "manipulate": MANIPULATE_OPTIONS, "capture": CAPTURE_OPTIONS}
"""Method -> its options."""

METHOD_LISTS = {"synthesize": ("scenes", "seeds", "hands"), "manipulate": ("scenes", "grasps"),
                "capture": ("interactions", "scenes")}
"""Method -> the lists its jobs expand (as a product, in this order)."""

_NOT_FOR = {"seeds": "its result does not depend on a seed",
            "hands": {"manipulate": "the hand is the grasp's", "capture": "the hand is the scene's"},
            "grasps": "only manipulate jobs have grasps", "interactions": "only capture jobs have interactions"}
_ALL_KEYS = ("method",) + tuple(dict.fromkeys(k for m in METHODS for k in METHOD_LISTS[m] + tuple(METHOD_OPTIONS[m])))
_SIDES = ("right", "left")


@dataclass(frozen=True)
class Job:
    """One run of a batch: one method on one scene (with one seed and hand, one grasp, or one interaction) and
    fixed options.

    id: ``<prefix>_<hash10>`` (module docstring), the name of its result directory ``DIR/jobs/<id>/``
    method: ``"synthesize"``, ``"manipulate"`` or ``"capture"`` (``torchhand capture resynthesize``)
    scene: a built-in scene name, or the absolute path of a scene directory
    seed: the random seed (synthesize), else None
    hand: ``"default"`` (the scene's own hands) or ``"SIDE=ABSOLUTE_PATH.xml"`` (synthesize); ``"grasp"`` (manipulate:
        the grasp's hand); ``"default"`` (capture: the scene's hand)
    options: (name, value) pairs in the method's option order (:data:`METHOD_OPTIONS`), every option with its
        default filled in; list options (``mass``, ...) as tuples
    inputs: what was hashed for the scene, the hand, the grasp, the interaction (built-in name or SHA-256 of the
        content)
    grasp: manipulate: the absolute path of the grasp file; ``default_grasp``: it is the scene's own (the command
        then finds it itself, ``--grasp`` is left out); else ""
    interaction: capture: the absolute path of the interaction file; else ""
    """

    id: str
    method: str
    scene: str
    seed: int | None
    hand: str
    options: tuple[tuple[str, object], ...]
    inputs: tuple[tuple[str, str], ...]
    grasp: str = ""
    default_grasp: bool = False
    interaction: str = ""

    def argv(self) -> list[str]:
        """The ``torchhand`` command line of the job, without ``--out``, ``--threads``, ``--device`` and
        ``--no-progress`` (the worker adds those its method has). Every option is passed explicitly."""
        if self.method == "manipulate":
            args = ["manipulate", self.scene] + ([] if self.default_grasp else ["--grasp", self.grasp])
        elif self.method == "capture":
            args = ["capture", "resynthesize", self.interaction, "--scene", self.scene]
        else:
            args = [self.method, self.scene, "--seed", str(self.seed)]
        specs = METHOD_OPTIONS[self.method]
        for name, value in self.options:
            spec = specs[name]
            if spec.kind == "bool":
                args += [spec.flag] if value else []
            elif spec.kind == "floats" and value is not None:
                args += [spec.flag, ",".join(str(v) for v in value)]
            elif value is not None:
                args += [spec.flag, str(value)]
        if self.method == "synthesize" and self.hand != "default":
            args += ["--hand", self.hand]
        return args

    def to_dict(self) -> dict:
        out = {"id": self.id, "method": self.method, "scene": self.scene, "seed": self.seed, "hand": self.hand,
               "options": {k: list(v) if isinstance(v, tuple) else v for k, v in self.options},
               "inputs": dict(self.inputs), "argv": self.argv()}
        if self.method == "manipulate":
            out["grasp"] = self.grasp
        if self.method == "capture":
            out["interaction"] = self.interaction
        return out


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
    seen: dict = {}
    jobs: dict[str, Job] = {}
    used: list[str] = []
    for i, table in enumerate(tables, 1):
        where = f"[[jobs]] #{i}"
        method = table.get("method", defaults.get("method", "synthesize"))
        _check_method(method, where)
        used.append(method)
        _check_keys(table, where, method)
        merged = {k: v for k, v in defaults.items() if k == "method" or k in METHOD_LISTS[method]
                  or k in METHOD_OPTIONS[method]}
        merged.update(table)
        options = _options(merged, METHOD_OPTIONS[method], where)
        expand = {"synthesize": _synthesize_jobs, "manipulate": _manipulate_jobs, "capture": _capture_jobs}[method]
        for job in expand(merged, options, path.parent, where, seen, check_inputs):
            jobs.setdefault(job.id, job)
    for key in defaults:                       # a default no table takes is a mistake (a typo'd method, ...)
        if key != "method" and not any(key in METHOD_LISTS[m] or key in METHOD_OPTIONS[m] for m in used):
            raise InputValueError(f"[defaults]: key '{key}' applies to no [[jobs]] table of this manifest (methods: "
                                  f"{', '.join(dict.fromkeys(used))})")
    return Manifest(path=path, text=text, jobs=tuple(jobs.values()))


def _synthesize_jobs(merged, options, base, where, seen, check_inputs):
    scenes = _list(merged, "scenes", str, where, None)
    seeds = _list(merged, "seeds", int, where, [0])
    hands = _list(merged, "hands", str, where, ["default"])
    for scene_entry in scenes:
        scene, scene_key = _scene(scene_entry, base, where, seen)
        for seed in seeds:
            for hand_entry in hands:
                hand, hand_key = _hand(hand_entry, base, where)
                if check_inputs:
                    check_synthesize(scene, hand, dict(options), where, seen)
                yield _make_job("synthesize", scene, scene_key, seed, hand, hand_key, options)


def _manipulate_jobs(merged, options, base, where, seen, check_inputs):
    scenes = _list(merged, "scenes", str, where, None)
    grasps = _list(merged, "grasps", str, where, ["default"])
    for scene_entry in scenes:
        scene, scene_key = _scene(scene_entry, base, where, seen)
        for grasp_entry in grasps:
            grasp, default = _grasp(grasp_entry, scene, scene_key, base, where)
            grasp_key = f"sha256:{_file_hash(Path(grasp), seen)}"
            if check_inputs:
                check_manipulate(scene, grasp, dict(options), where, seen)
            inputs = (("scene", scene_key), ("grasp", grasp_key))
            label = "grasp" if default else _file_label(grasp)
            digest = _digest("manipulate", inputs, None, options)
            yield Job(id=f"{_label(scene_key, scene)}_{label}_{digest}", method="manipulate", scene=scene, seed=None,
                      hand="grasp", options=options, inputs=inputs, grasp=grasp, default_grasp=default)


def _capture_jobs(merged, options, base, where, seen, check_inputs):
    interactions = _list(merged, "interactions", str, where, None)
    scenes = _list(merged, "scenes", str, where, None)
    for entry in interactions:
        path = base / entry
        if not path.is_file():
            raise MissingFileError(f"{where}: interactions: interaction file '{entry}' ({path.resolve()}) does not "
                                   f"exist")
        inter = str(path.resolve())
        inter_key = f"sha256:{_file_hash(Path(inter), seen)}"
        for scene_entry in scenes:
            scene, scene_key = _scene(scene_entry, base, where, seen)
            if check_inputs:
                check_capture(scene, inter, dict(options), where, seen)
            inputs = (("scene", scene_key), ("interaction", inter_key))
            digest = _digest("capture", inputs, None, options)
            yield Job(id=f"{_label(scene_key, scene)}_{_file_label(inter)}_{digest}", method="capture", scene=scene,
                      seed=None, hand="default", options=options, inputs=inputs, interaction=inter)


def _check_keys(table: dict, where: str, method: str | None) -> None:
    """Every key known; in a [[jobs]] table (``method`` given), every key one of that method's."""
    for key in table:
        if method is not None and key in METHOD_LISTS[method] + ("method",) + tuple(METHOD_OPTIONS[method]):
            continue
        if method is None and key in _ALL_KEYS:
            continue
        if key in _ALL_KEYS:
            why = _NOT_FOR.get(key, "")
            why = why.get(method, "") if isinstance(why, dict) else why
            owners = [m for m in METHODS if key in METHOD_LISTS[m] or key in METHOD_OPTIONS[m]]
            raise InputValueError(f"{where}: key '{key}' does not apply to method '{method}'"
                                  f"{f' ({why})' if why else ''}; it is a key of {', '.join(owners)}; keys of "
                                  f"{method}: {', '.join(METHOD_LISTS[method] + tuple(METHOD_OPTIONS[method]))}")
        known = (METHOD_LISTS[method] + tuple(METHOD_OPTIONS[method])) if method else _ALL_KEYS[1:]
        hint = "; list seeds as seeds = [0, 1]" if key == "seed" else \
            "; list grasps as grasps = [\"g.npz\"]" if key == "grasp" else \
            "; list interactions as interactions = [\"interaction.npz\"]" if key == "interaction" else \
            "; --threads and --device are options of `torchhand batch`" if key in ("threads", "device") else \
            f"; known: method, {', '.join(known)}"
        raise UnknownNameError(f"{where}: unknown key '{key}'{hint}")


def _check_method(method, where: str) -> None:
    if method in METHODS:
        return
    if method in FUTURE_METHODS:
        raise InputValueError(f"{where}: method '{method}' is not available in batch manifests "
                              f"({FUTURE_METHODS[method]}); available: {', '.join(METHODS)}")
    raise UnknownNameError(f"{where}: unknown method {method!r}; available: {', '.join(METHODS)}")


def _options(merged: dict, specs: dict, where: str) -> tuple[tuple[str, object], ...]:
    out = []
    for name, spec in specs.items():
        value = spec.default
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
    if spec.kind == "floats":
        values = value if isinstance(value, list) else [value]
        if not values:
            raise bad("a number or a non-empty list of numbers")
        return tuple(_number(name, dataclasses.replace(spec, kind="float"), v, where, "a number or a list of "
                                                                                            "numbers") for v in values)
    return _number(name, spec, value, where)


def _number(name: str, spec: _Option, value, where: str, what: str | None = None):
    bad = lambda text: InputValueError(f"{where}: {name}: expected {text}, got {value!r}")  # noqa: E731
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (spec.kind == "int" and
                                                                           not isinstance(value, int)):
        raise bad(what or ("an integer" if spec.kind == "int" else "a number"))
    value = int(value) if spec.kind == "int" else float(value)
    if value != value or spec.low is not None and (value <= spec.low if spec.strict else value < spec.low) or \
            spec.high is not None and value > spec.high:
        lo = f"{'>' if spec.strict else '>='} {spec.low:g}" if spec.low is not None else ""
        raise bad(f"a number {lo}" + (f" and <= {spec.high:g}" if spec.high is not None else ""))
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
    from ..scene.builtin import list_builtin_scenes

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


def _grasp(entry: str, scene: str, scene_key: str, base: Path, where: str) -> tuple[str, bool]:
    """(absolute grasp path, whether it is the scene's own): ``"default"`` is a built-in scene's packaged grasp
    (``torchhand.scene.builtin.liu.grasp_path``) or ``grasp.npz`` in a scene directory."""
    if entry == "default":
        if scene_key.startswith("builtin:"):
            from ..scene.builtin.liu import grasp_path

            found = grasp_path(scene)
            if found is None:
                raise InputValueError(f"{where}: grasps: the built-in scene '{scene}' has no packaged grasp; list "
                                      f"grasp files as grasps = [\"grasp.npz\"] (make one with `torchhand grasp`)")
            return str(Path(found).resolve()), True
        path = Path(scene) / "grasp.npz"
        if not path.is_file():
            raise MissingFileError(f"{where}: grasps: scene directory {scene} has no grasp.npz; list grasp files as "
                                   f"grasps = [\"grasp.npz\"]")
        return str(path), True
    path = base / entry
    if not path.is_file():
        raise MissingFileError(f"{where}: grasps: grasp file '{entry}' ({path.resolve()}) does not exist")
    return str(path.resolve()), False


def _file_hash(path: Path, seen: dict) -> str:
    key = ("file", str(path))
    if key not in seen:
        seen[key] = hashlib.sha256(path.read_bytes()).hexdigest()
    return seen[key]


def _digest(method: str, inputs, seed, options) -> str:
    """10 hex digits of the SHA-256 of what a job computes (module docstring)."""
    doc = {"method": method, "inputs": dict(inputs),
           "options": {k: list(v) if isinstance(v, tuple) else v for k, v in options}}
    if method == "synthesize":
        doc["seed"] = seed
    canonical = json.dumps(doc, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(canonical.encode()).hexdigest()[:10]


def _make_job(method, scene, scene_key, seed, hand, hand_key, options) -> Job:
    inputs = (("scene", scene_key), ("hand", hand_key))
    prefix = f"{_label(scene_key, scene)}_s{seed}_{_hand_label(hand)}"
    return Job(id=f"{prefix}_{_digest(method, inputs, seed, options)}", method=method, scene=scene, seed=seed,
               hand=hand, options=options, inputs=inputs)


def _file_label(path: str) -> str:
    """A grasp's or an interaction's name in an id: its stem, or its folder's name for a generic stem."""
    p = Path(path)
    return _clean(p.parent.name if p.stem in ("grasp", "interaction") and p.parent.name else p.stem)


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
