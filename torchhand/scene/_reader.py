"""Reading a scene directory (``docs/scene_format.md``): ``scene.toml`` + mesh + ``trajectories.npz``, validated.

:func:`load_scene_dir` backs :func:`torchhand.scene.load_scene` for paths. Conventions (see
:mod:`torchhand.conventions`): world z-up, metres, seconds, kilograms; poses are 4x4 rigid transforms
``T_world_frame``, float64.
"""

from __future__ import annotations

import math
import tomllib
import zipfile
from pathlib import Path

import numpy as np
import torch

from ..conventions import check_transforms
from ..errors import FileFormatError, InputValueError, MissingFileError, ShapeError, TorchhandError
from ..geometry.objects import load_object
from ._model import Scene
from ._parts import DEFAULT_GRAVITY, SIDES, Environment, HandTrack, MocapSource
from ._writer import _EXTERNAL, _SCENE_TOML, _TRAJ_FILE

__all__ = ["load_scene_dir"]


_SCHEMA = {
    "": {"format_version", "scene", "object", "environment", "hands", "source"},
    "scene": {"name", "description", "fps", "friction", "gravity", "trajectories", "external_wrench"},
    "object": {"name", "mesh", "mass", "density", "scale", "repair"},
    "environment": {"table", "table_height", "friction", "table_extent", "floor", "floor_height"},
    "hands": {"side", "length", "model", "mount", "rest"},
    "source": {"kind", "fps", "frames", "first_frame", "units_scale", "up_axis", "handedness", "wrists"},
    "source.wrists": {"side", "file", "joint", "rotation"},
}

READ_VERSIONS = (1, 2)
"""Scene format versions this reader accepts (version 1 has no ``[source]`` table)."""


class _Reader:
    """Typed access to a parsed scene.toml with errors that name the file and the field."""

    def __init__(self, path: Path, doc: dict):
        self.path, self.doc = path, doc

    def table(self, key: str, required: bool = True) -> dict:
        if key not in self.doc:
            if required:
                raise FileFormatError(f"{self.path}: missing table [{key}]")
            return {}
        t = self.doc[key]
        if not isinstance(t, dict):
            raise FileFormatError(f"{self.path}: '{key}' must be a table [{key}], got {type(t).__name__}")
        self.unknown(t, key)
        return t

    def unknown(self, t: dict, section: str) -> None:
        extra = sorted(set(t) - _SCHEMA[section])
        if extra:
            where = f"[{section}]" if section else "top level"
            raise FileFormatError(f"{self.path}: unknown key(s) {', '.join(extra)} in {where}; "
                                  f"allowed: {', '.join(sorted(_SCHEMA[section]))}")

    def get(self, t: dict, section: str, key: str, kind: str, default=...):
        field_name = f"{section}.{key}" if section else key
        if key not in t:
            if default is ...:
                raise FileFormatError(f"{self.path}: missing field {field_name}")
            return default
        v = t[key]
        ok = {
            "number": isinstance(v, (int, float)) and not isinstance(v, bool),
            "int": isinstance(v, int) and not isinstance(v, bool),
            "str": isinstance(v, str),
            "bool": isinstance(v, bool),
            "vec3": isinstance(v, list) and len(v) == 3
            and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v),
        }[kind]
        if not ok:
            expected = {"vec3": "a list of 3 numbers", "int": "an integer", "number": "a number",
                        "str": "a string", "bool": "true or false"}[kind]
            raise FileFormatError(f"{self.path}: field {field_name}: expected {expected}, got {v!r}")
        if kind == "number" and not math.isfinite(float(v)):
            raise InputValueError(f"{self.path}: field {field_name}: expected a finite number, got {v}")
        return v

    def positive(self, t, section, key, default=..., strict=True):
        v = self.get(t, section, key, "number", default)
        if v is None:
            return None
        if (v <= 0) if strict else (v < 0):
            raise InputValueError(f"{self.path}: field {section}.{key}: expected a number "
                                  f"{'>' if strict else '>='} 0, got {v}")
        return float(v)


def load_scene_dir(directory: Path) -> Scene:
    """Read and validate the scene directory ``directory`` (see :func:`torchhand.scene.load_scene`)."""
    toml_path = directory / _SCENE_TOML
    if not toml_path.is_file():
        raise MissingFileError(f"name_or_dir: '{directory}' has no {_SCENE_TOML}")
    try:
        doc = tomllib.loads(toml_path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as err:
        raise FileFormatError(f"{toml_path}: malformed TOML: {err}") from None
    except (OSError, UnicodeDecodeError) as err:
        raise FileFormatError(f"{toml_path}: cannot read: {err}") from None
    r = _Reader(toml_path, doc)
    r.unknown(doc, "")
    version = r.get(doc, "", "format_version", "int")
    if version not in READ_VERSIONS:
        raise FileFormatError(f"{toml_path}: format_version {version} is not supported (this reader: "
                              f"{', '.join(map(str, READ_VERSIONS))}; a newer file needs a newer torchhand)")
    sc, ob, env = r.table("scene"), r.table("object"), r.table("environment", required=False)

    fps = r.positive(sc, "scene", "fps")
    friction = r.positive(sc, "scene", "friction", strict=False)
    gravity = r.get(sc, "scene", "gravity", "vec3", list(DEFAULT_GRAVITY))
    name = r.get(sc, "scene", "name", "str", directory.resolve().name)
    description = r.get(sc, "scene", "description", "str", "")
    traj_name = r.get(sc, "scene", "trajectories", "str", _TRAJ_FILE)
    external_flag = r.get(sc, "scene", _EXTERNAL, "bool", None)

    mesh_name = r.get(ob, "object", "mesh", "str")
    mass = r.positive(ob, "object", "mass", None)
    density = r.positive(ob, "object", "density", None)
    if mass is not None and density is not None:
        raise FileFormatError(f"{toml_path}: give at most one of object.mass and object.density")
    scale = r.positive(ob, "object", "scale", 1.0)
    repair = r.get(ob, "object", "repair", "bool", False)
    obj_name = r.get(ob, "object", "name", "str", Path(mesh_name).stem)

    extent = env.get("table_extent")
    if extent is not None and not (isinstance(extent, list) and len(extent) == 4 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in extent)):
        raise FileFormatError(f"{toml_path}: field environment.table_extent: expected [x_min, x_max, y_min, y_max], "
                              f"got {extent!r}")
    fields = dict(table=r.get(env, "environment", "table", "bool", False),
                  table_height=float(r.get(env, "environment", "table_height", "number", 0.0)),
                  friction=r.positive(env, "environment", "friction", 0.5, strict=False),
                  table_extent=None if extent is None else tuple(float(v) for v in extent),
                  floor=r.get(env, "environment", "floor", "bool", False),
                  floor_height=float(r.get(env, "environment", "floor_height", "number", 0.0)))
    try:
        environment = Environment(**fields)
    except InputValueError as e:
        raise FileFormatError(f"{toml_path}: [environment]: {e}") from None

    hands_doc = doc.get("hands")
    if not isinstance(hands_doc, list) or not 1 <= len(hands_doc) <= 2:
        raise FileFormatError(f"{toml_path}: expected 1 or 2 [[hands]] tables, got "
                              f"{len(hands_doc) if isinstance(hands_doc, list) else repr(hands_doc)}")
    hand_specs = [_hand_entry(r, toml_path, directory, i, hd) for i, hd in enumerate(hands_doc)]
    if len({h[0] for h in hand_specs}) != len(hand_specs):
        raise InputValueError(f"{toml_path}: [[hands]] sides must be distinct, got {[h[0] for h in hand_specs]}")

    mesh_path = directory / mesh_name
    if not mesh_path.is_file():
        raise MissingFileError(f"{toml_path}: object.mesh '{mesh_path}' does not exist")
    traj_path = directory / traj_name
    arrays, external = _read_trajectories(traj_path, ["object_pose"] + [f"wrist_pose_{h[0]}" for h in hand_specs],
                                          external_flag)
    T = arrays["object_pose"].shape[0]
    if external is not None and external.shape[0] != T:
        raise ShapeError(f"{traj_path}: {_EXTERNAL}: expected T = {T} frames (as object_pose), got {external.shape[0]}")
    for key, a in arrays.items():
        if a.shape[0] != T:
            raise ShapeError(f"{traj_path}: {key}: expected T = {T} frames (as object_pose), got {a.shape[0]}")
        check_transforms(a, f"{traj_path}: {key}")

    obj = load_object(mesh_path, mass=mass, density=density, scale=scale, name=obj_name, repair=repair)
    captured = _read_optional_poses(traj_path, [f"captured_wrist_pose_{h[0]}" for h in hand_specs]
                                    + ["captured_object_pose"], T)
    hands = tuple(HandTrack(side=s, wrist_pose=arrays[f"wrist_pose_{s}"], length=length, model=model,
                            mount=None if mount is None else tuple(mount), rest=rest,
                            captured_wrist_pose=captured.get(f"captured_wrist_pose_{s}"))
                  for s, length, model, mount, rest in hand_specs)
    try:
        source = _read_source(r, doc) if "source" in doc else None
        scene = Scene(name=name, object=obj, object_pose=arrays["object_pose"], fps=fps, hands=hands,
                      friction=friction, environment=environment,
                      gravity=torch.tensor([float(g) for g in gravity], dtype=torch.float64),
                      description=description, source=source, external_wrench=external,
                      captured_object_pose=captured.get("captured_object_pose"))
        return scene.validate()
    except TorchhandError as err:  # name the file for errors found by the dataclass checks
        raise type(err)(f"{toml_path}: {err}") from None


def _read_source(r: _Reader, doc: dict) -> MocapSource:
    src = r.table("source")
    wrists_doc = src.get("wrists")
    if not isinstance(wrists_doc, list) or not wrists_doc or not all(isinstance(w, dict) for w in wrists_doc):
        raise FileFormatError(f"{r.path}: [source] needs one or more [[source.wrists]] tables")
    wrists, rotations = [], []
    for i, w in enumerate(wrists_doc):
        r.unknown(w, "source.wrists")
        where = f"source.wrists[{i}]"
        side = r.get(w, where, "side", "str")
        wrists.append((side, r.get(w, where, "file", "str"), r.get(w, where, "joint", "str")))
        if "rotation" in w:
            R = np.asarray(w["rotation"], dtype=np.float64) if isinstance(w["rotation"], list) else None
            if R is None or R.shape != (3, 3) or not np.isfinite(R).all():
                raise FileFormatError(f"{r.path}: field {where}.rotation: expected 3 rows of 3 numbers")
            rotations.append((side, R))
    return MocapSource(kind=r.get(src, "source", "kind", "str"), wrists=tuple(wrists),
                       fps=r.positive(src, "source", "fps"), frames=r.get(src, "source", "frames", "int"),
                       first_frame=float(r.get(src, "source", "first_frame", "number", 0.0)),
                       units_scale=r.positive(src, "source", "units_scale", 1.0),
                       up_axis=r.get(src, "source", "up_axis", "str", "y"),
                       handedness=r.get(src, "source", "handedness", "str", "right"),
                       hand_rotation=tuple(rotations))


def _read_optional_poses(path: Path, keys: list[str], T: int) -> dict[str, torch.Tensor]:
    """The pose arrays among ``keys`` that the trajectory file holds ((T, 4, 4) each, checked), float64 tensors."""
    with np.load(path, allow_pickle=False) as data:
        raw = {k: data[k] for k in keys if k in data.files}
    out = {}
    for k, a in raw.items():
        if a.dtype.kind not in "fiu" or a.shape != (T, 4, 4):
            raise ShapeError(f"{path}: {k}: expected a numeric array of shape ({T}, 4, 4), got {a.dtype} {a.shape}")
        out[k] = torch.tensor(a, dtype=torch.float64)
        check_transforms(out[k], f"{path}: {k}")
    return out


def _read_trajectories(path: Path, keys: list[str], external_flag: bool | None = None
                       ) -> tuple[dict[str, torch.Tensor], torch.Tensor | None]:
    """The pose arrays ``keys`` ((T, 4, 4) each) and the optional external wrench (T, 6), float64 tensors.
    ``external_flag``: ``[scene] external_wrench`` (True: the array is required; False: it is ignored; None: read
    when present)."""
    if not path.is_file():
        raise MissingFileError(f"scene.trajectories: '{path}' does not exist")
    try:
        with np.load(path, allow_pickle=False) as data:
            present = set(data.files)
            missing = [k for k in keys if k not in present]
            if external_flag is True and _EXTERNAL not in present:
                missing.append(_EXTERNAL)
            if missing:
                raise FileFormatError(
                    f"{path}: missing array(s) {', '.join(missing)}; has {', '.join(sorted(present))}"
                )
            raw = {k: data[k] for k in keys}
            ext = data[_EXTERNAL] if external_flag is not False and _EXTERNAL in present else None
    except TorchhandError:
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as err:
        raise FileFormatError(f"{path}: cannot read npz: {type(err).__name__}: {err}") from None
    out = {}
    for k, a in raw.items():
        if a.dtype.kind not in "fiu":
            raise FileFormatError(f"{path}: {k}: expected a numeric array, got dtype {a.dtype}")
        if a.ndim != 3 or a.shape[1:] != (4, 4) or a.shape[0] < 1:
            raise ShapeError(f"{path}: {k}: expected shape (T, 4, 4), got {a.shape}")
        out[k] = torch.tensor(a, dtype=torch.float64)
    if ext is None:
        return out, None
    if ext.dtype.kind not in "fiu":
        raise FileFormatError(f"{path}: {_EXTERNAL}: expected a numeric array, got dtype {ext.dtype}")
    if ext.ndim != 2 or ext.shape[1] != 6:
        raise ShapeError(f"{path}: {_EXTERNAL}: expected shape (T, 6) (force N, torque N m about the centre of mass, "
                         f"world), got {ext.shape}")
    if not np.isfinite(ext).all():
        t = int(np.flatnonzero(~np.isfinite(ext).all(1))[0])
        raise InputValueError(f"{path}: {_EXTERNAL}: expected finite values, frame {t} has {ext[t].tolist()}")
    return out, torch.tensor(ext, dtype=torch.float64)


def _hand_entry(r, toml_path, directory, i: int, hd) -> tuple:
    """(side, length, model path or "default", mount or None, rest or None) of ``[[hands]]`` entry ``i``."""
    if not isinstance(hd, dict):
        raise FileFormatError(f"{toml_path}: hands[{i}] must be a table")
    r.unknown(hd, "hands")
    side = r.get(hd, f"hands[{i}]", "side", "str")
    if side not in SIDES:
        raise InputValueError(f"{toml_path}: field hands[{i}].side: expected 'right' or 'left', got {side!r}")
    model = r.get(hd, f"hands[{i}]", "model", "str", "default")
    if model != "default":
        mpath = (directory / model).resolve()
        if not mpath.is_file():
            raise MissingFileError(f"{toml_path}: hands[{i}].model '{mpath}' does not exist (an MJCF or URDF "
                                   "hand file, relative to the scene directory, or \"default\")")
        model = str(mpath)
    mount = hd.get("mount")
    if mount is not None and not (isinstance(mount, list) and len(mount) == 6 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in mount)):
        raise FileFormatError(f"{toml_path}: field hands[{i}].mount: expected 6 finite numbers (shift metres, "
                              f"rotation vector degrees), got {mount!r}")
    rest = r.get(hd, f"hands[{i}]", "rest", "str", None)
    if rest not in (None, "zero", "relaxed"):
        raise FileFormatError(f"{toml_path}: field hands[{i}].rest: expected \"zero\" or \"relaxed\", got {rest!r}")
    return side, r.positive(hd, f"hands[{i}]", "length", 0.19), model, mount, rest
