"""The linearisation of Liu 2009's per-frame problem (Eq. 8) at (q, root, s), for :func:`.synth.synthesize_frame`:
residuals, constraint rows, bounds and the merit of a step, in stages over the frame's fixed set-up.

:class:`FrameSetup` holds what is fixed for the frame (the contacts, their capsules and tangents, the proximal
weights, the previous frame); :func:`linearise` returns a :class:`Linearisation`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ._frame_geometry import _closest_segment_points, _pad, rotvec
from ._frame_torques import ELASTIC_WEIGHT, SETTLE_WEIGHT, TOUCH_WEIGHT, _pose_batch, torques
from .torque_derivs import point_jacobian, torques_and_derivatives, tree_state

__all__ = ["FrameSetup", "Linearisation", "linearise"]


@dataclass(frozen=True)
class FrameSetup:
    """What one frame's linearisations share (see :func:`.synth.synthesize_frame` for each quantity). ``floor`` holds
    the non-penetration floors, filled by the frame's first linearisation and kept for the others."""

    H: object
    inertia: object
    Jp_const: object
    N: object
    R_prev: object
    Rs: object
    active: object
    analytic: object
    approach: object
    ca: object
    closing: object
    cr: object
    ctx: object
    d0: object
    dt: object
    f_use: object
    floor: object
    hand: object
    links: object
    movable: object
    nv: object
    os_: object
    prev: object
    s_prev: object
    s_step: object
    seg: object
    seg_len: object
    settle: object
    slide_dir: object
    st: object
    start: object
    tangents: object
    wq: object
    wx: object
    y_prev: object


@dataclass(frozen=True)
class Linearisation:
    """Eq. 8 linearised: objective residual ``r`` and Jacobian ``Jr``, proximal residual ``pr`` and ``Jp``, equality
    rows ``A``, ``b`` with weights ``w``, inequality rows ``C``, ``d`` (the first ``m_app`` the receding slack),
    step bounds ``vlo``, ``vhi``, the hand points ``h``, each contact's ``gap``, the ``objective``, the largest
    violation ``viol`` and the ``merit`` of the point."""

    r: np.ndarray
    Jr: np.ndarray
    pr: np.ndarray
    Jp: np.ndarray
    A: np.ndarray
    b: np.ndarray
    w: np.ndarray
    C: np.ndarray
    d: np.ndarray
    m_app: int
    vlo: np.ndarray
    vhi: np.ndarray
    h: np.ndarray
    gap: np.ndarray
    objective: float
    viol: float
    merit: float


def linearise(f: FrameSetup, q, root, s) -> Linearisation:
    """Residuals, constraints and bounds at (q, root, s); also the hand points h."""
    Rl, T, ax_w, c, cw, g_a, g_c, h, sd_a, sd_c, ts = _kinematics(f, q, root, s)
    Jp, Jr, pr, r, rv = _objective(f, Rl, h, q, root, s, ts)
    depth, depth_all, f_lks, f_pts, m_, near_f, pa, pb = _finger_pairs(f, T)
    J_all, Ja, Jc, Jm_pad, n_main, xm = _jacobians(f, Rl, T, ax_w, c, cw, f_lks, f_pts, m_, q, root, ts)
    A_rows, C_rows, G_rows, b_rows, d_rows, eq_viol, g_rows, in_viol, soft_J, soft_r, w_rows = _contact_rows(f, Jc, Jm_pad, Rl, cw, g_c, sd_c, xm)
    C_blocks, d_blocks = _penetration_rows(f, C_rows, G_rows, J_all, Ja, ax_w, d_rows, depth, depth_all, g_a, g_rows, in_viol, m_, n_main, near_f, pa, pb, sd_a)
    cr, ctx, dt, movable, nv, prev, s_prev, s_step, st = f.cr, f.ctx, f.dt, f.movable, f.nv, f.prev, f.s_prev, f.s_step, f.st
    # bounds: joint limits and speeds, root speeds, the axis parameter
    dq_max = st.joint_speed * dt * (1.0 - 1e-9)        # strictly inside: checkers compare with >
    lo = np.minimum(np.maximum(ctx.q_lo, prev.q - dq_max) - q, 0.0)
    hi = np.maximum(np.minimum(ctx.q_hi, prev.q + dq_max) - q, 0.0)
    s_lo = np.minimum(np.maximum(0.0, s_prev - s_step) - s, 0.0)
    s_hi = np.maximum(np.minimum(1.0, s_prev + s_step) - s, 0.0)
    vlo = np.concatenate([np.minimum(-st.root_rate * dt - rv, 0.0),
                                    np.minimum(prev.root[:3, 3] - st.root_speed * dt - root[:3, 3], 0.0), lo, s_lo])
    vhi = np.concatenate([np.maximum(st.root_rate * dt - rv, 0.0),
                                    np.maximum(prev.root[:3, 3] + st.root_speed * dt - root[:3, 3], 0.0), hi, s_hi])
    objective = float(r @ r) if st.objective == "torque" else float(((q - prev.q) ** 2).sum() + (rv ** 2).sum())
    if soft_r:
        pr, Jp = np.concatenate([pr, soft_r]), np.concatenate([Jp, np.array(soft_J)], 0)
    viol = max([0.0] + [float(v) for v in eq_viol] + [float(v) for v in in_viol])
    merit = (float(r @ r) + float(pr @ pr) + float(np.dot(w_rows, eq_viol))
             + ELASTIC_WEIGHT * sum(max(0.0, v) for v in in_viol))
    m_app = len(G_rows)
    return Linearisation(r=r, Jr=Jr, pr=pr, Jp=Jp, A=np.array(A_rows).reshape(-1, nv), b=np.array(b_rows), w=np.array(w_rows),
                          C=np.concatenate(C_blocks, 0), d=np.concatenate(d_blocks), m_app=m_app,
                          vlo=vlo, vhi=vhi, h=h,
                          gap=np.where(movable, sd_c - cr, sd_c),
                          objective=objective, viol=viol, merit=merit)


def _kinematics(f: FrameSetup, q, root, s):
    """One kinematics pass: link poses, the contacts' capsule axis points and the axis samples in the world, their
    signed distances and gradients, and the hand points h facing the object."""
    H, Rs, analytic, ca, cr, ctx, hand, links, movable, os_, seg, start = f.H, f.Rs, f.analytic, f.ca, f.cr, f.ctx, f.hand, f.links, f.movable, f.os_, f.seg, f.start
    ts = None
    c = np.where(movable[:, None], ca + s[:, None] * seg, start.h)    # axis points, link frame
    if analytic:                                                       # one kinematics pass serves all below
        ts = tree_state(ctx.order, q, root)
        T = ts.T
    else:
        T = hand.forward_kinematics(torch.as_tensor(q)[None], torch.as_tensor(root)[None])[0].numpy()
    Rl = T[links, :3, :3]
    cw = np.einsum("hij,hj->hi", Rl, c) + T[links, :3, 3]
    ax_w = np.einsum("pij,pj->pi", T[ctx.ax_link, :3, :3], ctx.ax_local) + T[ctx.ax_link, :3, 3]
    qpts = np.concatenate([cw, ax_w], 0)
    sd, grad = ctx.sdf_with_grad((qpts - os_) @ Rs)
    grad = grad @ Rs.T                                                 # world gradient
    sd_c, g_c, sd_a, g_a = sd[:H], grad[:H], sd[H:], grad[H:]
    n_c = g_c / np.maximum(np.linalg.norm(g_c, axis=-1, keepdims=True), 1e-12)
    h = np.where(movable[:, None], c - cr[:, None] * np.einsum("hji,hj->hi", Rl, n_c), start.h)
    return Rl, T, ax_w, c, cw, g_a, g_c, h, sd_a, sd_c, ts


def _objective(f: FrameSetup, Rl, h, q, root, s, ts):
    """The objective residual and its Jacobian (analytic, or forward differences in one batched call), and the
    proximal terms."""
    H, Jp_const, N, R_prev, analytic, ctx, f_use, hand, links, movable, nv, prev, s_prev, seg, seg_len, st, wq, wx = f.H, f.Jp_const, f.N, f.R_prev, f.analytic, f.ctx, f.f_use, f.hand, f.links, f.movable, f.nv, f.prev, f.s_prev, f.seg, f.seg_len, f.st, f.wq, f.wx
    # ---- the objective residual and its Jacobian (analytic, or forward differences in one batched call)
    if st.objective == "torque" and analytic:
        u, du_dx, du_dp = torques_and_derivatives(ctx.order, ts, links, h, f_use, ctx.gravity)
        r = u - ctx.u_bar
        Jr = np.zeros((N, nv))
        Jr[:, :N] = du_dx
        Jr[:, N:] = np.einsum("hnc,hc->nh", du_dp, np.einsum("hij,hj->hi", Rl, seg)) * movable[None]
    elif st.objective == "torque":
        Qb, Rb, Hb = _pose_batch(root, q, h, 1e-7, False)
        Hs = np.repeat(h[None], H, 0)
        Hs[np.arange(H), np.arange(H)] += 1e-7 * seg
        ub = torques(hand, np.concatenate([Qb, np.repeat(q[None], H, 0)]),
                     np.concatenate([Rb, np.repeat(root[None], H, 0)]), links, np.concatenate([Hb, Hs]), f_use,
                     ctx.gravity)
        r = ub[0] - ctx.u_bar
        Jr = ((ub[1:] - ub[0]) / 1e-7).T
        Jr[:, N:] *= movable[None]
    else:
        r, Jr = np.zeros(0), np.zeros((0, nv))
    if f.inertia is not None:                              # Eq. 5's M q_ddot + C, linearised at the frame's start
        r = r + f.inertia.residual(q, root)                # (set only with the torque objective)
        Jr[:, :N] += f.inertia.m_dt2
    rv = rotvec(root[:3, :3] @ R_prev.T)
    pr = np.concatenate([wq * rv, wx * (root[:3, 3] - prev.root[:3, 3]), wq * (q - prev.q),
                         st.prox_h * seg_len * (s - s_prev)])
    Jp = Jp_const
    return Jp, Jr, pr, r, rv


def _finger_pairs(f: FrameSetup, T):
    """Finger-finger pairs (addition (a)): capsule pairs of different fingers within 1 cm and their closest points."""
    ctx = f.ctx
    pa = pb = depth = f_pts = f_lks = None
    # ---- finger-finger pairs (addition (a)): capsule pairs of different fingers within 1 cm
    if len(ctx.pairs):
        i0, i1 = ctx.pairs_np[:, 0], ctx.pairs_np[:, 1]
        a0 = np.einsum("pij,pj->pi", T[i0, :3, :3], ctx.cap_a[i0]) + T[i0, :3, 3]
        b0 = np.einsum("pij,pj->pi", T[i0, :3, :3], ctx.cap_b[i0]) + T[i0, :3, 3]
        a1 = np.einsum("pij,pj->pi", T[i1, :3, :3], ctx.cap_a[i1]) + T[i1, :3, 3]
        b1 = np.einsum("pij,pj->pi", T[i1, :3, :3], ctx.cap_b[i1]) + T[i1, :3, 3]
        pa, pb = _closest_segment_points(a0, b0, a1, b1)
        depth = ctx.cap_r[i0] + ctx.cap_r[i1] - np.linalg.norm(pa - pb, axis=-1)
        near_f = np.flatnonzero(depth > -0.01)
        depth_all = depth
    else:
        near_f = np.zeros(0, dtype=np.int64)
        depth_all = None
    m_ = len(near_f)
    if m_:
        la, lb_ = ctx.pairs_np[near_f, 0], ctx.pairs_np[near_f, 1]
        f_pts = np.concatenate([pa[near_f], pb[near_f]], 0)
        f_lks = np.concatenate([la, lb_])
    return depth, depth_all, f_lks, f_pts, m_, near_f, pa, pb


def _jacobians(f: FrameSetup, Rl, T, ax_w, c, cw, f_lks, f_pts, m_, q, root, ts):
    """Point Jacobians of the contacts, the material points, the axis samples and the pairs' closest points (one
    call)."""
    H, analytic, ctx, hand, links, nv, prev = f.H, f.analytic, f.ctx, f.hand, f.links, f.nv, f.prev
    # ---- kinematics of the points involved (one point Jacobian call: contacts, material points, axis samples
    # and the pairs' closest points)
    xm = np.einsum("hij,hj->hi", Rl, prev.h) + T[links, :3, 3]
    pts_link = np.concatenate([links, links, ctx.ax_link])
    n_main = pts_link.shape[0]
    if analytic:
        if m_:
            J_all = point_jacobian(ctx.order, ts, np.concatenate([pts_link, f_lks]),
                                   np.concatenate([cw, xm, ax_w, f_pts], 0))
        else:
            J_all = point_jacobian(ctx.order, ts, pts_link, np.concatenate([cw, xm, ax_w], 0))
    else:
        pts_local = np.concatenate([c, prev.h, ctx.ax_local], 0)
        J_all = hand.point_jacobian(torch.as_tensor(q)[None], torch.as_tensor(pts_link),
                                    torch.as_tensor(pts_local), torch.as_tensor(root)[None],
                                    wrt_root=True)[0].numpy()
        if m_:
            loc = np.einsum("pji,pj->pi", T[f_lks, :3, :3], f_pts - T[f_lks, :3, 3])
            J_all = np.concatenate([J_all, hand.point_jacobian(
                torch.as_tensor(q)[None], torch.as_tensor(f_lks), torch.as_tensor(loc),
                torch.as_tensor(root)[None], wrt_root=True)[0].numpy()], 0)
    Jc, Jm, Ja = J_all[:H], J_all[H:2 * H], J_all[2 * H:n_main]
    Jm_pad = _pad(Jm, nv)
    return J_all, Ja, Jc, Jm_pad, n_main, xm


def _contact_rows(f: FrameSetup, Jc, Jm_pad, Rl, cw, g_c, sd_c, xm):
    """The contacts' rows: receding slack of added contacts, Eq. 6 (touch) and Eq. 7 (no slip, or sliding along the
    force), as equalities, inequalities or weighted residuals."""
    H, N, Rs, active, approach, closing, cr, d0, movable, nv, os_, prev, seg, settle, slide_dir, st, tangents, y_prev = f.H, f.N, f.Rs, f.active, f.approach, f.closing, f.cr, f.d0, f.movable, f.nv, f.os_, f.prev, f.seg, f.settle, f.slide_dir, f.st, f.tangents, f.y_prev
    A_rows, b_rows, C_rows, d_rows = [], [], [], []
    eq_viol, in_viol, soft_r, soft_J = [], [], [], []
    w_rows = []
    G_rows, g_rows = [], []                                 # receding-slack rows (elastic like the equalities)
    Jcf_all = np.zeros((H, 3, nv))
    Jcf_all[:, :, :N] = Jc
    for i in range(H):
        Jcf = Jcf_all[i]
        if movable[i]:
            Jcf[:, N + i] = Rl[i] @ seg[i]
        if i in approach:                                   # receding slack towards its object point
            gap = cw[i] - cr[i] * 0 - (prev.p[i] @ Rs.T + os_)
            gn = np.linalg.norm(gap)
            if gn > 1e-9:
                G_rows.append(gap / gn @ Jcf)
                g_rows.append(approach[i] - gn)
                in_viol.append(gn - approach[i])
            continue
        if not active[i]:
            continue
        if movable[i]:                                      # Eq. 6: the capsule touches the object
            row = g_c[i] @ Jcf
            A_rows.append(row)
            b_rows.append(cr[i] - sd_c[i])
            eq_viol.append(abs(cr[i] - sd_c[i]))
            w_rows.append(TOUCH_WEIGHT)
            # and, when elastic mode relaxes Eq. 6, it does so away from the object: the contact's own axis
            # point keeps the non-penetration bound of the axis samples (which may miss it between samples)
            C_rows.append(-row)
            d_rows.append(sd_c[i] - cr[i] - min(-st.margin, sd_c[i] - cr[i]))
        else:
            A_rows.append(g_c[i] @ Jcf)
            b_rows.append(-sd_c[i])
            eq_viol.append(abs(sd_c[i]))
            w_rows.append(TOUCH_WEIGHT)
        if closing[i]:
            continue
        # Eq. 7 on the material points of h^{k-1}
        rel = xm[i] - y_prev[i] - d0[i]
        Jrel = Jm_pad[i]
        t1, t2 = tangents[i]
        if i in slide_dir:
            fhat, t3 = slide_dir[i]
            v3, vf = t3 @ rel, fhat @ rel
            A_rows.append(t3 @ Jrel)
            b_rows.append(-v3)
            eq_viol.append(abs(v3))
            w_rows.append(ELASTIC_WEIGHT)
            C_rows.append(-fhat @ Jrel)
            d_rows.append(vf)
            in_viol.append(-vf)
        elif settle:                                         # soft: weighted residual rows
            for t in (t1, t2):
                soft_r.append(SETTLE_WEIGHT * (t @ rel))
                soft_J.append(SETTLE_WEIGHT * (t @ Jrel))
        else:
            for t in (t1, t2):
                v = t @ rel
                A_rows.append(t @ Jrel)
                b_rows.append(-v)
                eq_viol.append(abs(v))
                w_rows.append(ELASTIC_WEIGHT)
    return A_rows, C_rows, G_rows, b_rows, d_rows, eq_viol, g_rows, in_viol, soft_J, soft_r, w_rows


def _penetration_rows(f: FrameSetup, C_rows, G_rows, J_all, Ja, ax_w, d_rows, depth, depth_all, g_a, g_rows, in_viol, m_, n_main, near_f, pa, pb, sd_a):
    """The inequality rows in blocks: receding slack, the contacts' rows, non-penetration of the capsule axes
    (object, table) and finger-finger separation, with their floors fixed at the frame's first linearisation."""
    ctx, floor, nv, st = f.ctx, f.floor, f.nv, f.st
    # the inequality rows in blocks: receding slack first (the first m_app rows), then the contacts' rows
    C_blocks = [np.array(G_rows + C_rows).reshape(-1, nv)]
    d_blocks = [np.array(g_rows + d_rows, dtype=np.float64)]
    # non-penetration of the capsule axes (object and table); only points within 1 cm of their limit. The
    # floor (-margin, or the depth a point already had at the frame's start, which may not grow) is fixed at
    # the frame's first linearisation: a point that an iterate moved in from afar is pushed back out, and the
    # new depth counts as a violation in the merit (a step that creates it is rejected)
    ax_r = ctx.ax_radius
    lim_obj = sd_a - ax_r
    lim_tab = ax_w[:, 2] - ax_r - ctx.table if ctx.table is not None else None
    if not floor:
        floor["obj"] = np.minimum(-st.margin, lim_obj)
        floor["tab"] = np.minimum(-st.margin, lim_tab) if lim_tab is not None else None
        floor["ff"] = np.minimum(-st.margin, -depth_all) if depth_all is not None else None
    lb = floor["obj"]
    near = np.flatnonzero(lim_obj < 0.01)
    C_blocks.append(_pad(-np.einsum("pc,pcn->pn", g_a[near], Ja[near]), nv))
    d_blocks.append(lim_obj[near] - lb[near])
    pen = [np.maximum(lb - lim_obj, 0.0).max(initial=0.0)]
    if lim_tab is not None:
        lbt = floor["tab"]
        near = np.flatnonzero(lim_tab < 0.01)
        C_blocks.append(_pad(-Ja[near, 2], nv))
        d_blocks.append(lim_tab[near] - lbt[near])
        pen.append(np.maximum(lbt - lim_tab, 0.0).max(initial=0.0))
    # finger-finger separation (addition (a)): capsule pairs of different fingers within 1 cm keep their axis
    # distance >= r_a + r_b - margin along the line between their closest axis points; a pair already deeper
    # may not go deeper
    if m_:
        nrm = pa[near_f] - pb[near_f]
        nrm = nrm / np.maximum(np.linalg.norm(nrm, axis=-1, keepdims=True), 1e-12)
        Jf = J_all[n_main:]
        Jd = np.einsum("pc,pcn->pn", nrm, Jf[:m_] - Jf[m_:])
        sep = -depth[near_f]
        lbf = floor["ff"][near_f]
        C_blocks.append(_pad(-Jd, nv))
        d_blocks.append(sep - lbf)
        pen.append(np.maximum(lbf - sep, 0.0).max(initial=0.0))
    in_viol.extend(float(v) for v in pen)
    return C_blocks, d_blocks
