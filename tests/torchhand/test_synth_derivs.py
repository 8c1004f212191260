"""Analytic derivatives of the static torques u = n(q) + sum_i J_i^T f_i (torchhand/manipulation/torque_derivs.py)
against central differences of MuJoCo's own generalised forces and of :func:`~torchhand.manipulation.synth.torques`,
the NumPy kinematics against the torch kernel, the point Jacobian against ``mj_jac``, and the per-frame synthesis
with analytic against forward-difference Jacobians."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from torchhand.kernels import kinematics as kin

from tests.conftest import shared_path
from torchhand.errors import InputValueError
from torchhand.hand import HandModel, default_hand
from torchhand.manipulation import ManipulationSettings, SynthSettings, manipulate
from torchhand.manipulation.synth import exp_rot, rotvec, torques
from torchhand.manipulation.torque_derivs import (
    point_jacobian,
    torques_and_derivatives,
    tree_order,
    tree_state,
)
from torchhand.scene import load_scene

# a chain with two hinges on one body (application order matters), a slide joint between hinges, offsets and an
# oblique axis: the cases the derivative formulas distinguish
CHAIN_XML = """<mujoco model="chain">
  <worldbody>
    <body name="palm">
      <geom type="box" size="0.04 0.01 0.04" density="1000"/>
      <body name="a" pos="0.01 0 0.05">
        <joint name="j0" type="hinge" axis="1 0 0"/>
        <joint name="j1" type="hinge" axis="0 1 0.3" pos="0.002 0 0"/>
        <geom type="capsule" fromto="0 0 0 0 0 0.04" size="0.008" density="1000"/>
        <body name="b" pos="0 0 0.045" quat="0.9 0.1 0.2 0">
          <joint name="s0" type="slide" axis="0 0.6 0.8"/>
          <geom type="capsule" fromto="0 0 0 0 0.01 0.03" size="0.007" density="1000"/>
          <body name="c" pos="0 0.01 0.035">
            <joint name="j2" type="hinge" axis="0 1 0" pos="0 0 0.003"/>
            <geom type="capsule" fromto="0 0 0 0.01 0 0.025" size="0.006" density="1000"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def _hand(which, tmp_path):
    if which == "default":
        return default_hand().to("cpu", torch.float64)
    if which == "chain":
        p = tmp_path / "chain.xml"
        p.write_text(CHAIN_XML)
        return HandModel.from_mjcf(p).to("cpu", torch.float64)
    return HandModel.from_mjcf(shared_path("hands", which, "right_hand.xml")).to("cpu", torch.float64)


def _config(hand, rng, H=4):
    """A random configuration within the limits, a random wrist pose and H random contact forces on links."""
    lim = hand.joint_limits.numpy()
    q = rng.uniform(lim[:, 0], lim[:, 1])
    root = np.eye(4)
    root[:3, :3] = exp_rot(rng.normal(size=3))
    root[:3, 3] = 0.1 * rng.normal(size=3)
    links = rng.integers(1, hand.num_links, size=H)
    h = 0.01 * rng.normal(size=(H, 3))
    f = 3.0 * rng.normal(size=(H, 3))
    return q, root, links, h, f


def _moved(root, q, dx):
    """The configuration moved by dx = (w, v, dq) in the coordinates of point_jacobian(wrt_root=True)."""
    r = root.copy()
    r[:3, :3] = exp_rot(dx[:3]) @ r[:3, :3]
    r[:3, 3] = r[:3, 3] + dx[3:6]
    return r, q + dx[6:]


@pytest.mark.parametrize("which", ["default", "chain", "allegro_hand", "shadow_hand"])
def test_derivatives_match_central_differences(which, tmp_path):
    """du/d(w, v, q) and du/dp against central differences (step 1e-6) of the torch torques (which match MuJoCo's
    qfrc_bias + J^T f to 1e-15, tests/torchhand/test_dynamics.py): 1e-7 of the largest entry; the NumPy link poses,
    joint axes and anchors against the torch kernel, and u itself, to 1e-14."""
    hand = _hand(which, tmp_path)
    order = tree_order(hand)
    rng = np.random.default_rng(7)
    eps = 1e-6
    for _ in range(3):
        q, root, links, h, f = _config(hand, rng)
        st = tree_state(order, q, root)
        T, axis, anchor = kin.joint_frames(hand.chain, torch.as_tensor(q)[None], torch.as_tensor(root)[None])
        assert np.abs(st.T - T[0].numpy()).max() < 1e-14
        assert np.abs(st.axis - axis[0].numpy()).max() < 1e-14
        assert np.abs(st.anchor - anchor[0].numpy()).max() < 1e-14
        u, du_dx, du_dp = torques_and_derivatives(order, st, links, h, f)
        assert np.abs(u - torques(hand, q[None], root[None], links, h[None], f)[0]).max() < 1e-14 * (1 + abs(u).max())
        N = 6 + hand.num_joints

        def u_at(dx, dh=0.0, root=root, q=q, links=links, h=h, f=f):
            r, qq = _moved(root, q, dx)
            return torques(hand, qq[None], r[None], links, (h + dh)[None], f)[0]

        num = np.stack([(u_at(eps * e) - u_at(-eps * e)) / (2 * eps) for e in np.eye(N)], 1)
        assert np.abs(num - du_dx).max() <= 1e-7 * np.abs(num).max()
        for i in range(len(links)):                       # a world displacement of contact i's point
            R = st.T[links[i], :3, :3]
            for c in range(3):
                dh = np.zeros_like(h)
                dh[i] = eps * R[c]                        # R^T e_c: link-frame step of a world step along e_c
                col = (u_at(np.zeros(N), dh) - u_at(np.zeros(N), -dh)) / (2 * eps)
                assert np.abs(col - du_dp[i, :, c]).max() <= 1e-7 * np.abs(du_dp).max()


def _mujoco_u(mujoco, m, data, hand, root, q, links, h, f, jid):
    """MuJoCo's u = S^T (qfrc_bias + sum mj_applyFT) in torchhand's coordinates (torque about the root origin,
    force, joints), q_dot = 0."""
    from scipy.spatial.transform import Rotation
    qadr, dadr = m.jnt_qposadr[jid], m.jnt_dofadr[jid]
    data.qpos[:] = m.qpos0
    x, y, z, w = Rotation.from_matrix(root[:3, :3]).as_quat()
    data.qpos[:3], data.qpos[3:7], data.qpos[qadr] = root[:3, 3], [w, x, y, z], q
    data.qvel[:] = 0
    mujoco.mj_forward(m, data)
    qfrc = data.qfrc_bias.copy()
    for i, l in enumerate(links):
        body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, hand.link_names[l])
        point = data.xmat[body].reshape(3, 3) @ h[i] + data.xpos[body]
        mujoco.mj_applyFT(m, data, f[i], np.zeros(3), point, body, qfrc)
    D = len(jid)
    S = np.zeros((m.nv, 6 + D))
    S[0:3, 3:6] = np.eye(3)
    S[3:6, 0:3] = root[:3, :3].T
    S[dadr, 6 + np.arange(D)] = 1
    return S.T @ qfrc, S


@pytest.mark.parametrize("which", ["default", "chain"])
def test_derivatives_match_mujoco(which, tmp_path):
    """Reference computed by MuJoCo alone: central differences (step 1e-6) of qfrc_bias + sum mj_applyFT over
    configurations moved in torchhand's root-twist coordinates give du/d(w, v, q) (1e-7 of the largest entry);
    mj_jac gives the point Jacobian (1e-12)."""
    mujoco = pytest.importorskip("mujoco")
    hand = _hand(which, tmp_path)
    m = mujoco.MjModel.from_xml_string(hand.to_mjcf())
    m.dof_armature[:] = 0
    data = mujoco.MjData(m)
    jid = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n) for n in hand.joint_names]
    assert m.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE and min(jid) > 0
    order = tree_order(hand)
    rng = np.random.default_rng(3)
    eps, N = 1e-6, 6 + hand.num_joints
    for _ in range(2):
        q, root, links, h, f = _config(hand, rng)
        st = tree_state(order, q, root)
        u, du_dx, _ = torques_and_derivatives(order, st, links, h, f)
        u_mj, S = _mujoco_u(mujoco, m, data, hand, root, q, links, h, f, jid)
        assert np.abs(u - u_mj).max() <= 1e-12 * (1 + np.abs(u).max())
        # point Jacobian of the contact points
        x = np.einsum("pij,pj->pi", st.T[links, :3, :3], h) + st.T[links, :3, 3]
        J = point_jacobian(order, st, links, x)
        for i, l in enumerate(links):
            body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, hand.link_names[l])
            jacp = np.zeros((3, m.nv))
            mujoco.mj_jac(m, data, jacp, None, x[i], body)
            assert np.abs(jacp @ S - J[i]).max() < 1e-12
        cols = []
        for e in np.eye(N):
            up = _mujoco_u(mujoco, m, data, hand, *_moved(root, q, eps * e), links, h, f, jid)[0]
            um = _mujoco_u(mujoco, m, data, hand, *_moved(root, q, -eps * e), links, h, f, jid)[0]
            cols.append((up - um) / (2 * eps))
        num = np.stack(cols, 1)
        assert np.abs(num - du_dx).max() <= 1e-7 * np.abs(num).max()


def test_rotvec_against_scipy():
    from scipy.spatial.transform import Rotation
    rng = np.random.default_rng(0)
    for k in range(500):
        w = rng.normal(size=3)
        w *= rng.uniform(0.0, 3.1) / np.linalg.norm(w) * (10.0 ** rng.uniform(-9, 0) if k % 2 else 1.0)
        R = exp_rot(w)
        assert np.abs(rotvec(R) - Rotation.from_matrix(R).as_rotvec()).max() < 1e-12


def test_bad_derivatives_setting():
    with pytest.raises(InputValueError, match="derivatives"):
        SynthSettings(derivatives="exact")


def test_manipulate_analytic_matches_finite_differences():
    """Frames 6..11 of box-turn from the test grasp (taken at frame 6): the settling first frame with analytic
    Jacobians reaches the objective it reaches with forward differences (1e-6 relative), both converged. (The motions
    themselves part by centiradians along the weakly determined directions of the first frame's problem, where a 1e-7
    relative change of the Jacobian moves the stationary point; the Jacobians themselves are held to 1e-7 above,
    against central differences and MuJoCo.)"""
    from tests.torchhand.test_grasp import FRAME, box_turn_grasp

    grasp, base = box_turn_grasp()
    scene = load_scene("box-turn").with_frames(FRAME, FRAME + 5)
    assert np.allclose(scene.object_pose[0].numpy(), base.object_pose[FRAME].numpy(), atol=1e-12)
    scene = dataclasses.replace(scene, object=base.object)
    res = {m: manipulate(scene, grasp, ManipulationSettings(synth=SynthSettings(derivatives=m)))
           for m in ("analytic", "finite")}
    a, b = res["analytic"], res["finite"]
    assert a.q.shape == b.q.shape == (5, grasp.q.shape[0])
    assert a.converged[0] and b.converged[0]
    assert abs(a.objective[0] - b.objective[0]) <= 1e-6 * abs(b.objective[0])
