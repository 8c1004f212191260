"""``torchhand hand``: inspect hand models, draw them, and export them as MJCF."""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

from ..errors import InputValueError, MissingFileError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("hand", help="inspect or draw a hand model, or export it as MJCF",
                       description="Inspect the default 36-DOF hand or a hand loaded from MJCF or URDF: print how "
                                   "the file was read, draw it, or export it as MJCF.")
    hs = p.add_subparsers(dest="hand_command", metavar="ACTION")
    hs.required = True

    show = hs.add_parser("show", help="print how a hand was read: palm, thumb, side, joints, mount, fingers, masses",
                         description="Print a hand model: its palm link, thumb and side, the root joints (root .. "
                                     "palm, locked when mounted on a wrist track), every joint with its limits "
                                     "(hinges in degrees, slides in metres), the mount (hand frame), couplings, the "
                                     "fingers (links, flexion joints, fingertip at the rest pose) and link masses "
                                     "(kg, centre of mass in the link frame).")
    _path_arg(show)
    _source_args(show)
    show.set_defaults(func=_show)

    render = hs.add_parser("render", help="draw the hand as a PNG: surface samples per finger, fingertips, palm, "
                                          "hand frame",
                           description="Draw a hand model at its rest pose (or q = 0) as a PNG with three views "
                                       "(the palm, the thumb's side, the fingertips): surface samples coloured per "
                                       "finger (palm and other links grey), each fingertip pad labelled with its "
                                       "finger, the palm link's origin, and the hand frame's axes (x red, y green, "
                                       "z blue). Matplotlib, no display needed.")
    _path_arg(render)
    _source_args(render)
    render.add_argument("--out", default="hand.png", help="output PNG path (written atomically; default hand.png)")
    render.add_argument("--q", choices=["rest", "zero"], default="rest",
                        help="pose drawn: the model's rest pose (default) or q = 0 clamped to the limits")
    render.set_defaults(func=_render)

    exp = hs.add_parser("export-mjcf", help="write the hand as MJCF (root body with a free joint)",
                        description="Write a hand model as an MJCF file that MuJoCo loads; the root body carries a "
                                    "free joint so qpos = (root position, root quaternion wxyz, q).")
    _source_args(exp)
    exp.add_argument("out", help="output .xml path (written atomically)")
    exp.set_defaults(func=_export)


def _path_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("path", nargs="?", metavar="PATH", help="MJCF (.xml) or URDF (.urdf) hand file (default: the "
                                                           "built-in hand, --side and --length)")


def _source_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--side", choices=["right", "left"], default="right", help="default hand's side (default right)")
    p.add_argument("--length", type=float, default=0.19, help="default hand's length in metres (default 0.19)")
    p.add_argument("--mjcf", help="load this MJCF (or URDF) hand instead of the default one")


def _file_arg(args) -> str | None:
    path, mjcf = getattr(args, "path", None), args.mjcf
    if path and mjcf and Path(path) != Path(mjcf):
        raise InputValueError(f"PATH {path} and --mjcf {mjcf}: give the hand file once")
    return path or mjcf


def _load(args):
    from ..hand import HandModel, default_hand

    path = _file_arg(args)
    if path:
        if not os.path.isfile(path):
            what = "PATH" if getattr(args, "path", None) else "--mjcf"
            raise MissingFileError(f"{what}: file not found: {path}")
        return HandModel.from_file(path)
    return default_hand(args.side, args.length)


def _limits(hand, d: int) -> str:
    lo, hi = (float(v) for v in hand.joint_limits[d])
    if int(hand.chain.joint_type[d]) == 0:
        return f"[{math.degrees(lo):7.1f}, {math.degrees(hi):7.1f}] deg"
    return f"[{lo:7.4f}, {hi:7.4f}] m"


def _joint_line(hand, d: int) -> str:
    link = hand.link_names[int(hand.chain.joint_link[d])]
    kind = "hinge" if int(hand.chain.joint_type[d]) == 0 else "slide"
    return f"  {d:2d} {hand.joint_names[d]:<18} {kind:<5} on {link:<18} {_limits(hand, d)}"


def _show(args) -> int:
    hand = _load(args)
    from_file = _file_arg(args) is not None
    print(f"hand {hand.name}: side {hand.side}, length {hand.length:.3f} m, {hand.num_links} links, "
          f"{hand.num_joints} joints (+6 root DOF), {hand.num_fingers} fingers, "
          f"{hand.sample_points.shape[0]} surface samples, {hand.collision_pairs.shape[0]} finger-finger pairs")
    _print_reading(hand, from_file)
    print("joints:")
    for d in range(hand.num_joints):
        print(_joint_line(hand, d))
    _print_mount(hand, _file_arg(args))
    _print_couplings(hand)
    _print_fingers(hand)
    print(f"links (total mass {float(hand.link_mass.sum()):.4f} kg; {_mass_source(args, hand)}):")
    for l, name in enumerate(hand.link_names):
        com = ", ".join(f"{1000 * float(v):6.1f}" for v in hand.link_com[l])
        print(f"  {l:2d} {name:<18} {1000 * float(hand.link_mass[l]):9.2f} g   com ({com}) mm")
    return 0


def _root_links(hand) -> list[int]:
    """Links from the root to the palm (both included), root first."""
    from ..hand.mount import _shared_links, palm_link

    palm = palm_link(hand)
    return sorted(_shared_links(hand) | {palm}, key=lambda l: _depth(hand, l))


def _depth(hand, link: int) -> int:
    parents, n = hand.chain.link_parent.tolist(), 0
    while parents[link] >= 0:
        link, n = parents[link], n + 1
    return n


def _print_reading(hand, from_file: bool) -> None:
    from ..hand.mount import palm_link, thumb_index

    palm = palm_link(hand)
    print(f"palm: {hand.link_names[palm]} (link {palm}, the link the fingers branch from)")
    th = thumb_index(hand)
    print(f"thumb: {'none found' if th is None else repr(hand.finger_names[th]) + f' (finger {th})'}")
    print(f"side: {hand.side}" + (" (from the thumb's position)" if from_file else " (built-in hand, --side)"))
    root = _root_links(hand)
    joints = [d for d in range(hand.num_joints) if int(hand.chain.joint_link[d]) in root]
    print(f"root joints (on the links {' > '.join(hand.link_names[l] for l in root)}; locked at q_rest when "
          f"mounted on a wrist track):" + ("" if joints else " none"))
    for d in joints:
        print(_joint_line(hand, d))


def _print_mount(hand, path: str | None) -> None:
    from ..hand.mount import hand_frame, load_sidecar, sidecar_frame, sidecar_path

    try:
        F = hand_frame(hand)
    except InputValueError as err:
        print(f"mount: no hand frame: {err}")
        return
    print("mount (hand frame in the root link's parent frame, at q = 0):")
    _print_frame(F)
    if path is not None and load_sidecar(path).get("mount"):
        print(f"  the sidecar {sidecar_path(path)} overrides it with:")
        _print_frame(sidecar_frame(load_sidecar(path), F))


def _print_frame(F) -> None:
    def v(a, scale=1.0):
        return "(" + ", ".join(f"{scale * float(c):7.3f}" for c in a) + ")"

    print(f"  origin {v(F[:3, 3], 1000.0)} mm   x {v(F[:3, 0])}   y {v(F[:3, 1])}")


def _print_couplings(hand) -> None:
    if not hand.couplings:
        print("couplings: none")
        return
    print("couplings (reported only; every joint moves freely within its limits):")
    for c in hand.couplings:
        print(f"  {c.kind:<8} {c.name:<18} {', '.join(c.joints)}")


def _print_fingers(hand) -> None:
    import torch

    from ..hand.mount import thumb_index

    T = hand.forward_kinematics(hand.q_rest.unsqueeze(0))[0]
    distal = hand.distal_link
    tips = (T[distal, :3, :3] @ hand.fingertip.to(T.dtype).unsqueeze(-1)).squeeze(-1) + T[distal, :3, 3]
    th = thumb_index(hand)
    print("fingers (links; flexion joints; fingertip pad at q_rest in the root link's parent frame, mm):")
    for f, name in enumerate(hand.finger_names):
        links = [hand.link_names[int(i)] for i in hand.finger_links[f] if int(i) >= 0]
        flex = [hand.joint_names[int(j)] for j in hand.flexion_joints[f] if int(j) >= 0]
        tip = ", ".join(f"{1000 * float(c):7.1f}" for c in tips[f].to(torch.float64))
        label = f"{name} (thumb)" if f == th and name != "thumb" else name
        print(f"  {label:<12} {' > '.join(links)}")
        print(f"  {'':<12} flexion {', '.join(flex) or 'none'}; tip ({tip}) mm")


def _mass_source(args, hand) -> str:
    if _file_arg(args):
        return "the file's inertial elements, or its geoms as MuJoCo computes them"
    from ..hand.default import HAND_MASS_FRACTION, REFERENCE_BODY_MASS

    return (f"{HAND_MASS_FRACTION:.3f} of a {REFERENCE_BODY_MASS:.0f} kg body at 0.19 m, scaled with length^3, "
            "split by collision volume (Winter 2009, Table 4.1)")


def _render(args) -> int:
    from ._hand_figure import write_hand_png

    out = Path(args.out)
    folder = out.parent if str(out.parent) else Path(".")
    if not folder.is_dir():
        raise MissingFileError(f"--out {out}: folder not found: {folder}")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InputValueError(f"--out {out}: cannot write in {folder}")
    hand = _load(args)
    write_hand_png(hand, out, pose=args.q)
    print(f"wrote {out} ({hand.name}, {hand.side}, q = {args.q})")
    return 0


def _export(args) -> int:
    from ..hand.mjcf import save_mjcf

    hand = _load(args)
    out = Path(args.out)
    save_mjcf(hand, out)
    print(f"wrote {out} ({hand.num_joints} joints, root body {hand.link_names[0]!r} with a free joint)")
    return 0
