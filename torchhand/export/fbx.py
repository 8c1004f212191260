"""FBX through Blender: torchhand computes the scene, Blender's own FBX exporter writes the file.

Blender as a Python module (``bpy``) needs NumPy 1.x, so nothing of torchhand runs inside Blender. This module
computes everything on torchhand's side and writes it as one JSON job (:meth:`FbxScene.to_json`); the
Blender-side script :mod:`torchhand.export._blender_fbx` (standard library, ``bpy`` and ``mathutils`` only) reads
it, builds the armatures, their animation and the meshes, and calls ``bpy.ops.export_scene.fbx``.

The job (``"format": "torchhand-fbx"``, ``"version": 1``), world z-up, metres, seconds:

    ``fps``, ``frames``     frame rate and frame count T; frame t is keyed at Blender frame t (FBX time t / fps)
    ``armatures``           per armature: ``name``, ``bones`` (J names, parents first), ``parents`` (J ints, -1 for
                            a root), ``rest`` (J bone rest matrices, 16 floats row-major: head at the frame's rest
                            origin, bone Y axis along the bone), ``length`` (J metres), ``pose`` (T x J bone
                            matrices, world)
    ``meshes``              per mesh: ``name``, ``vertices`` (V x 3, its own frame), ``faces`` (F x 3), ``pose``
                            (T matrices ``T_world_mesh``)

A bone's matrix is its frame's pose times a fixed rest offset, ``B_j(t) = F_j(t) O_j`` with ``O_j`` a rotation
(:func:`armature_spec`): bone heads are the frames' origins in every frame.

Where Blender runs (:func:`find_blender`): ``$TORCHHAND_BLENDER`` (a ``blender`` executable, or a Python interpreter
with ``bpy`` when its name contains ``python``), else ``bpy`` in this interpreter, else ``blender`` on ``PATH``.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..errors import InputValueError, MissingDependencyError, ShapeError, TorchhandError
from .skeleton import hand_skeleton

__all__ = ["FbxArmature", "FbxMesh", "FbxScene", "BlenderRunner", "BlenderError", "INSTALL_HINT", "SCRIPT",
           "armature_spec", "frame_rate", "solution_fbx_scene", "body_fbx_scene", "find_blender", "write_fbx"]

SCRIPT = Path(__file__).with_name("_blender_fbx.py")
"""The Blender-side script (run by Blender, or imported when ``bpy`` imports here)."""

INSTALL_HINT = ("install Blender as a Python module with pip install 'torchhand[blender]' (bpy 4.5, brings NumPy "
                "1.26; Python 3.11 only) or set TORCHHAND_BLENDER to a Blender executable")
_ENV = "TORCHHAND_BLENDER"
_MIN_LENGTH = 0.002  # metres: the shortest bone
_EPS = 1e-6


class BlenderError(TorchhandError, RuntimeError):
    """Blender ran but did not write the FBX file; the message holds the end of its output."""


@dataclass(frozen=True, eq=False)
class FbxArmature:
    """One armature of an FBX job (module docstring).

    name: object and armature name; bones: J names; parents: J ints (-1: root), parents precede children
    rest: bone rest matrices, (J, 4, 4), world, metres, bone Y along the bone; length: (J,) metres
    pose: bone matrices per frame, (T, J, 4, 4), world, metres; offset: ``O_j``, (J, 4, 4), bone = frame @ O_j
    """

    name: str
    bones: tuple
    parents: tuple
    rest: np.ndarray
    length: np.ndarray
    pose: np.ndarray
    offset: np.ndarray


@dataclass(frozen=True, eq=False)
class FbxMesh:
    """A rigid mesh of an FBX job: vertices (V, 3) metres in its own frame, faces (F, 3) int, pose (T, 4, 4)
    ``T_world_mesh``."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    pose: np.ndarray


@dataclass(frozen=True, eq=False)
class FbxScene:
    """What one FBX file holds: fps (1/s), frames T, armatures and meshes (each posed over the T frames)."""

    fps: float
    frames: int
    armatures: tuple = ()
    meshes: tuple = ()

    def to_json(self) -> dict:
        """The job the Blender-side script reads (module docstring); floats written exactly (``repr``)."""
        def mats(a: np.ndarray) -> list:
            return np.asarray(a, dtype=np.float64).reshape(*a.shape[:-2], 16).tolist()

        return {"format": "torchhand-fbx", "version": 1, "fps": float(self.fps), "frames": int(self.frames),
                "armatures": [{"name": a.name, "bones": list(a.bones), "parents": [int(p) for p in a.parents],
                               "rest": mats(a.rest), "length": [float(x) for x in a.length], "pose": mats(a.pose)}
                              for a in self.armatures],
                "meshes": [{"name": m.name, "vertices": np.asarray(m.vertices, dtype=np.float64).tolist(),
                            "faces": np.asarray(m.faces, dtype=np.int64).tolist(), "pose": mats(m.pose)}
                           for m in self.meshes]}


def frame_rate(fps: float) -> float:
    """The frame rate written: ``fps``, or the whole number within 0.01 % of it (a BVH frame time of 0.0333333 s
    is 30 fps), since Blender keeps whole frame rates exactly and its FBX importer keys at the rounded rate."""
    fps = float(fps)
    if not (np.isfinite(fps) and fps > 0):
        raise InputValueError(f"fps: expected a positive frame rate, got {fps}")
    whole = float(round(fps))
    return whole if whole >= 1 and abs(fps - whole) <= 1e-4 * fps else fps


def _unit(v: np.ndarray) -> np.ndarray | None:
    n = float(np.linalg.norm(v))
    return v / n if n > _EPS else None


def _bone_frame(y: np.ndarray, R: np.ndarray) -> np.ndarray:
    """A rotation whose Y axis is ``y`` and whose X axis is the frame ``R``'s x (or z) axis made orthogonal."""
    for axis in (R[:, 0], R[:, 2], R[:, 1]):
        x = _unit(axis - float(axis @ y) * y)
        if x is not None:
            return np.stack([x, y, np.cross(x, y)], axis=1)
    raise InputValueError("armature: degenerate rest frame")


def armature_spec(name: str, bones, parents, frames: np.ndarray, rest_frames: np.ndarray) -> FbxArmature:
    """An armature whose bone heads follow ``frames``.

    Args:
        name: the armature's name
        bones: J bone names; parents: J parent indices (-1: root), each parent before its children
        frames: frame poses per time step, (T, J, 4, 4), world, metres (link poses, End Site points)
        rest_frames: the rest pose of the frames, (J, 4, 4)

    Returns:
        the :class:`FbxArmature`: each bone's head at its frame's origin, its Y axis toward the mean of its
        children's rest origins (a leaf: along its parent bone, a tenth of the parent's length, at least 2 mm),
        its X axis the frame's x axis made orthogonal; ``pose = frames @ offset``, ``offset = inv(rest_frame) @ rest``.
    """
    bones, parents = tuple(str(b) for b in bones), tuple(int(p) for p in parents)
    frames, rest_frames = np.asarray(frames, dtype=np.float64), np.asarray(rest_frames, dtype=np.float64)
    J = len(bones)
    if frames.ndim != 4 or frames.shape[1:] != (J, 4, 4) or rest_frames.shape != (J, 4, 4) or len(parents) != J:
        raise ShapeError(f"armature {name}: expected {J} parents, frames (T, {J}, 4, 4) and rest (J, 4, 4), got "
                         f"{len(parents)}, {frames.shape}, {rest_frames.shape}")
    if any(not -1 <= p < j for j, p in enumerate(parents)) or len(set(bones)) != J:
        raise InputValueError(f"armature {name}: bone names must be unique and parents precede their children")
    origin = rest_frames[:, :3, 3]
    kids: dict[int, list[int]] = {}
    for j, p in enumerate(parents):
        kids.setdefault(p, []).append(j)
    rest = np.tile(np.eye(4), (J, 1, 1))
    length = np.zeros(J)
    for j in range(J):
        y, n = None, 0.0
        ch = kids.get(j, [])
        for d in ([origin[ch].mean(0) - origin[j]] + [origin[k] - origin[j] for k in ch]) if ch else []:
            if np.linalg.norm(d) >= _MIN_LENGTH:
                y, n = _unit(d), float(np.linalg.norm(d))
                break
        if y is None:
            p = parents[j]
            y = rest[p, :3, 1] if p >= 0 else rest_frames[j, :3, 0]
            n = max(0.1 * length[p], _MIN_LENGTH) if p >= 0 else 0.01
        rest[j, :3, :3] = _bone_frame(y, rest_frames[j, :3, :3])
        rest[j, :3, 3] = origin[j]
        length[j] = n
    offset = np.linalg.inv(rest_frames) @ rest
    offset[:, :3, 3] = 0.0
    return FbxArmature(name=name, bones=bones, parents=parents, rest=rest, length=length, pose=frames @ offset,
                       offset=offset)


def _hand_frames(model, q: np.ndarray, root_pose: np.ndarray | None):
    """The hand's BVH-skeleton frames (links, then End Sites at their points), (T, J, 4, 4), and at rest."""
    m = model.to(device="cpu", dtype=torch.float64)
    skel = hand_skeleton(m)
    with torch.no_grad():
        X = m.forward_kinematics(torch.as_tensor(np.asarray(q, dtype=np.float64)),
                                 None if root_pose is None else torch.as_tensor(np.asarray(root_pose))).numpy()
        X0 = m.forward_kinematics(torch.zeros(1, m.num_joints, dtype=torch.float64)).numpy()

    def with_ends(L: np.ndarray) -> np.ndarray:
        ends = L[:, skel.link_of[skel.num_links:]].copy()
        pts = skel.end_point[skel.num_links:]
        ends[..., :3, 3] = np.einsum("tjab,jb->tja", ends[..., :3, :3], pts) + ends[..., :3, 3]
        return np.concatenate([L, ends], axis=1)

    return skel, with_ends(X), with_ends(X0)[0]


def solution_fbx_scene(result, index: int) -> FbxScene:
    """Solution ``index`` of ``result`` (a :class:`~torchhand.io.result.Result`) as an FBX job.

    One armature per hand, ``<side>_hand``, bones as the BVH export's joints (one per link named as the link, and
    ``<link>_end`` at each fingertip pad point and at the end of each other leaf link), rest pose ``q = 0`` with
    the wrist at the origin; the object mesh ``object`` posed by ``object_pose``; the result's frame rate.
    """
    n = len(result.solution_files)
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or not 0 <= index < n:
        raise InputValueError(f"index: expected a solution 0..{n - 1} of {result.path}, got {index!r}")
    sol = result.solution(int(index))
    arms = []
    for hand in sol.hands:
        skel, X, X0 = _hand_frames(result.hand_models[hand.side], hand.q, hand.root_pose)
        arms.append(armature_spec(f"{hand.side}_hand", skel.names, skel.parents, X, X0))
    mesh = result.scene.object.mesh
    obj = FbxMesh("object", np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64),
                  np.asarray(sol.object_pose, dtype=np.float64))
    return FbxScene(fps=frame_rate(sol.fps), frames=int(sol.T), armatures=tuple(arms), meshes=(obj,))


def body_fbx_scene(clip, source, name: str = "body") -> FbxScene:
    """A body BVH clip (``body_with_fingers``) as an FBX job: one armature ``name``, a bone per BVH joint (End
    Sites too), in torchhand's world (the scene's ``source`` conversion: its units, up axis and handedness), at
    the clip's frame rate over all its frames; the rest pose is the BVH's (every channel zero)."""
    from ..scene.mocap import convert_transforms

    def world(G: torch.Tensor) -> np.ndarray:
        return convert_transforms(G, units_scale=source.units_scale, up_axis=source.up_axis,
                                  handedness=source.handedness).numpy()

    frames = world(clip.global_transforms())
    rest = world(clip.rest_transforms()[None])[0]
    arm = armature_spec(name, clip.names, clip.parents, frames, rest)
    return FbxScene(fps=frame_rate(clip.fps), frames=int(clip.num_frames), armatures=(arm,))


@dataclass(frozen=True)
class BlenderRunner:
    """How Blender runs: kind "bpy" (in this interpreter), "blender" (an executable) or "python" (an interpreter
    with bpy); command: the executable for the last two, () for "bpy"; source: where it was found."""

    kind: str
    command: tuple = ()
    source: str = ""


def _bpy_imports() -> bool:
    """Whether ``import bpy`` works in this interpreter."""
    try:
        import bpy  # noqa: F401
    except Exception:       # an ImportError, or bpy built against another NumPy failing on import
        return False
    return True


def find_blender(*, env=None, which=shutil.which, in_process=None) -> BlenderRunner:
    """Where Blender runs (module docstring): ``$TORCHHAND_BLENDER``, else ``bpy`` here, else ``blender`` on PATH.

    env: the environment (default ``os.environ``); which: ``shutil.which``; in_process: whether ``import bpy``
    works (None: try it). Raises MissingDependencyError (the install line) when none is there, and for a
    ``TORCHHAND_BLENDER`` that names no executable.
    """
    env = os.environ if env is None else env
    named = env.get(_ENV, "").strip()
    if named:
        exe = which(named) or (named if os.path.isfile(named) and os.access(named, os.X_OK) else None)
        if exe is None:
            raise MissingDependencyError(f"{_ENV}={named}: not an executable; {INSTALL_HINT}")
        kind = "python" if "python" in Path(named).name.lower() else "blender"
        return BlenderRunner(kind, (str(exe),), _ENV)
    if _bpy_imports() if in_process is None else in_process:
        return BlenderRunner("bpy", (), "bpy")
    exe = which("blender")
    if exe:
        return BlenderRunner("blender", (str(exe),), "PATH")
    raise MissingDependencyError(f"--format fbx needs Blender: {INSTALL_HINT}")


def _run(runner: BlenderRunner, job: Path, out: Path, timeout: float | None) -> None:
    """Run the Blender-side script on ``job``, writing ``out``."""
    if runner.kind == "bpy":
        from . import _blender_fbx

        with contextlib.redirect_stdout(io.StringIO()):
            _blender_fbx.main([str(job), str(out)])
        return
    if runner.kind == "python":
        cmd = [*runner.command, str(SCRIPT), str(job), str(out)]
    else:
        cmd = [*runner.command, "--background", "--factory-startup", "--python-exit-code", "1", "--python",
               str(SCRIPT), "--", str(job), str(out)]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)
    except (OSError, subprocess.TimeoutExpired) as err:
        raise BlenderError(f"{runner.command[0]}: could not run it ({err})") from None
    if done.returncode != 0 or not out.is_file() or out.stat().st_size == 0:
        text = (done.stderr or "") + (done.stdout or "")
        if "No module named 'bpy'" in text:
            raise MissingDependencyError(f"{_ENV}={runner.command[0]}: this Python has no bpy; {INSTALL_HINT}")
        tail = " | ".join(line.strip() for line in text.strip().splitlines()[-3:])
        raise BlenderError(f"{runner.command[0]} did not write {out.name} (exit {done.returncode}): {tail}")


def write_fbx(scene: FbxScene, path, *, blender: BlenderRunner | None = None, timeout: float | None = None) -> Path:
    """Write ``scene`` as an FBX file at ``path`` through Blender, atomically; returns the path.

    The job goes to a temporary folder; Blender writes a temporary file beside ``path``, which is flushed and
    renamed into place, so ``path`` is the old file or the new one. blender: :func:`find_blender` (None: find it
    now); timeout: seconds for a Blender subprocess (None: no limit).
    """
    runner = find_blender() if blender is None else blender
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".fbx", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        with tempfile.TemporaryDirectory(prefix="torchhand-fbx-") as work:
            job = Path(work) / "job.json"
            job.write_text(json.dumps(scene.to_json()))
            tmp.unlink()
            _run(runner, job, tmp, timeout)
        if not tmp.is_file() or tmp.stat().st_size == 0:
            raise BlenderError(f"Blender did not write {path.name}")
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path
