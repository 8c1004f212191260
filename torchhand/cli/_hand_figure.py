"""The figure of ``torchhand hand render``: a hand model drawn from three sides as a PNG (matplotlib's Agg canvas,
no display needed).

Views, in the hand frame (:func:`torchhand.hand.mount.hand_frame`: ``+x`` along the fingers, ``+z`` out of the
back of the hand, ``+y`` toward the thumb on a right hand): looking at the palm (from ``-z``, fingers up), from the
thumb's side, and from the fingertips (back of the hand up). A hand without a hand frame is drawn along its root
link's parent axes instead. Lengths in millimetres from the hand frame's origin (or the palm link's origin).
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import torch

from .._atomic import atomic_bytes
from ..errors import InputValueError

__all__ = ["hand_geometry", "write_hand_png"]

_GREY = (0.55, 0.55, 0.55)
_LIGHT = (0.84, 0.84, 0.84)
_AXIS_COLOURS = ("tab:red", "tab:green", "tab:blue")


def hand_geometry(hand, pose: str = "rest") -> dict:
    """Points of ``hand`` at ``pose`` ("rest" or "zero": q = 0 clamped), in the root link's parent frame, metres.

    Returns a dict: points (S, 3), point_finger (S,) (-1 for the palm and other links, -2 for the links between
    the root and the palm: an arm, a wrist), tips (F, 3), palm (3,), frame (4, 4) hand frame or None, frame_error
    (str, "" when there is a frame).
    """
    from ..hand.mount import _shared_links, hand_frame, palm_link

    m = hand.to(device="cpu", dtype=torch.float64)
    if pose == "rest":
        q = m.q_rest.unsqueeze(0)
    elif pose == "zero":
        q = m.clamp_to_limits(torch.zeros(1, m.num_joints, dtype=torch.float64))
    else:
        raise InputValueError(f"--q: expected rest or zero, got {pose!r}")
    T = m.forward_kinematics(q)[0].numpy()                                   # (L, 4, 4)
    Ts = T[m.sample_link.numpy()]
    points = np.einsum("sab,sb->sa", Ts[:, :3, :3], m.sample_points.numpy()) + Ts[:, :3, 3]
    distal = m.distal_link.numpy()
    tips = np.einsum("fab,fb->fa", T[distal, :3, :3], m.fingertip.numpy()) + T[distal, :3, 3]
    try:
        frame, error = hand_frame(m), ""
    except InputValueError as err:
        frame, error = None, str(err)
    link_finger = m.link_finger.numpy().copy()
    palm = palm_link(m)
    for link in _shared_links(m) - {palm}:
        link_finger[link] = -2
    return {"points": points, "point_finger": link_finger[m.sample_link.numpy()], "tips": tips,
            "palm": T[palm, :3, 3], "frame": frame, "frame_error": error}


def _views(geo: dict, side: str) -> tuple[np.ndarray, np.ndarray, list]:
    """(origin, R, views): coordinates ``(p - origin) @ R``; each view (title, h, v, depth, labels), h, v and depth
    a (signed axis index) pair (index, sign) into the rotated coordinates, depth growing toward the viewer; labels
    "radial" (away from the palm) or "row" (alternately below and above, for tips side by side)."""
    if geo["frame"] is not None:
        F = geo["frame"]
        t = -1.0 if side == "left" else 1.0           # the thumb lies on +y for a right hand, on -y for a left one
        views = [("palm (from -z, fingers up)", (1, 1.0), (0, 1.0), (2, -1.0), "radial"),
                 ("thumb's side (back of the hand " + ("right)" if t > 0 else "left)"), (2, t), (0, 1.0), (1, t),
                  "radial"),
                 ("fingertips (from +x, back of the hand up)", (1, 1.0), (2, 1.0), (0, 1.0), "row")]
        return F[:3, 3], F[:3, :3], views
    views = [("root x-y (from +z)", (0, 1.0), (1, 1.0), (2, 1.0), "radial"),
             ("root y-z (from +x)", (1, 1.0), (2, 1.0), (0, 1.0), "radial"),
             ("root z-x (from +y)", (2, 1.0), (0, 1.0), (1, 1.0), "radial")]
    return geo["palm"], np.eye(3), views


def _project(geo: dict, origin, R, view) -> dict:
    """Screen coordinates (mm) of one view: proj (a function of points), h, v, depth of the samples, tips (th, tv),
    palm (ph, pv), and the box (hmin, hmax, vmin, vmax) of the hand (palm and fingers, not an arm), with margins."""
    _, (hi, hs), (vi, vs), (di, ds), _ = view

    def proj(p):
        c = (np.atleast_2d(p) - origin) @ R * 1000.0
        return hs * c[:, hi], vs * c[:, vi], ds * c[:, di]

    h, v, d = proj(geo["points"])
    th, tv, _ = proj(geo["tips"])
    ph, pv, _ = proj(geo["palm"])
    hand_pts = geo["point_finger"] >= -1
    box_h, box_v = [h[hand_pts], th, ph, [0.0]], [v[hand_pts], tv, pv, [0.0]]
    if geo["frame"] is not None:                  # the hand frame's arrows (_draw_axes)
        F = geo["frame"]
        eh, ev, _ = proj(F[:3, 3] + _axis_length(geo) * F[:3, :3].T)
        box_h, box_v = box_h + [eh], box_v + [ev]
    box_h, box_v = np.concatenate(box_h), np.concatenate(box_v)
    margin = 0.12 * max(float(np.ptp(box_h)), float(np.ptp(box_v)), 1.0)
    box = (box_h.min() - margin, box_h.max() + margin, box_v.min() - margin, box_v.max() + margin)
    return {"proj": proj, "h": h, "v": v, "d": d, "th": th, "tv": tv, "ph": ph, "pv": pv, "box": box}


def _finger_colour(f: int):
    from matplotlib import colormaps

    return colormaps["tab10"](f % 10) if f >= 0 else (_GREY if f == -1 else _LIGHT)


def _tip_label(hand, f: int, thumb: int | None) -> str:
    name = hand.finger_names[f]
    if f == thumb and name != "thumb":
        return f"thumb ({name})"
    return name


def _draw_view(ax, hand, geo: dict, pr: dict, view, thumb) -> None:
    """One view: surface samples far to near, fingertips labelled, the palm's origin, the hand frame's axes; the
    view is limited to the hand (palm and fingers), an arm or a wrist below the palm drawn light and cut off."""
    order = np.argsort(pr["d"])
    colours = np.array([_finger_colour(int(f))[:3] for f in geo["point_finger"]])
    ax.scatter(pr["h"][order], pr["v"][order], s=3, c=colours[order], linewidths=0)
    th, tv, ph, pv = pr["th"], pr["tv"], pr["ph"], pr["pv"]
    for f in range(hand.num_fingers):
        ax.plot(th[f], tv[f], marker="*", ms=11, mfc=_finger_colour(f), mec="black", mew=0.8, zorder=5)
    hmin, hmax, vmin, vmax = pr["box"]
    groups = sorted(_tip_groups(th, tv, 0.04 * max(hmax - hmin, vmax - vmin)), key=lambda g: th[g].mean())
    for k, members in enumerate(groups):
        at = np.array([th[members].mean(), tv[members].mean()])
        if view[4] == "row":
            away = np.array([0.0, -1.0 if k % 2 == 0 else 1.0])
        else:
            away = at - np.array([ph[0], pv[0]])
            away = away / max(float(np.linalg.norm(away)), 1e-9)
        colour = _finger_colour(members[0]) if len(members) == 1 else "black"
        ax.annotate(" / ".join(_tip_label(hand, f, thumb) for f in members), tuple(at), xytext=tuple(away * 9.0),
                    textcoords="offset points", fontsize=8, zorder=6, **_alignment(away),
                    bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": colour, "alpha": 0.85})
    ax.plot(ph, pv, marker="X", ms=9, color="black", zorder=5)
    ax.annotate("palm", (ph[0], pv[0]), xytext=(-7, -9), textcoords="offset points", ha="right", fontsize=8,
                zorder=6)
    if geo["frame"] is not None:
        _draw_axes(ax, geo["frame"], pr["proj"], _axis_length(geo))
    ax.set_xlim(hmin, hmax)
    ax.set_ylim(vmin, vmax)
    ax.set_title(view[0], fontsize=10)
    ax.set_aspect("equal", adjustable="box")
    ax.grid(True, lw=0.3, alpha=0.5)
    ax.set_xlabel("mm", fontsize=8)
    ax.tick_params(labelsize=7)


def _axis_length(geo: dict) -> float:
    """Length of the hand frame's arrows: a quarter of the hand's extent, at least 2 cm."""
    return max(0.25 * float(np.ptp(geo["points"][geo["point_finger"] >= -1], axis=0).max()), 0.02)


def _alignment(away) -> dict:
    """Text alignment that puts a label on the side of its point that ``away`` points to."""
    ha = "center" if abs(away[0]) < 0.4 else ("left" if away[0] > 0 else "right")
    va = "center" if abs(away[1]) < 0.4 else ("bottom" if away[1] > 0 else "top")
    return {"ha": ha, "va": va}


def _tip_groups(h, v, radius: float) -> list[list[int]]:
    """Fingertips that lie within ``radius`` of a group's first tip in this view share one label."""
    groups: list[list[int]] = []
    for f in range(len(h)):
        for g in groups:
            if np.hypot(h[f] - h[g[0]], v[f] - v[g[0]]) < radius:
                g.append(f)
                break
        else:
            groups.append([f])
    return groups


def _draw_axes(ax, F, proj, length: float) -> None:
    oh, ov, _ = proj(F[:3, 3])
    for k, (name, colour) in enumerate(zip("xyz", _AXIS_COLOURS)):
        eh, ev, _ = proj(F[:3, 3] + length * F[:3, k])
        if np.hypot(eh[0] - oh[0], ev[0] - ov[0]) < 1e-3 * length * 1000.0:       # pointing at the viewer
            ax.plot(oh, ov, marker="o", ms=6, mfc="none", mec=colour, zorder=7)
            continue
        ax.annotate("", (eh[0], ev[0]), (oh[0], ov[0]), zorder=7,
                    arrowprops={"arrowstyle": "-|>", "color": colour, "lw": 1.8})
        ax.annotate(name, (eh[0], ev[0]), xytext=(3, 3), textcoords="offset points", color=colour, fontsize=9,
                    fontweight="bold", zorder=7)


def _legend(fig, hand, thumb) -> None:
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], ls="", marker="o", color=_finger_colour(f), label=_tip_label(hand, f, thumb))
               for f in range(hand.num_fingers)]
    handles.append(Line2D([], [], ls="", marker="o", color=_GREY, label="palm / other links"))
    handles.append(Line2D([], [], ls="", marker="o", color=_LIGHT, label="root .. palm (arm, wrist)"))
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8, frameon=False)


def hand_figure(hand, pose: str = "rest"):
    """The matplotlib Figure of ``hand`` at ``pose`` (module docstring)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from ..hand.mount import thumb_index

    geo = hand_geometry(hand, pose)
    origin, R, views = _views(geo, hand.side)
    thumb = thumb_index(hand)
    projected = [_project(geo, origin, R, view) for view in views]
    fig = Figure(figsize=(15, 6.2), dpi=100)
    FigureCanvasAgg(fig)
    widths = [pr["box"][1] - pr["box"][0] for pr in projected]          # one scale (mm per inch) in every view
    axes = fig.subplots(1, len(views), gridspec_kw={"width_ratios": widths})
    for ax, view, pr in zip(axes, views, projected):
        _draw_view(ax, hand, geo, pr, view, thumb)
    frame = ("hand frame: x red, y green, z blue; mm from its origin" if geo["frame"] is not None
             else f"no hand frame ({geo['frame_error']}); mm from the palm link's origin")
    fig.suptitle(f"{hand.name}: {hand.side} hand, {hand.num_links} links, {hand.num_joints} joints, "
                 f"{hand.num_fingers} fingers, {geo['points'].shape[0]} surface samples; q = {pose}\n{frame}",
                 fontsize=11)
    _legend(fig, hand, thumb)
    fig.subplots_adjust(left=0.04, right=0.99, top=0.86, bottom=0.13, wspace=0.18)
    return fig


def write_hand_png(hand, out, pose: str = "rest") -> Path:
    """Draw ``hand`` (:func:`hand_figure`) into the PNG ``out``, atomically (a temporary file in the same folder,
    then ``os.replace``). Raises InputValueError when the file cannot be written."""
    out = Path(out)
    buf = io.BytesIO()
    hand_figure(hand, pose).savefig(buf, format="png")
    try:
        atomic_bytes(out, buf.getvalue())
    except OSError as err:
        raise InputValueError(f"--out {out}: cannot write it ({err.strerror or err})") from None
    return out
