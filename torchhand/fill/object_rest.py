"""The captured object within capture noise: at rest where it rests, on the table where it stands.

A tracked object jitters too. ManipNet's ``mug1`` stands on the table 0.7-5.5 mm above its plane, tilted 1-6
degrees from its base, and "resting" it moves 1-14 mm/s: the table then carries it on one rim point, or not at all,
and every table contact slides. A still object with the hand away cannot pass a dynamic test like that. So, for an
imported capture, within stated limits:

* **on the table**: where the object stands on the table (its lowest point, of its convex hull, within ``near``
  of the plane, above or below, and that height changing slower than ``lift_speed`` after a Gaussian low-pass of
  ``fade / 2`` seconds: a lift or a set-down is the capture's own), its pose is rotated so that the hull face
  closest to lying flat does (when within ``level``; a face of at least ``min_face`` of the hull's area: no
  levelling for a round object) and lowered or raised so that it touches the plane; the change fades in and out
  over ``fade`` seconds beside those frames (smoothstep), and never reaches beyond ``far`` from the plane;
* **at rest**: runs of at least ``min_rest`` seconds in which the object stands on the table and its smoothed speed
  (:func:`~torchhand.fill.phases.pose_speed`) stays below ``rest_speed`` hold one pose: the median position and the
  medoid orientation of the run, when every frame of the run lies within ``hold`` (metres, radians) of it; the hold
  fades in and out over ``fade`` seconds (smoothstep) on the moving frames beside the run.

The used track replaces the scene's ``object_pose``; the captured one is kept (``Scene.captured_object_pose``, the
result's ``object_pose_captured``) and the deviation is reported. A stated deviation from Ye & Liu 2012, whose
object track is the capture as is; on by default for imported captures only. Conventions: 4x4 world poses
``T_world_object``, metres, seconds, radians; the table's normal is +z.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ..errors import InputValueError
from ..geometry.poses import matrix_to_quat
from .wrist import _angle, _blend, deviation_summary

__all__ = ["ObjectRest", "ObjectAdjustment", "steady_object", "with_object"]


@dataclass(frozen=True)
class ObjectRest:
    """Limits of the object's adjustment (module docstring). Metres, seconds, m/s, radians; ``near``, ``far``,
    ``lift_speed``: the table correction; ``rest_speed``, ``min_rest``, ``hold``: the rest hold; ``fade``: both."""

    near: float = 0.006
    far: float = 0.015
    level: float = math.radians(8.0)
    min_face: float = 0.05
    lift_speed: float = 0.03
    rest_speed: float = 0.03
    min_rest: float = 0.2
    hold: tuple = (0.005, math.radians(3.0))
    fade: float = 0.1

    def __post_init__(self):
        for name in ("near", "far", "level", "min_face", "lift_speed", "rest_speed", "min_rest", "fade"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputValueError(f"ObjectRest.{name}: expected a finite number >= 0, got {v!r}")
        if self.far <= self.near:
            raise InputValueError(f"ObjectRest: expected far > near, got near {self.near}, far {self.far}")
        if len(self.hold) != 2 or not all(math.isfinite(v) and v >= 0 for v in self.hold):
            raise InputValueError(f"ObjectRest.hold: expected (metres, radians) >= 0, got {self.hold!r}")


@dataclass(frozen=True, eq=False)
class ObjectAdjustment:
    """The captured and the used object track.

    captured, used: (T, 4, 4) world, float64; translation: |used - captured| of the position, (T,) metres;
    rotation: the angle between their orientations, (T,) radians; on_table: (T,) weight of the table correction
    in [0, 1]; resting: (T,) bool, frames holding a rest pose.
    """

    captured: torch.Tensor
    used: torch.Tensor
    translation: torch.Tensor
    rotation: torch.Tensor
    on_table: torch.Tensor
    resting: torch.Tensor

    def summary(self) -> dict:
        return {**deviation_summary(self.translation, self.rotation),
                "frames_on_table": int((self.on_table > 0).sum()), "frames_resting": int(self.resting.sum())}

    def describe(self) -> str:
        m = self.summary()
        return (f"object moved by median {m['translation_mm']['median']:.1f} mm / {m['rotation_deg']['median']:.1f} "
                f"deg (max {m['translation_mm']['max']:.1f} mm / {m['rotation_deg']['max']:.1f} deg); "
                f"{m['frames_on_table']} frames on the table, {m['frames_resting']} at rest")


def steady_object(pose: torch.Tensor, mesh, table_height: float | None, fps: float,
                  settings: ObjectRest = ObjectRest()) -> ObjectAdjustment:
    """The object track put on the table and held at rest (module docstring).

    Args:
        pose: captured object poses, (T, 4, 4) world; mesh: the object's trimesh (object frame); table_height: z of
        the table plane, or None (no table: nothing changes); fps: frames per second.
    """
    captured = pose.detach().cpu().double()
    T = captured.shape[0]
    zero = torch.zeros(T, dtype=torch.float64)
    if table_height is None or T == 0:
        return ObjectAdjustment(captured, captured.clone(), zero, zero.clone(), zero.clone(),
                                torch.zeros(T, dtype=torch.bool))
    hull = mesh.convex_hull
    V = torch.as_tensor(np.asarray(hull.vertices), dtype=torch.float64)
    centre = torch.as_tensor(np.asarray(mesh.center_mass if mesh.is_volume else hull.centroid), dtype=torch.float64)
    w_table = _table_weight(_gap(captured, V, table_height), fps, settings)
    used = _drop(_level(captured, _bases(hull, settings.min_face), centre, w_table, settings.level), V,
                 table_height, w_table)
    resting, held = _rest_runs(used, fps, w_table, settings)
    if resting.any():
        w = _fade_weight(resting, settings.fade * fps)
        used = _drop(_blend(used, held, w), V, table_height, w_table)
    return ObjectAdjustment(captured, used, (used[:, :3, 3] - captured[:, :3, 3]).norm(dim=-1),
                            _angle(captured, used), w_table, resting)


def with_object(scene, used: torch.Tensor):
    """``scene`` with ``object_pose`` replaced by ``used (T, 4, 4)``; the track it replaces is kept as
    ``captured_object_pose`` (unless one is kept already: the capture stays the capture)."""
    import dataclasses

    captured = scene.object_pose if scene.captured_object_pose is None else scene.captured_object_pose
    return dataclasses.replace(scene, object_pose=used.to(scene.object_pose), captured_object_pose=captured)


def _gap(pose: torch.Tensor, V: torch.Tensor, h: float) -> torch.Tensor:
    """(T,) height of the lowest hull vertex above the table plane (negative: below)."""
    z = torch.einsum("tj,nj->tn", pose[:, 2, :3], V) + pose[:, 2, 3, None]
    return z.min(-1).values - h


def _table_weight(gap: torch.Tensor, fps: float, s: ObjectRest) -> torch.Tensor:
    """(T,) weight of the table correction: 1 on the frames that stand on the table (within ``near`` of the plane,
    either side, with the gap changing slower than ``lift_speed``: not lifted or set down), a smoothstep to 0 over
    ``fade`` seconds beside them in time, and nothing beyond ``far`` (a smoothstep from ``near``)."""
    g = gap.numpy()
    sigma = max(0.5 * s.fade * fps, 0.5)
    half = max(1, int(math.ceil(3 * sigma)))
    k = np.exp(-0.5 * (np.arange(-half, half + 1) / sigma) ** 2)
    smooth = np.convolve(np.pad(g, half, mode="edge"), k / k.sum(), mode="valid")
    rate = np.gradient(smooth) * fps if len(g) > 1 else np.zeros_like(g)
    on = (np.abs(g) <= s.near) & (np.abs(rate) <= s.lift_speed)
    if not on.any():
        return torch.zeros_like(gap)
    x = ((s.far - gap.abs()) / (s.far - s.near)).clamp(0, 1)
    return _fade_weight(torch.as_tensor(on), s.fade * fps) * x * x * (3 - 2 * x)


def _bases(hull, min_face: float) -> torch.Tensor:
    """Outward normals (object frame) of the hull's flat faces (coplanar facets and single triangles) of at least
    ``min_face`` of its area, (B, 3)."""
    normals, areas = list(np.asarray(hull.facets_normal).reshape(-1, 3)), list(np.asarray(hull.facets_area))
    in_facet = np.zeros(len(hull.faces), dtype=bool)
    for f in hull.facets:
        in_facet[f] = True
    normals += list(np.asarray(hull.face_normals)[~in_facet])
    areas += list(np.asarray(hull.area_faces)[~in_facet])
    keep = np.asarray(areas) >= min_face * float(hull.area)
    return torch.as_tensor(np.asarray(normals, dtype=np.float64).reshape(-1, 3)[keep], dtype=torch.float64)


def _level(pose: torch.Tensor, bases: torch.Tensor, centre: torch.Tensor, w: torch.Tensor,
           limit: float) -> torch.Tensor:
    """Rotate each frame (about the centre of mass, by fraction ``w``) so that the flat face nearest to facing down
    does, where it is within ``limit`` of it."""
    out = pose.clone()
    if bases.numel() == 0:
        return out
    n = torch.einsum("tij,bj->tbi", pose[:, :3, :3], bases)               # world normals (T, B, 3)
    tilt = torch.arccos((-n[..., 2]).clamp(-1, 1))
    best = tilt.argmin(-1)
    ang = tilt.gather(1, best[:, None])[:, 0]
    nb = n[torch.arange(pose.shape[0]), best]                              # (T, 3)
    down = torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64)
    axis = torch.cross(nb, down.expand_as(nb), dim=-1)
    norm = axis.norm(dim=-1, keepdim=True)
    ok = (ang <= limit) & (norm[:, 0] > 1e-12) & (w > 0)
    if not ok.any():
        return out
    axis = axis / norm.clamp_min(1e-300)
    R = _axis_angle(axis, ang * w)                                         # (T, 3, 3)
    c = torch.einsum("tij,j->ti", pose[:, :3, :3], centre) + pose[:, :3, 3]
    newR = R @ pose[:, :3, :3]
    newp = c + torch.einsum("tij,tj->ti", R, pose[:, :3, 3] - c)
    out[ok, :3, :3] = newR[ok]
    out[ok, :3, 3] = newp[ok]
    return out


def _drop(pose: torch.Tensor, V: torch.Tensor, h: float, w: torch.Tensor) -> torch.Tensor:
    out = pose.clone()
    out[:, 2, 3] = out[:, 2, 3] - w * _gap(pose, V, h)
    return out


def _rest_runs(pose: torch.Tensor, fps: float, w_table: torch.Tensor, s: ObjectRest):
    """(T,) bool frames of the held runs and (T, 4, 4) the pose each frame is held at (its run's, or the nearest
    run's outside runs; the frame's own where no run was held)."""
    from .phases import PhaseSettings, pose_speed

    T = pose.shape[0]
    speed = pose_speed(pose, fps, PhaseSettings())
    still = (speed < s.rest_speed) & (w_table.numpy() >= 1.0)
    resting = np.zeros(T, dtype=bool)
    held = pose.clone()
    runs = []
    t = 0
    while t < T:
        if not still[t]:
            t += 1
            continue
        e = t
        while e < T and still[e]:
            e += 1
        if e - t >= max(2, math.ceil(s.min_rest * fps)):
            hp = _hold_pose(pose[t:e])
            dp = (pose[t:e, :3, 3] - hp[:3, 3]).norm(dim=-1).max()
            da = _angle(pose[t:e], hp.expand(e - t, 4, 4)).max()
            if dp <= s.hold[0] and da <= s.hold[1]:
                runs.append((t, e, hp))
                resting[t:e] = True
        t = e
    if not runs:
        return torch.as_tensor(resting), held
    for t in range(T):                     # each frame's nearest run, by the distance to its nearer end
        k = int(np.argmin([0 if a <= t < b else min(abs(t - a), abs(t - (b - 1))) for a, b, _ in runs]))
        held[t] = runs[k][2]
    return torch.as_tensor(resting), held


def _hold_pose(run: torch.Tensor) -> torch.Tensor:
    """The median position and the medoid orientation (least summed chordal distance) of a run of poses."""
    q = matrix_to_quat(run[:, :3, :3])
    dist = 1 - (q @ q.T).abs()                                             # chordal-like distance on rotations
    k = int(dist.sum(-1).argmin())
    out = run[k].clone()
    out[:3, 3] = run[:, :3, 3].median(dim=0).values
    return out


def _fade_weight(resting: torch.Tensor, width: float) -> torch.Tensor:
    """1 on resting frames, a smoothstep to 0 over ``width`` frames beside them."""
    T = resting.shape[0]
    idx = np.flatnonzero(resting.numpy())
    t = np.arange(T)
    dist = np.abs(t[:, None] - idx[None]).min(1).astype(np.float64)
    x = np.clip(1 - dist / (max(width, 1.0) + 1), 0, 1)
    return torch.as_tensor(x * x * (3 - 2 * x))


def _axis_angle(axis: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """Rodrigues: (T, 3) unit axes, (T,) angles -> (T, 3, 3)."""
    K = torch.zeros(axis.shape[0], 3, 3, dtype=axis.dtype)
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
    K = K - K.transpose(1, 2)
    s, c = torch.sin(angle)[:, None, None], torch.cos(angle)[:, None, None]
    return torch.eye(3, dtype=axis.dtype) + s * K + (1 - c) * (K @ K)
