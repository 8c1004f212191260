"""``torchhand scene``: list, show, export and import scenes (a thin layer over :mod:`torchhand.scene`).

    torchhand scene list
    torchhand scene show NAME_OR_DIR
    torchhand scene export NAME_OR_DIR DIR [--frames START:STOP] [--fps FPS] [--overwrite]
    torchhand scene import-mocap --object-mesh MESH (--hand-bvh [SIDE=]BVH ... | --body-bvh BVH --wrist-joint
        [SIDE=]NAME ...) (--object-bvh BVH | --object-npz NPZ) --out DIR [options]
    torchhand scene import-mocap --manipnet FOLDER --out DIR [--frames START:STOP] [--fps FPS]
"""

from __future__ import annotations

import math
import sys
from contextlib import contextmanager

from ..errors import InputValueError

_SIDES = ("right", "left")


def register(subparsers) -> None:
    p = subparsers.add_parser("scene", help="list, show, export and import scenes",
                              description="List, show, export and import torchhand scenes.")
    sub = p.add_subparsers(dest="scene_command", metavar="ACTION")
    sub.required = True

    q = sub.add_parser("list", help="list the built-in scenes", description="List the built-in scenes.")
    q.set_defaults(func=_list)

    q = sub.add_parser("show", help="summarise a scene", description="Summarise a built-in scene or a scene "
                       "directory: frames, fps, duration, object size and mass, hands, environment.")
    q.add_argument("scene", metavar="NAME_OR_DIR", help="built-in scene name or scene directory")
    q.set_defaults(func=_show)

    q = sub.add_parser("export", help="write a scene directory", description="Write a scene (built-in or a "
                       "directory) as a scene directory (docs/scene_format.md); files are replaced atomically.")
    q.add_argument("scene", metavar="NAME_OR_DIR", help="built-in scene name or scene directory")
    q.add_argument("out", metavar="DIR", help="target directory (created if missing)")
    _add_frames_fps(q)
    q.add_argument("--overwrite", action="store_true", help="replace scene files already in DIR")
    q.set_defaults(func=_export)

    q = sub.add_parser("import-mocap", help="build a scene directory from motion capture",
                       description="Build a scene from BVH motion capture (wrists from a hand BVH root or a body "
                       "BVH joint, the object from a BVH root or an npz of poses) and write it as a scene "
                       "directory. See torchhand.scene.mocap for the unit, up-axis, handedness and hand-frame "
                       "conversions.")
    q.add_argument("--out", required=True, metavar="DIR", help="scene directory to write")
    q.add_argument("--overwrite", action="store_true", help="replace scene files already in DIR")
    q.add_argument("--manipnet", metavar="FOLDER", help="a ManipNet capture folder (rightHand.bvh, "
                   "leftHand.bvh, <object>.bvh, <object>.obj); sets decimetres, y-up, left-handed")
    q.add_argument("--hands", default="right,left", help="with --manipnet: hands to import (default right,left)")
    q.add_argument("--object-mesh", metavar="MESH", help="object mesh in the object frame, source units")
    q.add_argument("--hand-bvh", action="append", metavar="[SIDE=]BVH",
                   help="hand BVH whose root is the wrist; repeat as right=... left=... for two hands")
    q.add_argument("--body-bvh", metavar="BVH", help="body BVH (needs --wrist-joint)")
    q.add_argument("--wrist-joint", action="append", metavar="[SIDE=]NAME",
                   help="wrist joint name; repeat as right=... left=... for two hands")
    q.add_argument("--side", choices=_SIDES, default="right", help="side of a single hand (default right)")
    q.add_argument("--object-bvh", metavar="BVH", help="BVH whose root carries the object's motion")
    q.add_argument("--object-joint", metavar="NAME", help="object joint in --object-bvh (default its root)")
    q.add_argument("--object-npz", metavar="NPZ", help="npz with object_pose (F, 4, 4) in source units and axes")
    q.add_argument("--units-scale", type=float, default=1.0, help="metres per source unit (default 1; 0.1 "
                   "for decimetres)")
    q.add_argument("--mesh-scale", type=float, default=None, help="metres per mesh unit (default units-scale)")
    q.add_argument("--up-axis", choices=("y", "z"), default="y", help="source up axis (default y)")
    q.add_argument("--handedness", choices=_SIDES, default="right",
                   help="source coordinate handedness (left for Unity / ManipNet)")
    q.add_argument("--mirror-mesh", action="store_true", help="mirror the mesh with a left-handed source")
    _add_frames_fps(q, frames_help="source frames to keep, START:STOP, before resampling")
    q.add_argument("--name", help="scene name (default the mesh's stem)")
    q.add_argument("--mass", type=float, help="object mass, kg")
    q.add_argument("--density", type=float, help="object density, kg/m^3 (instead of --mass)")
    q.add_argument("--friction", type=float, default=0.8, help="hand-object friction coefficient (default 0.8)")
    q.add_argument("--table-height", default=None, metavar="Z|auto",
                   help="table plane height in metres, or 'auto' (lowest object point); default no table")
    q.add_argument("--table-friction", type=float, default=0.5, help="object-table friction (default 0.5)")
    q.add_argument("--description", default="", help="scene description")
    q.set_defaults(func=_import_mocap)


def _add_frames_fps(q, frames_help: str = "keep frames START:STOP (Python slice, 0-based)") -> None:
    q.add_argument("--frames", metavar="START:STOP", help=frames_help)
    q.add_argument("--fps", type=float, help="resample to this frame rate (frames per second)")


# ---------------------------------------------------------------------------------------------------------------
# actions


def _list(args) -> int:
    from ..scene.builtin import builtin_scene_description, list_builtin_scenes

    names = list_builtin_scenes()
    width = max(len(n) for n in names)
    for n in names:
        print(f"{n:<{width}}  {builtin_scene_description(n)}")
    return 0


def _show(args) -> int:
    from ..scene import load_scene

    with _progress(1, "loading") as tick:
        scene = load_scene(args.scene)
        tick()
    print(summary(scene))
    return 0


def _export(args) -> int:
    from ..scene import load_scene

    with _progress(3, "exporting") as tick:
        scene = load_scene(args.scene)
        tick()
        scene = _edit(scene, args)
        tick()
        path = scene.export(args.out, overwrite=args.overwrite)
        tick()
    print(f"wrote {path}: scene '{scene.name}', {scene.T} frames at {scene.fps:g} fps")
    return 0


def _import_mocap(args) -> int:
    from ..scene.mocap import import_mocap_scene, manipnet_scene

    frames = _parse_frames(args.frames)
    table = _parse_table(args.table_height)
    with _progress(7, "importing") as tick:
        if args.manipnet:
            hands = tuple(h.strip() for h in args.hands.split(",") if h.strip())
            scene = manipnet_scene(args.manipnet, frame_range=frames, fps=args.fps, hands=hands,
                                   mass=0.3 if args.mass is None else args.mass, friction=args.friction,
                                   table_height="auto" if args.table_height is None else table,
                                   progress=lambda step: tick(step))
        else:
            if args.object_mesh is None:
                raise InputValueError("--object-mesh: required (or use --manipnet)")
            scene = import_mocap_scene(
                object_mesh=args.object_mesh, hand_bvh=_parse_sided(args.hand_bvh, "--hand-bvh"),
                body_bvh=args.body_bvh, wrist_joint=_parse_sided(args.wrist_joint, "--wrist-joint"),
                side=args.side, object_bvh=args.object_bvh, object_joint=args.object_joint,
                object_npz=args.object_npz, units_scale=args.units_scale, mesh_scale=args.mesh_scale,
                up_axis=args.up_axis, handedness=args.handedness, mirror_mesh=args.mirror_mesh,
                frame_range=frames, fps=args.fps, name=args.name, mass=args.mass, density=args.density,
                friction=args.friction, table_height=table, table_friction=args.table_friction,
                description=args.description, progress=lambda step: tick(step))
        tick("writing")
        path = scene.export(args.out, overwrite=args.overwrite)
    print(f"wrote {path}: scene '{scene.name}', {scene.T} frames at {scene.fps:g} fps, "
          f"hands {', '.join(scene.sides)}")
    return 0


# ---------------------------------------------------------------------------------------------------------------
# helpers


def summary(scene) -> str:
    """A human-readable multi-line summary of a scene."""
    import numpy as np
    import torch

    obj = scene.object
    ext = np.asarray(obj.mesh.extents)
    env = scene.environment
    lines = [
        f"scene:        {scene.name}",
        f"description:  {scene.description or '-'}",
        f"frames:       {scene.T} at {scene.fps:g} fps, duration {scene.duration:.3f} s",
        f"object:       {obj.name}, mass {obj.mass:.3f} kg, size {ext[0]:.3f} x {ext[1]:.3f} x {ext[2]:.3f} m, "
        f"{len(obj.mesh.vertices)} vertices, {len(obj.mesh.faces)} faces, "
        f"{'watertight' if obj.watertight else 'open mesh'}",
    ]
    p = scene.object_pose[:, :3, 3]
    travel = float((p - p[:1]).norm(dim=-1).max())
    R_rel = scene.object_pose[:1, :3, :3].transpose(-1, -2) @ scene.object_pose[:, :3, :3]
    cos = ((R_rel.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1, 1)
    turn = math.degrees(float(torch.acos(cos).max()))
    lines.append(f"object motion: up to {travel:.3f} m and {turn:.1f} deg from the first frame")
    for h in scene.hands:
        d = (h.wrist_pose[:, :3, 3] - p).norm(dim=-1)
        lines.append(f"hand:         {h.side}, length {h.length:.3f} m, wrist-object origin distance "
                     f"{float(d.min()):.3f}..{float(d.max()):.3f} m")
    lines.append(f"friction:     hand-object {scene.friction:g}")
    if env.table:
        edge = "" if env.table_extent is None else (" over x {:.3f}..{:.3f}, y {:.3f}..{:.3f} m"
                                                   .format(*env.table_extent))
        lines.append(f"environment:  table at z = {env.table_height:.4f} m{edge}, object-table friction "
                     f"{env.friction:g}")
    else:
        lines.append("environment:  no table")
    if env.floor:
        lines.append(f"              floor at z = {env.floor_height:.4f} m")
    g = scene.gravity.tolist()
    lines.append(f"gravity:      ({g[0]:g}, {g[1]:g}, {g[2]:g}) m/s^2")
    return "\n".join(lines)


def _edit(scene, args):
    frames = _parse_frames(args.frames)
    if frames is not None:
        scene = scene.with_frames(*frames)
    if args.fps is not None:
        scene = scene.resample(args.fps)
    return scene


def _parse_frames(text: str | None):
    if text is None:
        return None
    start, sep, stop = text.partition(":")
    try:
        if not sep:
            raise ValueError
        return int(start), int(stop)
    except ValueError:
        raise InputValueError(f"--frames: expected START:STOP with integers, got {text!r}") from None


def _parse_table(text: str | None):
    if text is None or text == "auto":
        return text
    try:
        value = float(text)
    except ValueError:
        raise InputValueError(f"--table-height: expected a number or 'auto', got {text!r}") from None
    if not math.isfinite(value):
        raise InputValueError(f"--table-height: expected a finite number, got {text!r}")
    return value


def _parse_sided(values: list[str] | None, flag: str):
    """``['right=a', 'left=b']`` -> mapping; ``['a']`` -> 'a' (for --side); None -> None."""
    if not values:
        return None
    if len(values) == 1 and not _has_side(values[0]):
        return values[0]
    out = {}
    for v in values:
        if not _has_side(v):
            raise InputValueError(f"{flag}: with several values each must be SIDE=VALUE (right=... left=...), "
                                  f"got {v!r}")
        side, _, rest = v.partition("=")
        if side in out:
            raise InputValueError(f"{flag}: side {side!r} given twice")
        out[side] = rest
    return out


def _has_side(v: str) -> bool:
    side, sep, _ = v.partition("=")
    return bool(sep) and side in _SIDES


@contextmanager
def _progress(total: int, desc: str):
    """A tqdm bar on stderr (hidden when stderr is not a terminal); yields ``tick(step=None)``."""
    from tqdm import tqdm

    bar = tqdm(total=total, desc=desc, file=sys.stderr, disable=None, leave=False)

    def tick(step: str | None = None) -> None:
        if step:
            bar.set_postfix_str(step)
        if bar.n < bar.total:
            bar.update(1)

    try:
        yield tick
    finally:
        bar.close()
