"""`torchhand render` of BVH files: units, up axis and rig kind, the timeline, skeleton pixels where the cameras
project the joints, the CLI's outputs, and one-line errors with exit code 2.

The shared reference data (``test_freebvh.bvh``: a Mixamo body with fingers, 30 fps, cm; ``hello-world.bvh``: a
Leap Motion hand, about 37 fps, mm, y up) is found through ``TORCHHAND_SHARED_DATA``; tests that need it skip when it
is absent, and the drawing tests skip when no offscreen OpenGL can be opened.
"""

from __future__ import annotations

from dataclasses import replace

import imageio.v3 as iio
import numpy as np
import pytest

from torchhand.cli import main
from torchhand.errors import InputValueError
from torchhand.render.bvh_clip import guess_units, joint_side, skeleton_from_bvh
from torchhand.render.compose import RenderOptions
from torchhand.render.skeleton_view import (frame_indices, render_skeleton_frames, skeleton_panels, skeleton_radii,
                                            timeline, timeline_length)

from tests.conftest import shared_path

W, H = 160, 120


def _body():
    return shared_path("mocap", "bvh_python_tests", "test_freebvh.bvh")


def _hand():
    return shared_path("mocap", "leap_hand_bvh", "hello-world.bvh")


def _needs_gl():
    from torchhand.render.backend import RenderBackendError, offscreen_renderer

    try:
        offscreen_renderer(16, 16).delete()
    except RenderBackendError as err:
        pytest.skip(f"no offscreen OpenGL here: {err}")


def _one_line_error(capsys, *needles):
    err = capsys.readouterr().err.strip()
    assert err.startswith("torchhand: error:") and "\n" not in err, err
    for n in needles:
        assert n in err, err
    return err


# A body standing along +z in metres (head above the feet along z), with a two-joint finger on the right hand.
Z_UP_BODY = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0.95
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Spine
  {
    OFFSET 0 0 0.5
    CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT Head
    {
      OFFSET 0 0 0.25
      CHANNELS 3 Zrotation Xrotation Yrotation
      End Site
      {
        OFFSET 0 0 0.2
      }
    }
    JOINT RightHand
    {
      OFFSET -0.6 0 0.1
      CHANNELS 3 Zrotation Xrotation Yrotation
      JOINT RightIndex1
      {
        OFFSET -0.1 0 0
        CHANNELS 3 Zrotation Xrotation Yrotation
        End Site
        {
          OFFSET -0.04 0 0
        }
      }
    }
  }
  JOINT LeftFoot
  {
    OFFSET 0.1 0 -0.9
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 0.1 -0.05
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.05
0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0
0 0.1 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0
"""


def test_units_up_and_kind_of_the_reference_rigs():
    body = skeleton_from_bvh(_body())
    assert (body.kind, body.units, body.up, body.units_auto, body.up_auto) == ("body", "cm", "y", True, True)
    assert sorted(body.names[w] for w in body.wrists) == ["mixamorig:LeftHand", "mixamorig:RightHand"]
    assert body.is_finger.sum() == 2 * 5 * 4  # three joints and an End Site per finger, two hands
    height = np.ptp(body.positions[0, :, 2])  # z-up world, metres
    assert 1.4 < height < 2.1, height
    hand = skeleton_from_bvh(_hand())
    assert (hand.kind, hand.units, hand.up) == ("hand", "mm", "y")
    assert [hand.names[w] for w in hand.wrists] == ["rHand"] and joint_side("rHand") == "right"
    assert 0.12 < hand.size < 0.25  # wrist to middle fingertip, metres
    cm = skeleton_from_bvh(_hand(), units="cm")
    assert not cm.units_auto and np.allclose(cm.positions, 10 * hand.positions)
    z = skeleton_from_bvh(_hand(), up="z")  # the file's y becomes world y instead of world z
    assert np.allclose(z.positions[..., 1], hand.positions[..., 2])


def test_z_up_body_and_unit_rule(tmp_path):
    f = tmp_path / "zup.bvh"
    f.write_text(Z_UP_BODY)
    s = skeleton_from_bvh(f)
    assert (s.kind, s.units, s.up) == ("body", "m", "z")
    assert s.positions[0, s.names.index("Head"), 2] > s.positions[0, s.names.index("LeftFoot"), 2] + 1.0
    assert s.wrists == (s.names.index("RightHand"),)
    assert [joint_side(n) for n in ("mixamorig:RightHand", "L_wrist", "lThumb1", "Root", "LowerBack")] == \
        ["right", "left", "left", None, None]
    assert guess_units(170.0, "body") == "cm" and guess_units(1700.0, "body") == "mm"
    assert guess_units(1.9, "hand") == "dm" and guess_units(0.2, "hand") == "m"
    with pytest.raises(InputValueError, match="--bvh-units"):
        skeleton_from_bvh(f, units="inch")


def test_timeline_keeps_each_file_on_its_own_clock():
    body, hand = skeleton_from_bvh(_body()), skeleton_from_bvh(_hand())
    assert body.fps == pytest.approx(30.0, rel=1e-4) and hand.fps == pytest.approx(1 / 0.027)
    T = timeline_length([body, hand])  # the body (69 / 30 fps = 2.3 s) outlasts the hand (82 / 37 fps = 2.2 s)
    assert T == max(69, int(np.ceil(82 * 0.027 * body.fps - 1e-6)))
    fps, times = timeline([body, hand], 30, 36, None)
    assert fps == body.fps and np.allclose(times, np.arange(30, 36) / body.fps)
    assert frame_indices(body, times).tolist() == list(range(30, 36))
    assert frame_indices(hand, times).tolist() == [int(np.floor(t / 0.027 + 1e-6)) for t in times]
    fps, times = timeline([body, hand], 0, 30, 15.0)  # half the rate: every other body frame
    assert len(times) == 15 and frame_indices(body, times).tolist() == list(range(0, 30, 2))
    assert frame_indices(hand, np.array([100.0])).tolist() == [hand.F - 1]  # holds its last frame


def _segment_distance(px: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of pixels (N, 2) to segments a -> b (B, 2): (N, B)."""
    d = b - a
    L2 = np.maximum((d ** 2).sum(-1), 1e-12)
    t = np.clip(((px[:, None, :] - a[None]) * d[None]).sum(-1) / L2, 0.0, 1.0)
    return np.linalg.norm(px[:, None, :] - (a[None] + t[..., None] * d[None]), axis=-1)


@pytest.fixture(scope="module")
def drawn():
    """The Mixamo body (whole motion and right-hand close-up) and the Leap hand (close-up), output frames 20-22,
    160x120, without labels and shadows; and the same views with every skeleton moved far out of sight."""
    _needs_gl()
    skeletons = [skeleton_from_bvh(_body()), skeleton_from_bvh(_hand())]
    fps, times = timeline(skeletons, 20, 23)
    opts = RenderOptions(W, H, shadows=False, labels=False, legend=False)
    panels = skeleton_panels(skeletons, times, fps, opts)
    frames = list(render_skeleton_frames(panels, opts))
    away = []
    for p in panels:
        T = p.skeleton.transforms.copy()
        T[..., :3, 3] += 1e4
        away.append(replace(p, skeleton=replace(p.skeleton, transforms=T)))
    plates = list(render_skeleton_frames(away, opts))
    return panels, frames, plates


def test_panels_and_not_blank(drawn):
    panels, frames, _ = drawn
    assert [(p.view, p.skeleton.name) for p in panels] == [("world", "test_freebvh.bvh"),
                                                           ("hand", "test_freebvh.bvh"),
                                                           ("hand", "hello-world.bvh")]
    assert panels[1].skeleton.names[panels[1].joint] == "mixamorig:RightHand"
    assert panels[0].floor is not None and panels[1].floor is None
    drawn = panels[1].drawn
    hand = panels[1].skeleton.subtree(panels[1].joint)  # the wrist and one hand's 20 finger joints
    assert len(hand) == 21 and drawn[hand].all() and drawn.sum() == 21 + 2  # and the forearm and upper arm joints
    assert len(frames) == 3
    for f in frames:
        assert f.shape == (H, 3 * W + 4, 3) and f.dtype == np.uint8
        for i in range(3):
            assert f[:, i * (W + 2): i * (W + 2) + W].std() > 10


@pytest.mark.parametrize("k", [0, 2])
def test_skeleton_pixels_where_the_joints_project(drawn, k):
    panels, frames, plates = drawn
    for i, p in enumerate(panels):
        img = frames[k][:, i * (W + 2): i * (W + 2) + W].astype(int)
        bg = plates[k][:, i * (W + 2): i * (W + 2) + W].astype(int)
        s = p.skeleton
        P = s.positions[p.frames[k]]
        bones = s.bones()
        if p.drawn is not None:  # a hand close-up draws the hand, forearm and upper arm only
            bones = bones[p.drawn[bones].all(-1)]
        uv, depth = p.camera.project(P, k)
        assert (depth[bones].min(-1) > 0).any()
        body_r, finger_r = skeleton_radii(s)
        radius = np.where(s.is_finger[bones[:, 1]], finger_r, body_r)
        f = 0.5 * H / np.tan(0.5 * p.camera.yfov)
        mid_depth = depth[bones].mean(-1)
        r_px = f * radius / np.maximum(mid_depth, 1e-9)
        a, b = uv[bones[:, 0]], uv[bones[:, 1]]
        mid = 0.5 * (a + b)
        inside = (mid[:, 0] >= 0) & (mid[:, 0] < W) & (mid[:, 1] >= 0) & (mid[:, 1] < H) & (mid_depth > 0)
        changed = np.abs(img - bg).sum(-1) > 40
        # Every bone thick enough to cover its centre pixel is drawn there.
        thick = inside & (r_px >= 1.0)
        assert thick.sum() >= 5, (i, thick.sum())
        m = np.floor(mid[thick]).astype(int)  # pixel x covers columns [x, x + 1)
        hit = changed[np.clip(m[:, 1], 0, H - 1), np.clip(m[:, 0], 0, W - 1)]
        assert hit.mean() > 0.9, (i, hit.mean())
        # And nothing is drawn away from the projected bones and joints.
        ys, xs = np.nonzero(changed)
        px = np.stack([xs, ys], axis=-1).astype(float)
        front = (depth[bones] > 0).all(-1)
        near = _segment_distance(px, a[front], b[front]) <= (1.6 * r_px[front] + 2.0)[None]
        assert near.any(-1).mean() > 0.98, (i, near.any(-1).mean())
        if i == 0:  # the whole body is in view and upright: head above feet in the image
            names = [n.split(":")[-1] for n in s.names]
            head, foot = uv[names.index("Head")], uv[names.index("LeftFoot")]
            assert head[1] < foot[1] - 0.3 * H
            assert ((uv >= 0) & (uv < [W, H])).all()


def test_cli_body_with_hand_beside(tmp_path, capsys):
    _needs_gl()
    out = tmp_path / "frames"
    assert main(["render", str(_body()), "--compare", str(_hand()), "--out", str(out), "--format", "png",
                 "--size", f"{W}x{H}", "--frames", "10:13", "--no-progress", "--no-shadows"]) == 0
    assert f"3 frames, {3 * W + 4}x{H}, 3 panel(s), png" in capsys.readouterr().out
    files = sorted(out.iterdir())
    assert [f.name for f in files] == ["frame_00000.png", "frame_00001.png", "frame_00002.png"]
    img = iio.imread(files[0])
    assert img.shape == (H, 3 * W + 4, 3) and img.std() > 10
    panels = [img[:, i * (W + 2): i * (W + 2) + W].astype(int) for i in range(3)]
    assert np.abs(panels[0] - panels[1]).mean() > 2 and np.abs(panels[1] - panels[2]).mean() > 2
    gif = tmp_path / "two.gif"
    assert main(["render", str(_body()), str(_hand()), "--out", str(gif), "--size", f"{W}x{H}", "--frames", "0:2",
                 "--no-close-up", "--bvh-units", "cm,mm", "--no-progress", "--no-shadows"]) == 0
    assert f"2 frames, {2 * W + 2}x{H}, 2 panel(s), gif" in capsys.readouterr().out
    assert iio.imread(gif, index=None).shape == (2, H, 2 * W + 2, 3)


def test_cli_bad_bvh_input(tmp_path, capsys):
    assert main(["render", str(tmp_path / "missing.bvh"), "--out", str(tmp_path / "x.gif")]) == 2
    _one_line_error(capsys, "missing.bvh", "does not exist")
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT hips\n{\n  OFFSET 0 0 0\n  CHANNELS 2 Xposition Yrotation\n}\nMOTION\nFrames: 1\n"
                   "Frame Time: 0.1\n0 zero\n")
    assert main(["render", str(bad), "--out", str(tmp_path / "x.gif")]) == 2
    _one_line_error(capsys, "bad.bvh:10", "non-numeric")
    assert not (tmp_path / "x.gif").exists()


def test_cli_bad_bvh_options(tmp_path, capsys):
    body, hand = str(_body()), str(_hand())
    out = str(tmp_path / "x.gif")
    for args, needle in ((["--bvh-units", "inch"], "--bvh-units"), (["--bvh-units", "cm,mm,dm"], "--bvh-units"),
                         (["--bvh-up", "x"], "--bvh-up"), (["--follow", "NoSuchJoint"], "NoSuchJoint"),
                         (["--frames", "0:500"], "--frames"), (["--grid"], "--grid"),
                         (["--compare", str(tmp_path)], "BVH files cannot")):
        assert main(["render", body, "--compare", hand, "--out", out, "--no-progress", *args]) == 2, args
        _one_line_error(capsys, needle)
    assert main(["render", str(tmp_path), str(tmp_path), "--out", out]) == 2
    _one_line_error(capsys, "RESULT_DIR")
    assert main(["render", str(tmp_path), "--bvh-units", "cm", "--out", out]) == 2
    _one_line_error(capsys, "--bvh-units", ".bvh inputs only")
