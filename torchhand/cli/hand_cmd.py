"""``torchhand hand``: inspect hand models and export them as MJCF."""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

from ..errors import MissingFileError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("hand", help="inspect a hand model or export it as MJCF",
                       description="Inspect the default 36-DOF hand or a hand loaded from MJCF; export MJCF.")
    hs = p.add_subparsers(dest="hand_command", metavar="ACTION")
    hs.required = True

    show = hs.add_parser("show", help="print links, joints, limits, fingers and masses",
                         description="Print a hand model's joints (with limits in degrees), fingers and link masses "
                                     "(kg, centre of mass in the link frame).")
    _source_args(show)
    show.set_defaults(func=_show)

    exp = hs.add_parser("export-mjcf", help="write the hand as MJCF (root body with a free joint)",
                        description="Write a hand model as an MJCF file that MuJoCo loads; the root body carries a "
                                    "free joint so qpos = (root position, root quaternion wxyz, q).")
    _source_args(exp)
    exp.add_argument("out", help="output .xml path (written atomically)")
    exp.set_defaults(func=_export)


def _source_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--side", choices=["right", "left"], default="right", help="default hand's side (default right)")
    p.add_argument("--length", type=float, default=0.19, help="default hand's length in metres (default 0.19)")
    p.add_argument("--mjcf", help="load this MJCF hand instead of the default one")


def _load(args):
    from ..hand import HandModel, default_hand

    if args.mjcf:
        if not os.path.exists(args.mjcf):
            raise MissingFileError(f"--mjcf: file not found: {args.mjcf}")
        return HandModel.from_mjcf(args.mjcf)
    return default_hand(args.side, args.length)


def _show(args) -> int:
    hand = _load(args)
    print(f"hand {hand.name}: side {hand.side}, length {hand.length:.3f} m, {hand.num_links} links, "
          f"{hand.num_joints} joints (+6 root DOF), {hand.num_fingers} fingers, "
          f"{hand.sample_points.shape[0]} surface samples, {hand.collision_pairs.shape[0]} finger-finger pairs")
    print("joints:")
    for d, name in enumerate(hand.joint_names):
        lo, hi = (math.degrees(float(v)) for v in hand.joint_limits[d])
        link = hand.link_names[int(hand.chain.joint_link[d])]
        kind = "hinge" if int(hand.chain.joint_type[d]) == 0 else "slide"
        print(f"  {d:2d} {name:<18} {kind:<5} on {link:<18} [{lo:7.1f}, {hi:7.1f}] deg")
    print("fingers:")
    for f, name in enumerate(hand.finger_names):
        links = [hand.link_names[int(i)] for i in hand.finger_links[f] if int(i) >= 0]
        print(f"  {name:<8} {' > '.join(links)}")
    print(f"links (total mass {float(hand.link_mass.sum()):.4f} kg; {_mass_source(args, hand)}):")
    for l, name in enumerate(hand.link_names):
        com = ", ".join(f"{1000 * float(v):6.1f}" for v in hand.link_com[l])
        print(f"  {l:2d} {name:<18} {1000 * float(hand.link_mass[l]):9.2f} g   com ({com}) mm")
    return 0


def _mass_source(args, hand) -> str:
    if args.mjcf:
        return "the MJCF's <inertial> elements, or its geoms as MuJoCo computes them"
    from ..hand.default import HAND_MASS_FRACTION, REFERENCE_BODY_MASS

    return (f"{HAND_MASS_FRACTION:.3f} of a {REFERENCE_BODY_MASS:.0f} kg body at 0.19 m, scaled with length^3, "
            "split by collision volume (Winter 2009, Table 4.1)")


def _export(args) -> int:
    from ..hand.mjcf import save_mjcf

    hand = _load(args)
    out = Path(args.out)
    save_mjcf(hand, out)
    print(f"wrote {out} ({hand.num_joints} joints, root body {hand.link_names[0]!r} with a free joint)")
    return 0
