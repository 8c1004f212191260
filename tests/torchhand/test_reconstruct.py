"""reconstruct_motion (Ye & Liu 2012 §6): contacts kept, motion smoothed, joint limits, collision rounds, free
fingers, windows, bad input, dtypes; the contact- and collision-free problem against a dense least-squares
reference solved by NumPy."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch
import trimesh

import torchhand
from torchhand.hand.collision import hand_object_penetration
from torchhand.errors import InputTypeError, InputValueError, ShapeError
from torchhand.geometry.sdf import SDFGrid
from torchhand.synthesis.reconstruct import ContactTrack, ReconstructStatus, reconstruct_motion

CONTACT_FINGERS = (0, 1, 2)  # thumb, index, middle hold the object; ring and little are free


@pytest.fixture(scope="module")
def hand():
    return torchhand.default_hand("right")


@pytest.fixture(scope="module")
def sphere_sdf(tmp_path_factory):
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.02)
    return SDFGrid.from_mesh(mesh, voxel_size=0.002, cache_dir=tmp_path_factory.mktemp("sdf"), progress=False)


def acceleration(q: torch.Tensor) -> float:
    """E1 of Eq. 10 summed over the motion."""
    return float(((q[2:] - 2 * q[1:-1] + q[:-2]) ** 2).sum())


def wrist_track(T: int, dtype=torch.float64) -> torch.Tensor:
    """A wrist that translates and turns slowly, (T, 4, 4)."""
    s = torch.linspace(0, 1, T, dtype=torch.float64)
    a = 0.4 * torch.sin(math.pi * s)
    root = torch.eye(4, dtype=torch.float64).repeat(T, 1, 1)
    root[:, 0, 0], root[:, 0, 1], root[:, 1, 0], root[:, 1, 1] = a.cos(), -a.sin(), a.sin(), a.cos()
    root[:, :3, 3] = torch.stack([0.05 * s, 0.02 * torch.sin(2 * math.pi * s), 0.01 * s], dim=-1)
    return root.to(dtype)


def fingertip_world(hand, q, root, fingers) -> torch.Tensor:
    """World position of the fingertip pads of ``fingers``, (T, len(fingers), 3)."""
    poses = hand.forward_kinematics(q, root)
    T_d = poses[:, hand.distal_link[list(fingers)]]
    return (T_d[..., :3, :3] @ hand.fingertip[list(fingers)].unsqueeze(-1)).squeeze(-1) + T_d[..., :3, 3]


def fingertip_track(hand, q, root, fingers=CONTACT_FINGERS) -> ContactTrack:
    """Contacts that keep the fingertip pads of ``fingers`` where they are in motion ``q``."""
    T = q.shape[0]
    f = list(fingers)
    return ContactTrack(link=hand.distal_link[f].expand(T, -1).clone(),
                        point_local=hand.fingertip[f].expand(T, -1, -1).clone(),
                        target=fingertip_world(hand, q, root, fingers),
                        mask=torch.ones(T, len(f), dtype=torch.bool))


def searched_motion(hand, T: int, seed: int = 0, noise: float = 0.04):
    """A smooth finger motion, the contacts it makes with the pads of thumb, index and middle, and a jerky
    'searched' path: the smooth motion plus joint noise, projected back onto the contacts by a few Gauss–Newton
    steps (the search returns poses that satisfy their frame's contacts)."""
    g = torch.Generator().manual_seed(seed)
    s = torch.linspace(0, 1, T, dtype=torch.float64)[:, None]
    lo, hi = hand.joint_limits.unbind(-1)
    phase = 2 * math.pi * torch.rand(hand.num_joints, generator=g, dtype=torch.float64)
    q_smooth = hand.clamp_to_limits(hand.q_rest + 0.12 * (hi - lo) * torch.sin(2 * math.pi * s + phase))
    root = wrist_track(T)
    contacts = fingertip_track(hand, q_smooth, root)
    q = hand.clamp_to_limits(q_smooth + noise * torch.randn(T, hand.num_joints, generator=g, dtype=torch.float64))
    link, local = contacts.link[0], contacts.point_local[0]
    for _ in range(8):
        x, J = hand.points_and_jacobian(q, link, local, root)
        r = (contacts.target - x).reshape(T, -1, 1)
        J = J.reshape(T, -1, hand.num_joints)
        dq = (J.mT @ torch.linalg.solve(J @ J.mT + 1e-9 * torch.eye(J.shape[1], dtype=J.dtype), r)).squeeze(-1)
        q = hand.clamp_to_limits(q + dq)
    return root, q_smooth, q, contacts


# ---------------------------------------------------------------------------------------------------------------
# contacts, smoothness, limits


@pytest.mark.parametrize("segment", [60, 20])  # one window, and four overlapping ones
def test_contacts_kept_motion_smoothed_limits_respected(hand, segment):
    T = 50
    root, q_smooth, q_search, contacts = searched_motion(hand, T)
    search_error = (fingertip_world(hand, q_search, root, CONTACT_FINGERS) - contacts.target).norm(dim=-1).max()
    assert search_error < 1e-3  # the searched path satisfies its contacts ...
    assert acceleration(q_search) > 20 * acceleration(q_smooth)  # ... but jerks

    res = reconstruct_motion(hand, root, q_search, contacts, segment=segment)
    assert res.q.shape == (T, hand.num_joints) and res.q.dtype == torch.float64
    assert res.contact_error.shape == res.penetration.shape == res.smoothness.shape == res.frame_status.shape == (T,)
    assert res.status is ReconstructStatus.OK and res.status.message.startswith("ok")
    assert bool((res.frame_status == int(ReconstructStatus.OK)).all())
    # (1) contacts within tolerance, checked by an independent forward kinematics evaluation
    err = (fingertip_world(hand, res.q, root, CONTACT_FINGERS) - contacts.target).norm(dim=-1)
    assert float(err.max()) <= 1e-3
    assert torch.allclose(res.contact_error, err.amax(dim=1), atol=1e-12)
    # (2) the acceleration energy drops substantially
    assert acceleration(res.q) < 0.05 * acceleration(q_search)
    # (3) joint limits hold exactly
    lo, hi = hand.joint_limits.unbind(-1)
    assert bool(((res.q >= lo) & (res.q <= hi)).all())
    assert res.iterations == 1  # no sdf: one round
    assert bool((res.penetration == 0).all())


def test_limits_hold_when_a_contact_is_out_of_reach(hand):
    T = 12
    root = wrist_track(T)
    q = hand.q_rest.repeat(T, 1)
    contacts = fingertip_track(hand, q, root, fingers=(1,))
    # Frames 4..7 ask the index pad to be 6 cm further out than the extended finger reaches.
    far = contacts.target.clone()
    out = far[4:8] - root[4:8, None, :3, 3]
    far[4:8] += 0.06 * out / out.norm(dim=-1, keepdim=True)
    contacts = ContactTrack(contacts.link, contacts.point_local, far, contacts.mask)
    res = reconstruct_motion(hand, root, q, contacts, max_inner=15)
    lo, hi = hand.joint_limits.unbind(-1)
    assert bool(((res.q >= lo) & (res.q <= hi)).all())
    assert torch.isfinite(res.q).all()
    # The unreachable frames are reported, the others are kept.
    assert res.status is ReconstructStatus.CONTACT_VIOLATED
    violated = res.frame_status == int(ReconstructStatus.CONTACT_VIOLATED)
    assert bool(violated[4:8].all()) and not bool(violated[:2].any()) and not bool(violated[-2:].any())
    assert bool((res.contact_error[4:8] > 0.03).all())
    # Reaching for the far target straightens the finger against its extension limits.
    index_flex = [hand.joint_index(n) for n in ("index_mcp_flex", "index_pip", "index_dip")]
    at_limit = (res.q[4:8, index_flex] - lo[index_flex]).abs() < 1e-9
    assert bool(at_limit.any())


def test_free_fingers_move_to_rest(hand):
    T = 40
    root, _, q_search, contacts = searched_motion(hand, T, seed=1)
    q_rest = hand.q_rest
    ring_little = [j for j, name in enumerate(hand.joint_names) if name.startswith(("ring", "little"))]
    # The search left ring and little far from rest; no contacts hold them.
    q_far = q_search.clone()
    lo, hi = hand.joint_limits.unbind(-1)
    q_far[:, ring_little] = (0.3 * lo + 0.7 * hi)[ring_little]
    res = reconstruct_motion(hand, root, q_far, contacts)
    before = (q_far[:, ring_little] - q_rest[ring_little]).abs().mean()
    after = (res.q[:, ring_little] - q_rest[ring_little]).abs().mean()
    assert after < 0.1 * before
    # A finger released halfway moves toward rest after the release and not before it.
    free = torch.zeros(T, hand.num_fingers, dtype=torch.bool)
    free[:, 3:] = True
    free[T // 2:, 2] = True
    mask = contacts.mask.clone()
    mask[T // 2:, 2] = False
    released = ContactTrack(contacts.link, contacts.point_local, contacts.target, mask)
    middle = [j for j, name in enumerate(hand.joint_names) if name.startswith("middle")]
    q_mid = q_far.clone()
    q_mid[:, middle] = (0.3 * lo + 0.7 * hi)[middle]
    res2 = reconstruct_motion(hand, root, q_mid, released, free=free, q_rest=q_rest)
    dist = (res2.q[:, middle] - q_rest[middle]).abs().mean(dim=1)
    assert float(dist[-5:].max()) < 0.5 * float(dist[:5].min())
    assert float(res2.contact_error[: T // 2 - 1].max()) <= 1e-3


# ---------------------------------------------------------------------------------------------------------------
# collisions


def _sphere_under_index(hand, sdf, T, depth=0.005):
    """A 2 cm sphere the index pad sinks ``depth`` into at the rest pose, static, with the wrist at the origin."""
    q = hand.q_rest[None]
    root = torch.eye(4, dtype=torch.float64)[None]
    tip = fingertip_world(hand, q, root, (1,))[0, 0]
    poses = hand.forward_kinematics(q, root)
    nail = poses[0, hand.distal_link[1], :3, :3] @ hand.nail_normal[1]
    centre = tip - (0.02 - depth) * nail
    object_pose = torch.eye(4, dtype=torch.float64).repeat(T, 1, 1)
    object_pose[:, :3, 3] = centre
    return root.expand(T, 4, 4).clone(), object_pose, sdf.to(dtype=torch.float64)


def test_penetration_resolved_by_collision_rounds(hand, sphere_sdf):
    T = 16
    root, object_pose, sdf = _sphere_under_index(hand, sphere_sdf, T)
    g = torch.Generator().manual_seed(3)
    q_search = hand.clamp_to_limits(hand.q_rest + 0.02 * torch.randn(T, hand.num_joints, generator=g,
                                                                      dtype=torch.float64))
    none = ContactTrack.empty(T)
    # Smoothing alone pulls the free index finger to its rest pose, inside the sphere.
    plain = reconstruct_motion(hand, root, q_search, none)
    pen = hand_object_penetration(hand, hand.forward_kinematics(plain.q, root), sdf, object_pose)
    assert float(-pen.sd.min()) > 3e-3
    res = reconstruct_motion(hand, root, q_search, none, sdf=sdf, object_pose=object_pose)
    assert res.status is ReconstructStatus.OK
    assert 1 < res.iterations <= 5
    assert float(res.penetration.max()) <= 1e-3
    pen = hand_object_penetration(hand, hand.forward_kinematics(res.q, root), sdf, object_pose)
    assert torch.allclose(res.penetration, (-pen.sd.amin(dim=1)).clamp_min(0))
    lo, hi = hand.joint_limits.unbind(-1)
    assert bool(((res.q >= lo) & (res.q <= hi)).all())


def test_contact_on_the_object_kept_while_other_fingers_clear_it(hand, sphere_sdf):
    T = 16
    root, object_pose, sdf = _sphere_under_index(hand, sphere_sdf, T, depth=0.0)
    # The index pad rests on the sphere (a kept contact); the free middle finger is pulled to a rest pose that is
    # abducted toward the index and curled into the sphere.
    q = hand.q_rest.repeat(T, 1)
    contacts = fingertip_track(hand, q, root, fingers=(1,))
    q_rest = hand.q_rest.clone()
    middle = [hand.joint_index(n) for n in ("middle_mcp_abd", "middle_mcp_flex", "middle_pip", "middle_dip")]
    q_rest[middle] = torch.tensor([0.34, 0.4, 0.9, 0.8], dtype=torch.float64)
    plain = reconstruct_motion(hand, root, q, contacts, q_rest=q_rest)
    assert plain.status is ReconstructStatus.OK  # without an sdf only the contacts are checked
    pen = hand_object_penetration(hand, hand.forward_kinematics(plain.q, root), sdf, object_pose)
    middle_links = hand.finger_links[2, 1:]
    assert float(-pen.deepest_value[:, middle_links].min()) > 5e-3
    res = reconstruct_motion(hand, root, q, contacts, sdf=sdf, object_pose=object_pose, q_rest=q_rest)
    assert res.status is ReconstructStatus.OK
    assert float(res.contact_error.max()) <= 1e-3
    assert float(res.penetration.max()) <= 1e-3
    # the middle finger still leans toward its rest pose as far as the sphere lets it
    assert float((res.q[:, middle] - q_rest[middle]).abs().max()) < float((q[:, middle] - q_rest[middle]).abs().max())


# ---------------------------------------------------------------------------------------------------------------
# reference: the quadratic problem without contacts or collisions


def dense_reference(hand, q_search, free, q_rest, bend_weight, rest_weight, search_weight) -> np.ndarray:
    """argmin over all joints and frames of sum_t E1 + w E2 + the priors, as one dense least-squares problem."""
    T, D = q_search.shape
    qs, qr, fr = q_search.numpy(), q_rest.numpy(), free.numpy()
    jf = hand.link_finger[hand.chain.joint_link].numpy()
    rows, rhs = [], []

    def var(t, j):
        return t * D + j

    for t in range(1, T - 1):
        for j in range(D):
            r = np.zeros(T * D)
            r[var(t - 1, j)], r[var(t, j)], r[var(t + 1, j)] = 1.0, -2.0, 1.0
            rows.append(r)
            rhs.append(0.0)
    for t in range(T):
        for f in range(hand.num_fingers):
            a, b, c = hand.flexion_joints[f].tolist()
            r = np.zeros(T * D)
            r[var(t, a)], r[var(t, b)], r[var(t, c)] = 1.0, -2.0, 1.0
            rows.append(math.sqrt(bend_weight) * r)
            rhs.append(0.0)
        for j in range(D):
            w = rest_weight if fr[t, jf[j]] else search_weight
            r = np.zeros(T * D)
            r[var(t, j)] = math.sqrt(w)
            rows.append(r)
            rhs.append(math.sqrt(w) * (qr[j] if fr[t, jf[j]] else qs[t, j]))
    sol, *_ = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)
    return sol.reshape(T, D)


def test_smoothing_matches_dense_least_squares(hand):
    T = 24
    g = torch.Generator().manual_seed(7)
    lo, hi = hand.joint_limits.unbind(-1)
    mid = 0.5 * (lo + hi)
    s = torch.linspace(0, 1, T, dtype=torch.float64)[:, None]
    q_search = mid + (hi - lo) * (0.1 * torch.sin(3 * s + torch.arange(hand.num_joints)) +
                                  0.03 * torch.randn(T, hand.num_joints, generator=g, dtype=torch.float64))
    free = torch.rand(T, hand.num_fingers, generator=g) < 0.4
    q_rest = mid + 0.05 * (hi - lo)
    weights = dict(bend_weight=0.3, rest_weight=0.05, search_weight=0.02)
    ref = dense_reference(hand, q_search, free, q_rest, **weights)
    assert bool(((torch.from_numpy(ref) > lo) & (torch.from_numpy(ref) < hi)).all())  # no bound is active
    res = reconstruct_motion(hand, wrist_track(T), q_search, ContactTrack.empty(T), free=free, q_rest=q_rest,
                             **weights)
    np.testing.assert_allclose(res.q.numpy(), ref, atol=1e-9)
    assert res.status is ReconstructStatus.OK
    # the reported smoothness is Eq. 10 + w Eq. 11 of the answer
    q = torch.from_numpy(ref)
    acc = torch.zeros(T, dtype=torch.float64)
    acc[1:-1] = ((q[2:] - 2 * q[1:-1] + q[:-2]) ** 2).sum(-1)
    fj = hand.flexion_joints
    bend = ((q[:, fj[:, 0]] - 2 * q[:, fj[:, 1]] + q[:, fj[:, 2]]) ** 2).sum(-1)
    torch.testing.assert_close(res.smoothness, acc + 0.3 * bend, atol=1e-9, rtol=1e-7)


def test_windows_join_smoothly(hand):
    """Solved in the default 60-frame windows, the motion stays close to the one-window answer and as smooth."""
    T = 150
    g = torch.Generator().manual_seed(11)
    lo, hi = hand.joint_limits.unbind(-1)
    s = torch.linspace(0, 1, T, dtype=torch.float64)[:, None]
    q_search = hand.clamp_to_limits(0.5 * (lo + hi) + (hi - lo) * (
        0.15 * torch.sin(4 * s + torch.arange(hand.num_joints)) +
        0.05 * torch.randn(T, hand.num_joints, generator=g, dtype=torch.float64)))
    root, none = wrist_track(T), ContactTrack.empty(T)
    free = torch.zeros(T, hand.num_fingers, dtype=torch.bool)
    whole = reconstruct_motion(hand, root, q_search, none, free=free, segment=T)
    windows = reconstruct_motion(hand, root, q_search, none, free=free)
    assert float((whole.q - windows.q).abs().max()) < 0.01
    # no kink at the joins: the acceleration of the windowed answer is close to the global optimum's
    assert acceleration(windows.q) < 1.1 * acceleration(whole.q)
    assert acceleration(windows.q) < 1e-3 * acceleration(q_search)


# ---------------------------------------------------------------------------------------------------------------
# dtypes, edge cases, errors


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_dtypes(hand, dtype):
    T = 20
    root, _, q_search, contacts = searched_motion(hand, T, seed=2)
    res = reconstruct_motion(hand, root.to(dtype), q_search.to(dtype), contacts.to(dtype=dtype))
    assert res.q.dtype == res.contact_error.dtype == res.penetration.dtype == dtype
    assert res.frame_status.dtype == torch.int8
    assert float(res.contact_error.max()) <= 1e-3
    assert acceleration(res.q.double()) < 0.1 * acceleration(q_search)
    assert res.status is ReconstructStatus.OK


@pytest.mark.parametrize("T", [1, 2])
def test_short_motions(hand, T):
    root, _, q_search, contacts = searched_motion(hand, 20, seed=4)
    res = reconstruct_motion(hand, root[:T], q_search[:T], ContactTrack(
        contacts.link[:T], contacts.point_local[:T], contacts.target[:T], contacts.mask[:T]))
    assert res.q.shape == (T, hand.num_joints)
    assert float(res.contact_error.max()) <= 1e-3
    assert bool((res.smoothness >= 0).all())


def test_padding_slots_are_ignored(hand):
    T = 8
    root, _, q_search, contacts = searched_motion(hand, T, seed=5)
    padded = ContactTrack(link=torch.cat([contacts.link, torch.full((T, 2), -1)], dim=1),
                          point_local=torch.cat([contacts.point_local, torch.full((T, 2, 3), float("nan"))], dim=1),
                          target=torch.cat([contacts.target, torch.full((T, 2, 3), float("nan"))], dim=1),
                          mask=torch.cat([contacts.mask, torch.zeros(T, 2, dtype=torch.bool)], dim=1))
    a = reconstruct_motion(hand, root, q_search, contacts)
    b = reconstruct_motion(hand, root, q_search, padded)
    torch.testing.assert_close(a.q, b.q, atol=1e-12, rtol=0)
    torch.testing.assert_close(a.contact_error, b.contact_error, atol=1e-12, rtol=0)
    assert b.status is ReconstructStatus.OK


def test_palm_contact_is_reported_not_enforced(hand):
    T = 5
    root = wrist_track(T)
    q = hand.q_rest.repeat(T, 1)
    contacts = ContactTrack(link=torch.zeros(T, 1, dtype=torch.long),
                            point_local=torch.zeros(T, 1, 3, dtype=torch.float64),
                            target=root[:, None, :3, 3] + torch.tensor([0.0, 0.0, 0.01], dtype=torch.float64),
                            mask=torch.ones(T, 1, dtype=torch.bool))
    res = reconstruct_motion(hand, root, q, contacts)
    assert res.status is ReconstructStatus.CONTACT_VIOLATED
    torch.testing.assert_close(res.contact_error, torch.full((T,), 0.01, dtype=torch.float64))


def test_bad_input_names_the_argument(hand):
    T = 6
    root, q = wrist_track(T), hand.q_rest.repeat(T, 1)
    none = ContactTrack.empty(T)
    with pytest.raises(ShapeError, match=r"q_search: expected shape \(\*, 30\), got \(6, 29\)"):
        reconstruct_motion(hand, root, q[:, :-1], none)
    with pytest.raises(ShapeError, match=r"root: expected shape \(6, 4, 4\), got \(5, 4, 4\)"):
        reconstruct_motion(hand, root[:5], q, none)
    with pytest.raises(ShapeError, match=r"contacts.link: expected shape \(6, K\)"):
        reconstruct_motion(hand, root, q, ContactTrack.empty(T + 1))
    with pytest.raises(ShapeError, match=r"ContactTrack.target: expected shape \(6, 2, 3\), got \(6, 2\)"):
        ContactTrack(torch.zeros(T, 2, dtype=torch.long), torch.zeros(T, 2, 3), torch.zeros(T, 2),
                     torch.zeros(T, 2, dtype=torch.bool))
    with pytest.raises(InputTypeError, match="ContactTrack.mask: expected a bool tensor"):
        ContactTrack(torch.zeros(T, 2, dtype=torch.long), torch.zeros(T, 2, 3), torch.zeros(T, 2, 3),
                     torch.zeros(T, 2))
    with pytest.raises(ShapeError, match=r"free: expected shape \(6, 5\), got \(6, 4\)"):
        reconstruct_motion(hand, root, q, none, free=torch.zeros(T, 4, dtype=torch.bool))
    with pytest.raises(ShapeError, match=r"q_rest: expected shape \(30\), got \(29,\)"):
        reconstruct_motion(hand, root, q, none, q_rest=q[0, :-1])
    with pytest.raises(ShapeError, match=r"object_pose: expected shape \(6, 4, 4\)"):
        reconstruct_motion(hand, root, q, none, sdf=SDFGrid(torch.zeros(2, 2, 2, dtype=torch.float64),
                                                            torch.zeros(3, dtype=torch.float64), 0.01),
                           object_pose=root[:2])
    with pytest.raises(InputValueError, match="sdf, object_pose: give both"):
        reconstruct_motion(hand, root, q, none, object_pose=root)
    with pytest.raises(InputTypeError, match="root: expected dtype torch.float64"):
        reconstruct_motion(hand, root.float(), q, none)
    with pytest.raises(InputValueError, match=r"contacts.link: masked entries must be in \[0, 20\)"):
        reconstruct_motion(hand, root, q, ContactTrack(torch.full((T, 1), 20), torch.zeros(T, 1, 3, dtype=q.dtype),
                                                       torch.zeros(T, 1, 3, dtype=q.dtype),
                                                       torch.ones(T, 1, dtype=torch.bool)))
    with pytest.raises(InputValueError, match="segment: expected an integer >= 8"):
        reconstruct_motion(hand, root, q, none, segment=4)
    with pytest.raises(InputValueError, match="rest_weight: expected a finite non-negative number"):
        reconstruct_motion(hand, root, q, none, rest_weight=-1.0)
    with pytest.raises(InputValueError, match="q_search: contains NaN"):
        reconstruct_motion(hand, root, q * float("nan"), none, check=True)


def test_nan_input_is_reported_not_hidden(hand):
    T = 6
    root, q = wrist_track(T), hand.q_rest.repeat(T, 1)
    q[2, 5] = float("nan")
    res = reconstruct_motion(hand, root, q, ContactTrack.empty(T), max_inner=3)
    assert res.status is ReconstructStatus.DIVERGED
    assert int(res.frame_status[2]) == int(ReconstructStatus.DIVERGED)


# --- the table and the joint-speed bound (reconstruct_bounds) ------------------------------------------------------

def test_joint_speed_bound_holds_through_a_jump(hand):
    """A free finger whose searched path jumps by 1.2 rad in one frame: with max_joint_step the reconstructed
    motion moves no joint more than the bound per frame (Eq. 9 alone spreads the jump but does not bound it)."""
    T = 30
    root = wrist_track(T)
    q = hand.q_rest.expand(T, -1).clone()
    j = hand.joint_names.index("index_mcp_flex")
    q[15:, j] += 1.2
    contacts = ContactTrack.empty(T)
    step = 8.0 / 30.0
    free = torch.zeros(T, hand.num_fingers, dtype=torch.bool)          # held to the searched pose (weakly)
    plain = reconstruct_motion(hand, root, q, contacts, free=free, search_weight=30.0)
    bounded = reconstruct_motion(hand, root, q, contacts, free=free, search_weight=30.0, max_joint_step=step)
    assert float((plain.q[1:] - plain.q[:-1]).abs().max()) > step          # the bound is not vacuous here
    assert float((bounded.q[1:] - bounded.q[:-1]).abs().max()) <= step * (1 + 1e-3)
    assert float(bounded.q[-1, j] - bounded.q[0, j]) > 1.0                 # it still gets there


def test_table_keeps_finger_capsules_above_the_plane(hand):
    """A motion whose flexed fingers dip 5 mm under a table plane: with table_height every movable finger
    capsule ends above it (within the penetration tolerance), and the result's penetration reports it."""
    from torchhand.synthesis.reconstruct_bounds import table_depth

    T = 12
    root = wrist_track(T)
    q = hand.q_rest.expand(T, -1).clone()
    for i, name in enumerate(hand.joint_names):
        if name.endswith(("mcp_flex", "pip")) and not name.startswith("thumb"):
            q[:, i] = 0.8 * hand.joint_limits[i, 1]
    depth = table_depth(hand, hand.forward_kinematics(q, root), 0.0)
    finger = hand.link_finger >= 0
    # put the plane 5 mm above the lowest finger capsule
    lowest = -float(depth[:, finger].amax())
    table = lowest + 0.005
    res = reconstruct_motion(hand, root, q, ContactTrack.empty(T), table_height=table, penetration_tol=5e-4)
    after = table_depth(hand, hand.forward_kinematics(res.q, root), table)
    from torchhand.synthesis.reconstruct import _finger_layout

    movable = _finger_layout(hand).movable                 # links the finger joints move (not the metacarpals)
    assert float(depth[:, movable].amax()) > 0.004
    assert float(after[:, movable].amax()) <= 5e-4 + 1e-5
    assert float(res.penetration.max()) <= 5e-4 + 1e-5


# ---------------------------------------------------------------------------------------------------------------
# many paths at once


def _same_result(a, b) -> bool:
    return (all(torch.equal(getattr(a, f), getattr(b, f)) for f in ("q", "contact_error", "penetration",
                                                                     "smoothness", "frame_status"))
            and (a.iterations, a.status) == (b.iterations, b.status))


@pytest.mark.parametrize("options", [dict(), dict(segment=8, max_joint_step=0.15, max_inner=12, step_tol=1e-4)])
def test_paths_solved_together_are_each_as_alone(hand, sphere_sdf, options):
    """``reconstruct_motions``: four paths of one wrist and object (one resting clear of the sphere with the thumb
    pad kept, three sinking in by different amounts) solved together give each path's alone result bit for bit,
    although they need different numbers of collision rounds and Gauss–Newton steps."""
    from torchhand.synthesis.reconstruct import reconstruct_motions

    T = 16
    root, object_pose, sdf = _sphere_under_index(hand, sphere_sdf, T)
    g = torch.Generator().manual_seed(3)
    paths = [hand.clamp_to_limits(hand.q_rest + s * torch.randn(T, hand.num_joints, generator=g, dtype=torch.float64))
             for s in (0.0, 0.02, 0.06)]
    lifted = hand.q_rest.clone()
    lifted[hand.joint_names.index("index_mcp_flex")] -= 0.5
    paths.insert(0, hand.clamp_to_limits(lifted).expand(T, -1).clone())
    thumb = fingertip_track(hand, paths[0], root, fingers=(0,))
    tracks = [thumb] + [dataclasses.replace(thumb, mask=torch.zeros_like(thumb.mask)) for _ in paths[1:]]
    held = torch.zeros(T, hand.num_fingers, dtype=torch.bool)           # the first path is held where it is
    kw = dict(sdf=sdf, object_pose=object_pose, finger_tol=1e-3, **options)
    alone = [reconstruct_motion(hand, root, q, c, free=f, **kw)
             for q, c, f in zip(paths, tracks, [held, None, None, None])]
    free = [held] + [_free_of(hand, c) for c in tracks[1:]]              # the others: the default, as alone
    together = reconstruct_motions(hand, root, torch.stack(paths), tracks, free=free, **kw)
    assert len({r.iterations for r in alone}) > 1                  # the paths leave the collision rounds apart
    assert all(_same_result(a, b) for a, b in zip(alone, together))
    # the order of the paths does not matter
    again = reconstruct_motions(hand, root, torch.stack(paths[::-1]), tracks[::-1], free=free[::-1], **kw)[::-1]
    assert all(_same_result(a, b) for a, b in zip(alone, again))


def _free_of(hand, contacts) -> torch.Tensor:
    """reconstruct_motion's default ``free``: no masked contact on any link of the finger."""
    finger = hand.link_finger[contacts.link.clamp(0, hand.num_links - 1)]
    on = (finger.unsqueeze(-1) == torch.arange(hand.num_fingers)) & contacts.mask.unsqueeze(-1)
    return ~on.any(dim=1)


def test_paths_solved_together_refuse_mismatched_input(hand):
    from torchhand.synthesis.reconstruct import reconstruct_motions

    T = 6
    root = wrist_track(T)
    q = hand.q_rest.expand(2, T, -1).clone()
    one = ContactTrack.empty(T)
    with pytest.raises(ShapeError, match="q_search"):
        reconstruct_motions(hand, root, q[0], [one])
    with pytest.raises(ShapeError, match="contacts"):
        reconstruct_motions(hand, root, q, [one])
    with pytest.raises(ShapeError, match="slots"):
        reconstruct_motions(hand, root, q, [one, fingertip_track(hand, q[1], root, fingers=(0,))])


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_paths_solved_together_are_each_as_alone(hand, sphere_sdf):
    from torchhand.synthesis.reconstruct import reconstruct_motions

    T = 16
    root, object_pose, sdf = _sphere_under_index(hand, sphere_sdf, T)
    g = torch.Generator().manual_seed(5)
    paths = torch.stack([hand.clamp_to_limits(hand.q_rest + s * torch.randn(T, hand.num_joints, generator=g,
                                                                            dtype=torch.float64))
                         for s in (0.0, 0.02, 0.06)]).cuda()
    h, root, object_pose, sdf = hand.to("cuda"), root.cuda(), object_pose.cuda(), sdf.to("cuda")
    tracks = [ContactTrack.empty(T, device="cuda")] * 3
    kw = dict(sdf=sdf, object_pose=object_pose, finger_tol=1e-3, max_joint_step=0.15)
    alone = [reconstruct_motion(h, root, q, c, **kw) for q, c in zip(paths, tracks)]
    together = reconstruct_motions(h, root, paths, tracks, **kw)
    assert all(_same_result(a, b) for a, b in zip(alone, together))
