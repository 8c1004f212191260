"""Writing a scene directory (``docs/scene_format.md``): ``scene.toml`` + mesh + ``trajectories.npz``, atomically.

:func:`export_scene_dir` backs :meth:`torchhand.scene.Scene.export`.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from ..errors import InputValueError
from ._parts import FORMAT_VERSION, SIDES, HandTrack, MocapSource

if TYPE_CHECKING:  # pragma: no cover
    from ._model import Scene

__all__ = ["export_scene_dir"]

_SCENE_TOML = "scene.toml"
_MESH_FILE = "object.obj"
_TRAJ_FILE = "trajectories.npz"
_EXTERNAL = "external_wrench"   # the optional (T, 6) array in the trajectories npz and its [scene] flag


def export_scene_dir(scene: Scene, directory: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Write ``scene`` as a scene directory and return its path (see :meth:`torchhand.scene.Scene.export`)."""
    target = Path(directory)
    if target.exists() and not target.is_dir():
        raise InputValueError(f"directory: '{target}' exists and is not a directory")
    names = (_MESH_FILE, _TRAJ_FILE) + tuple(n for t in scene.hands if t.model != "default"
                                              for n in _hand_files(t)) + (_SCENE_TOML,)
    if not overwrite:
        clash = [n for n in names if (target / n).exists()]
        if clash:
            raise InputValueError(
                f"directory: '{target}' already holds {', '.join(clash)}; pass overwrite=True "
                "(CLI: --overwrite) to replace them"
            )
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.tmp-", dir=target.parent))
    except OSError as err:
        raise InputValueError(f"directory: cannot write a scene into '{target}': {err}") from err
    try:
        _write_files(scene, tmp)
        target.mkdir(exist_ok=True)
        for n in names:  # scene.toml last: a reader never sees it before the files it names
            os.replace(tmp / n, target / n)
    except OSError as err:
        raise InputValueError(f"directory: cannot write a scene into '{target}': {err}") from err
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return target


def _write_files(scene: Scene, out: Path) -> None:
    import tomli_w
    import trimesh

    mesh = scene.object.mesh
    text = trimesh.exchange.obj.export_obj(mesh, include_normals=False, include_color=False,
                                           include_texture=False, digits=12)
    (out / _MESH_FILE).write_text(text, encoding="utf-8")
    arrays = {"object_pose": scene.object_pose.detach().cpu().to(torch.float64).numpy()}
    for h in scene.hands:
        arrays[f"wrist_pose_{h.side}"] = h.wrist_pose.detach().cpu().to(torch.float64).numpy()
        if h.captured_wrist_pose is not None:
            arrays[f"captured_wrist_pose_{h.side}"] = h.captured_wrist_pose.detach().cpu().to(torch.float64).numpy()
    if scene.captured_object_pose is not None:
        arrays["captured_object_pose"] = scene.captured_object_pose.detach().cpu().to(torch.float64).numpy()
    if scene.external_wrench is not None:
        arrays[_EXTERNAL] = scene.external_wrench.detach().cpu().to(torch.float64).numpy()
    with open(out / _TRAJ_FILE, "wb") as f:
        np.savez(f, **arrays)
    doc = {
        "format_version": FORMAT_VERSION,
        "scene": {
            "name": scene.name,
            "description": scene.description,
            "fps": float(scene.fps),
            "friction": float(scene.friction),
            "gravity": [float(v) for v in scene.gravity.tolist()],
            "trajectories": _TRAJ_FILE,
        } | ({_EXTERNAL: True} if scene.external_wrench is not None else {}),
        "object": {"name": scene.object.name, "mesh": _MESH_FILE, "mass": float(scene.object.mass),
                   "scale": 1.0},
        "environment": _environment_doc(scene.environment),
    }
    if scene.source is not None:
        doc["source"] = _source_doc(scene.source)
    text = tomli_w.dumps(doc)
    for h in sorted(scene.hands, key=lambda h: SIDES.index(h.side)):  # written as [[hands]] tables
        entry = {"side": h.side, "length": float(h.length)}
        if h.model != "default":
            entry["model"] = _write_hand(h, out)
        if h.mount is not None:
            entry["mount"] = [float(v) for v in h.mount]
        if h.rest is not None:
            entry["rest"] = h.rest
        text += "\n[[hands]]\n" + tomli_w.dumps(entry)
    (out / _SCENE_TOML).write_text(text, encoding="utf-8")


def _hand_files(track: HandTrack) -> tuple[str, ...]:
    """Files a scene directory holds for an MJCF hand: the model (meshes inline) and its sidecar, if any."""
    from ..hand.mount import sidecar_path

    xml = f"hand_{track.side}.xml"
    return (xml, sidecar_path(xml).name) if sidecar_path(track.model).is_file() else (xml,)


def _write_hand(track: HandTrack, out: Path) -> str:
    """Write an MJCF hand into the scene directory, self-contained (meshes inline), with its sidecar."""
    from ..hand.mjcf import load_mjcf, save_mjcf
    from ..hand.mount import sidecar_path

    files = _hand_files(track)
    save_mjcf(load_mjcf(track.model, side=track.side), out / files[0])
    if len(files) > 1:
        shutil.copyfile(sidecar_path(track.model), out / files[1])
    return files[0]


def _source_doc(src: MocapSource) -> dict:
    rot = dict(src.hand_rotation)
    return {"kind": src.kind, "fps": float(src.fps), "frames": int(src.frames),
            "first_frame": float(src.first_frame), "units_scale": float(src.units_scale), "up_axis": src.up_axis,
            "handedness": src.handedness,
            "wrists": [{"side": side, "file": file, "joint": joint}
                       | ({"rotation": [list(r) for r in rot[side]]} if side in rot else {})
                       for side, file, joint in src.wrists]}


def _environment_doc(env) -> dict:
    """The [environment] table; the table edge and the floor only when the scene has them (older readers and
    older files stay as they were)."""
    doc = {"table": bool(env.table), "table_height": float(env.table_height), "friction": float(env.friction)}
    if env.table_extent is not None:
        doc["table_extent"] = [float(v) for v in env.table_extent]
    if env.floor:
        doc["floor"] = True
        doc["floor_height"] = float(env.floor_height)
    return doc
