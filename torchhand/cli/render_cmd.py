"""``torchhand render RESULT_DIR --out clip.mp4``: draw synthesized hand motion as a video.

One solution becomes a clip; several (``--solutions 0,1,2`` or ``all``, or ``--grid``) are drawn side by side in a
labelled grid (solution index, strategy, key numbers and the search statistics of stats.json). ``--compare
REFERENCE`` puts a reference motion (another result directory, or a solution .npz such as converted mocap) beside the
synthesized one. Drawn: the hand(s), the object, the table, hand-object contacts (cyan), object-table contacts
(yellow) and contact forces (red arrows; the legend gives newtons per centimetre). RESULT_DIR may also be a lone
solution .npz, drawn as hands alone.

``torchhand render BODY.bvh [MORE.bvh ...] --compare HAND.bvh --out clip.mp4``: draw BVH skeletons side by side
on one timeline, each at its own frame rate: bones as capsules (fingers orange), a whole-motion view of a body and a
close-up of its right wrist when it has fingers, a close-up of a hand rig's wrist in the hand's own frame.
``--compare`` files go to the right, so a hand capture sits beside the close-up of the body it was spliced into.
Units and up axis are guessed per file (--bvh-units, --bvh-up; docs/render.md gives the rules).

Output: H.264 mp4 (needs ffmpeg from imageio-ffmpeg), GIF, or PNG frames into a directory (--format png, or an --out
without .mp4/.gif); an --out ending in .png is one image, of one frame (--frames A:A+1). Rendering is offscreen (EGL, or OSMesa); PYOPENGL_PLATFORM is respected when set.
"""

from __future__ import annotations

import argparse

from ..errors import InputValueError
from ._common import add_threads_argument, apply_threads

_BVH_ONLY = (("follow", "--follow"), ("no_close_up", "--no-close-up"), ("bvh_units", "--bvh-units"),
             ("bvh_up", "--bvh-up"), ("bvh_handedness", "--bvh-handedness"))


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("render", help="draw solutions of a result directory, or BVH motion, as mp4 / GIF / PNG "
                                      "frames", description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("inputs", nargs="+", metavar="INPUT", help="output directory of `torchhand synthesize` (or a "
                                                              "solution .npz), or one or more .bvh files")
    p.add_argument("--out", required=True, help="output file (.mp4, .gif) or directory for PNG frames")
    p.add_argument("--solutions", help="solution indices: 0,1,2 or 1:4 or all (default: 0; with --grid: all)")
    p.add_argument("--grid", action="store_true", help="labelled grid of solutions (default when several are chosen)")
    p.add_argument("--size", default="640x480", help="size of one panel in pixels, WIDTHxHEIGHT (default 640x480)")
    p.add_argument("--fps", type=float, help="frames per second of the video (default: the solution's; BVH: the "
                                             "first file's)")
    p.add_argument("--format", choices=["mp4", "gif", "png"], help="output format (default: from --out's suffix)")
    p.add_argument("--frames", metavar="A:B", help="only frames A <= k < B (BVH: of the first file)")
    p.add_argument("--orbit", action="store_true", help="orbit the camera about the vertical axis (30 deg/s)")
    p.add_argument("--compare", metavar="REFERENCE", action="append",
                   help="a reference motion drawn beside: a result directory or a solution .npz; with BVH inputs, a "
                        ".bvh drawn to their right (repeatable)")
    p.add_argument("--no-shadows", action="store_true", help="no cast shadows (about twice as fast on a CPU)")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    b = p.add_argument_group("BVH inputs")
    b.add_argument("--follow", metavar="JOINT", help="the close-up follows JOINT in every file that has it (default: "
                                                     "the right wrist of a rig with fingers)")
    b.add_argument("--no-close-up", action="store_true", help="whole-motion views only")
    b.add_argument("--bvh-units", metavar="auto|m|dm|cm|mm", help="file units, one for all files or one per file "
                                                                  "(cm,mm) (default auto: from the skeleton's size)")
    b.add_argument("--bvh-up", metavar="auto|y|z", help="the files' up axis, one or one per file (default auto: y "
                                                        "unless a body's rest pose stands along z)")
    b.add_argument("--bvh-handedness", metavar="right|left", help="the files' coordinate handedness, one or one per "
                                                                  "file (default right)")
    add_threads_argument(p)
    p.set_defaults(func=run)


def run(args) -> int:
    apply_threads(args.threads)
    from torchhand.render.jobs import is_bvh, parse_size, render_bvh, render_result

    compare = args.compare or []
    bvh = [is_bvh(p) for p in (*args.inputs, *compare)]
    progress = False if args.no_progress else None
    if any(bvh):
        if not all(bvh):
            raise InputValueError("INPUT, --compare: BVH files cannot be drawn with result directories or .npz "
                                  "solutions; give only .bvh files or one result")
        for dest, flag in (("solutions", "--solutions"), ("grid", "--grid")):
            if getattr(args, dest):
                raise InputValueError(f"{flag}: applies to result directories, not to BVH files")
        info = render_bvh(args.inputs, args.out, compare=compare, size=parse_size(args.size), fps=args.fps,
                          fmt=args.format, frames=args.frames, orbit=args.orbit, shadows=not args.no_shadows,
                          units=args.bvh_units, up=args.bvh_up, handedness=args.bvh_handedness, follow=args.follow,
                          close_up=not args.no_close_up, progress=progress)
    else:
        if len(args.inputs) > 1:
            raise InputValueError(f"RESULT_DIR: expected one result directory or solution .npz, got "
                                  f"{len(args.inputs)} inputs (only .bvh files are drawn several at once)")
        if len(compare) > 1:
            raise InputValueError(f"--compare: expected one reference for a result, got {len(compare)}")
        for dest, flag in _BVH_ONLY:
            if getattr(args, dest):
                raise InputValueError(f"{flag}: applies to .bvh inputs only")
        info = render_result(args.inputs[0], args.out, solutions=args.solutions, grid=args.grid,
                             size=parse_size(args.size), fps=args.fps, fmt=args.format, frames=args.frames,
                             orbit=args.orbit, compare=compare[0] if compare else None,
                             shadows=not args.no_shadows, progress=progress)
    w, h = info["size"]
    print(f"wrote {info['out']}: {info['frames']} frames, {w}x{h}, {info['panels']} panel(s), {info['format']}")
    return 0
