"""Expanding a validated ``[[jobs]]`` table into jobs (:mod:`torchhand.batch.manifest`): its lists as a product,
each input resolved (a built-in scene or a directory, a hand file and its sidecar, a grasp, an interaction) and
hashed, and each job's id (a readable prefix and 10 hex digits of what the job computes)."""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

from ..errors import InputValueError, MissingFileError, UnknownNameError
from ._job import Job
from ._schema import _SIDES, _list, _Table
from .inputs import check_capture, check_manipulate, check_synthesize


def _table_jobs(table: _Table, base: Path, where: str, seen: dict, check_inputs: bool):
    """The jobs of one table, in order (module docstring of :mod:`torchhand.batch.manifest`)."""
    expand = {"synthesize": _synthesize_jobs, "manipulate": _manipulate_jobs, "capture": _capture_jobs}[table.method]
    return expand(table.merged, table.options, base, where, seen, check_inputs)


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
        raise InputValueError(f"{where}: hands: '{entry}': expected \"default\", SIDE=PATH (.xml or .urdf) with SIDE right or "
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
