"""The windowed Gauss-Newton smoothing of the motion reconstruction (:mod:`.reconstruct`, Eqs. 9-11): overlapping
windows of frames, each solved with an augmented Lagrangian of its contact and collision constraints, a trust
region, backtracking on a merit function and frozen (bound) joints."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .reconstruct_bounds import (speed_penalty, speed_terms, speed_update,
                                 speed_values)

from ._reconstruct_records import (_ACTIVE_SET_ROUNDS, _BACKTRACK_STEPS, _FRAME_SCALE, _LOOKAHEAD, _MAX_STEP,
                                   _RESIDUAL_FRACTION, _SOLVE_DTYPE, _Constraints, _Layout,
                                   _Problem)


# ----------------------------------------------------------------------------------------------------------------
# Windows
# ----------------------------------------------------------------------------------------------------------------
def _smooth_sequence(p: _Problem, q, eq, ineq, lam_eq, lam_in, segment: int):
    """Solve the whole motion window by window.

    A window of ``segment`` frames is solved with its first two frames fixed to the previous window's answer (so
    position and velocity are continuous and the acceleration terms across the join are part of the problem); its
    last ``segment // 3`` frames are a look-ahead that keeps the far end of the committed part from feeling the
    window's free boundary, and are solved again by the next window.
    """
    T = q.shape[0]
    q, lam_eq, lam_in = q.clone(), lam_eq.clone(), lam_in.clone()
    overlap = segment // _LOOKAHEAD
    start, fixed = 0, 0
    while True:
        end = min(start + segment, T)
        sl = slice(start, end)
        q[sl], lam_eq[sl], lam_in[sl] = _solve_window(p, sl, q[sl], fixed, eq.frames(sl), ineq.frames(sl),
                                                      lam_eq[sl], lam_in[sl])
        if end == T:
            return q, lam_eq, lam_in
        start, fixed = end - overlap - 2, 2


@dataclass(frozen=True)
class _Window:
    """One window's constant data: S frames, finger-local layout (F, S, n) with index ``t * n + j`` when flat."""

    root: torch.Tensor         # (S, 4, 4)
    eq: _Constraints
    ineq: _Constraints
    m_eq: torch.Tensor         # (S, K) bool: contacts this window enforces (not on held frames)
    m_in: torch.Tensor         # (S, C) bool
    H0: torch.Tensor           # (F, S n, S n): E1, w E2 and the priors
    b0: torch.Tensor           # (F, S n)
    held: torch.Tensor         # (F, S, n) bool: padding joints and the frames fixed by the previous window
    lo: torch.Tensor           # (F, 1, n) joint limits, radians
    hi: torch.Tensor


def _solve_window(p: _Problem, sl: slice, x: torch.Tensor, fixed: int, eq: _Constraints, ineq: _Constraints,
                  lam_eq: torch.Tensor, lam_in: torch.Tensor):
    """Gauss–Newton / augmented-Lagrangian / active-set solve of one window of S frames, all fingers at once.

    x: joint angles, (S, D), radians (the initial guess); the first ``fixed`` frames are held.
    returns: the solution (S, D) and the updated multipliers (S, K, 3) and (S, C).
    """
    lay, wdt = p.layout, _SOLVE_DTYPE
    S = x.shape[0]
    F, n = lay.joints.shape
    live = (torch.arange(S, device=x.device) >= fixed)[:, None]  # frames this window may change
    held = (~lay.valid)[:, None, :].expand(F, S, n).clone()
    held[:, :fixed] = True
    H0, b0 = _quadratic_terms(p, sl, S)
    w = _Window(root=p.root[sl], eq=eq, ineq=ineq, m_eq=eq.mask & live, m_in=ineq.mask & live, H0=H0, b0=b0,
                held=held, lo=lay.lo.to(wdt)[:, None, :], hi=lay.hi.to(wdt)[:, None, :])
    xl = x[:, lay.joints].permute(1, 0, 2).to(wdt) * lay.valid[:, None, :]  # (F, S, n), finger-local
    at_bound = torch.zeros_like(held)
    bound_value = torch.zeros_like(xl)
    lam_v = xl.new_zeros(F, max(S - 1, 0), n, 2) if p.joint_step is not None else None
    step = math.inf
    for it in range(p.max_inner):
        (pos_eq, J_eq), (pos_in, J_in) = _linearise(p, x, w.root, (eq, ineq))
        c_eq, g_in = _residuals(eq, ineq, pos_eq, pos_in)
        if it > 0 and step <= p.step_tol:
            # Gauss–Newton has converged for the current multipliers: stop if the constraints are met, otherwise
            # take one augmented-Lagrangian multiplier step and go on.
            worst_eq = float(c_eq.norm(dim=-1)[w.m_eq].max()) if bool(w.m_eq.any()) else 0.0
            worst_in = float((-g_in)[w.m_in].max().clamp_min(0)) if bool(w.m_in.any()) else 0.0
            worst_v = 0.0
            if lam_v is not None:
                lam_v_next, worst_v = speed_update(xl, lay.valid, p.joint_step, lam_v, p.rho_speed)
            if worst_eq <= _RESIDUAL_FRACTION * p.contact_tol and worst_in <= _RESIDUAL_FRACTION * p.penetration_tol \
                    and worst_v <= 1e-4:
                break
            lam_eq = torch.where(w.m_eq[..., None], lam_eq + p.rho * c_eq, lam_eq)
            lam_in = torch.where(w.m_in, (lam_in - p.rho * g_in).clamp_min(0), lam_in)
            if lam_v is not None:
                lam_v = lam_v_next
        frozen = w.held | at_bound
        values = torch.where(at_bound, bound_value, xl)
        sol, grad = _gauss_newton_step(p, w, xl, frozen, values, J_eq, c_eq, lam_eq, J_in, g_in, lam_in, lam_v)
        d, at_bound, bound_value = _limit_step(w, xl, sol, grad, at_bound, bound_value)
        alpha = _backtrack(p, w, x, xl, d, (c_eq, g_in), lam_eq, lam_in, lam_v)
        new = xl + alpha * d
        step = float((new - xl).abs().max()) if new.numel() else 0.0
        xl = new
        x = _to_global(x, lay, xl)
    return x, lam_eq, lam_in


def _gauss_newton_step(p: _Problem, w: _Window, xl, frozen, values, J_eq, c_eq, lam_eq, J_in, g_in, lam_in,
                       lam_v=None):
    """Minimiser of the window's linearised problem with ``frozen`` entries held at ``values`` (F, S, n), and the
    model gradient there (F, S, n).

    Which one-sided constraints are active is decided on the linear model: start from those violated now and add
    those the solution would violate until the set stops growing (a point pushed out by one step must not be let
    go at the next and fall back in).
    """
    F, S, n = xl.shape
    blocks, rhs = _constraint_terms(p, xl, w.eq, J_eq, c_eq, lam_eq, w.m_eq, None)
    H_eq = w.H0.clone()
    _add_block_diagonal(H_eq, blocks)
    b_eq = w.b0 + rhs.reshape(F, S * n)
    normal = w.ineq.normal.to(_SOLVE_DTYPE)
    rows_in = (normal[..., None] * J_in).sum(2)  # (S, C, n)
    active = w.m_in & (lam_in / p.rho - g_in > 0)
    speed = lam_v is not None
    if speed:
        valid = p.layout.valid
        active_v = lam_v / p.rho_speed - speed_values(xl, p.joint_step) > 0
    for _ in range(_ACTIVE_SET_ROUNDS):
        blk_in, rhs_in = _constraint_terms(p, xl, w.ineq, J_in, g_in, lam_in, active, normal)
        H = H_eq.clone()
        _add_block_diagonal(H, blk_in)
        b = b_eq + rhs_in.reshape(F, S * n)
        if speed:
            H_v, b_v = speed_terms(xl, valid, p.joint_step, lam_v, p.rho_speed, active_v)
            H, b = H + H_v, b + b_v
        sol = _solve_frozen(H, b, frozen.reshape(F, S * n), values.reshape(F, S * n))
        if not bool(w.m_in.any()) and not speed:
            break
        moved = (sol.view(F, S, n) - xl).permute(1, 0, 2).gather(1, w.ineq.finger[..., None].expand(-1, -1, n))
        grown = active | (w.m_in & (lam_in / p.rho - (g_in + (rows_in * moved).sum(-1)) > 0))
        same = bool((grown == active).all())
        if speed:
            grown_v = active_v | (lam_v / p.rho_speed - speed_values(sol.view(F, S, n), p.joint_step) > 0)
            same = same and bool((grown_v == active_v).all())
            active_v = grown_v
        if same:
            break
        active = grown
    grad = (H @ sol.unsqueeze(-1)).squeeze(-1) - b
    return sol.view(F, S, n), grad.view(F, S, n)


def _limit_step(w: _Window, xl, sol, grad, at_bound, bound_value):
    """The step (F, S, n) toward ``sol``, shortened to ``_MAX_STEP`` and clamped into the joint limits, and the new
    set of joints held at a bound: one that leaves its range is held until the model gradient points back inside."""
    d = sol - xl
    sol = xl + d * (_MAX_STEP / d.abs().amax(dim=(1, 2), keepdim=True).clamp_min(1e-30)).clamp(max=1.0)
    release = at_bound & (((bound_value >= w.hi) & (grad > 0)) | ((bound_value <= w.lo) & (grad < 0)))
    over, under = sol > w.hi, sol < w.lo
    bound_value = torch.where(over, w.hi.expand_as(sol), torch.where(under, w.lo.expand_as(sol), bound_value))
    at_bound = ((at_bound & ~release) | over | under) & ~w.held
    d = torch.where(w.held, torch.zeros_like(sol), torch.minimum(torch.maximum(sol, w.lo), w.hi) - xl)
    return d, at_bound, bound_value


def _backtrack(p: _Problem, w: _Window, x, xl, d, residuals, lam_eq, lam_in, lam_v=None) -> torch.Tensor:
    """Step length per finger, (F, 1, 1): halved until the merit does not rise (0 if it always does). The
    Gauss–Newton model ignores the constraints' curvature, which dominates the weak priors in the directions the
    contacts leave free, so full steps can overshoot."""
    merit0 = _merit(p, w, xl, *residuals, lam_eq, lam_in, lam_v)
    alpha = xl.new_ones(xl.shape[0], 1, 1)
    for _ in range(_BACKTRACK_STEPS):
        trial = xl + alpha * d
        poses = p.hand.forward_kinematics(_to_global(x, p.layout, trial), w.root)
        merit1 = _merit(p, w, trial, *_residuals(w.eq, w.ineq, _positions(poses, w.eq), _positions(poses, w.ineq)),
                        lam_eq, lam_in, lam_v)
        worse = merit1 > merit0 + 1e-12 * merit0.abs()
        if not bool(worse.any()):
            return alpha
        alpha = torch.where(worse[:, None, None], alpha / 2, alpha)
    return torch.where(worse[:, None, None], torch.zeros_like(alpha), alpha)


def _to_global(x: torch.Tensor, lay: _Layout, xl: torch.Tensor) -> torch.Tensor:
    """x (S, D) with the finger joints replaced by the finger-local values xl (F, S, n)."""
    out = x.clone()
    out[:, lay.joints[lay.valid]] = xl.permute(1, 0, 2)[:, lay.valid].to(x.dtype)
    return out


def _residuals(eq: _Constraints, ineq: _Constraints, pos_eq: torch.Tensor, pos_in: torch.Tensor):
    """Equality residuals c = p - target (S, K, 3) and one-sided values g = normal . (p - target) (S, C), float64."""
    wdt = _SOLVE_DTYPE
    c_eq = pos_eq.to(wdt) - eq.target.to(wdt)
    g_in = ((pos_in.to(wdt) - ineq.target.to(wdt)) * ineq.normal.to(wdt)).sum(-1)
    return c_eq, g_in


def _positions(poses: torch.Tensor, con: _Constraints) -> torch.Tensor:
    """World positions (S, C, 3) of constrained link points, from link poses (S, L, 4, 4)."""
    S = poses.shape[0]
    T_l = poses[torch.arange(S, device=poses.device)[:, None], con.link]  # (S, C, 4, 4)
    return (T_l[..., :3, :3] @ con.local.unsqueeze(-1)).squeeze(-1) + T_l[..., :3, 3]


def _merit(p: _Problem, w: _Window, xl, c_eq, g_in, lam_eq, lam_in, lam_v=None) -> torch.Tensor:
    """Augmented-Lagrangian merit of every finger's window, (F,): the quadratic terms plus the constraint terms."""
    F = xl.shape[0]
    flat = xl.reshape(F, -1)
    value = 0.5 * (flat * (w.H0 @ flat.unsqueeze(-1)).squeeze(-1)).sum(-1) - (w.b0 * flat).sum(-1)
    pen_eq = 0.5 * p.rho * ((c_eq + lam_eq / p.rho) ** 2).sum(-1) * w.m_eq
    pen_in = 0.5 * p.rho * (lam_in / p.rho - g_in).clamp_min(0) ** 2 * w.m_in
    if lam_v is not None:
        value = value + speed_penalty(xl, p.layout.valid, p.joint_step, lam_v, p.rho_speed)
    value = value.index_add(0, w.eq.finger.reshape(-1), pen_eq.reshape(-1))
    return value.index_add(0, w.ineq.finger.reshape(-1), pen_in.reshape(-1))


def _quadratic_terms(p: _Problem, sl: slice, S: int):
    """The constant part of a window's normal equations: E1 (Eq. 10), w E2 (Eq. 11) and the priors.

    returns H0 (F, S n, S n) and b0 (F, S n) in the time-major layout ``index = t * n + j``.
    """
    lay, wdt = p.layout, _SOLVE_DTYPE
    F, n = lay.joints.shape
    dev = lay.joints.device
    A = torch.zeros(max(S - 2, 0), S, dtype=wdt, device=dev)
    if S >= 3:
        r = torch.arange(S - 2, device=dev)
        A[r, r], A[r, r + 1], A[r, r + 2] = 1.0, -2.0, 1.0
    H0 = torch.kron(A.T @ A, torch.eye(n, dtype=wdt, device=dev)).expand(F, S * n, S * n).clone()
    e = lay.bend.to(wdt)
    bend = (p.bend_weight * e[:, :, None] * e[:, None, :])[:, None].expand(F, S, n, n)
    w = p.prior_weight[sl].to(wdt).T[:, :, None] * lay.valid[:, None, :]  # (F, S, n)
    blocks = bend + torch.diag_embed(w)
    _add_block_diagonal(H0, blocks)
    b0 = (w * p.prior_target[sl].to(wdt).permute(1, 0, 2)).reshape(F, S * n)
    return H0, b0


def _add_block_diagonal(H: torch.Tensor, blocks: torch.Tensor) -> None:
    """H (F, S n, S n) += blockdiag over frames of ``blocks (F, S, n, n)``, in place."""
    F, S, n, _ = blocks.shape
    H.view(F, S, n, S, n).diagonal(dim1=1, dim2=3).add_(blocks.permute(0, 2, 3, 1))


def _linearise(p: _Problem, x: torch.Tensor, root: torch.Tensor, cons: tuple):
    """World positions (S, C, 3) and finger-local Jacobians (S, C, 3, n) of the points of each constraint set.

    A link point's position and Jacobian are the affine combination of those of the link's origin and three axis
    points, which one batched Jacobian call gives for every link.
    """
    lay, wdt = p.layout, _SOLVE_DTYPE
    S, n = x.shape[0], lay.joints.shape[1]
    poses, X, JX = p.hand.kinematics(x, p.frame_links, p.frame_points, root)  # (S, 4L, 3), (S, 4L, 3, D)
    P, D = JX.shape[1], JX.shape[-1]
    flat = JX.to(wdt).reshape(S, P * 3 * D)
    corner = torch.arange(4, device=x.device)[:, None] * 3 + torch.arange(3, device=x.device)   # (4, 3)
    out = []
    for con in cons:
        C = con.link.shape[1]
        u = con.local.to(wdt) / _FRAME_SCALE
        w = torch.cat([1 - u.sum(-1, keepdim=True), u], dim=-1)                   # (S, C, 4)
        # only the n columns of the constraint's finger, of its link's four points: (S, C, 4, 3, n)
        cols = lay.joints[con.finger]                                              # (S, C, n)
        row = 12 * con.link[..., None, None] + corner                             # (S, C, 4, 3)
        J = flat.gather(1, (row[..., None] * D + cols[:, :, None, None, :]).reshape(S, -1)).view(S, C, 4, 3, n)
        Jl = (J * w[..., None, None]).sum(2) * lay.valid[con.finger][:, :, None, :]   # (S, C, 3, n)
        out.append((_positions(poses, con), Jl))
    return tuple(out)


def _constraint_terms(p: _Problem, xl, con: _Constraints, Jl, c, lam, active, normal):
    """Normal-equation blocks (F, S, n, n) and right-hand sides (F, S, n) of the active point constraints.

    Equalities (normal None) minimise rho/2 |c + lam/rho|^2 with c = p(q) - target, linearised; one-sided
    constraints g = normal . (p(q) - target) >= 0 minimise rho/2 (lam/rho - g)^2 where that is positive.
    """
    F, S, n = xl.shape
    C = con.link.shape[1]
    if C == 0:
        return xl.new_zeros(F, S, n, n), xl.new_zeros(F, S, n)
    rows = Jl if normal is None else (normal[..., None] * Jl).sum(2, keepdim=True)  # (S, C, r, n)
    shift = c + lam / p.rho if normal is None else (c - lam / p.rho).unsqueeze(-1)  # (S, C, r)
    x_now = xl.permute(1, 0, 2).gather(1, con.finger[..., None].expand(S, C, n))  # (S, C, n)
    a = active.to(xl.dtype)[..., None]
    rhs = p.rho * torch.einsum("scrn,scr->scn", rows, (rows @ x_now[..., None]).squeeze(-1) - shift) * a
    blk = p.rho * torch.einsum("scrn,scrm->scnm", rows, rows) * a[..., None]
    index = (torch.arange(S, device=xl.device)[:, None] * F + con.finger).reshape(-1)
    blocks = xl.new_zeros(S * F, n, n).index_add_(0, index, blk.reshape(S * C, n, n))
    vec = xl.new_zeros(S * F, n).index_add_(0, index, rhs.reshape(S * C, n))
    return blocks.view(S, F, n, n).permute(1, 0, 2, 3), vec.view(S, F, n).permute(1, 0, 2)


def _solve_frozen(H: torch.Tensor, b: torch.Tensor, frozen: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
    """Solve H x = b (F, N, N), (F, N) with the entries where ``frozen`` held at ``values``.

    The system is symmetric positive definite whenever a prior weight is positive; Cholesky is used, with a
    pseudo-inverse for any batch element where it fails.
    """
    keep = (~frozen).to(H.dtype)
    held = values * frozen
    b = torch.where(frozen, values, b - (H @ held.unsqueeze(-1)).squeeze(-1))
    Hr = H * keep[:, :, None] * keep[:, None, :] + torch.diag_embed(frozen.to(H.dtype))
    L, info = torch.linalg.cholesky_ex(Hr)
    sol = torch.cholesky_solve(b.unsqueeze(-1), L).squeeze(-1)
    bad = info != 0
    if bool(bad.any()):
        sol[bad] = (torch.linalg.pinv(Hr[bad], hermitian=True) @ b[bad].unsqueeze(-1)).squeeze(-1)
    return sol
