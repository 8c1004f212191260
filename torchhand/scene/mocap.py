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
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import torch

from .bvh import BVHClip, read_bvh
from ..errors import FileFormatError, InputValueError, MissingFileError, ShapeError
from ..geometry.objects import RigidObject, load_object
from ._model import Scene
from ._parts import SIDES, Environment, HandTrack, MocapSource

__all__ = ["import_mocap_scene", "manipnet_scene", "hand_frame_rotation", "convert_transforms"]

_FINGER_KEYS = {
    "middle": ("middle", "mid"),
    "index": ("index",),
    "pinky": ("pinky", "pinkie", "little"),
}


def convert_transforms(G: torch.Tensor, *, units_scale: float = 1.0, up_axis: str = "y",
                       handedness: str = "right") -> torch.Tensor:
    """Source transforms to torchhand world transforms (module docstring, steps 1-3).

    Args:
        G: source transforms, (..., 4, 4), file units and axes
        units_scale: metres per file unit
        up_axis: "y" or "z", the source's up axis
        handedness: "right" or "left", the source's coordinate handedness

    Returns:
        transforms in the z-up world, (..., 4, 4), metres, dtype of ``G``
    """
    _check_choice(up_axis, "up_axis", ("y", "z"))
    _check_choice(handedness, "handedness", ("right", "left"))
    out = G.clone()
    if handedness == "left":
        M = torch.diag(G.new_tensor([-1.0, 1.0, 1.0, 1.0]))
        out = M @ out @ M
    out[..., :3, 3] = out[..., :3, 3] * units_scale
    if up_axis == "y":
        C = G.new_tensor([[1.0, 0, 0, 0], [0, 0, -1.0, 0], [0, 1.0, 0, 0], [0, 0, 0, 1.0]])
        out = C @ out
    return out


def hand_frame_rotation(clip: BVHClip, wrist: int, side: str, *, handedness: str = "right",
                        up_axis: str = "y") -> tuple[np.ndarray, float | None, str]:
    """The fixed rotation from the wrist joint's local axes to the hand frame (module docstring).

    Args:
        clip: the BVH
        wrist: index of the wrist joint
        side: "right" or "left"
        handedness: the source's handedness ("left" mirrors the rest offsets first)
        up_axis: the source's up axis (used by the fallback rule only)

    Returns:
        R_fix: hand axes (columns x, y, z) in the wrist joint's (mirrored) local coordinates, (3, 3)
        length: rest wrist-to-middle-fingertip distance in file units, or None (fallback rule)
        rule: "fingers" or "fallback"
    """
    rest_T = clip.rest_transforms().numpy()
    if handedness == "left":
        M = np.diag([-1.0, 1.0, 1.0, 1.0])
        rest_T = M @ rest_T @ M
    rest = rest_T[:, :3, 3]
    R_rest = rest_T[wrist, :3, :3]  # identity for BVH (zero channels), kept for generality
    origin = rest[wrist]
    chains = {k: _finger_chain(clip, wrist, keys) for k, keys in _FINGER_KEYS.items()}
    if all(chains.values()):
        depth = min(len(c) for c in chains.values())
        for k in range(depth):
            mid = rest[chains["middle"][k]] - origin
            thumbward = rest[chains["index"][k]] - rest[chains["pinky"][k]]
            if np.linalg.norm(mid) > 1e-9 and np.linalg.norm(thumbward) > 0.25 * np.linalg.norm(mid):
                x = _unit(mid)
                y = thumbward - x * float(x @ thumbward)
                if np.linalg.norm(y) > 1e-6 * np.linalg.norm(thumbward):
                    y = _unit(y) if side == "right" else -_unit(y)
                    R_world = np.stack([x, y, np.cross(x, y)], axis=1)
                    tip = _deepest(clip, chains["middle"][0])
                    length = float(np.linalg.norm(rest[tip] - origin))
                    return R_rest.T @ R_world, (length if length > 0 else None), "fingers"
    # fallback: forearm direction and palms down (or palms in for hanging arms)
    kids = clip.children(wrist)
    if kids and np.linalg.norm(rest[kids[0]] - origin) > 1e-9:
        x = _unit(rest[kids[0]] - origin)
    elif clip.parents[wrist] >= 0 and np.linalg.norm(origin - rest[clip.parents[wrist]]) > 1e-9:
        x = _unit(origin - rest[clip.parents[wrist]])
    else:
        raise InputValueError(
            f"wrist_joint: cannot tell the forearm direction of '{clip.names[wrist]}' in {clip.path} "
            "(no child, End Site or parent at a distance)"
        )
    up = np.array([0.0, 1.0, 0.0]) if up_axis == "y" else np.array([0.0, 0.0, 1.0])
    if abs(float(x @ up)) < math.cos(math.radians(30.0)):
        z = _unit(up - x * float(x @ up))
    else:
        root = rest[0]
        lateral = origin - root
        lateral = lateral - up * float(up @ lateral)
        lateral = lateral - x * float(x @ lateral)
        if np.linalg.norm(lateral) < 1e-9:
            raise InputValueError(
                f"wrist_joint: '{clip.names[wrist]}' in {clip.path} hangs vertically on the body's midline; "
                "cannot guess the palm direction"
            )
        z = _unit(lateral)
    y = np.cross(z, x)
    return R_rest.T @ np.stack([x, y, z], axis=1), None, "fallback"


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

    # -- wrists -------------------------------------------------------------------------------------------------
    sources: dict[str, tuple[BVHClip, int]] = {}
    if hand_bvh is not None:
        paths = _per_side(hand_bvh, side, "hand_bvh")
        joints = _per_side(wrist_joint, side, "wrist_joint") if wrist_joint is not None else {}
        for s, path in paths.items():
            tick(f"reading {Path(path).name}")
            clip = read_bvh(path)
            sources[s] = (clip, clip.joint_index(joints[s]) if s in joints else _first_root(clip))
    else:
        if wrist_joint is None:
            raise InputValueError("wrist_joint: required with body_bvh (a joint name, or a mapping side -> name)")
        tick(f"reading {Path(body_bvh).name}")
        clip = read_bvh(body_bvh)
        for s, jname in _per_side(wrist_joint, side, "wrist_joint").items():
            sources[s] = (clip, clip.joint_index(jname))

    # -- object -------------------------------------------------------------------------------------------------
    if object_bvh is not None:
        tick(f"reading {Path(object_bvh).name}")
        oclip = read_bvh(object_bvh)
        oj = oclip.joint_index(object_joint) if object_joint is not None else _first_root(oclip)
        F_obj, frame_time = oclip.num_frames, oclip.frame_time
    else:
        oclip, oj = None, -1
        raw_obj = _read_object_npz(Path(object_npz))
        F_obj, frame_time = raw_obj.shape[0], None
    clips = [c for c, _ in sources.values()] + ([oclip] if oclip is not None else [])
    for c in clips:
        if c.num_frames != F_obj:
            raise ShapeError(f"{c.path}: has {c.num_frames} frames, the object trajectory has {F_obj}")
    frame_time = frame_time if frame_time is not None else clips[0].frame_time
    for c in clips:
        if abs(c.frame_time - frame_time) > 1e-6 * frame_time:
            raise InputValueError(f"{c.path}: frame time {c.frame_time} differs from {frame_time}")
    src_fps = 1.0 / frame_time
    if abs(src_fps - round(src_fps)) < 1e-3:
        src_fps = float(round(src_fps))

    start, stop = _frame_range(frame_range, F_obj)
    frames = slice(start, stop)

    tick("converting poses")
    conv = dict(units_scale=units_scale, up_axis=up_axis, handedness=handedness)
    if oclip is not None:
        obj_pose = convert_transforms(oclip.global_transforms(frames)[:, oj], **conv)
    else:
        obj_pose = convert_transforms(raw_obj[frames], **conv)
    hands, wrists, rotations = [], [], []
    for s in SIDES:
        if s not in sources:
            continue
        clip, j = sources[s]
        R_fix, length, _ = hand_frame_rotation(clip, j, s, handedness=handedness, up_axis=up_axis)
        wrists.append((s, str(Path(clip.path).resolve()), clip.names[j]))
        rotations.append((s, np.asarray(R_fix, dtype=np.float64)))
        fix = torch.eye(4, dtype=torch.float64)
        fix[:3, :3] = torch.as_tensor(R_fix)
        wrist = convert_transforms(clip.global_transforms(frames)[:, j], **conv) @ fix
        hands.append(HandTrack(side=s, wrist_pose=wrist,
                               length=0.19 if length is None else length * units_scale))

    tick(f"loading {Path(object_mesh).name}")
    obj = _load_mesh(Path(object_mesh), mass, density, mesh_scale, mirror_mesh)
    environment = _environment(table_height, table_friction, obj, obj_pose)
    source = MocapSource(kind="body" if body_bvh is not None else "hand", wrists=tuple(wrists), fps=src_fps,
                         frames=F_obj, first_frame=float(start), units_scale=units_scale, up_axis=up_axis,
                         handedness=handedness, hand_rotation=tuple(rotations))
    scene = Scene(name=name or Path(object_mesh).stem, object=obj, object_pose=obj_pose, fps=src_fps,
                  hands=tuple(hands), friction=friction, environment=environment, description=description,
                  source=source)
    if fps is not None and float(fps) != src_fps:
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
# helpers


def _check_choice(value, name: str, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise InputValueError(f"{name}: expected one of {', '.join(repr(c) for c in choices)}, got {value!r}")


def _positive(value, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise InputValueError(f"{name}: expected a finite positive number, got {value!r}")
    return float(value)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _per_side(value, side: str, name: str) -> dict[str, object]:
    if isinstance(value, Mapping):
        out = dict(value)
        if not out or any(k not in SIDES for k in out):
            raise InputValueError(f"{name}: mapping keys must be 'right' and/or 'left', got {list(out)}")
        return out
    return {side: value}


def _first_root(clip: BVHClip) -> int:
    return clip.parents.index(-1)


def _finger_chain(clip: BVHClip, wrist: int, keys: tuple[str, ...]) -> list[int]:
    """Joints of the first finger chain below ``wrist`` whose names contain one of ``keys`` (breadth first)."""
    def matches(j: int) -> bool:
        n = clip.names[j].lower()
        if keys == ("middle", "mid"):
            return "middle" in n or "mid" in n.replace("middle", "")
        return any(k in n for k in keys)

    queue = list(clip.children(wrist))
    while queue:
        j = queue.pop(0)
        if matches(j) and not clip.is_end_site[j]:
            chain = [j]
            while True:
                nxt = [c for c in clip.children(chain[-1]) if not clip.is_end_site[c]]
                if not nxt:
                    break
                chain.append(nxt[0])
            return chain
        queue.extend(clip.children(j))
    return []


def _deepest(clip: BVHClip, j: int) -> int:
    while clip.children(j):
        j = clip.children(j)[0]
    return j


def _frame_range(frame_range, F: int) -> tuple[int, int]:
    if frame_range is None:
        return 0, F
    try:
        start, stop = (int(v) for v in frame_range)
    except (TypeError, ValueError):
        raise InputValueError(f"frame_range: expected (start, stop), got {frame_range!r}") from None
    if not 0 <= start < stop <= F:
        raise InputValueError(f"frame_range: expected 0 <= start < stop <= {F} (source frames), got {frame_range}")
    if stop - start < 2:
        raise InputValueError(f"frame_range: needs at least 2 frames, got {frame_range}")
    return start, stop


def _read_object_npz(path: Path) -> torch.Tensor:
    import zipfile

    if not path.is_file():
        raise MissingFileError(f"object_npz: '{path}' does not exist")
    try:
        with np.load(path, allow_pickle=False) as data:
            if "object_pose" not in data.files:
                raise FileFormatError(f"{path}: missing array 'object_pose'; has {', '.join(data.files)}")
            a = data["object_pose"]
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as err:
        raise FileFormatError(f"{path}: cannot read npz: {type(err).__name__}: {err}") from None
    if a.dtype.kind not in "fiu" or a.ndim != 3 or a.shape[1:] != (4, 4):
        raise ShapeError(f"{path}: object_pose: expected a numeric (F, 4, 4) array, got {a.dtype} {a.shape}")
    return torch.tensor(a, dtype=torch.float64)


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
