"""How far a solution's wrist and object are from the captured ones (the optional ``root_pose_captured`` and
``object_pose_captured`` of a solution file).

A method may move the wrist within capture noise (``torchhand fill``, docs/fill.md); the file then keeps the
captured track beside the used one. The checker reports the deviation per frame as information: it is the
method's stated choice, not a physical error, so it has no limit and never fails a solution. Metres and radians
in, millimetres and degrees out.
"""

from __future__ import annotations

import numpy as np

__all__ = ["wrist_deviation", "object_deviation"]


def wrist_deviation(sol) -> dict:
    """Per hand with a captured track: the deviation of ``root_pose`` from ``root_pose_captured`` per frame.

    Returns {side: {"translation_mm": [T floats], "rotation_deg": [T floats], "max_translation_mm",
    "max_rotation_deg", "median_translation_mm", "median_rotation_deg", "frames_moved"}}; {} when no hand has one.
    """
    out = {}
    for hs in sol.hands:
        cap = getattr(hs, "root_pose_captured", None)
        if cap is not None:
            out[hs.side] = _deviation(hs.root_pose, cap)
    return out


def object_deviation(sol) -> dict:
    """The deviation of ``object_pose`` from ``object_pose_captured`` per frame (the keys of
    :func:`wrist_deviation`'s entries); {} when the file has no captured object track."""
    cap = getattr(sol, "object_pose_captured", None)
    return {} if cap is None else _deviation(sol.object_pose, cap)


def _deviation(used: np.ndarray, cap: np.ndarray) -> dict:
    t = 1e3 * np.linalg.norm(used[:, :3, 3] - cap[:, :3, 3], axis=-1)
    R = np.swapaxes(cap[:, :3, :3], -1, -2) @ used[:, :3, :3]
    r = np.degrees(np.arccos(np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1.0, 1.0)))
    return {"translation_mm": [round(float(x), 4) for x in t], "rotation_deg": [round(float(x), 4) for x in r],
            "max_translation_mm": float(t.max()), "max_rotation_deg": float(r.max()),
            "median_translation_mm": float(np.median(t)), "median_rotation_deg": float(np.median(r)),
            "frames_moved": int(((t > 1e-6) | (r > 1e-6)).sum())}
