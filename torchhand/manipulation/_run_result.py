"""The records of the manipulation loop (:mod:`.manipulate`): its settings, the per-hand and whole results, one
synthesized frame's row (:class:`_FrameRow`) and the assembly of the rows into a :class:`ManipulationResult`."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ._frame_dynamics import inertial_torques
from ._plan_contacts import _Contacts
from ._plan_records import PlanSettings
from .grasp import Grasp
from .synth import SynthSettings


@dataclass(frozen=True)
class ManipulationSettings:
    """plan: :class:`~torchhand.manipulation.plan.PlanSettings` (window, force limit, added contacts, mass, friction);
    synth: :class:`~torchhand.manipulation.synth.SynthSettings` (objective, speed bounds, proximal weights)."""

    plan: PlanSettings = field(default_factory=PlanSettings)
    synth: SynthSettings = field(default_factory=SynthSettings)


@dataclass(frozen=True, eq=False)
class HandMotion:
    """One hand's synthesized motion (NumPy, float64; T frames, D of its joints).

    side: "right" | "left"; hand: its HandModel; grasp: its (snapped) grasp
    q: (T, D) rad; root: T_world_hand, (T, 4, 4); torque: u^k, (T, 6 + D); torque_rest: u_bar, (6 + D,)
    """

    side: str
    hand: object
    grasp: Grasp
    q: np.ndarray
    root: np.ndarray
    torque: np.ndarray
    torque_rest: np.ndarray


@dataclass(frozen=True, eq=False)
class ManipulationResult:
    """A synthesized manipulation (NumPy, float64). T frames, D joints, K hand-contact slots (in order of creation),
    E table slots.

    scene: the input scene; grasp: the (snapped) grasp; hand: the HandModel (float64)
    q: joint angles, (T, D), rad; root: wrist poses T_world_hand, (T, 4, 4)
    torque: u^k = M q_ddot + C + n + sum J^T f (Eq. 5 in full; rates by central differences of the frames), (T, 6 + D):
        torque about the root origin (world, N m), force (world, N), joint torques (N m)
    torque_rest: u_bar, (6 + D,)
    contact_link: (K,) link index; contact_mask: (T, K) active (carrying force)
    contact_hand_local: h, (T, K, 3), link frame; contact_object_local: p, (T, K, 3), object frame
    contact_point: world contact point on the object, (T, K, 3); contact_normal: into the object, (T, K, 3)
    contact_force: re-projected f = B lambda, (T, K, 3), N; contact_lambda: (T, K, 4); planned_force: (T, K, 3)
    contact_sliding: (T, K) the contact slid into frame t; contact_added: (T, K) an added contact, active at t
    env_mask (T, E), env_point (T, E, 3), env_force (T, E, 3): table contacts and their re-projected forces
    objective: |u - u_bar|^2 (pose ablation: |q - q^{k-1}|^2) per frame, (T,)
    iterations: Gauss-Newton iterations per frame (T,); converged: (T,) bool; violation: (T,) metres
    reproject_status: :class:`~torchhand.kernels.status.SolverStatus` of each frame's re-projection QP (T,)
    num_added: contacts added; settings; timings: seconds (``stage1_s``, ``plan_s``, ``synth_s``, ``total_s``,
    ``per_frame_s``)
    deferred: times an added contact was still apart (more than ``plan.TOUCH_TOL``) at the frame it was to carry
    force first, so that frame was planned and synthesized again without it
    hands: every hand's :class:`HandMotion`, in the grasps' order; with two hands ``grasp``, ``hand``, ``q``,
    ``root``, ``torque`` and ``torque_rest`` above are the first hand's, and ``contact_link`` numbers the links of
    all hands (hand j's link l is ``sum of the earlier hands' link counts + l``)
    """

    scene: object
    grasp: Grasp
    hand: object
    q: np.ndarray
    root: np.ndarray
    torque: np.ndarray
    torque_rest: np.ndarray
    contact_link: np.ndarray
    contact_mask: np.ndarray
    contact_hand_local: np.ndarray
    contact_object_local: np.ndarray
    contact_point: np.ndarray
    contact_normal: np.ndarray
    contact_force: np.ndarray
    contact_lambda: np.ndarray
    planned_force: np.ndarray
    contact_sliding: np.ndarray
    contact_added: np.ndarray
    env_mask: np.ndarray
    env_point: np.ndarray
    env_force: np.ndarray
    objective: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray
    violation: np.ndarray
    reproject_status: np.ndarray
    num_added: int
    settings: ManipulationSettings
    friction: float
    mass: float
    timings: dict = field(default_factory=dict)
    deferred: int = 0
    hands: tuple = ()

    @property
    def T(self) -> int:
        return int(self.q.shape[0])


@dataclass(frozen=True, eq=False)
class _FrameRow:
    """One synthesized frame of the manipulation loop, as :func:`_collect` writes it (NumPy, float64; H hand contacts
    at that frame, E table slots).

    H: hand contacts at the frame; frames: (q (D_j,), root (4, 4)) per hand; u: u^k per hand, (6 + D_j,)
    h: contact points in their link frame, (H, 3); p: on the object, object frame, (H, 3)
    point: world contact points, (H, 3); normal: world normals into the object, (H, 3)
    force: re-projected forces, (H + E, 3), N; lam: their lambda, (H + E, 4); planned: F_k as planned, (H + E, 3)
    active, sliding, added: (H,) bool; objective, iterations, converged, violation: the synthesis' (summed over the
    hands, largest, all, largest); rstatus: the re-projection's status; snap: the contacts as frame k was
    re-projected with (:func:`._run_reproject._rebalance_last` re-projects a partial result's last frame with them)
    """

    H: int
    frames: list
    u: list
    h: np.ndarray
    p: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    force: np.ndarray
    lam: np.ndarray
    planned: np.ndarray
    active: np.ndarray
    sliding: np.ndarray
    added: np.ndarray
    objective: float
    iterations: int
    converged: bool
    violation: float
    rstatus: int
    snap: _Contacts


def _collect(scene, grasps, ctxs, settings, run, rows: list[_FrameRow], u_bar, timings,
             deferred: int = 0) -> ManipulationResult:
    """The result of the frames in ``rows`` (all of them, or the first ``len(rows)`` when the motion stopped early:
    then the scene is cut to those frames and the slots are the contacts that existed when it stopped)."""
    geo, c = run.geo, run.c
    T, E, K = len(rows), geo.E, max(r.H for r in rows)     # K = len(c.link) when every frame was done
    if T < geo.T:
        scene = scene.with_frames(0, T)
    z3 = lambda: np.zeros((T, K, 3))  # noqa: E731
    out = dict(contact_mask=np.zeros((T, K), bool), contact_hand_local=z3(), contact_object_local=z3(),
               contact_point=z3(), contact_normal=z3(), contact_force=z3(), contact_lambda=np.zeros((T, K, 4)),
               planned_force=z3(), contact_sliding=np.zeros((T, K), bool), contact_added=np.zeros((T, K), bool),
               env_force=np.zeros((T, E, 3)), objective=np.zeros(T), iterations=np.zeros(T, np.int64),
               converged=np.zeros(T, bool), violation=np.zeros(T), reproject_status=np.zeros(T, np.int8))
    per_hand = []
    for j, (g, ctx) in enumerate(zip(grasps, ctxs)):
        D = ctx.hand.num_joints
        q, root, torque = np.zeros((T, D)), np.zeros((T, 4, 4)), np.zeros((T, 6 + D))
        for t, r in enumerate(rows):
            q[t], root[t] = r.frames[j]
            torque[t] = r.u[j]
        torque = torque + inertial_torques(ctx.hand, q, root, scene.fps)   # Eq. 5's M q_ddot + C, written frames
        per_hand.append(HandMotion(side=g.side, hand=ctx.hand, grasp=g, q=q, root=root, torque=torque,
                                   torque_rest=u_bar[j]))
    for t, r in enumerate(rows):
        H = r.H
        m = r.active
        out["contact_mask"][t, :H] = m
        out["contact_hand_local"][t, :H] = r.h
        out["contact_object_local"][t, :H] = r.p
        out["contact_point"][t, :H] = r.point * m[:, None]
        out["contact_normal"][t, :H] = r.normal * m[:, None]
        out["contact_force"][t, :H] = r.force[:H] * m[:, None]
        out["contact_lambda"][t, :H] = r.lam[:H] * m[:, None]
        out["planned_force"][t, :H] = r.planned[:H] * m[:, None]
        out["contact_sliding"][t, :H] = r.sliding
        out["contact_added"][t, :H] = r.added
        out["env_force"][t] = r.force[H:] * geo.env_mask[t][:, None]
        out["objective"][t], out["iterations"][t] = r.objective, r.iterations
        out["converged"][t], out["violation"][t], out["reproject_status"][t] = r.converged, r.violation, r.rstatus
    ps = settings.plan
    first = per_hand[0]
    return ManipulationResult(
        scene=scene, grasp=first.grasp, hand=first.hand, q=first.q, root=first.root, torque=first.torque,
        torque_rest=first.torque_rest, contact_link=np.array(c.link[:K], dtype=np.int64),
        env_mask=geo.env_mask[:T].copy(), env_point=geo.env_points[:T].copy(),
        num_added=int(sum(s >= 0 for s in c.source[:K])),
        settings=settings, friction=geo.mu,
        mass=float(ps.mass if ps.mass is not None else scene.object.mass), timings=timings, deferred=deferred,
        hands=tuple(per_hand), **out)
