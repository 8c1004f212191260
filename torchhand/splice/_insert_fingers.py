"""Giving a finger-less body the hand rig's fingers (:func:`insert_fingers`; the rule in
:mod:`torchhand.splice.retarget`, "Insertion"): the hand's size against the body's forearm, the finger subtree
grafted under the body's wrist with its offsets turned into the body's hand frame, the wrist's End Site removed,
and the body's rig extended by the new joints."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from ..errors import InputValueError
from ..scene.bvh import BVHClip
from ._hand_frame import _MIRROR, _check_choice, hand_frame
from ._rig_record import SIDES, Arm, Rig, _name_side
from .rig_hierarchy import rest_positions

__all__ = ["HAND_LENGTH", "FOREARM_LENGTH", "Inserted", "insert_fingers"]

HAND_LENGTH = 0.19
"""Wrist to middle-fingertip length of the reference hand, metres."""
FOREARM_LENGTH = 0.26
"""Elbow to wrist length of the reference forearm, metres (the inserted hand is scaled by forearm / this)."""


class Inserted(NamedTuple):
    """What :func:`insert_fingers` returns.

    clip: the body with the finger joints added (new columns zero)
    rig: the body's rig with that side's fingers, indices into ``clip``
    column_map: new column of each of the body's columns, (C_old,) int64
    """

    clip: BVHClip
    rig: Rig
    column_map: np.ndarray


def insert_fingers(body_clip: BVHClip, body_rig: Rig, side: str, hand_clip: BVHClip, hand_rig: Rig, *,
                   hand_handedness: str = "right", body_handedness: str = "right", up_axis: str | None = None
                   ) -> Inserted:
    """Add the hand rig's ``side`` finger subtree under the body's wrist (module docstring).

    Args:
        body_clip, body_rig: a body whose ``side`` has no finger joints (its arm needs an elbow or forearm joint)
        side: "right" or "left"
        hand_clip, hand_rig: the rig whose fingers are copied
        hand_handedness, body_handedness: "right", or "left" for a left-handed file
        up_axis: the body file's up axis for its hand frame ("y"/"z"), guessed from the trunk when None

    Returns:
        :class:`Inserted` (clip, rig, column_map)
    """
    _check_choice(side, "side", SIDES)
    _check_choice(hand_handedness, "hand_handedness", SIDES)
    _check_choice(body_handedness, "body_handedness", SIDES)
    barm = body_rig.arm(side)
    hand_rig.arm(side)                                           # the hand needs a wrist too
    if body_rig.has_fingers(side):
        raise InputValueError(f"side: {body_clip.path} already has {side}-hand finger joints; retarget onto them")
    if not hand_rig.has_fingers(side):
        raise InputValueError(f"side: {hand_clip.path} has no {side}-hand finger joints to insert")
    placement = _placement(body_clip, body_rig, side, hand_clip, hand_rig, hand_handedness=hand_handedness,
                           body_handedness=body_handedness, up_axis=up_axis)
    grown = _graft(body_clip, barm, side, hand_clip, hand_rig, placement)
    clip, idx = _drop_wrist_end_sites(body_clip, grown, barm.wrist)
    old2 = lambda i: idx[grown.old(i)]                           # noqa: E731
    pos2 = {k: idx[v] for k, v in grown.pos.items()}
    return Inserted(clip=clip, rig=_inserted_rig(body_rig, hand_rig, side, clip, old2, pos2),
                    column_map=grown.column_map)


@dataclass(frozen=True)
class _Placement:
    """How the hand's offsets enter the body: ``offset_body = scale * (rotation @ offset_hand)``.

    scale: body units per hand unit (module docstring of :mod:`torchhand.splice.retarget`, "Insertion")
    rotation: the hand rig's rest hand frame into the body's, handedness included (``Mb Hb Hhᵀ Mh``), (3, 3)
    """

    scale: float
    rotation: np.ndarray


@dataclass(frozen=True)
class _Grown:
    """The body with the finger subtree added after the wrist's subtree (the wrist's End Site still there).

    clip: the grown clip (new motion columns zero); column_map: new column of each body column, (C_old,) int64
    at: index of the first new joint; count: the number of new joints; pos: hand joint -> its index in ``clip``
    """

    clip: BVHClip
    column_map: np.ndarray
    at: int
    count: int
    pos: dict[int, int]

    def old(self, i: int) -> int:
        """The index in :attr:`clip` of the body's joint ``i``."""
        return i if i < self.at else i + self.count


def _placement(body_clip: BVHClip, body_rig: Rig, side: str, hand_clip: BVHClip, hand_rig: Rig, *,
               hand_handedness: str, body_handedness: str, up_axis: str | None) -> _Placement:
    """The hand's scale (wrist to middle fingertip = HAND_LENGTH x forearm / FOREARM_LENGTH) and frame change."""
    barm, harm = body_rig.arms[side], hand_rig.arms[side]
    brest = rest_positions(body_clip, body_handedness)
    hrest = rest_positions(hand_clip, hand_handedness)
    elbow = barm.elbow if barm.elbow is not None else barm.forearm
    forearm = float(np.linalg.norm(brest[barm.wrist] - brest[elbow])) if elbow is not None else 0.0
    if forearm <= 0:
        raise InputValueError(f"side: the {side} arm of {body_clip.path} has no elbow joint apart from its wrist "
                              "to size the hand by")
    tips = hand_rig.tips.get(side, {})
    tip = tips.get("middle")
    if tip is not None:
        hand_len = float(np.linalg.norm(hrest[tip] - hrest[harm.wrist]))
    else:
        hand_len = max(float(np.linalg.norm(hrest[t] - hrest[harm.wrist])) for t in tips.values())
    if hand_len <= 0:
        raise InputValueError(f"hand: cannot measure the hand of {hand_clip.path} (fingertips at the wrist)")
    scale = HAND_LENGTH / FOREARM_LENGTH * forearm / hand_len
    Hh = hand_frame(hand_clip, hand_rig, side, handedness=hand_handedness)
    Hb = hand_frame(body_clip, body_rig, side, handedness=body_handedness, up_axis=up_axis)
    Mh = _MIRROR if hand_handedness == "left" else np.eye(3)
    Mb = _MIRROR if body_handedness == "left" else np.eye(3)
    return _Placement(scale=scale, rotation=Mb @ Hb @ Hh.T @ Mh)


def _graft(body_clip: BVHClip, barm: Arm, side: str, hand_clip: BVHClip, hand_rig: Rig,
           placement: _Placement) -> _Grown:
    """Insert the hand's finger subtree after the body wrist's subtree: joints, offsets, rotation channels, zero
    motion columns."""
    harm = hand_rig.arms[side]
    scale, R = placement.scale, placement.rotation
    sub = _finger_subtree(hand_clip, hand_rig, side)
    new_names = _new_names(hand_clip, [k for k in sub if not hand_clip.is_end_site[k]], side, set(body_clip.names))
    at = max(_subtree(body_clip.parents, barm.wrist)) + 1
    N = len(sub)
    old = lambda i: i if i < at else i + N                       # noqa: E731
    pos = {k: at + n for n, k in enumerate(sub)}

    names, parents, offsets, channels, ends = [], [], [], [], []
    for k in sub:
        p = hand_clip.parents[k]
        if hand_clip.is_end_site[k]:
            names.append(new_names[p] + "_end")
        else:
            names.append(new_names[k])
        parents.append(barm.wrist if p == harm.wrist else pos[p])
        offsets.append(scale * (R @ hand_clip.offsets[k]))
        channels.append(tuple(c for c in hand_clip.channels[k] if c.endswith("rotation")))
        ends.append(hand_clip.is_end_site[k])
    bn, bp = list(body_clip.names), list(body_clip.parents)
    all_names = tuple(bn[:at] + names + bn[at:])
    all_parents = tuple([old(p) if p >= 0 else -1 for p in bp[:at]] + parents
                        + [old(p) if p >= 0 else -1 for p in bp[at:]])
    all_offsets = np.concatenate([body_clip.offsets[:at], np.asarray(offsets).reshape(-1, 3),
                                  body_clip.offsets[at:]])
    all_channels = tuple(list(body_clip.channels[:at]) + channels + list(body_clip.channels[at:]))
    all_ends = tuple(list(body_clip.is_end_site[:at]) + ends + list(body_clip.is_end_site[at:]))
    starts = body_clip.channel_start
    c_at = starts[at] if at < body_clip.num_joints else body_clip.motion.shape[1]
    c_new = sum(len(c) for c in channels)
    C = body_clip.motion.shape[1]
    column_map = np.arange(C, dtype=np.int64)
    column_map[c_at:] += c_new
    motion = np.zeros((body_clip.num_frames, C + c_new), dtype=np.float64)
    motion[:, column_map] = body_clip.motion
    all_offsets.setflags(write=False)
    motion.setflags(write=False)
    column_map.setflags(write=False)
    clip = replace(body_clip, names=all_names, parents=all_parents, offsets=all_offsets, channels=all_channels,
                   is_end_site=all_ends, motion=motion)
    return _Grown(clip=clip, column_map=column_map, at=at, count=N, pos=pos)


def _drop_wrist_end_sites(body_clip: BVHClip, grown: _Grown, wrist: int) -> tuple[BVHClip, dict[int, int]]:
    """The grown clip without the wrist's End Site, and each joint's index in it (grown index -> new index).

    The wrist's End Site (a finger-less rig's hand bone) would now run through the palm: the fingers say where
    the hand ends. End Sites have no channels, so the motion columns do not move."""
    clip = grown.clip
    drop = {grown.old(j) for j in body_clip.children(wrist) if body_clip.is_end_site[j]}
    keep = [i for i in range(clip.num_joints) if i not in drop]
    idx = {o: n for n, o in enumerate(keep)}
    offs = np.ascontiguousarray(clip.offsets[keep])
    offs.setflags(write=False)
    clip = replace(clip, names=tuple(clip.names[i] for i in keep),
                   parents=tuple(idx[clip.parents[i]] if clip.parents[i] >= 0 else -1 for i in keep),
                   offsets=offs, channels=tuple(clip.channels[i] for i in keep),
                   is_end_site=tuple(clip.is_end_site[i] for i in keep))
    return clip, idx


def _subtree(parents, j: int) -> list[int]:
    out = [j]
    for k in range(j + 1, len(parents)):
        if parents[k] in out:
            out.append(k)
    return out


def _finger_subtree(clip: BVHClip, rig: Rig, side: str) -> list[int]:
    """The wrist's child subtrees that hold the side's finger joints or tips, hierarchy order."""
    w = rig.arms[side].wrist
    wanted = set(rig.fingers[side].values()) | set(rig.tips.get(side, {}).values())
    out = []
    for c in (k for k in range(clip.num_joints) if clip.parents[k] == w):
        sub = _subtree(clip.parents, c)
        if wanted & set(sub):
            out += sub
    return sorted(out)


def _new_names(clip: BVHClip, joints: list[int], side: str, taken: set[str]) -> dict[int, str]:
    out = {}
    for k in joints:
        n = clip.names[k]
        if _name_side(n) is None:
            n = ("R_" if side == "right" else "L_") + n
        while n in taken or n + "_end" in taken:
            n += "_hand"
        taken.add(n)
        out[k] = n
    return out


def _inserted_rig(body: Rig, hand: Rig, side: str, clip: BVHClip, old, pos: dict[int, int]) -> Rig:
    arms = {s: Arm(side=a.side, shoulder=_opt(old, a.shoulder), elbow=_opt(old, a.elbow), wrist=old(a.wrist),
                   trunk=_opt(old, a.trunk), forearm=_opt(old, a.forearm)) for s, a in body.arms.items()}
    fingers = {s: {k: old(j) for k, j in d.items()} for s, d in body.fingers.items()}
    tips = {s: {k: old(j) for k, j in d.items()} for s, d in body.tips.items()}
    fingers[side] = {k: pos[j] for k, j in hand.fingers[side].items()}
    tips[side] = {k: pos[j] for k, j in hand.tips.get(side, {}).items() if j in pos}
    how = dict(body.how)
    how[f"{side} fingers"] = f"inserted from {hand.name}"
    return Rig(name=f"{body.name}+{hand.name}", arms=arms, fingers=fingers, tips=tips, names=clip.names,
               parents=clip.parents, is_end_site=clip.is_end_site, how=how)


def _opt(f, j: int | None) -> int | None:
    return None if j is None else f(j)
