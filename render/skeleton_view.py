"""Drawing BVH skeletons: panels on one timeline, their cameras, and the frames of a side-by-side video.

A :class:`SkeletonPanel` is one panel: a :class:`~torchhand.render.bvh_clip.SkeletonClip`, the skeleton frame it
shows at each output frame, and a :class:`~torchhand.render.camera.Camera` with one pose per output frame.
:func:`skeleton_panels` lays out the panels of several skeletons; :func:`render_skeleton_frames` draws them side by
side with pyrender (imported lazily, by :func:`~torchhand.render.backend.offscreen_renderer`).

Timeline
    Output frame k is at time ``t_k = t_0 + k / fps`` seconds; a skeleton recorded at ``fps_s`` shows its frame
    ``floor(t_k fps_s)``, and holds its last frame once it has run out. Each skeleton keeps its own clock.

Drawing
    A bone (a joint to each of its children, End Sites included) is a capsule: a cylinder between the two joints
    and a sphere at each joint, slightly wider than the bones except at wrists and End Sites. Body bones are steel
    blue and thicker (radius 0.9% of the body's measure, see :mod:`~torchhand.render.bvh_clip`), finger bones
    orange and thinner (3.5% of the hand's length). Floor, lights and background are those of
    :class:`~torchhand.render.renderer.Style`.

Panels and cameras
    * whole motion (``view="world"``): a fixed camera (or orbiting, ``RenderOptions.orbit``) framing every joint
      over the frames shown, on a floor at the lowest joint. It looks from ``RenderOptions.azimuth_deg`` when that
      is set; else, for a body whose joints name their side, at the body's front turned 30 degrees toward its
      right side; else from azimuth -60 degrees. A body is seen from at most 14 degrees above the horizontal.
    * close-up of a wrist (``view="hand"``): the camera moves with the hand frame (x toward the middle finger, y
      toward the thumb of a right hand, z out of the back of the hand), so the fingers are seen from the same side
      whatever the arm does, and the close-ups of two rigs are directly comparable: from the back of the hand, 40
      degrees round toward the thumb and 20 degrees from the fingertips' side, fingers pointing up. It frames the
      wrist, everything below it and the last quarter of the forearm, and draws only those and the two bones
      above the wrist (forearm and upper arm), so that the rest of the body does not hide the hand.
    * close-up of another joint (``view="follow"``): the camera keeps the world direction of the whole-motion view
      and moves with the joint, framing the joint and everything below it (at least 0.3 m across).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Iterator

import numpy as np

from torchhand.errors import InputValueError

from .bvh_clip import SkeletonClip, joint_side
from .camera import Camera, frame_points, look_at
from .compose import RenderOptions
from .overlay import draw_text_block, grid, grid_shape

__all__ = ["SkeletonStyle", "SkeletonPanel", "timeline", "timeline_length", "frame_indices", "skeleton_radii",
           "body_azimuth", "world_camera", "hand_camera", "follow_camera", "skeleton_panels", "bone_transforms",
           "joint_transforms", "render_skeleton_frames"]


@dataclass(frozen=True)
class SkeletonStyle:
    """Colours (linear RGBA in [0, 1]) and sizes (fractions of the rig's measure) of skeleton drawings."""

    background: tuple = (0.97, 0.97, 0.98, 1.0)
    floor: tuple = (0.62, 0.62, 0.64, 1.0)
    bone: tuple = (0.30, 0.44, 0.70, 1.0)
    joint: tuple = (0.14, 0.20, 0.36, 1.0)
    finger_bone: tuple = (0.96, 0.50, 0.12, 1.0)
    finger_joint: tuple = (0.72, 0.26, 0.05, 1.0)
    body_radius: float = 0.009  # of the body's measure (about its height or arm span)
    finger_radius: float = 0.035  # of the hand's length
    joint_scale: float = 1.35  # joint spheres / bone radius
    cap_scale: float = 1.05  # spheres at wrists and End Sites / bone radius (a capsule's cap, just covering the rim)
    sections: int = 32


@dataclass(frozen=True, eq=False)
class SkeletonPanel:
    """One panel of a skeleton video, n output frames.

    skeleton: the :class:`SkeletonClip` drawn
    frames: skeleton frame shown at each output frame, (n,) int
    camera: one pose per output frame
    view: "world", "hand" or "follow" (module docstring); joint: the followed joint's index, or -1
    floor: z of the floor plane, metres, or None for no floor
    titles: the fixed lines of the panel's label (the frame and time line is added per frame)
    drawn: the joints drawn, (J,) bool (a bone is drawn when both its joints are), or None for all
    """

    skeleton: SkeletonClip
    frames: np.ndarray
    camera: Camera
    view: str = "world"
    joint: int = -1
    floor: float | None = None
    titles: tuple = field(default_factory=tuple)
    drawn: np.ndarray | None = None

    @property
    def n(self) -> int:
        return int(len(self.frames))

    def label(self, k: int) -> list[str]:
        """The panel's text at output frame ``k``: titles, then ``frame i of F, t s`` (i counts from 0)."""
        i = int(self.frames[min(k, self.n - 1)])
        s = self.skeleton
        return [*self.titles, f"frame {i} of {s.F}, {i / s.fps:.2f} s"]


def timeline(skeletons: list[SkeletonClip], start: int, stop: int, fps: float | None = None) -> tuple[float,
                                                                                                   np.ndarray]:
    """Output times for the first skeleton's frames ``start <= k < stop`` (its clock: ``k / fps_0``), sampled at
    ``fps`` (default the first skeleton's rate). Returns (fps, times (n,) seconds)."""
    fps0 = skeletons[0].fps
    fps = float(fps or fps0)
    n = max(1, int(round((stop - start) * fps / fps0)))
    return fps, start / fps0 + np.arange(n) / fps


def timeline_length(skeletons: list[SkeletonClip]) -> int:
    """Frames of the first skeleton's clock that cover the longest skeleton."""
    fps0 = skeletons[0].fps
    return max(int(math.ceil(s.F * fps0 / s.fps - 1e-6)) for s in skeletons)


def frame_indices(skeleton: SkeletonClip, times: np.ndarray) -> np.ndarray:
    """The skeleton frame shown at each of ``times`` (n,) seconds: ``floor(t fps)``, at most the last, (n,) int."""
    i = np.floor(np.asarray(times) * skeleton.fps + 1e-6).astype(np.int64)
    return np.clip(i, 0, skeleton.F - 1)


def skeleton_radii(skeleton: SkeletonClip, style: SkeletonStyle = SkeletonStyle()) -> tuple[float, float]:
    """(body bone radius, finger bone radius), metres."""
    if skeleton.kind == "hand":
        hand = skeleton.size
        return style.finger_radius * hand, style.finger_radius * hand
    body = style.body_radius * skeleton.size
    if not skeleton.wrists:
        return body, body
    P = skeleton.positions[0]
    hand = max(float(np.linalg.norm(P[skeleton.subtree(w)] - P[w], axis=-1).max()) for w in skeleton.wrists)
    finger = style.finger_radius * hand if hand > 0 else 0.5 * body
    return body, min(finger, 0.6 * body)


def _padded(points: np.ndarray, r: float) -> np.ndarray:
    """``points`` (..., 3) and the corners of a cube of half-side ``r`` around each, (N, 3)."""
    P = points.reshape(-1, 3)
    corners = np.array([[x, y, z] for x in (-r, r) for y in (-r, r) for z in (-r, r)])
    return (P[:, None, :] + corners[None]).reshape(-1, 3)


def body_azimuth(skeleton: SkeletonClip, frames: np.ndarray) -> float | None:
    """Azimuth (degrees about +z) of a camera in front of the body, 30 degrees toward its right side; None when no
    joint names its side."""
    sides = [joint_side(n) for n in skeleton.names]
    left = [j for j, s in enumerate(sides) if s == "left" and not skeleton.is_finger[j]]
    right = [j for j, s in enumerate(sides) if s == "right" and not skeleton.is_finger[j]]
    if not left or not right:
        return None
    P = skeleton.positions[np.unique(frames)]
    d = (P[:, left].mean(1) - P[:, right].mean(1)).mean(0)  # toward the body's left
    if np.hypot(d[0], d[1]) < 1e-9:
        return None
    facing = math.degrees(math.atan2(-d[0], d[1]))  # left x up
    return facing - 30.0


def world_camera(skeleton: SkeletonClip, frames: np.ndarray, opts: RenderOptions, fps: float,
                 radius: float) -> Camera:
    """A camera framing every joint of ``skeleton`` at ``frames`` (n,) (module docstring)."""
    pts = _padded(skeleton.positions[np.unique(frames)], radius)
    az = opts.azimuth_deg
    if az is None:
        az = body_azimuth(skeleton, frames) if skeleton.kind == "body" else None
    az = -60.0 if az is None else az
    el = opts.elevation_deg if skeleton.kind == "hand" else min(opts.elevation_deg, 14.0)
    per_frame = opts.orbit_deg_per_s / fps if opts.orbit else 0.0
    return frame_points(pts, opts.width, opts.height, len(frames), azimuth_deg=az, elevation_deg=el,
                        orbit_deg_per_frame=per_frame)


# Virtual frame of the hand close-up: virtual x = hand z (back of the hand), virtual y = -hand y, virtual z = hand x
# (toward the fingers, up in the image); columns are the virtual axes in hand coordinates.
_HAND_VIEW = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])


def hand_camera(skeleton: SkeletonClip, wrist: int, frames: np.ndarray, opts: RenderOptions,
                radius: float) -> Camera:
    """A camera moving with the hand frame of ``wrist``, framing the wrist and everything below it at ``frames``
    (module docstring)."""
    H = skeleton.hand_frames(wrist)[frames]  # (n, 4, 4) T_world_hand
    inv = np.linalg.inv(H)
    P = skeleton.positions[frames][:, skeleton.subtree(wrist)]  # (n, K, 3)
    parent = skeleton.parents[wrist]
    if parent >= 0:  # and the last quarter of the forearm
        X = skeleton.positions[frames]
        P = np.concatenate([P, (0.75 * X[:, wrist] + 0.25 * X[:, parent])[:, None]], axis=1)
    local = np.einsum("nij,nkj->nki", inv[:, :3, :3], P) + inv[:, None, :3, 3]  # hand coordinates
    virtual = local @ _HAND_VIEW  # rows: (A^T h)^T
    az = -40.0 if skeleton.side(wrist) == "right" else 40.0
    cam = frame_points(_padded(virtual, radius), opts.width, opts.height, 1, azimuth_deg=az, elevation_deg=20.0)
    A = np.eye(4)
    A[:3, :3] = _HAND_VIEW
    poses = H @ A @ cam.poses[0]
    target = H[0, :3, :3] @ (_HAND_VIEW @ cam.target) + H[0, :3, 3]
    return Camera(yfov=cam.yfov, width=cam.width, height=cam.height, poses=poses, target=target)


def follow_camera(skeleton: SkeletonClip, joint: int, frames: np.ndarray, opts: RenderOptions,
                  radius: float) -> Camera:
    """A camera with the whole-motion view's direction moving with ``joint``, framing it and its descendants."""
    P = skeleton.positions[frames]
    local = P[:, skeleton.subtree(joint)] - P[:, joint:joint + 1]  # (n, K, 3) relative to the joint
    pts = _padded(np.concatenate([local.reshape(-1, 3), 0.15 * np.eye(3), -0.15 * np.eye(3)]), radius)
    az = opts.azimuth_deg
    if az is None:
        az = body_azimuth(skeleton, frames)
    cam = frame_points(pts, opts.width, opts.height, 1, azimuth_deg=-60.0 if az is None else az,
                       elevation_deg=opts.elevation_deg)
    poses = np.repeat(cam.poses, len(frames), axis=0)
    poses[:, :3, 3] += P[:, joint]
    return Camera(yfov=cam.yfov, width=cam.width, height=cam.height, poses=poses, target=cam.target + P[0, joint])


def _short(name: str) -> str:
    return str(name).split(":")[-1]


def _default_wrist(skeleton: SkeletonClip) -> int | None:
    if not skeleton.wrists:
        return None
    right = [w for w in skeleton.wrists if skeleton.side(w) == "right"]
    return (right or list(skeleton.wrists))[0]


def skeleton_panels(skeletons: list[SkeletonClip], times: np.ndarray, fps: float, opts: RenderOptions, *,
                    follow: str | None = None, close_up: bool = True,
                    style: SkeletonStyle = SkeletonStyle()) -> list[SkeletonPanel]:
    """The panels of ``skeletons`` at output ``times`` (n,) seconds, in order.

    A body gets a whole-motion panel, followed by a close-up of its right wrist (else its first wrist with
    fingers) when it has fingers; a hand rig gets the close-up alone. ``follow``: the close-up follows this joint
    instead, in every skeleton that has it (one of them must). ``close_up=False``: whole-motion panels only.
    """
    if follow is not None and not any(follow in s.names for s in skeletons):
        skeletons[0].joint_index(follow)  # UnknownNameError listing the joints
    panels = []
    for s in skeletons:
        frames = frame_indices(s, times)
        body_r, finger_r = skeleton_radii(s, style)
        r = style.joint_scale * max(body_r, finger_r)
        units = f"{s.units}{' (auto)' if s.units_auto else ''}, {s.up} up{' (auto)' if s.up_auto else ''}"
        if s.handedness == "left":
            units += ", left-handed"
        joint = None
        if close_up:
            joint = s.names.index(follow) if follow is not None and follow in s.names else _default_wrist(s)
        if s.kind == "body" or joint is None:
            cam = world_camera(s, frames, opts, fps, r)
            floor = float(s.positions[np.unique(frames)][..., 2].min()) - r
            panels.append(SkeletonPanel(s, frames, cam, "world", -1, floor, (s.name, units)))
        if joint is not None:
            drawn = None
            if joint in s.wrists:
                cam, view = hand_camera(s, joint, frames, opts, style.joint_scale * finger_r), "hand"
                drawn = np.zeros(len(s.names), dtype=bool)
                drawn[s.subtree(joint)] = True
                up = joint
                for _ in range(2):  # forearm and upper arm
                    up = s.parents[up]
                    if up < 0:
                        break
                    drawn[up] = True
            else:
                cam, view = follow_camera(s, joint, frames, opts, r), "follow"
            what = "hand frame" if view == "hand" else "following"
            titles = (s.name, f"close-up: {_short(s.names[joint])} ({what})")
            if s.kind == "hand":
                titles += (units,)
            panels.append(SkeletonPanel(s, frames, cam, view, joint, None, titles, drawn))
    return panels


# -- drawing ---------------------------------------------------------------------------------------------------


def _frames_with_z(d: np.ndarray) -> np.ndarray:
    """Rotations whose third column is each unit vector of ``d`` (N, 3), (N, 3, 3)."""
    helper = np.where(np.abs(d[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    x = np.cross(helper, d)
    x /= np.linalg.norm(x, axis=-1, keepdims=True)
    return np.stack([x, np.cross(d, x), d], axis=-1)


def bone_transforms(P: np.ndarray, bones: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Instance transforms of a unit cylinder (radius 1, z in [0, 1]) onto each bone, (B', 4, 4); bones shorter
    than 1e-9 m are left out. P: joint positions (J, 3); bones: (B, 2) parent, child; radius: (B,) metres."""
    a, b = P[bones[:, 0]], P[bones[:, 1]]
    d = b - a
    length = np.linalg.norm(d, axis=-1)
    keep = length > 1e-9
    a, d, length, radius = a[keep], d[keep], length[keep], radius[keep]
    T = np.tile(np.eye(4), (len(a), 1, 1))
    T[:, :3, :3] = _frames_with_z(d / length[:, None]) * np.stack([radius, radius, length], axis=-1)[:, None, :]
    T[:, :3, 3] = a
    return T


def joint_transforms(P: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Instance transforms of a unit sphere onto each joint, (J, 4, 4). P: (J, 3); radius: (J,) metres."""
    T = np.tile(np.eye(4), (len(P), 1, 1))
    T[:, :3, :3] *= radius[:, None, None]
    T[:, :3, 3] = P
    return T


class _SkeletonStage:
    """A panel's pyrender scene: floor and lights once, the bones and joints of each frame as instanced meshes."""

    def __init__(self, pr, panel: SkeletonPanel, style: SkeletonStyle, unit_meshes: dict):
        from .geometry import table_mesh

        self.pr, self.panel, self.unit = pr, panel, unit_meshes
        s = panel.skeleton
        body_r, finger_r = skeleton_radii(s, style)
        drawn = np.ones(len(s.names), dtype=bool) if panel.drawn is None else panel.drawn
        bones = s.bones()
        self.bones = bones[drawn[bones].all(-1)]
        self.bone_finger = s.is_finger[self.bones[:, 1]]
        self.bone_r = np.where(self.bone_finger, finger_r, body_r)
        end = np.array(s.bvh.is_end_site, dtype=bool)
        wrist = np.zeros(len(s.names), dtype=bool)
        wrist[list(s.wrists)] = True
        self.joints = np.nonzero(drawn)[0]
        self.joint_finger = s.is_finger[self.joints]
        self.joint_r = (np.where(s.is_finger, finger_r, body_r) * np.where(end | wrist, style.cap_scale, style.joint_scale))[
            self.joints]
        cam = panel.camera
        self.scene = pr.Scene(bg_color=style.background, ambient_light=(0.32, 0.32, 0.34))
        dist = float(np.linalg.norm(cam.poses[0, :3, 3] - cam.target))
        if panel.floor is not None:
            fmat = pr.MetallicRoughnessMaterial(baseColorFactor=style.floor, metallicFactor=0.0, roughnessFactor=0.9)
            self.scene.add(pr.Mesh.from_trimesh(table_mesh(cam.target[:2], panel.floor, 4.0 * dist), material=fmat,
                                                smooth=False))
        self.cam_node = self.scene.add(pr.PerspectiveCamera(yfov=cam.yfov, aspectRatio=cam.aspect,
                                                            znear=max(1e-3, 0.01 * dist), zfar=100.0 * dist),
                                       pose=cam.poses[0])
        key = np.array([-0.35, -0.45, -1.0])
        self.scene.add(pr.DirectionalLight(color=np.ones(3), intensity=2.8), pose=look_at(-key, np.zeros(3)))
        self.fill = self.scene.add(pr.PointLight(color=np.ones(3), intensity=1.6 * dist ** 2), pose=cam.poses[0])
        self._overlay: list = []

    def _instanced(self, primitive, poses: np.ndarray) -> None:
        if len(poses):
            p = self.pr.Primitive(positions=primitive.positions, normals=primitive.normals,
                                  indices=primitive.indices, material=primitive.material, poses=poses)
            self._overlay.append(self.scene.add(self.pr.Mesh(primitives=[p])))

    def set_frame(self, k: int) -> None:
        panel = self.panel
        t = int(panel.frames[min(k, panel.n - 1)])
        P = panel.skeleton.positions[t]
        for node in self._overlay:
            self.scene.remove_node(node)
        self._overlay = []
        fb, fj, J = self.bone_finger, self.joint_finger, self.joints
        self._instanced(self.unit["bone"], bone_transforms(P, self.bones[~fb], self.bone_r[~fb]))
        self._instanced(self.unit["finger_bone"], bone_transforms(P, self.bones[fb], self.bone_r[fb]))
        self._instanced(self.unit["joint"], joint_transforms(P[J[~fj]], self.joint_r[~fj]))
        self._instanced(self.unit["finger_joint"], joint_transforms(P[J[fj]], self.joint_r[fj]))
        pose = panel.camera.pose(k)
        self.scene.set_pose(self.cam_node, pose)
        self.scene.set_pose(self.fill, pose)


def _unit_meshes(pr, style: SkeletonStyle) -> dict:
    import trimesh

    cyl = trimesh.creation.cylinder(radius=1.0, height=1.0, sections=style.sections)
    cyl.apply_translation([0.0, 0.0, 0.5 - 0.5 * (cyl.bounds[0, 2] + cyl.bounds[1, 2])])  # z in [0, 1]
    ball = trimesh.creation.icosphere(subdivisions=3, radius=1.0)

    def mesh(m, color, smooth):
        mat = pr.MetallicRoughnessMaterial(baseColorFactor=color, metallicFactor=0.0, roughnessFactor=0.55)
        return pr.Mesh.from_trimesh(m, material=mat, smooth=smooth).primitives[0]

    return {"bone": mesh(cyl, style.bone, False), "finger_bone": mesh(cyl, style.finger_bone, False),
            "joint": mesh(ball, style.joint, True), "finger_joint": mesh(ball, style.finger_joint, True)}


def _rgb255(c) -> tuple:
    return tuple(int(round(255 * v)) for v in c[:3])


def render_skeleton_frames(panels: list[SkeletonPanel], opts: RenderOptions = RenderOptions(), *,
                           style: SkeletonStyle = SkeletonStyle(), progress=None) -> Iterator[np.ndarray]:
    """Composed frames (H, W, 3) uint8 of ``panels`` side by side (a near-square grid past three), one per output
    frame. ``progress``: an object with ``update(n)`` (a tqdm bar) or None.

    Raises:
        RenderBackendError: no offscreen OpenGL.
    """
    from .backend import offscreen_renderer

    if not panels:
        raise InputValueError("render_skeleton_frames: no panels to draw")
    n = max(p.n for p in panels)
    rows, cols = grid_shape(len(panels), opts.max_cols)
    renderer = offscreen_renderer(opts.width, opts.height)  # chooses the platform, then imports pyrender
    try:
        import pyrender as pr

        unit = _unit_meshes(pr, style)
        stages = [_SkeletonStage(pr, p, style, unit) for p in panels]
        flags = pr.RenderFlags.SHADOWS_DIRECTIONAL if opts.shadows else pr.RenderFlags.NONE
        key = [("body", _rgb255(style.bone)), ("fingers", _rgb255(style.finger_bone))]
        for k in range(n):
            images = []
            for stage in stages:
                stage.set_frame(k)
                with warnings.catch_warnings():  # older PyOpenGL calls numpy's deprecated tostring() on read-back
                    warnings.filterwarnings("ignore", category=DeprecationWarning, module="OpenGL")
                    color, _ = renderer.render(stage.scene, flags=flags)
                img = np.ascontiguousarray(color[..., :3])
                if opts.labels:
                    img = draw_text_block(img, stage.panel.label(k), "tl")
                if opts.legend and stage.panel.skeleton.is_finger.any():
                    img = draw_text_block(img, [t for t, _ in key], "bl", [c for _, c in key])
                images.append(img)
            yield images[0] if len(images) == 1 else grid(images, rows, cols)
            if progress is not None:
                progress.update(1)
    finally:
        renderer.delete()
