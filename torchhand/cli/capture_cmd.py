"""``torchhand capture estimate|synthetic|resynthesize|from-result``: interaction capture (Kry & Pai 2006),
docs/interaction_capture.md.

``torchhand capture estimate CAPTURE.npz --out DIR``
    Joint torques tau = J^T f over the 6 + D coordinates, contact events from the force tracks, the compliance of
    every coordinate at every event (rejected ones with a reason), C(t) and the reference trajectory
    theta_r = theta - C tau. Writes DIR/interaction.npz, DIR/summary.json, DIR/compliance_events.png and one
    DIR/contact_event_<e>.png per event; prints a table per coordinate. DIR must be new or empty, or hold an
    earlier estimate and --overwrite be given. Exit 0 written; 1 no contact event (the largest force is named);
    2 bad input.

``torchhand capture synthetic --out DIR``
    A capture with known compliance simulated by MuJoCo (a planar finger with joint springs pressing a plane;
    needs the [test] extra): DIR/capture.npz and DIR/planar_finger.xml.

``torchhand capture resynthesize INTERACTION --scene SCENE --out DIR``
    Quasi-static resynthesis (Sec. 7-8) of an interaction trajectory (interaction.npz) with the scene's object,
    table and hand: contacts, friction pyramids, G = J C J^T with root compliance, the object's rigid-body terms,
    object-table contacts, the contact LCP (Lemke per rollout, warm-started), grip adjustment on slip.
    --mass, --compliance-scale and --friction take comma-separated lists and expand to every combination, one
    rollout each. Writes the result directory of docs/result_format.md (stats.json method "kry_pai", one
    solutions/sol_XXX.npz per completed rollout). --variants FILE instead: named variants (each its own object,
    mass, friction, compliance scale) as rollouts of one batched step, one result directory each, DIR/<name>.
    Exit 0 written; 1 every rollout stopped at an unsolved LCP (the step is named); 2 bad input.

``torchhand capture from-result RESULT --out DIR``
    An inferred interaction from a ``torchhand synthesize`` result: the solution's contact forces (negated: on the hand)
    at the contact points in their link frames as DIR/capture.npz (source "inferred"), and DIR/interaction.npz with C(t)
    from a Kry & Pai Table 1 preset and theta_r = theta - C tau, tau = sum J^T f over the 6 + D coordinates.
    --friction-margin F (0.8) first re-solves each frame's forces for the same object wrench inside cones of F mu (the
    synthesis' forces sit on the cone's edge; 1 keeps them). Also DIR/hand.xml (the capture's hand), DIR/scene/ (the
    result's scene over the frames used) and DIR/summary.json. Exit 0 written; 2 bad input (a missing result, a bad
    --solution or --frames, an existing output without --overwrite).
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

from ..errors import InputValueError
from ._common import add_threads_argument, apply_threads


def register(sub: argparse._SubParsersAction) -> None:
    """``torchhand capture VERB``: one sub-command parser per verb."""
    p = sub.add_parser("capture", help="interaction capture: compliance and reference trajectory from forces",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    verbs = p.add_subparsers(dest="verb", metavar="VERB")
    verbs.required = True
    _add_estimate(verbs)
    _add_synthetic(verbs)
    _add_resynthesize(verbs)
    _add_from_result(verbs)


def _add_estimate(verbs: argparse._SubParsersAction) -> None:
    """``capture estimate CAPTURE --out DIR``: compliance at contact events, the reference trajectory."""
    e = verbs.add_parser("estimate", help="compliance at contact events and the reference trajectory",
                         description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    e.add_argument("capture", metavar="CAPTURE", help="capture.npz (docs/interaction_capture.md)")
    e.add_argument("--out", required=True, metavar="DIR",
                   help="output directory (new or empty; an earlier estimate with --overwrite)")
    e.add_argument("--overwrite", action="store_true", help="replace an earlier estimate in --out")
    e.add_argument("--hand", default=None, metavar="default|HAND.xml",
                   help="the hand (default: the capture's own `hand` entry)")
    e.add_argument("--degree", choices=["auto", "1", "2"], default="auto",
                   help="polynomial degree of the fits (auto: 2 where the pre-contact angle is curved)")
    e.add_argument("--method", choices=["joint", "slopes"], default="joint",
                   help="joint: one theta_r polynomial across both windows plus c tau (default); slopes: the "
                        "paper's change of slope at contact")
    e.add_argument("--window-pre", type=float, default=0.05, metavar="S", help="pre-contact window, s (0.05)")
    e.add_argument("--window-post", type=float, default=0.1, metavar="S",
                   help="post-contact window, s (0.1: reflexes change muscle force after about 100 ms)")
    e.add_argument("--force-threshold", type=float, default=0.05, metavar="N",
                   help="contact threshold f_on lower bound, newtons (0.05; raised to 3 sigma of the noise)")
    e.add_argument("--gap", type=float, default=0.05, metavar="S",
                   help="quiet time before a contact event and merge window of one finger's sensors, s (0.05)")
    e.add_argument("--mode", choices=["latest", "median"], default="latest",
                   help="C(t): latest valid estimate per coordinate (default) or the median of all")
    e.add_argument("--default-compliance", default="table1-exploring",
                   choices=["table1-exploring", "table1-scratching"],
                   help="compliance of coordinates without a valid estimate (Kry & Pai Table 1, extended)")
    e.add_argument("--allow-low-rate", action="store_true", help="accept captures below 200 Hz")
    e.add_argument("--max-event-plots", type=int, default=None, metavar="N",
                   help="write contact_event_<e>.png for the first N events only (default: all)")
    e.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    add_threads_argument(e)
    e.set_defaults(func=run_estimate)


def _add_synthetic(verbs: argparse._SubParsersAction) -> None:
    """``capture synthetic --out DIR``: a capture with known compliance simulated by MuJoCo."""
    s = verbs.add_parser("synthetic", help="a capture with known compliance simulated by MuJoCo",
                         description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    s.add_argument("--out", required=True, metavar="DIR", help="output directory (new or empty)")
    s.add_argument("--task", choices=["exploring", "scratching"], default="exploring",
                   help="Table 1 column for the joint stiffness (default exploring)")
    s.add_argument("--rate", type=float, default=500.0, metavar="HZ", help="frame rate, Hz (500)")
    s.add_argument("--noise-angle-deg", type=float, default=0.2, metavar="DEG", help="angle noise, degrees (0.2)")
    s.add_argument("--noise-force", type=float, default=0.01, metavar="N", help="force noise per component, N (0.01)")
    s.add_argument("--presses", type=int, default=80, metavar="N", help="number of presses (contact events; 80)")
    s.add_argument("--approach-speed", type=float, default=0.3, metavar="M_S",
                   help="fingertip reference speed towards the plane, m/s (0.3)")
    s.add_argument("--seed", type=int, default=0, help="seed of the postures, trajectories and noise (0)")
    s.set_defaults(func=run_synthetic)


def _add_resynthesize(verbs: argparse._SubParsersAction) -> None:
    """``capture resynthesize INTERACTION --scene SCENE --out DIR``: quasi-static resynthesis."""
    r = verbs.add_parser("resynthesize", help="quasi-static resynthesis of an interaction on a scene's object",
                         description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    r.add_argument("interaction", metavar="INTERACTION", help="interaction.npz (docs/interaction_capture.md)")
    r.add_argument("--scene", required=True, metavar="SCENE", help="built-in scene name or scene directory")
    r.add_argument("--out", required=True, metavar="DIR",
                   help="result directory (new or empty; an earlier result with --overwrite)")
    r.add_argument("--overwrite", action="store_true", help="replace an earlier result in --out")
    r.add_argument("--dt", type=float, default=None, metavar="S", help="step h, s (default 1/fps of the scene)")
    r.add_argument("--mass", default=None, metavar="KG[,KG...]", help="object masses, one rollout each")
    r.add_argument("--compliance-scale", default="1", metavar="S[,S...]", help="scales of the compliance C (1)")
    r.add_argument("--friction", default=None, metavar="MU[,MU...]", help="hand-object friction coefficients")
    r.add_argument("--variants", default=None, metavar="FILE",
                   help="a TOML file of named variants (object, mass, friction, compliance scale), all rollouts of "
                        "one batched step; one result directory each, --out DIR/<name> (docs/interaction_capture.md)")
    r.add_argument("--grip", choices=["none", "delayed", "imminent"], default="none",
                   help="grip adjustment on slip (Sec. 8.1): none, delayed (100 ms after slip) or imminent")
    r.add_argument("--slip-ratio", type=float, default=0.9, metavar="R", help="imminent slip at rho > R mu (0.9)")
    r.add_argument("--min-force", type=float, default=0.2, metavar="N", help="watch contacts above N newtons (0.2)")
    r.add_argument("--tighten", type=float, default=0.95, metavar="F", help="compliance factor per step (0.95)")
    r.add_argument("--grip-floor", type=float, default=0.2, metavar="F", help="lowest compliance scale (0.2)")
    r.add_argument("--grip-delay", type=float, default=0.1, metavar="S", help="reaction delay, s (0.1)")
    r.add_argument("--device", default="cpu", choices=["cpu", "cuda"],
                   help="where the step's tensors live (default cpu; the exact-mesh queries and the per-rollout LCPs "
                        "run on the CPU either way)")
    r.add_argument("--finger-friction", type=float, default=0.0, metavar="MU",
                   help="friction coefficient between fingers (finger-finger contact slots; 0: frictionless)")
    r.add_argument("--reach", action="store_true",
                   help="a finger the reference pushes with that does not touch the object closes on along the "
                        "reference's push until it does (docs/interaction_capture.md, 'Reach')")
    r.add_argument("--reach-rate", type=float, default=0.5, metavar="RAD_S", help="closing speed of --reach (0.5)")
    r.add_argument("--reach-limit", type=float, default=0.25, metavar="RAD",
                   help="largest extra closing per finger with --reach (0.25)")
    r.add_argument("--pyramid-m", type=int, default=4, metavar="M", help="friction pyramid direction pairs (4)")
    r.add_argument("--solver", choices=["lemke", "pgs", "auto"], default=None,
                   help="LCP solver (default: lemke, per rollout; auto = batched PGS + Lemke for what it leaves; "
                        "auto with --dtype float32)")
    r.add_argument("--settle-steps", type=int, default=0, metavar="N",
                   help="steps at the first reference before frame 0, object under gravity on the table (0)")
    r.add_argument("--close-open", action="store_true",
                   help="before frame 0, close the fingers along the interaction until every finger that pushes in it "
                        "pushes, and open them again, the wrist held (the paper's settle; needs the interaction's "
                        "theta)")
    r.add_argument("--dtype", choices=["float64", "float32"], default="float64", help="rollout dtype (float64)")
    r.add_argument("--object-contacts", choices=["mesh", "sdf"], default="mesh",
                   help="hand-object contacts: each link's capsule against the exact mesh (mesh, the checker's "
                        "geometry) or surface samples in a signed distance grid (sdf; --sdf-voxel)")
    r.add_argument("--sdf-voxel", type=float, default=0.001, metavar="M",
                   help="voxel of the grid with --object-contacts sdf, metres (0.001)")
    add_threads_argument(r)
    r.set_defaults(func=run_resynthesize)


def _add_from_result(verbs: argparse._SubParsersAction) -> None:
    """``capture from-result RESULT --out DIR``: an inferred interaction from a synthesis result."""
    f = verbs.add_parser("from-result", help="an inferred interaction from a synthesis result's contact forces",
                         description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    f.add_argument("result", metavar="RESULT", help="a `torchhand synthesize` result directory")
    f.add_argument("--solution", type=int, default=0, metavar="N", help="solution index (0)")
    f.add_argument("--frames", default=None, metavar="A:B",
                   help="the solution's frames A <= t < B to use (default: all; choose the part that holds the "
                        "object)")
    f.add_argument("--compliance", default="table1-exploring", choices=["table1-exploring", "table1-scratching"],
                   help="compliance of every coordinate (Kry & Pai Table 1, extended; default table1-exploring)")
    f.add_argument("--friction-margin", type=float, default=0.8, metavar="F",
                   help="re-solve each frame's hand forces for the same object wrench inside friction cones of "
                        "F mu (0 < F <= 1; 0.8): a grip with a safety margin instead of the synthesis' forces on the "
                        "cone's edge; 1 replays the solution's forces as they are")
    f.add_argument("--out", required=True, metavar="DIR",
                   help="output directory (new or empty; an earlier output with --overwrite)")
    f.add_argument("--overwrite", action="store_true", help="replace an earlier output in --out")
    add_threads_argument(f)
    f.set_defaults(func=run_from_result)


def _check_window(value: float, name: str) -> None:
    if not value > 0:
        raise InputValueError(f"{name}: expected a positive number of seconds, got {value}")


def run_estimate(args) -> int:
    apply_threads(args.threads)
    from torchhand.interaction import (EstimateSettings, NoContactError, capture_hand, estimate_capture,
                                       load_capture, prepare_output_dir, write_interaction)
    from torchhand.interaction.pipeline import format_table
    from torchhand.interaction.plots import write_plots

    _check_window(args.window_pre, "--window-pre")
    _check_window(args.window_post, "--window-post")
    if args.max_event_plots is not None and args.max_event_plots < 0:
        raise InputValueError(f"--max-event-plots: expected >= 0, got {args.max_event_plots}")
    capture = load_capture(args.capture)
    hand = capture_hand(capture, args.hand)
    out = prepare_output_dir(Path(args.out), overwrite=args.overwrite)
    if args.window_post > 0.1:
        print(f"torchhand: warning: --window-post {args.window_post:g} s is longer than the 100 ms before reflexes "
              "change muscle force; estimates may include reflex responses", file=sys.stderr)
    settings = EstimateSettings(window_pre=args.window_pre, window_post=args.window_post,
                                degree=None if args.degree == "auto" else int(args.degree),
                                force_threshold=args.force_threshold, gap=args.gap, mode=args.mode,
                                method=args.method)
    try:
        result = estimate_capture(capture, hand, settings, default=args.default_compliance,
                                  allow_low_rate=args.allow_low_rate)
    except NoContactError as err:
        print(f"torchhand: {err}", file=sys.stderr)
        return 1
    write_interaction(result, out)
    if not args.no_plots:
        write_plots(result, out, max_events=args.max_event_plots)
    print(format_table(result))
    missing = [result.names[j] for j in range(len(result.names))
               if result.trajectory.is_default[j] and (result.estimate.reason[:, j] > 2).any()]
    if missing:
        print(f"torchhand: warning: no valid estimate for {', '.join(missing)}; using {args.default_compliance}",
              file=sys.stderr)
    print(f"{result.events.count} contact events; wrote {out}")
    return 0


def _floats(text, name: str) -> tuple:
    if text is None:
        return (None,)
    try:
        values = tuple(float(x) for x in str(text).split(",") if x.strip())
    except ValueError:
        raise InputValueError(f"{name}: expected comma-separated numbers, got {text!r}") from None
    if not values:
        raise InputValueError(f"{name}: expected at least one number, got {text!r}")
    return values


def run_resynthesize(args) -> int:
    import torch

    from torchhand.interaction.grip import GripSettings
    from torchhand.interaction.reach import ReachSettings
    from torchhand.interaction.resynth import ResynthSettings

    apply_threads(args.threads)
    grip = GripSettings(mode=args.grip, ratio=args.slip_ratio, min_force=args.min_force, factor=args.tighten,
                        floor=args.grip_floor, delay=args.grip_delay)
    settings = ResynthSettings(dt=args.dt, pyramid_m=args.pyramid_m, solver=args.solver,
                               settle_steps=args.settle_steps, close_open=args.close_open, grip=grip,
                               dtype=getattr(torch, args.dtype),
                               object_contacts=args.object_contacts, sdf_voxel=args.sdf_voxel,
                               finger_friction=args.finger_friction, device=args.device,
                               reach=ReachSettings(enabled=args.reach, rate=args.reach_rate, limit=args.reach_limit))
    if args.variants is not None:
        return _resynthesize_variant_file(args, settings)
    return _resynthesize_grid(args, settings)


def _resynthesize_grid(args, settings) -> int:
    """--mass, --compliance-scale and --friction: every combination, one result directory."""
    from torchhand.interaction.resynth import (_progress_line, expand_variants, load_interaction, prepare_result_dir,
                                               resynthesize, write_resynthesis)
    from torchhand.scene import load_scene

    variants = expand_variants(_floats(args.mass, "--mass"), _floats(args.compliance_scale, "--compliance-scale"),
                               _floats(args.friction, "--friction"))
    writer = prepare_result_dir(args.out, overwrite=args.overwrite)
    try:
        inter = load_interaction(args.interaction)
        scene = load_scene(args.scene)
        result = resynthesize(inter, scene, variants=variants, settings=settings, progress=_progress_line)
    except BaseException:
        writer.abandon()
        raise
    out = write_resynthesis(result, writer=writer)
    _print_rollouts(result, scene, [f"rollout {i}" for i in range(len(result.rollouts))])
    ok = sum(r.ok for r in result.rollouts)
    print(f"{ok}/{len(result.rollouts)} rollouts completed, {result.timings['per_step_ms']:.1f} ms per step; "
          f"wrote {out}")
    return 0 if ok else 1


def _resynthesize_variant_file(args, settings) -> int:
    """--variants FILE: the file's variants as rollouts of one batch, one result directory each (--out DIR/name);
    every directory is validated before the work."""
    from torchhand.interaction._variant_spec import load_variant_file
    from torchhand.interaction.resynth import (_progress_line, load_interaction, prepare_result_dir, resynthesize,
                                               write_resynthesis)
    from torchhand.scene import load_scene

    if args.mass is not None or args.friction is not None or args.compliance_scale.strip() != "1":
        raise InputValueError("--variants: give masses, frictions and compliance scales in the file, not with "
                              "--mass, --friction or --compliance-scale")
    inter = load_interaction(args.interaction)
    scene = load_scene(args.scene)
    named = load_variant_file(args.variants, scene)
    out = Path(args.out)
    created = not out.exists()
    writers = []
    try:
        for name, _ in named:
            writers.append(prepare_result_dir(out / name, overwrite=args.overwrite))
        result = resynthesize(inter, scene, variants=tuple(v for _, v in named), settings=settings,
                              progress=_progress_line)
    except BaseException:
        for w in writers:
            w.abandon()
        if created and out.is_dir() and not any(out.iterdir()):
            out.rmdir()                 # the folder this run made, left empty
        raise
    for i, w in enumerate(writers):
        write_resynthesis(result.variant_result(i), writer=w)
    _print_rollouts(result, scene, [name for name, _ in named])
    ok = sum(r.ok for r in result.rollouts)
    print(f"{ok}/{len(result.rollouts)} variants completed, {result.timings['per_step_ms']:.1f} ms per step "
          f"(one batch); wrote {len(writers)} result director{'y' if len(writers) == 1 else 'ies'} under {args.out}")
    return 0 if ok else 1


def _print_rollouts(result, scene, labels) -> None:
    for label, r in zip(labels, result.rollouts):
        v = r.variant
        obj = v.object_of(scene)
        line = (f"{label} ({obj.name}, mass {v.mass if v.mass is not None else obj.mass:g} kg, friction "
                f"{v.friction if v.friction is not None else scene.friction:g}, compliance x{v.compliance_scale:g}): ")
        if r.ok:
            print(line + f"max object slip {1e3 * r.object_slip.max():.1f} mm, {len(r.grip_events)} grip events, "
                  f"max |theta_err| {r.theta_err.max():.2e}")
        else:
            print(line + f"stopped at step {r.failed_step} ({r.failed_status}): {r.status.message}", file=sys.stderr)


def run_from_result(args) -> int:
    import numpy as np

    from torchhand.interaction.inferred import infer_interaction, prepare_inferred_dir, write_inferred

    apply_threads(args.threads)
    created = not Path(args.out).exists()
    out = prepare_inferred_dir(Path(args.out), overwrite=args.overwrite)
    try:
        inf = infer_interaction(args.result, solution=args.solution, frames=args.frames, compliance=args.compliance,
                                friction_margin=args.friction_margin)
    except BaseException:
        if created:
            shutil.rmtree(out, ignore_errors=True)   # the directory this run made, still empty
        raise
    write_inferred(inf, out)
    fmag = np.linalg.norm(inf.capture.force, axis=-1).sum(1)
    a, b = inf.frames
    print(f"solution {inf.solution}, frames {a}:{b} ({inf.T} at {inf.capture.fps:g} fps): "
          f"{inf.capture.num_sensors} force sensors, total force on the hand up to {fmag.max():.3g} N "
          f"(inferred), compliance {inf.compliance}; largest |theta - theta_r|: root "
          f"{np.abs(inf.theta - inf.theta_r)[:, :3].max():.3g} rad, joints "
          f"{np.abs(inf.theta - inf.theta_r)[:, 6:].max():.3g} rad")
    m = inf.margin
    if m is not None and m.margin < 1:
        print(f"friction margin {m.margin:g}: {m.resolved}/{m.frames} loaded frames re-solved for the same object "
              f"wrench ({m.kept} kept the solution's forces); largest |f_t| / (mu f_n) {m.use_before:.2f} before, "
              f"{m.use_resolved:.2f} in the re-solved frames, {m.use_after:.2f} in all")
    print(f"wrote {out / 'capture.npz'}, {out / 'interaction.npz'}, {out / 'scene'}/")
    return 0


def run_synthetic(args) -> int:
    import numpy as np

    from torchhand.interaction.mujoco_truth import TruthSettings, write_truth_capture

    settings = TruthSettings(task=args.task, rate=args.rate, noise_angle_deg=args.noise_angle_deg,
                             noise_force=args.noise_force, presses=args.presses, approach_speed=args.approach_speed)
    out = Path(args.out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise InputValueError(f"--out {out}: exists and is not an empty directory")
    from torchhand._atomic import writable_dir

    writable_dir(out)
    path, run = write_truth_capture(out, settings, np.random.default_rng(args.seed))
    print(f"wrote {path} ({run.capture.num_frames} frames at {settings.rate:g} Hz, {settings.presses} presses, "
          f"hand {out / run.capture.hand})")
    return 0
