"""The windowed Gauss-Newton smoothing of the motion reconstruction (:mod:`.reconstruct`, Eqs. 9-11): overlapping
windows of frames, each solved with an augmented Lagrangian of its contact and collision constraints, a trust
region, backtracking on a merit function and frozen (bound) joints.

Many paths at once: P motions of one hand and root (the paths of one problem) are solved together. Every
decision (a window's convergence, multiplier steps, the active set, step lengths) is taken per path, and a path
that has converged is held while the others go on, so each path's iterates are those it has alone. Layouts:
per-path frame data (P, S, ...) is flattened to R = P S rows for kinematics and constraints (row ``p S + t``);
finger-local data is (P F, S, n) (block ``p F + f``)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .._tree import tree_map
from ..kernels._rows import at_least_two
from .reconstruct_bounds import (speed_penalty, speed_terms, speed_update,
                                 speed_values)

from ._reconstruct_records import (_ACTIVE_SET_ROUNDS, _BACKTRACK_STEPS, _FRAME_SCALE, _LOOKAHEAD, _MAX_STEP,
                                   _RESIDUAL_FRACTION, _SOLVE_DTYPE, _Constraints, _Layout,
                                   _Problem)


# ----------------------------------------------------------------------------------------------------------------
# Windows
# ----------------------------------------------------------------------------------------------------------------
def _smooth_sequence(p: _Problem, q, eq, ineq, lam_eq, lam_in, segment: int, running: torch.Tensor):
    """Solve the whole motions window by window: q (P, T, D), constraints and multipliers (P, T, ...); only the
    paths ``running`` (P,) bool, the others are returned as they are.

    A window of ``segment`` frames is solved with its first two frames fixed to the previous window's answer (so
    position and velocity are continuous and the acceleration terms across the join are part of the problem); its
    last ``segment // 3`` frames are a look-ahead that keeps the far end of the committed part from feeling the
    window's free boundary, and are solved again by the next window.
    """
    P, T = q.shape[:2]
    q, lam_eq, lam_in = q.clone(), lam_eq.clone(), lam_in.clone()
    overlap = segment // _LOOKAHEAD
    start, fixed = 0, 0
    while True:
        end = min(start + segment, T)
        sl = slice(start, end)
        rows = lambda t: t[:, sl].reshape(P * (end - start), *t.shape[2:]).clone()  # noqa: E731
        x, le, li = _solve_window(p, sl, q[:, sl], fixed, eq.rows(sl), ineq.rows(sl), rows(lam_eq), rows(lam_in),
                                  running)
        q[:, sl], lam_eq[:, sl], lam_in[:, sl] = x, le.view(lam_eq[:, sl].shape), li.view(lam_in[:, sl].shape)
        if end == T:
            return q, lam_eq, lam_in
        start, fixed = end - overlap - 2, 2


@dataclass(frozen=True)
class _Window:
    """One window's constant data: S frames of P paths (R = P S rows), finger-local layout (P F, S, n) with index
    ``t * n + j`` when flat."""

    root: torch.Tensor         # (R, 4, 4)
    eq: _Constraints           # (R, K, ...)
    ineq: _Constraints         # (R, C, ...)
    m_eq: torch.Tensor         # (R, K) bool: contacts this window enforces (not on held frames)
    m_in: torch.Tensor         # (R, C) bool
    H0: torch.Tensor           # (P F, S n, S n): E1, w E2 and the priors
    b0: torch.Tensor           # (P F, S n)
    held: torch.Tensor         # (P F, S, n) bool: padding joints and the frames fixed by the previous window
    lo: torch.Tensor           # (P F, 1, n) joint limits, radians
    hi: torch.Tensor
    paths: int                 # P
    valid: torch.Tensor        # (P F, n) bool: the layout's joints


def _solve_window(p: _Problem, sl: slice, x: torch.Tensor, fixed: int, eq: _Constraints, ineq: _Constraints,
                  lam_eq: torch.Tensor, lam_in: torch.Tensor, running: torch.Tensor):
    """Gauss–Newton / augmented-Lagrangian / active-set solve of one window of S frames, all fingers of P paths at
    once; a path leaves the batch when it has converged, and the paths not ``running`` (P,) bool are not in it.

    x: joint angles, (P, S, D), radians (the initial guess); the first ``fixed`` frames are held.
    eq, ineq, lam_eq (R, K, 3), lam_in (R, C): the window's constraints and multipliers, rows ``p S + t``.
    returns: the solution (P, S, D) and the updated multipliers (R, K, 3) and (R, C).
    """
    lay, wdt = p.layout, _SOLVE_DTYPE
    S = x.shape[1]
    F, n = lay.joints.shape
    out = [x.clone(), lam_eq.clone(), lam_in.clone()]
    ids = running.nonzero().squeeze(1)                                        # the paths in the batch
    w = _window(p, sl, S, fixed, ids, eq, ineq)
    rows = _rows_index(ids, S)
    x, lam_eq, lam_in = x[ids], lam_eq[rows], lam_in[rows]
    xl = _to_local(x, lay).to(wdt) * w.valid[:, None, :]                      # (P F, S, n), finger-local
    at_bound = torch.zeros_like(w.held)
    bound_value = torch.zeros_like(xl)
    lam_v = xl.new_zeros(len(ids) * F, max(S - 1, 0), n, 2) if p.joint_step is not None else None
    step = xl.new_full((len(ids),), math.inf)
    for it in range(p.max_inner if ids.numel() else 0):
        (pos_eq, J_eq), (pos_in, J_in) = _linearise(p, x, w.root, (w.eq, w.ineq))
        c_eq, g_in = _residuals(w.eq, w.ineq, pos_eq, pos_in)
        check = step <= p.step_tol if it > 0 else torch.zeros_like(step, dtype=torch.bool)
        if bool(check.any()):
            # Gauss–Newton has converged for the current multipliers: a path stops if its constraints are met,
            # otherwise it takes one augmented-Lagrangian multiplier step and goes on.
            P = len(ids)
            worst_eq = _path_max(c_eq.norm(dim=-1), w.m_eq, P)
            worst_in = _path_max(-g_in, w.m_in, P).clamp_min(0)
            worst_v = torch.zeros_like(worst_eq)
            if lam_v is not None:
                lam_v_next, worst_f = speed_update(xl, w.valid, p.joint_step, lam_v, p.rho_speed)
                worst_v = worst_f.view(P, F).amax(1)
            met = check & (worst_eq <= _RESIDUAL_FRACTION * p.contact_tol) \
                & (worst_in <= _RESIDUAL_FRACTION * p.penetration_tol) & (worst_v <= 1e-4)
            upd = check & ~met
            lam_eq = torch.where((upd.repeat_interleave(S)[:, None] & w.m_eq)[..., None], lam_eq + p.rho * c_eq,
                                 lam_eq)
            lam_in = torch.where(upd.repeat_interleave(S)[:, None] & w.m_in, (lam_in - p.rho * g_in).clamp_min(0),
                                 lam_in)
            if lam_v is not None:
                lam_v = torch.where(upd.repeat_interleave(F)[:, None, None, None], lam_v_next, lam_v)
            if bool(met.any()):                                               # they leave the batch
                _write_back(out, ids, met, x, lam_eq, lam_in, S)
                keep = (~met).nonzero().squeeze(1)
                if not keep.numel():
                    return tuple(out)
                ids, w = ids[keep], _subset(w, keep, S, F)
                r, b = _rows_index(keep, S), _rows_index(keep, F)
                x, step = x[keep], step[keep]
                xl, at_bound, bound_value = xl[b], at_bound[b], bound_value[b]
                lam_v = lam_v[b] if lam_v is not None else None
                lam_eq, lam_in, c_eq, g_in, J_eq, J_in = (t[r] for t in (lam_eq, lam_in, c_eq, g_in, J_eq, J_in))
        frozen = w.held | at_bound
        values = torch.where(at_bound, bound_value, xl)
        sol, grad = _gauss_newton_step(p, w, xl, frozen, values, J_eq, c_eq, lam_eq, J_in, g_in, lam_in, lam_v)
        d, at_bound, bound_value = _limit_step(w, xl, sol, grad, at_bound, bound_value)
        alpha = _backtrack(p, w, x, xl, d, (c_eq, g_in), lam_eq, lam_in, lam_v)
        new = xl + alpha * d
        step = (new - xl).abs().amax(dim=(1, 2)).view(len(ids), F).amax(1) if new.numel() else torch.zeros_like(step)
        xl = new
        x = _to_global(x, lay, xl)
    if ids.numel():
        _write_back(out, ids, torch.ones_like(ids, dtype=torch.bool), x, lam_eq, lam_in, S)
    return tuple(out)


def _rows_index(ids: torch.Tensor, S: int) -> torch.Tensor:
    """The rows ``i S + t`` (t < S) of the items ``ids``, in order."""
    return (ids[:, None] * S + torch.arange(S, device=ids.device)).reshape(-1)


def _window(p: _Problem, sl: slice, S: int, fixed: int, ids: torch.Tensor, eq: _Constraints,
            ineq: _Constraints) -> _Window:
    """The window's constant data for the paths ``ids`` (of the rows of ``eq`` and ``ineq``)."""
    lay, wdt = p.layout, _SOLVE_DTYPE
    P, (F, n) = len(ids), lay.joints.shape
    rows = _rows_index(ids, S)
    eq, ineq = tree_map(lambda t: t[rows], eq), tree_map(lambda t: t[rows], ineq)
    valid = lay.valid.repeat(P, 1)
    live = (torch.arange(S, device=ids.device) >= fixed).repeat(P)[:, None]  # frames this window may change
    held = (~valid)[:, None, :].expand(P * F, S, n).clone()
    held[:, :fixed] = True
    H0, b0 = _quadratic_terms(p, sl, S, ids)
    return _Window(root=p.root[sl].repeat(P, 1, 1), eq=eq, ineq=ineq, m_eq=eq.mask & live, m_in=ineq.mask & live,
                   H0=H0, b0=b0, held=held, lo=lay.lo.to(wdt).repeat(P, 1)[:, None, :],
                   hi=lay.hi.to(wdt).repeat(P, 1)[:, None, :], paths=P, valid=valid)


def _subset(w: _Window, keep: torch.Tensor, S: int, F: int) -> _Window:
    """The window of the batch's paths ``keep`` (indices into it)."""
    r, b = _rows_index(keep, S), _rows_index(keep, F)
    return _Window(root=w.root[r], eq=tree_map(lambda t: t[r], w.eq), ineq=tree_map(lambda t: t[r], w.ineq),
                   m_eq=w.m_eq[r], m_in=w.m_in[r], H0=w.H0[b], b0=w.b0[b], held=w.held[b], lo=w.lo[b], hi=w.hi[b],
                   paths=len(keep), valid=w.valid[b])


def _paths_view(w: _Window, todo: torch.Tensor, S: int, F: int):
    """For the batch's paths ``todo``: their rows (len(todo) S,), their finger blocks (len(todo) F,), their window,
    and ``take(t, index)``, a tensor's entries at the index (``t`` itself when ``todo`` is every path)."""
    r, b = _rows_index(todo, S), _rows_index(todo, F)
    if len(todo) == w.paths:
        return r, b, w, lambda t, i: t
    return r, b, _subset(w, todo, S, F), lambda t, i: t[i]


def _write_back(out: list, ids: torch.Tensor, which: torch.Tensor, x, lam_eq, lam_in, S: int) -> None:
    """Put the batch's paths ``which`` (bool, per batch path) into ``out`` (x, lam_eq, lam_in of all paths)."""
    local = which.nonzero().squeeze(1)
    rows, own = _rows_index(ids[local], S), _rows_index(local, S)
    out[0][ids[local]] = x[local]
    out[1][rows] = lam_eq[own]
    out[2][rows] = lam_in[own]


def _path_max(v: torch.Tensor, mask: torch.Tensor, P: int) -> torch.Tensor:
    """Largest entry of v (R, C) where ``mask`` per path (rows p S .. p S + S - 1), (P,); 0 where none."""
    m = torch.where(mask, v, torch.full_like(v, -math.inf)).reshape(P, -1)
    if not m.shape[1]:
        return v.new_zeros(P)
    top = m.amax(1)                                   # NaN stays NaN (not met), as in a plain max
    return torch.where(top == -math.inf, torch.zeros_like(top), top)


def _gauss_newton_step(p: _Problem, w: _Window, xl, frozen, values, J_eq, c_eq, lam_eq, J_in, g_in, lam_in,
                       lam_v=None):
    """Minimiser of the window's linearised problem with ``frozen`` entries held at ``values`` (P F, S, n), and the
    model gradient there (P F, S, n).

    Which one-sided constraints are active is decided on the linear model, per path: start from those violated now
    and add those the solution would violate until the set stops growing (a point pushed out by one step must not
    be let go at the next and fall back in). A path whose set has stopped growing keeps that round's solve and
    leaves the rounds.
    """
    PF, S, n = xl.shape
    P = w.paths
    F = PF // P
    blocks, rhs = _constraint_terms(p, w, xl, w.eq, J_eq, c_eq, lam_eq, w.m_eq, None)
    H_eq = w.H0.clone()
    _add_block_diagonal(H_eq, blocks)
    b_eq = w.b0 + rhs.reshape(PF, S * n)
    normal = w.ineq.normal.to(_SOLVE_DTYPE)
    rows_in = (normal[..., None] * J_in).sum(2)  # (R, C, n)
    active = w.m_in & (lam_in / p.rho - g_in > 0)
    speed = lam_v is not None
    active_v = lam_v / p.rho_speed - speed_values(xl, p.joint_step) > 0 if speed else None
    # without one-sided constraints (and no speed bound) the first solve is the answer
    no_ineq = torch.zeros(P, dtype=torch.bool, device=xl.device) if speed else ~w.m_in.view(P, -1).any(1)
    out_sol, out_grad = xl.new_empty(PF, S * n), xl.new_empty(PF, S * n)
    todo = torch.arange(P, device=xl.device)                    # the paths whose active set may still grow
    for _ in range(_ACTIVE_SET_ROUNDS):
        r, b, ws, take = _paths_view(w, todo, S, F)
        xs, act, lam_s = take(xl, b), take(active, r), take(lam_v, b) if speed else None
        g, lam, nrm = take(g_in, r), take(lam_in, r), take(normal, r)
        blk_in, rhs_in = _constraint_terms(p, ws, xs, ws.ineq, take(J_in, r), g, lam, act, nrm)
        H = H_eq[b]                                             # a copy: the blocks are added in place
        _add_block_diagonal(H, blk_in)
        rhs_all = take(b_eq, b) + rhs_in.reshape(len(b), S * n)
        if speed:
            H_v, b_v = speed_terms(xs, ws.valid, p.joint_step, lam_s, p.rho_speed, take(active_v, b))
            H, rhs_all = H + H_v, rhs_all + b_v
        sol = _solve_frozen(H, rhs_all, take(frozen, b).reshape(-1, S * n), take(values, b).reshape(-1, S * n))
        out_sol[b] = sol
        out_grad[b] = (H @ sol.unsqueeze(-1)).squeeze(-1) - rhs_all
        stop = no_ineq[todo]
        if not bool(stop.all()):
            moved = _rows_of(sol.view(-1, S, n) - xs, len(todo)).gather(1, ws.ineq.finger[..., None].expand(-1, -1, n))
            grown = act | (ws.m_in & (lam / p.rho - (g + (take(rows_in, r) * moved).sum(-1)) > 0))
            same = (grown == act).view(len(todo), -1).all(1)
            if speed:
                grown_v = take(active_v, b) | (lam_s / p.rho_speed - speed_values(sol.view(-1, S, n), p.joint_step) > 0)
                same = same & (grown_v == take(active_v, b)).view(len(todo), -1).all(1)
                active_v = active_v.index_copy(0, b, grown_v)
            stop = stop | same
            active = active.index_copy(0, r, torch.where(stop.repeat_interleave(S)[:, None], act, grown))
        todo = todo[~stop]
        if not todo.numel():
            break
    return out_sol.view(PF, S, n), out_grad.view(PF, S, n)


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
    """Step length per finger, (P F, 1, 1): halved until the merit does not rise (0 if it always does). The
    Gauss–Newton model ignores the constraints' curvature, which dominates the weak priors in the directions the
    contacts leave free, so full steps can overshoot. A path is tried again only while one of its fingers' merit
    rose (a finger's merit depends on its own joints only)."""
    PF, S = xl.shape[:2]
    P = w.paths
    F = PF // P
    merit0 = _merit(p, w, xl, *residuals, lam_eq, lam_in, lam_v)
    alpha = xl.new_ones(PF, 1, 1)
    worse = torch.zeros(PF, dtype=torch.bool, device=xl.device)
    todo = torch.arange(P, device=xl.device)
    for _ in range(_BACKTRACK_STEPS):
        r, b, ws, take = _paths_view(w, todo, S, F)
        trial = take(xl, b) + take(alpha, b) * take(d, b)
        poses = p.hand.forward_kinematics(_to_global(take(x, todo), p.layout, trial).flatten(0, 1), ws.root)
        merit1 = _merit(p, ws, trial, *_residuals(ws.eq, ws.ineq, _positions(poses, ws.eq),
                                                  _positions(poses, ws.ineq)),
                        take(lam_eq, r), take(lam_in, r), take(lam_v, b) if lam_v is not None else None)
        m0 = take(merit0, b)
        rose = merit1 > m0 + 1e-12 * m0.abs()
        worse = worse.index_copy(0, b, rose)
        if not bool(rose.any()):
            break
        alpha = alpha.index_copy(0, b, torch.where(rose[:, None, None], take(alpha, b) / 2, take(alpha, b)))
        todo = todo[rose.view(len(todo), F).any(1)]
    # a finger whose merit still rose after the last halving takes no step (after a break, none did)
    return torch.where(worse[:, None, None], torch.zeros_like(alpha), alpha)


def _to_global(x: torch.Tensor, lay: _Layout, xl: torch.Tensor) -> torch.Tensor:
    """x (P, S, D) with the finger joints replaced by the finger-local values xl (P F, S, n)."""
    P, S = x.shape[:2]
    out = x.clone()
    out[:, :, lay.joints[lay.valid]] = xl.view(P, -1, S, xl.shape[-1]).permute(0, 2, 1, 3)[:, :, lay.valid].to(x.dtype)
    return out


def _to_local(x: torch.Tensor, lay: _Layout) -> torch.Tensor:
    """The finger-local joints (P F, S, n) of x (P, S, D) (padding slots hold joint 0)."""
    P, S = x.shape[:2]
    return x[:, :, lay.joints].permute(0, 2, 1, 3).reshape(P * lay.joints.shape[0], S, lay.joints.shape[1])


def _rows_of(v: torch.Tensor, P: int) -> torch.Tensor:
    """Finger-local v (P F, S, n) as rows (P S, F, n)."""
    PF, S, n = v.shape
    return v.view(P, PF // P, S, n).permute(0, 2, 1, 3).reshape(P * S, PF // P, n)


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
    """Augmented-Lagrangian merit of every finger's window, (P F,): the quadratic terms plus the constraint terms."""
    F = xl.shape[0]
    flat = xl.reshape(F, -1)
    value = 0.5 * (flat * (w.H0 @ flat.unsqueeze(-1)).squeeze(-1)).sum(-1) - (w.b0 * flat).sum(-1)
    pen_eq = 0.5 * p.rho * ((c_eq + lam_eq / p.rho) ** 2).sum(-1) * w.m_eq
    pen_in = 0.5 * p.rho * (lam_in / p.rho - g_in).clamp_min(0) ** 2 * w.m_in
    if lam_v is not None:
        value = value + speed_penalty(xl, w.valid, p.joint_step, lam_v, p.rho_speed)
    value = value.index_add(0, _block(w, w.eq.finger).reshape(-1), pen_eq.reshape(-1))
    return value.index_add(0, _block(w, w.ineq.finger).reshape(-1), pen_in.reshape(-1))


def _block(w: _Window, finger: torch.Tensor) -> torch.Tensor:
    """The finger-local block ``p F + f`` (R, C) of each row's constraint fingers ``finger`` (R, C)."""
    R = finger.shape[0]
    F = w.valid.shape[0] // w.paths
    if w.paths == 1:
        return finger
    path = torch.arange(R, device=finger.device) // (R // w.paths)
    return finger + (F * path)[:, None]


def _quadratic_terms(p: _Problem, sl: slice, S: int, ids: torch.Tensor):
    """The constant part of a window's normal equations: E1 (Eq. 10), w E2 (Eq. 11) and the priors, of the paths
    ``ids`` (P of them).

    returns H0 (P F, S n, S n) and b0 (P F, S n) in the time-major layout ``index = t * n + j``.
    """
    lay, wdt = p.layout, _SOLVE_DTYPE
    F, n = lay.joints.shape
    dev, P = lay.joints.device, len(ids)
    A = torch.zeros(max(S - 2, 0), S, dtype=wdt, device=dev)
    if S >= 3:
        r = torch.arange(S - 2, device=dev)
        A[r, r], A[r, r + 1], A[r, r + 2] = 1.0, -2.0, 1.0
    H0 = torch.kron(A.T @ A, torch.eye(n, dtype=wdt, device=dev)).expand(P * F, S * n, S * n).clone()
    e = lay.bend.to(wdt)
    bend = (p.bend_weight * e[:, :, None] * e[:, None, :])[:, None].expand(F, S, n, n).repeat(P, 1, 1, 1)
    valid = lay.valid.repeat(P, 1)
    w = p.prior_weight[ids][:, sl].to(wdt).permute(0, 2, 1).reshape(P * F, S)[:, :, None] * valid[:, None, :]
    blocks = bend + torch.diag_embed(w)
    _add_block_diagonal(H0, blocks)
    target = p.prior_target[ids][:, sl].to(wdt).permute(0, 2, 1, 3).reshape(P * F, S, n)
    b0 = (w * target).reshape(P * F, S * n)
    return H0, b0


def _add_block_diagonal(H: torch.Tensor, blocks: torch.Tensor) -> None:
    """H (F, S n, S n) += blockdiag over frames of ``blocks (F, S, n, n)``, in place."""
    F, S, n, _ = blocks.shape
    H.view(F, S, n, S, n).diagonal(dim1=1, dim2=3).add_(blocks.permute(0, 2, 3, 1))


def _linearise(p: _Problem, x: torch.Tensor, root: torch.Tensor, cons: tuple):
    """World positions (R, C, 3) and finger-local Jacobians (R, C, 3, n) of the points of each constraint set, for
    x (P, S, D) (R = P S rows).

    A link point's position and Jacobian are the affine combination of those of the link's origin and three axis
    points, which one batched Jacobian call gives for every link.
    """
    lay, wdt = p.layout, _SOLVE_DTYPE
    x = x.flatten(0, 1)
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


def _constraint_terms(p: _Problem, w: _Window, xl, con: _Constraints, Jl, c, lam, active, normal):
    """Normal-equation blocks (P F, S, n, n) and right-hand sides (P F, S, n) of the active point constraints
    (R = P S rows of C slots).

    Equalities (normal None) minimise rho/2 |c + lam/rho|^2 with c = p(q) - target, linearised; one-sided
    constraints g = normal . (p(q) - target) >= 0 minimise rho/2 (lam/rho - g)^2 where that is positive.
    """
    PF, S, n = xl.shape
    P = w.paths
    F, R = PF // P, P * S
    C = con.link.shape[1]
    if C == 0:
        return xl.new_zeros(PF, S, n, n), xl.new_zeros(PF, S, n)
    rows = Jl if normal is None else (normal[..., None] * Jl).sum(2, keepdim=True)  # (R, C, r, n)
    shift = c + lam / p.rho if normal is None else (c - lam / p.rho).unsqueeze(-1)  # (R, C, r)
    x_now = _rows_of(xl, P).gather(1, con.finger[..., None].expand(R, C, n))       # (R, C, n)
    a = active.to(xl.dtype)[..., None]
    rhs = p.rho * torch.einsum("scrn,scr->scn", rows, (rows @ x_now[..., None]).squeeze(-1) - shift) * a
    blk = p.rho * torch.einsum("scrn,scrm->scnm", rows, rows) * a[..., None]
    index = (torch.arange(R, device=xl.device)[:, None] * F + con.finger).reshape(-1)
    blocks = xl.new_zeros(R * F, n, n).index_add_(0, index, blk.reshape(R * C, n, n))
    vec = xl.new_zeros(R * F, n).index_add_(0, index, rhs.reshape(R * C, n))
    return (blocks.view(P, S, F, n, n).permute(0, 2, 1, 3, 4).reshape(PF, S, n, n),
            vec.view(P, S, F, n).permute(0, 2, 1, 3).reshape(PF, S, n))


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
        # never a product of one matrix (its last bits differ from the same one in a batch, kernels/_rows.py): the
        # answer of a path must not depend on the other paths of its batch
        j = at_least_two(bad.nonzero().squeeze(1))
        sol[j] = (torch.linalg.pinv(Hr[j], hermitian=True) @ b[j].unsqueeze(-1)).squeeze(-1)
    return sol
