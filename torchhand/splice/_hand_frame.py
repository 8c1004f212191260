"""The canonical hand frame of a rig at rest (:func:`hand_frame`): from the recognised knuckles, or for a hand
without fingers the fallback rule of :func:`torchhand.scene.mocap.hand_frame_rotation`; and the mirror of
left-handed files."""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputValueError
from ..scene.bvh import BVHClip
from ._rig_record import SIDES, Arm, Rig
from .rig_hierarchy import FINGERS, rest_positions

__all__ = ["hand_frame"]

_MIRROR = np.diag([-1.0, 1.0, 1.0])


def hand_frame(clip: BVHClip, rig: Rig, side: str, *, handedness: str = "right", up_axis: str | None = None
               ) -> np.ndarray:
    """The canonical hand frame at rest, (3, 3): columns x, y, z in the file's rest coordinates (mirrored for a
    left-handed file).

    With fingers: x = wrist -> middle knuckle (the (middle, 1) joint; other knuckles when it is missing),
    y = pinky knuckle -> index knuckle made orthogonal to x for a right hand, its opposite for a left hand,
    z = x × y (the back of the hand; the palm faces -z), as :func:`torchhand.scene.mocap.hand_frame_rotation` but from
    the recognised knuckles. Without fingers: that function's fallback (x toward the wrist's child or End Site,
    z up for a horizontal arm, away from the root for a hanging one; ``up_axis`` "y"/"z", guessed as the axis
    along which the trunk lies above the root when None).
    """
    _check_choice(handedness, "handedness", SIDES)
    arm = rig.arm(side)
    rest = rest_positions(clip, handedness)
    w = rest[arm.wrist]
    fingers = rig.fingers.get(side, {})
    knuckle = {f: next((fingers[(f, o)] for o in (1, 2, 0) if (f, o) in fingers), None) for f in FINGERS}
    ahead = [knuckle[f] for f in ("middle", "index", "ring") if knuckle[f] is not None]
    across = [(a, b) for a in ("index", "middle") for b in ("pinky", "ring")
              if a != b and knuckle[a] is not None and knuckle[b] is not None]
    if ahead and across:
        x = _unit(rest[ahead[0]] - w)
        t = rest[knuckle[across[0][0]]] - rest[knuckle[across[0][1]]]
        y = t - x * float(x @ t)
        if np.linalg.norm(x) > 0 and np.linalg.norm(y) > 1e-6 * max(np.linalg.norm(t), 1e-300):
            y = _unit(y) if side == "right" else -_unit(y)
            return np.stack([x, y, np.cross(x, y)], axis=1)
    return _fallback_frame(clip, arm, rest, up_axis)


def _fallback_frame(clip: BVHClip, arm: Arm, rest: np.ndarray, up_axis: str | None) -> np.ndarray:
    w = rest[arm.wrist]
    kids = [k for k in range(clip.num_joints) if clip.parents[k] == arm.wrist and np.linalg.norm(rest[k] - w) > 1e-9]
    par = clip.parents[arm.wrist]
    if kids:
        x = _unit(rest[kids[0]] - w)
    elif par >= 0 and np.linalg.norm(w - rest[par]) > 1e-9:
        x = _unit(w - rest[par])
    else:
        raise InputValueError(f"hand frame: cannot tell the hand's direction at '{clip.names[arm.wrist]}' in "
                              f"{clip.path} (no finger joints, no child, End Site or parent at a distance)")
    if up_axis is None:
        up_axis = _guess_up(clip, arm, rest)
    _check_choice(up_axis, "up_axis", ("y", "z"))
    up = np.array([0.0, 1.0, 0.0]) if up_axis == "y" else np.array([0.0, 0.0, 1.0])
    if abs(float(x @ up)) < math.cos(math.radians(30.0)):
        z = _unit(up - x * float(x @ up))
    else:
        root = arm.wrist
        while clip.parents[root] >= 0:
            root = clip.parents[root]
        lateral = w - rest[root]
        lateral = lateral - up * float(up @ lateral)
        lateral = lateral - x * float(x @ lateral)
        if np.linalg.norm(lateral) < 1e-9:
            raise InputValueError(f"hand frame: '{clip.names[arm.wrist]}' in {clip.path} hangs vertically on the "
                                  "body's midline; cannot guess the palm direction")
        z = _unit(lateral)
    return np.stack([x, np.cross(z, x), z], axis=1)


def _guess_up(clip: BVHClip, arm: Arm, rest: np.ndarray) -> str:
    if arm.trunk is None:
        return "y"
    root = arm.trunk
    while clip.parents[root] >= 0:
        root = clip.parents[root]
    d = rest[arm.trunk] - rest[root]
    return "z" if abs(d[2]) > abs(d[1]) else "y"


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v / n if n > 0 else v


def _check_choice(value, name: str, choices) -> None:
    if value not in choices:
        raise InputValueError(f"{name}: expected one of {', '.join(map(repr, choices))}, got {value!r}")
