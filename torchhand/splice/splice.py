"""Splicing a separately captured hand onto a body capture, end to end (Majkowska et al. 2006).

``splice(body, hand, ...)`` recognises both rigs, makes the virtual markers of one arm in each clip, aligns them
in time (:func:`torchhand.splice.align.align`), resamples the hand clip's finger joints (and, with
``wrist="hand"``, its wrist) at the aligned hand time of every body frame, carries those rotations onto the
body's finger joints (:mod:`torchhand.splice.retarget`, with each segment's rest direction lined up, so rigs whose
rest poses differ, such as ManipNet's thumb folded across the palm, still show the source's finger directions; a
body without fingers first gets the hand rig's finger joints under its wrist) and returns the body clip with only
those channels changed, at the body's frame rate and with the body's hierarchy.

Matching points are pairs (body frame, hand frame) (0-based); with ``tolerance`` T (hand frames, Eq. 5) the
path passes within T of each. They are honoured by both passes and the final time map is corrected to show
hand frame y_k (within T) at body frame x_k (``torchhand.splice.align``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np
import torch

from ..scene.bvh import BVHClip
from ..errors import InputValueError
from torchhand.kernels.status import SolverStatus
from .align import Alignment, SpliceSettings, align
from .markers import ArmJoints, Markers, guess_units, guess_up_axis, virtual_markers
from .retarget import insert_fingers, retarget_fingers
from .retime import local_rotations, retime_motion, rotations_to_channels
from .rigs import Rig, detect_rig

__all__ = ["SpliceResult", "splice", "arm_joints", "clip_axes", "ClipAxes"]

MIN_FPS, MAX_FPS = 10.0, 1000.0
"""Frame rates outside this range are refused (a ``Frame Time`` in the wrong unit, most likely)."""


@dataclass(frozen=True)
class ClipAxes:
    """How to read one clip: metres per file unit, up axis ("y"/"z"), handedness ("right"/"left")."""

    units: float | None = None
    up: str | None = None
    handedness: str = "right"


@dataclass(frozen=True)
class SpliceResult:
    """What :func:`splice` returns.

    clip: the spliced body clip (body hierarchy, plus inserted finger joints when the body had none)
    alignment: the time alignment (one pair: B = 1)
    body_rig, hand_rig: the recognised rigs (body_rig of the output clip)
    matches: per carried joint (finger, ordinal, hand joint, body joint)
    report: everything else worth writing down (JSON-ready)
    """

    clip: BVHClip
    alignment: Alignment
    body_rig: Rig
    hand_rig: Rig
    matches: tuple
    report: dict = field(default_factory=dict)


def clip_axes(clip: BVHClip, rig: Rig, side: str, axes: ClipAxes | None = None) -> tuple[float, str]:
    """Units (metres per file unit) and up axis of ``clip``: given ones, else guessed (markers module)."""
    axes = axes or ClipAxes()
    joints = arm_joints(clip, rig, side)
    up = axes.up or guess_up_axis(clip, *_head_hips(clip, rig))
    units = axes.units if axes.units is not None else guess_units(clip, joints)
    return units, up


def _head_hips(clip: BVHClip, rig: Rig) -> tuple[int | None, int | None]:
    arm = next(iter(rig.arms.values()), None)
    if arm is None or arm.shoulder is None:
        return None, None
    root = clip.parents.index(-1)
    return arm.shoulder, root


def arm_joints(clip: BVHClip, rig: Rig, side: str) -> ArmJoints:
    """The marker joints of ``side``'s arm from a recognised rig."""
    if side not in rig.arms:
        raise InputValueError(f"side: {clip.path} has no {side} arm in rig '{rig.name}' "
                              f"(arms: {', '.join(rig.arms) or 'none'})")
    arm = rig.arms[side]
    w = arm.wrist
    forearm = getattr(arm, "forearm", None)
    if forearm is None:
        forearm = arm.elbow if arm.elbow is not None else (clip.parents[w] if clip.parents[w] >= 0 else None)
    fingers = rig.fingers.get(side, {})
    hand_point = fingers.get(("middle", 1))
    if hand_point is None:
        kids = clip.children(w)
        hand_point = kids[0] if kids else None
    return ArmJoints(wrist=w, forearm=forearm, elbow=arm.elbow, shoulder=arm.shoulder, trunk=arm.trunk,
                     hand_point=hand_point)


def _check_clip(clip: BVHClip, what: str) -> None:
    if not (MIN_FPS <= clip.fps <= MAX_FPS):
        raise InputValueError(f"{what}: frame rate {clip.fps:.4g} fps of {clip.path} is outside "
                              f"{MIN_FPS:.0f}-{MAX_FPS:.0f} fps (Frame Time {clip.frame_time:.6g} s)")
    if clip.motion.shape[1] == 0 or np.ptp(clip.motion, axis=0).max() == 0.0:
        raise InputValueError(f"{what}: no motion in {clip.path} (every channel constant): nothing to align")
    dur = (clip.num_frames - 1) * clip.frame_time
    if clip.num_frames < 5 or dur < 1.0:
        raise InputValueError(f"{what}: {clip.path} is too short to align ({clip.num_frames} frames, {dur:.2f} s; "
                              "at least 5 frames and 1 s)")


def splice(body: BVHClip, hand: BVHClip, *, side: str = "right", settings: SpliceSettings = SpliceSettings(),
           body_rig: str = "auto", hand_rig: str = "auto", body_axes: ClipAxes | None = None,
           hand_axes: ClipAxes | None = None, matches: list[tuple[int, int]] | None = None,
           wrist: str = "body", progress=None) -> SpliceResult:
    """Splice ``hand``'s fingers onto ``body`` (module docstring).

    Args:
        body, hand: the two clips
        side: "right" or "left", the arm to align and the fingers to carry
        settings: alignment settings
        body_rig, hand_rig: "auto", a rig name or a TOML map path (``torchhand.splice.rigs.detect_rig``)
        body_axes, hand_axes: units / up axis / handedness of each file (guessed when None)
        matches: matching points (body frame, hand frame), 0-based, strictly increasing in both
        wrist: "body" keeps the body's wrist; "hand" takes the hand clip's wrist rotation relative to its forearm
        progress: optional callable(str) told about each stage

    Returns:
        :class:`SpliceResult`
    """
    if side not in ("right", "left"):
        raise InputValueError(f"side: expected 'right' or 'left', got {side!r}")
    if wrist not in ("body", "hand"):
        raise InputValueError(f"wrist: expected 'body' or 'hand', got {wrist!r}")
    say = progress or (lambda s: None)
    t_start = time.perf_counter()
    clips = _prepare(body, hand, side, wrist, body_rig, hand_rig, body_axes or ClipAxes(), hand_axes or ClipAxes(),
                     say)
    timed = _align_clips(clips, matches, settings, say)
    say("resampling and retargeting")
    carried = _carry(clips, timed.alignment, side, wrist)
    report = _report(clips, timed, carried, side=side, wrist=wrist, settings=settings, matches=matches,
                     t_start=t_start)
    return SpliceResult(clip=carried.clip, alignment=timed.alignment, body_rig=carried.rig, hand_rig=clips.hand_rig,
                        matches=carried.matches, report=report)


@dataclass(frozen=True)
class _Clips:
    """The two clips read for alignment: the clips, their rigs and axes (``units`` metres per file unit, ``up``
    axis), and the virtual markers of the arm being spliced (:class:`~torchhand.splice.markers.Markers`)."""

    body: BVHClip
    hand: BVHClip
    body_rig: Rig
    hand_rig: Rig
    body_axes: ClipAxes
    hand_axes: ClipAxes
    body_units: float
    body_up: str
    hand_units: float
    hand_up: str
    body_markers: Markers
    hand_markers: Markers


@dataclass(frozen=True)
class _Timed:
    """The alignment of the two clips (one pair), its pass-1 status and the seconds it took."""

    alignment: Alignment
    status: int
    seconds: float


@dataclass(frozen=True)
class _Carried:
    """The body clip with the hand's finger rotations: the clip and its rig (fingers inserted when the body had
    none: ``column_map`` then maps the body's columns, else None) and the carried joints."""

    clip: BVHClip
    rig: Rig
    column_map: np.ndarray | None
    matches: tuple


def _prepare(body: BVHClip, hand: BVHClip, side: str, wrist: str, body_rig: str, hand_rig: str,
             body_axes: ClipAxes, hand_axes: ClipAxes, say) -> _Clips:
    """Both clips checked, their rigs recognised, units and up axes found, and the arm's virtual markers."""
    _check_clip(body, "body")
    _check_clip(hand, "hand")
    brig = detect_rig(body, body_rig)
    hrig = detect_rig(hand, hand_rig)
    if not hrig.fingers.get(side):
        raise InputValueError(f"hand: {hand.path} has no {side}-hand finger joints (rig '{hrig.name}'); "
                              "give --hand-map or check --side")
    if wrist == "hand" and getattr(hrig.arms.get(side), "forearm", None) is None:
        raise InputValueError(f"wrist: rig '{hrig.name}' of {hand.path} has no forearm joint above its {side} wrist, "
                              "so its wrist rotation is not relative to a forearm; use --wrist body")
    bu, bup = clip_axes(body, brig, side, body_axes)
    hu, hup = clip_axes(hand, hrig, side, hand_axes)
    say("markers")
    mb = virtual_markers(body, arm_joints(body, brig, side), units_scale=bu, up_axis=bup,
                         handedness=body_axes.handedness)
    mh = virtual_markers(hand, arm_joints(hand, hrig, side), units_scale=hu, up_axis=hup,
                         handedness=hand_axes.handedness)
    return _Clips(body=body, hand=hand, body_rig=brig, hand_rig=hrig, body_axes=body_axes, hand_axes=hand_axes,
                  body_units=bu, body_up=bup, hand_units=hu, hand_up=hup, body_markers=mb, hand_markers=mh)


def _align_clips(clips: _Clips, matches, settings: SpliceSettings, say) -> _Timed:
    """The two-pass alignment of the markers (one pair); InputValueError when pass 1 finds none."""
    mb, mh = clips.body_markers, clips.hand_markers
    n, m = mb.num_frames, mh.num_frames
    anchors = None
    if matches:
        _check_matches(matches, n, m)
        anchors = torch.tensor([list(p) for p in matches], dtype=torch.long).unsqueeze(0)
    say("alignment")
    t0 = time.perf_counter()
    al = align(mb.markers[None], mh.markers[None], body_fps=mb.fps, hand_fps=mh.fps,
               body_shoulder=_opt(mb.shoulder), body_trunk=_opt(mb.trunk), hand_shoulder=_opt(mh.shoulder),
               hand_trunk=_opt(mh.trunk), anchors=anchors, settings=settings)
    t_align = time.perf_counter() - t0
    status = int(al.status[0])
    if status != int(SolverStatus.CONVERGED):
        if matches and status == int(SolverStatus.INVALID_INPUT):
            raise InputValueError(f"match: the matching points {matches} cannot be honoured (out of range or "
                                  "not increasing)")
        raise InputValueError(
            f"no alignment within the band: hand {(m - 1) / mh.fps:.1f} s vs body {(n - 1) / mb.fps:.1f} s"
            + (f" with matching points {matches}" if matches else "")
            + "; widen --band1, add or loosen --match, or trim the clips")
    return _Timed(alignment=al, status=status, seconds=t_align)


def _carry(clips: _Clips, al: Alignment, side: str, wrist: str) -> _Carried:
    """The hand's finger (and, with ``wrist="hand"``, wrist) rotations resampled at the aligned hand time and
    carried onto the body's finger joints (inserted first when the body has none)."""
    body, hand, brig, hrig = clips.body, clips.hand, clips.body_rig, clips.hand_rig
    out_clip, out_rig = body, brig
    column_map = None
    if not brig.fingers.get(side):
        ins = insert_fingers(body, brig, side, hand, hrig, hand_handedness=clips.hand_axes.handedness,
                             body_handedness=clips.body_axes.handedness, up_axis=clips.body_up)
        out_clip, out_rig, column_map = ins.clip, ins.rig, ins.column_map
    hand_joints = sorted(set(hrig.finger_joints(side)) | ({hrig.arms[side].wrist} if wrist == "hand" else set()))
    hand_motion = retime_motion(hand, al.hand_frame[0].numpy(), joints=hand_joints)
    R_hand = local_rotations(hand, hand_motion)                                  # (n, Jh, 3, 3)
    carried = retarget_fingers(hand, hrig, out_clip, out_rig, side, R_hand,
                               src_handedness=clips.hand_axes.handedness,
                               dst_handedness=clips.body_axes.handedness,
                               include_wrist=(wrist == "hand"), align_rest=True)
    rotations, matched = carried.rotations, carried.matches
    motion = rotations_to_channels(out_clip, np.array(out_clip.motion), rotations)
    motion.setflags(write=False)
    return _Carried(clip=replace(out_clip, motion=motion), rig=out_rig, column_map=column_map,
                    matches=tuple(matched))


def _report(clips: _Clips, timed: _Timed, carried: _Carried, *, side: str, wrist: str, settings: SpliceSettings,
            matches, t_start: float) -> dict:
    """``report.json`` of the splice (JSON-ready)."""
    body, hand, mb, mh, al = clips.body, clips.hand, clips.body_markers, clips.hand_markers, timed.alignment
    n, m = mb.num_frames, mh.num_frames
    hand_frame = al.hand_frame[0].numpy()
    speed = np.gradient(hand_frame / mh.fps, 1.0 / mb.fps) if n > 1 else np.ones(1)
    return {
        "body": body.path, "hand": hand.path, "side": side,
        "body_rig": clips.body_rig.name, "hand_rig": clips.hand_rig.name,
        "body_frames": n, "hand_frames": m, "body_fps": mb.fps, "hand_fps": mh.fps,
        "body_units_m": clips.body_units, "hand_units_m": clips.hand_units, "body_up": clips.body_up,
        "hand_up": clips.hand_up,
        "body_handedness": clips.body_axes.handedness, "hand_handedness": clips.hand_axes.handedness,
        "features": settings.features, "passes": settings.passes,
        "band1": settings.band1, "band2": settings.band2,
        "band1_hand_frames": al.band1_frames, "band2_frames": al.band2_frames,
        "matches": [list(p) for p in (matches or [])], "tolerance_frames": settings.tolerance,
        "pass1_status": SolverStatus(timed.status).name,
        "pass2_used": bool(al.pass2_used[0]), "pass2_note": al.pass2_note[0],
        "hand_yaw_deg": math.degrees(float(al.yaw[0])),
        "local_speed_range": [float(speed.min()), float(speed.max())],
        "longest_hold_s": _longest_flat(hand_frame) / mb.fps,
        "fingers_inserted": carried.column_map is not None,
        "wrist": wrist,
        "joints_carried": [[m.finger, m.ordinal, m.src, m.dst] for m in carried.matches],
        "seconds_alignment": timed.seconds, "seconds_total": time.perf_counter() - t_start,
    }


def _opt(x: torch.Tensor | None) -> torch.Tensor | None:
    return None if x is None else x[None]


def _check_matches(matches, n: int, m: int) -> None:
    prev = (-1, -1)
    for b, h in matches:
        if not (0 <= b < n - 1) or not (0 <= h < m):
            raise InputValueError(f"match: {b}:{h} is outside the clips (body frames 0..{n - 2}, hand frames "
                                  f"0..{m - 1})")
        if b <= prev[0] or h <= prev[1]:
            raise InputValueError(f"match: {prev[0]}:{prev[1]} then {b}:{h}: matching points must increase in "
                                  "both clips")
        prev = (b, h)


def _longest_flat(frames: np.ndarray) -> int:
    """Longest run of body frames showing (almost) the same hand frame."""
    if len(frames) < 2:
        return 0
    flat = np.abs(np.diff(frames)) < 1e-3
    best = run = 0
    for f in flat:
        run = run + 1 if f else 0
        best = max(best, run)
    return best
