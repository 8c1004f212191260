"""``torchhand splice --body BODY.bvh --hand HAND.bvh --out DIR``: put separately captured fingers on a body.

Majkowska, Zordan & Faloutsos (SCA 2006): the two captures are aligned in time by a two-pass DTW (pass 1: signs
of marker velocity and acceleration, i.e. movement phases; pass 2: the hand's angle to the forearm within the
phases), and the hand clip's finger joints, re-timed, drive the body's finger joints. The body's other channels
are written unchanged. Both files are BVH; rigs are recognised from joint names (Mixamo, CMU/MB-Lab, Character
Creator, Leap, ManipNet, mocapbank) or given as a TOML map (docs/splice_rigs.md).

Writes DIR/spliced.bvh, DIR/warp.npz, DIR/report.json and, with --plots, DIR/plots/*.png (docs/splice.md).

Matching points: --match B:H pins body frame B to hand frame H (0-based frames, or seconds with an s suffix:
--match 2.5s:3.1s); --match B:H~T lets the path pass within T hand frames (or T s) of H. Repeat --match or
separate points with commas. One tolerance applies to a whole splice.
"""

from __future__ import annotations

import argparse

from ..errors import InputValueError
from ._common import Progress, add_threads_argument, apply_threads


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("splice", help="align a hand capture to a body capture and put its fingers on the body",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--body", required=True, metavar="BODY.bvh", help="the body capture (BVH)")
    p.add_argument("--hand", required=True, metavar="HAND.bvh", help="the hand capture (BVH)")
    p.add_argument("--out", required=True, metavar="DIR", help="result directory (created)")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier splice result in DIR")
    p.add_argument("--side", choices=["right", "left"], default="right", help="which hand (default right)")
    p.add_argument("--match", action="append", default=[], metavar="B:H[~T]",
                   help="matching point(s): body frame B with hand frame H (frames, or seconds as 1.2s)")
    p.add_argument("--band1", type=float, default=0.30,
                   help="pass 1 band radius as a fraction of the body length (default 0.30, the paper's)")
    p.add_argument("--band2", type=float, default=0.10,
                   help="pass 2 band radius as a fraction of the body length (default 0.10, the paper's)")
    p.add_argument("--passes", type=int, choices=[1, 2], default=2, help="DTW passes (default 2)")
    p.add_argument("--features", choices=["trunk", "paper"], default="trunk",
                   help="trunk: markers in the body's trunk frame (default); paper: Eq. 7's local yaw per cell")
    p.add_argument("--wrist", choices=["body", "hand"], default="body",
                   help="keep the body's wrist (default) or take the hand clip's wrist rotation")
    p.add_argument("--body-map", default="auto", metavar="NAME|FILE", help="body rig: auto, a rig name or a TOML map")
    p.add_argument("--hand-map", default="auto", metavar="NAME|FILE", help="hand rig: auto, a rig name or a TOML map")
    for who in ("body", "hand"):
        p.add_argument(f"--{who}-units", choices=["auto", "m", "dm", "cm", "mm"], default="auto",
                       help=f"{who} file units (default: guessed from the forearm or hand length)")
        p.add_argument(f"--{who}-up", choices=["auto", "y", "z"], default="auto",
                       help=f"{who} file up axis (default: guessed; y for hand rigs)")
        p.add_argument(f"--{who}-handedness", choices=["right", "left"], default=None,
                       help=f"{who} file coordinate handedness (default right; ManipNet hands: left)")
    p.add_argument("--plots", action="store_true", help="also write the cost matrices and the time map as PNG")
    p.add_argument("--no-progress", action="store_true", help="no progress lines on stderr")
    add_threads_argument(p)
    p.set_defaults(func=run)


def parse_matches(items: list[str], body_fps: float, hand_fps: float) -> tuple[list[tuple[int, int]], float]:
    """``B:H[~T]`` items (comma-separated allowed) -> (pairs of frames, tolerance in hand frames)."""
    pairs, tols = [], set()
    for item in ",".join(items).split(","):
        item = item.strip()
        if not item:
            continue
        spec, _, tol = item.partition("~")
        b, sep, h = spec.partition(":")
        if not sep:
            raise InputValueError(f"--match {item}: expected BODY:HAND, e.g. 120:95 or 4.0s:3.2s")
        pairs.append((_frame(b, body_fps, item), _frame(h, hand_fps, item)))
        tols.add(_frame(tol, hand_fps, item, integer=False) if tol else 0.0)
    if len(tols) > 1:
        raise InputValueError(f"--match: one tolerance per splice, got {sorted(tols)} hand frames")
    return pairs, (tols.pop() if tols else 0.0)


def _frame(text: str, fps: float, item: str, integer: bool = True):
    t = text.strip()
    try:
        if t.endswith("s"):
            v = float(t[:-1]) * fps
            return int(round(v)) if integer else v
        v = float(t)
    except ValueError:
        raise InputValueError(f"--match {item}: '{text}' is not a frame number or a time like 1.5s") from None
    if integer and v != int(v):
        raise InputValueError(f"--match {item}: frame '{text}' is not an integer (use an s suffix for seconds)")
    if v < 0:
        raise InputValueError(f"--match {item}: '{text}' is negative")
    return int(v) if integer else v


def run(args) -> int:
    threads = apply_threads(args.threads)
    from dataclasses import replace

    from ..scene.bvh import read_bvh
    from ..splice.align import SpliceSettings
    from ..splice.markers import UNITS
    from ..splice.output import prepare_out, write_splice
    from ..splice.splice import ClipAxes, splice

    settings = SpliceSettings(band1=args.band1, band2=args.band2, passes=args.passes, features=args.features)
    from pathlib import Path

    created = not Path(args.out).exists()
    out = prepare_out(args.out, overwrite=args.overwrite)
    progress = Progress("splice", disable=args.no_progress)
    written = False
    try:
        progress.update("reading", f"{args.body}, {args.hand}")
        body = read_bvh(args.body)
        hand = read_bvh(args.hand)
        matches, tol = parse_matches(args.match, body.fps, hand.fps)
        settings = replace(settings, tolerance=tol)

        def axes(who: str) -> ClipAxes:
            u = getattr(args, f"{who}_units")
            up = getattr(args, f"{who}_up")
            hd = getattr(args, f"{who}_handedness")
            return ClipAxes(units=None if u == "auto" else UNITS[u], up=None if up == "auto" else up,
                            handedness=hd or "right")

        result = splice(body, hand, side=args.side, settings=settings, body_rig=args.body_map,
                        hand_rig=args.hand_map, body_axes=axes("body"), hand_axes=axes("hand"),
                        matches=matches or None, wrist=args.wrist,
                        progress=lambda stage: progress.update(stage, ""))
        result.report["threads"] = threads
        progress.update("writing", str(out))
        write_splice(result, out)
        written = True
        plots = []
        if args.plots:
            from torchhand.render.splice_plots import plot_splice

            plots = plot_splice(out)
    finally:
        progress.close()
        if created and not written and out.is_dir() and not any(out.iterdir()):
            out.rmdir()                       # bad input found after validation: leave no empty directory
    r = result.report
    speed = r["local_speed_range"]
    print(f"wrote {out}/spliced.bvh: {r['body_frames']} frames at {r['body_fps']:.4g} fps, "
          f"{len(r['joints_carried'])} joints carried from {r['hand_rig']} onto {r['body_rig']}"
          + (" (finger joints added under the wrist)" if r["fingers_inserted"] else ""))
    print(f"alignment: pass 2 {'used' if r['pass2_used'] else 'skipped: ' + r['pass2_note']}; hand local speed "
          f"{speed[0]:.2f}-{speed[1]:.2f}x; {r['seconds_total']:.2f} s")
    for p in plots:
        print(f"wrote {p}")
    return 0
