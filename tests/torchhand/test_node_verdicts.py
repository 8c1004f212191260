"""The node test's dynamic verdict is taken after the force solve has converged, proved infeasibility or spent its
whole budget, not where the search's short iteration cap happened to stop it (NodeTestSettings.cone_retry_iters)."""

from __future__ import annotations

import dataclasses

import numpy as np
import torch
import trimesh

from torchhand.geometry.objects import RigidObject
from torchhand.scene.builtin import ye_liu as Y
from torchhand.synthesis.node_test import CAUSE_DYNAMIC, CAUSE_NONE, NodeTestSettings, evaluate_poses
from torchhand.synthesis.problem import build_problem


def _rod_problem():
    """A 3 x 18 cm rod standing on the table, an open right hand closing in on it from the side: at frame 6 one
    knuckle touches it while it rests, a thin contact set whose force solve needs about 2000 iterations."""
    T, radius, height = 72, 0.015, 0.18
    obj = RigidObject.from_trimesh(trimesh.creation.cylinder(radius=radius, height=height, sections=32),
                                   mass=0.15, name="rod")
    hold = (Y._APPROACH, T - 1 - Y._APPROACH)
    up = Y._ramp(T, hold[0] + 4, 32) - Y._ramp(T, 42, hold[1] - 2)
    pose = Y._poses(np.broadcast_to(np.eye(3), (T, 3, 3)),
                    np.stack([0.0 * up, 0.0 * up, Y.TABLE_HEIGHT + 0.5 * height + 0.10 * up], axis=-1))
    grasp = Y._grasp((1, 0, 0), (0, -1, 0), (0.0, -radius + 0.002, 0.5 * height - 0.04))
    scene = Y._scene("rod", "test rod", obj, pose, [("right", Y._wrist_track(pose, grasp, hold))])
    return build_problem(scene, torch.Generator().manual_seed(0))


def test_an_unfinished_force_solve_is_resumed_before_its_verdict():
    prob = _rod_problem()
    t = torch.tensor([6])
    q = torch.zeros(1, 1, prob.hands[0].q_rest.shape[-1], dtype=prob.dtype)
    s = NodeTestSettings()
    cut = evaluate_poses(prob, t, q, settings=dataclasses.replace(s, cone_retry_iters=None))
    resumed = evaluate_poses(prob, t, q, settings=s)
    long = evaluate_poses(prob, t, q, settings=dataclasses.replace(s, cone_iters=20000, cone_retry_iters=None))
    assert int(cut.c_mask.sum()) >= 1                       # a contact is there to carry force
    assert int(cut.cause[0]) == CAUSE_DYNAMIC               # cut at 300 iterations: rejected
    assert int(resumed.cause[0]) == int(long.cause[0]) == CAUSE_NONE
    torch.testing.assert_close(resumed.c_force, long.c_force, atol=1e-3 * prob.weight, rtol=0)


def test_the_resumed_verdict_holds_under_a_tiny_perturbation():
    """The rod's frame 6 keeps its verdict, and its forces, when the hand pose moves by 1e-9 rad."""
    prob = _rod_problem()
    t = torch.tensor([6, 6, 6])
    q = torch.zeros(3, 1, prob.hands[0].q_rest.shape[-1], dtype=prob.dtype)
    q[1] += 1e-9
    q[2] -= 1e-9
    res = evaluate_poses(prob, t, q, settings=NodeTestSettings())
    assert res.cause.tolist() == [CAUSE_NONE] * 3
    torch.testing.assert_close(res.c_force[1:], res.c_force[:1].expand(2, -1, -1), atol=1e-3 * prob.weight, rtol=0)


def test_a_contact_the_path_lands_counts_as_new_in_the_final_test():
    """The final test's sliding rule: a slot within contact distance at frame t - 1 is held at t (it may slide),
    unless the searched path establishes it at t (a landing finger that came close a frame early)."""
    from torchhand.synthesis.finishing import held_before

    c = torch.tensor([[0, 0], [1, 1], [1, 1], [1, 1]], dtype=torch.bool)     # (T, K): both on from frame 1
    plan = torch.tensor([[0, 0], [1, 0], [1, 1], [1, 1]], dtype=torch.bool)  # slot 1 lands at frame 2
    assert held_before(c).tolist() == [[False, False], [False, False], [True, True], [True, True]]
    assert held_before(c, plan).tolist() == [[False, False], [False, False], [True, False], [True, True]]
    # a slot the plan holds throughout stays held; one the plan never has is judged by the motion alone
    assert held_before(c, torch.ones_like(c))[2:].all() and held_before(c, torch.zeros_like(c))[2:].all()
