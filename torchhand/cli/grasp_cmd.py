"""``torchhand grasp``: make a grasp file (``grasp.npz``, docs/manipulation.md) for manipulation from a grasping pose.

* ``torchhand grasp from-result RESULT --solution N --frame F --out FILE``: the hand pose of a ``torchhand
  synthesize`` result at frame F;
* ``torchhand grasp from-qpos MJCF --qpos FILE --scene SCENE --frame F --out FILE``: an MJCF hand at a qpos vector
  (``.npy`` or ``.txt``), on the scene's object at frame F.

Both snap the grasp onto the object (``--snap-tol``, default 5 mm) and print the snap distances; the file is
written atomically and an existing one is refused unless ``--overwrite``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import InputValueError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("grasp", help="make a grasp file (grasp.npz) for manipulation from a grasping pose",
                       description="Make a grasp.npz (docs/manipulation.md): a hand pose on an object, snapped onto "
                                   "the object's surface.")
    gs = p.add_subparsers(dest="grasp_command", metavar="ACTION")
    gs.required = True

    r = gs.add_parser("from-result", help="the hand pose of a `torchhand synthesize` result at one frame",
                      description="Take q, the wrist pose and the object pose of a result's solution at a frame.")
    r.add_argument("result", help="result directory of `torchhand synthesize`")
    r.add_argument("--solution", type=int, default=0, help="solution index (default 0)")
    r.add_argument("--side", choices=["right", "left"], default=None, help="hand side (default: the first hand)")
    _common(r)
    r.set_defaults(func=_from_result)

    m = gs.add_parser("from-qpos", help="an MJCF hand at a MuJoCo qpos vector on a scene's object",
                      description="Map a MuJoCo qpos vector of an MJCF hand onto its joints by name; a free joint "
                                  "gives the root pose; the object pose is the scene's at --frame.")
    m.add_argument("mjcf", help="the hand's MJCF file (the model the qpos belongs to)")
    m.add_argument("--qpos", required=True, help="the model's qpos vector (.npy or .txt)")
    m.add_argument("--scene", required=True, help="built-in scene name or scene directory")
    m.add_argument("--side", choices=["right", "left"], default=None, help="hand side (default: the scene's first)")
    _common(m)
    m.set_defaults(func=_from_qpos)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--frame", type=int, required=True, help="frame of the motion the grasp is taken at")
    p.add_argument("--out", required=True, help="output grasp file (.npz)")
    p.add_argument("--snap-tol", type=float, default=0.005,
                   help="links within this distance of the object (metres) become contacts (default 0.005)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")


def _check_out(args) -> Path:
    out = Path(args.out)
    if out.exists() and not args.overwrite:
        raise InputValueError(f"--out {out} exists; pass --overwrite to replace it")
    if out.is_dir():
        raise InputValueError(f"--out {out} is a directory; give a file name such as grasp.npz")
    return out


def _finish(grasp, scene, args) -> int:
    from ..manipulation import make_grasp, save_grasp

    snapped, report = make_grasp(grasp, scene, tol=args.snap_tol)
    save_grasp(snapped, Path(args.out), overwrite=args.overwrite)
    for line in report.lines():
        print(f"snap: {line}")
    print(f"wrote {args.out}: {snapped.side} hand {snapped.hand!r}, frame {snapped.frame}, "
          f"{snapped.num_contacts} contact(s)")
    return 0


def _from_result(args) -> int:
    from ..manipulation import grasp_from_result

    _check_out(args)
    grasp, scene = grasp_from_result(args.result, solution=args.solution, frame=args.frame, side=args.side)
    return _finish(grasp, scene, args)


def _from_qpos(args) -> int:
    from ..manipulation import grasp_from_qpos, read_qpos
    from ..scene import load_scene

    _check_out(args)
    scene = load_scene(args.scene)
    grasp = grasp_from_qpos(args.mjcf, read_qpos(args.qpos), scene, frame=args.frame, side=args.side)
    return _finish(grasp, scene, args)
