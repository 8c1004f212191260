"""Hand dynamics (torchhand/hand/dynamics.py) against MuJoCo: link inertials read from MJCF and written back, the
mass matrix, gravity and contact torques and the floating-base point Jacobian of the default, Shadow and Allegro
hands; shapes, dtypes, bad input and the default hand's anthropometric mass."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

import torchhand
from torchhand.errors import InputValueError, ShapeError, UnknownNameError
from torchhand.hand import GeomSpec, JointSpec, LinkSpec, build_hand_model
from torchhand.hand.default import HAND_MASS_FRACTION, REFERENCE_BODY_MASS, REFERENCE_LENGTH
from torchhand.hand.dynamics import combine_inertials, mesh_inertial, primitive_inertial
from torchhand.hand.mjcf import hand_to_mjcf, load_mjcf, save_mjcf
from torchhand.hand.model import InertialSpec

from tests.conftest import shared_path
from tests.torchhand.test_mjcf import _pose, _quat_to_mat, _random_roots

mujoco = pytest.importorskip("mujoco")

TOL = 1e-9  # float64 agreement with MuJoCo: kg, kg m, kg m^2, N, N m, metres per radian
N_POSES = 64
ROBOT_HANDS = [("shadow_hand", "right_hand.xml"), ("shadow_hand", "left_hand.xml"),
               ("allegro_hand", "right_hand.xml"), ("allegro_hand", "left_hand.xml")]
ROBOT_IDS = ["shadow_right", "shadow_left", "allegro_right", "allegro_left"]


# ----------------------------------------------------------------------------------------------------------------
# MuJoCo helpers
# ----------------------------------------------------------------------------------------------------------------
def _mj_inertials(m, names):
    """MuJoCo's compiled mass (n,), com (n, 3) and inertia about the com in body axes (n, 3, 3) of named bodies."""
    ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n) for n in names]
    assert min(ids) >= 0
    R = np.stack([_quat_to_mat(m.body_iquat[i]) for i in ids])
    inertia = R @ (m.body_inertia[ids][:, :, None] * np.eye(3)) @ R.transpose(0, 2, 1)
    return m.body_mass[ids].copy(), m.body_ipos[ids].copy(), inertia


def _with_free_joint(path, root_body: str):
    """The MJCF file compiled by MuJoCo with a free joint added to ``root_body`` (its qpos is the body's world pose,
    which is the hand's ``root``); joint armature zeroed (our M has none)."""
    spec = mujoco.MjSpec.from_file(str(path))
    spec.find_body(root_body).add_freejoint()
    m = spec.compile()
    m.dof_armature[:] = 0
    return m


def _exported(hand):
    m = mujoco.MjModel.from_xml_string(hand_to_mjcf(hand))
    m.dof_armature[:] = 0
    return m


@dataclasses.dataclass
class _Reference:
    """MuJoCo's answers at N random poses, mapped to our coordinates (nu = (w, v, qdot); module docstring)."""

    q: torch.Tensor
    root: torch.Tensor
    M: np.ndarray
    bias: np.ndarray
    S: np.ndarray  # (B, nv, 6 + D): nu_mujoco = S nu
    m: object
    d: object
    qpos: np.ndarray


def _reference(hand, m, seed: int, n: int = N_POSES) -> _Reference:
    assert m.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE and m.jnt_qposadr[0] == 0
    jid = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name) for name in hand.joint_names]
    assert min(jid) > 0
    qadr, dadr = m.jnt_qposadr[jid], m.jnt_dofadr[jid]
    gen = torch.Generator().manual_seed(seed)
    q = hand.random_q(n, gen)
    pos, quat = _random_roots(n, gen)
    root = np.stack([_pose(_quat_to_mat(qq), p) for p, qq in zip(pos, quat)])
    d = mujoco.MjData(m)
    N = 6 + hand.num_joints
    Ms, bias, Ss, qposs = [], [], [], []
    for b in range(n):
        qpos = m.qpos0.copy()
        qpos[:3], qpos[3:7], qpos[qadr] = pos[b], quat[b], q[b].numpy()
        d.qpos[:], d.qvel[:] = qpos, 0
        mujoco.mj_forward(m, d)
        M = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, M, d.qM)
        # MuJoCo's free joint: qvel[0:3] = world velocity of the body origin, qvel[3:6] = body-frame angular velocity.
        S = np.zeros((m.nv, N))
        S[0:3, 3:6] = np.eye(3)
        S[3:6, 0:3] = root[b, :3, :3].T
        S[dadr, 6 + np.arange(hand.num_joints)] = 1
        Ms.append(S.T @ M @ S)
        bias.append(S.T @ d.qfrc_bias)
        Ss.append(S)
        qposs.append(qpos)
    return _Reference(q, torch.as_tensor(root), np.stack(Ms), np.stack(bias), np.stack(Ss), m, d, np.stack(qposs))


def _robot(parts):
    path = shared_path("hands", *parts)
    return path, load_mjcf(path)


def _assert_inertia_close(ours, ref):
    """Inertias (n, 3, 3) that MuJoCo diagonalised itself: its Jacobi eigen-solver stops at rotations of ~1e-6 rad
    (kEigEPS = 1e-12 on the cosine), so its principal axes carry ~1e-6 relative error; 5e-6 of each link's largest
    entry (and never more than 1e-10 kg m^2 on these hands)."""
    scale = np.abs(ref).max(axis=(1, 2), keepdims=True)
    assert (np.abs(ours - ref) <= 5e-6 * scale).all(), float((np.abs(ours - ref) / np.maximum(scale, 1e-300)).max())
    assert np.abs(ours - ref).max() < 1e-10


# ----------------------------------------------------------------------------------------------------------------
# Inertials: MJCF in, MJCF out
# ----------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("parts", ROBOT_HANDS, ids=ROBOT_IDS)
def test_inertials_read_from_mjcf_match_mujoco(parts):
    path, hand = _robot(parts)
    m = mujoco.MjModel.from_xml_path(str(path))
    mass, com, inertia = _mj_inertials(m, hand.link_names)
    ours = hand.link_mass.numpy(), hand.link_com.numpy(), hand.link_inertia.numpy()
    if parts[0] == "shadow_hand":
        # Explicit <inertial> on every body (diaginertia rotated by the inertial frame's quat).
        np.testing.assert_allclose(ours[0], mass, atol=1e-15, rtol=0)
        np.testing.assert_allclose(ours[1], com, atol=1e-15, rtol=0)
        np.testing.assert_allclose(ours[2], inertia, atol=1e-15, rtol=0)
        assert hand.total_mass == pytest.approx(3.794, abs=1e-12)  # with the 3 kg forearm
    else:
        # No <inertial>: from all geoms (visual meshes at density 800 with MuJoCo's legacy mesh inertia, in its
        # float32 vertex arithmetic; the collision boxes have mass 0).
        np.testing.assert_allclose(ours[0], mass, rtol=1e-13, atol=0)
        np.testing.assert_allclose(ours[1], com, atol=1e-15, rtol=0)
        _assert_inertia_close(ours[2], inertia)
        assert 0.6 < hand.total_mass < 0.7


@pytest.mark.parametrize("side", ["right", "left"])
def test_written_inertials_round_trip_through_mujoco(side, tmp_path):
    hand = torchhand.default_hand(side, 0.2)
    m = mujoco.MjModel.from_xml_path(str(save_mjcf(hand, tmp_path / "hand.xml")))
    mass, com, inertia = _mj_inertials(m, hand.link_names)
    np.testing.assert_allclose(mass, hand.link_mass.numpy(), atol=1e-15, rtol=0)
    np.testing.assert_allclose(com, hand.link_com.numpy(), atol=1e-15, rtol=0)
    np.testing.assert_allclose(inertia, hand.link_inertia.numpy(), atol=1e-15, rtol=0)
    back = load_mjcf(tmp_path / "hand.xml")
    assert torch.equal(back.link_mass, hand.link_mass) and torch.equal(back.link_com, hand.link_com)
    torch.testing.assert_close(back.link_inertia, hand.link_inertia, atol=1e-15 * hand.link_inertia.abs().max(),
                               rtol=0)


def test_written_shadow_hand_keeps_its_inertials():
    _, hand = _robot(("shadow_hand", "right_hand.xml"))
    m = mujoco.MjModel.from_xml_string(hand.to_mjcf())
    mass, com, inertia = _mj_inertials(m, hand.link_names)
    np.testing.assert_allclose(mass, hand.link_mass.numpy(), atol=1e-15, rtol=0)
    np.testing.assert_allclose(com, hand.link_com.numpy(), atol=1e-15, rtol=0)
    np.testing.assert_allclose(inertia, hand.link_inertia.numpy(), atol=1e-15, rtol=0)


_INERTIA_FORMS = """<mujoco model="inertia_forms">
  <compiler angle="degree" eulerseq="zyx"/>
  <default><geom density="700"/><default class="light"><geom density="300"/></default></default>
  <asset>
    <mesh name="wedge" vertex="0 0 0  0.0625 0 0  0 0.046875 0  0 0 0.03125  0.0625 0 0.03125  0 0.046875 0.03125"/>
    <mesh name="tet_exact" inertia="exact" vertex="0 0 0  0.03125 0 0  0 0.0625 0  0 0 0.046875"/>
    <mesh name="dent" vertex="0 0 0  0.0625 0 0  0.0625 0.0625 0  0 0.0625 0  0.03125 0.03125 0.015625
      0 0 0.0625  0.0625 0 0.0625  0.0625 0.0625 0.0625  0 0.0625 0.0625"
      face="0 2 1  0 3 2  5 6 4  6 7 4  7 8 4  8 5 4  0 1 6  0 6 5  1 2 7  1 7 6  2 3 8  2 8 7  3 0 5  3 5 8"/>
  </asset>
  <worldbody>
    <body name="base">
      <inertial pos="0.01 0.02 -0.01" euler="30 -20 60" mass="0.4" diaginertia="0.003 0.002 0.0015"/>
      <geom type="box" size="0.04 0.03 0.01"/>
      <body name="a" pos="0.05 0 0">
        <joint name="ja" axis="0 1 0" range="-30 60"/>
        <geom type="capsule" fromto="0 0 0 0.04 0.01 0" size="0.008"/>
        <geom type="sphere" size="0.01" pos="0.04 0.01 0" contype="0" conaffinity="0"/>
        <geom type="cylinder" size="0.006 0.01" euler="0 90 0" class="light"/>
        <geom type="ellipsoid" size="0.01 0.006 0.004" pos="0 0 0.01" mass="0.002"/>
        <geom type="box" size="0.01 0.01 0.01" group="4" pos="0 0.01 0"/>
        <body name="b" pos="0.05 0 0">
          <joint name="jb" axis="0 1 0" range="0 90"/>
          <inertial pos="0.01 0 0" mass="0.02" fullinertia="4e-6 5e-6 6e-6 1e-7 -2e-7 3e-7"/>
          <geom type="mesh" mesh="wedge" pos="0.01 0 0" quat="0.9 0.1 -0.2 0.3"/>
          <body name="c" pos="0.04 0 0">
            <joint name="jc" axis="0 1 0" range="0 90"/>
            <geom type="mesh" mesh="tet_exact" euler="10 20 30"/>
            <geom type="mesh" mesh="dent" pos="0.01 0 0" contype="0" conaffinity="0"/>
            <frame pos="0 0.01 0" euler="0 0 90"><geom type="box" size="0.005 0.01 0.002" pos="0.01 0 0"/></frame>
          </body>
        </body>
        <body name="tip_site_only" pos="0 0 0.02"><site name="s"/></body>
      </body>
    </body>
  </worldbody>
</mujoco>"""


@pytest.mark.parametrize("compiler", ["", 'inertiafromgeom="true"', 'inertiagrouprange="0 3"',
                                      'settotalmass="1.5"', 'boundmass="0.01" boundinertia="1e-6"'],
                         ids=["auto", "fromgeom_true", "grouprange", "settotalmass", "bounds"])
def test_inertial_forms_match_mujoco(tmp_path, compiler):
    """Explicit inertials (euler with eulerseq, fullinertia), inertia from primitives, visual geoms, mass vs
    density, classes, frames, meshes (legacy non-convex, exact) and the compiler's inertia settings."""
    xml = _INERTIA_FORMS.replace('eulerseq="zyx"', f'eulerseq="zyx" {compiler}')
    (tmp_path / "forms.xml").write_text(xml)
    hand = load_mjcf(tmp_path / "forms.xml")
    m = mujoco.MjModel.from_xml_string(xml)
    mass, com, inertia = _mj_inertials(m, hand.link_names)
    np.testing.assert_allclose(hand.link_mass.numpy(), mass, rtol=1e-12, atol=1e-15)
    # A body without geoms or <inertial> gets MuJoCo's ipos = its pos in the parent (only boundmass gives it mass);
    # ours is the link origin.
    some = np.array([n != "tip_site_only" for n in hand.link_names])
    np.testing.assert_allclose(hand.link_com.numpy()[some], com[some], rtol=0, atol=1e-12)
    _assert_inertia_close(hand.link_inertia.numpy(), inertia)
    assert hand.link_mass[hand.link_index("tip_site_only")] == (0.01 if "boundmass" in compiler else 0)


def test_mesh_and_primitive_inertials_against_trimesh():
    import trimesh

    for mesh in (trimesh.creation.box(extents=(0.02, 0.03, 0.05)), trimesh.creation.icosphere(2, radius=0.02),
                 trimesh.creation.annulus(0.01, 0.03, 0.02)):  # the annulus is not convex
        mesh.density = 1100.0
        m, c, I = mesh_inertial(mesh.vertices, mesh.faces, 1100.0)
        assert m == pytest.approx(mesh.mass, rel=1e-12)
        np.testing.assert_allclose(c, mesh.center_mass, atol=1e-15)
        np.testing.assert_allclose(I, mesh.moment_inertia, rtol=0, atol=1e-12 * np.abs(I).max())
        inverted = mesh_inertial(mesh.vertices, mesh.faces[:, ::-1], 1100.0)
        assert inverted[0] == pytest.approx(m, rel=1e-12)
    box = trimesh.creation.box(extents=(0.02, 0.03, 0.05))
    m, _, I = primitive_inertial("box", (0.01, 0.015, 0.025), 1000.0)
    box.density = 1000.0
    assert m == pytest.approx(box.mass, rel=1e-12)
    np.testing.assert_allclose(I, box.moment_inertia, rtol=1e-12, atol=0)
    # Parallel axis: two spheres joined.
    s = primitive_inertial("sphere", (0.01,), 1000.0)
    m2, c2, I2 = combine_inertials([(s[0], np.array([0.0, 0, 0]), s[2]), (s[0], np.array([0.02, 0, 0]), s[2])])
    assert m2 == pytest.approx(2 * s[0]) and np.allclose(c2, [0.01, 0, 0])
    assert I2[1, 1] == pytest.approx(2 * s[2][1, 1] + 2 * s[0] * 0.01 ** 2, rel=1e-12)
    assert I2[0, 0] == pytest.approx(2 * s[2][0, 0], rel=1e-12)


# ----------------------------------------------------------------------------------------------------------------
# Acceptance: dynamics against MuJoCo
# ----------------------------------------------------------------------------------------------------------------
def _cases():
    return ["default_right", "default_left", "shadow", "allegro"]


def _case(name):
    if name.startswith("default"):
        hand = torchhand.default_hand(name.split("_")[1])
        return hand, _exported(hand)
    path, hand = _robot((f"{name}_hand", "right_hand.xml"))
    return hand, _with_free_joint(path, hand.link_names[0])


@pytest.mark.parametrize("name", _cases())
def test_mass_matrix_and_gravity_match_mujoco(name):
    hand, m = _case(name)
    ref = _reference(hand, m, seed=17)
    M = hand.mass_matrix(ref.q, ref.root).numpy()
    G = hand.gravity_torques(ref.q, ref.root).numpy()
    N = 6 + hand.num_joints
    assert M.shape == (N_POSES, N, N) and G.shape == (N_POSES, N)
    assert np.abs(M - ref.M).max() < TOL, np.abs(M - ref.M).max()
    assert np.abs(G - ref.bias).max() < TOL, np.abs(G - ref.bias).max()
    assert np.array_equal(M, M.transpose(0, 2, 1))
    assert np.linalg.eigvalsh(M).min() > 0


@pytest.mark.parametrize("name", _cases())
def test_floating_point_jacobian_and_contact_torques_match_mujoco(name):
    hand, m = _case(name)
    ref = _reference(hand, m, seed=23)
    links = hand.distal_link
    tips = hand.fingertip
    J = hand.point_jacobian(ref.q, links, tips, ref.root, wrt_root=True).numpy()
    x, Jq = hand.points_and_jacobian(ref.q, links, tips, ref.root)
    assert J.shape == (N_POSES, hand.num_fingers, 3, 6 + hand.num_joints)
    assert np.array_equal(J[..., 6:], Jq.numpy())  # the joint columns are the existing Jacobian
    gen = torch.Generator().manual_seed(4)
    forces = torch.randn(N_POSES, hand.num_fingers, 3, generator=gen, dtype=torch.float64)
    tau = hand.contact_torques(ref.q, ref.root, links, tips, forces).numpy()
    jacp = np.zeros((3, m.nv))
    err_J = err_tau = 0.0
    for b in range(N_POSES):
        ref.d.qpos[:] = ref.qpos[b]
        mujoco.mj_kinematics(m, ref.d)
        mujoco.mj_comPos(m, ref.d)
        qfrc = np.zeros(m.nv)
        for f in range(hand.num_fingers):
            body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, hand.link_names[int(links[f])])
            mujoco.mj_jac(m, ref.d, jacp, None, x[b, f].numpy(), body)
            err_J = max(err_J, np.abs(jacp @ ref.S[b] - J[b, f]).max())
            mujoco.mj_applyFT(m, ref.d, forces[b, f].numpy(), np.zeros(3), x[b, f].numpy(), body, qfrc)
        err_tau = max(err_tau, np.abs(ref.S[b].T @ qfrc - tau[b]).max())
    assert err_J < TOL and err_tau < TOL, (err_J, err_tau)


def test_root_link_with_joints_matches_mujoco(tmp_path):
    """Joints on the root link hang off the root pose; MuJoCo gets a wrapper body with the free joint (1e-9 kg)."""
    xml = """<mujoco><compiler angle="radian"/><worldbody>
      <body name="palm"><joint name="wx" axis="1 0 0" range="-1 1"/><joint name="sz" type="slide" range="-0.1 0.1"/>
        <geom type="box" size="0.03 0.02 0.01" pos="0.01 0 0"/>
        <body name="f1" pos="0.05 0 0"><joint name="a" axis="0 1 0" range="0 1.5"/>
          <geom type="capsule" size="0.01 0.02" euler="0 1.5 0" pos="0.02 0 0"/>
          <body name="f2" pos="0.04 0 0"><joint name="b" axis="0 1 0" range="0 1.5"/>
            <geom type="capsule" size="0.01 0.02" pos="0.01 0 0.01"/>
          </body></body></body></worldbody></mujoco>"""
    (tmp_path / "h.xml").write_text(xml)
    hand = load_mjcf(tmp_path / "h.xml")
    ref = _reference(hand, _exported(hand), seed=5, n=16)
    M = hand.mass_matrix(ref.q, ref.root).numpy()
    G = hand.gravity_torques(ref.q, ref.root).numpy()
    assert np.abs(M - ref.M).max() < 1e-8 and np.abs(G - ref.bias).max() < 1e-7  # the wrapper's 1e-9 kg


# ----------------------------------------------------------------------------------------------------------------
# Invariants, shapes, dtypes, bad input
# ----------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("B", [1, 7])
def test_shapes_and_dtypes(B, dtype, device, gen):
    hand = torchhand.default_hand().to(device=device, dtype=dtype)
    assert hand.link_mass.dtype == dtype and hand.link_inertia.device.type == device
    q = hand.random_q(B, gen).to(device)
    root = torch.eye(4, dtype=dtype, device=device).repeat(B, 1, 1)
    root[:, :3, 3] = torch.tensor([0.1, -0.2, 0.3], dtype=dtype, device=device)
    N, P = 6 + hand.num_joints, 4
    links = torch.tensor([0, 3, 7, 19], device=device)
    pts = torch.zeros(P, 3, dtype=dtype, device=device)
    assert hand.mass_matrix(q, root).shape == (B, N, N)
    assert hand.mass_matrix(q).dtype == dtype
    assert hand.gravity_torques(q, root).shape == (B, N)
    assert hand.point_jacobian(q, links, pts, root, wrt_root=True).shape == (B, P, 3, N)
    assert hand.point_jacobian(q, links, pts, root).shape == (B, P, 3, hand.num_joints)  # default unchanged
    f = torch.ones(B, P, 3, dtype=dtype, device=device)
    assert hand.contact_torques(q, root, links, pts, f).shape == (B, N)
    g = torch.tensor([[0.0, 0.0, -9.81]], dtype=dtype, device=device).expand(B, 3)
    torch.testing.assert_close(hand.gravity_torques(q, root, g), hand.gravity_torques(q, root))


def test_float32_agrees_with_float64(gen):
    hand = torchhand.default_hand()
    q = hand.random_q(7, gen)
    pos, quat = _random_roots(7, gen)
    root = torch.as_tensor(np.stack([_pose(_quat_to_mat(qq), p) for p, qq in zip(pos, quat)]))
    h32 = hand.to(dtype=torch.float32)
    M64, M32 = hand.mass_matrix(q, root), h32.mass_matrix(q.float(), root.float())
    G64, G32 = hand.gravity_torques(q, root), h32.gravity_torques(q.float(), root.float())
    assert M32.dtype == torch.float32
    assert float((M32.double() - M64).abs().max()) < 1e-6 * float(M64.abs().max())
    assert float((G32.double() - G64).abs().max()) < 1e-5 * float(G64.abs().max())


def test_invariants(gen):
    """Gravity = -J^T (m g) at the links' centres of mass; the root block of M is the rigid-body one; M doesn't
    depend on the root's position; kinetic energy of a pure root translation is m |v|^2 / 2."""
    hand = torchhand.default_hand()
    B, L = 5, hand.num_links
    q = hand.random_q(B, gen)
    pos, quat = _random_roots(B, gen)
    root = torch.as_tensor(np.stack([_pose(_quat_to_mat(qq), p) for p, qq in zip(pos, quat)]))
    g = torch.tensor([0.3, -1.0, -9.0], dtype=torch.float64)
    weights = (hand.link_mass[:, None] * g).expand(B, L, 3)
    G = hand.gravity_torques(q, root, g)
    torch.testing.assert_close(G, -hand.contact_torques(q, root, torch.arange(L), hand.link_com, weights),
                               atol=1e-14, rtol=0)
    M = hand.mass_matrix(q, root)
    m = hand.total_mass
    torch.testing.assert_close(M[:, 3:6, 3:6], m * torch.eye(3, dtype=torch.float64).expand(B, 3, 3), atol=1e-14,
                               rtol=0)
    shifted = root.clone()
    shifted[:, :3, 3] += torch.tensor([1.0, 2.0, -3.0], dtype=torch.float64)
    torch.testing.assert_close(hand.mass_matrix(q, shifted), M, atol=1e-13, rtol=0)
    # Torque about the root origin of the weight: (com - o) x (m g) -> the root block of G is -(that, m g).
    T = hand.forward_kinematics(q, root)
    com = ((T[..., :3, :3] @ hand.link_com.unsqueeze(-1)).squeeze(-1) + T[..., :3, 3])
    c = (hand.link_mass[:, None] * com).sum(1) / m - root[:, :3, 3]
    torch.testing.assert_close(G[:, :3], -torch.linalg.cross(c, (m * g).expand(B, 3)), atol=1e-14, rtol=0)
    torch.testing.assert_close(G[:, 3:6], -(m * g).expand(B, 3), atol=1e-14, rtol=0)


def test_bad_input_raises_shape_errors(gen):
    hand = torchhand.default_hand()
    q = hand.random_q(3, gen)
    links, pts = torch.tensor([1, 2]), torch.zeros(2, 3, dtype=torch.float64)
    with pytest.raises(ShapeError, match="q: expected shape"):
        hand.mass_matrix(q[:, :5])
    with pytest.raises(ShapeError, match="root: expected shape"):
        hand.gravity_torques(q, torch.eye(4, dtype=torch.float64).expand(2, 4, 4))
    with pytest.raises(ShapeError, match="gravity: expected shape"):
        hand.gravity_torques(q, None, (0.0, -9.81))
    with pytest.raises(ShapeError, match="forces: expected shape"):
        hand.contact_torques(q, None, links, pts, torch.zeros(3, 3, 3, dtype=torch.float64))
    with pytest.raises(ShapeError, match="points_local: expected shape"):
        hand.point_jacobian(q, links, torch.zeros(3, 3, dtype=torch.float64), wrt_root=True)
    with pytest.raises(ShapeError, match="link_index: expected shape"):
        hand.contact_torques(q, None, torch.tensor([[1, 2]]), pts, torch.zeros(3, 2, 3, dtype=torch.float64))
    with pytest.raises(InputValueError, match="forces: dtype"):
        hand.contact_torques(q, None, links, pts, torch.zeros(3, 2, 3, dtype=torch.float32))
    with pytest.raises(ShapeError, match="link_mass: expected shape"):
        dataclasses.replace(hand, link_mass=torch.zeros(3, dtype=torch.float64))


# ----------------------------------------------------------------------------------------------------------------
# Built-in hand mass and build_hand_model's inertials
# ----------------------------------------------------------------------------------------------------------------
def test_default_hand_mass_follows_anthropometry():
    """0.006 of a 70 kg body (Dempster; Winter, Table 4.1) at 0.19 m, scaled with length^3, split by volume."""
    assert HAND_MASS_FRACTION * REFERENCE_BODY_MASS == pytest.approx(0.42)
    for side, length in (("right", REFERENCE_LENGTH), ("left", REFERENCE_LENGTH), ("right", 0.16), ("left", 0.22)):
        hand = torchhand.default_hand(side, length)
        assert hand.total_mass == pytest.approx(0.42 * (length / REFERENCE_LENGTH) ** 3, rel=1e-12)
    hand = torchhand.default_hand()
    assert (hand.link_mass > 0).all()
    # One density: mass / capsule volume is the same for every link; the palm link is the carpal capsule.
    r, h = hand.geoms.size[0, 0].item(), hand.geoms.size[0, 1].item()
    density = hand.link_mass[0].item() / (math.pi * (r * r * 2 * h + 4 * r ** 3 / 3))
    assert 1000 < density < 2000
    dist = hand.link_index("index_distal")
    r, h = hand.capsule_radius[dist].item(), 0.5 * (hand.capsule_b[dist] - hand.capsule_a[dist]).norm().item()
    assert hand.link_mass[dist].item() == pytest.approx(density * math.pi * (r * r * 2 * h + 4 * r ** 3 / 3), rel=1e-9)
    # Inertia about the centre of mass: positive definite, mirrored between sides.
    assert torch.linalg.eigvalsh(hand.link_inertia).min() > 0
    left = torchhand.default_hand("left")
    M = torch.diag(torch.tensor([1.0, -1.0, 1.0], dtype=torch.float64))
    torch.testing.assert_close(left.link_com, hand.link_com @ M, atol=1e-15, rtol=0)
    torch.testing.assert_close(left.link_inertia, M @ hand.link_inertia @ M, atol=1e-18, rtol=1e-12)


def test_build_hand_model_inertials():
    z = np.array([0.0, 0.0, 1.0])
    off = np.eye(4)
    off[0, 3] = 0.1
    links = [LinkSpec("base", None, np.eye(4)), LinkSpec("arm", "base", off), LinkSpec("empty", "arm", off)]
    joints = [JointSpec("j", "arm", "hinge", z, np.zeros(3), np.array([-1.0, 1.0]))]
    geoms = [GeomSpec("base", "sphere", np.array([0.02]), np.eye(4)),
             GeomSpec("arm", "box", np.array([0.05, 0.01, 0.01]), _pose(np.eye(3), [0.05, 0, 0]))]
    given = InertialSpec("base", 2.0, np.array([0.0, 0.0, 0.01]), np.diag([1e-3, 2e-3, 2.5e-3]))
    hand = build_hand_model("t", links, joints, geoms, inertials=[given])
    assert hand.link_mass.tolist() == pytest.approx([2.0, 1000 * 8 * 0.05 * 0.01 * 0.01, 0.0])
    torch.testing.assert_close(hand.link_com[1], torch.tensor([0.05, 0, 0], dtype=torch.float64))
    assert torch.equal(hand.link_inertia[2], torch.zeros(3, 3, dtype=torch.float64))
    assert build_hand_model("t", links, joints, geoms, density=500.0).link_mass[1].item() == \
        pytest.approx(500 * 8 * 0.05 * 0.01 * 0.01)
    with pytest.raises(UnknownNameError, match="nope"):
        build_hand_model("t", links, joints, geoms, inertials=[dataclasses.replace(given, link="nope")])
    with pytest.raises(InputValueError, match="more than one inertial"):
        build_hand_model("t", links, joints, geoms, inertials=[given, given])
    with pytest.raises(ShapeError, match="inertial of link 'base'"):
        build_hand_model("t", links, joints, geoms, inertials=[dataclasses.replace(given, com=np.zeros(2))])
    with pytest.raises(InputValueError, match="positive semi-definite"):
        build_hand_model("t", links, joints, geoms, inertials=[dataclasses.replace(given, inertia=-np.eye(3))])
    # A massless link is written with a tiny inertial that MuJoCo accepts; the rest as given.
    m = mujoco.MjModel.from_xml_string(hand.to_mjcf())
    mass, _, _ = _mj_inertials(m, hand.link_names)
    assert mass.tolist() == pytest.approx([2.0, hand.link_mass[1].item(), 1e-9], rel=1e-15)
    # A model constructed without inertials is massless.
    bare = dataclasses.replace(hand, link_mass=None, link_com=None, link_inertia=None)
    assert bare.total_mass == 0 and bare.link_inertia.shape == (3, 3, 3)
