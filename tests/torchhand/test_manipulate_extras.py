"""External wrenches on the object (planner, required wrench, the checker's balance) and the built-in grasp lookup of
``torchhand manipulate``."""

from __future__ import annotations

import dataclasses
import sys
import types
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from torchhand.check.motion import balance_errors
from torchhand.errors import InputValueError, ShapeError
from torchhand.manipulation.plan import plan_motion
from torchhand.scene import Environment
from torchhand.synthesis.problem import required_wrench

from .test_grasp import box_turn_grasp
from .test_plan import lift_scene, newton_euler

HOVER = (6, 16)           # frames of the test lift: at rest, then the start of the 10 cm lift


@pytest.fixture(scope="module")
def hover():
    """The grasped box without its table, frames HOVER of the lift: the hand carries everything."""
    grasp, base = box_turn_grasp()
    scene = lift_scene(grasp, base).with_frames(*HOVER)
    return grasp, dataclasses.replace(scene, environment=Environment())


def _reference(scene):
    """Required wrench (T, 6) and COM (T, 3) by the NumPy/SciPy Newton-Euler of test_plan (no external wrench)."""
    obj = scene.object
    return newton_euler(scene.object_pose.numpy(), obj.com, obj.mass, np.array(obj.inertia), scene.fps)


def _net(plan, com):
    """Net force (T, 3) and torque about the COM (T, 3) of every planned contact."""
    return plan.forces.sum(1), np.cross(plan.points - com[:, None], plan.forces).sum(1)


def test_external_wrench_that_cancels_everything_leaves_no_contact_force(hover):
    """An external wrench equal to what the motion needs, gravity included (f = m (a - g): +m g up at rest), leaves the
    contacts nothing to do: the minimum-norm F_-1 and every window's forces are zero. Without it the hand carries the
    weight."""
    grasp, scene = hover
    wrench, _ = _reference(scene)
    plain = plan_motion(scene, grasp)
    assert plain.forces.sum(1)[:, 2].min() > 0.9 * scene.object.mass * 9.81
    helped = plan_motion(dataclasses.replace(scene, external_wrench=torch.tensor(wrench)), grasp)
    largest = float(np.abs(helped.forces).max())
    print(f"largest contact force with the cancelling external wrench: {largest:.2e} N "
          f"(without: {np.abs(plain.forces).max():.3f} N)")
    assert largest < 1e-6 and np.abs(helped.f_init).max() < 1e-6
    np.testing.assert_allclose(helped.wrench, 0.0, atol=1e-9)


def test_lateral_push_changes_the_planned_forces_by_the_push(hover):
    """A push (force along +x and -y, torque about z) on the object: the contacts supply the required wrench minus
    the push, checked against the NumPy Newton-Euler wrench."""
    grasp, scene = hover
    push = np.zeros((scene.T, 6))
    push[:, 0], push[:, 1], push[:, 5] = 0.8, -0.3 * np.linspace(0, 1, scene.T), 0.01
    wrench, com = _reference(scene)
    plain = plan_motion(scene, grasp)
    pushed = plan_motion(dataclasses.replace(scene, external_wrench=torch.tensor(push)), grasp)
    for plan, ext in ((plain, 0.0), (pushed, push)):
        f, t = _net(plan, com)
        np.testing.assert_allclose(f, wrench[:, :3] - (ext if np.isscalar(ext) else ext[:, :3]), atol=1e-6)
        np.testing.assert_allclose(t, wrench[:, 3:] - (ext if np.isscalar(ext) else ext[:, 3:]), atol=1e-7)
    (f0, t0), (f1, t1) = _net(plain, com), _net(pushed, com)
    print(f"net force change {np.abs(f1 - f0 + push[:, :3]).max():.1e} N off the push")
    assert np.abs(f1 - f0 + push[:, :3]).max() < 1e-6 and np.abs(t1 - t0 + push[:, 3:]).max() < 1e-7
    assert (pushed.status == 0).all()


def test_required_wrench_subtracts_the_external_wrench(hover):
    _, scene = hover
    obj = scene.object
    args = (scene.object_pose, torch.tensor(np.array(obj.com)), obj.mass, torch.tensor(np.array(obj.inertia)),
            scene.gravity, scene.fps)
    _, w = required_wrench(*args)
    ext = torch.randn(scene.T, 6, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    assert torch.equal(required_wrench(*args, external=None)[1], w)
    assert torch.equal(required_wrench(*args, external=ext)[1], w - ext)
    np.testing.assert_allclose(w.numpy(), _reference(scene)[0], atol=1e-9)
    with pytest.raises(ShapeError, match=r"external: expected shape \(10, 6\)"):
        required_wrench(*args, external=ext[:3])


def test_balance_errors_with_an_external_wrench():
    """A box at rest (a = omega = alpha = 0) with two contacts, against the residual computed here by hand."""
    m, g = 0.5, np.array([0.0, 0.0, -9.81])
    pose = np.repeat(np.eye(4)[None], 3, 0)
    pose[:, :3, 3] = (0.1, 0.2, 1.0)
    com_local = np.array([0.01, 0.0, 0.0])
    c = pose[0, :3, 3] + com_local
    p = np.array([[0.06, 0.2, 1.0], [0.16, 0.2, 1.0]])
    f = np.array([[1.0, 0.0, 2.0], [-0.5, 0.3, 1.5]])
    T = 3
    sol = SimpleNamespace(object_pose=pose, fps=30.0, contact_mask=np.ones((T, 2), bool),
                          contact_force=np.repeat(f[None], T, 0), contact_point=np.repeat(p[None], T, 0),
                          env_contact_mask=np.zeros((T, 1), bool), env_contact_force=np.zeros((T, 1, 3)),
                          env_contact_point=np.zeros((T, 1, 3)))
    obj = SimpleNamespace(com=com_local, inertia=np.diag([1e-3, 2e-3, 3e-3]), extent=0.2)
    weight = m * 9.81
    # by hand: net force (0.5, 0.3, 3.5) + m g = (0.5, 0.3, -1.405); torque about c of the two forces
    net_f = np.array([0.5, 0.3, 3.5 - 4.905])
    net_t = np.cross(p[0] - c, f[0]) + np.cross(p[1] - c, f[1])
    f_err, t_err = balance_errors(sol, obj, m, g)
    np.testing.assert_allclose(f_err, np.linalg.norm(net_f) / weight, rtol=1e-12)
    np.testing.assert_allclose(t_err, np.linalg.norm(net_t) / (weight * 0.2), rtol=1e-12)
    ext = np.repeat(np.r_[-net_f, -net_t][None], T, 0)            # exactly what balances the box
    f_err, t_err = balance_errors(sol, obj, m, g, external=ext)
    assert f_err.max() < 1e-12 and t_err.max() < 1e-12
    ext[1] += (0.0, 0.0, 0.2, 0.0, 0.01, 0.0)                    # off by 0.2 N and 0.01 N m at frame 1
    f_err, t_err = balance_errors(sol, obj, m, g, external=ext)
    np.testing.assert_allclose(f_err, [0.0, 0.2 / weight, 0.0], atol=1e-12)
    np.testing.assert_allclose(t_err, [0.0, 0.01 / (weight * 0.2), 0.0], atol=1e-12)
    with pytest.raises(ShapeError, match="external"):
        balance_errors(sol, obj, m, g, external=np.zeros((T, 3)))


# ------------------------------------------------------------------------------------------------ built-in grasps
def test_builtin_scene_grasp_lookup(monkeypatch, tmp_path):
    """A built-in scene name without --grasp uses ``torchhand.scene.builtin.liu.grasp_path(name)``; None keeps the error;
    --grasp given once per hand, at most twice."""
    import torchhand.scene.builtin as scenes_pkg
    from torchhand.cli.manipulate_cmd import _grasp_paths

    shipped = tmp_path / "box-turn.grasp.npz"
    fake = types.ModuleType("torchhand.scene.builtin.liu")
    fake.grasp_path = lambda name: shipped if name == "box-turn" else None
    monkeypatch.setitem(sys.modules, "torchhand.scene.builtin.liu", fake)
    monkeypatch.setattr(scenes_pkg, "liu", fake, raising=False)
    assert _grasp_paths("box-turn", None) == [shipped]
    assert [p.name for p in _grasp_paths("box-turn", ["mine.npz"])] == ["mine.npz"]
    assert [p.name for p in _grasp_paths("box-turn", ["r.npz", "l.npz"])] == ["r.npz", "l.npz"]
    with pytest.raises(InputValueError, match="at most two"):
        _grasp_paths("box-turn", ["a.npz", "b.npz", "c.npz"])
    scene_dir = tmp_path / "two"                          # a scene directory: grasp.npz and grasp_<side>.npz
    scene_dir.mkdir()
    for name in ("scene.toml", "grasp.npz", "grasp_left.npz"):
        (scene_dir / name).write_bytes(b"")
    assert [p.name for p in _grasp_paths(str(scene_dir), None)] == ["grasp.npz", "grasp_left.npz"]
    with pytest.raises(InputValueError, match="--grasp: required for the built-in scene 'bottle-turn'"):
        _grasp_paths("bottle-turn", None)
    del fake.grasp_path                                   # a module without the function: the same error
    with pytest.raises(InputValueError, match="--grasp: required for the built-in scene 'box-turn'"):
        _grasp_paths("box-turn", None)
