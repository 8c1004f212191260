"""MJCF import/export against MuJoCo: FK agreement (exported default hand, Shadow, Allegro), geometry frames,
round trips, the parser's coverage of MJCF forms, and errors on bad input."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import torch

import torchhand
from torchhand.errors import FileFormatError, MissingFileError, TorchhandError
from torchhand.hand import HandModel
from torchhand.hand.mjcf import hand_to_mjcf, load_mjcf, save_mjcf

from tests.conftest import shared_path

mujoco = pytest.importorskip("mujoco")

REPO = Path(__file__).resolve().parents[2]
TOL = 1e-9  # metres and rotation-matrix entries, float64
N_POSES = 64


def _hand_file(*parts: str) -> Path:
    return shared_path("hands", *parts)


def _quat_to_mat(q: np.ndarray) -> np.ndarray:
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, np.asarray(q, dtype=np.float64))
    return R.reshape(3, 3)


def _pose(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


def _mj_body_poses(m, d, names) -> np.ndarray:
    """MuJoCo's world poses (n, 4, 4) of the named bodies after mj_kinematics."""
    ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n) for n in names]
    assert min(ids) >= 0, "a link has no MuJoCo body of the same name"
    return np.stack([_pose(d.xmat[i].reshape(3, 3), d.xpos[i]) for i in ids])


def _roots(pos: np.ndarray, quat: np.ndarray) -> torch.Tensor:
    """Root poses (B, 4, 4) from positions (B, 3) and quaternions wxyz (B, 4)."""
    return torch.as_tensor(np.stack([_pose(_quat_to_mat(qq), p) for p, qq in zip(pos, quat)]))


def _mj_free_fk(m, d, pos: np.ndarray, quat: np.ndarray, q: torch.Tensor, names) -> np.ndarray:
    """MuJoCo's body poses (B, L, 4, 4) of ``names`` for qpos = (pos, quat wxyz, q) of a free-jointed hand."""
    out = []
    for b in range(q.shape[0]):
        d.qpos[:] = np.concatenate([pos[b], quat[b], q[b].numpy()])
        mujoco.mj_kinematics(m, d)
        out.append(_mj_body_poses(m, d, names))
    return np.stack(out)


def _fk_errors(ours: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
    """Max position error (metres) and max rotation-matrix entry error over all poses and links."""
    pos = float(np.abs(ours[..., :3, 3] - ref[..., :3, 3]).max())
    return pos, float(np.abs(ours[..., :3, :3] - ref[..., :3, :3]).max())


def _random_roots(n: int, gen: torch.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Random root poses: positions (n, 3) in a 1 m cube and unit quaternions wxyz (n, 4)."""
    pos = (torch.rand(n, 3, generator=gen, dtype=torch.float64) - 0.5).numpy()
    quat = torch.randn(n, 4, generator=gen, dtype=torch.float64).numpy()
    return pos, quat / np.linalg.norm(quat, axis=1, keepdims=True)


# ----------------------------------------------------------------------------------------------------------------
# Acceptance: FK against MuJoCo
# ----------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("side", ["right", "left"])
def test_exported_default_hand_fk_matches_mujoco(side):
    hand = torchhand.default_hand(side)
    m = mujoco.MjModel.from_xml_string(hand_to_mjcf(hand))
    d = mujoco.MjData(m)
    D = hand.num_joints
    assert m.nq == 7 + D
    gen = torch.Generator().manual_seed(7)
    q = hand.random_q(N_POSES, gen)
    pos, quat = _random_roots(N_POSES, gen)
    root = _roots(pos, quat)
    ep, er = _fk_errors(hand.forward_kinematics(q, root).numpy(), _mj_free_fk(m, d, pos, quat, q, hand.link_names))
    assert ep < TOL and er < TOL, (ep, er)


@pytest.mark.parametrize("parts", [("shadow_hand", "right_hand.xml"), ("shadow_hand", "left_hand.xml"),
                                   ("allegro_hand", "right_hand.xml"), ("allegro_hand", "left_hand.xml")],
                         ids=["shadow_right", "shadow_left", "allegro_right", "allegro_left"])
def test_loaded_robot_hand_fk_matches_mujoco(parts):
    path = _hand_file(*parts)
    hand = load_mjcf(path)
    m = mujoco.MjModel.from_xml_path(str(path))
    d = mujoco.MjData(m)
    assert hand.num_joints == m.njnt == m.nq
    assert hand.num_links == m.nbody - 1
    assert hand.side == parts[1].split("_")[0]
    qadr = [int(m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n)]) for n in hand.joint_names]
    assert qadr == list(range(hand.num_joints))  # joints in MuJoCo's qpos order
    # Limits equal MuJoCo's compiled ranges (degrees/radians resolved, classes applied).
    np.testing.assert_allclose(hand.joint_limits.numpy(), m.jnt_range[: hand.num_joints], atol=1e-12)
    gen = torch.Generator().manual_seed(11)
    q = hand.random_q(N_POSES, gen)
    ours, ref = [], []
    for b in range(N_POSES):
        d.qpos[:] = q[b].numpy()
        mujoco.mj_kinematics(m, d)
        poses = _mj_body_poses(m, d, hand.link_names)
        ref.append(poses)
        ours.append(hand.forward_kinematics(q[b : b + 1], torch.as_tensor(poses[:1]))[0].numpy())
    ep, er = _fk_errors(np.stack(ours), np.stack(ref))
    assert ep < TOL and er < TOL, (ep, er)


@pytest.mark.parametrize("parts", [("shadow_hand", "right_hand.xml"), ("allegro_hand", "right_hand.xml")],
                         ids=["shadow", "allegro"])
def test_loaded_geometry_matches_mujoco_geom_frames(parts):
    """Collision geoms (visual ones skipped) in MuJoCo's order, as MuJoCo compiled them: primitives with MuJoCo's
    pose and size, mesh geoms with MuJoCo's (re-centred) vertices and pose."""
    path = _hand_file(*parts)
    hand = load_mjcf(path)
    m = mujoco.MjModel.from_xml_path(str(path))
    coll = [g for g in range(m.ngeom) if m.geom_contype[g] or m.geom_conaffinity[g]]
    assert len(coll) == hand.geoms.link.shape[0]
    n_mesh = 0
    for k, g in enumerate(coll):
        body = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, m.geom_bodyid[g])
        assert hand.link_names[int(hand.geoms.link[k])] == body
        ref = _pose(_quat_to_mat(m.geom_quat[g]), m.geom_pos[g])
        ours = hand.geoms.pose[k].numpy()
        if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
            n_mesh += 1
            mid = m.geom_dataid[g]
            np.testing.assert_allclose(ours, ref, atol=1e-12)
            V_mj = m.mesh_vert[m.mesh_vertadr[mid] : m.mesh_vertadr[mid] + m.mesh_vertnum[mid]].astype(np.float64)
            V_ours = hand.geoms.meshes[int(hand.geoms.mesh_index[k])][0].numpy()
            assert V_ours.shape == V_mj.shape
            np.testing.assert_array_equal(V_ours, V_mj)
        else:
            np.testing.assert_allclose(ours, ref, atol=1e-9)
            n = {mujoco.mjtGeom.mjGEOM_SPHERE: 1, mujoco.mjtGeom.mjGEOM_CAPSULE: 2,
                 mujoco.mjtGeom.mjGEOM_CYLINDER: 2, mujoco.mjtGeom.mjGEOM_BOX: 3}[int(m.geom_type[g])]
            np.testing.assert_allclose(hand.geoms.size[k, :n].numpy(), m.geom_size[g, :n], atol=1e-12)
    assert (n_mesh > 0) == (parts[0] == "shadow_hand")


def test_loaded_shadow_fingers():
    hand = load_mjcf(_hand_file("shadow_hand", "right_hand.xml"))
    assert hand.finger_names == ("ff", "mf", "rf", "lf", "th")
    ff = hand.finger_names.index("ff")
    assert [hand.link_names[int(i)] for i in hand.finger_links[ff]] == \
        ["rh_ffknuckle", "rh_ffproximal", "rh_ffmiddle", "rh_ffdistal"]
    assert [hand.joint_names[int(i)] for i in hand.flexion_joints[ff]] == ["rh_FFJ3", "rh_FFJ2", "rh_FFJ1"]
    # The Shadow palm faces -y: fingers flex toward -y, nails point +y; the tip is at the distal end (+z).
    assert float(hand.nail_normal[ff] @ torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)) > 0.99
    assert 0.025 < float(hand.fingertip[ff, 2]) < 0.04
    assert 0.15 < hand.length < 0.25


# ----------------------------------------------------------------------------------------------------------------
# Export and round trip
# ----------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("side", ["right", "left"])
def test_exported_names_and_limits(side):
    hand = torchhand.default_hand(side)
    m = mujoco.MjModel.from_xml_string(hand.to_mjcf())
    assert m.nq == 7 + hand.num_joints and m.njnt == 1 + hand.num_joints
    assert m.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE
    bodies = tuple(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, i) for i in range(1, m.nbody))
    joints = tuple(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, i) for i in range(1, m.njnt))
    assert bodies == hand.link_names and joints == hand.joint_names
    assert m.jnt_limited[1:].all()
    np.testing.assert_allclose(m.jnt_range[1:], hand.joint_limits.numpy(), atol=1e-15)


def test_round_trip_default_hand(tmp_path):
    hand = torchhand.default_hand("left", 0.2)
    out = save_mjcf(hand, tmp_path / "hand.xml")
    assert out.exists() and not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
    back = HandModel.from_mjcf(out)
    assert back.link_names == hand.link_names and back.joint_names == hand.joint_names
    assert torch.equal(back.joint_limits, hand.joint_limits)
    assert torch.equal(back.q_rest, hand.q_rest)
    assert (back.name, back.side, back.length) == (hand.name, hand.side, hand.length)
    assert back.finger_names == hand.finger_names
    for name in ("finger_links", "flexion_joints", "collision_pairs", "geoms.type", "geoms.link"):
        a, b = back, hand
        for part in name.split("."):
            a, b = getattr(a, part), getattr(b, part)
        assert torch.equal(a, b), name
    torch.testing.assert_close(back.nail_normal, hand.nail_normal, atol=1e-15, rtol=0)
    torch.testing.assert_close(back.fingertip, hand.fingertip, atol=1e-15, rtol=0)
    torch.testing.assert_close(back.geoms.pose, hand.geoms.pose, atol=1e-12, rtol=0)
    gen = torch.Generator().manual_seed(3)
    q = hand.random_q(N_POSES, gen)
    pos, quat = _random_roots(N_POSES, gen)
    root = torch.as_tensor(np.stack([_pose(_quat_to_mat(qq), p) for p, qq in zip(pos, quat)]))
    err = (back.forward_kinematics(q, root) - hand.forward_kinematics(q, root)).abs().max()
    assert float(err) < TOL


def test_finger_heuristics_on_exported_default_hand(tmp_path):
    """Without the stored annotations, the heuristics recover the default hand's fingers."""
    hand = torchhand.default_hand("right")
    xml = re.sub(r"<custom>.*?</custom>", "", hand_to_mjcf(hand), flags=re.S)
    (tmp_path / "plain.xml").write_text(xml)
    back = load_mjcf(tmp_path / "plain.xml", side="right")
    assert back.finger_names == hand.finger_names
    assert torch.equal(back.finger_links, hand.finger_links)
    assert torch.equal(back.flexion_joints, hand.flexion_joints)
    assert (back.nail_normal @ torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64) > 0.99).all()
    assert abs(back.length - hand.length) < 0.02


def test_exported_shadow_hand_round_trips_through_mujoco(tmp_path):
    """Loaded hand with mesh geoms -> inline-mesh MJCF -> MuJoCo: same FK; and back through load_mjcf."""
    hand = load_mjcf(_hand_file("shadow_hand", "right_hand.xml"))
    xml = hand.to_mjcf()
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    assert m.nq == 7 + hand.num_joints and m.nmesh == 3  # the four identical finger-tip meshes are shared
    gen = torch.Generator().manual_seed(5)
    q = hand.random_q(8, gen)
    pos, quat = _random_roots(8, gen)
    root = _roots(pos, quat)
    ep, er = _fk_errors(hand.forward_kinematics(q, root).numpy(), _mj_free_fk(m, d, pos, quat, q, hand.link_names))
    assert ep < TOL and er < TOL
    back = load_mjcf(save_mjcf(hand, tmp_path / "shadow.xml"))
    assert back.joint_names == hand.joint_names and torch.equal(back.geoms.type, hand.geoms.type)
    torch.testing.assert_close(back.forward_kinematics(q, root), hand.forward_kinematics(q, root), atol=TOL, rtol=0)


def test_root_with_joints_gets_a_wrapper_body(tmp_path):
    xml = """<mujoco><compiler angle="radian"/><worldbody>
      <body name="palm"><joint name="wx" axis="1 0 0" range="-1 1"/><joint name="sz" type="slide" range="-0.1 0.1"/>
        <geom type="sphere" size="0.02"/>
        <body name="f1" pos="0.05 0 0"><joint name="a" axis="0 1 0" range="0 1.5"/>
          <geom type="capsule" size="0.01 0.02"/>
          <body name="f2" pos="0.04 0 0"><joint name="b" axis="0 1 0" range="0 1.5"/>
            <geom type="capsule" size="0.01 0.02"/>
          </body></body></body></worldbody></mujoco>"""
    (tmp_path / "h.xml").write_text(xml)
    hand = load_mjcf(tmp_path / "h.xml")
    assert hand.joint_names == ("wx", "sz", "a", "b")
    out = hand.to_mjcf()
    m = mujoco.MjModel.from_xml_string(out)
    assert m.nq == 7 + 4 and mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, 1) == "torchhand_root"
    d = mujoco.MjData(m)
    q = torch.tensor([[0.3, 0.05, 0.7, 1.1]], dtype=torch.float64)
    d.qpos[:] = np.concatenate([[0.1, 0.2, 0.3], [1.0, 0, 0, 0], q[0].numpy()])
    mujoco.mj_kinematics(m, d)
    root = torch.as_tensor(_pose(np.eye(3), [0.1, 0.2, 0.3]))[None]
    ours = hand.forward_kinematics(q, root).numpy()[0]
    np.testing.assert_allclose(ours, _mj_body_poses(m, d, hand.link_names), atol=TOL)
    (tmp_path / "out.xml").write_text(out)
    assert load_mjcf(tmp_path / "out.xml").link_names == hand.link_names


# ----------------------------------------------------------------------------------------------------------------
# MJCF forms: degrees, orientations, classes, frames, fromto, slides, inline meshes
# ----------------------------------------------------------------------------------------------------------------
_FORMS = """<mujoco model="forms">
  <compiler eulerseq="zYx"/>
  <default>
    <joint axis="0 1 0" range="-30 60"/>
    <geom type="capsule" size="0.008"/>
    <default class="k">
      <joint axis="1 0 0" range="-10 10"/><geom type="box" size="0.01 0.01 0.01" pos="0 0 0.01"/>
    </default>
  </default>
  <asset>
    <mesh name="tet" vertex="0 0 0  0.02 0 0  0 0.03 0  0 0 0.04" face="0 2 1 0 1 3 0 3 2 1 2 3" scale="1 1 2"/>
  </asset>
  <worldbody>
    <body name="other_top_body"/>
  </worldbody>
  <worldbody>
    <body name="base" pos="1 2 3" euler="10 20 30" childclass="k">
      <freejoint/>
      <geom/>
      <body name="a" pos="0.05 0 0" axisangle="0 0 1 30">
        <joint name="a_abd"/>
        <joint name="a_flex" class="main" pos="0.01 0 0"/>
        <geom class="main" fromto="0 0 0 0.04 0.01 0"/>
        <body name="a2" pos="0.04 0 0" xyaxes="1 1 0 -1 1 0.2">
          <joint name="a2_flex" class="main"/>
          <geom class="main" type="mesh" mesh="tet" pos="0.01 0 0" quat="0.9 0.1 0.2 0.3"/>
          <geom type="sphere" size="0.01" contype="0" conaffinity="0"/>
        </body>
      </body>
      <frame pos="0 0.02 0" euler="0 0 45">
        <body name="b" zaxis="0.3 0.2 1">
          <joint name="b_slide" type="slide" axis="1 1 0" range="-0.01 0.02"/>
          <joint name="b_free_hinge" class="main" limited="false"/>
          <geom class="main" type="cylinder" fromto="0 0 0 0 0 -0.03" size="0.007"/>
          <body name="b2" pos="0 0 0.03" euler="5 -5 15"><joint name="b2_flex" class="main"/>
            <geom class="main" size="0.007 0.01" euler="0 90 0"/></body>
        </body>
      </frame>
    </body>
  </worldbody>
</mujoco>"""


def test_mjcf_forms_match_mujoco(tmp_path):
    (tmp_path / "forms.xml").write_text(_FORMS)
    hand = load_mjcf(tmp_path / "forms.xml", root_body="base")
    m = mujoco.MjModel.from_xml_string(_FORMS)
    d = mujoco.MjData(m)
    assert hand.link_names == ("base", "a", "a2", "b", "b2")
    assert hand.joint_names == ("a_abd", "a_flex", "a2_flex", "b_slide", "b_free_hinge", "b2_flex")
    lim = hand.joint_limits.numpy()
    np.testing.assert_allclose(lim[0], np.radians([-10, 10]), atol=1e-15)  # degrees by default, class k
    np.testing.assert_allclose(lim[1], np.radians([-30, 60]), atol=1e-15)
    np.testing.assert_allclose(lim[3], [-0.01, 0.02], atol=1e-15)  # slides are not converted
    np.testing.assert_allclose(lim[4], [-np.pi, np.pi], atol=1e-15)  # unlimited hinge
    assert hand.geoms.link.shape[0] == 5  # the visual sphere is skipped
    gen = torch.Generator().manual_seed(2)
    q = hand.random_q(16, gen)
    bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "base")
    errs = []
    for b in range(16):
        qpos = m.qpos0.copy()
        qpos[7:] = q[b].numpy()
        d.qpos[:] = qpos
        mujoco.mj_kinematics(m, d)
        ref = _mj_body_poses(m, d, hand.link_names)
        ours = hand.forward_kinematics(q[b : b + 1], torch.as_tensor(ref[:1]))[0].numpy()
        errs.append(_fk_errors(ours, ref))
        assert bid >= 0
    assert max(max(e) for e in errs) < TOL
    # Geom frames: MuJoCo's compiled ones (meshes re-centred by MuJoCo, their vertices with them).
    coll = [g for g in range(m.ngeom) if m.geom_contype[g] or m.geom_conaffinity[g]]
    for k, g in enumerate(coll):
        T = hand.geoms.pose[k].numpy()
        np.testing.assert_allclose(T, _pose(_quat_to_mat(m.geom_quat[g]), m.geom_pos[g]), atol=1e-12)


def test_ball_joint_becomes_three_hinges(tmp_path):
    xml = """<mujoco><worldbody><body name="p"><body name="c" pos="0 0 0.1">
      <joint name="j" type="ball" pos="0 0 0.01" range="0 45"/><geom size="0.01"/></body></body></worldbody></mujoco>"""
    (tmp_path / "ball.xml").write_text(xml)
    hand = load_mjcf(tmp_path / "ball.xml")
    assert hand.joint_names == ("j_x", "j_y", "j_z")
    np.testing.assert_allclose(hand.joint_limits.numpy(), np.tile(np.radians([-45, 45]), (3, 1)), atol=1e-15)
    np.testing.assert_allclose(hand.chain.joint_anchor.numpy(), np.tile([0, 0, 0.01], (3, 1)))


# ----------------------------------------------------------------------------------------------------------------
# Bad input
# ----------------------------------------------------------------------------------------------------------------
def _write(tmp_path, text: str, name: str = "bad.xml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_missing_file(tmp_path):
    p = tmp_path / "nope.xml"
    with pytest.raises(MissingFileError, match=re.escape(str(p))) as info:
        load_mjcf(p)
    assert isinstance(info.value, TorchhandError) and isinstance(info.value, FileNotFoundError)


def test_malformed_xml(tmp_path):
    p = _write(tmp_path, "<mujoco><worldbody><body name='a'></worldbody></mujoco>")
    with pytest.raises(FileFormatError, match=re.escape(str(p)) + ".*MuJoCo cannot compile it: XML parse error"):
        load_mjcf(p)


def test_unknown_joint_type(tmp_path):
    p = _write(tmp_path, "<mujoco><worldbody><body name='a'><body name='b'>"
                         "<joint name='jj' type='twist'/></body></body></worldbody></mujoco>")
    with pytest.raises(FileFormatError, match=re.escape(str(p)) + ".*invalid keyword: 'twist'"):
        load_mjcf(p)


@pytest.mark.parametrize("body, message", [
    ("<geom type='mesh' mesh='gone'/>", r"Error opening file '.*gone\.stl'"),
    ("<include file='x.xml'/>", r"Error opening file '.*x\.xml'"),
    ("<geom class='nope' size='0.1'/>", r"unknown default class name 'nope'"),
    ("<body name='b' quat='1 0 0'/>", r"attribute 'quat' does not have enough data"),
    ("<body name='b'><joint name='j' range='1 0' limited='true'/></body>", r"range\[0\] should be smaller"),
    ("<geom type='plane' size='1 1 1'/><body name='b'><joint name='j'/><geom size='0.01'/></body>",
     r"a plane, height field or SDF geom is not supported"),
], ids=["missing_mesh", "include", "unknown_class", "bad_quat", "bad_range", "plane"])
def test_bad_elements_name_file_and_element(tmp_path, body, message):
    asset = "<asset><mesh name='gone' file='gone.stl'/></asset>" if "gone" in body else ""
    p = _write(tmp_path, f"<mujoco>{asset}<worldbody><body name='a'>{body}</body></worldbody></mujoco>")
    with pytest.raises(TorchhandError, match=re.escape(str(p)) + ".*" + message) as err:
        load_mjcf(p)
    assert "\n" not in str(err.value)


def test_missing_mesh_is_a_missing_file_error(tmp_path):
    p = _write(tmp_path, "<mujoco><asset><mesh file='gone.stl'/></asset><worldbody><body name='a'/></worldbody>"
                         "</mujoco>")
    with pytest.raises(MissingFileError, match="gone.stl"):
        load_mjcf(p)


def test_save_mjcf_into_missing_folder(tmp_path):
    with pytest.raises(MissingFileError, match="folder not found"):
        save_mjcf(torchhand.default_hand(), tmp_path / "no" / "hand.xml")


@pytest.mark.parametrize("name", ["shadow_hand", "allegro_hand"])
def test_mounted_hand_round_trips_through_mujoco(tmp_path, name):
    """A hand mounted on its hand frame (root link offset not the identity, torchhand.hand.mount) is written with
    a wrapper body carrying the free joint: MuJoCo's body poses for qpos = (root, q) equal torchhand's FK, and
    load_mjcf reads the offset back."""
    import dataclasses

    from torchhand.hand.mount import track_hand

    track = dataclasses.replace(torchhand.load_scene("box-turn").hands[0], model=str(_hand_file(name,
                                                                                                 "right_hand.xml")))
    hand = track_hand(track)
    assert not torch.allclose(hand.chain.link_offset[0], torch.eye(4, dtype=hand.chain.link_offset.dtype))
    m = mujoco.MjModel.from_xml_string(hand.to_mjcf())
    d = mujoco.MjData(m)
    gen = torch.Generator().manual_seed(9)
    q = hand.random_q(6, gen).double()
    pos, quat = _random_roots(6, gen)
    root = _roots(pos, quat)
    ep, er = _fk_errors(hand.forward_kinematics(q, root).numpy(), _mj_free_fk(m, d, pos, quat, q, hand.link_names))
    assert ep < TOL and er < TOL
    back = load_mjcf(save_mjcf(hand, tmp_path / f"{name}.xml"))
    torch.testing.assert_close(back.forward_kinematics(q, root), hand.forward_kinematics(q, root), atol=TOL, rtol=0)
