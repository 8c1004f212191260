"""Inverse dynamics of the floating hand (torchhand/hand/inverse_dynamics.py) against MuJoCo's mj_inverse on the
written hand.xml of the default, Shadow and Allegro hands; its invariants (gravity torques at rest, mass-matrix
columns), dtypes, shapes and bad input; and the finite-difference rates of a written motion
(torchhand/hand/motion_rates.py) against analytic motions and MuJoCo's mj_differentiatePos."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

import torchhand
from tests.conftest import shared_path
from tests.torchhand.test_mjcf import _pose, _quat_to_mat, _random_roots
from torchhand.errors import InputValueError, ShapeError
from torchhand.hand import HandModel
from torchhand.hand.inverse_dynamics import inverse_dynamics
from torchhand.hand.motion_rates import motion_rates

mujoco = pytest.importorskip("mujoco")

TOL = 1e-9  # float64: largest |u - MuJoCo's| over the largest |u|
N_POSES = 32
HANDS = ["default_right", "default_left", "shadow", "allegro"]


# ----------------------------------------------------------------------------------------------------------------
# MuJoCo: the free joint's coordinates, verified rather than assumed
# ----------------------------------------------------------------------------------------------------------------
_FREE_BODY = """<mujoco><option gravity="0 0 0"/><worldbody><body name="b"><freejoint name="root"/>
  <inertial pos="0.1 0.05 -0.02" mass="1.3" diaginertia="0.01 0.02 0.03"/></body></worldbody></mujoco>"""


def _rotvec(R: np.ndarray) -> np.ndarray:
    return Rotation.from_matrix(R).as_rotvec()


def test_mujoco_free_joint_velocity_is_world_linear_and_body_angular():
    """qvel = (v, R^T w) and qacc = (a, R^T alpha): v, a the world velocity and acceleration of the body origin,
    w, alpha the world angular ones; checked with mj_integratePos and with mj_objectVelocity/-Acceleration (which
    report at the centre of mass, world axes)."""
    m = mujoco.MjModel.from_xml_string(_FREE_BODY)
    d = mujoco.MjData(m)
    rng = np.random.default_rng(3)
    quat = rng.normal(size=4)
    d.qpos[:3], d.qpos[3:7], d.qvel[:] = rng.normal(size=3), quat / np.linalg.norm(quat), rng.normal(size=6)
    d.qfrc_applied[:] = rng.normal(size=6)
    mujoco.mj_forward(m, d)
    mujoco.mj_rnePostConstraint(m, d)
    R, o, c = d.xmat[1].reshape(3, 3).copy(), d.xpos[1].copy(), d.xipos[1] - d.xpos[1]
    w, v, alpha, a = R @ d.qvel[3:], d.qvel[:3], R @ d.qacc[3:], d.qacc[:3]
    h, qpos = 1e-3, d.qpos.copy()  # a step of constant qvel: exact for both parts
    mujoco.mj_integratePos(m, qpos, d.qvel, h)
    d2 = mujoco.MjData(m)
    d2.qpos[:] = qpos
    mujoco.mj_kinematics(m, d2)
    np.testing.assert_allclose((d2.xpos[1] - o) / h, v, rtol=0, atol=1e-12)
    np.testing.assert_allclose(_rotvec(d2.xmat[1].reshape(3, 3) @ R.T) / h, w, rtol=0, atol=1e-11)
    vel, acc = np.zeros(6), np.zeros(6)
    mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, 1, vel, 0)
    mujoco.mj_objectAcceleration(m, d, mujoco.mjtObj.mjOBJ_BODY, 1, acc, 0)
    np.testing.assert_allclose(vel, np.r_[w, v + np.cross(w, c)], rtol=0, atol=1e-12)
    np.testing.assert_allclose(acc, np.r_[alpha, a + np.cross(alpha, c) + np.cross(w, np.cross(w, c))], rtol=0,
                               atol=1e-12)


# ----------------------------------------------------------------------------------------------------------------
# Against mj_inverse
# ----------------------------------------------------------------------------------------------------------------
def _hand(name: str) -> HandModel:
    if name.startswith("default"):
        return torchhand.default_hand(name.split("_")[1])
    return HandModel.from_file(shared_path("hands", f"{name}_hand", "right_hand.xml"))


def _mujoco_model(hand: HandModel):
    """The hand as a result writes it (hand.xml: free root joint), without armature, damping, springs or
    constraints; its inertials are the model's."""
    m = mujoco.MjModel.from_xml_string(hand.to_mjcf())
    m.dof_armature[:] = 0
    m.dof_damping[:] = 0
    m.jnt_stiffness[:] = 0
    m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
    ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n) for n in hand.link_names]
    assert m.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE and min(ids) >= 0
    np.testing.assert_allclose(m.body_mass[ids], hand.link_mass.numpy(), rtol=0, atol=1e-15)
    np.testing.assert_allclose(m.body_ipos[ids], hand.link_com.numpy(), rtol=0, atol=1e-15)
    return m


def _random_state(hand: HandModel, n: int, seed: int):
    """q within the limits, root poses in a 1 m cube, nu ~ N(0, 1) and nu_dot ~ N(0, 10^2) (rad, m, s)."""
    gen = torch.Generator().manual_seed(seed)
    q = hand.random_q(n, gen)
    pos, quat = _random_roots(n, gen)
    root = torch.as_tensor(np.stack([_pose(_quat_to_mat(qq), p) for p, qq in zip(pos, quat)]))
    N = 6 + hand.num_joints
    nu = torch.randn(n, N, generator=gen, dtype=torch.float64)
    nu_dot = 10 * torch.randn(n, N, generator=gen, dtype=torch.float64)
    return q, root, nu, nu_dot, quat


def _mj_inverse(hand: HandModel, m, q, root, nu, nu_dot, quat) -> np.ndarray:
    """MuJoCo's qfrc_inverse in torchhand's coordinates: qvel = S nu, qacc = S nu_dot, u = S^T qfrc_inverse."""
    jid = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n) for n in hand.joint_names]
    qadr, dadr = m.jnt_qposadr[jid], m.jnt_dofadr[jid]
    d = mujoco.MjData(m)
    D = hand.num_joints
    out = []
    for b in range(q.shape[0]):
        R = root[b, :3, :3].numpy()
        S = np.zeros((m.nv, 6 + D))
        S[0:3, 3:6] = np.eye(3)
        S[3:6, 0:3] = R.T
        S[dadr, 6 + np.arange(D)] = 1
        d.qpos[:] = m.qpos0
        d.qpos[:3], d.qpos[3:7], d.qpos[qadr] = root[b, :3, 3].numpy(), quat[b], q[b].numpy()
        d.qvel[:], d.qacc[:] = S @ nu[b].numpy(), S @ nu_dot[b].numpy()
        mujoco.mj_inverse(m, d)
        out.append(S.T @ d.qfrc_inverse)
    return np.stack(out)


@pytest.mark.parametrize("name", HANDS)
def test_inverse_dynamics_matches_mujoco(name):
    hand = _hand(name)
    m = _mujoco_model(hand)
    q, root, nu, nu_dot, quat = _random_state(hand, N_POSES, seed=11)
    ref = _mj_inverse(hand, m, q, root, nu, nu_dot, quat)
    u = inverse_dynamics(hand, q, root, nu, nu_dot, check=True)
    assert u.shape == (N_POSES, 6 + hand.num_joints) and u.dtype == torch.float64
    scale = float(np.abs(ref).max())
    assert float(np.abs(u.numpy() - ref).max()) <= TOL * scale, float(np.abs(u.numpy() - ref).max()) / scale
    h32 = hand.to(dtype=torch.float32)
    u32 = inverse_dynamics(h32, q.float(), root.float(), nu.float(), nu_dot.float()).double().numpy()
    assert float(np.abs(u32 - ref).max()) <= 1e-5 * scale, float(np.abs(u32 - ref).max()) / scale


_ROOT_JOINTS = """<mujoco><compiler angle="radian"/><worldbody>
  <body name="palm"><joint name="wx" axis="1 0 0" range="-1 1"/><joint name="sz" type="slide" range="-0.1 0.1"/>
    <geom type="box" size="0.03 0.02 0.01" pos="0.01 0 0"/>
    <body name="f1" pos="0.05 0 0"><joint name="a" axis="0 1 0" range="0 1.5"/>
      <joint name="s" type="slide" axis="0.6 0 0.8" range="-0.02 0.02"/>
      <geom type="capsule" size="0.01 0.02" euler="0 1.5 0" pos="0.02 0 0"/>
      <body name="f2" pos="0.04 0 0"><joint name="b" axis="0 1 0" pos="0.01 0.005 0" range="0 1.5"/>
        <geom type="capsule" size="0.01 0.02" pos="0.01 0 0.01"/>
      </body></body></body></worldbody></mujoco>"""


def test_slide_joints_and_joints_on_the_root_link_match_mujoco(tmp_path):
    """Hinges and slides on the root link hang off the root pose, a hinge and a slide on one link, an anchored hinge.
    MuJoCo gets a wrapper body at the root pose for the free joint, with a placeholder inertial (1e-9 kg, 1e-12 kg m^2
    isotropic, at its origin) whose share of the force, (I alpha, m (a - g)), is taken off MuJoCo's answer."""
    (tmp_path / "h.xml").write_text(_ROOT_JOINTS)
    hand = HandModel.from_file(tmp_path / "h.xml")
    m = _mujoco_model(hand)
    wrapper = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "torchhand_root")
    assert wrapper > 0
    mass, inertia = float(m.body_mass[wrapper]), m.body_inertia[wrapper]
    assert np.all(m.body_ipos[wrapper] == 0) and np.all(inertia == inertia[0])
    q, root, nu, nu_dot, quat = _random_state(hand, 16, seed=4)
    ref = _mj_inverse(hand, m, q, root, nu, nu_dot, quat)
    ref[:, :3] -= inertia[0] * nu_dot[:, :3].numpy()
    ref[:, 3:6] -= mass * (nu_dot[:, 3:6].numpy() - m.opt.gravity)
    u = inverse_dynamics(hand, q, root, nu, nu_dot).numpy()
    assert np.abs(u - ref).max() <= TOL * np.abs(ref).max(), np.abs(u - ref).max() / np.abs(ref).max()


def test_gravity_enters_as_in_mujoco():
    """Another gravity, per batch row, and a hand at rest in the world frame (root = None)."""
    hand = _hand("default_right")
    m = _mujoco_model(hand)
    q, _, nu, nu_dot, _ = _random_state(hand, 4, seed=2)
    g = torch.tensor([[0.5, -2.0, -9.0], [0.0, 0.0, 0.0], [3.0, 1.0, 2.0], [0.0, 9.81, 0.0]], dtype=torch.float64)
    u = inverse_dynamics(hand, q, None, nu, nu_dot, g)
    root = torch.eye(4, dtype=torch.float64).expand(4, 4, 4)
    for b in range(4):
        m.opt.gravity[:] = g[b].numpy()
        ref = _mj_inverse(hand, m, q[b:b + 1], root[b:b + 1], nu[b:b + 1], nu_dot[b:b + 1],
                          np.array([[1.0, 0, 0, 0]]))
        assert np.abs(u[b].numpy() - ref[0]).max() <= TOL * np.abs(ref).max()


# ----------------------------------------------------------------------------------------------------------------
# Invariants, shapes, dtypes, bad input
# ----------------------------------------------------------------------------------------------------------------
def test_at_rest_it_is_the_gravity_torque_and_unit_accelerations_give_the_mass_matrix():
    hand = _hand("default_right")
    q, root, _, _, _ = _random_state(hand, 3, seed=5)
    N = 6 + hand.num_joints
    zero = torch.zeros(3, N, dtype=torch.float64)
    G = hand.gravity_torques(q, root)
    torch.testing.assert_close(inverse_dynamics(hand, q, root, zero, zero), G, atol=1e-14 * G.abs().max(), rtol=0)
    M = hand.mass_matrix(q, root)
    eye = torch.eye(N, dtype=torch.float64)
    for b in range(3):
        cols = inverse_dynamics(hand, q[b].expand(N, -1), root[b].expand(N, 4, 4), zero[:1].expand(N, N), eye,
                                (0.0, 0.0, 0.0))
        torch.testing.assert_close(cols.T, M[b], atol=1e-14 * M[b].abs().max(), rtol=0)


def test_velocity_terms_are_quadratic_and_rigid_body_like():
    """Without gravity and acceleration u = C(q, nu) is quadratic in nu (C(2 nu) = 4 C(nu)); with the joints still,
    the hand turns as one rigid body and the force is its mass times the centripetal acceleration of its com."""
    hand = _hand("default_right")
    q, root, nu, _, _ = _random_state(hand, 4, seed=8)
    zero = torch.zeros_like(nu)
    C = inverse_dynamics(hand, q, root, nu, zero, (0.0, 0.0, 0.0))
    torch.testing.assert_close(inverse_dynamics(hand, q, root, 2 * nu, zero, (0.0, 0.0, 0.0)), 4 * C,
                               atol=1e-13 * C.abs().max(), rtol=0)
    rigid = nu.clone()
    rigid[:, 6:] = 0
    u = inverse_dynamics(hand, q, root, rigid, zero, (0.0, 0.0, 0.0))
    # a rigid body turning at w: the force is m w x (w x (c - o)) (centripetal acceleration of the com)
    T = hand.forward_kinematics(q, root)
    com = (T[..., :3, :3] @ hand.link_com.unsqueeze(-1)).squeeze(-1) + T[..., :3, 3]
    c = (hand.link_mass[:, None] * com).sum(1) / hand.total_mass - root[:, :3, 3]
    w = rigid[:, :3]
    expected = hand.total_mass * torch.linalg.cross(w, torch.linalg.cross(w, c))
    torch.testing.assert_close(u[:, 3:6], expected, atol=1e-13 * expected.abs().max(), rtol=0)


@pytest.mark.parametrize("B", [1, 7])
def test_shapes_and_dtypes(B, dtype, device):
    hand = _hand("default_right").to(device=device, dtype=dtype)
    q, root, nu, nu_dot, _ = _random_state(_hand("default_right"), B, seed=B)
    args = [x.to(device=device, dtype=dtype) for x in (q, root, nu, nu_dot)]
    u = inverse_dynamics(hand, *args)
    assert u.shape == (B, 6 + hand.num_joints) and u.dtype == dtype and u.device.type == device
    ref = inverse_dynamics(_hand("default_right"), q, root, nu, nu_dot)
    tol = 1e-5 if dtype == torch.float32 else 1e-13
    assert float((u.double().cpu() - ref).abs().max()) <= tol * float(ref.abs().max())


def test_bad_input_raises():
    hand = _hand("default_right")
    q, root, nu, nu_dot, _ = _random_state(hand, 3, seed=1)
    with pytest.raises(ShapeError, match="q: expected shape"):
        inverse_dynamics(hand, q[:, :5], root, nu, nu_dot)
    with pytest.raises(ShapeError, match="root: expected shape"):
        inverse_dynamics(hand, q, root[:2], nu, nu_dot)
    with pytest.raises(ShapeError, match="nu: expected shape"):
        inverse_dynamics(hand, q, root, nu[:, :-1], nu_dot)
    with pytest.raises(ShapeError, match="nu_dot: expected shape"):
        inverse_dynamics(hand, q, root, nu, nu_dot[:2])
    with pytest.raises(ShapeError, match="gravity: expected shape"):
        inverse_dynamics(hand, q, root, nu, nu_dot, (0.0, -9.81))
    with pytest.raises(InputValueError, match="nu_dot: dtype"):
        inverse_dynamics(hand, q, root, nu, nu_dot.float())
    bad = nu.clone()
    bad[1, 2] = float("nan")
    with pytest.raises(InputValueError, match="nu: contains NaN"):
        inverse_dynamics(hand, q, root, bad, nu_dot, check=True)


# ----------------------------------------------------------------------------------------------------------------
# Rates of a written motion
# ----------------------------------------------------------------------------------------------------------------
_AXIS = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
_W = 1.7 * _AXIS  # rad/s, constant world angular velocity
_R0 = Rotation.from_rotvec([0.3, 0.2, -1.0]).as_matrix()
_P0, _V0, _A = np.array([0.1, -0.2, 0.3]), np.array([0.5, 0.0, -0.4]), np.array([-1.0, 2.0, 0.5])
_FREQ = np.array([1.0, 2.5, 4.0])  # rad/s of the joints' sines


def _motion(fps: float, T: int):
    """Frames t / fps of a smooth motion and its exact (nu, nu_dot): joints sin(f t), the root turning at the
    constant world angular velocity _W about a fixed axis, its origin moving with constant acceleration _A."""
    t = np.arange(T) / fps
    q = np.sin(_FREQ * t[:, None])
    root = np.tile(np.eye(4), (T, 1, 1))
    root[:, :3, :3] = Rotation.from_rotvec(t[:, None] * _W).as_matrix() @ _R0
    root[:, :3, 3] = _P0 + _V0 * t[:, None] + 0.5 * _A * t[:, None] ** 2
    nu = np.concatenate([np.tile(_W, (T, 1)), _V0 + _A * t[:, None], _FREQ * np.cos(_FREQ * t[:, None])], axis=1)
    nu_dot = np.concatenate([np.zeros((T, 3)), np.tile(_A, (T, 1)), -_FREQ ** 2 * np.sin(_FREQ * t[:, None])],
                            axis=1)
    return q, root, nu, nu_dot


def test_rates_of_a_smooth_motion_are_second_order():
    errors = []
    for fps in (50.0, 100.0, 200.0):
        T = int(fps) + 1  # one second
        q, root, nu_ref, acc_ref = _motion(fps, T)
        nu, nu_dot = motion_rates(q, root, fps)
        assert nu.shape == nu_dot.shape == (T, 9) and nu.dtype == np.float64
        np.testing.assert_allclose(nu[:, :3], nu_ref[:, :3], rtol=0, atol=1e-12)  # constant w exactly
        np.testing.assert_allclose(nu_dot[:, :3], 0.0, rtol=0, atol=1e-9)
        np.testing.assert_allclose(nu[1:-1, 3:6], nu_ref[1:-1, 3:6], rtol=0, atol=1e-12)  # quadratic: exact
        np.testing.assert_allclose(nu_dot[:, 3:6], acc_ref[:, 3:6], rtol=0, atol=1e-9)
        errors.append((np.abs(nu[1:-1] - nu_ref[1:-1]).max(), np.abs(nu_dot[1:-1] - acc_ref[1:-1]).max()))
        # central differences: |error| <= max|x'''| dt^2 / 6 (rates), max|x''''| dt^2 / 12 (accelerations)
        assert errors[-1][0] <= _FREQ.max() ** 3 / fps ** 2 / 6
        assert errors[-1][1] <= _FREQ.max() ** 4 / fps ** 2 / 12
        np.testing.assert_array_equal(nu_dot[0], nu_dot[1])
        np.testing.assert_array_equal(nu_dot[-1], nu_dot[-2])
        np.testing.assert_allclose(nu[0], (np.r_[_W, (root[1, :3, 3] - root[0, :3, 3]) * fps,
                                                 (q[1] - q[0]) * fps]), rtol=0, atol=1e-12)
    errors = np.array(errors)
    ratios = errors[:-1] / errors[1:]
    assert ((ratios > 3.8) & (ratios < 4.2)).all(), ratios


def test_rates_of_one_and_two_frames():
    q, root, _, _ = _motion(30.0, 2)
    nu, nu_dot = motion_rates(q, root, 30.0)
    np.testing.assert_array_equal(nu[0], nu[1])
    np.testing.assert_array_equal(nu_dot, np.zeros((2, 9)))
    np.testing.assert_allclose(nu[0, 6:], (q[1] - q[0]) * 30.0, rtol=0, atol=1e-13)
    nu, nu_dot = motion_rates(q[:1], root[:1], 30.0)
    np.testing.assert_array_equal(nu, np.zeros((1, 9)))
    np.testing.assert_array_equal(nu_dot, np.zeros((1, 9)))
    nu, _ = motion_rates(np.zeros((3, 0)), root[[0, 1, 1]], 30.0)  # no joints
    assert nu.shape == (3, 6)


def test_half_step_root_rates_match_mujoco_differentiate_pos():
    """mj_differentiatePos gives (p1 - p0) / dt and the body-frame rotation vector of R0^T R1 / dt: R0 times it is
    our world w_{t+1/2}."""
    m = mujoco.MjModel.from_xml_string(_FREE_BODY)
    rng = np.random.default_rng(7)
    quat = rng.normal(size=(6, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    pos = rng.normal(size=(6, 3))
    fps = 60.0
    root = np.stack([_pose(_quat_to_mat(qq), p) for p, qq in zip(pos, quat)])
    for t in range(5):
        qvel = np.zeros(6)
        mujoco.mj_differentiatePos(m, qvel, 1 / fps, np.r_[pos[t], quat[t]], np.r_[pos[t + 1], quat[t + 1]])
        nu, _ = motion_rates(np.zeros((2, 0)), root[t:t + 2], fps)
        np.testing.assert_allclose(nu[0], np.r_[root[t, :3, :3] @ qvel[3:], qvel[:3]], rtol=0, atol=1e-10)


def test_motion_rates_bad_input():
    q, root, _, _ = _motion(30.0, 4)
    with pytest.raises(ShapeError, match="^q: "):
        motion_rates(q[0], root, 30.0)
    with pytest.raises(ShapeError, match="^q: "):
        motion_rates(q[:0], root[:0], 30.0)
    with pytest.raises(ShapeError, match="^root: "):
        motion_rates(q, root[:3], 30.0)
    with pytest.raises(ShapeError, match="^root: "):
        motion_rates(q, root[:, :3], 30.0)
    for fps in (0.0, -30.0, float("nan"), float("inf"), "30", True):
        with pytest.raises(InputValueError, match="^fps: "):
            motion_rates(q, root, fps)
    bad = q.copy()
    bad[2, 1] = np.nan
    with pytest.raises(InputValueError, match="^q: "):
        motion_rates(bad, root, 30.0)
    sheared = root.copy()
    sheared[1, 0, 1] += 0.1
    with pytest.raises(InputValueError, match="^root: frame 1"):
        motion_rates(q, sheared, 30.0)
