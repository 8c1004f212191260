"""Virtual markers, units and axes for splicing (Majkowska et al. 2006, Sec. 3 and 4).

The paper aligns two captures through four markers per arm: two on the wrist (p1, p2), one on the forearm (p3),
one on the hand (p4). A BVH has joints, not markers, so they are made by forward kinematics:

* p1, p2 = wrist joint centre +- 3 cm along the forearm's lateral axis (the styloids): the lateral axis is the
  hand's thumb-ward axis at rest (or, without fingers, the horizontal normal of the forearm), carried by the
  forearm segment's rotation;
* p3 = midpoint of elbow and wrist; for a hand rig whose forearm joint sits at the wrist (Leap), 13 cm behind the
  wrist along the forearm's axis (half a forearm); for a rig without a forearm (ManipNet) the same point carried
  by the wrist, rigid with the hand (pass 2 then sees no wrist bending and is skipped);
* p4 = the middle finger's base (its proximal joint), or the wrist's child or End Site on finger-less rigs.

All positions are in torchhand's world: metres, z up, right-handed (``mocap.convert_transforms``). Units and up
axis of a file are guessed from its rest pose unless given: units make the forearm 15-40 cm long (hand-only rigs:
wrist to middle fingertip 12-28 cm); the up axis is the one along which the head lies above the hips (hand-only
rigs: y, the BVH convention).

Body clips also give the shoulder position (Eq. 6's shoulder subtraction) and a trunk rotation (the paper's
"angle difference between the trunk orientations", used by the default feature mode).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ..scene.bvh import BVHClip
from ..errors import InputValueError
from ..scene.mocap import convert_transforms

__all__ = ["ArmJoints", "Markers", "virtual_markers", "guess_units", "guess_up_axis", "UNITS"]

UNITS = {"m": 1.0, "dm": 0.1, "cm": 0.01, "mm": 0.001}
"""Metres per file unit for the unit names the CLI accepts."""

_WRIST_HALF_WIDTH = 0.03     # m, styloid markers either side of the wrist joint
_HALF_FOREARM = 0.13         # m, forearm marker behind the wrist when the rig has no elbow position


@dataclass(frozen=True)
class ArmJoints:
    """The joints of one arm that the markers need (indices into a clip's joints; None = absent).

    wrist: the wrist joint (required)
    forearm: the joint whose rotation is the forearm segment's (usually the wrist's parent, the elbow joint);
        None: the wrist itself (a hand-only rig without forearm)
    elbow: the joint at the elbow's centre (for p3), None when the rig has none
    shoulder: the upper-arm joint at the shoulder's centre (body rigs), None for hand rigs
    trunk: a spine/chest joint whose rotation is the trunk's, None for hand rigs
    hand_point: the middle finger's base, or the wrist's child / End Site; None: 8 cm along the hand's axis
    thumbward: the hand's thumb-ward axis at rest in file coordinates, (3,), or None (use the forearm's normal)
    """

    wrist: int
    forearm: int | None = None
    elbow: int | None = None
    shoulder: int | None = None
    trunk: int | None = None
    hand_point: int | None = None
    thumbward: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class Markers:
    """Marker tracks of one arm of one clip, torchhand world (metres, z up).

    markers: p1, p2, p3, p4, (T, 4, 3), metres
    shoulder: shoulder centre, (T, 3), metres, or None (hand rig)
    trunk: trunk rotation relative to its rest pose, (T, 3, 3), or None (hand rig)
    fps: frames per second
    units_scale: metres per file unit used
    up_axis: the file's up axis used, "y" or "z"
    """

    markers: torch.Tensor
    shoulder: torch.Tensor | None
    trunk: torch.Tensor | None
    fps: float
    units_scale: float
    up_axis: str

    @property
    def num_frames(self) -> int:
        return int(self.markers.shape[0])


def guess_up_axis(clip: BVHClip, head: int | None = None, hips: int | None = None) -> str:
    """The file's up axis from the rest pose: the axis along which ``head`` lies above ``hips`` ("y" or "z");
    "y" when either is unknown (hand rigs: the BVH convention)."""
    if head is None or hips is None:
        return "y"
    rest = clip.rest_transforms().numpy()[:, :3, 3]
    d = rest[head] - rest[hips]
    return "z" if abs(d[2]) > abs(d[1]) else "y"


def guess_units(clip: BVHClip, joints: ArmJoints) -> float:
    """Metres per file unit: the candidate (m, dm, cm, mm) that makes the forearm 15-40 cm long (hand rigs: wrist
    to the farthest finger joint 12-28 cm). Raises InputValueError when none does."""
    rest = clip.rest_transforms().numpy()[:, :3, 3]
    if joints.elbow is not None and joints.elbow != joints.wrist:
        length = float(np.linalg.norm(rest[joints.wrist] - rest[joints.elbow]))
        lo, hi, what = 0.15, 0.40, "forearm"
    else:
        below = _descendants(clip, joints.wrist)
        if not below:
            raise InputValueError(f"units: cannot tell the units of {clip.path}: no joint below the wrist "
                                  f"'{clip.names[joints.wrist]}'")
        length = float(max(np.linalg.norm(rest[j] - rest[joints.wrist]) for j in below))
        lo, hi, what = 0.12, 0.28, "hand"
    for name, s in UNITS.items():
        if lo <= length * s <= hi:
            return s
    raise InputValueError(f"units: the {what} of {clip.path} is {length:.4g} file units long, not "
                          f"{lo * 100:.0f}-{hi * 100:.0f} cm in m, dm, cm or mm: give the units explicitly "
                          "(--body-units / --hand-units)")


def virtual_markers(clip: BVHClip, joints: ArmJoints, *, units_scale: float, up_axis: str = "y",
                    handedness: str = "right", frames=None, dtype=torch.float64) -> Markers:
    """The four markers, the shoulder and the trunk rotation of one arm, per frame (module docstring).

    Args:
        clip: the BVH
        joints: which joints the arm uses
        units_scale: metres per file unit
        up_axis: "y" or "z", the file's up axis
        handedness: "right" or "left" (a left-handed file is mirrored)
        frames: optional frame selection of the clip's motion
        dtype: dtype of the returned tensors

    Returns:
        :class:`Markers` (metres, z up)
    """
    G = convert_transforms(clip.global_transforms(frames), units_scale=units_scale, up_axis=up_axis,
                           handedness=handedness)                                   # (T, J, 4, 4)
    rest = convert_transforms(clip.rest_transforms(), units_scale=units_scale, up_axis=up_axis,
                              handedness=handedness)                                # (J, 4, 4)
    G = G.to(dtype)
    rest = rest.to(dtype)
    # Rest frames of BVH joints are all aligned with the file's axes, so R_world(t) @ R_rest^T is a segment's
    # rotation away from rest, and rest directions are carried by it.
    w = joints.wrist
    fa = joints.forearm if joints.forearm is not None else w
    wrist_pos = G[:, w, :3, 3]
    R_fa = G[:, fa, :3, :3] @ rest[fa, :3, :3].transpose(-1, -2)                    # (T, 3, 3)
    R_w = G[:, w, :3, :3] @ rest[w, :3, :3].transpose(-1, -2)

    hand_axis = _hand_axis_rest(clip, joints, rest)                                 # (3,) world rest
    if joints.elbow is not None and joints.elbow != w:
        forearm_rest = rest[w, :3, 3] - rest[joints.elbow, :3, 3]
    else:
        forearm_rest = hand_axis
    forearm_rest = forearm_rest / forearm_rest.norm().clamp_min(1e-12)
    lateral = _lateral_rest(joints, forearm_rest, rest, units_scale, up_axis, handedness)
    side_vec = R_fa @ lateral                                                       # (T, 3)
    p1 = wrist_pos + _WRIST_HALF_WIDTH * side_vec
    p2 = wrist_pos - _WRIST_HALF_WIDTH * side_vec
    if joints.elbow is not None and joints.elbow != w:
        p3 = 0.5 * (G[:, joints.elbow, :3, 3] + wrist_pos)
    else:
        carrier = R_fa if joints.forearm is not None else R_w
        p3 = wrist_pos - _HALF_FOREARM * (carrier @ forearm_rest)
    if joints.hand_point is not None and float((rest[joints.hand_point, :3, 3] - rest[w, :3, 3]).norm()) > 1e-4:
        p4 = G[:, joints.hand_point, :3, 3]
    else:
        p4 = wrist_pos + 0.08 * (R_w @ hand_axis)
    markers = torch.stack([p1, p2, p3, p4], 1)
    shoulder = G[:, joints.shoulder, :3, 3] if joints.shoulder is not None else None
    trunk = None
    if joints.trunk is not None:
        trunk = G[:, joints.trunk, :3, :3] @ rest[joints.trunk, :3, :3].transpose(-1, -2)
    if not torch.isfinite(markers).all():
        raise InputValueError(f"{clip.path}: non-finite marker positions")
    return Markers(markers=markers, shoulder=shoulder, trunk=trunk, fps=clip.fps, units_scale=units_scale,
                   up_axis=up_axis)


def _hand_axis_rest(clip: BVHClip, joints: ArmJoints, rest: torch.Tensor) -> torch.Tensor:
    """Unit direction wrist -> hand point at rest (world), or the forearm direction when there is none."""
    w = joints.wrist
    if joints.hand_point is not None:
        d = rest[joints.hand_point, :3, 3] - rest[w, :3, 3]
        if float(d.norm()) > 1e-6:
            return d / d.norm()
    below = _descendants(clip, w)
    if below:
        far = max(below, key=lambda j: float((rest[j, :3, 3] - rest[w, :3, 3]).norm()))
        d = rest[far, :3, 3] - rest[w, :3, 3]
        if float(d.norm()) > 1e-6:
            return d / d.norm()
    if joints.elbow is not None and joints.elbow != w:
        d = rest[w, :3, 3] - rest[joints.elbow, :3, 3]
        return d / d.norm().clamp_min(1e-12)
    raise InputValueError(f"{clip.path}: cannot tell the hand's direction at the wrist '{clip.names[w]}'")


def _lateral_rest(joints: ArmJoints, forearm: torch.Tensor, rest: torch.Tensor, units_scale: float, up_axis: str,
                  handedness: str) -> torch.Tensor:
    """Unit lateral axis of the forearm at rest (world): the thumb-ward axis made orthogonal to the forearm, or
    the horizontal normal of the forearm (the vertical normal when the forearm is vertical)."""
    if joints.thumbward is not None:
        x, y, z = joints.thumbward
        if handedness == "left":
            x = -x
        v = torch.tensor([x, -z, y] if up_axis == "y" else [x, y, z], dtype=rest.dtype)
        v = v - forearm * (v @ forearm)
        if float(v.norm()) > 1e-6:
            return v / v.norm()
    up = torch.tensor([0.0, 0.0, 1.0], dtype=rest.dtype)
    v = torch.linalg.cross(forearm, up)
    if float(v.norm()) < math.sin(math.radians(10.0)):
        v = torch.linalg.cross(forearm, torch.tensor([1.0, 0.0, 0.0], dtype=rest.dtype))
    return v / v.norm()


def _descendants(clip: BVHClip, j: int) -> list[int]:
    out, stack = [], list(clip.children(j))
    while stack:
        k = stack.pop()
        out.append(k)
        stack.extend(clip.children(k))
    return out
