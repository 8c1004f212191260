"""``torchhand synthesize SCENE --out DIR``: contact-sampling synthesis of finger motion (Ye & Liu 2012).

From the scene's wrist and object motion, a randomized depth-first search over contact points finds many diverse,
kinematically and dynamically feasible finger motions, which are then reconstructed into smooth motion and checked
again. SCENE is a built-in scene name (``torchhand scene list``) or a scene directory, e.g. one written by
``torchhand scene import-mocap --manipnet ../shared/data/mocap/manipnet/mug1 --frames 1200:1260 --out mug``.

Writes DIR/scene/, DIR/hand.xml, DIR/stats.json and DIR/solutions/sol_000.npz, ... as solutions are found
(docs/result_format.md); an interrupted run leaves them readable, with "complete": false in stats.json.
"""

from __future__ import annotations

import argparse
import sys

import torch

from ..errors import InputValueError, TorchhandError
from ._common import Progress, add_threads_argument, apply_threads


def register(sub: argparse._SubParsersAction) -> None:
    from ..synthesis import DEFAULT_MAX_NODES
    from ..synthesis.search import STRATEGIES

    p = sub.add_parser("synthesize", help="find diverse, physically plausible finger motions for a scene",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene", help="a built-in scene name or a scene directory")
    p.add_argument("--out", required=True,
                   help="output directory: new, empty, or an earlier result with --overwrite (checked before any "
                        "work; solutions are written as they are found)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing result directory (kept whole until the new result is complete)")
    p.add_argument("--solutions", type=int, default=10, help="stop after this many solutions (default 10)")
    p.add_argument("--max-nodes", type=int, default=DEFAULT_MAX_NODES, metavar="N",
                   help=f"search budget in node tests (frames tested); with it a seed gives the same solutions on "
                        f"any machine (default {DEFAULT_MAX_NODES}; 0: unbounded)")
    p.add_argument("--time-budget", type=float, default=None, metavar="SEC",
                   help="wall-clock cap for everything, seconds (default: none); a run stopped by it depends on the "
                        "machine's speed and load")
    p.add_argument("--seed", type=int, default=0, help="random seed; the same seed gives the same run (default 0)")
    p.add_argument("--seeds", default=None, metavar="A-B|A,B,...",
                   help="run these seeds as one batch (e.g. 0-7 or 0,3,5): one result per seed in OUT/seed_S/, each "
                        "the one --seed S gives alone, byte for byte with a node budget; their node tests share "
                        "batches (docs/synthesis.md, 'Many seeds at once')")
    p.add_argument("--out-each", action="append", default=[], metavar="SEED=DIR", help=argparse.SUPPRESS)
    #              (with --seeds: each seed's result directory, instead of OUT/seed_S; the batch's worker uses it)
    p.add_argument("--epsilon", type=float, default=10.0,
                   help="expected number of search nodes per path; windows are T/epsilon frames (default 10)")
    p.add_argument("--strategy", default="mixed", choices=list(STRATEGIES),
                   help="manipulation-strategy preference (default mixed; gait: loaded fingers hold or roll, never "
                        "slide, free ones relocate: finger gaits, docs/synthesis.md)")
    p.add_argument("--frames", metavar="A:B", help="synthesize frames A <= t < B of the scene only")
    p.add_argument("--hand", action="append", default=[], metavar="SIDE=PATH",
                   help="use this MJCF (.xml) or URDF (.urdf) hand for SIDE instead of the scene's (right=..., "
                        "left=...; docs/hand_model.md)")
    p.add_argument("--object", default=None, metavar="MESH",
                   help="swap the scene's object for this mesh (any file trimesh reads), driven by the same object "
                        "and wrist motion (docs/synthesis.md, 'Another object')")
    p.add_argument("--object-scale", type=float, default=1.0, metavar="S",
                   help="with --object: multiply the mesh's coordinates by S (its units to metres; default 1)")
    p.add_argument("--object-mass", type=float, default=None, metavar="KG",
                   help="with --object: its mass (default: the replaced object's)")
    p.add_argument("--object-align", default="rest", choices=["rest", "com", "frame"],
                   help="with --object: rest (default: centre of mass above the old one's, lowest point where the "
                        "old one rested on the table), com (centres of mass coincide), frame (the mesh's own frame "
                        "is the old object's)")
    p.add_argument("--object-up", default="z", choices=["z", "y", "x", "-z", "-y", "-x"],
                   help="with --object: the mesh axis that points up (default z; y for y-up files such as the "
                        "Stanford bunny)")
    p.add_argument("--object-yaw", type=float, default=0.0, metavar="DEG",
                   help="with --object: turn the mesh by DEG degrees about the vertical (default 0)")
    p.add_argument("--object-offset", default=None, metavar="X,Y,Z",
                   help="move the object by this offset in the (first) wrist's frame, metres, frame by frame: "
                        "toward the palm for an envelope grasp, away for a fingertip grip (docs/synthesis.md)")
    p.add_argument("--slide-speed", type=float, default=None, metavar="M_PER_S",
                   help="a contact held over two frames whose hand point moves faster than this on the object "
                        "slides (force on its friction cone's boundary); default: from the capture's own noise "
                        "for an imported motion capture (printed and recorded in stats.json), 0.02 otherwise")
    p.add_argument("--wrist-tolerance", default=None, metavar="MM,DEG",
                   help="how far the wrist may move from an imported capture's track while the hand holds the "
                        "object (steadied against it; docs/fill.md); default 5,3 for a capture, 0 (fixed, as in "
                        "the paper) otherwise")
    p.add_argument("--object-as-captured", action="store_true",
                   help="keep an imported capture's object track as is (default: put on the table where it stands "
                        "and held still where it rests, within capture noise; docs/fill.md)")
    p.add_argument("--smooth", type=float, default=0.0, metavar="SEC",
                   help="low-pass filter the object and wrist trajectories first (Gaussian, standard deviation "
                        "in seconds; 0.05 suits 30 fps motion capture; default 0: as given)")
    p.add_argument("--max-joint-speed", type=float, default=8.0, metavar="RAD_PER_S",
                   help="joint-speed bound of the reconstructed motion (default 8 rad/s)")
    p.add_argument("--keep-unsmoothed", action="store_true",
                   help="also write paths whose reconstruction fails, as searched (flagged: reconstructed = false)")
    p.add_argument("--trees", type=int, default=16, help="search trees grown in parallel (default 16)")
    p.add_argument("--candidates", type=int, default=16, help="candidates tested per expansion (default 16)")
    p.add_argument("--no-mount-fit", action="store_true",
                   help="mount a robot hand by its hand-frame rule only, without the reach fit (docs/hand_model.md)")
    p.add_argument("--no-reconstruct", action="store_true",
                   help="write the searched poses without smoothing (flagged unsmoothed)")
    p.add_argument("--device", default="cpu", choices=["cpu", "cuda"], help="device (default cpu)")
    p.add_argument("--dtype", default="float32", choices=["float32", "float64"], help="dtype (default float32)")
    add_threads_argument(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar or progress lines")
    p.set_defaults(func=run)


def with_hands(scene, items: list[str]):
    """The scene with ``SIDE=PATH.xml`` hand overrides applied (InputValueError for a bad item)."""
    import dataclasses
    from pathlib import Path

    from ..hand.mount import track_hand

    if not items:
        return scene
    models = {}
    for item in items:
        side, sep, path = item.partition("=")
        if not sep or side not in ("right", "left") or not path:
            raise InputValueError(f"--hand {item}: expected SIDE=PATH with SIDE right or left")
        if side not in scene.sides:
            raise InputValueError(f"--hand {item}: scene '{scene.name}' has no {side} hand (hands: "
                                  f"{', '.join(scene.sides)})")
        models[side] = str(Path(path).resolve())
    hands = tuple(dataclasses.replace(t, model=models.get(t.side, t.model)) for t in scene.hands)
    for t in hands:
        track_hand(t)                                   # load now: a bad file fails before any work
    return dataclasses.replace(scene, hands=hands)


def _frames(text: str, T: int) -> tuple[int, int]:
    try:
        a, b = (int(v) for v in text.split(":"))
    except ValueError:
        raise InputValueError(f"--frames: expected START:STOP with integers, got {text!r}") from None
    if not 0 <= a < b <= T:
        raise InputValueError(f"--frames: expected 0 <= START < STOP <= {T}, got {text!r}")
    return a, b


def _check_args(args) -> None:
    if args.device == "cuda" and not torch.cuda.is_available():
        raise InputValueError("--device cuda: no CUDA device is available; use --device cpu")
    if args.seeds is not None and args.seed != 0:
        raise InputValueError("--seeds: give either --seed S or --seeds A-B, not both")
    for name, value, low in (("--solutions", args.solutions, 1), ("--trees", args.trees, 1),
                             ("--candidates", args.candidates, 1), ("--max-nodes", args.max_nodes, 0)):
        if value < low:
            raise InputValueError(f"{name}: expected an integer >= {low}, got {value}")
    for name, value in (("--time-budget", args.time_budget), ("--epsilon", args.epsilon),
                        ("--slide-speed", args.slide_speed), ("--max-joint-speed", args.max_joint_speed)):
        if value is not None and not value > 0:
            raise InputValueError(f"{name}: expected a positive number, got {value:g}")
    if not args.smooth >= 0:
        raise InputValueError(f"--smooth: expected seconds >= 0, got {args.smooth}")


def _swap(scene, args):
    """The scene with --object swapped in (or as it is); the swap's record for stats.json or None."""
    from ..scene.swap import swap_object

    if args.object is None:
        given = [n for n, v, d in (("--object-scale", args.object_scale, 1.0), ("--object-mass", args.object_mass,
                                   None), ("--object-align", args.object_align, "rest"),
                                   ("--object-up", args.object_up, "z"), ("--object-yaw", args.object_yaw, 0.0))
                 if v != d]
        if given:
            raise InputValueError(f"{given[0]}: needs --object MESH")
        return scene, None
    try:
        swapped, swap = swap_object(scene, args.object, scale=args.object_scale, mass=args.object_mass,
                                    align=args.object_align, up=args.object_up, yaw=args.object_yaw)
    except TorchhandError as err:               # name the option, not the function's argument
        raise type(err)(f"--object {args.object}: {str(err).removeprefix('path: ')}") from None
    print(f"{scene.name}: object '{scene.object.name}' swapped for {args.object} (scale {args.object_scale:g}, "
          f"{swap.mass:g} kg, up {args.object_up}, yaw {args.object_yaw:g}°), placed by '{swap.align}' at frame "
          f"{swap.frame}; the object and wrist tracks are unchanged", file=sys.stderr)
    record = dict(swap.to_json(), mesh=str(args.object), scale=args.object_scale, up=args.object_up,
                  yaw=args.object_yaw, replaced=scene.object.name)
    return swapped, record


def _offset(scene, text: str | None):
    """The scene with --object-offset X,Y,Z applied (or as it is), and the offset for stats.json or None."""
    from ..scene.swap import offset_object

    if text is None:
        return scene, None
    try:
        o = [float(v) for v in text.split(",")]
    except ValueError:
        o = []
    if len(o) != 3:
        raise InputValueError(f"--object-offset: expected X,Y,Z in metres, got {text!r}")
    try:
        moved = offset_object(scene, o)
    except InputValueError as err:
        raise InputValueError(f"--object-offset {text}: {str(err).removeprefix('offset: ')}") from None
    print(f"{scene.name}: object moved by {text} m in the {scene.hands[0].side} wrist's frame", file=sys.stderr)
    return moved, {"offset_m": o, "frame": f"{scene.hands[0].side} wrist"}


def _prepare(scene, args):
    """The scene's capture preparation (torchhand.fill.prepare): slide speed, steadied wrists and object."""
    from ..fill.object_rest import ObjectRest
    from ..fill.prepare import prepare_capture
    from ..fill.wrist import parse_tolerance

    tol = None if args.wrist_tolerance is None else parse_tolerance(args.wrist_tolerance)
    return prepare_capture(scene, slide_speed=args.slide_speed, tolerance=tol,
                           object_rest=None if args.object_as_captured else ObjectRest())


def parse_seeds(text: str) -> list[int]:
    """``A-B`` (inclusive) or ``A,B,...`` (or a mix: ``0-3,9``) -> distinct seeds in order (InputValueError)."""
    seeds = []
    try:
        for part in text.split(","):
            lo, sep, hi = part.strip().partition("-")
            seeds.extend(range(int(lo), int(hi) + 1) if sep else [int(lo)])
    except ValueError:
        raise InputValueError(f"--seeds: expected A-B or A,B,... with integers >= 0, got {text!r}") from None
    if not seeds or min(seeds) < 0 or len(set(seeds)) != len(seeds):
        raise InputValueError(f"--seeds: expected distinct integers >= 0 (A-B with A <= B, or A,B,...), got {text!r}")
    return seeds


def _scene(args):
    """The scene as the options make it: hands, object swap and offset, smoothing, frames, capture preparation.
    Returns (scene, prepared, swap record, offset record)."""
    from ..scene import load_scene

    scene = load_scene(args.scene)
    scene = with_hands(scene, args.hand)
    scene, swap = _swap(scene, args)
    scene, offset = _offset(scene, args.object_offset)
    scene = scene.smoothed(args.smooth)   # the whole clip, before any frame range: no edge effects inside it
    if args.frames:
        scene = scene.with_frames(*_frames(args.frames, scene.T))
    prepared = _prepare(scene, args)
    return prepared.scene, prepared, swap, offset


def _writers(args, seeds) -> dict:
    """One result writer per seed (None: the single run's ``--out``), each claimed before any work."""
    from pathlib import Path

    from ..synthesis.output import ResultWriter

    if seeds is None:
        return {None: ResultWriter(args.out, overwrite=args.overwrite)}
    out = Path(args.out)
    each = {}
    for item in args.out_each:
        seed, _, path = item.partition("=")
        each[int(seed)] = Path(path)
    if each and sorted(each) != sorted(seeds):
        raise InputValueError(f"--out-each: expected one directory for each seed of --seeds, got {sorted(each)}")
    if not each and out.exists() and not out.is_dir():
        raise InputValueError(f"--out {out}: exists and is not a directory")
    writers = {}
    try:
        for seed in seeds:
            writers[seed] = ResultWriter(each.get(seed, out / f"seed_{seed}"), overwrite=args.overwrite)
    except BaseException:
        for w in writers.values():
            w.abandon()
        raise
    return writers


def run(args) -> int:
    from ..fill.prepare import is_capture
    from ..synthesis.node_test import NodeTestSettings
    from ..synthesis.pipeline import synthesize, synthesize_seeds

    _check_args(args)
    seeds = None if args.seeds is None else parse_seeds(args.seeds)
    threads = apply_threads(args.threads)
    writers = _writers(args, seeds)     # before any work: nothing is lost later
    try:
        scene, prepared, swap, offset = _scene(args)
    except BaseException:
        for w in writers.values():
            w.abandon()
        raise
    if prepared.phases or args.slide_speed is not None or args.wrist_tolerance is not None:
        print(f"{scene.name}: {prepared.describe()}", file=sys.stderr)
    max_nodes = args.max_nodes or None
    bar = Progress("synthesize", disable=args.no_progress)
    progress = _progress(bar, args, max_nodes, seeds)
    started = set()

    def on_solution(result, index):
        key = None if seeds is None else result.seed
        if key not in started:
            writers[key].start(result.problem, result.scene)
            started.add(key)
        writers[key].add(result, index)

    options = dict(solutions=args.solutions, max_nodes=max_nodes, time_budget=args.time_budget,
                   epsilon=args.epsilon, strategy=args.strategy, device=args.device, dtype=getattr(torch, args.dtype),
                   trees=args.trees, candidates=args.candidates, reconstruct=not args.no_reconstruct,
                   max_joint_speed=args.max_joint_speed, keep_unsmoothed=args.keep_unsmoothed, progress=progress,
                   on_solution=on_solution, mount_fit=not args.no_mount_fit,
                   node_settings=NodeTestSettings(slide_speed=prepared.slide_speed,
                                                  table_slide_speed=prepared.slide_speed if is_capture(scene)
                                                  else 1e-3))
    try:
        if seeds is None:
            results = {None: synthesize(scene, seed=args.seed, **options)}
        else:
            results = dict(zip(seeds, synthesize_seeds(scene, seeds, **options)))
    except KeyboardInterrupt:
        bar.close()
        for w in writers.values():
            where = w.interrupted(None, scene.name)
            print(f"torchhand: interrupted; {w.written} solution(s) checkpointed in {where} (stats.json says "
                  f"\"complete\": false)", file=sys.stderr)
        return 130
    bar.close()
    found = [_write(writers[key], result, key in started, prepared, swap, offset, threads, args, max_nodes)
             for key, result in results.items()]
    if seeds is not None:
        empty = [s for s, n in zip(seeds, found) if not n]
        print(f"{scene.name}: {len(seeds)} seeds in one batch, {sum(found)} solution(s); "
              + (f"none for seed(s) {', '.join(map(str, empty))}" if empty else "every seed wrote a result"))
    return 0 if all(found) else 1


def _progress(bar, args, max_nodes, seeds):
    """The progress callback of one run or of a batch of seeds (the batch's node tests summed)."""
    done = {}

    def progress(stage, info):
        if stage == "search":
            done[info.get("seed")] = (info["nodes_tested"], info["solutions"])
            nodes, sols = sum(v[0] for v in done.values()), sum(v[1] for v in done.values())
            budget = max_nodes * (len(seeds) if seeds else 1) if max_nodes else None
            want = args.solutions * (len(seeds) if seeds else 1)
            bar.update("search", f"{nodes}{f'/{budget}' if budget else ''} node tests, {sols}/{want} solutions, "
                       f"{info['elapsed']:.0f} s", nodes / budget if budget else None)
        elif stage == "reconstruct":
            who = f"seed {info['seed']} " if seeds else ""
            bar.update("reconstruct", f"{who}path {info['solution'] + 1}, {info['elapsed']:.0f} s")
        else:
            who = f"seed {info['seed']}, " if seeds and "seed" in info else ""
            bar.update(stage, f"{who}{info['elapsed']:.0f} s")
    return progress


def _write(writer, result, started: bool, prepared, swap, offset, threads, args, max_nodes) -> int:
    """Complete one result directory (stats.json with the run's records) and print its summary; returns the
    number of solutions written."""
    from ..fill.captured import result_reference
    from ..synthesis.output import stats_dict

    scene = result.scene
    if not started:
        writer.start(result.problem, result.scene)
    stats = stats_dict(result, threads=threads)
    stats["capture"] = prepared.to_json()
    if swap is not None:
        stats["object_swap"] = swap
    if offset is not None:
        stats["object_offset"] = offset
    reference = result_reference(result, writer.stage)
    if reference is not None:
        stats["reference"] = reference
        _say_reference(scene.name, reference)
    out = writer.complete(stats)
    for fit in result.mount_fits:
        print(fit.describe())
    st = result.stats
    n = len(result.finals)
    ex = result.excluded
    unsmoothed = sum(not f.reconstructed for f in result.finals)
    who = f" (seed {result.seed})" if args.seeds else ""
    batch = f" in a batch of {result.timings['batched']}" if "batched" in result.timings else ""   # the batch's rate
    print(f"{scene.name}{who}: {n} solution(s) in {result.timings['total_s']:.1f} s; {st.nodes_tested} node tests "
          f"({stats['nodes_per_second']:.0f}/s{batch}, stopped by {st.stopped_by}), "
          f"{st.dead_ends} dead ends (kinematic {st.rejections['kinematic']}, finger-finger "
          f"{st.rejections['finger_finger']}, dynamic {st.rejections['dynamic']}); {st.paths_found} path(s) found, "
          f"not written: {ex.failed_check} failed the final check, {ex.unsmoothed} could not be smoothed, "
          f"{ex.duplicate} duplicate(s)" + (f"; {unsmoothed} written unsmoothed" if unsmoothed else ""))
    if n == 0:
        _explain_failure(result, args, scene, max_nodes)
    print(f"wrote {out}/scene/, {out}/hand.xml, {out}/stats.json, {n} solution(s) in {out}/solutions/")
    return n


def _say_reference(name: str, reference: dict) -> None:
    """One stderr line per hand: the synthesized fingers against the captured ones (stats.json "reference")."""
    if "error" in reference:
        print(f"{name}: captured fingers not compared: {reference['error']}", file=sys.stderr)
        return
    for side, entry in reference.items():
        rows = entry["motions"]
        med = [r["tip_distance_mm"]["median"] for r in rows if r["frames"]]
        agree = [r["contact_agreement"] for r in rows if r["frames"]]
        if med:
            print(f"{name}: {side} fingertips vs the captured ones: median distance {min(med):.1f}-{max(med):.1f} mm, "
                  f"contact sets agree on {100 * min(agree):.0f}-{100 * max(agree):.0f} % of frames "
                  f"(stats.json reference, fingers_{side}_sol_*.png; the captured fingers: "
                  f"{entry['captured_fit']['file']})", file=sys.stderr)


def _explain_failure(result, args, scene, max_nodes) -> None:
    """Why no solution was written: the budget, how far the search got, a palm inside the object, the frames with
    the most rejections."""
    from ..synthesis.clearance import describe_palm

    st = result.stats
    budget = f"{max_nodes} node tests" if st.stopped_by == "max_nodes" else f"{args.time_budget:g} s" \
        if st.stopped_by == "time_budget" else "the budget"
    print(f"no feasible motion found within {budget}: the furthest any path got was frame "
          f"{st.deepest_frame} of {scene.T}. Try a larger --max-nodes, another --seed, a larger --slide-speed "
          f"or --wrist-tolerance for motion capture (docs/synthesis.md), or check that the wrists can reach the object "
          f"(torchhand inspect {args.scene}).", file=sys.stderr)
    palm = describe_palm(result.problem)
    if palm:
        print(f"{palm}: no finger motion can avoid that (a smaller --object-scale, or another object placement).",
              file=sys.stderr)
    worst = sorted(range(scene.T), key=lambda t: -sum(st.rejections_by_frame[t]))[:3]
    causes = ("kinematic", "finger-finger", "dynamic")
    where = ", ".join(f"frame {t}: {sum(st.rejections_by_frame[t])} ("
                      f"{causes[max(range(3), key=lambda c: st.rejections_by_frame[t][c])]} most)"
                      for t in worst if sum(st.rejections_by_frame[t]))
    if where:
        print(f"most rejections at {where} (stats.json: rejections_by_frame).", file=sys.stderr)
