"""``torchhand manipulate SCENE --out DIR``: hand motion that realises the scene's object motion from a grasping pose
(Liu 2009, "Dextrous manipulation from a grasping pose").

For every frame the contact forces of a short window are planned (Sec. 4; contacts are added when the grasp cannot
produce the required wrench), then the hand pose, the wrist and the contact points of that frame are synthesized so
that the hand's torques stay close to those of the grasp (Sec. 5). SCENE is a scene directory (its ``grasp.npz`` is
used unless ``--grasp`` names another) or a built-in scene name (its shipped grasp when it has one, otherwise
``--grasp`` is required). The grasp belongs to the first frame of the (``--frames``) range. A scene's
``external_wrench`` (docs/scene_format.md) is part of the wrench the contacts must balance.

Two hands: give ``--grasp`` once per hand (each file names its side), or keep ``grasp.npz`` (the scene's first hand)
and ``grasp_<side>.npz`` (the other) in the scene directory; the built-in ``liu-two-hand-lift`` ships both. Both
hands' contacts share one force plan; ``torque_right`` and ``torque_left`` hold each hand's torques.

Writes DIR/scene/ (with the synthesized wrist), DIR/hand.xml, DIR/solutions/sol_000.npz (with ``torque``,
``torque_rest`` and ``contact_added``) and DIR/stats.json (``method: "liu2009"``) (docs/result_format.md,
docs/manipulation.md). When the grasp cannot realise the motion at frame k (counted from the first manipulated
frame), exit 1 with one line giving k and the wrench deficit; the frames synthesized before it are written as a
valid result with ``complete: false`` and ``status: "grasp_unsuitable"`` in stats.json (nothing when there are
none). Every frame runs to a stationary merit within ``--max-iters`` iterations and says whether it converged
(stats.json ``sqp_converged``, ``frames_converged``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import InputValueError
from ._common import Progress, add_threads_argument, apply_threads


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("manipulate", help="hand motion for an object motion from a grasping pose (Liu 2009)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene", help="a scene directory (with grasp.npz) or a built-in scene name (its shipped grasp, "
                                 "or --grasp)")
    p.add_argument("--grasp", metavar="GRASP.npz", action="append",
                   help="the grasp (default: SCENE/grasp.npz); give it once per hand for two hands")
    p.add_argument("--out", required=True, help="output directory: new, empty, or an earlier result with --overwrite "
                                                "(checked before any work)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing result directory")
    p.add_argument("--window", type=int, default=6, help="frames per planning window, n (default 6; 5-10 work)")
    p.add_argument("--max-force", type=float, default=30.0, metavar="N",
                   help="normal-force limit of each hand contact, newtons (default 30)")
    p.add_argument("--no-objective", action="store_true",
                   help="ablation: minimise |q - q_prev|^2 instead of the torque deviation |u - u_bar|^2")
    p.add_argument("--frames", metavar="A:B", help="manipulate frames A <= t < B of the scene only")
    p.add_argument("--dynamics", choices=("quasi-static", "full"), default="quasi-static",
                   help="the objective's torques: quasi-static (default) or full, with the hand's M q_ddot + C by "
                        "backward differences (the stored torques are Eq. 5 in full either way)")
    p.add_argument("--sliding", action="store_true",
                   help="hand contacts may slide (Liu's rule: a planned force on the friction cone's boundary); "
                        "default: static")
    p.add_argument("--max-iters", type=int, default=30, metavar="K",
                   help="Gauss-Newton iterations per frame before polishing (the work budget; default 30)")
    add_threads_argument(p)
    p.add_argument("--no-progress", action="store_true", help="no progress lines")
    p.set_defaults(func=run)


def _builtin_grasp(name: str) -> Path | None:
    """The grasp shipped with the built-in scene ``name`` (``torchhand.scene.builtin.liu.grasp_path``), or None."""
    try:
        from ..scene.builtin import liu
    except ImportError:
        return None
    find = getattr(liu, "grasp_path", None)
    path = find(name) if callable(find) else None
    return None if path is None else Path(path)


def _packaged_grasp(name: str) -> tuple:
    """(the grasp shipped with the built-in scene ``name``, its hand resolved; a tuple for two hands), and its
    files (``torchhand.scene.builtin.liu``)."""
    from ..manipulation.grasp import load_packaged_grasp
    from ..scene.builtin.liu import grasp_paths

    return load_packaged_grasp(name), grasp_paths(name)


def _grasp_paths(scene_arg: str, grasp: list | None) -> list[Path]:
    """The grasp files: ``--grasp`` (once per hand), else the scene directory's ``grasp.npz`` and its
    ``grasp_right.npz`` / ``grasp_left.npz``, else the built-in scene's packaged grasp."""
    if grasp:
        if len(grasp) > 2:
            raise InputValueError(f"--grasp: at most two (one per hand), got {len(grasp)}")
        return [Path(g) for g in grasp]
    d = Path(scene_arg)
    if d.is_dir() and (d / "scene.toml").is_file():
        return [d / "grasp.npz"] + [d / f"grasp_{side}.npz" for side in ("right", "left")
                                    if (d / f"grasp_{side}.npz").is_file()]
    builtin = _builtin_grasp(scene_arg)
    if builtin is not None:
        return [builtin]
    raise InputValueError(f"--grasp: required for the built-in scene '{scene_arg}' (a scene directory uses its "
                          f"grasp.npz); make one with 'torchhand grasp'")


def run(args) -> int:
    from ..manipulation import load_grasp
    from ..manipulation.manipulate import (GraspUnsuitable, ManipulationSettings, manipulate, prepare_output,
                                           write_manipulation)
    from ..manipulation.plan import PlanSettings
    from ..manipulation.synth import SynthSettings
    from ..scene import load_scene
    from .synthesize_cmd import _frames

    if args.window < 1:
        raise InputValueError(f"--window: expected an integer >= 1, got {args.window}")
    if not args.max_force > 0:
        raise InputValueError(f"--max-force: expected a positive number of newtons, got {args.max_force:g}")
    threads = apply_threads(args.threads)
    grasp_files = _grasp_paths(args.scene, args.grasp)
    writer = prepare_output(args.out, overwrite=args.overwrite)      # before any work
    try:
        scene = load_scene(args.scene)
        if args.frames:
            scene = scene.with_frames(*_frames(args.frames, scene.T))
        if args.window > scene.T:
            raise InputValueError(f"--window: expected at most the {scene.T} frames of the motion, got {args.window}")
        packaged = not args.grasp and grasp_files == [_builtin_grasp(args.scene)]
        if packaged:
            grasp, grasp_files = _packaged_grasp(args.scene)
        else:
            grasps = [load_grasp(f) for f in grasp_files]
            grasp = grasps[0] if len(grasps) == 1 else grasps
        grasp_file = str(grasp_files[0]) if len(grasp_files) == 1 else [str(f) for f in grasp_files]
        settings = ManipulationSettings(
            plan=PlanSettings(window=args.window, max_contact_force=args.max_force),
            synth=SynthSettings(objective="pose" if args.no_objective else "torque", dynamics=args.dynamics,
                                sliding=args.sliding, max_iters=args.max_iters))
    except BaseException:
        writer.abandon()
        raise
    bar = Progress("manipulate", disable=args.no_progress)
    try:
        result = manipulate(scene, grasp, settings,
                            progress=lambda k, T, s: bar.update("frames", f"{k + 1}/{T}, {s:.1f} s", (k + 1) / T))
    except GraspUnsuitable as err:
        bar.close()
        where = "nothing written"
        if err.partial is None:
            writer.abandon()
        else:
            out = write_manipulation(err.partial, writer=writer, unsuitable=err, grasp_file=grasp_file,
                                     threads=threads)
            where = f"frames 0-{err.partial.T - 1} written to {out} (stats.json: complete false)"
        print(f"torchhand: grasp unsuitable for this motion at frame {err.frame}: {_deficit(err)}; {where}",
              file=sys.stderr)
        return 1
    except BaseException:
        bar.close()
        writer.abandon()
        raise
    bar.close()
    out = write_manipulation(result, writer=writer, grasp_file=grasp_file, threads=threads)
    t = result.timings["total_s"]
    print(f"{scene.name}: {result.T} frames in {t:.1f} s ({result.T / t:.1f} frames/s), {result.num_added} contact(s) "
          f"added; wrote {out}/scene/, {out}/hand.xml, {out}/stats.json, {out}/solutions/sol_000.npz")
    return 0


def _deficit(err) -> str:
    """The wrench deficit of a :class:`GraspUnsuitable`, in words."""
    import numpy as np

    d = err.deficit
    return (f"the contacts ({', '.join(err.contacts) or '-'}) lack {np.linalg.norm(d[:3]):.3f} N and "
            f"{np.linalg.norm(d[3:]):.4f} N m of the required wrench (force "
            f"{np.array2string(d[:3], precision=3)} N, torque {np.array2string(d[3:], precision=4)} N m)")
