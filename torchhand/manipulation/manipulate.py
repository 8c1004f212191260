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

import numpy as np

from ..errors import InputValueError
from . import plan as _plan
from ._plan_contacts import _normal_frame
from ._plan_records import GraspUnsuitable
from ._run_output import prepare_output, solution_arrays, stats_dict, write_manipulation  # noqa: F401 (importable here)
from ._run_reproject import _rebalance_last, _reproject
from ._run_result import HandMotion, ManipulationResult, ManipulationSettings, _collect, _FrameRow
from ._run_synth import _Hands, _hand_points, _of_hand, _synth_frame, _SynthFrame
from .grasp import Grasp
from .plan import PlanSettings  # noqa: F401  (importable from here, as before)
from .synth import SynthContext, torques
from .torque_derivs import static_torques, tree_state

RELEASE_GAP = 5e-4
"""A grasp contact whose link capsule stays farther than this from the object (or deeper in it) after the first
frame is released (metres): the capsule model cannot realise it without moving the other contacts."""

__all__ = ["HandMotion", "ManipulationSettings", "ManipulationResult", "manipulate", "solution_arrays", "write_manipulation",
           "GraspUnsuitable"]


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


@dataclass
class _Tally:
    """Running totals of one manipulation run, seconds (``t_*`` are clock readings), and the contacts deferred
    because they were late (mutable: the loop adds to it frame by frame)."""

    t_start: float
    t_stage1: float = 0.0
    t_plan: float = 0.0
    t_synth: float = 0.0
    per_frame: list = field(default_factory=list)
    deferred: int = 0

    def timings(self) -> dict:
        return {"stage1_s": self.t_stage1 - self.t_start, "plan_s": self.t_plan, "synth_s": self.t_synth,
                "total_s": time.perf_counter() - self.t_start, "per_frame_s": self.per_frame}


@dataclass(frozen=True, eq=False)
class _Loop:
    """What stays fixed over the frames: the scene, the settings, the planning run (:class:`.plan._Run`, whose
    contacts and geometry the steps update), the (snapped) grasps, each hand's :class:`~.synth.SynthContext` and
    equilibrium torques u_bar (6 + D_j,)."""

    scene: object
    settings: ManipulationSettings
    run: object
    grasps: tuple
    ctxs: list
    u_bar: list


@dataclass(frozen=True, eq=False)
class _Carry:
    """What frame k takes from frame k-1: every hand and its contact points, the object pose (4, 4), each hand's
    kinematics (:func:`~.torque_derivs.tree_state`), F_{k-1} per slot (H + E, 3), the window solution that
    warm-starts the next plan (None: none) and every hand at frame k-2, (q, root) per hand (the inertial term)."""

    prev: _Hands
    pose: np.ndarray
    ts: list
    f_prev: np.ndarray
    z: object
    older: list


def _manipulate(scene, grasp, settings: ManipulationSettings | None, *, hand, progress) -> ManipulationResult:
    settings = settings or ManipulationSettings()
    tally = _Tally(t_start=time.perf_counter())
    run = _plan._start(scene, grasp, settings.plan, hand)
    loop, carry = _stage1(scene, settings, run, tally)
    run.geo.reach_step = settings.synth.joint_speed / float(scene.fps)   # added contacts must be reachable
    rows: list[_FrameRow] = []
    added_k: dict = {}
    for k in range(run.geo.T):
        t0 = time.perf_counter()
        try:
            f_k, z, syn, t1 = _plan_and_synthesize(loop, k, carry, added_k, tally)
        except GraspUnsuitable as err:                  # keep the frames done before it (None when none)
            err.window = k
            err.partial = _partial(loop, rows, tally)
            raise
        active = _release_unclosed(run, k, syn)
        ts = [tree_state(loop.ctxs[j].order, q, root) for j, (q, root) in enumerate(syn.frames)]
        row, carry = _finish_frame(loop, k, carry, f_k, z, syn, active, ts)
        rows.append(row)
        t2 = time.perf_counter()
        tally.t_plan += t1 - t0
        tally.t_synth += t2 - t1
        tally.per_frame.append(t2 - t0)
        if progress is not None:
            progress(k, run.geo.T, t2 - tally.t_start)
    return _collect(scene, loop.grasps, loop.ctxs, settings, run, rows, loop.u_bar, tally.timings(), tally.deferred)


def _stage1(scene, settings: ManipulationSettings, run, tally: _Tally) -> tuple[_Loop, _Carry]:
    """Each hand's synthesis context and equilibrium torques u_bar = n(q0) + sum_i J_i(q0, h_i)^T f_i^{-1} at the
    grasp pose (Sec. 3 Stage 1); sets ``tally.t_stage1``. Returns the loop's fixed inputs and frame 0's carry."""
    geo, c = run.geo, run.c
    grasps = run.grasp if isinstance(run.grasp, tuple) else (run.grasp,)
    pose = geo.pose
    H0 = len(c.link)
    links0 = np.array(c.link)
    scene.environment.require_plain("manipulation")
    env = scene.environment
    table = env.table_height if env.table else None
    gravity = tuple(scene.gravity.double().tolist())
    ctxs, frames, u_bar = [], [], []
    for j, g in enumerate(grasps):
        hj = geo.hands[j]
        ctx = SynthContext(hj, scene.object.mesh, np.zeros(6 + hj.num_joints), scene.fps, table, gravity,
                           settings.synth)
        root0 = pose[0] @ g.wrist_in_object
        sel = _of_hand(geo, links0, j)
        ctx.u_bar = torques(hj, g.q[None], root0[None], links0[sel] - geo.link_offset[j], np.stack(c.h)[sel][None],
                            run.f_init_vals[:H0][sel])[0]
        ctxs.append(ctx)
        u_bar.append(ctx.u_bar)
        frames.append((g.q.copy(), root0))
    tally.t_stage1 = time.perf_counter()
    prev = _Hands(frames, np.stack(c.h), np.stack(c.p))
    ts_prev = [tree_state(ctx.order, q, root) for ctx, (q, root) in zip(ctxs, prev.frames)]   # kinematics of prev
    loop = _Loop(scene=scene, settings=settings, run=run, grasps=grasps, ctxs=ctxs, u_bar=u_bar)
    return loop, _Carry(prev=prev, pose=pose[0], ts=ts_prev, f_prev=run.f_init_vals, z=None, older=frames)


def _plan_and_synthesize(loop: _Loop, k: int, carry: _Carry, added_k: dict, tally: _Tally):
    """Steps 1-3: plan window k (contacts added when infeasible) and synthesize frame k. An added contact carries
    force only once it touches (Liu: the slack "reaches zero at the frame when the contact is established"): one
    still apart (more than ``plan.TOUCH_TOL``) after its first frame waits a frame, and frame k is planned and
    synthesized again without it (contacts added then must touch already, ``plan._candidate``); each such wait
    counts in ``tally.deferred``. Returns (F_k (H + E, 3), the window solution, the :class:`_SynthFrame`, the
    clock reading when planning ended)."""
    run, c = loop.run, loop.run.c
    H_before = len(c.link)
    z_in = carry.z
    while True:
        f_k, z = _plan._step(run, k, carry.f_prev, z_in)
        t1 = time.perf_counter()
        syn = _synth_frame(run, loop.ctxs, k, f_k, carry.prev, carry.pose, H_before, added_k, loop.settings.synth,
                           carry.older)
        late = [i for i in np.flatnonzero(syn.closing) if abs(float(syn.gap[i])) > _plan.TOUCH_TOL]
        if not late:
            return f_k, z, syn, t1
        run.out.pop()
        for i in late:
            c.start[i] = k + 1
        tally.deferred += len(late)
        z_in = None


def _partial(loop: _Loop, rows: list, tally: _Tally) -> ManipulationResult | None:
    """The result of the frames done before a :class:`GraspUnsuitable` (None when none is left): the last frame
    re-balanced for the cut scene, or dropped (until one balances) when its forces cannot."""
    while rows and not _rebalance_last(loop.run, loop.ctxs, rows, loop.scene, loop.settings):
        rows.pop()                              # its forces cannot balance the cut scene: not written
    if not rows:
        return None
    return _collect(loop.scene, loop.grasps, loop.ctxs, loop.settings, loop.run, rows, loop.u_bar, tally.timings(),
                    tally.deferred)


def _release_unclosed(run, k: int, syn: _SynthFrame) -> np.ndarray:
    """The contacts active at frame k, (H,) bool. At k = 0 the grasp contacts the capsule model cannot close
    (``|gap| > RELEASE_GAP``) are released: inactive from now on."""
    active = syn.active.copy()
    if k == 0:
        for i in np.flatnonzero(active & (np.abs(syn.gap) > RELEASE_GAP)):
            run.c.start[i] = run.geo.T
            active[i] = False
    return active


def _finish_frame(loop: _Loop, k: int, carry: _Carry, f_k: np.ndarray, z, syn: _SynthFrame, active: np.ndarray,
                  ts: list) -> tuple[_FrameRow, _Carry]:
    """Steps 4-5 after the synthesis of frame k: move the active contacts to the synthesized hand, re-project the
    forces onto them, recompute the torques, update the contact states for frame k+1 and move the hands the next
    windows choose added contacts from. ``ts``: each hand's kinematics at frame k. Returns frame k's row and the
    carry into frame k+1."""
    run = loop.run
    c, geo = run.c, run.geo
    pose = geo.pose
    Rs, os_ = pose[k][:3, :3], pose[k][:3, 3]
    H = len(c.link)
    source = np.array(c.source)
    n_w = np.stack(c.n) @ pose[k][:3, :3].T               # the normals before the update
    p_new = _move_contacts(loop, k, syn, active, ts)
    f_fin, lam_fin, rstatus = _reproject(c, geo, run.settings, k, f_k, syn.lam)
    snap = dataclasses.replace(c, link=list(c.link), h=list(c.h), p=list(c.p), n=list(c.n), t1=list(c.t1),
                               start=list(c.start), source=list(c.source), h_obj=list(c.h_obj),
                               slide=dict(c.slide))      # the contacts as frame k was re-projected with
    u = _hand_torques(loop, syn, active, ts, f_fin)
    sliding_now = _contact_states(loop, k, carry, syn, active, ts, n_w)
    row = _FrameRow(H=H, frames=syn.frames, u=u, h=syn.h.copy(), p=p_new.copy(), point=np.stack(c.p) @ Rs.T + os_,
                    normal=np.stack(c.n) @ Rs.T, force=f_fin, lam=lam_fin, planned=f_k.copy(), active=active,
                    sliding=sliding_now & active, added=active & (source >= 0), objective=syn.objective,
                    iterations=syn.iterations, converged=syn.converged, violation=syn.violation, rstatus=rstatus,
                    snap=snap)
    for j, (q, root) in enumerate(syn.frames):
        geo.move_hand(q, np.linalg.inv(pose[k]) @ root, j)
    return row, _Carry(prev=_Hands(syn.frames, syn.h, p_new), pose=pose[k], ts=ts, f_prev=f_fin, z=z,
                       older=carry.prev.frames)


def _move_contacts(loop: _Loop, k: int, syn: _SynthFrame, active: np.ndarray, ts: list) -> np.ndarray:
    """The active contacts move to the synthesized hand: h from the synthesis, p from Eq. 6 projected onto the mesh,
    with the mesh's normal there and the tangent transported (one kinematics pass of frame k per hand, ``ts``).
    Updates the planning run's contacts; returns the contacts' object points at frame k, (H, 3)."""
    c, geo = loop.run.c, loop.run.geo
    pose = geo.pose
    H = len(c.link)
    h = syn.h
    x = _hand_points(geo, ts, syn.links, h)
    Rs, os_ = pose[k][:3, :3], pose[k][:3, 3]
    p_obj = (x - os_) @ Rs
    p_proj = np.asarray(loop.scene.object.mesh.nearest.on_surface(p_obj)[0])      # closest points (no sign needed)
    n_in = -loop.ctxs[0].object_normals(p_proj)
    p_new = syn.prev.p.copy()
    for i in range(H):
        if active[i]:
            c.h[i], c.p[i] = h[i].copy(), p_proj[i].copy()
            n = n_in[i]
            t = c.t1[i] - (c.t1[i] @ n) * n
            c.n[i], c.t1[i] = n, (t / np.linalg.norm(t) if np.linalg.norm(t) > 1e-9 else _normal_frame(n))
            p_new[i] = c.p[i]
    return p_new


def _hand_torques(loop: _Loop, syn: _SynthFrame, active: np.ndarray, ts: list, f_fin: np.ndarray) -> list:
    """u^k of each hand, (6 + D_j,): gravity and the re-projected forces of its active contacts."""
    geo, H = loop.run.geo, len(loop.run.c.link)
    links, h, u = syn.links, syn.h, []
    for j in range(len(loop.grasps)):
        sel = _of_hand(geo, links, j) & active
        u.append(static_torques(loop.ctxs[j].order, ts[j], links[sel] - geo.link_offset[j], h[sel], f_fin[:H][sel],
                                loop.ctxs[j].gravity))
    return u


def _contact_states(loop: _Loop, k: int, carry: _Carry, syn: _SynthFrame, active: np.ndarray, ts: list,
                    n_w: np.ndarray) -> np.ndarray:
    """Contact states for frame k+1 (Eq. 7's relative velocity of the material points of h^{k-1}): an active,
    not closing contact whose points moved apart tangentially faster than ``slip_speed`` slides into frame k+1
    (``c.slide``). ``n_w``: the contacts' world normals at k before the update, (H, 3). Returns frame k's sliding
    flags, (H,) bool."""
    c, geo = loop.run.c, loop.run.geo
    pose = geo.pose
    Rs, os_ = pose[k][:3, :3], pose[k][:3, 3]
    prev, pose_prev = syn.prev, carry.pose
    H = len(c.link)
    xm = _hand_points(geo, ts, syn.links, prev.h)
    x_prev = _hand_points(geo, carry.ts, syn.links, prev.h)
    d_now = xm - (prev.p @ Rs.T + os_)
    d_before = x_prev - (prev.p @ pose_prev[:3, :3].T + pose_prev[:3, 3])
    v = (d_now - d_before) * loop.scene.fps
    v_t = v - (v * n_w).sum(-1, keepdims=True) * n_w
    speed = np.linalg.norm(v_t, axis=-1)
    sliding_now = syn.slide.copy()
    c.slide.clear()
    for i in range(H):
        ss = loop.settings.synth
        if ss.sliding and active[i] and not syn.closing[i] and speed[i] > ss.slip_speed:
            c.slide[i] = v_t[i]
    return sliding_now
