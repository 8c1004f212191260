"""The capture's own noise, and the slide speed the search should use for it.

While the hand holds the object, a still grip keeps the wrist still in the object's frame; a capture does not (its
markers slide on skin and its tracks are filtered apart). So, over the frames of the contact phases, the wrist's
pose in the object's frame is differenced frame to frame, and five points of the hand where it touches what it holds
are followed (the wrist, the palm and grasp centres, the middle fingertip and the thumb tip of the hand frame, see
:func:`_touch_points`): the fastest one's speed in the object's frame is how fast a contact appears to slide
although the grip is still.

* ``jitter_mm`` / ``jitter_deg``: the median per-frame translation of the wrist and rotation in the object frame;
* ``slide_speed``: the median over the frames of that speed (m/s), clamped to [0.02, 0.10] m/s: the search calls a held
  contact sliding only beyond it (``NodeTestSettings.slide_speed``; 0.02 m/s, the node test's default, is the
  floor; 0.1 m/s, 3 mm per frame at 30 fps, the ceiling). Without contact frames: 0.02.

Measured on ManipNet's mug1 at 30 fps (docs/fill.md): the segment 614-674 gives 0.054 m/s (the value tuned by hand
for it was 0.05); the whole capture's contact phases give 0.094 m/s (they include regrasps), so ``torchhand fill``
measures each window's own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .phases import _track, hand_points

__all__ = ["CaptureNoise", "capture_noise", "SLIDE_SPEED_RANGE"]


def _touch_points(length: float, side: str) -> np.ndarray:
    """Where a hand touches what it holds, in the hand frame, (5, 3) metres: the wrist, the palm and grasp centres
    (:func:`torchhand.fill.phases.hand_points`), the middle fingertip of an open hand and the thumb tip of a closing
    one (toward +y for a right hand, -y for a left)."""
    thumb_y = 0.35 * length if side == "right" else -0.35 * length
    return np.vstack([[0.0, 0.0, 0.0], hand_points(length), [0.95 * length, 0.0, -0.02],
                      [0.45 * length, thumb_y, -0.04]])

SLIDE_SPEED_RANGE = (0.02, 0.10)
"""m/s: the clamp of the slide speed from the noise."""


@dataclass(frozen=True)
class CaptureNoise:
    """The wrist-object noise while held: slide_speed (m/s, for the search), jitter_mm and jitter_deg (medians per
    frame), frames (the frame pairs measured; 0: none, the default slide speed)."""

    slide_speed: float
    jitter_mm: float
    jitter_deg: float
    frames: int

    def to_json(self) -> dict:
        return {"slide_speed": self.slide_speed, "jitter_mm": self.jitter_mm, "jitter_deg": self.jitter_deg,
                "frames": self.frames}


def capture_noise(scene, side: str, phases) -> CaptureNoise:
    """The noise of hand ``side`` over the contact phases of ``phases`` (module docstring)."""
    track = _track(scene, side)
    held = np.zeros(scene.T, dtype=bool)
    for p in phases:
        if p.kind == "contact":
            held[p.start:p.stop] = True
    pair = held[1:] & held[:-1]
    if not pair.any():
        return CaptureNoise(SLIDE_SPEED_RANGE[0], 0.0, 0.0, 0)
    W = track.wrist_pose.detach().cpu().double().numpy()
    O = scene.object_pose.detach().cpu().double().numpy()
    rel = np.linalg.solve(O, W)                                                # T_object_wrist, (T, 4, 4)
    pts = np.c_[_touch_points(track.length, side), np.ones(5)]                # (5, 4), hand frame
    point = np.einsum("tij,pj->tpi", rel, pts)[..., :3]                        # (T, 5, 3), object frame
    speed = np.linalg.norm(np.diff(point, axis=0), axis=-1).max(-1)[pair] * scene.fps
    step = np.linalg.norm(np.diff(rel[:, :3, 3], axis=0), axis=1)[pair]
    R = np.einsum("tji,tjk->tik", rel[:-1, :3, :3], rel[1:, :3, :3])[pair]
    angle = np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1.0, 1.0))
    slide = float(np.clip(np.median(speed), *SLIDE_SPEED_RANGE))
    return CaptureNoise(slide_speed=round(slide, 4), jitter_mm=float(1e3 * np.median(step)),
                        jitter_deg=float(math.degrees(np.median(angle))), frames=int(pair.sum()))
