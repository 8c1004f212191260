"""Contact slots of the quasi-static step against independent geometry: hand-object slots from the links' capsules
against the exact mesh (trimesh's closest points and signed distances are the reference) and finger-finger slots
(MuJoCo's capsule distances and Jacobians are the reference)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from torchhand.interaction._contacts import BODY_ENV, BODY_OBJECT, BODY_SELF, TablePlane, find_contacts, self_pairs
from torchhand.interaction.step import StepObject, StepSettings, initial_state, quasi_static_step

from .test_step import F64, _pose, hand_from_mjcf, lever_xml, pinch_xml

HALF = np.array([0.02, 0.02, 0.03])


def _box() -> trimesh.Trimesh:
    return trimesh.creation.box(extents=2 * HALF)


@pytest.mark.parametrize("where", ["face", "edge", "corner", "inside"])
def test_capsule_contacts_on_the_exact_mesh_match_trimesh(where):
    """The lever's spherical tip (radius 5 mm, 5 cm from the hinge) near a 4 x 4 x 6 cm box, on a face, off an edge
    and off a corner at 45 degrees, and 1 mm inside a face: the slot's separation is trimesh's distance minus the
    radius, the written surface point (point - separation d0) is trimesh's closest point, d0 is the closest-point
    direction (the face normal on a face; the bisector at an edge; the diagonal at a corner), and the slot point
    lies on the tip's sphere."""
    hand = hand_from_mjcf(lever_xml())
    r = float(hand.capsule_radius[1])
    tip = hand.capsule_a[1].numpy()                  # the sphere's centre (a fitted point capsule) at q = 0
    gap = 0.002
    corner = HALF * np.array([-1.0, 1.0, 1.0])
    targets = {"face": np.array([-HALF[0] - r - gap, 0.0, 0.005]),
               "edge": np.array([-HALF[0], 0.0, HALF[2]]) + (r + gap) * np.array([-1.0, 0.0, 1.0]) / 2 ** 0.5,
               "corner": corner + (r + gap) * np.array([-1.0, 1.0, 1.0]) / 3 ** 0.5,
               "inside": np.array([-HALF[0] + 0.001 - r, 0.0, 0.0])}
    E = _pose(*(tip - targets[where]))               # move the box so that the tip's centre sits at the target
    mesh = _box()
    obj = StepObject(None, 0.1, (0.0, 0.0, 0.0), np.eye(3) * 1e-4, 1.0, mesh=mesh)
    c = find_contacts(hand, torch.zeros(1, 1, dtype=F64), _pose(), object_pose=E, geometry="capsules",
                      object_mesh=obj.mesh, margin=0.01)
    slot = 1                                          # the lever link's object slot
    assert int(c.body[slot]) == BODY_OBJECT and bool(c.mask[0, slot])
    centre_obj = targets[where]
    closest, dist, _ = trimesh.proximity.closest_point(mesh, centre_obj[None])
    inside = trimesh.proximity.signed_distance(mesh, centre_obj[None])[0] > 0
    sd_out = -dist[0] if inside else dist[0]
    sep = float(c.separation[0, slot])
    assert sep == pytest.approx(sd_out - r, abs=1e-9)
    off = E[0, :3, 3].numpy()
    surface = (c.points[0, slot] - c.separation[0, slot] * c.d0[0, slot]).numpy() - off
    np.testing.assert_allclose(surface, closest[0], atol=1e-9)
    want = (centre_obj - closest[0]) * (-1.0 if inside else 1.0)
    np.testing.assert_allclose(c.d0[0, slot].numpy(), want / np.linalg.norm(want), atol=1e-9)
    assert np.linalg.norm(c.points[0, slot].numpy() - tip) == pytest.approx(r, abs=1e-9)
    expected = {"face": [-1, 0, 0], "edge": [-2 ** -0.5, 0, 2 ** -0.5], "corner": np.array([-1, 1, 1]) / 3 ** 0.5,
                "inside": [-1, 0, 0]}[where]
    np.testing.assert_allclose(c.d0[0, slot].numpy(), expected, atol=1e-6)


def test_finger_finger_slots_stop_fingers_at_touch():
    """The pinch hand (two two-link fingers, capsules of 6 mm, 6 cm apart) closes with no object: its references cross
    the midline. Without finger-finger slots the capsules interpenetrate; with them the fingers stop touching (MuJoCo's
    mj_geomDistance of the two fingertip capsules, the palm at MuJoCo's origin: |d| < 0.05 mm), the frictionless force
    is along the line between the capsule axes, equal and opposite on the two fingers, and each joint deflects by C (J_a
    - J_b)^T f with J from MuJoCo's mj_jac at the two surface points (within 1e-9 rad; the root, 10 cm up in the step,
    is rigid: its compliance is 0)."""
    mujoco = pytest.importorskip("mujoco")
    hand = hand_from_mjcf(pinch_xml())
    assert self_pairs(hand).tolist() == [[1, 3], [1, 4], [2, 3], [2, 4]]
    env = TablePlane(offset=-1.0)                     # far below: no table contact
    root = _pose(z=0.1)
    C = torch.tensor([[0.0] * 6 + [1.0, 2.0, 1.0, 2.0]], dtype=F64)
    target = torch.tensor([[0.6, 0.3, 0.6, 0.3]], dtype=F64)
    m = mujoco.MjModel.from_xml_string(pinch_xml())
    d = mujoco.MjData(m)
    geoms = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n) for n in ("left1", "right1")]
    gid = [int(np.nonzero(m.geom_bodyid == b)[0][0]) for b in geoms]

    def distance(q):
        d.qpos[:] = q.numpy()[0]
        mujoco.mj_forward(m, d)
        return mujoco.mj_geomDistance(m, d, gid[0], gid[1], 0.05, None)

    out = {}
    for on in (False, True):
        settings = StepSettings(geometry="capsules", self_contacts=on)
        state = initial_state(hand, torch.zeros(1, 4, dtype=F64), root, env=env, settings=settings)
        for k in range(1, 21):
            state, rep = quasi_static_step(state, hand, target * min(1.0, k / 10), root, C, None, env, settings)
            assert int(rep.status[0]) == 0
        out[on] = state
    assert distance(out[False].q) < -0.005                 # 5 mm and more into each other
    s = out[True]
    assert abs(distance(s.q)) < 5e-5
    selfs = (s.contacts.body == BODY_SELF) & s.contacts.mask[0]
    f = s.forces[0][selfs]
    assert f.norm(dim=-1).max() > 0.1
    slots = torch.nonzero(selfs).flatten()
    # the force is along d0 (frictionless) and the joint deflection is C (J_a - J_b)^T f, J from MuJoCo
    for n in slots.tolist():
        fn = s.forces[0, n]
        assert torch.linalg.cross(fn, s.contacts.d0[0, n]).norm() <= 1e-9 * max(float(fn.norm()), 1.0)
    _deflection_is_mujoco_jacobian_transpose(hand, s, slots, C, root, m, d)


def _deflection_is_mujoco_jacobian_transpose(hand, s, slots, C, root, m, d):
    """theta - theta_r = C (J_a - J_b)^T f over the finger-finger slots, J from MuJoCo's mj_jac at the two surface
    points (the root is rigid in these tests), within 1e-9 rad."""
    import mujoco

    tau = np.zeros(4)
    d.qpos[:] = s.q.numpy()[0]
    mujoco.mj_forward(m, d)
    pairs = self_pairs(hand)
    for n in slots.tolist():
        fn = s.forces[0, n]
        d0 = s.contacts.d0[0, n]
        q = n - (len(s.contacts.body) - len(pairs))
        a, b = (int(x) for x in pairs[q])
        ra, rb = float(hand.capsule_radius[a]), float(hand.capsule_radius[b])
        pa = s.contacts.points[0, n].numpy()
        axis_a = pa + ra * d0.numpy()
        # the point on b: across the gap from a's axis point along -d0 (touching: separation ~ 0)
        pb = axis_a - (ra + rb + float(s.contacts.separation[0, n])) * d0.numpy() + rb * d0.numpy()
        for link, p, sign in ((a, pa - root[0, :3, 3].numpy(), 1.0), (b, pb - root[0, :3, 3].numpy(), -1.0)):
            jacp = np.zeros((3, m.nv))
            body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, hand.link_names[link])
            mujoco.mj_jac(m, d, jacp, None, p, body)
            tau += sign * jacp.T @ fn.numpy()
    dq = (s.q - s.theta_r)[0].numpy()
    np.testing.assert_allclose(dq, C[0, 6:].numpy() * tau, atol=1e-9)


def _pinch_closed(hand, target, mu: float, steps: int = 30):
    """The pinch hand (root rigid, 10 cm up, no table) driven to ``target`` over 10 steps and held, finger-finger
    friction ``mu``: the last state and the compliance."""
    env = TablePlane(offset=-1.0)
    root = _pose(z=0.1)
    C = torch.tensor([[0.0] * 6 + [1.0, 2.0, 1.0, 2.0]], dtype=F64)
    settings = StepSettings(geometry="capsules", self_contacts=True, self_mu=mu)
    state = initial_state(hand, torch.zeros(1, 4, dtype=F64), root, env=env, settings=settings)
    for k in range(1, steps + 1):
        state, rep = quasi_static_step(state, hand, target * min(1.0, k / 10), root, C, None, env, settings)
        assert int(rep.status[0]) == 0
    return state, C, root


def test_finger_finger_friction_holds_fingers_that_would_slide():
    """Asymmetric references press the pinch's fingertips together with a shear (the left finger's reference bends
    at its base, the right one's at its tip). Frictionless, the force is normal and the tips slide past each other.
    With friction 0.5 the contact sticks: a tangential force of 0.19 f_n appears (inside the cone, so not sliding),
    the fingers stop elsewhere, and the joints still deflect by C (J_a - J_b)^T f with MuJoCo's Jacobians. With
    friction 0.1, below what sticking needs, the tangential force sits at the friction pyramid's limit (slip)."""
    mujoco = pytest.importorskip("mujoco")
    hand = hand_from_mjcf(pinch_xml())
    target = torch.tensor([[0.7, 0.0, 0.5, 0.6]], dtype=F64)
    m = mujoco.MjModel.from_xml_string(pinch_xml())
    d = mujoco.MjData(m)
    ratio, q = {}, {}
    for mu in (0.0, 0.1, 0.5):
        s, C, root = _pinch_closed(hand, target, mu)
        slots = torch.nonzero((s.contacts.body == BODY_SELF) & s.contacts.mask[0]).flatten()
        assert len(slots) == 1
        n = int(slots[0])
        f, d0 = s.forces[0, n], s.contacts.d0[0, n]
        fn = float(f @ d0)
        assert fn > 1.0
        ratio[mu] = float((f - fn * d0).norm()) / fn
        q[mu] = s.q[0]
        _deflection_is_mujoco_jacobian_transpose(hand, s, slots, C, root, m, d)
    assert ratio[0.0] < 1e-9
    assert 0.15 < ratio[0.5] < 0.5 - 0.1                     # sticking, well inside the cone
    # sliding: on the pyramid's boundary (m = 4 pairs: between cos(pi/8) mu and mu)
    assert 0.1 * np.cos(np.pi / 8) - 1e-9 <= ratio[0.1] <= 0.1 + 1e-9
    assert float((q[0.5] - q[0.0]).abs().max()) > 0.03         # the stuck fingers stop elsewhere (rad)


def test_slot_jacobians_are_computed_where_active_and_equal_the_full_ones():
    """find_contacts computes Jacobians only for the slots active in some rollout. Two rollouts of the pinch hand:
    one closed (fingertips crossed) on a box, one open with its fingertips at the table and the box away (disjoint
    active sets, finger-finger and table slots included): every slot's J rows equal point_jacobian at its point (for
    a finger-finger slot J_a - J_b) where the slot is active, and are 0 where it is not."""
    from torchhand.hand.dynamics import point_jacobian

    hand = hand_from_mjcf(pinch_xml())
    q = torch.tensor([[0.6, 0.3, 0.6, 0.3], [0.0, 0.0, 0.0, 0.0]], dtype=F64)
    root = torch.cat([_pose(z=0.1), _pose(z=0.085)])
    E = torch.cat([_pose(z=0.005), _pose(x=1.0)])
    c = find_contacts(hand, q, root, object_pose=E, object_mesh=StepObject(None, 0.1, (0.0, 0.0, 0.0), np.eye(3) * 1e-4,
                      1.0, mesh=_box()).mesh, geometry="capsules", plane=TablePlane(offset=0.0), margin=0.01,
                      self_pairs=self_pairs(hand))
    B, N = c.mask.shape
    for b, bodies in ((0, {BODY_OBJECT, BODY_SELF}), (1, {BODY_ENV})):
        assert {int(x) for x in c.body[c.mask[b]]} == bodies
    J = c.J.reshape(B, N, 3, -1)
    pairs = self_pairs(hand)
    first_self = N - len(pairs)
    for b in range(B):
        for n in range(N):
            if not bool(c.mask[b, n]):
                assert not bool(J[b, n].any())
                continue
            link = int(c.link[n])
            want = point_jacobian(hand, q[b:b + 1], [link], c.local[b:b + 1, n:n + 1], root[b:b + 1])[0, 0]
            if int(c.body[n]) == BODY_SELF:
                ib = int(pairs[n - first_self, 1])
                pb = c.points[b, n] - c.separation[b, n] * c.d0[b, n]     # b's surface point, across the gap
                T = hand.forward_kinematics(q[b:b + 1], root[b:b + 1])[0, ib]
                lb = T[:3, :3].T @ (pb - T[:3, 3])
                want = want - point_jacobian(hand, q[b:b + 1], [ib], lb[None, None], root[b:b + 1])[0, 0]
            torch.testing.assert_close(J[b, n], want, rtol=0, atol=1e-12)


def test_mesh_only_object_needs_capsule_geometry():
    from torchhand.errors import InputValueError

    hand = hand_from_mjcf(lever_xml())
    obj = StepObject(None, 0.1, (0.0, 0.0, 0.0), np.eye(3) * 1e-4, 1.0, mesh=_box())
    with pytest.raises(InputValueError, match="geometry='capsules'"):
        initial_state(hand, torch.zeros(1, 1, dtype=F64), _pose(), object_pose=_pose(x=0.2), obj=obj,
                      settings=StepSettings(geometry="samples"))
    with pytest.raises(InputValueError, match="sdf"):
        StepObject(None, 0.1, (0.0, 0.0, 0.0), np.eye(3) * 1e-4, 1.0)
