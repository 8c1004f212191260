"""Added contacts in the manipulation loop (Liu 2009, Sec. 4.3 and Sec. 5): a contact carries force only once it
touches. The gap of every added contact at its first force frame is measured on the result's hand.xml posed by
MuJoCo; the written frames must pass the independent checker; candidates the hand cannot reach in time are not
added."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from torchhand.check import check_result
from torchhand.manipulation import ManipulationSettings, manipulate, write_manipulation
from torchhand.manipulation import plan as _plan
from torchhand.manipulation.plan import GraspUnsuitable, PlanSettings

from .test_grasp import box_turn_grasp
from .test_manipulate import _mujoco_model, _quat
from .test_plan import lift_scene

HEAVY = 1.0               # kg: the test grasp cannot lift it at 30 N without added contacts
FRAMES = (6, 16)          # the lift's rest and the start of the lift, where the grasp runs short
TOUCH = 0.002             # metres: the checker's contact-hand bound


def heavy_lift(grasp, base):
    """The lift of test_plan with a 1 kg box (mass and inertia of the scene's object, so the checker balances the
    same wrench), frames FRAMES."""
    scene = lift_scene(grasp, base).with_frames(*FRAMES)
    obj = scene.object
    heavy = dataclasses.replace(obj, mass=HEAVY, inertia=np.asarray(obj.inertia) * (HEAVY / obj.mass))
    return dataclasses.replace(scene, object=heavy)


@pytest.fixture(scope="module")
def heavy(tmp_path_factory):
    grasp, base = box_turn_grasp()
    scene = heavy_lift(grasp, base)
    try:
        res, err = manipulate(scene, grasp, ManipulationSettings()), None
    except GraspUnsuitable as e:
        res, err = e.partial, e
    assert res is not None, "the heavy lift stopped before its first frame"
    d = write_manipulation(res, tmp_path_factory.mktemp("added") / "r", unsuitable=err)
    return grasp, scene, res, err, d


def test_added_contacts_touch_when_they_first_carry_force(heavy):
    """Either the whole lift or an honest stop: the frames written pass the checker, and every added contact's hand
    point (its link posed by MuJoCo) is within 2 mm of its object point at the first frame it carries force (before
    the rule, contacts added at t_e = k carried force 16-19 mm away on this lift at 1.5 kg)."""
    _, _, res, err, d = heavy
    report = check_result(d)
    assert report.passed, report.solutions[0].failure()
    mujoco, m = _mujoco_model(d)
    z = np.load(d / "solutions" / "sol_000.npz")
    names = [str(n) for n in z["joint_names"]]
    jid = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n) for n in names]
    qadr = m.jnt_qposadr[jid]
    data = mujoco.MjData(m)
    link_names = [str(n) for n in z["contact_link_name"]]
    slots = z["contact_slot"]
    seen: set = set()
    gaps = []
    for t in range(z["q"].shape[0]):
        root = z["root_pose"][t]
        data.qpos[:] = m.qpos0
        data.qpos[:3], data.qpos[3:7], data.qpos[qadr] = root[:3, 3], _quat(root[:3, :3]), z["q"][t]
        mujoco.mj_kinematics(m, data)
        for k in np.flatnonzero(z["contact_added"][t]):
            if slots[t, k] in seen or not np.linalg.norm(z["contact_force"][t, k]) > 0:
                continue
            seen.add(int(slots[t, k]))
            body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, link_names[z["contact_link"][t, k]])
            x = data.xmat[body].reshape(3, 3) @ z["contact_hand_local"][t, k] + data.xpos[body]
            gaps.append(float(np.linalg.norm(x - z["contact_point"][t, k])))
    print(f"heavy lift: {res.T} frames written ({'complete' if err is None else f'unsuitable at frame {err.frame}'}), "
          f"{res.num_added} contact(s) added, {res.deferred} deferral(s); gaps at first force "
          f"{np.round(np.array(gaps) * 1000, 2).tolist()} mm")
    if not gaps:     # measured 2026-11-28 with converged frames: no contact is added before the stop
        pytest.xfail(f"the heavy lift added no contact that carried force ({res.num_added} added; "
                     f"{'complete' if err is None else f'unsuitable at frame {err.frame}'}): added contacts are not a "
                     "robust decision of the planner yet (docs/manipulation.md)")
    assert all(g <= TOUCH for g in gaps), gaps


def test_candidates_must_be_reachable(heavy):
    """At the grasp, with no frame to approach (t_e = k), a candidate must already touch; Liu's plain choice (the
    closest sample on another link, planning alone) does not. A link that only the wrist moves (the little finger's
    metacarpal) cannot approach while the other contacts hold the hand; a free fingertip can."""
    grasp, scene, _, _, _ = heavy
    run = _plan._start(scene, grasp, PlanSettings())
    geo, c = run.geo, run.c
    geo.reach_step = 0.3
    forces = np.linalg.norm(run.f_init_vals[:len(c.link)], axis=1)
    i = int(np.argmax(forces))
    plain = _plan._candidate(c, geo, i)
    assert plain is not None
    link, local, p, _ = plain
    x = geo.link_pose[link, :3, :3] @ local + geo.link_pose[link, :3, 3]
    assert np.linalg.norm(x - p) > TOUCH                                      # Liu's nearest link is apart
    now = _plan._candidate(c, geo, i, frames=0, k=0)
    if now is not None:
        link, local, p, _ = now
        x = geo.link_pose[link, :3, :3] @ local + geo.link_pose[link, :3, 3]
        assert np.linalg.norm(x - p) <= _plan.TOUCH_TOL
    hand = geo.hand
    held = set(c.link)
    free_tip = next(hand.link_index(f"{f}_distal") for f in ("ring", "middle", "index", "little")
                    if hand.link_index(f"{f}_distal") not in held)
    reach = {}
    for link in (hand.link_index("little_metacarpal"), free_tip):
        idx = np.flatnonzero(geo.sample_link == link)
        sd, p, _ = _plan.signed_distance(geo.mesh, geo.samples[idx])
        toward = (p - geo.samples[idx]) / np.abs(sd)[:, None]
        reach[link] = (float(np.abs(sd).min()), float(_plan._reach(c, geo, idx, toward, 5, 0).max()))
    gap, most = reach[hand.link_index("little_metacarpal")]
    assert most < 0.25 * gap, reach                # only the wrist moves it, and the contacts hold the wrist
    gap, most = reach[free_tip]
    assert most > 0.5 * gap, reach                 # a free finger closes centimetres in 5 frames
    assert torch.is_tensor(scene.object_pose)
