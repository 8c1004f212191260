"""Render frames of an exported glb with Blender (Cycles on the CPU, headless), to compare with ``torchhand render``.

    python scripts/blender_render_glb.py out/export/sol_000.glb --out frames/ [--frames 0,33,65] [--size 480x360]

Needs ``bpy`` (``pip install -e '.[blender]'``). The frame rate is read from the glb's ``scene.extras.fps`` (written
by ``torchhand export``) so that Blender frame ``k`` is the result's frame ``k``. The camera looks at the object
from the front right and above, as ``torchhand render`` does by default; the light is one sun. Writes
``blender_XXX.png`` per frame.
"""

from __future__ import annotations

import argparse
import json
import struct
from pathlib import Path


def glb_extras(path: Path) -> dict:
    """``scenes[0].extras`` of a .glb (its JSON chunk)."""
    data = path.read_bytes()
    length = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20:20 + length])
    return (doc.get("scenes") or [{}])[0].get("extras") or {}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("glb", type=Path)
    ap.add_argument("--out", type=Path, required=True, help="folder for the PNG frames")
    ap.add_argument("--frames", default=None, help="frames to render, e.g. 0,33,65 (default first, middle, last)")
    ap.add_argument("--size", default="480x360", help="WIDTHxHEIGHT pixels")
    ap.add_argument("--samples", type=int, default=8, help="Cycles samples per pixel")
    args = ap.parse_args()
    import bpy
    from mathutils import Vector

    extras = glb_extras(args.glb)
    fps, T = int(round(extras.get("fps", 30))), int(extras.get("frames", 1))
    frames = [int(f) for f in args.frames.split(",")] if args.frames else sorted({0, (T - 1) // 2, T - 1})
    width, height = (int(v) for v in args.size.lower().split("x"))
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps = fps
    bpy.ops.import_scene.gltf(filepath=str(args.glb))
    scene.frame_set(frames[0])
    target = bpy.data.objects["object"].matrix_world.translation.copy()
    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    scene.collection.objects.link(cam)
    cam.location = target + Vector((0.35, -0.45, 0.30))
    cam.rotation_euler = (target - cam.location).to_track_quat("-Z", "Y").to_euler()
    scene.camera = cam
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    sun.data.energy = 3.0
    sun.rotation_euler = (0.6, 0.2, 0.3)
    scene.collection.objects.link(sun)
    scene.world = bpy.data.worlds.new("world")
    scene.world.use_nodes = True
    scene.world.node_tree.nodes["Background"].inputs[1].default_value = 0.6
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = args.samples
    scene.render.resolution_x, scene.render.resolution_y = width, height
    args.out.mkdir(parents=True, exist_ok=True)
    for f in frames:
        scene.frame_set(f)
        scene.render.filepath = str(args.out / f"blender_{f:03d}.png")
        bpy.ops.render.render(write_still=True)
    print(f"wrote {len(frames)} frame(s) to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
