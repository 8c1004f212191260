"""Scenes from motion capture: wrists from BVH joints, the object from a BVH root or an npz of poses.

Coordinate conversion (applied to every source transform ``G``, 4x4, file units and axes)
    1. handedness: a left-handed source (Unity, e.g. ManipNet) is mirrored by negating x in the file coordinates
       and in every joint's local coordinates, ``G' = M G M`` with ``M = diag(-1, 1, 1, 1)``; ``G'`` is again a
       proper rigid transform. Joint rest offsets are mirrored the same way.
    2. units: translations are multiplied by ``units_scale`` (0.1 for decimetres, 0.01 for centimetres).
    3. up axis: a y-up source is rotated into torchhand's z-up world, ``(x, y, z) -> (x, -z, y)`` (+90 degrees
       about x); a z-up source is left as it is.
    The object's mesh is read in its own frame and scaled by ``mesh_scale`` (default ``units_scale``). It is not
    mirrored by default: mesh files are right-handed and Unity's importer negates x on import, which the mirror
    of step 1 undoes; pass ``mirror_mesh=True`` for a mesh stored in the same left-handed coordinates as the BVH.

Hand frame (the wrist joint's local axes are not torchhand's hand frame)
    A fixed rotation ``R_fix`` (joint-local coordinates of the hand axes) is computed once from the rest pose (all
    channels zero) and the wrist pose is ``T_world_hand = T_world_joint @ [R_fix, 0; 0, 1]`` (origin kept at the
    wrist joint centre).

    * Finger rule (hand BVHs such as ManipNet's, Mixamo or the CMU rig with fingers): among the wrist joint's
      descendants, the chains whose names contain ``middle``/``mid``, ``index`` and ``pinky``/``little`` give the
      finger bases (the first chain joint where the index and pinky bases are apart, for rigs whose finger roots
      all sit at one point). ``+x`` is the direction wrist -> middle-finger base; ``+y`` is the direction
      pinky base -> index base (toward the thumb) made orthogonal to x for a right hand, its opposite for a left
      hand; ``+z = x × y``, so the palm faces ``-z``. The hand length is the rest distance from the wrist to the
      end of the middle finger chain.
    * Fallback (a body BVH whose wrist joint has no finger children, e.g. ``RightWrist`` with an End Site):
      ``+x`` is the rest direction from the wrist to its child / End Site (or from its parent to it); the back of
      the hand ``+z`` is assumed to be the rest-pose up axis made orthogonal to x (palms down, as in a T-pose) or,
      when the arm hangs within 30 degrees of vertical, the lateral direction away from the root joint (palms
      facing the thighs); ``+y = z × x``. The hand length is the default 0.19 m. This is an assumption about the
      rig, not a measurement: check the result (``torchhand scene show``) for rigs in other rest poses.

Frames: ``frame_range = (start, stop)`` selects source frames ``start <= k < stop`` before resampling to ``fps``.
The source frame rate is ``1 / Frame Time``, rounded to an integer when it is within 1e-3 of one.

Modules
    ``_mocap_convert``  :func:`convert_transforms` and :func:`hand_frame_rotation` (the two rules above)
    ``_mocap_sources``  reading the wrist and object sources and their shared timing
    this module         :func:`import_mocap_scene` (sources -> converted tracks -> scene) and :func:`manipnet_scene`
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..errors import InputValueError, MissingFileError
from ..geometry.objects import RigidObject, load_object
from ._model import Scene
from ._mocap_convert import _check_choice, convert_transforms, hand_frame_rotation
from ._mocap_sources import _ObjectSource, _positive, _read_object, _read_wrists, _timing, _Timing, _Wrist
from ._parts import SIDES, Environment, HandTrack, MocapSource

__all__ = ["import_mocap_scene", "manipnet_scene", "hand_frame_rotation", "convert_transforms"]


@dataclass(frozen=True)
class _Tracks:
    """The sources converted into the z-up world (metres): ``object_pose`` (F', 4, 4) over the kept frames, the
    ``hands`` (one :class:`HandTrack` per side, right first), and per side the wrist's source ``(side, resolved BVH
    path, joint name)`` and its fixed rotation ``(side, R_fix (3, 3))`` for :class:`MocapSource`."""

    object_pose: torch.Tensor
    hands: tuple[HandTrack, ...]
    wrists: tuple[tuple[str, str, str], ...]
    rotations: tuple[tuple[str, np.ndarray], ...]


def import_mocap_scene(
    *,
    object_mesh: str | os.PathLike,
    hand_bvh: str | os.PathLike | Mapping[str, str | os.PathLike] | None = None,
    body_bvh: str | os.PathLike | None = None,
    wrist_joint: str | Mapping[str, str] | None = None,
    side: str = "right",
    object_bvh: str | os.PathLike | None = None,
    object_joint: str | None = None,
    object_npz: str | os.PathLike | None = None,
    units_scale: float = 1.0,
    mesh_scale: float | None = None,
    up_axis: str = "y",
    handedness: str = "right",
    mirror_mesh: bool = False,
    frame_range: tuple[int, int] | None = None,
    fps: float | None = None,
    name: str | None = None,
    mass: float | None = None,
    density: float | None = None,
    friction: float = 0.8,
    table_height: float | str | None = None,
    table_friction: float = 0.5,
    description: str = "",
    progress=None,
) -> Scene:
    """Build a validated :class:`Scene` from motion capture (conversions: module docstring).

    Args:
        object_mesh: the object's mesh file, in the object frame of its trajectory, file units.
        hand_bvh: a hand BVH whose root (or ``wrist_joint``) is the wrist, for ``side``; or a mapping
            ``{"right": path, "left": path}`` for two hands.
        body_bvh: a body BVH; ``wrist_joint`` names the wrist (a str for ``side``, or a mapping side -> name).
        wrist_joint: the wrist joint's name (required with ``body_bvh``; default the root of a hand BVH).
        side: the hand's side when ``hand_bvh`` / ``wrist_joint`` is a single value.
        object_bvh: a BVH whose root (or ``object_joint``) carries the object's 6-DOF motion.
        object_npz: alternatively, an npz with ``object_pose`` (F, 4, 4) in the source units and axes.
        units_scale: metres per source unit (0.1 for ManipNet's decimetres).
        mesh_scale: metres per mesh unit, default ``units_scale``.
        up_axis: "y" (converted to z-up) or "z".
        handedness: "right", or "left" for left-handed sources (Unity: ManipNet).
        mirror_mesh: also mirror the mesh (see the module docstring).
        frame_range: (start, stop) source frames to keep, before resampling.
        fps: resample to this frame rate (frames per second); default the source rate.
        name: scene name, default the mesh's stem.
        mass, density: the object's mass (kg) or density (kg/m^3); at most one.
        friction: hand-object Coulomb friction coefficient.
        table_height: None (no table), a z in metres, or "auto" (the lowest point the object reaches).
        table_friction: object-table friction coefficient.
        description: free text for the scene.
        progress: optional callable ``progress(step: str)`` told about each step (the CLI drives tqdm with it).

    Raises:
        InputValueError / InputTypeError: inconsistent arguments (both or neither of hand_bvh/body_bvh, of
            object_bvh/object_npz; bad side, frame range, scale).
        MissingFileError, FileFormatError: unreadable inputs (BVH errors name file and line).
        UnknownNameError: a joint name that is not in the BVH (the message lists the joints).
        ShapeError: sources with different frame counts, an npz ``object_pose`` that is not (F, 4, 4).
    """
    tick = progress if progress is not None else (lambda step: None)
    _check_choice(side, "side", SIDES)
    _check_choice(up_axis, "up_axis", ("y", "z"))
    _check_choice(handedness, "handedness", ("right", "left"))
    units_scale = _positive(units_scale, "units_scale")
    mesh_scale = units_scale if mesh_scale is None else _positive(mesh_scale, "mesh_scale")
    if (hand_bvh is None) == (body_bvh is None):
        raise InputValueError("hand_bvh, body_bvh: give exactly one of them")
    if (object_bvh is None) == (object_npz is None):
        raise InputValueError("object_bvh, object_npz: give exactly one of them")

    wrists = _read_wrists(hand_bvh, body_bvh, wrist_joint, side, tick)
    obj_source = _read_object(object_bvh, object_joint, object_npz, tick)
    timing = _timing(wrists, obj_source, frame_range)
    tick("converting poses")
    tracks = _convert_tracks(wrists, obj_source, slice(timing.start, timing.stop), units_scale=units_scale,
                             up_axis=up_axis, handedness=handedness)
    tick(f"loading {Path(object_mesh).name}")
    obj = _load_mesh(Path(object_mesh), mass, density, mesh_scale, mirror_mesh)
    environment = _environment(table_height, table_friction, obj, tracks.object_pose)
    source = _mocap_source("body" if body_bvh is not None else "hand", tracks, timing, units_scale=units_scale,
                           up_axis=up_axis, handedness=handedness)
    scene = Scene(name=name or Path(object_mesh).stem, object=obj, object_pose=tracks.object_pose, fps=timing.fps,
                  hands=tracks.hands, friction=friction, environment=environment, description=description,
                  source=source)
    if fps is not None and float(fps) != timing.fps:
        tick("resampling")
        scene = scene.resample(fps)
    return scene.validate()


def manipnet_scene(root_dir: str | os.PathLike, frame_range: tuple[int, int] | None = None, fps: float | None = None,
                   hands: tuple[str, ...] = ("right", "left"), *, mass: float = 0.3, friction: float = 0.8,
                   table_height: float | str | None = "auto", progress=None) -> Scene:
    """A scene from a ManipNet capture folder (``rightHand.bvh``, ``leftHand.bvh``, ``<object>.bvh`` and
    ``<object>.obj``): decimetres (``units_scale=0.1``), y-up, left-handed (Unity), 120 Hz.

    Args:
        root_dir: the folder, e.g. ``.../manipnet/mug1``.
        frame_range: (start, stop) source frames (at 120 Hz) to keep.
        fps: resample to this rate; default 120.
        hands: which hands to import, a tuple of "right"/"left".
        mass: object mass, kg (the mug: 0.3).
        friction: hand-object friction coefficient.
        table_height: None, metres, or "auto" (the lowest point the object reaches: where it rests).
        progress: optional callable ``progress(step: str)``, as in :func:`import_mocap_scene`.
    """
    root = Path(root_dir)
    if not root.is_dir():
        raise MissingFileError(f"root_dir: ManipNet folder '{root}' does not exist")
    if isinstance(hands, str) or not hands or any(h not in SIDES for h in hands) or len(set(hands)) != len(hands):
        raise InputValueError(f"hands: expected distinct sides from {SIDES}, got {hands!r}")
    hand_files = {"right": root / "rightHand.bvh", "left": root / "leftHand.bvh"}
    objs = sorted(p for p in root.glob("*.bvh") if p.name not in ("rightHand.bvh", "leftHand.bvh"))
    if len(objs) != 1:
        raise MissingFileError(f"root_dir: expected one object BVH besides the hands in '{root}', found "
                               f"{[p.name for p in objs]}")
    mesh = objs[0].with_suffix(".obj")
    if not mesh.is_file():
        raise MissingFileError(f"root_dir: object mesh '{mesh}' does not exist")
    return import_mocap_scene(
        object_mesh=mesh, hand_bvh={h: hand_files[h] for h in hands}, object_bvh=objs[0], units_scale=0.1,
        up_axis="y", handedness="left", frame_range=frame_range, fps=fps, name=f"manipnet-{objs[0].stem}",
        mass=mass, friction=friction, table_height=table_height,
        description=f"ManipNet capture '{root.name}' ({', '.join(hands)} hand), frames {frame_range or 'all'}",
        progress=progress,
    )


# ---------------------------------------------------------------------------------------------------------------
# stages


def _convert_tracks(wrists: dict[str, _Wrist], obj: _ObjectSource, frames: slice, *, units_scale: float,
                    up_axis: str, handedness: str) -> _Tracks:
    """The object's poses and each side's wrist track over ``frames``, in the z-up world (module docstring)."""
    conv = dict(units_scale=units_scale, up_axis=up_axis, handedness=handedness)
    if obj.clip is not None:
        obj_pose = convert_transforms(obj.clip.global_transforms(frames)[:, obj.joint], **conv)
    else:
        obj_pose = convert_transforms(obj.poses[frames], **conv)
    hands, sources, rotations = [], [], []
    for s in SIDES:
        if s not in wrists:
            continue
        clip, j = wrists[s].clip, wrists[s].joint
        R_fix, length, _ = hand_frame_rotation(clip, j, s, handedness=handedness, up_axis=up_axis)
        sources.append((s, str(Path(clip.path).resolve()), clip.names[j]))
        rotations.append((s, np.asarray(R_fix, dtype=np.float64)))
        fix = torch.eye(4, dtype=torch.float64)
        fix[:3, :3] = torch.as_tensor(R_fix)
        wrist = convert_transforms(clip.global_transforms(frames)[:, j], **conv) @ fix
        hands.append(HandTrack(side=s, wrist_pose=wrist,
                               length=0.19 if length is None else length * units_scale))
    return _Tracks(object_pose=obj_pose, hands=tuple(hands), wrists=tuple(sources), rotations=tuple(rotations))


def _mocap_source(kind: str, tracks: _Tracks, timing: _Timing, *, units_scale: float, up_axis: str,
                  handedness: str) -> MocapSource:
    """Where the scene came from (:class:`MocapSource`)."""
    return MocapSource(kind=kind, wrists=tracks.wrists, fps=timing.fps, frames=timing.frames,
                       first_frame=float(timing.start), units_scale=units_scale, up_axis=up_axis,
                       handedness=handedness, hand_rotation=tracks.rotations)


def _load_mesh(path: Path, mass, density, scale: float, mirror: bool) -> RigidObject:
    if not mirror:
        return load_object(path, mass=mass, density=density, scale=scale)
    base = load_object(path, mass=mass, density=density, scale=scale)
    mesh = base.mesh.copy()
    mesh.apply_transform(np.diag([-1.0, 1.0, 1.0, 1.0]))  # trimesh flips the winding of a reflection
    return RigidObject.from_trimesh(mesh, mass=base.mass, name=base.name)


def _environment(table_height, friction: float, obj: RigidObject, obj_pose: torch.Tensor) -> Environment:
    if table_height is None:
        return Environment(table=False, table_height=0.0, friction=friction)
    if isinstance(table_height, str):
        if table_height != "auto":
            raise InputValueError(f"table_height: expected None, a number or 'auto', got {table_height!r}")
        hull = torch.as_tensor(np.asarray(obj.mesh.convex_hull.vertices), dtype=obj_pose.dtype)
        z = torch.einsum("tj,nj->tn", obj_pose[:, 2, :3], hull) + obj_pose[:, 2, 3, None]
        return Environment(table=True, table_height=float(z.min()), friction=friction)
    return Environment(table=True, table_height=table_height, friction=friction)
