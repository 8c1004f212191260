"""Carrying finger rotations from one rig to another, and giving a finger-less body the hand rig's fingers.

Rule (:func:`retarget_fingers`)
    In a BVH every joint's frame is aligned with the file's axes in the rest pose (every channel zero), so a
    joint's local channel rotation ``L`` (``R(ch1) @ R(ch2) @ R(ch3)``, :mod:`torchhand.scene.bvh`) is its rotation away
    from rest, expressed in the rest axes. It is re-expressed in each rig's canonical hand frame at rest,
    ``H`` (columns: hand axes x, y, z in the file's rest coordinates, :func:`hand_frame`):
    ``Δ = Hsᵀ Ls Hs`` and ``Lt = Ht Δ Htᵀ`` on the destination joint with the same (finger, ordinal)
    (:mod:`torchhand.splice.rigs` for ordinals). A left-handed file (ManipNet) is mirrored first
    (``M L M``, ``M = diag(-1, 1, 1)``, its rest positions too) and a left-handed destination is mirrored back.
    In one step: ``Lt = A Ls Aᵀ`` with ``A = Mt Ht Hsᵀ Ms``.

    Chains that differ: for each destination joint with a role the source also has, the source path is every
    joint from the previous role both rigs share (or the wrist) down to that role's joint. When the destination
    path between the same two roles has as many joints, they are paired one to one (ManipNet onto ManipNet:
    ``THUMB_CMC_FE`` and ``THUMB_CMC_AA`` each onto itself); otherwise the source path's rotations are composed
    (``L_a @ L_b``, parent first) onto the destination role's joint. So a source metacarpal (MB-Lab ``index00``)
    is carried into the destination's proximal joint when the destination has none, and ManipNet's two CMC
    joints become one CMC rotation on a three-joint thumb. Destination joints without a source counterpart (a
    metacarpal the source lacks, ``THUMB_CMC_FE`` when the source has one CMC joint, tip joints) are left out of
    the result and keep the destination's values; when those values are not the rest pose they add to the
    carried rotation.

    ``include_wrist``: the wrist's rotation relative to its forearm joint is carried the same way (both rigs
    need a forearm joint, and both rest poses are taken to hold the hand in line with the forearm).

    What is preserved: the rotation of every carried joint relative to the hand, in the hand frame, equals the
    source's (up to the destination's unmatched joints). Segment directions then agree up to each rig's rest
    difference: the angle between corresponding segments in the posed hands equals their angle at rest. Rigs
    whose rest poses differ a lot keep that difference: ManipNet's rest thumb points back toward the wrist, 161
    and 139 degrees away from the Mixamo and CMU rest thumbs, so its carried thumb is folded on those rigs.

Rest alignment (``align_rest=True``, an option; the rule above is the default)
    Per carried joint d, ``C_d`` is the smallest rotation (hand coordinates) taking d's rest segment direction
    (toward the next carried joint of its finger, or its tip) onto the source's; ``Lt = Ht C_pᵀ Δ C_d Htᵀ``, p the
    carried joint above d (``C_p = I`` at the wrist; a segment without length in either rig keeps ``C_p``). Then
    every posed segment points where the source's does, relative to the hand frame, while twist about the segment
    follows the minimal rotation. Identical rigs get ``C = I``, i.e. the default rule.

Insertion (:func:`insert_fingers`)
    A body without finger joints gets the hand rig's finger subtree under its wrist: every joint and End Site
    of the wrist's child chains that hold fingers, with the joints' rotation channels (position channels are
    dropped) and zero motion (the rest pose; the caller fills the rotations). Offsets are rotated from the hand
    rig's rest hand frame into the body's (``Mb Hb Hhᵀ Mh``, handedness included) and scaled so that the wrist
    to middle-fingertip length (to the middle finger's End Site, or its last joint) equals
    ``HAND_LENGTH * forearm / FOREARM_LENGTH`` = 0.19 m x (the body's forearm length / 0.26 m), which also
    converts the hand's units into the body's. The body, having no fingers, gets its hand frame from the fallback
    rule of :func:`torchhand.scene.mocap.hand_frame_rotation` (x from the wrist to its child or End Site, the back of
    the hand up for a horizontal arm, outward for a hanging one), so the inserted hand continues the forearm.

    The wrist's End Site, if it has one (the hand bone of a finger-less rig), is removed: it would run through the
    palm. Hierarchy order: the new joints follow the wrist's existing subtree, so
    joint indices remain a depth-first order, parents precede children, and ``motion``'s columns follow the
    joints in index order as :attr:`BVHClip.channel_start` assumes. Joints after the insertion point shift by the
    number of new joints; ``column_map[c]`` is the new column of the body's column ``c``. Names: the hand's names,
    prefixed ``R_``/``L_`` when they carry no side (ManipNet), with ``_hand`` appended on a clash with a body name.

Modules: ``_hand_frame`` (:func:`hand_frame`), ``_insert_fingers`` (:func:`insert_fingers`); this module matches
the joints of two rigs and carries the rotations.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch

from ..errors import InputTypeError, InputValueError, ShapeError
from ..scene.bvh import BVHClip
from ._hand_frame import _MIRROR, _check_choice, hand_frame
from ._insert_fingers import FOREARM_LENGTH, HAND_LENGTH, Inserted, insert_fingers
from ._rig_record import SIDES, Rig
from .rig_hierarchy import FINGERS, rest_positions

__all__ = ["Match", "Retargeted", "Inserted", "HAND_LENGTH", "FOREARM_LENGTH", "hand_frame", "finger_matches",
           "retarget_fingers", "insert_fingers"]


class Match(NamedTuple):
    """One carried joint: finger ("thumb".."pinky", or "wrist" with ordinal 0), ordinal, source joint name
    (names joined by "+" when a path is composed), destination joint name."""

    finger: str
    ordinal: int
    src: str
    dst: str


class Retargeted(NamedTuple):
    """What :func:`retarget_fingers` returns.

    rotations: destination joint index -> local rotations, (F, 3, 3), dtype and device of the input
    matches: the carried joints, in destination hierarchy order
    """

    rotations: dict[int, torch.Tensor]
    matches: list[Match]


# ---------------------------------------------------------------------------------------------------------------
# matching


def _path(parents, j: int, stop: int) -> list[int] | None:
    """Joints from ``stop`` (exclusive) down to ``j`` (inclusive), parent first; None if ``stop`` is not above."""
    out = [j]
    k = parents[j]
    while k >= 0 and k != stop:
        out.append(k)
        k = parents[k]
    return out[::-1] if k == stop else None


def _plan(src_rig: Rig, dst_rig: Rig, side: str, include_wrist: bool) -> list[tuple[int, list[int], Match]]:
    """(destination joint, source path, match) for every carried destination joint, destination order."""
    sa, da = src_rig.arm(side), dst_rig.arm(side)
    sf, df = src_rig.fingers.get(side, {}), dst_rig.fingers.get(side, {})
    if not sf:
        raise InputValueError(f"side: the source rig '{src_rig.name}' has no {side}-hand finger joints")
    if not df:
        raise InputValueError(f"side: the destination rig '{dst_rig.name}' has no {side}-hand finger joints; "
                              "insert the hand rig's fingers first (insert_fingers)")
    out = []
    sn, dn = src_rig.names, dst_rig.names
    if include_wrist:
        if sa.forearm is None or da.forearm is None:
            which = src_rig if sa.forearm is None else dst_rig
            raise InputValueError(f"include_wrist: rig '{which.name}' has no forearm joint above its {side} wrist, "
                                  "so its wrist rotation is not relative to a forearm")
        out += _pair(src_rig.parents, dst_rig.parents, sa.wrist, sa.forearm, da.wrist, da.forearm, "wrist", 0, sn, dn)
    for f in FINGERS:
        shared = sorted(o for (ff, o) in df if ff == f and (f, o) in sf)
        prev = -1
        for o in shared:
            s_stop = sa.wrist if prev < 0 else sf[(f, prev)]
            d_stop = da.wrist if prev < 0 else df[(f, prev)]
            out += _pair(src_rig.parents, dst_rig.parents, sf[(f, o)], s_stop, df[(f, o)], d_stop, f, o, sn, dn)
            prev = o
    out.sort(key=lambda t: t[0])
    return out


def _pair(sp, dp, s_joint, s_stop, d_joint, d_stop, finger, ordinal, sn, dn):
    s_path = _path(sp, s_joint, s_stop) or [s_joint]
    d_path = _path(dp, d_joint, d_stop) or [d_joint]
    if len(s_path) == len(d_path):
        return [(d, [s], Match(finger, ordinal, sn[s], dn[d])) for s, d in zip(s_path, d_path)]
    return [(d_joint, s_path, Match(finger, ordinal, "+".join(sn[s] for s in s_path), dn[d_joint]))]


def finger_matches(src_rig: Rig, dst_rig: Rig, side: str, *, include_wrist: bool = False) -> list[Match]:
    """The joints :func:`retarget_fingers` carries (module docstring), in destination hierarchy order."""
    return [m for _, _, m in _plan(src_rig, dst_rig, side, include_wrist)]


# ---------------------------------------------------------------------------------------------------------------
# retargeting


def retarget_fingers(src_clip: BVHClip, src_rig: Rig, dst_clip: BVHClip, dst_rig: Rig, side: str,
                     src_local: torch.Tensor, *, src_handedness: str = "right", dst_handedness: str = "right",
                     include_wrist: bool = False, align_rest: bool = False) -> Retargeted:
    """Carry ``side``'s finger rotations from the source rig onto the destination rig (module docstring).

    Args:
        src_clip, src_rig: the source clip (its rest pose) and its rig
        dst_clip, dst_rig: the destination clip (its rest pose) and its rig
        side: "right" or "left"
        src_local: the source's local joint rotations, (F, Js, 3, 3), Js = src_clip.num_joints (file axes)
        src_handedness, dst_handedness: "right", or "left" for a left-handed file (ManipNet)
        include_wrist: also carry the wrist's rotation relative to its forearm joint
        align_rest: also remove the rigs' rest-pose difference per segment (module docstring, "Rest alignment")

    Returns:
        :class:`Retargeted`: destination joint -> local rotations (F, 3, 3) in the destination's file axes, and
        the matches
    """
    _check_choice(side, "side", SIDES)
    _check_choice(src_handedness, "src_handedness", SIDES)
    _check_choice(dst_handedness, "dst_handedness", SIDES)
    if not isinstance(src_local, torch.Tensor):
        raise InputTypeError(f"src_local: expected a torch.Tensor, got {type(src_local).__name__}")
    Js = src_clip.num_joints
    if src_local.ndim != 4 or tuple(src_local.shape[1:]) != (Js, 3, 3):
        raise ShapeError(f"src_local: expected shape (F, {Js}, 3, 3) for {src_clip.path}, got "
                         f"{tuple(src_local.shape)}")
    plan = _plan(src_rig, dst_rig, side, include_wrist)
    Hs = hand_frame(src_clip, src_rig, side, handedness=src_handedness)
    Ht = hand_frame(dst_clip, dst_rig, side, handedness=dst_handedness)
    Ms = _MIRROR if src_handedness == "left" else np.eye(3)
    Mt = _MIRROR if dst_handedness == "left" else np.eye(3)
    if align_rest:
        C_own, C_par = _rest_alignment(plan, src_clip, src_rig, dst_clip, dst_rig, side, Hs, Ht, src_handedness,
                                       dst_handedness)
    else:
        C_own = C_par = {d: np.eye(3) for d, _, _ in plan}
    rotations = {}
    for d, s_path, _ in plan:
        L = src_local[:, s_path[0]]
        for s in s_path[1:]:
            L = L @ src_local[:, s]
        left = src_local.new_tensor(Mt @ Ht @ C_par[d].T @ Hs.T @ Ms)
        right = src_local.new_tensor(Ms @ Hs @ C_own[d] @ Ht.T @ Mt)
        rotations[d] = left @ L @ right
    return Retargeted(rotations=rotations, matches=[m for _, _, m in plan])


def _rest_alignment(plan, src_clip, src_rig, dst_clip, dst_rig, side, Hs, Ht, src_hand, dst_hand):
    """Per carried destination joint d: C_own[d], the minimal rotation (hand coordinates) taking d's rest
    segment direction onto the source's, and C_par[d], the same for d's carried parent (identity at the wrist)."""
    rs, rt = rest_positions(src_clip, src_hand) @ Hs, rest_positions(dst_clip, dst_hand) @ Ht
    ts, tt = src_rig.tips.get(side, {}), dst_rig.tips.get(side, {})
    C_own, C_par = {}, {}
    for finger in FINGERS + ("wrist",):
        entries = [(d, p[-1]) for d, p, m in plan if m.finger == finger]
        prev = np.eye(3)
        for n, (d, s) in enumerate(entries):
            C_par[d] = prev
            if finger == "wrist":
                C_own[d] = prev
                continue
            if n + 1 < len(entries):
                d_next, s_next = entries[n + 1]
            else:
                d_next, s_next = tt.get(finger, d), ts.get(finger, s)
            C_own[d] = prev = _min_rotation(rt[d_next] - rt[d], rs[s_next] - rs[s], prev)
    return C_own, C_par


def _min_rotation(a: np.ndarray, b: np.ndarray, default: np.ndarray) -> np.ndarray:
    """The smallest rotation taking direction ``a`` onto ``b``, (3, 3); ``default`` when either has no length."""
    na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    if na < 1e-9 * max(nb, 1.0) or nb < 1e-9 * max(na, 1.0):
        return default
    a, b = a / na, b / nb
    v, c = np.cross(a, b), float(a @ b)
    if c < -1.0 + 1e-12:                                 # opposite: half a turn about any normal of a
        n = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        n = n / np.linalg.norm(n)
        return 2.0 * np.outer(n, n) - np.eye(3)
    K = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + K + K @ K / (1.0 + c)
