"""Rendering whole videos: shared framing and force scale for one or more panels, labels, legend, grid, writing.

:func:`render_frames` yields composed frames for a list of :class:`~torchhand.render.clip.Clip` (one panel each,
side by side in a grid); :func:`write_video` streams them into an mp4 / GIF / PNG directory;
:func:`render_hand_motion` draws a hand alone from joint angles and wrist poses (for any method's results).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from torchhand.errors import InputValueError

from .camera import Camera, frame_points
from .clip import Clip, clip_from_hand, clip_points, force_scale
from .overlay import draw_legend, draw_text_block, grid, grid_shape

__all__ = ["RenderOptions", "default_azimuth", "panel_camera", "render_frames", "write_video",
           "render_hand_motion"]


@dataclass(frozen=True)
class RenderOptions:
    """How to draw.

    width, height: size of one panel, pixels
    orbit: turn the camera about the vertical axis, ``orbit_deg_per_s`` degrees per second of the clip
    azimuth_deg: viewing direction about world +z (None: chosen from the hands' placement); elevation_deg above
        the horizontal
    shadows: cast the key light's shadows (about twice the rendering time on a CPU)
    labels, legend: draw each panel's text lines and the colour / force-scale key
    max_cols: at most this many panels per row (None: near-square)
    """

    width: int = 640
    height: int = 480
    orbit: bool = False
    orbit_deg_per_s: float = 30.0
    azimuth_deg: float | None = None
    elevation_deg: float = 28.0
    shadows: bool = True
    labels: bool = True
    legend: bool = True
    max_cols: int | None = None


def _rgb255(c) -> tuple:
    return tuple(int(round(255 * v)) for v in c[:3])


def default_azimuth(clip: Clip) -> float:
    """A viewing azimuth (degrees about world +z) that shows the hands: for two hands, perpendicular to the line
    between the wrists; for one hand, 120 degrees round from the wrist's side of the object (toward the thumb for
    a right hand), so the grasping fingers are seen from the side and front. A table with an edge (a block) is
    kept behind the object: a view from the table's side turns round."""
    az = _hand_azimuth(clip)
    if clip.table_extent is None or clip.object_pose is None:
        return az
    x0, x1, y0, y1 = clip.table_extent
    away = clip.object_pose[:, :2, 3].mean(0) - np.array([0.5 * (x0 + x1), 0.5 * (y0 + y1)])
    if away @ np.array([math.cos(math.radians(az)), math.sin(math.radians(az))]) < 0:
        az += 180.0
    return az


def _hand_azimuth(clip: Clip) -> float:
    if not clip.hands:
        return -60.0
    wrists = [h.link_poses[:, 0, :3, 3].mean(0) for h in clip.hands]
    if len(wrists) == 2:
        sides = [getattr(h.hand, "side", "right") for h in clip.hands]
        right, left = (wrists[0], wrists[1]) if sides[0] != "left" else (wrists[1], wrists[0])
        d = right - left
        return math.degrees(math.atan2(d[1], d[0])) - 90.0
    center = clip.object_pose[:, :3, 3].mean(0) if clip.object_pose is not None else None
    if center is None:  # hand alone: look at the palm side, from the thumb side
        R = clip.hands[0].link_poses[0, 0, :3, :3]
        d = -R[:, 2] + 0.6 * R[:, 1]
        return math.degrees(math.atan2(d[1], d[0]))
    d = wrists[0] - center
    if np.hypot(d[0], d[1]) < 1e-6:
        return -60.0
    turn = 120.0 if getattr(clip.hands[0].hand, "side", "right") != "left" else -120.0
    return math.degrees(math.atan2(d[1], d[0])) + turn


def panel_camera(clips: list[Clip], opts: RenderOptions, frames: int, fps: float) -> Camera:
    """One camera for all panels: framed on the union of the clips' hands and objects."""
    pts = np.concatenate([clip_points(c) for c in clips])
    az = opts.azimuth_deg if opts.azimuth_deg is not None else default_azimuth(clips[-1])
    per_frame = opts.orbit_deg_per_s / fps if opts.orbit else 0.0
    return frame_points(pts, opts.width, opts.height, frames, azimuth_deg=az, elevation_deg=opts.elevation_deg,
                        orbit_deg_per_frame=per_frame)


def render_frames(clips: list[Clip], opts: RenderOptions = RenderOptions(), *, camera: Camera | None = None,
                  progress=None) -> Iterator[np.ndarray]:
    """Composed frames (H, W, 3) uint8 of ``clips`` drawn side by side, as many as the longest clip has (shorter
    ones hold their last frame). ``progress``: an object with ``update(n)`` (a tqdm bar) or None.

    Raises:
        RenderBackendError: no offscreen OpenGL.
    """
    from .renderer import ClipRenderer, Style

    if not clips:
        raise InputValueError("render_frames: no clips to draw")
    for c in clips:
        if c.T < 1:
            raise InputValueError("render_frames: a clip has no frames")
    frames = max(c.T for c in clips)
    fps = clips[0].fps
    if camera is None:
        camera = panel_camera(clips, opts, frames, fps)
    pts = np.concatenate([clip_points(c) for c in clips])
    extent = float(np.ptp(pts, axis=0).max())
    mpn, npc = force_scale(clips, 0.3 * extent)
    style = Style(metres_per_newton=mpn, shadows=opts.shadows, dot_radius=max(0.0025, 0.012 * extent),
                  arrow_radius=max(0.001, 0.005 * extent), head_radius=max(0.0028, 0.013 * extent),
                  head_length=max(0.007, 0.03 * extent))
    colors = {"contact": _rgb255(style.contact), "env_contact": _rgb255(style.env_contact),
              "force": _rgb255(style.force)}
    has_forces = any(c.contact_force is not None or c.env_contact_force is not None for c in clips)
    rows, cols = grid_shape(len(clips), opts.max_cols)
    with ClipRenderer(opts.width, opts.height, style) as renderer:
        stages = [renderer.stage(c, camera) for c in clips]
        for f in range(frames):
            panels = []
            for clip, stage in zip(clips, stages):
                img = stage.render(f)
                if opts.labels and clip.labels:
                    img = draw_text_block(img, clip.labels, "tl")
                if opts.legend:
                    has_c = clip.contact_mask is not None and bool(clip.contact_mask.any())
                    has_e = clip.env_contact_mask is not None and bool(clip.env_contact_mask.any())
                    img = draw_legend(img, npc if has_forces and (has_c or has_e) else None, has_c, has_e, colors)
                panels.append(img)
            yield panels[0] if len(panels) == 1 else grid(panels, rows, cols)
            if progress is not None:
                progress.update(1)


def write_video(clips: list[Clip], out, fmt: str, opts: RenderOptions = RenderOptions(), *, fps: float | None = None,
                progress=None):
    """Render ``clips`` and write them to ``out`` (mp4 / gif file, or a directory of PNG frames for "png").

    Returns the output path. Raises :class:`~torchhand.render.backend.RenderBackendError` when ffmpeg or offscreen
    OpenGL are missing (checked before rendering starts for ffmpeg).
    """
    from .video import FrameWriter, check_writer

    check_writer(fmt)
    fps = float(fps or clips[0].fps)
    with FrameWriter(out, fmt, fps, frames=max(c.T for c in clips)) as writer:
        for frame in render_frames(clips, opts, progress=progress):
            writer.write(frame)
    return writer.out


def render_hand_motion(q, root, hand=None, *, opts: RenderOptions = RenderOptions(), fps: float = 30.0,
                       joint_names=None, labels=()) -> np.ndarray:
    """Frames of a hand alone, (T, H, W, 3) uint8.

    q: finger joint angles, (T, D), radians, in ``joint_names`` order (default: the hand's)
    root: wrist poses ``T_world_hand``, (T, 4, 4), world, metres
    hand: :class:`~torchhand.hand.HandModel` (default: the default right hand)
    """
    clip = clip_from_hand(np.asarray(q), np.asarray(root), hand, fps=fps, joint_names=joint_names, labels=labels)
    return np.stack(list(render_frames([clip], opts)))
