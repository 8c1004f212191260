"""``torchhand export RESULT_DIR --out DIR``: solutions as BVH, glTF and FBX, and fingers back onto a captured body.

Per solution: DIR/sol_XXX.bvh (the hand's skeleton, one joint per link of hand.xml, an End Site at each fingertip,
centimetres and y-up by default) and DIR/sol_XXX.glb (glTF 2.0: the object and its motion, the table, the hand as
animated nodes with a mesh per link, metres and y-up as glTF requires; --contacts adds contact points). A second
hand goes to DIR/sol_XXX_<side>.bvh. --format fbx (not a default) also writes DIR/sol_XXX.fbx through Blender: an
armature per hand, the object mesh, metres, frame t at FBX time t/fps (needs bpy: pip install 'torchhand[blender]',
or TORCHHAND_BLENDER=/path/to/blender, or blender on PATH). With --onto BODY.bvh (a scene imported by `scene
import-mocap --body-bvh`): DIR/body_with_fingers.bvh, the body's channels untouched, its finger joints driven by the
solution (and body_with_fingers.fbx with --format fbx). DIR/export.json lists what was written. Blender walk-through
and conventions: docs/export.md.
"""

from __future__ import annotations

import argparse

from ._common import Progress, add_threads_argument, apply_threads


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export", help="write solutions as BVH / glTF / FBX, or fingers back onto the captured body",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("result", metavar="RESULT_DIR", help="a result directory (torchhand synthesize --out)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (created)")
    p.add_argument("--solutions", default=None, metavar="0,1|all",
                   help="solutions to export: indices (0,2), a range (1:4) or all (default all; 0 with --onto)")
    p.add_argument("--format", default=None, metavar="bvh,gltf,fbx",
                   help="formats to write: bvh, gltf, fbx (default bvh,gltf; with --onto only the body unless "
                        "given; fbx runs Blender)")
    p.add_argument("--units", choices=["cm", "m"], default="cm", help="BVH units (default cm)")
    p.add_argument("--up", choices=["y", "z"], default="y", help="BVH up axis (default y)")
    p.add_argument("--contacts", action="store_true", help="put contact points into the glb as small spheres")
    p.add_argument("--onto", metavar="BODY.bvh", default=None,
                   help="the body BVH the scene was imported from: write body_with_fingers.bvh")
    p.add_argument("--blend", type=float, default=0.2, metavar="SEC",
                   help="with --onto: seconds of blend from the captured fingers at the segment's ends (default 0.2)")
    p.add_argument("--body-map", default="auto", metavar="NAME|FILE",
                   help="with --onto: the body's rig (auto, a rig name or a TOML joint map; docs/splice_rigs.md)")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier export in DIR")
    p.add_argument("--no-progress", action="store_true", help="no progress lines on stderr")
    add_threads_argument(p)
    p.set_defaults(func=run)


def run(args) -> int:
    apply_threads(args.threads)
    from ..export import export_result

    if args.format is None:
        formats = () if args.onto else ("bvh", "gltf")
    else:
        formats = tuple(f.strip() for f in args.format.split(",") if f.strip())
    solutions = args.solutions if args.solutions is not None else (None if args.onto else "all")
    progress = Progress("export", disable=args.no_progress)
    try:
        progress.update("reading", args.result)
        rep = export_result(args.result, args.out, solutions=solutions, formats=formats, units=args.units,
                            up=args.up, contacts=args.contacts, onto=args.onto, blend=args.blend,
                            body_rig=args.body_map, overwrite=args.overwrite,
                            progress=lambda text: progress.update("writing", text))
    finally:
        progress.close()
    n = len(rep.report["solutions"])
    if not rep.report["result_complete"]:
        print(f"note: {args.result} is a partial run; exported the solutions written so far")
    print(f"wrote {len(rep.files)} file(s) for {n} solution(s) to {rep.out} in {rep.report['seconds']:.1f} s")
    for entry in rep.report["solutions"]:
        onto = entry.get("onto")
        if onto:
            for side, info in onto["sides"].items():
                err = info.get("fingertip_error_max_m")
                print(f"{entry['solution']} {side}: body frames {onto['segment_source_frames'][0]}-"
                      f"{onto['segment_source_frames'][1]}, fingertips within "
                      f"{'n/a' if err is None else f'{1000 * err:.2f} mm'} of the solution's")
    if rep.removed:
        print(f"removed {len(rep.removed)} file(s) of the earlier export: {', '.join(rep.removed)}")
    return 0
