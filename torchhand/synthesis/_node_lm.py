"""The Levenberg–Marquardt solve of the node test's kinematic test (:mod:`._node_kinematics`), as an iteration
function over explicit state.

One iteration is a pure function of tensors (:func:`_iteration`), with no host synchronisation. On the CPU the
loop stops once every row has stopped (a check every 4 iterations); on a GPU it runs all iterations, captured once
per shape as a CUDA graph (:func:`torchhand.kernels.graphs.replayed`): a row that has stopped keeps its pose
either way, so the answer is the same whether the loop stops early or not.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import torch

from torchhand.kernels import kinematics as _kin
from torchhand.kernels.graphs import fixed_loops, replayed

from ..errors import InputValueError
from ._node_geometry import _axis_points, capsule_point_facing
from ._node_records import NodeTestSettings


class _State(NamedTuple):
    """Per-row iteration state: q, best_q (N, D); lam, best_cost (N, G); stopped (N,); best_A (N, D, D);
    best_g (N, D)."""

    q: torch.Tensor
    lam: torch.Tensor
    best_q: torch.Tensor
    best_cost: torch.Tensor
    stopped: torch.Tensor
    best_A: torch.Tensor
    best_g: torch.Tensor


class _Ref:
    """A key part naming an object by identity (and keeping it alive while the key is cached)."""

    def __init__(self, obj):
        self.obj = obj

    def __hash__(self):
        return id(self.obj)

    def __eq__(self, other):
        return isinstance(other, _Ref) and other.obj is self.obj


class _Const:
    """What an iteration reads besides its tensors: the hand, the problem's SDF and solids, the settings, and the
    index tensors derived from them (built once per solve)."""

    def __init__(self, problem, hand, slot_link: torch.Tensor, s: NodeTestSettings, dtype, device):
        F = hand.num_fingers
        self.hand, self.sdf, self.s = hand, problem.sdf, s
        self.table, self.ground = problem.table_height, problem.ground
        self.P, self.F, self.D = slot_link.shape[0], F, hand.num_joints
        self.slot_link = slot_link
        self.nail_local = hand.fingertip + hand.nail_normal                      # (F, 3), distal frame
        self.ax_link, self.ax_local, self.ax_r = _axis_points(hand)
        self.link_all = torch.cat([slot_link, hand.distal_link, hand.distal_link, self.ax_link])
        if self.link_all.numel() and device.type == "cpu" and (
                int(self.link_all.min()) < 0 or int(self.link_all.max()) >= hand.num_links):
            raise InputValueError(f"slot links must be in [0, {hand.num_links})")
        self.eye = torch.eye(self.D, dtype=dtype, device=device)
        # The problem separates by finger (every joint moves one finger's links, every residual depends on one
        # finger's joints; the palm's slot is constant): damping and step acceptance are per finger (group F:
        # what belongs to no finger), so one finger's rejected step does not hold back the others.
        self.G = F + 1
        lf = hand.link_finger
        ax_group = torch.where(lf[self.ax_link] >= 0, lf[self.ax_link], F)
        solids = self.table is not None or self.ground is not None
        self.res_group = torch.cat([torch.where(lf[slot_link] >= 0, lf[slot_link], F).repeat_interleave(3),
                                    torch.arange(F, device=device), ax_group] + ([ax_group] if solids else []))
        jf = hand.link_finger[hand.chain.joint_link]
        self.joint_group = torch.where(jf >= 0, jf, F)                           # (D,)
        self.count = torch.zeros(self.G, dtype=dtype, device=device).index_add_(
            0, self.joint_group, torch.ones(self.D, dtype=dtype, device=device))

    def key(self, iters: int, roll: bool) -> tuple:
        """The graph cache key: everything an iteration reads that is not one of its tensors. ``slot_link`` is
        every link of the hand (the only caller's), so the hand names it; the shapes complete the key."""
        return ("lm", _Ref(self.hand), _Ref(self.sdf), _Ref(self.ground), self.table, self.s, iters, roll)


def _points(c: _Const, q, root, slot_local, target, roll):
    """World positions (N, P + 2 F + A, 3) and Jacobian (N, P + 2 F + A, 3, D) at q of the slots' hand points,
    the fingertips, the nail points and the capsule-axis points."""
    hand, P, F = c.hand, c.P, c.F
    N = q.shape[0]
    if roll is not None:
        facing = capsule_point_facing(hand, hand.forward_kinematics(q, root), c.slot_link.expand(N, P), target)
        slot_local = torch.where(roll[..., None], facing, slot_local)
    local = torch.cat([slot_local, hand.fingertip.expand(N, F, 3), c.nail_local.expand(N, F, 3),
                       c.ax_local.expand(N, c.ax_link.shape[0], 3)], 1)
    _, x, J = _kin.fk_and_point_jacobian(hand.chain, q, root, c.link_all, local.to(q.dtype))
    return x, J


def _iteration(c: _Const, it: int, st: _State, root, T_obj, T_inv, lo, hi, anchor, free, slot_local, target,
               weight, nail_target, nail_on, roll) -> _State:
    """One projected Levenberg–Marquardt iteration (see :func:`lm_solve`); ``it`` the iteration's number."""
    s, P, F, D = c.s, c.P, c.F, c.D
    q = st.q
    N = q.shape[0]
    reg = s.reg_weight ** 2
    R_inv, t_inv = T_inv[:, None, :3, :3], T_inv[:, None, :3, 3]
    x, J = _points(c, q, root, slot_local, target, roll)
    J = J * free[:, None, None, :]          # a joint whose box is a point (a locked wrist) couples no finger
    r = (x[:, :P] - target) * weight[..., None]                         # (N, P, 3)
    Jw = J[:, :P] * weight[..., None, None]
    g_vec = x[:, P + F:P + 2 * F] - x[:, P:P + F]                       # nail normals, world (N, F, 3)
    Jg = J[:, P + F:P + 2 * F] - J[:, P:P + F]                          # (N, F, 3, D)
    cn = (g_vec * nail_target).sum(-1)                                  # (N, F)
    viol = nail_on & (cn < s.nail_cos)
    rn = torch.where(viol, (cn - s.nail_cos) * s.nail_weight, torch.zeros_like(cn))
    Jn = (nail_target.unsqueeze(-1) * Jg).sum(-2) * (s.nail_weight * viol.to(q.dtype))[..., None]  # (N, F, D)
    xa = x[:, P + 2 * F:]
    sd, grad = c.sdf.query_with_grad((R_inv @ xa.unsqueeze(-1)).squeeze(-1) + t_inv)
    g_world = (T_obj[:, None, :3, :3] @ grad.unsqueeze(-1)).squeeze(-1)
    ra = (c.ax_r + s.push_margin - sd).clamp_min(0)                     # (N, A)
    on = (ra > 0).to(q.dtype)
    Ja = -(g_world.unsqueeze(-1) * J[:, P + 2 * F:]).sum(-2) * on[..., None]   # (N, A, D)
    Jf, rf = [Jw.reshape(N, -1, D), Jn, Ja], [r.reshape(N, -1), rn, ra]
    if c.table is not None:
        # the table: every finger capsule stays above the plane z = table (one-sided, as the object)
        rt = (c.ax_r + s.push_margin - (xa[..., 2] - c.table)).clamp_min(0)       # (N, A)
        Jf.append(-J[:, P + 2 * F:, 2] * (rt > 0).to(q.dtype)[..., None])
        rf.append(rt)
    elif c.ground is not None:
        # a table block and a floor: the same, along the solids' outward normal
        gsd, gn = c.ground.point_distance(xa)                                     # (N, A), (N, A, 3)
        rt = (c.ax_r + s.push_margin - gsd).clamp_min(0)
        Jf.append(-(gn.unsqueeze(-1) * J[:, P + 2 * F:]).sum(-2) * (rt > 0).to(q.dtype)[..., None])
        rf.append(rt)
    Jf, rf = torch.cat(Jf, 1), torch.cat(rf, 1)
    cost = torch.zeros(N, c.G, dtype=q.dtype, device=q.device).index_add_(1, c.res_group, rf * rf)
    cost = cost.index_add_(1, c.joint_group, reg * (q - anchor) ** 2)   # (N, G)
    A = Jf.transpose(1, 2) @ Jf + reg * c.eye
    g = (Jf.transpose(1, 2) @ rf.unsqueeze(-1)).squeeze(-1) + reg * (q - anchor)
    better = cost <= st.best_cost                                       # (N, G)
    lam = torch.where(better, st.lam / 3, st.lam * 10).clamp(1e-9, 1e3)
    best_cost = torch.where(better, cost, st.best_cost)
    bj = better[:, c.joint_group] & ~st.stopped[:, None]                # (N, D) per joint
    best_q = torch.where(bj, q, st.best_q)
    # A is block-diagonal by finger, so replacing whole rows keeps each finger's block consistent
    best_A = A if it == 0 else torch.where(bj[..., None], A, st.best_A)
    best_g = g if it == 0 else torch.where(bj, g, st.best_g)
    diag = best_A.diagonal(dim1=1, dim2=2)                              # (N, D)
    scale = torch.zeros(N, c.G, dtype=q.dtype, device=q.device).index_add_(1, c.joint_group, diag)
    damp = (lam * scale / c.count.clamp_min(1))[:, c.joint_group] + s.damping     # (N, D)
    Ad = best_A + torch.diag_embed(damp)
    L, _ = torch.linalg.cholesky_ex(Ad)
    # two batched triangular solves (cholesky_solve on CUDA loops over the batch on the host)
    y = torch.linalg.solve_triangular(L, -best_g.unsqueeze(-1), upper=False)
    step = torch.linalg.solve_triangular(L.transpose(-1, -2), y, upper=True).squeeze(-1)
    q = torch.minimum(torch.maximum(best_q + step, lo), hi)
    # every 4 iterations a row whose steps fell below 1e-4 rad keeps its pose from then on (its answer is its
    # own, whatever the other rows of the batch do)
    stopped = st.stopped | ((q - best_q).abs().amax(-1) < 1e-4) if it % 4 == 3 else st.stopped
    return _State(q, lam, best_q, best_cost, stopped, best_A, best_g)


def lm_solve(problem, hand, root, T_obj, T_inv, q, lo, hi, anchor, slot_link, slot_local, target, weight,
             nail_target, nail_on, iters: int, s: NodeTestSettings, roll=None) -> torch.Tensor:
    """Projected Levenberg–Marquardt on weighted point targets, the nail condition and non-penetration; returns
    the best pose (N, D).

    root, T_obj, T_inv (N, 4, 4); q, lo, hi, anchor (N, D); slot_link (P,) long; slot_local (N, P, 3); target
    (N, P, 3) world; weight (N, P) (0 = slot unused); nail_target (N, F, 3) outward unit normals; nail_on (N, F);
    roll (N, P) bool or None: slots whose hand point is re-chosen every iteration as the point of the link's capsule
    facing the target (a rolling contact: the residual is the capsule's distance to it, ICP-like Gauss-Newton).
    Non-penetration: for points along every finger link's capsule axis, the one-sided residual
    max(0, radius + margin - sd(point)) with its SDF-gradient Jacobian.
    """
    N, D = q.shape
    c = _Const(problem, hand, slot_link, s, q.dtype, q.device)
    free = (hi > lo).to(q.dtype)                                         # (N, D)
    inf = torch.full((N, c.G), float("inf"), dtype=q.dtype, device=q.device)
    st = _State(q, torch.full((N, c.G), 1e-4, dtype=q.dtype, device=q.device), q, inf,
                torch.zeros(N, dtype=torch.bool, device=q.device), None, None)
    args = (root, T_obj, T_inv, lo, hi, anchor, free, slot_local, target, weight, nail_target, nail_on)
    if not fixed_loops(q.device):
        for it in range(iters + 1):
            st = _iteration(c, it, st, *args, roll)
            if it % 4 == 3 and bool(st.stopped.all()):       # every row keeps its pose from here on
                break
        return st.best_q
    # iteration 0 takes its A and g as they are: these zeros only give the graph its inputs' shapes
    st = st._replace(best_A=q.new_zeros(N, D, D), best_g=q.new_zeros(N, D))
    extra = () if roll is None else (roll,)
    return replayed(c.key(iters, roll is not None), functools.partial(_iterations, c, iters), *st, *args, *extra,
                    rows=N)


def _iterations(c: _Const, iters: int, *tensors) -> torch.Tensor:
    """Iterations 0 .. iters, all of them (no stop: see the module docstring); tensors: the 7 fields of
    :class:`_State`, the 12 arguments of :func:`_iteration`, and ``roll`` if any. Returns best_q (N, D)."""
    st, args = _State(*tensors[:7]), tensors[7:19]
    roll = tensors[19] if len(tensors) > 19 else None
    for it in range(iters + 1):
        st = _iteration(c, it, st, *args, roll)
    return st.best_q
