"""Re-projection of the planned forces onto the synthesized contacts (:mod:`.manipulate`, addition (c) of
docs/manipulation.md), and the re-balancing of the last frame of a partial result."""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from ..kernels.force_plan import assemble_frame_lps, assemble_window_qp
from ..kernels.status import SolverStatus
from ..solvers import qp as qp_solvers
from ._plan_added import allowed_deficit
from ._plan_contacts import _Contacts, _Geometry
from ._plan_records import PlanSettings
from ._plan_window import _window_arrays, _wrench_fit
from ._run_result import ManipulationSettings
from ._run_synth import _of_hand
from .synth import torques


def _reproject(c: _Contacts, geo: _Geometry, settings: PlanSettings, k: int, f_plan: np.ndarray,
               lam_plan: np.ndarray):
    """Addition (c): the forces closest to the plan that balance frame k with the updated contacts, by the planner's
    QP solver (``PlanSettings.qp_solver``). When the updated contacts cannot balance the frame exactly but miss by
    no more than the planner's deficit allowance (:data:`~torchhand.manipulation.plan.BALANCE_ALLOWANCE`: a pinch
    whose line has moved off the centre of mass), the frame is balanced for the nearest wrench they can produce
    (the least-squares fit), as the planner does. ``c``, ``geo``, ``settings``: the planning run's contacts (as frame k
    has them), geometry and settings. Returns (forces (M, 3), lambda (M, 4), status)."""
    f, lam, status = _reproject_once(c, geo, settings, k, f_plan, lam_plan)
    if status == int(SolverStatus.CONVERGED):
        return f, lam, status
    planned = geo.wrench[k].copy()
    geo.wrench[k] = geo.wrench_required[k]
    _, d = _wrench_fit(c, geo, k, settings)
    geo.wrench[k] = geo.wrench_required[k] - d
    if allowed_deficit(geo, d):
        f, lam, status = _reproject_once(c, geo, settings, k, f_plan, lam_plan)
        if status == int(SolverStatus.CONVERGED):
            return f, lam, status
    geo.wrench[k] = planned
    return f_plan, lam_plan, status


def _reproject_once(c: _Contacts, geo: _Geometry, settings: PlanSettings, k: int, f_plan: np.ndarray,
                    lam_plan: np.ndarray):
    args = _window_arrays(c, geo, k, 1, settings)
    lps = assemble_frame_lps(**args)
    M = args["points"].shape[2]
    basis = assemble_window_qp(f_prev=args["points"].new_zeros(1, M, 3), **args).basis[0, 0]      # (M, 3, 4)
    Bd = torch.block_diag(*basis.unbind(0))
    zero = (basis.abs().sum(-2) == 0).reshape(-1).to(Bd.dtype)
    Q = 2 * (Bd.T @ Bd) + 2 * torch.diag(zero) + 1e-9 * torch.eye(4 * M, dtype=Bd.dtype)
    p = -2 * Bd.T @ torch.as_tensor(f_plan.reshape(-1), dtype=Bd.dtype)
    warm = (torch.as_tensor(lam_plan.reshape(1, -1)), None, None)
    if settings.qp_solver == "dense":
        res = qp_solvers.solve(Q[None], p[None], lps.G[0], lps.h[0], lps.A[0], lps.b[0], backend="dense",
                               warm_start=warm)
    else:
        res = qp_solvers.solve(Q[None], p[None], lps.G[0], lps.h[0], lps.A[0], lps.b[0], backend="kernel",
                               warm_start=warm, method="admm")
    status = int(res.status[0])
    if status != int(SolverStatus.CONVERGED):
        return f_plan, lam_plan, status
    lam = res.z[0].clamp_min(0).reshape(M, 4)
    return (basis @ lam[..., None]).squeeze(-1).numpy(), lam.numpy(), status


def _rebalance_last(run, ctxs, rows: list, scene, settings: ManipulationSettings) -> bool:
    """A partial result is the result of the scene cut to its frames, whose required wrench at the last frame
    differs (one-sided differences at the end of the motion instead of central ones): re-project that frame's
    forces onto it (addition (c)) and recompute its torques, so the partial result balances its own scene.
    Returns False when no forces of that frame's contacts balance it (the caller drops the frame), else True with
    ``rows[-1]`` replaced by the re-balanced row."""
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
        f, lam, status = _reproject(r.snap, geo, ps, k, r.force, r.lam)
    finally:
        geo.wrench[k], geo.wrench_required[k] = saved
    if status != int(SolverStatus.CONVERGED):
        return False
    m = r.active
    H_row = r.H
    links = np.array(c.link[:H_row])
    u = list(r.u)
    for j, (q, root) in enumerate(r.frames):
        sel = _of_hand(geo, links, j) & m
        u[j] = torques(geo.hands[j], q[None], root[None], links[sel] - geo.link_offset[j], r.h[sel][None],
                       f[:H_row][sel], ctxs[j].gravity)[0]
    rows[-1] = dataclasses.replace(r, force=f, lam=lam, rstatus=status, u=u)
    return True
