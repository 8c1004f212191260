"""``torchhand render RESULT_DIR --out clip.mp4``: draw synthesized hand motion as a video.

One solution becomes a clip; several (``--solutions 0,1,2`` or ``all``, or ``--grid``) are drawn side by side in a
labelled grid (solution index, strategy, key numbers and the search statistics of stats.json). ``--compare
REFERENCE`` puts a reference motion (another result directory, or a solution .npz such as converted mocap) beside the
synthesized one. Drawn: the hand(s), the object, the table, hand-object contacts (cyan), object-table contacts
(yellow) and contact forces (red arrows; the legend gives newtons per centimetre). RESULT_DIR may also be a lone
solution .npz, drawn as hands alone.

Output: H.264 mp4 (needs ffmpeg from imageio-ffmpeg), GIF, or PNG frames into a directory (--format png, or an --out
without .mp4/.gif). Rendering is offscreen (EGL, or OSMesa); PYOPENGL_PLATFORM is respected when set.
"""

from __future__ import annotations

import argparse
from ._common import add_threads_argument, apply_threads


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("render", help="draw solutions of a result directory as mp4 / GIF / PNG frames",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("result", metavar="RESULT_DIR", help="output directory of `torchhand synthesize` (or a solution "
                                                        ".npz)")
    p.add_argument("--out", required=True, help="output file (.mp4, .gif) or directory for PNG frames")
    p.add_argument("--solutions", help="solution indices: 0,1,2 or 1:4 or all (default: 0; with --grid: all)")
    p.add_argument("--grid", action="store_true", help="labelled grid of solutions (default when several are chosen)")
    p.add_argument("--size", default="640x480", help="size of one panel in pixels, WIDTHxHEIGHT (default 640x480)")
    p.add_argument("--fps", type=float, help="frames per second of the video (default: the solution's)")
    p.add_argument("--format", choices=["mp4", "gif", "png"], help="output format (default: from --out's suffix)")
    p.add_argument("--frames", metavar="A:B", help="only frames A <= k < B")
    p.add_argument("--orbit", action="store_true", help="orbit the camera about the vertical axis (30 deg/s)")
    p.add_argument("--compare", metavar="REFERENCE", help="a reference motion drawn beside: a result directory or "
                                                          "a solution .npz")
    p.add_argument("--no-shadows", action="store_true", help="no cast shadows (about twice as fast on a CPU)")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    add_threads_argument(p)
    p.set_defaults(func=run)


def run(args) -> int:
    apply_threads(args.threads)
    from torchhand.render.jobs import parse_size, render_result

    info = render_result(args.result, args.out, solutions=args.solutions, grid=args.grid, size=parse_size(args.size),
                         fps=args.fps, fmt=args.format, frames=args.frames, orbit=args.orbit, compare=args.compare,
                         shadows=not args.no_shadows, progress=False if args.no_progress else None)
    w, h = info["size"]
    print(f"wrote {info['out']}: {info['frames']} frames, {w}x{h}, {info['panels']} panel(s), {info['format']}")
    return 0
