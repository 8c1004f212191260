"""Camera framing and projection.

A :class:`Camera` is a pinhole with vertical field of view ``yfov`` and one pose per frame (T, 4, 4), world,
column-vector convention; it looks along its local -z with +y up (OpenGL / pyrender). :func:`frame_points` places it
so that given world points fill the image, from a fixed direction or orbiting about the vertical (world +z) axis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from torchhand.errors import InputValueError

__all__ = ["Camera", "look_at", "frame_points"]


@dataclass(frozen=True, eq=False)
class Camera:
    """A perspective camera.

    yfov: vertical field of view, radians
    width, height: image size, pixels
    poses: ``T_world_camera`` per frame, (T, 4, 4); the camera looks along its -z, +y up
    target: the point looked at, (3,), world, metres
    """

    yfov: float
    width: int
    height: int
    poses: np.ndarray
    target: np.ndarray

    @property
    def aspect(self) -> float:
        return self.width / self.height

    def pose(self, frame: int) -> np.ndarray:
        """``T_world_camera`` at ``frame`` (the last pose for frames past the end), (4, 4)."""
        return self.poses[min(frame, len(self.poses) - 1)]

    def project(self, points: np.ndarray, frame: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates of world ``points`` (N, 3): (N, 2) as (column, row) floats, and depth (N,) metres in
        front of the camera (negative behind it)."""
        P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        inv = np.linalg.inv(self.pose(frame))
        c = P @ inv[:3, :3].T + inv[:3, 3]
        depth = -c[:, 2]
        f = 0.5 * self.height / math.tan(0.5 * self.yfov)
        with np.errstate(divide="ignore", invalid="ignore"):
            u = 0.5 * self.width + f * c[:, 0] / depth
            v = 0.5 * self.height - f * c[:, 1] / depth
        return np.stack([u, v], axis=-1), depth

    def resized(self, width: int, height: int) -> "Camera":
        return Camera(self.yfov, int(width), int(height), self.poses, self.target)


def look_at(eye: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """``T_world_camera`` (4, 4) of a camera at ``eye`` looking at ``target`` with world ``up`` up."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross(up, back)
    if np.linalg.norm(right) < 1e-9:
        right = np.array([1.0, 0.0, 0.0])
    right /= np.linalg.norm(right)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = right, np.cross(back, right), back, eye
    return T


def frame_points(points: np.ndarray, width: int, height: int, frames: int, *, azimuth_deg: float = -60.0,
                 elevation_deg: float = 28.0, yfov_deg: float = 35.0, margin: float = 1.12,
                 orbit_deg_per_frame: float = 0.0) -> Camera:
    """A camera that keeps world ``points`` (N, 3) in view over ``frames`` frames.

    The camera looks at the centre of the points' bounding box from ``azimuth_deg`` (about world +z, 0 = from +x)
    and ``elevation_deg`` above the horizontal; with ``orbit_deg_per_frame`` it turns about the vertical axis
    through that centre. The distance is the smallest at which every point projects inside the image at every
    frame, times ``margin``.
    """
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    P = P[np.isfinite(P).all(axis=1)]
    if len(P) == 0:
        raise InputValueError("frame_points: no finite points to frame")
    if width < 2 or height < 2 or frames < 1:
        raise InputValueError(f"frame_points: expected width, height >= 2 and frames >= 1, got {width}x{height}, "
                              f"{frames}")
    lo, hi = P.min(0), P.max(0)
    target = 0.5 * (lo + hi)
    yfov = math.radians(yfov_deg)
    ty = math.tan(0.5 * yfov)
    tx = ty * width / height
    el = math.radians(elevation_deg)
    azimuths = np.radians(azimuth_deg + orbit_deg_per_frame * np.arange(frames))
    # Distance needed per distinct azimuth; the largest keeps the framing steady while orbiting.
    dist = 1e-3
    unique = np.unique(np.round(azimuths, 6))
    step = max(1, len(unique) // 72)
    for az in unique[::step]:
        back = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        R = look_at(target + back, target)[:3, :3]
        c = (P - target) @ R  # camera-frame coordinates with the camera at the target
        # A point at camera coords (x, y, z) seen from distance d: depth d - z; inside iff |x| <= tx (d - z).
        need = np.maximum(np.abs(c[:, 0]) / tx, np.abs(c[:, 1]) / ty) + c[:, 2]
        dist = max(dist, float(need.max()))
    dist *= margin
    poses = np.empty((frames, 4, 4))
    for k, az in enumerate(azimuths):
        back = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        poses[k] = look_at(target + dist * back, target)
    return Camera(yfov=yfov, width=int(width), height=int(height), poses=poses, target=target)
