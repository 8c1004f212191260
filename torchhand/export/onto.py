"""Fingers back onto the captured body: a solution's finger motion written into the body BVH its scene came from.

A scene imported with ``scene import-mocap --body-bvh BODY --wrist-joint ...`` records its source
(:class:`~torchhand.scene.MocapSource`): the file, the wrist joint per side, the source frame rate, the source frame
at the scene's frame 0, the units, up axis and handedness, and the fixed rotation ``R_fix`` from the wrist joint's
axes to the hand frame. With it the solution's hand is placed exactly in the wrist joint's local frame:

    ``L_l = M [R_fix R_l, R_fix t_l / u] M``   (``H_l = [R_l, t_l]``: link pose in the hand frame, metres, from FK;
    ``u``: metres per file unit; ``M = diag(-1, 1, 1)`` for left-handed files, the identity otherwise)

The up-axis conversion cancels (``R_fix`` is in the joint's own axes). ``L_l`` builds a BVH hand whose palm hangs
from the body's wrist (:mod:`torchhand.export.skeleton`, attached), in the body's file axes and units.

The body's finger joints are then driven by that hand through the splicing joint maps
(:func:`torchhand.splice.retarget.retarget_fingers` with ``align_rest=True``: each finger segment points where the
solution's does relative to the hand, in the body rig's own rest pose, twist about the segment from the minimal
rotation); a body without finger joints on that side first gets the hand's fingers inserted under its wrist
(:func:`torchhand.splice.retarget.insert_fingers`). The body rig's bones are not the scene hand's bones (a Mixamo
finger is longer, its knuckle elsewhere), so direction matching alone leaves the fingertips 1-3 cm from the
solution's, and contacts would be lost; each finger chain is therefore bent afterwards, FABRIK from the retargeted
pose with the chain's base fixed, until its tip reaches the solution's fingertip, and every segment is swung onto its
new direction by the smallest rotation (twist kept). A tip beyond the chain's reach stops at full extension.

Only finger joints' rotation channels change, and only in the source frames the scene covers (``first_frame ..
first_frame + (T - 1) fps_src / fps``, the solution's joint angles interpolated linearly to the source frames);
every other channel and frame keeps the captured value. Within ``blend`` seconds of each end of the segment (ends
that are not the clip's own ends) the rotations ramp from the captured ones to the solution's (slerp, smoothstep
weight), so the finger motion joins without a jump; the fingertips reach the solution's only outside these ramps.

The wrist is the body's, not the solution's ``root_pose``: they agree unless the synthesis smoothed the wrist track
(``synthesize --smooth``). The report gives the remaining fingertip distances per finger.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from ..scene.bvh import BVHClip
from ..errors import InputValueError
from ..splice.retarget import insert_fingers, retarget_fingers
from ..splice.retime import local_rotations, rotations_to_channels
from ..splice.rigs import detect_rig
from .skeleton import hand_skeleton, skeleton_channels, skeleton_motion

__all__ = ["OntoBody", "fingers_onto_body", "hand_in_wrist_frame", "blend_weights"]

_MIRROR = np.diag([-1.0, 1.0, 1.0])


@dataclass(frozen=True)
class OntoBody:
    """The body with the solution's fingers.

    clip: the body clip (its hierarchy, plus inserted finger joints for sides that had none), captured channels
        everywhere except finger rotations in the segment
    segment: (first, last) source frames written, inclusive, per side
    report: JSON-ready figures (fingertip distances to the solution's in metres, blended frames, joints carried)
    """

    clip: BVHClip
    segment: dict
    report: dict = field(default_factory=dict)


def hand_in_wrist_frame(model, q: np.ndarray, R_fix: np.ndarray, units_scale: float, handedness: str):
    """Link poses ``L_l`` of the hand in the wrist joint's local file frame (module docstring).

    Args:
        model: the :class:`~torchhand.hand.HandModel`
        q: joint angles, (N, D), radians
        R_fix: (3, 3) wrist-joint axes -> hand frame; units_scale: metres per file unit; handedness of the file

    Returns:
        (N, L, 4, 4) file units and axes; the rest pose (L, 4, 4); the point map (3, 3) metres -> file
    """
    m = model.to(device="cpu", dtype=torch.float64)
    M = _MIRROR if handedness == "left" else np.eye(3)
    H = m.forward_kinematics(torch.as_tensor(np.asarray(q, dtype=np.float64))).numpy()
    H_rest = m.forward_kinematics(torch.zeros(1, m.num_joints, dtype=torch.float64)).numpy()[0]

    def place(X: np.ndarray) -> np.ndarray:
        out = np.array(X, copy=True)
        out[..., :3, :3] = M @ R_fix @ X[..., :3, :3] @ M
        out[..., :3, 3] = (X[..., :3, 3] @ R_fix.T @ M.T) / units_scale
        return out

    return place(H), place(H_rest), M / units_scale


def fingers_onto_body(result, index: int, body: BVHClip, *, blend: float = 0.2, body_rig: str = "auto",
                      progress=None) -> OntoBody:
    """Write solution ``index`` of ``result`` onto ``body`` (module docstring).

    Args:
        result: a :class:`~torchhand.io.result.Result` whose scene has a ``source`` (``scene import-mocap``)
        index: the solution
        body: the captured clip the scene was imported from
        blend: seconds of ramp at each inner end of the segment, >= 0
        body_rig: "auto", a rig name or a TOML joint map (:func:`torchhand.splice.rigs.detect_rig`)
        progress: optional callable(str)

    Raises:
        InputValueError: the scene has no mocap source, or ``body`` is not the file it came from (frame count,
            frame rate or wrist joint differ), or the solution has no hand that the source names.
    """
    say = progress or (lambda s: None)
    scene = result.scene
    src = scene.source
    if src is None:
        raise InputValueError(f"onto: the scene of {result.path} was not imported from motion capture (its "
                              "scene.toml has no [source] table); import it with `torchhand scene import-mocap`")
    if not (isinstance(blend, (int, float)) and math.isfinite(blend) and blend >= 0):
        raise InputValueError(f"blend: expected seconds >= 0, got {blend}")
    if body.num_frames != src.frames or abs(body.fps - src.fps) > 2e-3:
        raise InputValueError(f"onto: {body.path} has {body.num_frames} frames at {body.fps:.6g} fps; the scene was "
                              f"imported from {src.frames} frames at {src.fps:.6g} fps "
                              f"({', '.join(sorted({f for _, f, _ in src.wrists}))})")
    sol = result.solution(index)
    brig = detect_rig(body, body_rig)
    clip = body
    frames, u = _segment_frames(src, scene.fps, sol.T, body.num_frames)
    report = {"body": body.path, "body_rig": brig.name, "solution": index,
              "segment_source_frames": [int(frames[0]), int(frames[-1])], "blend_s": float(blend), "sides": {}}
    hands = []
    for hand in sol.hands:                       # the hands placed at their wrists, fingers inserted where needed
        side = hand.side
        _, joint = src.wrist(side)
        body.joint_index(joint)
        model = result.hand_models[side]
        q = _interp_rows(hand.q, u)
        X, X_rest, K = hand_in_wrist_frame(model, q, src.rotation(side), src.units_scale, src.handedness)
        hand_clip, hand_local = _attached_hand(hand_skeleton(model), X, X_rest, K, 1.0 / src.fps, side)
        hrig = detect_rig(hand_clip, "torchhand", unsided=side)
        inserted = not brig.fingers.get(side)
        if inserted:
            say(f"inserting {side} fingers below {joint}")
            ins = insert_fingers(clip, brig, side, hand_clip, hrig, hand_handedness=src.handedness,
                                 body_handedness=src.handedness, up_axis=src.up_axis)
            clip, brig = ins.clip, ins.rig
        tips = _solution_tips(model, X, K)                                         # (N, F, 3) wrist frame
        hands.append((side, joint, model, hand_clip, hrig, hand_local, tips, inserted))
    motion = np.array(clip.motion, dtype=np.float64, copy=True)
    seg = motion[frames].copy()
    changed: list[int] = []
    for side, joint, model, hand_clip, hrig, hand_local, tips, inserted in hands:
        say(f"{side} fingers onto {joint}")
        carried = retarget_fingers(hand_clip, hrig, clip, brig, side, hand_local, src_handedness=src.handedness,
                                   dst_handedness=src.handedness, align_rest=True)
        seg = rotations_to_channels(clip, seg, carried.rotations)
        w = clip.joint_index(joint)
        Gw = clip.global_transforms(frames).numpy()[:, w]
        targets = np.einsum("nab,nfb->nfa", Gw[:, :3, :3], tips) + Gw[:, None, :3, 3]
        reached = _reach_tips(clip, seg, brig, side, list(model.finger_names), targets)
        seg = rotations_to_channels(clip, seg, reached)
        changed += list(carried.rotations) + list(reached)
        report["sides"][side] = {"wrist_joint": joint, "fingers_inserted": inserted,
                                 "joints_carried": [[m.finger, m.ordinal, m.src, m.dst] for m in carried.matches],
                                 "_tips": targets, "_names": list(model.finger_names)}
    captured = local_rotations(clip, motion[frames])
    written = local_rotations(clip, seg)
    w = blend_weights(frames, clip.num_frames, clip.fps, blend)
    blended = {d: _blend(captured[:, d], written[:, d], w) for d in sorted(set(changed))}
    before = motion[frames[0] - 1] if frames[0] > 0 else None
    motion[frames] = rotations_to_channels(clip, motion[frames], blended, continue_from=before)
    out = dataclasses.replace(clip.with_motion(motion), path=body.path)
    for side, info in report["sides"].items():
        info.update(_tip_report(out, brig, side, info.pop("_names"), info.pop("_tips"), frames, src, w == 1.0))
    return OntoBody(clip=out, segment={s: (int(frames[0]), int(frames[-1])) for s in report["sides"]},
                    report=report)


def _solution_tips(model, X: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Fingertip pad points of the placed hand, (N, F, 3), wrist frame, file units."""
    m = model.to(device="cpu", dtype=torch.float64)
    tips_local = m.fingertip.numpy() @ K.T
    Xd = X[:, m.distal_link.numpy()]
    return np.einsum("nfab,fb->nfa", Xd[..., :3, :3], tips_local) + Xd[..., :3, 3]


def _rig_finger(name: str) -> str:
    """The splicing rigs' finger key of a hand model's finger name (the built-in hand's "little" is "pinky")."""
    return "pinky" if name == "little" else name


def _chains(rig, side: str, names: list[str]) -> dict[str, list[int]]:
    """Per finger of the hand, the body's chain joints (by ordinal) and its tip joint last."""
    out = {}
    fingers = rig.fingers.get(side, {})
    tips = rig.tips.get(side, {})
    for name in names:
        key = _rig_finger(name)
        chain = [j for (f, _), j in sorted(fingers.items(), key=lambda kv: kv[0][1]) if f == key]
        tip = tips.get(key)
        if not chain or tip is None:
            continue
        if tip != chain[-1]:
            chain.append(tip)
        if len(chain) >= 2 and all(rig.parents[b] == a for a, b in zip(chain, chain[1:])):
            out[name] = chain
    return out


def _reach_tips(clip: BVHClip, seg: np.ndarray, rig, side: str, names: list[str], targets: np.ndarray,
                iterations: int = 24) -> dict[int, torch.Tensor]:
    """Bend each finger chain so that its tip reaches the solution's fingertip (FABRIK from the retargeted pose,
    the chain's base fixed), swinging each segment by the smallest rotation; returns joint -> local rotations."""
    G = clip.with_motion(seg).global_transforms().numpy()                          # (N, J, 4, 4)
    out: dict[int, torch.Tensor] = {}
    chains = _chains(rig, side, names)
    for f, name in enumerate(names):
        chain = chains.get(name)
        if chain is None:
            continue
        p = G[:, chain][:, :, :3, 3].copy()                                               # (N, n+1, 3)
        lengths = np.linalg.norm(np.diff(p, axis=1), axis=-1)                       # (N, n)
        base, goal = p[:, 0].copy(), targets[:, f]
        new = p.copy()
        for _ in range(iterations):
            new[:, -1] = goal
            for i in range(len(chain) - 2, -1, -1):
                new[:, i] = new[:, i + 1] + lengths[:, i, None] * _unit(new[:, i] - new[:, i + 1])
            new[:, 0] = base
            for i in range(len(chain) - 1):
                new[:, i + 1] = new[:, i] + lengths[:, i, None] * _unit(new[:, i + 1] - new[:, i])
        Rg = {}
        for i, j in enumerate(chain[:-1]):
            swing = _min_rotation(p[:, i + 1] - p[:, i], new[:, i + 1] - new[:, i])
            Rg[j] = swing @ G[:, j, :3, :3]
        for j in chain[:-1]:
            parent = clip.parents[j]
            Rp = Rg[parent] if parent in Rg else G[:, parent, :3, :3]
            out[j] = torch.from_numpy(np.einsum("nba,nbc->nac", Rp, Rg[j]))
    return out


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 1e-12, n, 1.0)


def _min_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotations taking directions ``a`` onto ``b``, (N, 3) each -> (N, 3, 3)."""
    a, b = _unit(a), _unit(b)
    axis = np.cross(a, b)
    s = np.linalg.norm(axis, axis=-1)
    c = np.einsum("na,na->n", a, b)
    rotvec = _unit(axis) * np.arctan2(s, c)[:, None]
    return Rotation.from_rotvec(rotvec).as_matrix()


def _segment_frames(src, fps: float, T: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Source frames inside the scene's span and their fractional scene frames."""
    ratio = src.fps / fps
    lo = math.ceil(src.first_frame - 1e-6)
    hi = math.floor(src.first_frame + (T - 1) * ratio + 1e-6)
    hi = min(hi, n - 1)
    if hi < lo:
        raise InputValueError(f"onto: the scene covers no whole source frame (source frames {src.first_frame:.3f}"
                              f" .. {src.first_frame + (T - 1) * ratio:.3f})")
    frames = np.arange(lo, hi + 1)
    u = np.clip((frames - src.first_frame) / ratio, 0.0, T - 1)
    return frames, u


def _interp_rows(a: np.ndarray, u: np.ndarray) -> np.ndarray:
    i0 = np.clip(np.floor(u).astype(np.int64), 0, a.shape[0] - 1)
    i1 = np.minimum(i0 + 1, a.shape[0] - 1)
    w = (u - i0)[:, None]
    return (1.0 - w) * a[i0] + w * a[i1]


def _attached_hand(skel, X, X_rest, K, frame_time: float, side: str) -> tuple[BVHClip, torch.Tensor]:
    """The hand as a BVH clip whose root (the palm) sits at its place below the wrist, and its local rotations
    (N, J, 3, 3) in the clip's joint order."""
    offsets, local_R, local_p, moving = skeleton_motion(skel, X, X_rest, K, attached=True)
    channels, motion = skeleton_channels(skel, local_R, local_p, moving)
    clip = BVHClip(path=f"{side}_hand", names=skel.names, parents=skel.parents, offsets=offsets, channels=channels,
                   is_end_site=skel.is_end_site, frame_time=frame_time, motion=motion)
    J = len(skel.names)
    R = np.broadcast_to(np.eye(3), (X.shape[0], J, 3, 3)).copy()
    R[:, : skel.num_links] = local_R
    return clip, torch.from_numpy(R)


def blend_weights(frames: np.ndarray, num_frames: int, fps: float, blend: float) -> np.ndarray:
    """Weight of the solution per segment frame, (N,) in [0, 1]: 0 on the segment's first frame, 1 from
    ``K = max(1, round(blend * fps))`` frames in (smoothstep in between), the same toward the last frame; an end
    of the segment that is an end of the clip has no ramp. ``blend = 0``: all ones."""
    n = len(frames)
    w = np.ones(n)
    if blend > 0:
        K = max(1, int(round(blend * fps)))
        i = np.arange(n, dtype=np.float64)
        if frames[0] > 0:
            w = np.minimum(w, i / K)
        if frames[-1] < num_frames - 1:
            w = np.minimum(w, (n - 1 - i) / K)
    w = np.clip(w, 0.0, 1.0)
    return w * w * (3 - 2 * w)


def _blend(captured: torch.Tensor, solution: torch.Tensor, w: np.ndarray) -> torch.Tensor:
    """Per frame, the rotation ``w`` of the way from the captured one to the solution's (slerp)."""
    if np.all(w == 1.0):
        return solution
    Rc = Rotation.from_matrix(captured.numpy())
    Rs = Rotation.from_matrix(solution.numpy())
    delta = (Rc.inv() * Rs).as_rotvec()
    out = Rc * Rotation.from_rotvec(delta * w[:, None])
    return torch.from_numpy(out.as_matrix())


def _tip_report(clip: BVHClip, rig, side: str, names: list[str], targets: np.ndarray, frames: np.ndarray, src,
                inner: np.ndarray) -> dict:
    """Fingertip distances (metres) between the written body and the solution placed at the body's wrist, over
    the segment's ``inner`` frames (outside the blends; all frames when the segment is all blend)."""
    G = clip.global_transforms(frames).numpy()
    tips = rig.tips.get(side, {})
    if not inner.any():
        inner = np.ones_like(inner)
    dist = {}
    for f, name in enumerate(names):
        j = tips.get(_rig_finger(name))
        if j is not None:
            dist[name] = np.linalg.norm(G[:, j, :3, 3] - targets[:, f], axis=-1)[inner] * src.units_scale
    worst = max((float(d.max()) for d in dist.values()), default=None)
    return {"fingertip_error_m": {n: {"median": float(np.median(d)), "max": float(d.max())} for n, d in dist.items()},
            "fingertip_error_max_m": worst, "blended_frames": int((~inner).sum()),
            "fingertips_without_body_joint": [n for n in names if n not in dist]}
