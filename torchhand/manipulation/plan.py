"""Contact-force planning from a grasp (Liu 2009, Sec. 3 Stage 1 and Sec. 4, Eqs. 1-4, Sec. 4.3).

**Scope.** This is the planning half of Liu's main loop (Fig. 2). Alone (:func:`plan_motion`) the grasp is
**rigid**: hand contacts stay where the snapped grasp puts them, fixed in the object frame, and move with the object,
so "the contact positions p^{k-1} solved by the previous iteration" are always the grasp's and no hand contact
slides. The manipulation loop (:mod:`.manipulate`) steps the same machinery frame by frame (``_start``, ``_step``)
and, between frames, moves the contacts to the synthesized frame k-1 (points, normals, transported tangents; a
contact that slid into frame k takes the sliding ray at t = k from ``_Contacts.slide``) and the hand surface that
new contacts are chosen from (``_Geometry.move_hand``).

Stage 1 (preprocessing)
    Initial contacts: the snapped grasp's (:mod:`.snap`). F_{-1} = argmin sum_i |f_i|^2 subject to Eq. 1 at frame 0
    and the limits (the resolution of Liu's equilibrium torques, docs/manipulation.md); it is lambda^{k-1} of the
    first window. When frame 0 itself is infeasible, contacts are added there as below.

Window loop, for k = 0 .. T-1
    1. Eq. 4 over t = k .. k+n-1 (n = ``window``, 6; shorter at the end of the motion), assembled by
       :func:`torchhand.kernels.force_plan.assemble_window_qp` and solved by
       :func:`torchhand.kernels.convex_qp.solve_convex_qp`: hand contacts at ``object_pose[t] @ p_i`` with
       transported tangents (``R_t t1_i``, so bases do not flip), static pyramids, normal force <= ``f_max``
       (30 N); table contacts from :func:`torchhand.scene._contacts.environment_contacts` (at most 8 per frame,
       farthest-point thinned), static or sliding as the object motion says (the sliding ray points along the
       table's velocity relative to the object's point, i.e. against the object's), lambda >= 0 only; the required
       wrench from :func:`torchhand.synthesis.problem.required_wrench` (less the scene's ``external_wrench``, which
       acts on the object: the contacts supply the rest). F_k = B_k lambda_k is kept; F_{k+1} ..
       are re-planned by the next window.
    2. Infeasible (Sec. 4.3): the per-frame LPs (:func:`~torchhand.kernels.force_plan.assemble_frame_lps`,
       :func:`torchhand.solvers.qp.lp_feasible` with ``method="admm"``) find the first infeasible frame t_a. Hand contacts
       are ordered by decreasing |f_i|; for contact i on link S_i the new hand point is the hand surface sample
       (at the grasp pose) closest to h_i that is not on S_i, paired with its closest object point (normal from
       that face). Pairs are added one at a time, each active from t_a on, and the LPs re-tested; the loop stops
       when every frame of the window is feasible. No set that makes the window feasible:
       :class:`GraspUnsuitable` with the frame and the wrench deficit.

Readings and deviations (documented choices; the paper is silent or the rigid grasp forces them)
    * "The contact forces" that order the contacts do not exist when Eq. 4 is infeasible: they are taken from the
      least-squares wrench fit at t_a, ``argmin |W lambda - w|^2 + 1e-4 sum_i |f_i|^2`` subject to the limits
      (the forces the contacts would push with, saturated ones first). Its residual ``w - W lambda`` is the
      **wrench deficit** reported by :class:`GraspUnsuitable`.
    * New contacts go to the first infeasible frame of the window. Liu adds them at the window's last frame
      because earlier frames were made feasible by earlier windows; with rigid contacts that first infeasible frame
      *is* the last one, except in the first window (and Stage 1), whose frames are all new.
    * A candidate's link must hold no contact yet (Liu: only "not on S_i"), so every addition brings a new link;
      once the closest candidates of all contacts are taken, the next round cycles again with the added ones.
    * When added contacts become active. Liu (Sec. 4.3, Sec. 5): new contacts go to "the last frame of the window",
      and the synthesis enforces Eq. 6 "with a receding slack that reaches zero at the frame when the contact is
      established"; a contact therefore carries force only from the frame it touches, and the frames before it are
      its approach. Read that way, three rules hold in the manipulation loop (``geo.reach_step`` set):
      (1) a candidate must be reachable in the frames left before it carries force, t_a - k (:func:`_candidate`,
      :func:`_reach`: its gap at most ``TOUCH_TOL`` plus what the hand can close at the synthesis' speed bounds
      while the active contacts keep still; a link moved only by the wrist, such as a metacarpal of the default
      hand, reaches next to nothing); the cycle over the contacts skips unreachable candidates and takes the reachable
      one nearest the highest-force contact; (2) with t_a = k (the window's first frame is infeasible, which Liu
      calls the rare case where the synthesis' new contact positions break the plan) only a touching candidate
      can be added, otherwise the grasp is unsuitable, as Liu deems it; (3) the loop (:mod:`.manipulate`) checks
      after the synthesis that an added contact touches (within ``TOUCH_TOL``) at its first active frame, and
      otherwise plans and synthesizes that frame again with the contact pending one frame more.
      Planning alone (:func:`plan_motion`, rigid grasp) has no hand motion and keeps Liu's plain choice.
    * Added contacts keep their first position (no synthesis moves them onto the hand yet) and stay to the end.
    * The per-frame LP status and the QP status are recorded per frame; a QP that fails although every LP is
      feasible (a solver failure, not an infeasible motion) keeps the LP's witness forces for that frame and its
      status says so.

Conventions: world z-up, metres, seconds, newtons; contact normals point into the object; f = B lambda is the force
of the hand (or the table) on the object; wrench = (force, torque about the COM), world.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from ..errors import InputValueError
from ._plan_added import _add_contacts, _allow_small_deficits
from ._plan_contacts import _Contacts, _Geometry, _initial_contacts
from ._plan_records import ForcePlan, GraspUnsuitable, PlanSettings, WindowRecord
from ._plan_window import _CONVERGED, _frame_feasible, _qp, plan_forces
# names of the private modules that tests and the manipulation loop reach through this module
from ._plan_added import (BALANCE_ALLOWANCE, REACH_FACTOR, TOUCH_TOL, _candidate, _reach,  # noqa: F401
                          allowed_deficit)
from ._plan_contacts import _add, _normal_frame  # noqa: F401
from ._plan_window import _shift_warm, _window_arrays, _wrench_fit  # noqa: F401
from .grasp import Grasp, check_grasp_hand, grasp_hand
from .snap import signed_distance, snap_grasp  # noqa: F401  (signed_distance: the tests reach it here)

__all__ = ["PlanSettings", "ForcePlan", "WindowRecord", "GraspUnsuitable", "plan_motion", "plan_forces"]


def _solve(c, geo, k, n, f_prev, settings, records, z_prev=None):
    """Eq. 4 at window k, with contacts added when infeasible (after the deficit allowance,
    :func:`_allow_small_deficits`). Returns (lambda, basis, status, objective, args, z)."""
    H0 = len(c.link)
    geo.wrench[k:k + n] = geo.wrench_required[k:k + n]      # undo the allowance of earlier windows on these frames
    out = _qp(c, geo, k, n, _pad(f_prev, H0, geo.E), settings, records, z_prev)
    if out[2] == _CONVERGED:
        return out
    feasible, _, _ = _frame_feasible(c, geo, k, n, settings, records)
    if not feasible.all() and _allow_small_deficits(c, geo, k, n, feasible, settings):
        out = _qp(c, geo, k, n, _pad(f_prev, H0, geo.E), settings, records)
        if out[2] == _CONVERGED:
            return out
        feasible, _, _ = _frame_feasible(c, geo, k, n, settings, records)
    if not feasible.all():
        n = _add_contacts(c, geo, k, n, feasible, settings, records)
        out = _qp(c, geo, k, n, _pad(f_prev, H0, geo.E, len(c.link)), settings, records)
        if out[2] == _CONVERGED:
            return out
    # every frame's LP is feasible but the QP failed (a solver failure, not an infeasible motion): the LPs' witness
    lam, basis, status, _, args, _ = out
    _, _, zl = _frame_feasible(c, geo, k, n, settings, records)
    M = args["points"].shape[2]
    return zl.reshape(n, M, 4).clamp_min(0).numpy(), basis, status, float("nan"), args, None


def _pad(f_prev: np.ndarray, H_old: int, E: int, H_new: int | None = None) -> np.ndarray:
    """f_prev (H_old + E, 3) with zero rows for hand slots added after it (H_new - H_old of them)."""
    H_new = H_old if H_new is None else H_new
    return np.concatenate([f_prev[:H_old], np.zeros((H_new - H_old, 3)), f_prev[H_old:H_old + E]], 0)


# ------------------------------------------------------------------------------------------------ the whole motion
def plan_motion(scene, grasp: Grasp, settings: PlanSettings | None = None, *, hand=None) -> ForcePlan:
    """Plan contact forces for ``scene``'s object motion from ``grasp`` (module docstring; rigid grasp, planning
    stage only: the hand-motion synthesis of Liu's Sec. 5 is not part of this function).

    Args:
        scene: a :class:`~torchhand.scene.Scene` (object, its pose track, friction, table); its hand tracks are
            not used
        grasp: the grasp on the scene's object; snapped here (``settings.snap_tol``) when it has no contacts
        settings: :class:`PlanSettings`
        hand: the grasp's hand model (default :func:`~torchhand.manipulation.grasp.grasp_hand`)

    Returns:
        :class:`ForcePlan`

    Raises:
        GraspUnsuitable: a window stays infeasible whatever contacts are added (frame and wrench deficit);
        InputValueError / UnknownNameError: a grasp that does not fit its hand or cannot be snapped.
    """
    settings = settings or PlanSettings()
    t_start = time.perf_counter()
    run = _start(scene, grasp, settings, hand)
    t_stage1 = time.perf_counter()
    f_prev, z = run.f_init_vals, None
    for k in range(run.geo.T):
        t0 = time.perf_counter()
        f_prev, z = _step(run, k, f_prev, z)
        run.per_frame.append(time.perf_counter() - t0)
    return _assemble(run, t_start, t_stage1)


@dataclass
class _Run:
    """The working state of one planning run: geometry, contacts, kept problems, Stage 1's F_{-1} and the frames
    planned so far (mutable; :func:`plan_motion` and the manipulation loop step it frame by frame)."""

    geo: _Geometry
    c: _Contacts
    grasp: Grasp | tuple          # one grasp, or one per hand (snapped)
    settings: PlanSettings
    records: list | None
    f_init_h: int
    f_init_vals: np.ndarray
    out: list = field(default_factory=list)
    per_frame: list = field(default_factory=list)


def _start(scene, grasp, settings: PlanSettings, hand=None) -> _Run:
    """Snap the grasp(s) if needed, build the geometry and contacts, and solve Stage 1 (F_{-1}). ``grasp``: one
    :class:`Grasp` or a sequence of them (one per hand, different sides); ``hand``: its hand model, or a sequence
    matching the grasps (None: :func:`grasp_hand`)."""
    grasps = [grasp] if isinstance(grasp, Grasp) else list(grasp)
    hands = list(hand) if isinstance(hand, (list, tuple)) else [hand] * len(grasps)
    if not grasps or len(grasps) > 2 or len(hands) != len(grasps):
        raise InputValueError(f"grasp: expected one grasp or one per hand (two at most), got {len(grasps)} grasp(s) "
                              f"and {len(hands)} hand model(s)")
    if len({g.side for g in grasps}) != len(grasps):
        raise InputValueError(f"grasp: two grasps of the same side ({grasps[0].side}); one per hand")
    for j, g in enumerate(grasps):
        hands[j] = (hands[j] or grasp_hand(g)).to("cpu", torch.float64)
        check_grasp_hand(g, hands[j])
        if not g.has_contacts:
            grasps[j], _ = snap_grasp(g, hands[j], scene.object.mesh, tol=settings.snap_tol)
    geo = _Geometry(scene, grasps, hands, settings)
    if geo.T < 1:
        raise InputValueError("scene: the object motion has no frames")
    grasp = grasps[0] if len(grasps) == 1 else tuple(grasps)
    c = _initial_contacts(geo, grasps)
    records: list | None = [] if settings.keep_problems else None
    # Stage 1: F_{-1} = argmin sum |f|^2 s.t. Eq. 1 at frame 0 (f_prev = 0 makes Eq. 3 exactly that).
    lam, basis, status, _, _, _ = _solve(c, geo, 0, 1, np.zeros((len(c.link) + geo.E, 3)), settings, records)
    f_prev = np.einsum("mij,mj->mi", basis[0], lam[0])
    return _Run(geo=geo, c=c, grasp=grasp, settings=settings, records=records, f_init_h=len(c.link), f_init_vals=f_prev)


def _step(run: _Run, k: int, f_prev: np.ndarray, z=None):
    """Plan window k (Eq. 4, contacts added when infeasible) and keep F_k. f_prev: F_{k-1} per slot of the
    previous frame, (H_prev + E, 3). Returns (F_k (H + E, 3), the window solution for the next warm start)."""
    c, geo, E = run.c, run.geo, run.geo.E
    n = min(run.settings.window, geo.T - k)
    H_before = len(f_prev) - E
    lam, basis, status, obj, args, z = _solve(c, geo, k, n, _pad(f_prev, H_before, E, len(c.link)), run.settings,
                                              run.records, z)
    f_k = np.einsum("mij,mj->mi", basis[0], lam[0])
    run.out.append([len(c.link), lam[0], f_k, args["points"][0, 0].numpy(), args["normals"][0, 0].numpy(),
                    args["mask"][0, 0].numpy(), status, obj])
    return f_k, z


def _assemble(run: _Run, t_start: float, t_stage1: float) -> ForcePlan:
    c, geo, E, out = run.c, run.geo, run.geo.E, run.out
    f_init_h, f_init_vals, records, per_frame = run.f_init_h, run.f_init_vals, run.records, run.per_frame
    # Assemble (T, K) arrays: hand slots in order of creation, then table slots.
    H = len(c.link)
    K, T = H + E, geo.T
    forces, lams = np.zeros((T, K, 3)), np.zeros((T, K, 4))
    points, normals, mask = np.zeros((T, K, 3)), np.zeros((T, K, 3)), np.zeros((T, K), dtype=bool)
    status_t, obj_t = np.zeros(T, dtype=np.int8), np.zeros(T)
    for t, (h, lam_t, f_t, p_t, n_t, m_t, st, ob) in enumerate(out):
        sl = np.r_[np.arange(h), H + np.arange(E)]
        forces[t, sl], lams[t, sl], points[t, sl], normals[t, sl], mask[t, sl] = f_t, lam_t, p_t, n_t, m_t
        status_t[t], obj_t[t] = st, ob
    f_init = np.zeros((K, 3))
    f_init[np.r_[np.arange(f_init_h), H + np.arange(E)]] = f_init_vals
    added_at = np.array([s if src >= 0 else -1 for s, src in zip(c.start, c.source)] + [-1] * E, dtype=np.int64)
    added = mask & (added_at >= 0)[None]
    hand_flags = np.array([True] * H + [False] * E)
    links = tuple(geo.link_name(l) for l in c.link) + ("table",) * E
    t_end = time.perf_counter()
    return ForcePlan(
        forces=forces, lam=lams, points=points, normals=normals, mask=mask, hand=hand_flags, links=links,
        hand_local=np.concatenate([np.stack(c.h), np.zeros((E, 3))]) if H else np.zeros((K, 3)),
        object_local=np.concatenate([np.stack(c.p), np.zeros((E, 3))]) if H else np.zeros((K, 3)),
        added=added, added_at=added_at, added_from=np.array(c.source + [-1] * E, dtype=np.int64), f_init=f_init,
        com=geo.com, wrench=geo.wrench, status=status_t, objective=obj_t,
        timings={"stage1_s": t_stage1 - t_start, "plan_s": t_end - t_stage1, "per_frame_s": per_frame},
        records=tuple(records or ()))
