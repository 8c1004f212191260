"""``torchhand fill SCENE --out DIR``: finger motion for every frame of a whole capture (docs/fill.md).

The capture is segmented into phases (free hand, approach, contact, release) from the object's motion and the
wrist-object distance; each contact phase, with its approach and release, is synthesized in overlapping windows
(independent searches, each with its own seed), and the windows are stitched into one motion per variant that
covers every frame: crossfades over the overlaps, transitions to the hand's rest pose in free-hand frames. SCENE
is a built-in scene name (``torchhand scene list``) or a scene directory, e.g. one written by
``torchhand scene import-mocap --manipnet ../shared/data/mocap/manipnet/mug1 --hands right --fps 30 --out mug``.

Writes the result directory (docs/result_format.md) of the whole scene, with ``frame_status`` per frame in every
solution file (0 solved, 1 free hand, 2 unsolved: not claimed) and ``phases.json`` (phases, windows and their
outcome). ``torchhand check DIR`` checks every frame that is not flagged unsolved and lists those apart. Exit code
1 when no window found a solution (the result is still written), 2 for bad input.
"""

from __future__ import annotations

import argparse
import sys

from ..errors import InputValueError
from ._common import add_threads_argument, apply_threads


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fill", help="finger motion for every frame of a whole capture, window by window",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene", help="a built-in scene name or a scene directory")
    p.add_argument("--out", required=True,
                   help="output directory: new, empty, or an earlier result with --overwrite (checked before any "
                        "work)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing result directory (kept whole until the new result is complete)")
    p.add_argument("--side", choices=["right", "left"], default=None,
                   help="the hand whose phases set the windows (default: every hand's)")
    p.add_argument("--variants", type=int, default=3,
                   help="motions written: solutions searched per window (default 3)")
    p.add_argument("--window", type=int, default=60, metavar="F", help="longest window, frames (default 60)")
    p.add_argument("--overlap", type=int, default=15, metavar="F",
                   help="frames shared by consecutive windows, crossfaded (default 15; window >= 3 x overlap)")
    p.add_argument("--max-nodes", type=int, default=30000, metavar="N",
                   help="search budget per window in node tests, shared by its searches (default 30000)")
    p.add_argument("--stall-nodes", type=int, default=5000, metavar="N",
                   help="node tests without a deeper frame after which a window's search stops at a wall and the "
                        "window goes on past it (default 5000)")
    p.add_argument("--seed", type=int, default=0, help="main seed; each window's is derived from it (default 0)")
    p.add_argument("--slide-speed", type=float, default=None, metavar="M_PER_S",
                   help="slide speed of held contacts (default: from the capture's own noise; 0.02 for a scene that "
                        "is not a capture)")
    p.add_argument("--wrist-tolerance", default=None, metavar="MM,DEG",
                   help="how far a capture's wrist may move while it holds the object (default 5,3; 0 keeps it)")
    p.add_argument("--object-as-captured", action="store_true",
                   help="keep the capture's object track as is (default: put on the table where it stands and held "
                        "still where it rests, within capture noise)")
    p.add_argument("--jobs", type=int, default=1,
                   help="1: every window's searches together in this process, their node tests in shared calls; "
                        "N: N processes, each searching one window at a time (the same results; default 1)")
    p.add_argument("--device", default="cpu", choices=["cpu", "cuda"],
                   help="where the searches run (default cpu; with cuda use --jobs 1)")
    add_threads_argument(p)
    p.add_argument("--no-progress", action="store_true", help="no progress lines")
    p.set_defaults(func=run)


def run(args) -> int:
    import torch

    from ..fill.run import fill_capture
    from ..fill.wrist import parse_tolerance

    for name, value, low in (("--variants", args.variants, 1), ("--window", args.window, 1),
                             ("--overlap", args.overlap, 2), ("--max-nodes", args.max_nodes, 1),
                             ("--stall-nodes", args.stall_nodes, 1), ("--jobs", args.jobs, 1)):
        if value < low:
            raise InputValueError(f"{name}: expected an integer >= {low}, got {value}")
    if args.window < 3 * args.overlap:
        raise InputValueError(f"--window: expected at least 3 x --overlap = {3 * args.overlap} frames, got "
                              f"{args.window}")
    if args.slide_speed is not None and not args.slide_speed > 0:
        raise InputValueError(f"--slide-speed: expected a positive number, got {args.slide_speed:g}")
    if args.device == "cuda" and not torch.cuda.is_available():
        raise InputValueError("--device cuda: no CUDA device is available; use --device cpu")
    tolerance = None if args.wrist_tolerance is None else parse_tolerance(args.wrist_tolerance)
    apply_threads(args.threads)
    say = None if args.no_progress else (lambda line: print(line, file=sys.stderr, flush=True))
    try:
        result = fill_capture(args.scene, args.out, side=args.side, variants=args.variants, window=args.window,
                              overlap=args.overlap, max_nodes=args.max_nodes, seed=args.seed,
                              slide_speed=args.slide_speed, tolerance=tolerance, jobs=args.jobs, progress=say,
                              overwrite=args.overwrite, steady_object=not args.object_as_captured,
                              stall_nodes=args.stall_nodes, device=args.device)
    except KeyboardInterrupt:
        print(f"torchhand: interrupted; nothing complete was written to {args.out} (an earlier result there is "
              f"kept whole)", file=sys.stderr)
        return 130
    unsolved = [int((s == 2).sum()) for s in result.frame_status]
    print(f"wrote {result.out}: {len(result.frame_status)} motion(s) of {result.frame_status.shape[1]} frames in "
          f"{result.time_s:.0f} s; {sum(r.status == 'solved' for r in result.windows)}/{len(result.windows)} "
          f"windows solved whole, {sum(r.status == 'partial' for r in result.windows)} in part; contact-phase frames solved {100 * result.coverage:.1f} %; unsolved frames per motion "
          f"{unsolved} (phases.json, frame_status)")
    errors = [r for r in result.windows if r.status == "error"]
    if errors:
        print(f"{len(errors)} window(s) stopped with an error (their frames are flagged unsolved): "
              + "; ".join(f"frames {r.window.start}-{r.window.stop - 1}: {r.summary['error']}" for r in errors),
              file=sys.stderr)
        return 1
    if result.windows and not any(r.pieces for r in result.windows):
        print("no window found a solution: every contact frame is flagged unsolved. Try a larger --max-nodes, another "
              "--seed or shorter windows (docs/fill.md); phases.json lists each window's rejections.", file=sys.stderr)
        return 1
    return 0
