"""The quasi-static step of Kry & Pai §7 (torchhand/interaction/step.py and the rigid-body kernels it uses):
rigid-body terms against integration and finite differences, a free body against MuJoCo, the closed form of a
1-DOF lever, per-step invariants, forces against MuJoCo with joint springs, and the LCP against Clarabel."""

from __future__ import annotations

import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from torchhand.hand.model import HandModel
from torchhand.interaction.mujoco_truth import ROOT_HEIGHT, TIMESTEP, planar_finger_mjcf
from torchhand.interaction.step import (StepObject, StepSettings, TablePlane, initial_state, quasi_static_step)
from torchhand.kernels.contact_lcp import effective_compliance, integrate_object, rigid_body_terms
from torchhand.kernels.spatial import adjoint, gamma, se3_inverse
from torchhand.kernels.status import SolverStatus
from torchhand.geometry.sdf import SDFGrid

F64 = torch.float64
CONVERGED = int(SolverStatus.CONVERGED)
TABLE1 = [0.3488, 0.9882, 0.6715, 2.0052]   # wrist, MP, PIP, DIP, rad/(N m)


# ----------------------------------------------------------------------------------------------------------------
# builders (also used by scripts/bench_interaction.py)
# ----------------------------------------------------------------------------------------------------------------
def hand_from_mjcf(xml: str) -> HandModel:
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "hand.xml"
        path.write_text(xml)
        return HandModel.from_mjcf(path)


def lever_xml(length: float = 0.05, radius: float = 0.005) -> str:
    """One hinge about y at the root origin; a sphere of ``radius`` at (length, 0, 0). +theta moves it down."""
    return (f'<mujoco model="lever"><compiler angle="radian"/><worldbody><body name="base">'
            f'<body name="lever"><joint name="hinge" type="hinge" axis="0 1 0"/>'
            f'<inertial pos="{length / 2} 0 0" mass="0.001" diaginertia="1e-7 1e-7 1e-7"/>'
            f'<geom name="tip" type="sphere" pos="{length} 0 0" size="{radius}"/></body></body>'
            f'</worldbody></mujoco>')


def _finger_bodies(name: str, x: float, y: float, axis: str, lengths=(0.05, 0.03), radius=0.006,
                   direction=(0.0, 0.0, -1.0)) -> str:
    """A finger from (x, y, 0) along ``direction`` (default hanging down) with hinges about ``axis``."""
    inner = ""
    d = np.asarray(direction, dtype=np.float64)
    for j in reversed(range(len(lengths))):
        pos = f"{x} {y} 0" if j == 0 else " ".join(str(v) for v in lengths[j - 1] * d)
        end = " ".join(str(v) for v in lengths[j] * d)
        mid = " ".join(str(v) for v in lengths[j] * d / 2)
        inner = (f'<body name="{name}{j}" pos="{pos}"><joint name="{name}_j{j}" type="hinge" axis="{axis}"/>'
                 f'<inertial pos="{mid}" mass="0.002" diaginertia="1e-7 1e-7 1e-7"/>'
                 f'<geom type="capsule" fromto="0 0 0 {end}" size="{radius}"/>{inner}</body>')
    return inner


def pinch_xml() -> str:
    """Two two-link fingers at x = -+3 cm closing towards each other (a pinch)."""
    return ('<mujoco model="pinch"><compiler angle="radian"/><worldbody><body name="palm">'
            + _finger_bodies("left", -0.03, 0.0, "0 -1 0") + _finger_bodies("right", 0.03, 0.0, "0 1 0")
            + "</body></worldbody></mujoco>")


def comb_xml(fingers: int = 5) -> str:
    """``fingers`` two-link fingers in a row along y, pointing along +x; positive angles flex them down."""
    return ('<mujoco model="comb"><compiler angle="radian"/><worldbody><body name="palm">'
            + "".join(_finger_bodies(f"f{i}", 0.0, 0.025 * (i - (fingers - 1) / 2), "0 1 0",
                                     direction=(1.0, 0.0, 0.0))
                      for i in range(fingers))
            + "</body></worldbody></mujoco>")


def box_grid(half, voxel: float = 0.002, pad: float = 0.012) -> SDFGrid:
    """Exact signed distance of an axis-aligned box centred at the origin, sampled on a grid (float64)."""
    half = np.asarray(half, dtype=np.float64)
    n = np.ceil(2 * (half + pad) / voxel).astype(int) + 1
    origin = -(n - 1) * voxel / 2
    axes = [origin[i] + voxel * np.arange(n[i]) for i in range(3)]
    P = np.stack(np.meshgrid(*axes, indexing="ij"), -1)
    q = np.abs(P) - half
    sd = np.linalg.norm(np.maximum(q, 0), axis=-1) + np.minimum(q.max(-1), 0)
    return SDFGrid(values=torch.from_numpy(sd), origin=torch.from_numpy(origin), voxel_size=voxel)


def _pose(x=0.0, y=0.0, z=0.0, B=1) -> torch.Tensor:
    T = torch.eye(4, dtype=F64).repeat(B, 1, 1)
    T[:, :3, 3] = torch.tensor([x, y, z], dtype=F64)
    return T


def box_object(mass: float = 0.05, half=(0.02, 0.02, 0.03), mu: float = 1.0) -> StepObject:
    hx, hy, hz = half
    inertia = mass / 3 * np.diag([hy * hy + hz * hz, hx * hx + hz * hz, hx * hx + hy * hy])
    return StepObject(box_grid(half), mass, (0.0, 0.0, 0.0), inertia, mu)


def pinch_scene(B: int = 1, solver: str = "lemke", gravity=(0.0, 0.0, -9.81), squeeze=0.25):
    """The pinch hand at z = 10 cm around a free 5 x 5 x 6 cm box (50 g) centred 5 cm up, gravity on.
    Returns (hand, state, C, obj, settings, reference(k) -> theta_r) with theta_r ramping to ``squeeze`` rad."""
    hand = hand_from_mjcf(pinch_xml())
    obj = box_object()
    settings = StepSettings(solver=solver, gravity=gravity)
    root = _pose(z=0.1, B=B)
    q0 = torch.zeros(B, 4, dtype=F64)
    state = initial_state(hand, q0, root, object_pose=_pose(z=0.05, B=B), obj=obj, settings=settings)
    C = torch.tensor([[0.05] * 3 + [1e-4] * 3 + [1.0, 2.0, 1.0, 2.0]], dtype=F64).expand(B, 10)
    scale = torch.linspace(1.0, 1.3, B, dtype=F64)[:, None]

    def reference(k: int) -> torch.Tensor:
        return q0 + squeeze * min(1.0, k / 10) * scale * torch.tensor([1.0, 0.5, 1.0, 0.5], dtype=F64)

    return hand, state, C, obj, settings, reference


def comb_scene(B: int = 1, solver: str = "lemke", fingers: int = 5):
    """The comb hand 3.5 cm above a table (mu 0.8), fingertips 2 mm above it, then pressing: one contact per finger.
    Returns (hand, state, C, env, settings, reference(k) -> theta_r)."""
    hand = hand_from_mjcf(comb_xml(fingers))
    env = TablePlane(offset=0.0, mu=0.8)
    settings = StepSettings(solver=solver, geometry="capsules")
    root = _pose(z=0.035, B=B)
    q0 = torch.full((B, 2 * fingers), 0.25, dtype=F64)
    state = initial_state(hand, q0, root, env=env, settings=settings)
    C = torch.tensor([[0.3488] * 3 + [1e-4] * 3 + [0.9882, 2.0052] * fingers], dtype=F64).expand(B, -1)
    scale = torch.linspace(1.0, 1.5, B, dtype=F64)[:, None]

    def reference(k: int) -> torch.Tensor:
        return q0 + 0.25 * min(1.0, k / 10) * scale * torch.linspace(0.6, 1.0, 2 * fingers, dtype=F64)

    return hand, state, C, env, settings, reference


def scene_to(device, hand, state, C, obj, reference):
    """The builders' CPU scene on ``device``: hand, state, compliance, the object's grid and the reference."""
    from torchhand._tree import tree_to

    if device == "cpu":
        return hand, state, C, obj, reference
    if obj is not None:
        obj = replace(obj, sdf=obj.sdf.to(device), support=None if obj.support is None else obj.support.to(device))
    return (hand.to(device), tree_to(state, device), C.to(device), obj,
            lambda k: reference(k).to(device))


def run(state, hand, C, reference, steps, obj=None, env=None, settings=StepSettings(), root_r=None):
    """Steps 1 .. steps; returns the final state and the list of reports."""
    reports = []
    root_r = state.root_r if root_r is None else root_r
    for k in range(1, steps + 1):
        state, rep = quasi_static_step(state, hand, reference(k), root_r, C, obj, env, settings)
        reports.append(rep)
    return state, reports


# ----------------------------------------------------------------------------------------------------------------
# rigid body
# ----------------------------------------------------------------------------------------------------------------
def _random_body(B: int, N: int, seed: int):
    rng = np.random.default_rng(seed)
    from scipy.spatial.transform import Rotation

    E = np.tile(np.eye(4), (B, 1, 1))
    E[:, :3, :3] = Rotation.random(B, random_state=seed).as_matrix()
    E[:, :3, 3] = rng.normal(0, 0.1, (B, 3))
    A = rng.normal(size=(B, 3, 3))
    inertia = 1e-4 * (A @ A.transpose(0, 2, 1) + np.eye(3))
    M = np.zeros((B, 6, 6))
    M[:, :3, :3] = inertia
    M[:, 3:, 3:] = 0.3 * np.eye(3)
    phi = rng.normal(size=(B, 6))
    r = E[:, None, :3, 3] + rng.normal(0, 0.03, (B, N, 3))
    w_ext = rng.normal(size=(B, 6))
    t = lambda a: torch.from_numpy(a)  # noqa: E731
    return t(E), t(phi), t(M), t(r), t(w_ext), t(rng.normal(size=(B, N, 3)))


def test_rigid_body_terms_against_integration_and_finite_differences():
    """U_phi f + u_phi is the motion h Gamma Ad phi^{k+1} the integrator implies (exactly: linear in f), and the
    finite-difference response of the body points moved by E^{k+1} = E^k exp(h phi^{k+1}) to a contact impulse
    (to O(h))."""
    B, N = 7, 4
    E, phi, M, r, w_ext, f = _random_body(B, N, 0)
    mask = torch.ones(B, N, dtype=torch.bool)
    mask[2, 1:] = False
    h = 1e-3
    U, u = rigid_body_terms(E, phi, M, r, h, w_ext, mask)
    assert U.shape == (B, 3 * N, 3 * N) and u.shape == (B, 3 * N)
    torch.testing.assert_close(U, U.transpose(1, 2))
    assert torch.linalg.eigvalsh(U).max() <= 1e-15                                      # negative semidefinite
    assert U[2, 3:].abs().max() == 0 and u[2, 3:].abs().max() == 0                      # masked rows
    fm = f * mask[..., None]
    GA = (gamma(r) * mask.repeat_interleave(3, 1)[..., None]) @ adjoint(E)          # masked points: not moved

    def motion(force, hh):
        out = integrate_object(E, phi, M, r, force, hh, w_ext, mask)
        lin = hh * (GA @ out.phi[..., None]).squeeze(-1)
        T = out.E @ se3_inverse(E)                                                       # world motion
        moved = r @ T[:, :3, :3].transpose(1, 2) + T[:, None, :3, 3]
        return lin, ((moved - r) * mask[..., None]).reshape(B, -1)

    lin1, d1 = motion(fm, h)
    lin0, d0 = motion(torch.zeros_like(f), h)
    Uf = (U @ fm.reshape(B, -1, 1)).squeeze(-1)
    torch.testing.assert_close(lin1 - lin0, Uf, atol=1e-15, rtol=1e-10)
    torch.testing.assert_close(lin0, u, atol=1e-15, rtol=1e-10)
    # actual motion of the body points (exact exponential): O(h^2) per step around the linear prediction
    scale = Uf.abs().max()
    assert (d1 - d0 - Uf).abs().max() <= 1e-2 * scale
    assert (d0 - u).abs().max() <= 1e-2 * u.abs().max()
    # the wrench on the body is minus the contact forces' wrench, in body coordinates
    w = integrate_object(E, phi, M, r, fm, h, w_ext, mask).w
    ww = (gamma(r).transpose(1, 2) @ fm.reshape(B, -1, 1)).squeeze(-1)
    torch.testing.assert_close(w, -(adjoint(E).transpose(1, 2) @ ww[..., None]).squeeze(-1))


def test_free_body_matches_mujoco():
    """A spinning, falling free box (no contacts) integrated with the step's semi-implicit Euler against MuJoCo
    (RK4, 0.05 ms) over 0.3 s: first-order convergence in h."""
    mujoco = pytest.importorskip("mujoco")
    mass, inertia = 0.2, np.array([2e-4, 3e-4, 4e-4])
    w0, v0 = np.array([3.0, 8.0, 1.0]), np.array([0.3, -0.2, 1.0])            # body axes
    xml = (f'<mujoco><option timestep="5e-5" integrator="RK4" gravity="0 0 -9.81"/><worldbody>'
           f'<body name="b" pos="0 0 1"><freejoint/><inertial pos="0 0 0" mass="{mass}" '
           f'diaginertia="{inertia[0]} {inertia[1]} {inertia[2]}"/></body></worldbody></mujoco>')
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    d.qvel[:3], d.qvel[3:] = v0, w0                  # free joint: world linear velocity, body angular velocity
    T_end = 0.3
    for _ in range(int(round(T_end / 5e-5))):
        mujoco.mj_step(m, d)
    R_ref = d.xmat[1].reshape(3, 3)
    p_ref = d.xpos[1].copy()
    errs = []
    for h in (2e-3, 1e-3):
        E = _pose(z=1.0)
        phi = torch.tensor([[*w0, *v0]], dtype=F64)
        M = torch.from_numpy(np.diag([*inertia, mass, mass, mass]))[None]
        r = torch.zeros(1, 0, 3, dtype=F64)
        f = torch.zeros(1, 0, 3, dtype=F64)
        for _ in range(int(round(T_end / h))):
            g = E[:, :3, :3].transpose(1, 2) @ torch.tensor([0.0, 0.0, -9.81], dtype=F64)
            w_ext = torch.cat([torch.zeros(1, 3, dtype=F64), mass * g], -1)
            out = integrate_object(E, phi, M, r, f, h, w_ext)
            E, phi = out.E, out.phi
        rot_err = np.linalg.norm(E[0, :3, :3].numpy() - R_ref)
        pos_err = np.linalg.norm(E[0, :3, 3].numpy() - p_ref)
        errs.append((rot_err, pos_err))
    (r2, p2), (r1, p1) = errs
    assert r1 < 3e-3 and p1 < 4e-3, errs                                 # h g T / 2 = 1.5 mm of the fall
    assert 1.6 < r2 / r1 < 2.5 and 1.6 < p2 / p1 < 2.5, errs                          # O(h)


# ----------------------------------------------------------------------------------------------------------------
# closed form, invariants
# ----------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("solver", ["lemke", "pgs"])
def test_lever_closed_form(solver):
    """A 1-DOF finger (lever l, compliance c) pressing a frictionless plane it touches at theta_c = 0:
    G = c l^2 and, once settled, f = delta / (c l^2) with delta = l (theta_r - theta_c). B = 1 with Lemke, B = 7
    (seven references) with the batched solver."""
    length, c = 0.05, 0.8
    hand = hand_from_mjcf(lever_xml(length))
    radius = float(hand.capsule_radius[1])
    B = 1 if solver == "lemke" else 7
    env = TablePlane(offset=-radius, mu=0.0)
    settings = StepSettings(solver=solver, geometry="capsules")
    root = _pose(B=B)
    C = torch.tensor([[0.0] * 6 + [c]], dtype=F64).expand(B, 7)
    theta_final = torch.linspace(0.05, 0.2, B, dtype=F64)[:, None]
    state = initial_state(hand, torch.full((B, 1), -0.05, dtype=F64), root, env=env, settings=settings)
    reference = lambda k: -0.05 + (theta_final + 0.05) * min(1.0, k / 10)  # noqa: E731
    state, reports = run(state, hand, C, reference, 16, env=env, settings=settings)
    assert all(bool((rep.status == CONVERGED).all()) for rep in reports)
    arm = state.contacts.points[:, 1, 0] - root[:, 0, 3]                              # slot 1: lever vs plane
    G = effective_compliance(state.contacts.J, C, state.contacts.mask)
    torch.testing.assert_close(G[:, 5, 5], c * arm ** 2, rtol=1e-12, atol=0)           # G_zz = c l^2
    torch.testing.assert_close(arm, torch.full_like(arm, length), rtol=1e-4, atol=0)
    delta = length * (theta_final[:, 0] - 0.0)
    f_closed = delta / (c * length ** 2)
    torch.testing.assert_close(state.forces[:, 1, 2], f_closed, rtol=1e-4, atol=0)
    torch.testing.assert_close(state.q[:, 0], torch.zeros(B, dtype=F64), atol=1e-6, rtol=0)
    print(f"\nlever closed form ({solver}): f = {state.forces[:, 1, 2].tolist()} N, delta/(c l^2) = "
          f"{f_closed.tolist()} N")


def test_joint_limits_clamp_and_report():
    """theta^{k+1} is clamped into hand.xml's joint range (read here by MuJoCo, the reference) and the clamp is
    reported: a lever limited to [-0.3, -0.02] rad whose reference (0.2 rad) presses into a plane it touches at
    theta = 0 stops at its limit, 0.02 rad above the plane's contact, carries no force and reports a clamp of
    0.22 rad; without clamping (the paper's step) it presses the plane as in the closed form."""
    mujoco = pytest.importorskip("mujoco")
    length, c = 0.05, 0.8
    xml = lever_xml(length).replace('axis="0 1 0"/>', 'axis="0 1 0" limited="true" range="-0.3 -0.02"/>')
    hi = float(mujoco.MjModel.from_xml_string(xml).jnt_range[0, 1])
    hand = hand_from_mjcf(xml)
    radius = float(hand.capsule_radius[1])
    env = TablePlane(offset=-radius, mu=0.0)
    C = torch.tensor([[0.0] * 6 + [c]], dtype=F64)
    reference = lambda k: torch.full((1, 1), -0.05 + 0.25 * min(1.0, k / 10), dtype=F64)  # noqa: E731
    for clamp in (True, False):
        settings = StepSettings(solver="lemke", geometry="capsules", clamp_joints=clamp)
        state = initial_state(hand, torch.full((1, 1), -0.05, dtype=F64), _pose(), env=env, settings=settings)
        state, reports = run(state, hand, C, reference, 14, env=env, settings=settings)
        assert all(bool((rep.status == CONVERGED).all()) for rep in reports)
        if clamp:
            assert float(state.q[0, 0]) == pytest.approx(hi, abs=1e-15)
            assert float(state.forces.abs().max()) == 0.0
            assert float(reports[-1].joint_clamp[0]) == pytest.approx(0.2 - hi, abs=1e-12)
            assert float(reports[0].joint_clamp[0]) == 0.0               # -0.025 rad: inside the range
        else:
            assert float(state.q[0, 0]) == pytest.approx(0.0, abs=1e-6)  # on the plane, beyond the limit
            assert float(state.forces[0, 1, 2]) == pytest.approx(length * 0.2 / (c * length ** 2), rel=1e-4)
            assert all(float(rep.joint_clamp.abs().max()) == 0.0 for rep in reports)


def _check_invariants(rep, mu, tol_len=1e-10, tol_f=1e-7):
    m = rep.mask
    b0 = rep.beta[..., 0]
    assert (rep.nu[..., 0][m] >= -tol_len).all()                                     # no penetration predicted
    assert (rep.sigma[m] >= -tol_f).all() and (rep.beta >= 0).all()                    # inside the pyramid
    comp = max(1e-9, 10 * tol_len)
    assert ((rep.beta * rep.nu).abs()[m] <= comp * (1 + rep.beta[m])).all()             # complementarity
    assert ((rep.lam * rep.sigma).abs()[m] <= comp).all()
    f = torch.einsum("bnrk,bnk->bnr", rep.D, rep.beta)
    assert (f[(b0 <= 0) & m].abs() <= tol_f).all()                                       # beta_0 = 0 => f = 0
    d0 = rep.D[..., 0]
    fn = (f * d0).sum(-1)
    ft = f - fn[..., None] * d0
    assert (torch.linalg.vector_norm(ft, dim=-1) <= mu * fn + tol_f).all()               # pyramid inside the cone
    du_t = rep.du - (rep.du * d0).sum(-1, keepdim=True) * d0
    power = (ft * du_t).sum(-1)                                                          # friction dissipates
    assert (power <= tol_len * (1 + torch.linalg.vector_norm(f, dim=-1))).all(), power.max()


@pytest.mark.parametrize("solver", ["lemke", "pgs"])
def test_pinch_invariants_and_hold(solver):
    """A free 50 g box squeezed by two fingers under gravity: every LCP solved, every per-step invariant holds,
    the box stays within 5 mm (it falls freely until the fingers close), both fingers touch it and the grip carries
    its weight. (Held longer, the box pivots about the line through the two distal contacts, below its centre of
    mass, while the proximal contacts slide: point contacts without torsional friction, as in the paper.)"""
    hand, state, C, obj, settings, reference = pinch_scene(B=1 if solver == "lemke" else 3, solver=solver)
    state, reports = run(state, hand, C, reference, 20, obj=obj, settings=settings)
    for rep in reports:
        assert (rep.status == CONVERGED).all(), rep.residual
        assert (rep.residual <= 1e-8).all()
        _check_invariants(rep, obj.mu)
    assert (reports[-1].n_contacts >= 2).all()
    assert (state.object_pose[:, :3, 3] - torch.tensor([0.0, 0.0, 0.05], dtype=F64)).norm(dim=-1).max() < 5e-3
    total = state.forces.sum(1)                                                        # on the hand
    print(f"\npinch ({solver}): contacts {reports[-1].n_contacts.tolist()}, total force on the hand "
          f"{total.tolist()} N, box at {state.object_pose[:, :3, 3].tolist()}, twist {state.phi.norm(dim=-1).tolist()}")
    torch.testing.assert_close(total[:, 2], torch.full_like(total[:, 2], -obj.mass * 9.81), rtol=0.05, atol=0)
    assert (reports[-1].theta_err_max < 1e-3).all()


def test_sliding_drag_invariants():
    """The planar finger dragged along a table (root reference moving in x) slides: the slip lambda is positive,
    the force sits on the pyramid boundary and friction opposes the slip."""
    hand = hand_from_mjcf(planar_finger_mjcf(TABLE1))
    env = TablePlane(mu=0.4)
    settings = StepSettings(geometry="capsules")
    root = _pose(z=ROOT_HEIGHT)
    th0 = torch.tensor([[0.15, 0.25, 0.3, 0.2]], dtype=F64)
    th1 = torch.tensor([[0.40, 0.45, 0.35, 0.25]], dtype=F64)
    C = torch.tensor([[0.0] * 3 + [1e-4] * 3 + TABLE1], dtype=F64)
    state = initial_state(hand, th0, root, env=env, settings=settings)
    slid = 0
    for k in range(1, 31):
        root_r = _pose(x=0.002 * max(0, k - 15), z=ROOT_HEIGHT)
        state, rep = quasi_static_step(state, hand, th0 + (th1 - th0) * min(1.0, k / 12), root_r, C, env=env,
                                       settings=settings)
        assert (rep.status == CONVERGED).all()
        _check_invariants(rep, env.mu)
        slid += int(((rep.lam > 1e-6) & (rep.sigma.abs() < 1e-8) & rep.mask).sum())
    assert slid >= 5


# ----------------------------------------------------------------------------------------------------------------
# references: MuJoCo with joint springs, Clarabel
# ----------------------------------------------------------------------------------------------------------------
def _mujoco_press(mu: float, th_a, th_t, duration: float, ramp: float):
    mujoco = pytest.importorskip("mujoco")
    xml = planar_finger_mjcf(TABLE1)
    cond = 1 if mu == 0 else 3
    xml = (xml.replace('contype="1" conaffinity="0"',
                       f'contype="1" conaffinity="0" condim="{cond}" friction="{max(mu, 1e-9)} 0.005 0.0001"')
           .replace('friction="1 0.005 0.0001"', f'friction="{max(mu, 1e-9)} 0.005 0.0001" condim="{cond}"')
           .replace('solref="0.0005 1"', 'solref="-1e6 -300"')                      # stiff contact (0.2 mm)
           .replace('cone="elliptic"', 'cone="elliptic" noslip_iterations="30"'))     # no frictional creep
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    d.qpos[:] = th_a
    for k in range(int(round(duration / TIMESTEP))):
        m.qpos_spring[:] = th_a + (th_t - th_a) * min(1.0, k * TIMESTEP / ramp)
        mujoco.mj_step(m, d)
    f6 = np.zeros(6)
    total = np.zeros(3)
    for i in range(d.ncon):
        con = d.contact[i]
        mujoco.mj_contactForce(m, d, i, f6)
        fw = con.frame.reshape(3, 3).T @ f6[:3]                # on geom2 = the surface: the hand gets -fw
        total += -fw if m.geom_bodyid[con.geom2] == 0 else fw
    return total, d.qpos.copy()


@pytest.mark.parametrize("mu, tol", [(0.0, 0.03), (0.3, 0.03), (1.0, 0.05)])
def test_planar_finger_press_against_mujoco(mu, tol):
    """The four-joint planar finger (springs 1/c, Table 1) pressing a table to equilibrium: the contact force of
    the quasi-static steps against MuJoCo's (stiff contact, no frictional creep): frictionless, sliding to the end
    (mu = 0.3: the force ends on the cone, unique) and sticking (mu = 1: the tangential force depends on where the
    tip stuck during the approach, so the dynamic and the quasi-static paths may differ more)."""
    hand = hand_from_mjcf(planar_finger_mjcf(TABLE1))
    env = TablePlane(mu=mu)
    h, n = 1.0 / 120, 30
    settings = StepSettings(geometry="capsules", h=h)
    root = _pose(z=ROOT_HEIGHT)
    th_a = np.array([0.15, 0.25, 0.3, 0.2])
    th_t = np.array([0.40, 0.45, 0.35, 0.25])
    C = torch.tensor([[0.0] * 6 + TABLE1], dtype=F64)
    state = initial_state(hand, torch.from_numpy(th_a)[None], root, env=env, settings=settings)
    ref = lambda k: torch.from_numpy(th_a + (th_t - th_a) * min(1.0, k / n))[None]  # noqa: E731
    state, reports = run(state, hand, C, ref, 2 * n, env=env, settings=settings)
    assert all(bool((rep.status == CONVERGED).all()) for rep in reports)
    ours = state.forces[0].sum(0).numpy()
    theirs, q_mj = _mujoco_press(mu, th_a, th_t, 2 * n * h, n * h)
    rel = np.linalg.norm(ours - theirs) / np.linalg.norm(theirs)
    print(f"\nplanar finger, mu = {mu}: ours {ours.round(4).tolist()} N, MuJoCo {theirs.round(4).tolist()} N, "
          f"relative difference {rel:.4f}; joint angles differ by {np.abs(state.q[0].numpy() - q_mj).max():.2e} rad")
    assert rel < tol
    if mu > 0:
        assert abs(ours[0]) > 0.2 * abs(ours[2])                                         # friction is at work


def test_lcp_against_clarabel():
    """The step's own LCPs (pinch: coupled fingers, free object, friction) against Clarabel on the equivalent QP:
    beta* minimises 1/2 beta^T A beta + s'^T beta over beta >= 0, sum_j beta_ij <= mu_i beta*_i0 (beta*_i0 fixed
    from the LCP solution); the forces D beta are compared, not beta (beta is not unique)."""
    clarabel = pytest.importorskip("clarabel")
    import scipy.sparse as sp

    hand, state, C, obj, settings, reference = pinch_scene()
    _, reports = run(state, hand, C, reference, 12, obj=obj, settings=settings)
    checked = 0
    for rep in reports[2:]:
        lcp = rep.lcp
        Na, K = lcp.D.shape[1], lcp.D.shape[3]
        na = int(rep.n_contacts[0])
        if na == 0:
            continue
        nk = na * K
        rows = np.r_[0:nk]
        A = lcp.M[0, :Na * K, :Na * K].numpy()[np.ix_(rows, rows)]
        s = lcp.q[0, :nk].numpy()
        beta_l = rep.beta[0, rep.order[0, :na]].reshape(-1).numpy()
        mu = lcp.mu[0, :na].numpy()
        P = sp.csc_matrix(np.triu(0.5 * (A + A.T)))
        Ain = [-sp.eye(nk)]
        b = [np.zeros(nk)]
        T = np.zeros((na, nk))
        for i in range(na):
            T[i, i * K + 1:(i + 1) * K] = 1.0
        Ain.append(sp.csc_matrix(T))
        b.append(mu * beta_l.reshape(na, K)[:, 0])
        st = clarabel.DefaultSettings()
        st.verbose = False
        st.tol_gap_abs = st.tol_gap_rel = st.tol_feas = 1e-12
        sol = clarabel.DefaultSolver(P, s, sp.vstack(Ain).tocsc(), np.concatenate(b),
                                     [clarabel.NonnegativeConeT(nk + na)], st).solve()
        assert str(sol.status) == "Solved", sol.status
        beta_c = np.asarray(sol.x)
        D = lcp.D[0, :na].numpy()
        f_l = np.einsum("nrk,nk->nr", D, beta_l.reshape(na, K))
        f_c = np.einsum("nrk,nk->nr", D, beta_c.reshape(na, K))
        np.testing.assert_allclose(f_c, f_l, atol=1e-5 * max(1.0, np.abs(f_l).max()))
        checked += 1
    assert checked >= 8


def test_bad_input():
    from torchhand.errors import InputValueError

    with pytest.raises(InputValueError, match="solver"):
        StepSettings(solver="qp")
    with pytest.raises(InputValueError, match="pyramid_m"):
        StepSettings(pyramid_m=0)
    hand, state, C, obj, settings, reference = pinch_scene()
    with pytest.raises(InputValueError, match="C: compliances"):
        quasi_static_step(state, hand, reference(1), state.root_r, -C, obj, None, settings)
    with pytest.raises(ValueError, match="C"):
        quasi_static_step(state, hand, reference(1), state.root_r, C[:, :5], obj, None, settings)


def test_comb_batched_solver_agrees_with_lemke():
    """Five fingers on a compliant root pressing a table, B = 7 rollouts: the root columns of J couple every pair
    of fingers in G; the batched solvers give Lemke's forces, and the per-step invariants hold. The planar fingers
    have no compliance of their own across their plane (y), so G - U_phi is not definite on the force space there:
    the y forces may be shared differently among the fingers (f is unique only where G is definite, design note
    §3 item 14); their sum, and the in-plane forces, are compared. On these rank-deficient problems plain PGS can
    stall (one rollout in seven at 1e-8 within 1000 sweeps), hence ``solver="auto"``: Lemke for the stragglers."""
    solver = "auto"
    out = {}
    for name in ("lemke", solver):
        hand, state, C, env, settings, ref = comb_scene(7, "lemke")
        settings = replace(settings, solver=name, pgs_tol=1e-8, pgs_max_iters=1000)
        state, reports = run(state, hand, C, ref, 14, env=env, settings=settings)
        for rep in reports:
            assert (rep.status == CONVERGED).all()
            _check_invariants(rep, env.mu, tol_len=1e-8, tol_f=1e-6)        # to the PGS tolerance
        out[name] = state
    assert (out["lemke"].contacts.mask.sum(1) == 5).all()
    f, f_ref = out[solver].forces, out["lemke"].forces
    # (14 steps apart: the non-unique split feeds back through the configurations, hence 5e-4 N on ~1 N forces)
    torch.testing.assert_close(f[..., [0, 2]], f_ref[..., [0, 2]], atol=5e-4, rtol=0)
    torch.testing.assert_close(f.sum(1), f_ref.sum(1), atol=5e-4, rtol=0)
    c = out["lemke"].contacts
    G = effective_compliance(c.J, C.expand(7, -1), c.mask)
    idx = c.mask[0].nonzero().flatten()
    blocks = G[0].reshape(len(c.link), 3, len(c.link), 3)[idx][:, :, idx]
    assert (blocks[0, :, 1].abs().max() > 1e-4)                                         # fingers coupled


def test_lever_float32():
    """The lever's closed form in float32 (batched solver): forces within 1e-3 relative."""
    length, c = 0.05, 0.8
    hand = hand_from_mjcf(lever_xml(length)).to(dtype=torch.float32)
    f32 = torch.float32
    radius = float(hand.capsule_radius[1])
    env = TablePlane(offset=-radius, mu=0.5)
    settings = StepSettings(solver="pgs", geometry="capsules")
    root = torch.eye(4, dtype=f32)[None].repeat(7, 1, 1)
    C = torch.tensor([[0.0] * 6 + [c]], dtype=f32).expand(7, 7)
    theta_final = torch.linspace(0.05, 0.2, 7, dtype=f32)[:, None]
    state = initial_state(hand, torch.full((7, 1), -0.05, dtype=f32), root, env=env, settings=settings)
    reference = lambda k: -0.05 + (theta_final + 0.05) * min(1.0, k / 10)  # noqa: E731
    state, reports = run(state, hand, C, reference, 16, env=env, settings=settings)
    assert all(bool((rep.status == CONVERGED).all()) for rep in reports)
    assert state.forces.dtype == f32
    # with friction the tip may carry a tangential force; the torque about the hinge is the closed form's
    arm = state.contacts.points[:, 1] - root[:, :3, 3]
    torque = torch.linalg.cross(arm, state.forces[:, 1], dim=-1)[:, 1]
    torch.testing.assert_close(-torque, (theta_final[:, 0] - state.q[:, 0]) / c, rtol=1e-3, atol=1e-4)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA not available")
@pytest.mark.parametrize("scene", ["comb", "pinch"])
def test_batched_step_cuda_matches_cpu(scene):
    """Batched rollouts (B = 6, 12 steps, PGS with Lemke for the stragglers) on the GPU give the CPU's forces and
    configurations (float64)."""
    out = {}
    for device in ("cpu", "cuda"):
        if scene == "comb":
            hand, state, C, env, settings, ref = comb_scene(6, "auto")
            obj = None
        else:
            hand, state, C, obj, settings, ref = pinch_scene(6, "auto")
            env = None
        settings = replace(settings, pgs_tol=1e-9, pgs_max_iters=1000)
        hand, state, C, obj, ref = scene_to(device, hand, state, C, obj, ref)
        state, reports = run(state, hand, C, ref, 12, obj=obj, env=env, settings=settings)
        assert all(bool((rep.status == CONVERGED).all()) for rep in reports)
        out[device] = state
    g, c = out["cuda"], out["cpu"]
    assert g.q.is_cuda
    torch.testing.assert_close(g.q.cpu(), c.q, atol=1e-6, rtol=0)
    torch.testing.assert_close(g.forces.sum(1).cpu(), c.forces.sum(1), atol=1e-4, rtol=0)
    if scene == "pinch":
        torch.testing.assert_close(g.object_pose.cpu(), c.object_pose, atol=1e-6, rtol=0)
