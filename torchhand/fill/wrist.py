"""The captured wrist within capture noise: a wrist track steadied against the object it holds.

A captured wrist jitters 1-5 mm and 1-2 degrees per frame against the object it holds (markers slide on skin, the
two tracks are filtered separately). A rigid grip cannot follow that: the search can only call every contact
"sliding". So, within a tolerance of the captured track (default 5 mm and 3 degrees; 0 keeps the capture exactly,
as in the paper), the wrist may move: while the hand holds the object, its pose in the object's frame is smoothed
over time (a Gaussian of ``sigma`` seconds on the object-relative track), so that a still grip stays still on the
object; the change fades in and out over ``sigma`` around the held frames; each frame's change is then limited to
the tolerance (translation scaled down, rotation shortened along its geodesic). The used track replaces the
scene's; the captured one is kept in the result (``root_pose_captured``), and the checker reports the deviation.

This is a stated deviation from Ye & Liu 2012, whose wrist is fixed, and it is on by default only for imported
captures (``torchhand fill``). Conventions: 4x4 world poses ``T_world_frame``, metres, radians; frames of the scene.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import torch

from ..errors import InputValueError
from ..geometry.poses import matrix_to_quat, quat_to_matrix, slerp, smooth_poses

__all__ = ["WristTolerance", "WristAdjustment", "steady_wrist", "parse_tolerance", "with_wrist"]


@dataclass(frozen=True)
class WristTolerance:
    """How far the used wrist may move from the captured one.

    translation: metres (default 0.005); rotation: radians (default 3 degrees); sigma: smoothing width of the
    object-relative track, seconds (default 0.1). translation = rotation = 0 keeps the capture exactly.
    """

    translation: float = 0.005
    rotation: float = math.radians(3.0)
    sigma: float = 0.1

    def __post_init__(self):
        for name in ("translation", "rotation"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputValueError(f"wrist tolerance {name}: expected a finite number >= 0, got {v!r}")
        if not (isinstance(self.sigma, (int, float)) and math.isfinite(self.sigma) and self.sigma > 0):
            raise InputValueError(f"wrist tolerance sigma: expected seconds > 0, got {self.sigma!r}")

    @property
    def fixed(self) -> bool:
        return self.translation == 0 and self.rotation == 0

    def to_json(self) -> dict:
        return {"translation_mm": 1e3 * self.translation, "rotation_deg": math.degrees(self.rotation),
                "sigma_s": self.sigma}


def parse_tolerance(text: str) -> WristTolerance:
    """``"MM,DEG"`` (e.g. ``"5,3"``; ``"0"`` or ``"0,0"``: fixed) -> :class:`WristTolerance`."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) == 1 and values[0] == 0:
        values = [0.0, 0.0]
    if len(values) != 2 or not all(math.isfinite(v) and v >= 0 for v in values):
        raise InputValueError(f"--wrist-tolerance: expected MM,DEG with two numbers >= 0 (e.g. 5,3; 0 = fixed), "
                              f"got {text!r}")
    return WristTolerance(translation=values[0] * 1e-3, rotation=math.radians(values[1]))


@dataclass(frozen=True, eq=False)
class WristAdjustment:
    """The captured and the used wrist track of one hand.

    captured, used: (T, 4, 4) world, float64; translation: |used - captured| position, (T,) metres; rotation: the
    angle between their orientations, (T,) radians; weight: how much of the steadied track was used, (T,) in [0, 1]
    """

    captured: torch.Tensor
    used: torch.Tensor
    translation: torch.Tensor
    rotation: torch.Tensor
    weight: torch.Tensor

    def summary(self) -> dict:
        return {**deviation_summary(self.translation, self.rotation), "frames_moved": int((self.weight > 0).sum())}


def steady_wrist(wrist: torch.Tensor, object_pose: torch.Tensor, held: np.ndarray, fps: float,
                 tolerance: WristTolerance = WristTolerance()) -> WristAdjustment:
    """Steady a captured wrist track against the object while it is held (module docstring).

    Args:
        wrist: captured wrist poses, (T, 4, 4) world; object_pose: (T, 4, 4) world; held: (T,) bool, the frames
        in which the hand holds the object (e.g. the contact phases); fps: frames per second.
    Returns:
        :class:`WristAdjustment`; ``used == captured`` where nothing is held or the tolerance is zero.
    """
    wrist = wrist.double()
    T = wrist.shape[0]
    held_t = torch.as_tensor(np.asarray(held, dtype=bool))
    if held_t.shape != (T,):
        raise InputValueError(f"held: expected ({T},) bool, got shape {tuple(held_t.shape)}")
    zero = torch.zeros(T, dtype=torch.float64)
    if tolerance.fixed or not held_t.any() or T < 3:
        return WristAdjustment(wrist, wrist.clone(), zero, zero.clone(), zero.clone())
    sigma = max(tolerance.sigma * fps, 0.5)
    obj = object_pose.double()
    rel = torch.linalg.solve(obj, wrist)                                    # T_object_wrist
    smooth = smooth_poses(rel, sigma)
    weight = _fade(held_t, sigma)
    target = obj @ _blend(rel, smooth, weight)                             # world
    used = torch.where((weight > 0)[:, None, None], _limit(wrist, target, tolerance), wrist)  # exact elsewhere
    dt = (used[:, :3, 3] - wrist[:, :3, 3]).norm(dim=-1)
    return WristAdjustment(wrist, used, dt, _angle(wrist, used), weight)


def with_wrist(scene, side: str, used: torch.Tensor):
    """``scene`` with the wrist track of hand ``side`` replaced by ``used (T, 4, 4)``; the track it replaces is kept
    as ``captured_wrist_pose`` (unless one is kept already: the capture stays the capture)."""
    def moved(h):
        captured = h.wrist_pose if h.captured_wrist_pose is None else h.captured_wrist_pose
        return dataclasses.replace(h, wrist_pose=used.to(h.wrist_pose), captured_wrist_pose=captured)

    hands = tuple(moved(h) if h.side == side else h for h in scene.hands)
    return dataclasses.replace(scene, hands=hands)


def deviation_summary(translation: torch.Tensor, rotation: torch.Tensor) -> dict:
    """Median and largest of a per-frame deviation: translation (T,) metres -> mm, rotation (T,) radians -> deg."""
    t, r = 1e3 * translation.numpy(), np.degrees(rotation.numpy())
    return {"translation_mm": {"median": float(np.median(t)), "max": float(t.max())},
            "rotation_deg": {"median": float(np.median(r)), "max": float(r.max())}}


def _fade(held: torch.Tensor, sigma: float) -> torch.Tensor:
    """(T,) weights: 1 on held frames, falling to 0 over ~2 sigma frames outside them (a smoothed step)."""
    x = held.double()
    half = max(1, int(math.ceil(2 * sigma)))
    k = torch.exp(-0.5 * (torch.arange(-half, half + 1, dtype=torch.float64) / sigma) ** 2)
    k = k / k.sum()
    spread = torch.nn.functional.conv1d(torch.nn.functional.pad(x[None, None], (half, half), mode="replicate"),
                                        k[None, None])[0, 0]
    return torch.where(held, torch.ones_like(x), (2 * spread).clamp(0, 1))


def _blend(a: torch.Tensor, b: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Per frame, the pose a fraction ``w`` of the way from ``a`` to ``b`` (lerp positions, slerp rotations); exactly
    ``a`` where ``w`` is 0."""
    out = a.clone()
    k = w > 0
    out[k, :3, 3] = a[k, :3, 3] + w[k, None] * (b[k, :3, 3] - a[k, :3, 3])
    out[k, :3, :3] = quat_to_matrix(slerp(matrix_to_quat(a[k, :3, :3]), matrix_to_quat(b[k, :3, :3]), w[k]))
    return out


def _limit(captured: torch.Tensor, target: torch.Tensor, tol: WristTolerance) -> torch.Tensor:
    """``target`` moved back toward ``captured`` so that each frame's change is within the tolerance."""
    d = target[:, :3, 3] - captured[:, :3, 3]
    n = d.norm(dim=-1)
    scale_t = torch.where(n > tol.translation, tol.translation / n.clamp_min(1e-300), torch.ones_like(n))
    ang = _angle(captured, target)
    scale_r = torch.where(ang > tol.rotation, tol.rotation / ang.clamp_min(1e-300), torch.ones_like(ang))
    out = captured.clone()
    out[:, :3, 3] = captured[:, :3, 3] + scale_t[:, None] * d
    q0, q1 = matrix_to_quat(captured[:, :3, :3]), matrix_to_quat(target[:, :3, :3])
    out[:, :3, :3] = quat_to_matrix(slerp(q0, q1, scale_r))
    return out


def _angle(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Rotation angle between the orientations of pose tracks a and b, (T,) radians."""
    R = a[:, :3, :3].transpose(-1, -2) @ b[:, :3, :3]
    c = ((R.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1, 1)
    return torch.arccos(c)
