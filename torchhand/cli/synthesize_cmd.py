"""``torchhand synthesize SCENE --out DIR``: contact-sampling synthesis of finger motion (Ye & Liu 2012).

From the scene's wrist and object motion, a randomized depth-first search over contact points finds many diverse,
kinematically and dynamically feasible finger motions, which are then reconstructed into smooth motion and checked
again. SCENE is a built-in scene name (``torchhand scene list``) or a scene directory, e.g. one written by
``torchhand scene import-mocap --manipnet ../shared/data/mocap/manipnet/mug1 --frames 1200:1260 --out mug``.

Writes DIR/scene/, DIR/hand.xml, DIR/stats.json and DIR/solutions/sol_000.npz, ... (see docs/synthesis.md).
"""

from __future__ import annotations

import argparse
import sys

import torch

from ..errors import InputValueError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("synthesize", help="find diverse, physically plausible finger motions for a scene",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene", help="a built-in scene name or a scene directory")
    p.add_argument("--out", required=True, help="output directory (created; result files in it are replaced)")
    p.add_argument("--solutions", type=int, default=10, help="stop after this many solutions (default 10)")
    p.add_argument("--time-budget", type=float, default=120.0,
                   help="seconds for everything: preparation, search, reconstruction (default 120)")
    p.add_argument("--seed", type=int, default=0, help="random seed; the same seed gives the same run (default 0)")
    p.add_argument("--epsilon", type=float, default=10.0,
                   help="expected number of search nodes per path; windows are T/epsilon frames (default 10)")
    p.add_argument("--strategy", default="mixed", choices=["static", "sliding", "relocating", "mixed"],
                   help="manipulation-strategy preference (default mixed)")
    p.add_argument("--frames", metavar="A:B", help="synthesize frames A <= t < B of the scene only")
    p.add_argument("--slide-speed", type=float, default=0.02, metavar="M_PER_S",
                   help="a contact held over two frames whose hand point moves faster than this on the object "
                        "slides (force on its friction cone's boundary); motion capture, whose wrist drifts by "
                        "millimetres per frame against the object, needs about 0.05 (default 0.02)")
    p.add_argument("--smooth", type=float, default=0.0, metavar="SEC",
                   help="low-pass filter the object and wrist trajectories first (Gaussian, standard deviation "
                        "in seconds; 0.05 suits 30 fps motion capture; default 0: as given)")
    p.add_argument("--trees", type=int, default=16, help="search trees grown in parallel (default 16)")
    p.add_argument("--candidates", type=int, default=16, help="candidates tested per expansion (default 16)")
    p.add_argument("--no-reconstruct", action="store_true", help="write the searched poses without smoothing")
    p.add_argument("--device", default="cpu", choices=["cpu", "cuda"], help="device (default cpu)")
    p.add_argument("--dtype", default="float32", choices=["float32", "float64"], help="dtype (default float32)")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    p.set_defaults(func=run)


def _frames(text: str, T: int) -> tuple[int, int]:
    try:
        a, b = (int(v) for v in text.split(":"))
    except ValueError:
        raise InputValueError(f"--frames: expected START:STOP with integers, got {text!r}") from None
    if not 0 <= a < b <= T:
        raise InputValueError(f"--frames: expected 0 <= START < STOP <= {T}, got {text!r}")
    return a, b


def run(args) -> int:
    from tqdm import tqdm

    from ..scene import load_scene
    from ..synthesis.output import write_result
    from ..synthesis.node_test import NodeTestSettings
    from ..synthesis.pipeline import synthesize

    if args.device == "cuda" and not torch.cuda.is_available():
        raise InputValueError("--device cuda: no CUDA device is available; use --device cpu")
    for name, value, low in (("--solutions", args.solutions, 1), ("--trees", args.trees, 1),
                             ("--candidates", args.candidates, 1)):
        if value < low:
            raise InputValueError(f"{name}: expected an integer >= {low}, got {value}")
    if not args.time_budget > 0 or not args.epsilon > 0 or not args.slide_speed > 0:
        raise InputValueError("--time-budget, --epsilon and --slide-speed must be positive")
    if not args.smooth >= 0:
        raise InputValueError(f"--smooth: expected seconds >= 0, got {args.smooth}")
    scene = load_scene(args.scene)        # before anything is written: a bad scene leaves no output behind
    scene = scene.smoothed(args.smooth)   # the whole clip, before any frame range: no edge effects inside it
    if args.frames:
        scene = scene.with_frames(*_frames(args.frames, scene.T))
    bar = tqdm(total=round(args.time_budget), unit="s", desc="synthesize", disable=True if args.no_progress else None,
               bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.0f}/{total:.0f} s [{postfix}]")

    def progress(stage, info):
        bar.n = min(int(info["elapsed"]), bar.total)
        post = {"stage": stage}
        if stage == "search":
            post.update(nodes=info["nodes_tested"], solutions=info["solutions"],
                        left=f"{max(0.0, info['budget'] - info['elapsed']):.0f}s")
        elif stage == "reconstruct":
            post.update(solution=f"{info['solution'] + 1}/{info['of']}")
        bar.set_postfix(post, refresh=True)

    result = synthesize(scene, solutions=args.solutions, time_budget=args.time_budget, seed=args.seed,
                        epsilon=args.epsilon, strategy=args.strategy, device=args.device,
                        dtype=getattr(torch, args.dtype), trees=args.trees, candidates=args.candidates,
                        reconstruct=not args.no_reconstruct, progress=progress,
                        node_settings=NodeTestSettings(slide_speed=args.slide_speed))
    bar.close()
    write_result(result, scene, args.out, strategy=args.strategy, seed=args.seed)
    st = result.stats
    n = len(result.solutions)
    print(f"{scene.name}: {n} solution(s) in {result.timings['total_s']:.1f} s; {st.nodes_tested} node tests "
          f"({st.nodes_tested / max(result.timings['search_s'], 1e-9):.0f}/s), {st.dead_ends} dead ends "
          f"(kinematic {st.rejections['kinematic']}, finger-finger {st.rejections['finger_finger']}, "
          f"dynamic {st.rejections['dynamic']}); {result.excluded} path(s) excluded by the final check")
    if n == 0:
        print(f"no feasible motion found within {args.time_budget:g} s: the furthest any path got was frame "
              f"{st.deepest_frame} of {scene.T}. Try a longer --time-budget, another --seed, --slide-speed 0.05 "
              f"for motion capture (docs/synthesis.md), or check that the wrists can reach the object "
              f"(torchhand inspect {args.scene}).", file=sys.stderr)
        worst = sorted(range(scene.T), key=lambda t: -sum(st.rejections_by_frame[t]))[:3]
        causes = ("kinematic", "finger-finger", "dynamic")
        where = ", ".join(f"frame {t}: {sum(st.rejections_by_frame[t])} ("
                          f"{causes[max(range(3), key=lambda c: st.rejections_by_frame[t][c])]} most)"
                          for t in worst if sum(st.rejections_by_frame[t]))
        if where:
            print(f"most rejections at {where} (stats.json: rejections_by_frame).", file=sys.stderr)
    print(f"wrote {args.out}/scene/, {args.out}/hand.xml, {args.out}/stats.json, {n} solution(s) in "
          f"{args.out}/solutions/")
    return 0 if n else 1
