"""The captured fingers as a reference (torchhand.fill.reference): fingertips from the ManipNet hand BVH in the
scene's world, the comparison of synthesized with captured fingers, and its figure."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from tests.conftest import shared_data_dir
from torchhand.errors import InputValueError, ShapeError
from torchhand.fill.reference import (CONTACT_DISTANCE, FINGERS, _source_joints, captured_fingertips,
                                      compare_fingers, plot_comparison, solution_fingertips)
from torchhand.hand import default_hand

MUG = shared_data_dir() / "mocap" / "manipnet" / "mug1"
needs_mug = pytest.mark.skipif(not (MUG / "rightHand.bvh").is_file(),
                               reason=f"ManipNet mug1 capture not found under {MUG} (set TORCHHAND_SHARED_DATA)")


@pytest.fixture(scope="module")
def mug():
    from torchhand.scene.mocap import manipnet_scene
    return manipnet_scene(MUG, fps=30.0, hands=("right",))


@pytest.fixture(scope="module")
def tips(mug):
    return captured_fingertips(mug, "right")


def _mesh_distance(scene, points, frames):
    """(T', F) metres: world points (T', F, 3) at scene ``frames`` (a slice) to the object's mesh, trimesh in the
    object frame."""
    import trimesh
    O = scene.object_pose.numpy()[frames]
    local = np.einsum("tji,tpj->tpi", O[:, :3, :3], points - O[:, None, :3, 3])
    _, d, _ = trimesh.proximity.closest_point(scene.object.mesh, local.reshape(-1, 3))
    return d.reshape(points.shape[:2])


@needs_mug
def test_captured_fingertips_sit_on_the_hand(mug, tips):
    """Shape, finite; the source's wrist joint read the same way lands on the scene's wrist (frame mapping and
    conversion); fingertips 10-22 cm from the wrist, toward +x, thumb on the thumb side (+y, right hand)."""
    assert tips.shape == (mug.T, 5, 3) and tips.dtype == np.float64 and np.isfinite(tips).all()
    W = mug.hands[0].wrist_pose.numpy()
    wrist = _source_joints(mug, "right", lambda clip, j: [j])[:, 0]
    np.testing.assert_allclose(wrist, W[:, :3, 3], atol=1e-9)
    local = np.einsum("tji,tfj->tfi", W[:, :3, :3], tips - W[:, None, :3, 3])     # hand frame
    reach = np.linalg.norm(local, axis=-1)
    assert (np.median(reach, 0) > 0.10).all() and (np.median(reach, 0) < 0.22).all()
    assert reach.max() < 1.3 * mug.hands[0].length
    assert (np.median(local[..., 0], 0) > 0.05).all()                              # toward the fingertips
    y = np.median(local[..., 1], 0)
    assert y[0] > y[1] > y[2] > y[3] > y[4]                                          # thumb .. little along -y


@needs_mug
def test_captured_fingertips_touch_the_mug_while_it_is_held(mug, tips):
    """Held (segment 614-674): index, middle and ring within 2 cm of the mug at the median; away at the start."""
    d = _mesh_distance(mug, tips[614:674], slice(614, 674))
    assert (np.median(d[:, 1:4], 0) < 0.02).all() and (np.median(d, 0) < 0.03).all()
    assert (_mesh_distance(mug, tips[:30], slice(0, 30)) > 0.05).all()


@needs_mug
def test_captured_fingertips_follow_the_scene_frames(mug, tips):
    """A slice of the scene reads the same fingertips; without a source, or a source BVH without fingers: None."""
    np.testing.assert_allclose(captured_fingertips(mug.with_frames(614, 674), "right"), tips[614:674], atol=1e-12)
    half = mug.with_frames(600, 700).resample(15.0)                   # source frames at half the rate
    np.testing.assert_allclose(captured_fingertips(half, "right"), tips[600:700:2], atol=1e-9)
    assert captured_fingertips(dataclasses.replace(mug, source=None), "right") is None
    objsrc = dataclasses.replace(mug.source, wrists=(("right", str(MUG / "mug1.bvh"), "mug1"),))
    assert captured_fingertips(dataclasses.replace(mug, source=objsrc), "right") is None
    with pytest.raises(InputValueError, match="side: .*no 'left' hand"):
        captured_fingertips(mug, "left")


@needs_mug
def test_compare_captured_with_itself_and_a_shifted_copy(mug, tips, tmp_path):
    same = compare_fingers(tips, None, mug, "right")
    s = same.summary()
    assert s["frames"] == mug.T and s["tip_distance_mm"]["median"] == 0.0 and s["tip_distance_mm"]["p90"] == 0.0
    assert s["contact_agreement"] == 1.0 and set(s["contact_agreement_per_finger"].values()) == {1.0}
    assert same.captured_contact[614:674, 1:4].mean() > 0.6 and not same.captured_contact[:30].any()
    # 1 cm off along world x, no synthesized contact given as all False; only the solved half compared
    frames = np.zeros(mug.T, bool)
    frames[: mug.T // 2] = True
    off = compare_fingers(tips + np.array([0.01, 0.0, 0.0]), np.zeros((mug.T, 5), bool), mug, "right",
                          frames=frames)
    o = off.summary()
    assert o["frames"] == mug.T // 2 and abs(o["tip_distance_mm"]["median"] - 10.0) < 1e-6
    expect = 1.0 - off.captured_contact[frames].mean(0)
    np.testing.assert_allclose([o["contact_agreement_per_finger"][f] for f in FINGERS], expect, atol=1e-4)
    assert o["contact_agreement"] == pytest.approx((~off.captured_contact[frames].any(1)).mean(), abs=1e-4)
    png = plot_comparison(off, tmp_path / "fingers.png", fps=mug.fps, title="mug1")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


@needs_mug
def test_compare_rejects_bad_input(mug, tips):
    with pytest.raises(ShapeError, match="fingertips"):
        compare_fingers(tips[:, :4], None, mug, "right")
    with pytest.raises(ShapeError, match="contact"):
        compare_fingers(tips, np.zeros((mug.T, 4), bool), mug, "right")
    with pytest.raises(InputValueError, match="contact_distance"):
        compare_fingers(tips, None, mug, "right", contact_distance=-1.0)
    with pytest.raises(InputValueError, match="no captured fingers"):
        compare_fingers(tips, None, dataclasses.replace(mug, source=None), "right")
    empty = compare_fingers(np.full_like(tips, np.nan), None, mug, "right").summary()
    assert empty["frames"] == 0 and empty["tip_distance_mm"]["median"] is None


def test_solution_fingertips_of_the_built_in_hand():
    """Rest pose on the identity: each pad point ahead of the wrist, the middle one near the hand length; moving the
    wrist moves the fingertips rigidly; shapes are checked."""
    hand = default_hand("right", 0.19)
    q = hand.q_rest[None].expand(3, -1)
    eye = torch.eye(4, dtype=torch.float64).expand(3, 4, 4)
    rest = solution_fingertips(hand, q, eye)
    assert rest.shape == (3, 5, 3) and hand.finger_names == FINGERS
    assert (rest[..., 0] > 0.05).all() and 0.7 * 0.19 < np.linalg.norm(rest[0, 2]) < 1.05 * 0.19
    c, s = np.cos(0.7), np.sin(0.7)
    A = np.array([[c, -s, 0, 0.3], [s, c, 0, -0.1], [0, 0, 1, 0.8], [0, 0, 0, 1.0]])
    moved = solution_fingertips(hand, q, np.broadcast_to(A, (3, 4, 4)))
    np.testing.assert_allclose(moved, rest @ A[:3, :3].T + A[:3, 3], atol=1e-12)
    with pytest.raises(ShapeError, match="q"):
        solution_fingertips(hand, q[:, :5], eye)
    with pytest.raises(ShapeError, match="root_pose"):
        solution_fingertips(hand, q, eye[:2])


def test_contact_distance_default_is_documented():
    assert 0.0 < CONTACT_DISTANCE <= 0.03


@needs_mug
def test_reference_report_writes_figures_and_a_plot_per_motion(mug, tmp_path):
    """reference_report on two motions of a mug clip (the rest pose, and the rest pose with the fingers curled):
    a summary per motion in stats form, a PNG each, the frame selection honoured; a model without the five named
    fingers is not compared."""
    from torchhand.fill.reference import reference_report
    from torchhand.hand.mount import track_hand

    clip = mug.with_frames(620, 650)
    hand = track_hand(clip.hands[0]).to("cpu", torch.float64)
    rest = hand.q_rest.double().expand(clip.T, -1)[:, None]                  # (T, H=1, D)
    lim = hand.joint_limits.double()
    curled = torch.minimum(torch.maximum(rest + 0.6, lim[:, 0]), lim[:, 1])
    roots = clip.hands[0].wrist_pose.double()[None]                          # (H, T, 4, 4)
    frames = [np.ones(clip.T, bool), np.arange(clip.T) < 10]
    rep = reference_report(clip, [hand], [(rest, roots), (curled, roots)], tmp_path, frames=frames)
    rows = rep["right"]
    assert [r["frames"] for r in rows] == [30, 10]
    assert rows[0]["tip_distance_mm"]["median"] != rows[1]["tip_distance_mm"]["median"]
    for r in rows:
        assert 0 < r["tip_distance_mm"]["median"] <= r["tip_distance_mm"]["p90"] < 300
        assert 0 <= r["contact_agreement"] <= 1
    for v in (0, 1):
        png = tmp_path / f"fingers_right_sol_{v:03d}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    other = dataclasses.replace(hand, finger_names=("a", "b", "c", "d", "e"))
    assert reference_report(clip, [other], [(rest, roots)], tmp_path / "none", plot=False) == {}


@needs_mug
def test_fit_recovers_fingertips_of_a_known_pose(mug, monkeypatch):
    """The fit of torchhand.fill.captured reaches fingertip targets that a known pose of the model makes (targets
    standing in for the capture's): median within 0.1 mm (the rest-pose pull keeps it off zero), every finger within
    2 mm (a redundant chain may end a step budget short of its target), inside the joint limits."""
    import torchhand.fill.captured as captured
    from torchhand.hand.mount import track_hand

    clip = mug.with_frames(620, 630)
    hand = track_hand(clip.hands[0]).to("cpu", torch.float64)
    lim = hand.joint_limits.double()
    g = torch.Generator().manual_seed(0)
    q_true = lim[:, 0] + (lim[:, 1] - lim[:, 0]) * (0.3 + 0.4 * torch.rand(clip.T, lim.shape[0], generator=g,
                                                                           dtype=torch.float64))
    root = clip.hands[0].wrist_pose.double()
    goal = solution_fingertips(hand, q_true, root)
    monkeypatch.setattr(captured, "captured_fingertips", lambda scene, side: goal)
    fit = captured.fit_captured_fingers(clip, "right", hand)
    assert np.nanmedian(fit.residual) < 1e-4 and np.nanmax(fit.residual) < 2e-3, \
        f"median {1e3 * np.nanmedian(fit.residual):.3f} mm, largest {1e3 * np.nanmax(fit.residual):.2f} mm"
    assert bool(((fit.q >= lim[:, 0] - 1e-12) & (fit.q <= lim[:, 1] + 1e-12)).all())


@needs_mug
def test_captured_fingers_as_a_solution_file(mug, tmp_path):
    """write_captured on a mug clip: a solution file the reader accepts, the built-in hand within ~1 cm of the
    captured finger ends (median), no contacts; a robot-like model without the five fingers is refused."""
    from torchhand.fill.captured import fit_captured_fingers
    from torchhand.fill.captured import write_captured
    from torchhand.hand.mount import track_hand
    from torchhand.io.result import load_solution

    clip = mug.with_frames(620, 650)
    hand = track_hand(clip.hands[0])
    info = write_captured(clip, "right", hand, clip.hands[0].wrist_pose, tmp_path)
    assert info["file"] == "captured_right.npz" and info["residual_mm"]["median"] < 12
    sol = load_solution(tmp_path / "captured_right.npz")
    assert sol.T == 30 and sol.hands[0].side == "right" and sol.hands[0].q.shape == (30, hand.num_joints)
    assert not sol.contact_mask.any() and not sol.reconstructed
    np.testing.assert_array_equal(sol.object_pose, clip.object_pose.numpy())
    with pytest.raises(InputValueError, match="fingers"):
        fit_captured_fingers(clip, "right", dataclasses.replace(hand, finger_names=("a", "b", "c", "d", "e")))
