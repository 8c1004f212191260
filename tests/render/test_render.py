"""Headless rendering of a built-in scene: frame count, content where the camera says, overlays, reference image.

The reference image ``tests/data/render_ref_box_turn.png`` is frame 5 of the box-turn fixture clip (320x240,
downsampled 2x). After an intended change of the drawing, regenerate it with

    TORCHHAND_REGEN_RENDER_REF=1 python -m pytest -q tests/render/test_render.py -k reference

and look at the new image before committing it.
"""

from __future__ import annotations

import os
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from torchhand.render.clip import Clip, clip_from_solution
from torchhand.render.compose import RenderOptions, panel_camera, render_frames, render_hand_motion
from torchhand.render.results import load_result_dir

from .fixture_result import rest_pose_motion

REF = Path(__file__).resolve().parents[1] / "data" / "render_ref_box_turn.png"
W, H = 320, 240


@pytest.fixture(scope="module")
def rendered(box_turn_result):
    result = load_result_dir(box_turn_result)
    clip = clip_from_solution(result, result.solution(0))
    opts = RenderOptions(W, H)
    camera = panel_camera([clip], opts, clip.T, clip.fps)
    frames = list(render_frames([clip], opts, camera=camera))
    # The same view without hand and object (table only): what the background looks like at each pixel.
    plate = Clip(hands=(), fps=clip.fps, object_pose=clip.object_pose, table_height=clip.table_height)
    empty = next(iter(render_frames([plate], RenderOptions(W, H, legend=False), camera=camera)))
    return clip, camera, frames, empty


def test_frame_count_size_and_not_blank(rendered):
    clip, _, frames, _ = rendered
    assert len(frames) == clip.T == 10
    for f in frames:
        assert f.shape == (H, W, 3) and f.dtype == np.uint8
        assert f.std() > 20  # not a flat image
    assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).mean() > 0.5  # the scene moves


def test_hand_and_object_where_the_camera_projects_them(rendered):
    clip, camera, frames, empty = rendered
    t = 5
    img, bg = frames[t].astype(int), empty.astype(int)
    hand = clip.hands[0]
    mid = 0.5 * (hand.hand.capsule_a.numpy() + hand.hand.capsule_b.numpy())  # (L, 3) link-local
    P = hand.link_poses[t]
    centres = np.einsum("lij,lj->li", P[:, :3, :3], mid) + P[:, :3, 3]
    uv, depth = camera.project(centres, t)
    assert (depth > 0).all()
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
    assert inside.all(), uv[~inside]
    px = np.round(uv).astype(int)
    changed = np.abs(img[px[:, 1], px[:, 0]] - bg[px[:, 1], px[:, 0]]).sum(-1) > 40
    assert changed.mean() > 0.85, changed
    # Skin colour (red above blue) at most link centres.
    skin = img[px[:, 1], px[:, 0]]
    assert (skin[:, 0] > skin[:, 2] + 15).mean() > 0.7
    # The object (bluish, translucent) around its projected centre.
    c = clip.object_pose[t, :3, :3] @ clip.object_mesh.centroid + clip.object_pose[t, :3, 3]
    (u, v), = np.round(camera.project(c[None], t)[0]).astype(int)
    window = img[v - 3:v + 4, u - 3:u + 4].reshape(-1, 3)
    assert (np.abs(window - bg[v - 3:v + 4, u - 3:u + 4].reshape(-1, 3)).sum(-1) > 20).all()
    assert (window[:, 2] > window[:, 0] + 10).all()  # blue over the table


def test_overlay_colours_present(rendered):
    _, _, frames, _ = rendered
    img = frames[5].astype(int)
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    cyan = (r < 90) & (g > 150) & (b > 170)
    yellow = (r > 200) & (g > 150) & (b < 80)
    red = (r > 150) & (g < 70) & (b < 70)
    # The legend has one swatch of each; the scene adds dots and arrows beyond those.
    assert cyan.sum() > 40 and yellow.sum() > 40 and red.sum() > 50, (cyan.sum(), yellow.sum(), red.sum())
    legend = np.zeros_like(cyan)
    legend[H // 2:, : W // 2] = True
    assert (red & ~legend).sum() > 20  # force arrows in the scene, not only the legend swatch


def _half(img: np.ndarray) -> np.ndarray:
    h, w = img.shape[0] // 2 * 2, img.shape[1] // 2 * 2
    x = img[:h, :w].astype(np.float64)
    return np.round(0.25 * (x[0::2, 0::2] + x[1::2, 0::2] + x[0::2, 1::2] + x[1::2, 1::2])).astype(np.uint8)


def test_reference_image(rendered):
    frame = _half(rendered[2][5])
    if os.environ.get("TORCHHAND_REGEN_RENDER_REF"):
        REF.parent.mkdir(parents=True, exist_ok=True)
        iio.imwrite(REF, frame)
        pytest.skip(f"regenerated {REF}")
    ref = iio.imread(REF)
    assert ref.shape == frame.shape
    diff = np.abs(ref.astype(int) - frame.astype(int)).mean()
    assert diff < 6.0, f"mean abs difference {diff:.2f} to {REF.name} (0-255 levels)"


def test_hand_alone():
    hand, q, root = rest_pose_motion(frames=3)
    frames = render_hand_motion(q, root, hand, opts=RenderOptions(160, 120, shadows=False))
    assert frames.shape == (3, 120, 160, 3)
    bg = frames[0, 0, 0].astype(int)
    fg = np.abs(frames.astype(int) - bg).sum(-1) > 30
    assert 0.05 < fg[0].mean() < 0.9  # a hand fills part of the frame
    assert not np.array_equal(frames[0], frames[-1])  # the fingers close


def test_two_hands(two_hand_result):
    result = load_result_dir(two_hand_result)
    clip = clip_from_solution(result, result.solution(0))
    assert len(clip.hands) == 2
    opts = RenderOptions(160, 120, shadows=False, legend=False)
    camera = panel_camera([clip], opts, clip.T, clip.fps)
    img = next(iter(render_frames([clip], opts, camera=camera))).astype(int)
    for h in clip.hands:  # both wrists project into the image onto skin-coloured pixels nearby
        (u, v), = np.round(camera.project(h.link_poses[0, 4, :3, 3][None], 0)[0]).astype(int)
        assert 0 <= u < 160 and 0 <= v < 120
        win = img[max(v - 4, 0):v + 5, max(u - 4, 0):u + 5].reshape(-1, 3)
        assert ((win[:, 0] > win[:, 2] + 15) & (win[:, 0] > 150)).any()
