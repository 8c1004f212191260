"""Phases of a capture for one hand: free hand, approach, contact, release.

The fingers are what is missing, so the rules read only the object's motion and the wrist's track:

* **hand-object distance** (:func:`hand_object_distance`): the exact distance from the object's mesh to the nearer
  of two points of the hand frame, the palm centre ``(0.45 L, 0, -0.02)`` and the grasp centre ``(0.6 L, 0,
  -0.04)`` (metres; ``L`` the hand length; the palm faces -z, so these lie where a held object touches the palm
  and where the fingers close around it);
* **the object moves**: its speed, or its angular speed times ``lever``, after a Gaussian low-pass of
  ``smooth`` seconds (capture jitter of a resting object stays below the threshold), exceeds ``moving_speed``;
* **contact** where the hand is within ``contact_distance`` of the object, or within ``approach_distance`` while
  the object moves (a moving object near the hand is carried by it); gaps shorter than ``min_gap`` seconds between
  contact frames are closed (hysteresis), then contact runs shorter than ``min_contact`` seconds are dropped;
* **approach**: up to ``margin`` seconds before a contact run, while the hand is within ``approach_distance``;
  **release**: the same after it; **free**: every other frame.

Frames are the scene's; a phase is ``[start, stop)``. Phases are contiguous, ordered and cover every frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


from ..errors import InputValueError
from ..geometry.poses import smooth_poses

__all__ = ["PHASE_KINDS", "Phase", "PhaseSettings", "hand_object_distance", "object_speed", "pose_speed", "segment_phases",
           "format_phases"]

PHASE_KINDS = ("free", "approach", "contact", "release")


@dataclass(frozen=True)
class Phase:
    """A run of frames of one kind: ``kind`` in :data:`PHASE_KINDS`, frames ``[start, stop)``."""

    kind: str
    start: int
    stop: int

    @property
    def frames(self) -> int:
        return self.stop - self.start

    def to_json(self) -> dict:
        return {"kind": self.kind, "start": self.start, "stop": self.stop}


@dataclass(frozen=True)
class PhaseSettings:
    """Thresholds of the phase rules (module docstring). Metres, seconds, m/s."""

    contact_distance: float = 0.03
    approach_distance: float = 0.10
    moving_speed: float = 0.05
    lever: float = 0.05
    smooth: float = 0.1
    min_gap: float = 0.3
    min_contact: float = 0.3
    margin: float = 0.5

    def __post_init__(self):
        for name in ("contact_distance", "approach_distance", "moving_speed", "lever", "smooth", "min_gap",
                     "min_contact", "margin"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputValueError(f"PhaseSettings.{name}: expected a finite number >= 0, got {v!r}")


def _track(scene, side: str):
    for h in scene.hands:
        if h.side == side:
            return h
    raise InputValueError(f"side: the scene has no {side!r} hand (it has {', '.join(h.side for h in scene.hands)})")


def hand_points(length: float) -> np.ndarray:
    """The palm centre and the grasp centre in the hand frame, (2, 3) metres."""
    return np.array([[0.45 * length, 0.0, -0.02], [0.6 * length, 0.0, -0.04]])


def hand_object_distance(scene, side: str) -> np.ndarray:
    """(T,) metres: the distance from the object's mesh to the nearer of the hand's palm and grasp centres."""
    import trimesh

    track = _track(scene, side)
    pts = hand_points(track.length)
    W = track.wrist_pose.detach().cpu().double().numpy()
    O = scene.object_pose.detach().cpu().double().numpy()
    world = np.einsum("tij,pj->tpi", W[:, :3, :3], pts) + W[:, None, :3, 3]          # (T, 2, 3)
    local = np.einsum("tji,tpj->tpi", O[:, :3, :3], world - O[:, None, :3, 3])       # object frame
    _, d, _ = trimesh.proximity.closest_point(scene.object.mesh, local.reshape(-1, 3))
    return d.reshape(-1, len(pts)).min(1)


def object_speed(scene, settings: PhaseSettings = PhaseSettings()) -> np.ndarray:
    """(T,) m/s: the smoothed object's speed plus its angular speed times ``settings.lever``."""
    return pose_speed(scene.object_pose, scene.fps, settings)


def pose_speed(poses, fps: float, settings: PhaseSettings = PhaseSettings()) -> np.ndarray:
    """(T,) m/s of a pose track (T, 4, 4): after a Gaussian low-pass of ``settings.smooth`` seconds, its speed plus
    its angular speed times ``settings.lever``; each frame takes the larger of its two steps."""
    poses = poses.detach().cpu().double()
    T = poses.shape[0]
    if T < 2:
        return np.zeros(T)
    if settings.smooth > 0:
        poses = smooth_poses(poses, max(settings.smooth * fps, 0.5))
    p = poses[:, :3, 3].numpy()
    R = poses[:, :3, :3].numpy()
    v = np.linalg.norm(np.diff(p, axis=0), axis=1)
    rel = np.einsum("tji,tjk->tik", R[:-1], R[1:])
    ang = np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1.0, 1.0))
    step = (v + settings.lever * ang) * fps
    return np.concatenate([step[:1], np.maximum(step[:-1], step[1:]), step[-1:]]) if len(step) > 1 else \
        np.concatenate([step, step])


def segment_phases(scene, side: str, settings: PhaseSettings = PhaseSettings()) -> tuple[Phase, ...]:
    """The phases of hand ``side`` over every frame of ``scene`` (module docstring)."""
    d = hand_object_distance(scene, side)
    return phases_from_signals(d, object_speed(scene, settings), scene.fps, settings)


def phases_from_signals(d: np.ndarray, speed: np.ndarray, fps: float,
                        settings: PhaseSettings = PhaseSettings()) -> tuple[Phase, ...]:
    """The phase rules on a hand-object distance ``d`` (T,) metres and an object speed (T,) m/s."""
    T = len(d)
    contact = (d <= settings.contact_distance) | ((speed > settings.moving_speed) & (d <= settings.approach_distance))
    contact = _close_gaps(contact, int(round(settings.min_gap * fps)))
    contact = _drop_short(contact, int(round(settings.min_contact * fps)))
    kind = np.zeros(T, dtype=np.int8)                                       # 0 free, 1 approach, 2 contact, 3 release
    kind[contact] = 2
    near = d <= settings.approach_distance
    m = int(round(settings.margin * fps))
    for start, stop in _runs(contact):
        t = start - 1
        while t >= max(0, start - m) and kind[t] == 0 and near[t]:
            kind[t] = 1
            t -= 1
        t = stop
        while t < min(T, stop + m) and kind[t] == 0 and near[t]:
            kind[t] = 3
            t += 1
    return phases_from_codes(kind)


def phases_from_codes(kind: np.ndarray) -> tuple[Phase, ...]:
    """The runs of per-frame codes (T,) (indices into :data:`PHASE_KINDS`) as phases."""
    T = len(kind)
    out, start = [], 0
    for t in range(1, T + 1):
        if t == T or kind[t] != kind[start]:
            out.append(Phase(PHASE_KINDS[int(kind[start])], start, t))
            start = t
    return tuple(out)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of the runs of True."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.nonzero(edges == 1)[0].tolist(), np.nonzero(edges == -1)[0].tolist()))


def _close_gaps(mask: np.ndarray, n: int) -> np.ndarray:
    out = mask.copy()
    runs = _runs(mask)
    for (_, a), (b, _) in zip(runs[:-1], runs[1:]):
        if b - a < n:
            out[a:b] = True
    return out


def _drop_short(mask: np.ndarray, n: int) -> np.ndarray:
    out = mask.copy()
    for a, b in _runs(mask):
        if b - a < n:
            out[a:b] = False
    return out


def format_phases(phases, fps: float) -> str:
    """A table of the phases: kind, frames and seconds."""
    lines = [f"{'phase':<9} {'frames':>13} {'seconds':>17}"]
    for p in phases:
        lines.append(f"{p.kind:<9} {p.start:>6}-{p.stop - 1:<6} {p.start / fps:>8.2f}-{p.stop / fps:<8.2f}")
    return "\n".join(lines)


def contact_fraction(phases) -> float:
    """The fraction of frames in contact phases."""
    total = sum(p.frames for p in phases)
    return sum(p.frames for p in phases if p.kind == "contact") / total if total else 0.0



