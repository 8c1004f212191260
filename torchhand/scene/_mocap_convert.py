"""Motion-capture coordinates: source transforms into torchhand's world (:func:`convert_transforms`) and the fixed
rotation from a wrist joint's axes to the hand frame (:func:`hand_frame_rotation`); the rules are in the module
docstring of :mod:`torchhand.scene.mocap`."""

from __future__ import annotations

import math

import numpy as np
import torch

from ..errors import InputValueError
from ._bvh_clip import BVHClip

__all__ = ["convert_transforms", "hand_frame_rotation"]

_FINGER_KEYS = {
    "middle": ("middle", "mid"),
    "index": ("index",),
    "pinky": ("pinky", "pinkie", "little"),
}


def convert_transforms(G: torch.Tensor, *, units_scale: float = 1.0, up_axis: str = "y",
                       handedness: str = "right") -> torch.Tensor:
    """Source transforms to torchhand world transforms (module docstring, steps 1-3).

    Args:
        G: source transforms, (..., 4, 4), file units and axes
        units_scale: metres per file unit
        up_axis: "y" or "z", the source's up axis
        handedness: "right" or "left", the source's coordinate handedness

    Returns:
        transforms in the z-up world, (..., 4, 4), metres, dtype of ``G``
    """
    _check_choice(up_axis, "up_axis", ("y", "z"))
    _check_choice(handedness, "handedness", ("right", "left"))
    out = G.clone()
    if handedness == "left":
        M = torch.diag(G.new_tensor([-1.0, 1.0, 1.0, 1.0]))
        out = M @ out @ M
    out[..., :3, 3] = out[..., :3, 3] * units_scale
    if up_axis == "y":
        C = G.new_tensor([[1.0, 0, 0, 0], [0, 0, -1.0, 0], [0, 1.0, 0, 0], [0, 0, 0, 1.0]])
        out = C @ out
    return out


def hand_frame_rotation(clip: BVHClip, wrist: int, side: str, *, handedness: str = "right",
                        up_axis: str = "y") -> tuple[np.ndarray, float | None, str]:
    """The fixed rotation from the wrist joint's local axes to the hand frame (module docstring).

    Args:
        clip: the BVH
        wrist: index of the wrist joint
        side: "right" or "left"
        handedness: the source's handedness ("left" mirrors the rest offsets first)
        up_axis: the source's up axis (used by the fallback rule only)

    Returns:
        R_fix: hand axes (columns x, y, z) in the wrist joint's (mirrored) local coordinates, (3, 3)
        length: rest wrist-to-middle-fingertip distance in file units, or None (fallback rule)
        rule: "fingers" or "fallback"
    """
    rest_T = clip.rest_transforms().numpy()
    if handedness == "left":
        M = np.diag([-1.0, 1.0, 1.0, 1.0])
        rest_T = M @ rest_T @ M
    rest = rest_T[:, :3, 3]
    R_rest = rest_T[wrist, :3, :3]  # identity for BVH (zero channels), kept for generality
    found = _finger_rule(clip, wrist, side, rest)
    if found is not None:
        R_world, length = found
        return R_rest.T @ R_world, (length if length > 0 else None), "fingers"
    return R_rest.T @ _fallback_rule(clip, wrist, rest, up_axis), None, "fallback"


def _finger_rule(clip: BVHClip, wrist: int, side: str, rest: np.ndarray) -> tuple[np.ndarray, float] | None:
    """(hand axes in rest coordinates (3, 3), rest wrist-to-middle-fingertip length) from the middle, index and
    pinky chains; None when the rig lacks one of them or their bases never separate."""
    origin = rest[wrist]
    chains = {k: _finger_chain(clip, wrist, keys) for k, keys in _FINGER_KEYS.items()}
    if not all(chains.values()):
        return None
    depth = min(len(c) for c in chains.values())
    for k in range(depth):
        mid = rest[chains["middle"][k]] - origin
        thumbward = rest[chains["index"][k]] - rest[chains["pinky"][k]]
        if np.linalg.norm(mid) > 1e-9 and np.linalg.norm(thumbward) > 0.25 * np.linalg.norm(mid):
            x = _unit(mid)
            y = thumbward - x * float(x @ thumbward)
            if np.linalg.norm(y) > 1e-6 * np.linalg.norm(thumbward):
                y = _unit(y) if side == "right" else -_unit(y)
                R_world = np.stack([x, y, np.cross(x, y)], axis=1)
                tip = _deepest(clip, chains["middle"][0])
                return R_world, float(np.linalg.norm(rest[tip] - origin))
    return None


def _fallback_rule(clip: BVHClip, wrist: int, rest: np.ndarray, up_axis: str) -> np.ndarray:
    """Hand axes in rest coordinates (3, 3): forearm direction and palms down (or palms in for hanging arms)."""
    origin = rest[wrist]
    kids = clip.children(wrist)
    if kids and np.linalg.norm(rest[kids[0]] - origin) > 1e-9:
        x = _unit(rest[kids[0]] - origin)
    elif clip.parents[wrist] >= 0 and np.linalg.norm(origin - rest[clip.parents[wrist]]) > 1e-9:
        x = _unit(origin - rest[clip.parents[wrist]])
    else:
        raise InputValueError(
            f"wrist_joint: cannot tell the forearm direction of '{clip.names[wrist]}' in {clip.path} "
            "(no child, End Site or parent at a distance)"
        )
    up = np.array([0.0, 1.0, 0.0]) if up_axis == "y" else np.array([0.0, 0.0, 1.0])
    if abs(float(x @ up)) < math.cos(math.radians(30.0)):
        z = _unit(up - x * float(x @ up))
    else:
        root = rest[0]
        lateral = origin - root
        lateral = lateral - up * float(up @ lateral)
        lateral = lateral - x * float(x @ lateral)
        if np.linalg.norm(lateral) < 1e-9:
            raise InputValueError(
                f"wrist_joint: '{clip.names[wrist]}' in {clip.path} hangs vertically on the body's midline; "
                "cannot guess the palm direction"
            )
        z = _unit(lateral)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)


def _finger_chain(clip: BVHClip, wrist: int, keys: tuple[str, ...]) -> list[int]:
    """Joints of the first finger chain below ``wrist`` whose names contain one of ``keys`` (breadth first)."""
    def matches(j: int) -> bool:
        n = clip.names[j].lower()
        if keys == ("middle", "mid"):
            return "middle" in n or "mid" in n.replace("middle", "")
        return any(k in n for k in keys)

    queue = list(clip.children(wrist))
    while queue:
        j = queue.pop(0)
        if matches(j) and not clip.is_end_site[j]:
            chain = [j]
            while True:
                nxt = [c for c in clip.children(chain[-1]) if not clip.is_end_site[c]]
                if not nxt:
                    break
                chain.append(nxt[0])
            return chain
        queue.extend(clip.children(j))
    return []


def _deepest(clip: BVHClip, j: int) -> int:
    while clip.children(j):
        j = clip.children(j)[0]
    return j


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _check_choice(value, name: str, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise InputValueError(f"{name}: expected one of {', '.join(repr(c) for c in choices)}, got {value!r}")
