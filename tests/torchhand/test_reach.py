"""Adjusting a grasp to the object: reaching for a missing contact (torchhand.interaction.reach: the offset's rule on
its own, and the pinch closing on a box narrower than the one its interaction was made on), and the paper's settle
(closing and opening again before the first frame) on a misplaced box."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from torchhand.errors import InputValueError
from torchhand.interaction.reach import ReachPlan, ReachSettings, reach_update

from .test_resynth import HALF, _cli, pinch_files


def _plan(pushes, direction, joint_finger):
    return ReachPlan(torch.tensor([pushes]), torch.tensor([direction], dtype=torch.float64),
                     torch.tensor(joint_finger))


def test_reaching_fingers_move_on_touching_ones_hold_released_ones_give_back():
    """Two fingers of two joints. Finger 0 pushes in the reference and does not touch: its offset moves rate h along
    its direction. Finger 1 pushes and touches: it holds. Then the limit caps finger 0's offset, and when the
    reference stops pushing with it, the offset shrinks by rate h."""
    s = ReachSettings(enabled=True, rate=0.5, limit=0.25)
    h = 0.01
    u = [0.6, 0.8, 1.0, 0.0]
    plan = _plan([True, True], u, [0, 0, 1, 1])
    touching = torch.tensor([[False, True]])
    off = torch.zeros(1, 4, dtype=torch.float64)
    off = reach_update(off, 0, plan, touching, h, s)
    np.testing.assert_allclose(off.numpy(), [[0.003, 0.004, 0.0, 0.0]], atol=1e-15)
    for _ in range(100):
        off = reach_update(off, 0, plan, touching, h, s)
    np.testing.assert_allclose(np.linalg.norm(off[0, :2].numpy()), 0.25, atol=1e-12)     # capped at the limit
    np.testing.assert_allclose(off[0, 2:].numpy(), 0.0)
    released = _plan([False, True], [0.0, 0.0, 1.0, 0.0], [0, 0, 1, 1])
    back = reach_update(off, 0, released, touching, h, s)
    np.testing.assert_allclose(np.linalg.norm(back[0, :2].numpy()), 0.25 - 0.005, atol=1e-12)
    np.testing.assert_allclose((back[0, :2] / back[0, :2].norm()).numpy(), [0.6, 0.8], atol=1e-12)
    for _ in range(60):
        back = reach_update(back, 0, released, touching, h, s)
    assert float(back.abs().max()) == 0.0


def test_the_pinch_reaches_for_a_narrower_box(tmp_path):
    """The pinch's interaction gets the captured joints of its own box's resynthesis as ``theta`` (where the box held
    the fingers). On that box the reach changes nothing (the fingers touch where the reference says they push). On a
    box 2.4 cm narrower (1.6 cm wide) the plain rollout grips with 1.0 N at most (the fingers meet it late, their
    references barely past it); with the reach the fingers close on while they miss it and grip harder (above
    1.5 N), the box is lifted all the same, the written theta_r includes the offset, and every frame passes the
    checker."""
    from torchhand.check import check_result
    from torchhand.interaction.resynth import (ResynthSettings, load_interaction, resynthesize, save_interaction,
                                               write_resynthesis)
    from torchhand.scene import load_scene

    tmp = tmp_path
    scene_dir, inter_path = pinch_files(tmp / "base")
    inter = load_interaction(inter_path)
    base = resynthesize(inter, load_scene(scene_dir), settings=ResynthSettings())
    theta = np.concatenate([inter.root_theta_r, np.asarray(base.rollouts[0].q)], 1)
    inter = dataclasses.replace(inter, theta=theta)
    assert load_interaction(save_interaction(inter, tmp / "with_theta.npz")).theta.tobytes() == theta.tobytes()
    reach = ResynthSettings(reach=ReachSettings(enabled=True))
    same = resynthesize(inter, load_scene(scene_dir), settings=reach).rollouts[0]
    assert np.array_equal(same.q, base.rollouts[0].q) and np.array_equal(same.theta_r, inter.theta_r)
    narrow_dir, _ = pinch_files(tmp / "narrow", half=(0.008, HALF[1], HALF[2]))
    narrow = load_scene(narrow_dir)
    grip = {}
    for on in (False, True):
        res = resynthesize(inter, narrow, settings=reach if on else ResynthSettings())
        r = res.rollouts[0]
        assert r.ok
        z = np.asarray(r.object_pose)[:, 2, 3]
        assert z[-1] - z[0] > 0.045
        grip[on] = float(np.linalg.norm(r.contact_force, axis=-1).max())
        offset = r.theta_r - inter.theta_r
        assert (np.abs(offset).max() > 0.02) == on
        out = write_resynthesis(res, tmp / f"out{int(on)}")
        assert check_result(out).passed
    assert grip[False] < 1.1 and grip[True] > 1.5


def test_cli_reach_needs_the_interactions_theta(tmp_path, capsys):
    """--reach on an interaction without 'theta': exit 2 with one line naming the problem."""
    scene_dir, inter = pinch_files(tmp_path / "in")
    assert _cli([str(inter), "--scene", str(scene_dir), "--out", str(tmp_path / "out"), "--reach"]) == 2
    assert "no 'theta'" in capsys.readouterr().err
    with pytest.raises(InputValueError, match="rate"):
        ReachSettings(rate=-1.0)


def test_close_open_pushes_a_misplaced_box_into_the_grasp(tmp_path):
    """The paper's settle (§8.3): the box placed 8 mm off the pinch's centre line. The fingers close along the
    interaction until both push (4 steps at 60 Hz) and open again, the wrist held: the box starts the rollout within
    1.5 mm of the centre and the lift slips 1 mm in the hand; without it the box starts 8 mm off and slips 5 mm.
    On the well-placed box it changes the motion by less than a micrometre."""
    from torchhand.hand.mount import track_hand
    from torchhand.interaction import resynth as R
    from torchhand.interaction.resynth import ResynthSettings, load_interaction, resynthesize
    from torchhand.scene import load_scene

    scene_dir, inter_path = pinch_files(tmp_path / "base")
    inter, scene = load_interaction(inter_path), load_scene(scene_dir)
    base = resynthesize(inter, scene, settings=ResynthSettings()).rollouts[0]
    inter = dataclasses.replace(inter, theta=np.concatenate([inter.root_theta_r, np.asarray(base.q)], 1))
    hand = track_hand(scene.hands[0]).to("cpu", torch.float64)
    plan = R._reference_plan(inter, hand, 1 / 60, inter.theta_r, ResynthSettings(close_open=True))
    assert R._close_open(plan) == (1, 2, 3, 4, 3, 2, 1, 0)
    on = ResynthSettings(close_open=True)
    same = resynthesize(inter, scene, settings=on).rollouts[0].object_pose
    assert np.abs(same - base.object_pose).max() < 1e-6
    pose = scene.object_pose.clone()
    pose[:, 0, 3] += 0.008
    off = dataclasses.replace(scene, object_pose=pose)
    plain = resynthesize(inter, off, settings=ResynthSettings()).rollouts[0]
    settled = resynthesize(inter, off, settings=on).rollouts[0]
    assert abs(plain.object_pose[0, 0, 3] - 0.008) < 1e-6 and abs(settled.object_pose[0, 0, 3]) < 0.0015
    assert settled.object_slip.max() < 0.0015 < 0.004 < plain.object_slip.max()
    assert settled.object_pose[-1, 2, 3] - settled.object_pose[0, 2, 3] > 0.049


def test_cli_close_open_needs_the_interactions_theta(tmp_path, capsys):
    scene_dir, inter = pinch_files(tmp_path / "in")
    assert _cli([str(inter), "--scene", str(scene_dir), "--out", str(tmp_path / "out"), "--close-open"]) == 2
    assert "no 'theta'" in capsys.readouterr().err
