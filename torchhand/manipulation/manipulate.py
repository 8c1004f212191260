"""The manipulation loop (Liu 2009, Fig. 2): plan the window's contact forces, add contacts when infeasible,
synthesize the hand at frame k, update the contacts, slide the window.

For k = 0 .. T-1:

1. **Plan** (Sec. 4, :mod:`.plan`): Eq. 4 over frames k .. k+n-1 with the contact positions of the synthesized
   frame k-1 (the grasp's at k = 0) frozen in the object frame; contacts that slid into frame k use the sliding
   ray at t = k. F_{k-1} is the re-projected force of frame k-1 (F_{-1} of Stage 1 at k = 0).
2. **Add contacts** when infeasible (Sec. 4.3, inside :mod:`.plan`); no set of contacts: :class:`GraspUnsuitable`,
   carrying the result of the frames synthesized before it (``partial``) for a partial result directory.
3. **Synthesize** frame k (Sec. 5, :func:`.synth.synthesize_frame`): q, the root pose and the hand points h; the
   object points p follow from Eq. 6 and are projected onto the mesh (trimesh), with the mesh's normal there.
   An added contact carries force only once it touches: one whose capsule is still more than ``plan.TOUCH_TOL``
   (1 mm) from the object after the synthesis of its first active frame waits one frame more, and frame k is
   planned (contacts added then must already touch) and synthesized again without it. Added contacts are chosen
   reachable in the frames before they carry force (``plan._candidate``, ``plan._reach``; docs/manipulation.md,
   "When added contacts carry force").
4. **Re-project the forces** (addition (c) of docs/manipulation.md): ``min sum_i |B_i(p^k) lambda_i - f_i^plan|^2``
   subject to Eq. 1 at frame k with the new contact points, the cones and the force limit (ADMM of
   :func:`torchhand.kernels.convex_qp.solve_convex_qp`, warm-started from the plan); the torques ``u^k = n(q^k) +
   sum_i J_i(q^k, h_i^k)^T f_i^k`` are recomputed with these forces, so the stored forces balance the object and
   the stored torques hold them.
5. **Update contact states**: a contact whose material points moved apart tangentially faster than
   ``slip_speed`` (1 mm/s) slides into frame k+1 (Eq. 7's relaxed rows and the sliding ray in planning).

Equilibrium torques (Sec. 3 Stage 1): ``u_bar = n(q0) + sum_i J_i(q0, h_i)^T f_i^{-1}``, F_{-1} the minimum-norm
forces that hold the object at frame 0, at the grasp pose (wrist at ``object_pose[0] @ wrist_in_object``).

Conventions: metres, seconds, radians, newtons; T_world_* 4x4 column-vector transforms; contact normals point into
the object; f = force of the hand (or table) on the object; generalised forces ``(torque about the root origin,
force, joint torques)`` in the order of :func:`~torchhand.hand.dynamics.point_jacobian` with ``wrt_root=True``.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch

from .._numerics import record as numerics_record
from ..errors import InputValueError
from ..kernels.convex_qp import solve_convex_qp
from ..kernels.force_plan import assemble_frame_lps, assemble_window_qp
from ..kernels.status import SolverStatus
from . import plan as _plan
from ..solvers._dense import solve_qp_dense
from .grasp import Grasp
from .plan import GraspUnsuitable, PlanSettings
from .synth import HandFrame, SynthContext, SynthSettings, synthesize_frame, torques
from .torque_derivs import static_torques, tree_state

RELEASE_GAP = 5e-4
"""A grasp contact whose link capsule stays farther than this from the object (or deeper in it) after the first
frame is released (metres): the capsule model cannot realise it without moving the other contacts."""

__all__ = ["HandMotion", "ManipulationSettings", "ManipulationResult", "manipulate", "solution_arrays", "write_manipulation",
           "GraspUnsuitable"]


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
    torque: u^k, (T, 6 + D): torque about the root origin (world, N m), force (world, N), joint torques (N m)
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


def _boundary(f: np.ndarray, n: np.ndarray, t1: np.ndarray, mu: float, ratio: float) -> bool:
    fn = float(f @ n)
    t2 = np.cross(n, t1)
    return fn > 0 and abs(f @ t1) + abs(f @ t2) >= ratio * mu * fn


def _reproject(run, k: int, f_plan: np.ndarray, lam_plan: np.ndarray):
    """Addition (c): the forces closest to the plan that balance frame k with the updated contacts, by the planner's
    QP solver (``PlanSettings.qp_solver``). When the updated contacts cannot balance the frame exactly but miss by
    no more than the planner's deficit allowance (:data:`~torchhand.manipulation.plan.BALANCE_ALLOWANCE`: a pinch
    whose line has moved off the centre of mass), the frame is balanced for the nearest wrench they can produce
    (the least-squares fit), as the planner does. Returns (forces (M, 3), lambda (M, 4), status)."""
    geo = run.geo
    f, lam, status = _reproject_once(run, k, f_plan, lam_plan)
    if status == int(SolverStatus.CONVERGED):
        return f, lam, status
    planned = geo.wrench[k].copy()
    geo.wrench[k] = geo.wrench_required[k]
    _, d = _plan._wrench_fit(run.c, geo, k, run.settings)
    geo.wrench[k] = geo.wrench_required[k] - d
    if _plan.allowed_deficit(geo, d):
        f, lam, status = _reproject_once(run, k, f_plan, lam_plan)
        if status == int(SolverStatus.CONVERGED):
            return f, lam, status
    geo.wrench[k] = planned
    return f_plan, lam_plan, status


def _reproject_once(run, k: int, f_plan: np.ndarray, lam_plan: np.ndarray):
    args = _plan._window_arrays(run.c, run.geo, k, 1, run.settings)
    lps = assemble_frame_lps(**args)
    M = args["points"].shape[2]
    basis = assemble_window_qp(f_prev=args["points"].new_zeros(1, M, 3), **args).basis[0, 0]      # (M, 3, 4)
    Bd = torch.block_diag(*basis.unbind(0))
    zero = (basis.abs().sum(-2) == 0).reshape(-1).to(Bd.dtype)
    Q = 2 * (Bd.T @ Bd) + 2 * torch.diag(zero) + 1e-9 * torch.eye(4 * M, dtype=Bd.dtype)
    p = -2 * Bd.T @ torch.as_tensor(f_plan.reshape(-1), dtype=Bd.dtype)
    warm = (torch.as_tensor(lam_plan.reshape(1, -1)), None, None)
    if run.settings.qp_solver == "dense":
        res = solve_qp_dense(Q[None], p[None], lps.G[0], lps.h[0], lps.A[0], lps.b[0], warm_start=warm)
    else:
        res = solve_convex_qp(Q[None], p[None], lps.G[0], lps.h[0], lps.A[0], lps.b[0], warm_start=warm,
                              method="admm")
    status = int(res.status[0])
    if status != int(SolverStatus.CONVERGED):
        return f_plan, lam_plan, status
    lam = res.z[0].clamp_min(0).reshape(M, 4)
    return (basis @ lam[..., None]).squeeze(-1).numpy(), lam.numpy(), status


def manipulate(scene, grasp, settings: ManipulationSettings | None = None, *, hand=None,
               progress=None) -> ManipulationResult:
    """Synthesize the hand motion that realises ``scene``'s object motion from ``grasp`` (module docstring).

    Args:
        scene: a :class:`~torchhand.scene.Scene` (object, pose track, friction, table); its hand tracks give only
            the sides and their order; the wrists are synthesized
        grasp: the grasp at the scene's frame 0 (snapped here when it has no contacts), or one grasp per hand for
            two hands (a sequence, sides different; put in the scene's hand order). Two hands share one force plan
            per window (every contact of both in Eq. 4; an added contact goes to the hand of the contact it comes
            from) and the re-projection; each hand is synthesized with its own contacts and forces.
        settings: :class:`ManipulationSettings`
        hand: the grasp's hand model (default :func:`~torchhand.manipulation.grasp.grasp_hand`), or a sequence
            matching the grasps
        progress: called as ``progress(k, T, seconds)`` after each frame, or None

    Returns:
        :class:`ManipulationResult`

    Raises:
        GraspUnsuitable: a planning window stays infeasible whatever contacts are added (frame, wrench deficit);
            its ``window`` is the frame k whose window failed and its ``partial`` the :class:`ManipulationResult`
            of frames 0 .. k-1 (the scene cut to them; the last frame's forces re-balanced for the cut scene, or the
            frame dropped when they cannot be), or None when no frame is left;
        InputValueError / UnknownNameError: a grasp that does not fit its hand or cannot be snapped.

    The per-frame subproblems are small dense NumPy solves; they run with one BLAS thread (threadpoolctl), because
    a multi-threaded BLAS rounds differently and the ablation's motion measurably depended on it. So the result is
    the same on any machine for the same inputs and torch thread count.
    """
    from threadpoolctl import threadpool_limits

    if not isinstance(grasp, Grasp):                     # one grasp per hand, in the scene's hand order
        grasps = list(grasp)
        hands = list(hand) if isinstance(hand, (list, tuple)) else [hand] * len(grasps)
        sides = [h.side for h in scene.hands]
        rank = {s: i for i, s in enumerate(sides)}
        if any(g.side not in rank for g in grasps):
            raise InputValueError(f"grasp: sides {', '.join(g.side for g in grasps)}; the scene has "
                                  f"{', '.join(sides)}")
        order = sorted(range(len(grasps)), key=lambda i: rank[grasps[i].side])
        grasp = tuple(grasps[i] for i in order) if len(grasps) > 1 else grasps[0]
        hand = (tuple(hands[i] for i in order) if len(grasps) > 1 else hands[0]) if hands else None
    with threadpool_limits(limits=1, user_api="blas"):
        return _manipulate(scene, grasp, settings, hand=hand, progress=progress)


def _manipulate(scene, grasp, settings: ManipulationSettings | None, *, hand, progress) -> ManipulationResult:
    settings = settings or ManipulationSettings()
    ps, ss = settings.plan, settings.synth
    t_start = time.perf_counter()
    run = _plan._start(scene, grasp, ps, hand)
    geo, c = run.geo, run.c
    grasps = run.grasp if isinstance(run.grasp, tuple) else (run.grasp,)
    NH = len(grasps)
    T = geo.T
    pose = geo.pose
    H0 = len(c.link)
    links0 = np.array(c.link)
    env = scene.environment
    table = env.table_height if env.table else None
    gravity = tuple(scene.gravity.double().tolist())
    ctxs, frames, u_bar = [], [], []
    for j, g in enumerate(grasps):
        hj = geo.hands[j]
        ctx = SynthContext(hj, scene.object.mesh, np.zeros(6 + hj.num_joints), scene.fps, table, gravity, ss)
        root0 = pose[0] @ g.wrist_in_object
        sel = _of_hand(geo, links0, j)
        ctx.u_bar = torques(hj, g.q[None], root0[None], links0[sel] - geo.link_offset[j], np.stack(c.h)[sel][None],
                            run.f_init_vals[:H0][sel])[0]
        ctxs.append(ctx)
        u_bar.append(ctx.u_bar)
        frames.append((g.q.copy(), root0))
    t_stage1 = time.perf_counter()
    prev = _Hands(frames, np.stack(c.h), np.stack(c.p))
    pose_prev = pose[0]
    ts_prev = [tree_state(ctx.order, q, root) for ctx, (q, root) in zip(ctxs, prev.frames)]   # kinematics of prev
    added_k: dict = {}
    f_prev, z = run.f_init_vals, None
    rows, per_frame, t_plan, t_synth = [], [], 0.0, 0.0
    geo.reach_step = ss.joint_speed / float(scene.fps)      # added contacts must be reachable (plan._candidate)
    deferred = 0
    timings = lambda: {"stage1_s": t_stage1 - t_start, "plan_s": t_plan, "synth_s": t_synth,  # noqa: E731
                       "total_s": time.perf_counter() - t_start, "per_frame_s": per_frame}
    for k in range(T):
        t0 = time.perf_counter()
        H_before = len(c.link)
        z_in = z
        while True:                                        # plan and synthesize frame k (again when a contact is late)
            try:
                f_k, z = _plan._step(run, k, f_prev, z_in)
            except GraspUnsuitable as err:                  # keep the frames done before it (None when none)
                err.window = k
                while rows and not _rebalance_last(run, ctxs, rows, scene, settings):
                    rows.pop()                              # its forces cannot balance the cut scene: not written
                err.partial = None if not rows else _collect(scene, grasps, ctxs, settings, run, rows, u_bar,
                                                             timings(), deferred)
                raise
            t1 = time.perf_counter()
            res, closing, active, slide, links, prev_k, f_k, lam_k = _synth_frame(
                run, ctxs, k, f_k, prev, pose_prev, H_before, added_k, ss)
            # an added contact carries force only once it touches (Liu: the slack "reaches zero at the frame when the
            # contact is established"): one still apart after its first frame waits a frame and frame k is planned
            # and synthesized again without it (contacts added then must touch already, plan._candidate)
            late = [i for i in np.flatnonzero(closing) if abs(float(res.gap[i])) > _plan.TOUCH_TOL]
            if not late:
                break
            run.out.pop()
            for i in late:
                c.start[i] = k + 1
            deferred += len(late)
            z_in = None
        prev = prev_k
        H = len(c.link)
        source = np.array(c.source)
        n_w = np.stack(c.n) @ pose[k][:3, :3].T
        h = res.h
        if k == 0:                                         # grasp contacts the capsule model cannot close: released
            for i in np.flatnonzero(active & (np.abs(res.gap) > RELEASE_GAP)):
                c.start[i] = T
                active[i] = False
        # object points from Eq. 6, projected onto the mesh, with the mesh's normal (one kinematics pass of frame k
        # per hand serves them, the torques and the material points of h^{k-1} below)
        ts = [tree_state(ctxs[j].order, q, root) for j, (q, root) in enumerate(res.frames)]
        x = _hand_points(geo, ts, links, h)
        Rs, os_ = pose[k][:3, :3], pose[k][:3, 3]
        p_obj = (x - os_) @ Rs
        p_proj = np.asarray(scene.object.mesh.nearest.on_surface(p_obj)[0])      # closest points (no sign needed)
        n_in = -ctxs[0].object_normals(p_proj)
        p_new = prev.p.copy()
        for i in range(H):
            if active[i]:
                c.h[i], c.p[i] = h[i].copy(), p_proj[i].copy()
                n = n_in[i]
                t = c.t1[i] - (c.t1[i] @ n) * n
                c.n[i], c.t1[i] = n, (t / np.linalg.norm(t) if np.linalg.norm(t) > 1e-9 else _plan._normal_frame(n))
                p_new[i] = c.p[i]
        f_fin, lam_fin, rstatus = _reproject(run, k, f_k, lam_k)
        snap = dataclasses.replace(c, link=list(c.link), h=list(c.h), p=list(c.p), n=list(c.n), t1=list(c.t1),
                                   start=list(c.start), source=list(c.source), h_obj=list(c.h_obj),
                                   slide=dict(c.slide))      # the contacts as frame k was re-projected with
        u = []
        for j in range(NH):
            sel = _of_hand(geo, links, j) & active
            u.append(static_torques(ctxs[j].order, ts[j], links[sel] - geo.link_offset[j], h[sel], f_fin[:H][sel],
                                    ctxs[j].gravity))
        # contact states for frame k+1 (Eq. 7's relative velocity of the material points)
        xm = _hand_points(geo, ts, links, prev.h)
        x_prev = _hand_points(geo, ts_prev, links, prev.h)
        d_now = xm - (prev.p @ Rs.T + os_)
        d_before = x_prev - (prev.p @ pose_prev[:3, :3].T + pose_prev[:3, 3])
        v = (d_now - d_before) * scene.fps
        v_t = v - (v * n_w).sum(-1, keepdims=True) * n_w
        speed = np.linalg.norm(v_t, axis=-1)
        sliding_now = slide.copy()
        c.slide.clear()
        for i in range(H):
            if active[i] and not closing[i] and speed[i] > ss.slip_speed:
                c.slide[i] = v_t[i]
        rows.append(dict(H=H, frames=res.frames, u=u, h=h.copy(), p=p_new.copy(), point=np.stack(c.p) @ Rs.T + os_,
                         normal=np.stack(c.n) @ Rs.T, force=f_fin, lam=lam_fin, plan=f_k.copy(), active=active,
                         sliding=sliding_now & active, added=active & (source >= 0), obj=res.objective,
                         it=res.iterations, conv=res.converged, viol=res.violation, rstatus=rstatus, snap=snap))
        for j, (q, root) in enumerate(res.frames):
            geo.move_hand(q, np.linalg.inv(pose[k]) @ root, j)
        prev = _Hands(res.frames, h, p_new)
        ts_prev = ts
        pose_prev = pose[k]
        f_prev = f_fin
        t2 = time.perf_counter()
        t_plan += t1 - t0
        t_synth += t2 - t1
        per_frame.append(t2 - t0)
        if progress is not None:
            progress(k, T, t2 - t_start)
    return _collect(scene, grasps, ctxs, settings, run, rows, u_bar, timings(), deferred)


@dataclass(frozen=True, eq=False)
class _Hands:
    """Every hand at one frame: (q (D_j,), root (4, 4)) per hand, and the contacts' points (H, 3) in their link's
    frame (h) and the object frame (p), in contact order (the contacts of all hands)."""

    frames: list
    h: np.ndarray
    p: np.ndarray


def _of_hand(geo, links: np.ndarray, j: int) -> np.ndarray:
    """(H,) bool: the contacts (numbered links ``links``) of hand j."""
    links = np.asarray(links)
    return (links >= geo.link_offset[j]) & (links < geo.link_offset[j + 1])


def _hand_points(geo, ts: list, links: np.ndarray, local: np.ndarray) -> np.ndarray:
    """World positions (H, 3) of the link-frame points ``local`` on the numbered ``links``, each from its hand's
    :func:`~.torque_derivs.tree_state` in ``ts``."""
    out = np.zeros((len(links), 3))
    for j, t in enumerate(ts):
        sel = _of_hand(geo, links, j)
        if sel.any():
            out[sel] = _link_points(t, links[sel] - geo.link_offset[j], np.asarray(local)[sel])
    return out


def _rebalance_last(run, ctxs, rows: list, scene, settings: ManipulationSettings) -> bool:
    """A partial result is the result of the scene cut to its frames, whose required wrench at the last frame
    differs (one-sided differences at the end of the motion instead of central ones): re-project that frame's
    forces onto it (addition (c)) and recompute its torques, so the partial result balances its own scene.
    Returns False when no forces of that frame's contacts balance it (the caller drops the frame)."""
    from ..synthesis.problem import required_wrench

    geo, c, ps = run.geo, run.c, settings.plan
    T = len(rows)
    k, r = T - 1, rows[-1]
    cut = scene.with_frames(0, T)
    obj = cut.object
    mass = float(ps.mass if ps.mass is not None else obj.mass)
    inertia = torch.tensor(np.array(obj.inertia), dtype=torch.float64) * (mass / float(obj.mass))
    _, wrench = required_wrench(cut.object_pose.double(), torch.tensor(np.array(obj.com), dtype=torch.float64), mass,
                                inertia, cut.gravity.double(), cut.fps, external=cut.external_wrench)
    saved = geo.wrench[k].copy(), geo.wrench_required[k].copy()
    geo.wrench[k] = geo.wrench_required[k] = wrench[-1].numpy()
    try:                                                # with the contacts as that frame had them
        f, lam, status = _reproject(SimpleNamespace(c=r["snap"], geo=geo, settings=ps), k, r["force"], r["lam"])
    finally:
        geo.wrench[k], geo.wrench_required[k] = saved
    if status != int(SolverStatus.CONVERGED):
        return False
    m = r["active"]
    H_row = r["H"]
    links = np.array(c.link[:H_row])
    r["force"], r["lam"], r["rstatus"] = f, lam, status
    for j, (q, root) in enumerate(r["frames"]):
        sel = _of_hand(geo, links, j) & m
        r["u"][j] = torques(geo.hands[j], q[None], root[None], links[sel] - geo.link_offset[j], r["h"][sel][None],
                            f[:H_row][sel], ctxs[j].gravity)[0]
    return True


def _synth_frame(run, ctxs, k: int, f_k: np.ndarray, prev: _Hands, pose_prev: np.ndarray, H_before: int,
                 added_k: dict, ss):
    """Synthesize frame k with the forces F_k just planned (Sec. 5), each hand with its own contacts: the contacts'
    states at k (active, closing, sliding) and the receding slack of the added contacts that are not active yet,
    ``sigma_j(k) = d_j (t_e - k) / (t_e - t_a)`` (t_a the frame that added it, t_e its first active frame, d_j its
    gap at t_a). Records (t_a, d_j) of contacts added since frame k-1 in ``added_k``. The hands share only the
    object and its forces (planned together); their syntheses are separate.
    Returns (result: ``frames`` [(q, root)] per hand, ``h`` (H, 3), ``gap`` (H,), ``objective`` (sum over the hands),
    ``iterations`` (largest), ``converged`` (all), ``violation`` (largest); closing (H,), active (H,), slide (H,),
    links (H,), the frame k-1 with the added contacts' points appended, F_k, lambda_k)."""
    c, geo, pose = run.c, run.geo, run.geo.pose
    lam_k = run.out[-1][1]
    H = len(c.link)
    links = np.array(c.link)
    for i in range(H_before, H):                       # contacts added by this window
        if i not in added_k:
            j = geo.hand_of(links[i])
            q, root = prev.frames[j]
            x = _frame_points(geo.hands[j], HandFrame(q=q, root=root, h=None, p=None),
                              links[i:i + 1] - geo.link_offset[j], np.stack(c.h)[i:i + 1])[0]
            added_k[i] = (k, float(np.linalg.norm(x - (pose[k][:3, :3] @ c.p[i] + pose[k][:3, 3]))))
    start = np.array(c.start)
    source = np.array(c.source)
    active = start <= k
    closing = active & (start == k) & (source >= 0)
    approach = {}
    for i, (ta, d) in added_k.items():
        te = start[i]
        if k < te:
            approach[i] = d * (te - k) / max(te - ta, 1)
    Hp = len(prev.h)
    h_prev = np.concatenate([prev.h, np.stack(c.h)[Hp:]], 0) if H > Hp else prev.h
    p_prev = np.concatenate([prev.p, np.stack(c.p)[Hp:]], 0) if H > Hp else prev.p
    prev = _Hands(prev.frames, h_prev, p_prev)
    normals_prev = np.stack(c.n)
    n_w = normals_prev @ pose[k][:3, :3].T
    t1_w = np.stack(c.t1) @ pose[k][:3, :3].T
    slide = np.array([(i in c.slide) or (active[i] and _boundary(f_k[i], n_w[i], t1_w[i], geo.mu, ss.boundary))
                      for i in range(H)])
    rel = pose[k] @ np.linalg.inv(pose_prev)
    out_frames, h_new, gap = [], h_prev.copy(), np.zeros(H)
    objective, iterations, converged, violation = 0.0, 0, True, 0.0
    for j, ctx in enumerate(ctxs):
        sel = np.flatnonzero(_of_hand(geo, links, j))
        local = {int(i): a for a, i in enumerate(sel)}
        q, root = prev.frames[j]
        before = HandFrame(q=q, root=root, h=h_prev[sel], p=p_prev[sel])
        guess = HandFrame(q=q.copy(), root=rel @ root, h=h_prev[sel].copy(), p=p_prev[sel])
        res = synthesize_frame(ctx, before, guess, links[sel] - geo.link_offset[j], f_k[:H][sel], active[sel],
                               pose[k], pose_prev, normals_prev[sel], slide[sel],
                               {local[i]: v for i, v in approach.items() if i in local}, closing[sel],
                               settle=k == 0)
        out_frames.append((res.frame.q, res.frame.root))
        h_new[sel] = res.frame.h
        if res.gap is not None:
            gap[sel] = res.gap
        objective += res.objective
        iterations = max(iterations, res.iterations)
        converged = converged and res.converged
        violation = max(violation, res.violation)
    out = SimpleNamespace(frames=out_frames, h=h_new, gap=gap, objective=objective, iterations=iterations,
                          converged=converged, violation=violation)
    return out, closing, active, slide, links, prev, f_k, lam_k


def _frame_points(hand, frame: HandFrame, links, local) -> np.ndarray:
    from .synth import _points
    return _points(hand, frame.q, frame.root, np.asarray(links), np.asarray(local))


def _link_points(ts, links, local) -> np.ndarray:
    """World positions (P, 3) of link-frame points ``local`` (P, 3) on ``links`` (P,), from a
    :func:`~.torque_derivs.tree_state` (the arithmetic of :func:`.synth._points`)."""
    links = np.asarray(links)
    if len(links) == 0:
        return np.zeros((0, 3))
    Tl = ts.T[links]
    return np.einsum("pij,pj->pi", Tl[:, :3, :3], np.asarray(local)) + Tl[:, :3, 3]


def _collect(scene, grasps, ctxs, settings, run, rows, u_bar, timings, deferred: int = 0) -> ManipulationResult:
    """The result of the frames in ``rows`` (all of them, or the first ``len(rows)`` when the motion stopped early:
    then the scene is cut to those frames and the slots are the contacts that existed when it stopped)."""
    geo, c = run.geo, run.c
    T, E, K = len(rows), geo.E, max(r["H"] for r in rows)     # K = len(c.link) when every frame was done
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
            q[t], root[t] = r["frames"][j]
            torque[t] = r["u"][j]
        per_hand.append(HandMotion(side=g.side, hand=ctx.hand, grasp=g, q=q, root=root, torque=torque,
                                   torque_rest=u_bar[j]))
    for t, r in enumerate(rows):
        H = r["H"]
        m = r["active"]
        out["contact_mask"][t, :H] = m
        out["contact_hand_local"][t, :H] = r["h"]
        out["contact_object_local"][t, :H] = r["p"]
        out["contact_point"][t, :H] = r["point"] * m[:, None]
        out["contact_normal"][t, :H] = r["normal"] * m[:, None]
        out["contact_force"][t, :H] = r["force"][:H] * m[:, None]
        out["contact_lambda"][t, :H] = r["lam"][:H] * m[:, None]
        out["planned_force"][t, :H] = r["plan"][:H] * m[:, None]
        out["contact_sliding"][t, :H] = r["sliding"]
        out["contact_added"][t, :H] = r["added"]
        out["env_force"][t] = r["force"][H:] * geo.env_mask[t][:, None]
        out["objective"][t], out["iterations"][t] = r["obj"], r["it"]
        out["converged"][t], out["violation"][t], out["reproject_status"][t] = r["conv"], r["viol"], r["rstatus"]
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


# ------------------------------------------------------------------------------------------------ result directory
def solution_arrays(result: ManipulationResult) -> dict:
    """The ``sol_000.npz`` arrays (docs/result_format.md, docs/manipulation.md): every key of the contract plus
    ``torque`` (T, 6 + D), ``torque_names`` (6 + D,), ``torque_rest`` (6 + D,), ``contact_added`` (T, K) and the
    method's own keys (``contact_lambda``, ``planned_force``, ``contact_hand_local``, ``contact_object_local``,
    ``objective``, ``sqp_iterations``, ``mass``, ``variant_mass`` (only when ``PlanSettings.mass`` overrides the
    scene's mass), ``contact_slot`` (T, K): the contact's slot in order of creation,
    -1 where inactive (columns are sorted active-first per frame, so the slot identifies a contact across frames),
    and ``contact_slot_link`` (K,): each slot's link index, never-active slots included).

    Two hands (docs/result_format.md): per side also ``q_<side>``, ``root_pose_<side>``, ``joint_names_<side>``,
    ``guiding_<side>`` and the method's ``torque_<side>``, ``torque_rest_<side>``, ``torque_names_<side>``; ``q``,
    ``root_pose``, ``joint_names``, ``torque``, ``torque_rest`` and ``torque_names`` repeat the right hand's, and
    ``contact_link_name`` lists ``right/<link>`` and ``left/<link>`` in the hands' order."""
    from ..io.result import FORMAT_VERSION

    r = result
    T, K = r.contact_mask.shape
    order = np.argsort(~r.contact_mask, axis=1, kind="stable")          # active contacts first in every frame
    take = lambda a: np.take_along_axis(a, order[..., None] if a.ndim == 3 else order, 1)  # noqa: E731
    mask = take(r.contact_mask)
    link = np.where(mask, r.contact_link[order], -1)
    hands = r.hands or (HandMotion(r.grasp.side, r.hand, r.grasp, r.q, r.root, r.torque, r.torque_rest),)
    main = next((m for m in hands if m.side == "right"), hands[0])
    names = list(main.hand.joint_names)
    tnames = lambda jn: np.array(["root_torque_x", "root_torque_y", "root_torque_z", "root_force_x",  # noqa: E731
                                  "root_force_y", "root_force_z"] + list(jn))
    link_names = (list(main.hand.link_names) if len(hands) == 1
                  else [f"{m.side}/{n}" for m in hands for n in m.hand.link_names])
    per_side = {}
    if len(hands) > 1:
        for m in hands:
            per_side.update({f"q_{m.side}": m.q, f"root_pose_{m.side}": m.root,
                             f"joint_names_{m.side}": np.array(list(m.hand.joint_names)),
                             f"guiding_{m.side}": np.zeros((T, m.hand.num_fingers), bool),
                             f"torque_{m.side}": m.torque, f"torque_rest_{m.side}": m.torque_rest,
                             f"torque_names_{m.side}": tnames(m.hand.joint_names)})
    return {
        **per_side,
        "format_version": np.array(FORMAT_VERSION), "joint_names": np.array(names),
        "q": main.q, "root_pose": main.root, "object_pose": r.scene.object_pose.double().numpy(),
        "fps": np.array(float(r.scene.fps)),
        "contact_mask": mask, "contact_link": link.astype(np.int64), "contact_link_name": np.array(link_names),
        "contact_point": take(r.contact_point), "contact_normal": take(r.contact_normal),
        "contact_force": take(r.contact_force), "contact_sliding": take(r.contact_sliding) & mask,
        "env_contact_mask": r.env_mask, "env_contact_point": r.env_point * r.env_mask[..., None],
        "env_contact_force": r.env_force,
        "strategy": np.array("liu2009"), "friction": np.array(r.friction), "reconstructed": np.array(True),
        "guiding": np.zeros((T, main.hand.num_fingers), bool),
        "torque": main.torque, "torque_rest": main.torque_rest, "torque_equilibrium": main.torque_rest,
        "torque_names": tnames(names),
        "contact_added": take(r.contact_added) & mask, "contact_lambda": take(r.contact_lambda),
        "planned_force": take(r.planned_force), "contact_hand_local": take(r.contact_hand_local),
        "contact_object_local": take(r.contact_object_local), "objective": r.objective,
        "sqp_iterations": r.iterations, "mass": np.array(r.mass),
        "contact_slot": np.where(mask, order, -1).astype(np.int64),
        "contact_slot_link": r.contact_link.astype(np.int64),
        # a mass override (PlanSettings.mass) is not the scene's: the checker balances the solution with its own
        **({"variant_mass": np.array(float(r.mass))} if float(r.mass) != float(r.scene.object.mass) else {}),
    }


def stats_dict(result: ManipulationResult, unsuitable: GraspUnsuitable | None = None, **extra) -> dict:
    """stats.json of a manipulation result (``method: "liu2009"``). With ``unsuitable`` (the error that stopped the
    motion; ``result`` holds the frames done before it) the stats say ``complete: false``, ``status:
    "grasp_unsuitable"`` and give the frame and the wrench deficit under ``unsuitable``."""
    from ..io.result import FORMAT_VERSION

    r, s = result, result.settings
    fps_run = r.T / r.timings["total_s"] if r.timings.get("total_s") else None
    if unsuitable is not None:
        e = unsuitable
        extra = {"unsuitable": {"frame": e.frame, "window": e.window, "frames_done": r.T,
                                "deficit": e.deficit.tolist(), "deficit_force_N": float(np.linalg.norm(e.deficit[:3])),
                                "deficit_torque_Nm": float(np.linalg.norm(e.deficit[3:])),
                                "contacts": list(e.contacts), "message": str(e)}, **extra}
    return {"format_version": FORMAT_VERSION, "complete": unsuitable is None,
            "status": "complete" if unsuitable is None else "grasp_unsuitable", "method": "liu2009",
            "scene": r.scene.name,
            "T": r.T, "fps": float(r.scene.fps), "solutions": 1, "time_s": r.timings.get("total_s"),
            "frames_per_second": fps_run, "timings_s": r.timings, "added_contacts": r.num_added,
            "deferred_contacts": r.deferred,
            "max_joint_speed": s.synth.joint_speed, "sqp_iterations": r.iterations.tolist(),
            "sqp_converged": r.converged.tolist(), "reproject_status": r.reproject_status.tolist(),
            "settings": {"plan": dataclasses.asdict(s.plan), "synth": dataclasses.asdict(s.synth)},
            "mass": r.mass, "friction": r.friction, "threads": torch.get_num_threads(),
            "numerics": numerics_record(), **extra}


def prepare_output(out, *, overwrite: bool = False):
    """Validate and claim the result directory before any work (the synthesis writer's rules). Raises
    InputValueError with one line."""
    from ..synthesis.output import ResultWriter

    return ResultWriter(out, overwrite=overwrite)


def write_manipulation(result: ManipulationResult, out=None, *, overwrite: bool = False, writer=None,
                       unsuitable: GraspUnsuitable | None = None, **extra) -> Path:
    """Write the result directory: scene/ (with the synthesized wrist), hand.xml, solutions/sol_000.npz,
    stats.json last; every file atomically. Returns its path.

    unsuitable: the :class:`GraspUnsuitable` that stopped the motion, with ``result = unsuitable.partial`` (the
    frames done before it): the directory is a valid result of those frames whose stats.json says ``complete:
    false`` and ``status: "grasp_unsuitable"`` (:func:`stats_dict`)."""
    writer = writer if writer is not None else prepare_output(out, overwrite=overwrite)
    scene = result.scene
    motions = result.hands or (HandMotion(result.grasp.side, result.hand, result.grasp, result.q, result.root,
                                          result.torque, result.torque_rest),)
    # the written scene holds the manipulated hands, in the scene's order, with their synthesized wrists
    by_side = {h.side: h for h in scene.hands}
    tracks = [dataclasses.replace(by_side.get(m.side, scene.hands[0]), side=m.side,
                                  wrist_pose=torch.as_tensor(m.root)) for m in motions]
    scene = dataclasses.replace(scene, hands=tuple(tracks))
    writer.begin(result, scene, [m.hand for m in motions])
    writer.write_solution(0, solution_arrays(result), scene.name)
    return writer.complete(stats_dict(result, unsuitable, **extra))
