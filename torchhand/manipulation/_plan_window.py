"""The window problems of contact-force planning (:mod:`.plan`, Liu 2009 Eq. 4): the per-window kernel inputs, the
window QP (:func:`plan_forces`, :func:`_qp`) with its warm start, the per-frame LP feasibility test and the
least-squares wrench fit at one frame."""

from __future__ import annotations

import numpy as np
import torch

from ..solvers import qp as qp_solvers
from ..kernels.force_plan import FrameLPs, assemble_frame_lps, assemble_window_qp
from ..kernels.status import SolverStatus
from ._plan_contacts import _Contacts, _Geometry
from ._plan_records import PlanSettings, WindowRecord

_CONVERGED = int(SolverStatus.CONVERGED)


def _window_arrays(c: _Contacts, geo: _Geometry, k: int, n: int, settings: PlanSettings):
    """Per-window inputs of the force_plan kernels (B = 1): points, normals, com, mu, wrench, mask, hand, sliding,
    tangent."""
    H, E = len(c.link), geo.E
    M = H + E
    ts = np.arange(k, k + n)
    R, o = geo.pose[ts, :3, :3], geo.pose[ts, :3, 3]
    pts = np.zeros((n, M, 3))
    nrm = np.zeros((n, M, 3))
    tan = np.zeros((n, M, 3))
    slide = np.zeros((n, M, 3))
    mask = np.zeros((n, M), dtype=bool)
    if H:
        P, N, T1 = np.stack(c.p), np.stack(c.n), np.stack(c.t1)
        pts[:, :H] = np.einsum("tij,hj->thi", R, P) + o[:, None]
        nrm[:, :H] = np.einsum("tij,hj->thi", R, N)
        tan[:, :H] = np.einsum("tij,hj->thi", R, T1)
        mask[:, :H] = ts[:, None] >= np.array(c.start)[None]
        for i, v in c.slide.items():
            slide[0, i] = v
    if E:
        pts[:, H:] = geo.env_points[ts]
        nrm[:, H:] = (0.0, 0.0, 1.0)
        tan[:, H:] = (1.0, 0.0, 0.0)
        slide[:, H:] = geo.env_slide[ts]
        mask[:, H:] = geo.env_mask[ts]
    mu = np.array([geo.mu] * H + [geo.mu_env] * E)
    hand = np.array([True] * H + [False] * E)
    t = lambda a: torch.as_tensor(a, dtype=torch.float64)[None]  # noqa: E731
    return dict(points=t(pts), normals=t(nrm), com=t(geo.com[ts]), mu=t(mu), wrench=t(geo.wrench[ts]),
                mask=torch.as_tensor(mask)[None], hand=torch.as_tensor(hand)[None],
                f_max=float(settings.max_contact_force), sliding=t(slide), tangent=t(tan))


def plan_forces(c: _Contacts, geo: _Geometry, k: int, n: int, f_prev: np.ndarray, settings: PlanSettings,
                records: list | None = None, z_prev: np.ndarray | None = None, method: str = "admm"):
    """Solve Eq. 4 for the window t = k .. k+n-1 with the current contacts (no additions).

    f_prev: B^{k-1} lambda^{k-1} per slot, (M, 3), newtons (M = hand contacts + table slots).
    z_prev: the previous window's solution (z, lam, nu) as returned here, shifted by one frame into a warm start
    (primal and multipliers, :func:`_shift_warm`) when its slots are the same.
    method: the kernel's ``method``: "admm" (ADMM with its active-set polish, warm-started when possible; the
    default), "auto" (the kernel's choice: ADMM with a warm start, the interior point without), "ipm" (the
    interior point, cold; the fallback for thin feasible sets, where ADMM stalls or declares infeasibility too
    early) or "dense" (:func:`torchhand.solvers.qp.solve` with ``backend="dense"``: the same interior point and polish in NumPy /
    LAPACK for this one problem, far less overhead than the batched kernel at B = 1; the warm start is polished
    first, then starts the interior point; what it leaves undecided goes to the kernel).
    Returns (lambda (n, M, 4), basis (n, M, 3, 4), status, objective of Eq. 4 (with its constant), the args,
    the solution (z (4 M n,), lam (5 M n,), nu (6 n,)) for the next window's warm start).
    """
    args = _window_arrays(c, geo, k, n, settings)
    qp = assemble_window_qp(f_prev=torch.as_tensor(f_prev, dtype=torch.float64)[None], **args)
    M = args["points"].shape[2]
    warm = _shift_warm(z_prev, n, M) if method != "ipm" else None
    if method == "dense":
        res = qp_solvers.solve(qp.Q, qp.p, qp.G, qp.h, qp.A, qp.b, backend="dense", warm_start=warm)
    else:
        res = qp_solvers.solve(qp.Q, qp.p, qp.G, qp.h, qp.A, qp.b, backend="kernel", warm_start=warm, method=method)
    status = int(res.status[0])
    obj = float(res.objective[0] + qp.offset[0])
    if records is not None:
        records.append(WindowRecord(frame=k, qp=qp, objective=float(res.objective[0]), status=status))
    lam = res.z[0].reshape(n, M, 4).clamp_min(0).numpy()
    return lam, qp.basis[0].numpy(), status, obj, args, (res.z[0].numpy(), res.lam[0].numpy(), res.nu[0].numpy())


def _shift_warm(z_prev, n: int, M: int):
    """The previous window's solution (z (n' 4 M,), lam (n' 5 M,), nu (n' 6,)), n' = n or n + 1, shifted by one
    frame into a warm start of window k's QP (B = 1): its frames k .. k+n'-2, the last one repeated when n' = n
    (the window did not shorten). Rows of :func:`~torchhand.kernels.force_plan.assemble_window_qp`: lam is
    (-lambda <= 0 per frame, then n^T B lambda <= f_max per frame), nu is Eq. 1 per frame. None when the slots
    changed (another M) or there is no previous window."""
    if z_prev is None:
        return None
    z, lam, nu = z_prev
    n_old = z.shape[0] // (4 * M) if M else 0
    if z.shape[0] != 4 * M * n_old or n_old not in (n, n + 1) or lam.shape[0] != 5 * M * n_old \
            or nu.shape[0] != 6 * n_old:
        return None

    def shift(v, per):                          # drop frame k-1; repeat the last frame when the window kept its n
        v = torch.as_tensor(v, dtype=torch.float64)
        return torch.cat([v[per:], v[-per:]]) if n_old == n else v[per:]

    lam_b, lam_f = lam[:4 * M * n_old], lam[4 * M * n_old:]
    return (shift(z, 4 * M)[None], torch.cat([shift(lam_b, 4 * M), shift(lam_f, M)])[None], shift(nu, 6)[None])


def _frame_feasible(c: _Contacts, geo: _Geometry, k: int, n: int, settings: PlanSettings,
                    records: list | None = None) -> tuple[np.ndarray, FrameLPs, torch.Tensor]:
    """Per-frame LP feasibility of the window (Eq. 4 without objective), the n LPs in one batch, decided by
    :func:`torchhand.solvers.qp.lp_feasible` with ``method="admm"`` (the convex-QP kernel with Q = 0 on unit rows; feasible
    iff the witness's largest unit-row violation is below ``tol (1 + |h|_inf + |b|_inf)``, a bound that does not
    grow with the witness; undecided counts as infeasible).
    Returns (feasible (n,), lps, witness z (n, 4 M)).
    """
    from ..solvers.qp import lp_feasible

    args = _window_arrays(c, geo, k, n, settings)
    lps = assemble_frame_lps(**args)
    G, h, A, b = (x.flatten(0, 1) for x in lps)
    res = lp_feasible(G, h, A, b, method="admm")
    feasible = res.feasible.numpy().copy()
    if records is not None:
        records.append(WindowRecord(frame=k, lps=lps, feasible=feasible))
    return feasible, lps, res.z


FIT_FORCE_WEIGHT = 1e-4
"""Weight of sum |f|^2 (N^2) against the squared wrench residual (N^2 and (N m)^2) in :func:`_wrench_fit`. With 1e-6,
a pinch that missed the required torque by 0.3 mN m was fitted with a 4 N squeeze of its two contacts (the
residual fell by a hair), the frame was planned for that wrench and the hand answered with a 22-degree turn while
the object rested (liu-roll); with 1e-4 the fit keeps the forces near what the wrench needs."""


def _wrench_fit(c: _Contacts, geo: _Geometry, t: int, settings: PlanSettings):
    """Least-squares wrench fit at frame t: argmin |W lambda - w|^2 + FIT_FORCE_WEIGHT sum |f|^2 s.t. the limits (the dense
    single-problem QP path; the batched kernel with ``qp_solver="kernel"``, as :func:`_qp`).
    Returns (forces (M, 3), deficit w - W lambda (6,))."""
    args = _window_arrays(c, geo, t, 1, settings)
    lps = assemble_frame_lps(**args)
    W, w = lps.A[0, 0], lps.b[0, 0]
    basis = assemble_window_qp(f_prev=args["points"].new_zeros(1, args["points"].shape[2], 3), **args).basis[0, 0]
    M = basis.shape[0]
    Bd = torch.block_diag(*basis.unbind(0)) if M else W.new_zeros(0, 0)
    zero = (basis.abs().sum(-2) == 0).reshape(-1).to(W.dtype)
    Q = 2 * (W.T @ W + FIT_FORCE_WEIGHT * Bd.T @ Bd + torch.diag(zero))
    if settings.qp_solver == "kernel":
        res = qp_solvers.solve(Q[None], (-2 * W.T @ w)[None], lps.G[0], lps.h[0], backend="kernel")
    else:
        res = qp_solvers.solve(Q[None], (-2 * W.T @ w)[None], lps.G[0], lps.h[0], backend="dense")
    lam = res.z[0].clamp_min(0)
    forces = (basis @ lam.reshape(M, 4, 1)).squeeze(-1)
    return forces.numpy(), (w - W @ lam).numpy()

def _qp(c, geo, k, n, f_prev, settings, records, z_prev=None):
    """The window QP, by default by the dense single-problem solver (``method="dense"``,
    :func:`torchhand.solvers.qp.solve` with ``backend="dense"``: the previous window's solution polished when its slots are the
    same, else the interior point (started from it) and polish in NumPy / LAPACK; what that leaves undecided
    goes to the kernel's interior point, then ADMM). With ``PlanSettings(qp_solver="kernel")`` (for
    comparisons), the batched torch kernel: ADMM (warm-started from the previous
    window when its slots are the same), then the interior point when ADMM does not converge. The dense path
    keeps the continuity of the warm start (its polished active set) and meets the same CONVERGED test; it is
    about twice as fast per frame at B = 1 (the kernel's cost there is per-operation overhead).

    In the kernel path, ADMM goes first for speed and for the motion's continuity, no longer to work around the
    kernel: the interior point now meets the same CONVERGED test (complementarity row by row). The kernel's own choice
    (``method="auto"``: the interior point whenever there is no warm start) agrees with Clarabel as closely and
    gives the same box-turn motion to 3e-9 degrees, but on the test turn (box-turn frames 14-25, torque objective)
    its slightly different forces at frames 0-1 led the synthesis to contacts that cannot hold frame 2
    (docs/manipulation.md, "Solver notes")."""
    if settings.qp_solver == "dense":
        return plan_forces(c, geo, k, n, f_prev, settings, records, z_prev, method="dense")
    out = plan_forces(c, geo, k, n, f_prev, settings, records, z_prev, method="admm")
    if out[2] != _CONVERGED:
        out = plan_forces(c, geo, k, n, f_prev, settings, records, method="ipm")
    return out
