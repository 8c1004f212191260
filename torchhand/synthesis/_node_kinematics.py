"""The kinematic test of the node test (:mod:`.node_test`): a damped least-squares solve of each hand's fingers onto
the guiding points, then the verdicts on joint limits, guide error and penetration."""

from __future__ import annotations

import torch

from torchhand.kernels._rows import at_least_two

from ..hand.collision import hand_object_penetration
from .problem import SynthesisProblem
from ._node_geometry import _axis_points, _finger_depth, _rotate, _transform, capsule_point_facing
from ._node_records import Guides, NodeTestSettings


def _lm_solve(problem, hand, root, T_obj, T_inv, q, lo, hi, anchor, slot_link, slot_local, target, weight,
              nail_target, nail_on, iters: int, s: NodeTestSettings, roll=None) -> torch.Tensor:
    """Projected Levenberg–Marquardt on weighted point targets, the nail condition and non-penetration.

    root, T_obj, T_inv (N, 4, 4); q, lo, hi, anchor (N, D); slot_link (P,) long; slot_local (N, P, 3); target
    (N, P, 3) world; weight (N, P) (0 = slot unused); nail_target (N, F, 3) outward unit normals; nail_on (N, F);
    roll (N, P) bool or None: slots whose hand point is re-chosen every iteration as the point of the link's capsule
    facing the target (a rolling contact: the residual is the capsule's distance to it, ICP-like Gauss-Newton).
    Non-penetration: for points along every finger link's capsule axis, the one-sided residual
    max(0, radius + margin - sd(point)) with its SDF-gradient Jacobian.
    """
    N, D = q.shape
    F = hand.num_fingers
    P = slot_link.shape[0]
    nail_local = hand.fingertip + hand.nail_normal                      # (F, 3), distal frame
    ax_link, ax_local, ax_r = _axis_points(hand)
    link_all = torch.cat([slot_link, hand.distal_link, hand.distal_link, ax_link])
    eye = torch.eye(D, dtype=q.dtype, device=q.device)
    reg = s.reg_weight ** 2
    R_inv, t_inv = T_inv[:, None, :3, :3], T_inv[:, None, :3, 3]
    # The problem separates by finger (every joint moves one finger's links, every residual depends on one finger's
    # joints; the palm's slot is constant): damping and step acceptance are per finger (group F: what belongs to no
    # finger), so one finger's rejected step does not hold back the others, in one batched solve.
    G = F + 1
    lf = hand.link_finger
    table, ground = problem.table_height, problem.ground
    ax_group = torch.where(lf[ax_link] >= 0, lf[ax_link], F)
    solids = table is not None or ground is not None
    res_group = torch.cat([torch.where(lf[slot_link] >= 0, lf[slot_link], F).repeat_interleave(3),
                           torch.arange(F, device=q.device), ax_group] + ([ax_group] if solids else []))
    jf = hand.link_finger[hand.chain.joint_link]
    joint_group = torch.where(jf >= 0, jf, F)                            # (D,)
    free = (hi > lo).to(q.dtype)                                         # (N, D)
    lam = torch.full((N, G), 1e-4, dtype=q.dtype, device=q.device)
    best_q, best_cost = q, torch.full((N, G), float("inf"), dtype=q.dtype, device=q.device)
    stopped = torch.zeros(N, dtype=torch.bool, device=q.device)
    best_A = best_g = None
    for it in range(iters + 1):
        if roll is not None:
            facing = capsule_point_facing(hand, hand.forward_kinematics(q, root), slot_link.expand(N, P), target)
            slot_local = torch.where(roll[..., None], facing, slot_local)
        local = torch.cat([slot_local, hand.fingertip.expand(N, F, 3), nail_local.expand(N, F, 3),
                           ax_local.expand(N, ax_link.shape[0], 3)], 1)
        _, x, J = hand.kinematics(q, link_all, local, root)
        J = J * free[:, None, None, :]          # a joint whose box is a point (a locked wrist) couples no finger
        r = (x[:, :P] - target) * weight[..., None]                         # (N, P, 3)
        Jw = J[:, :P] * weight[..., None, None]
        g_vec = x[:, P + F:P + 2 * F] - x[:, P:P + F]                       # nail normals, world (N, F, 3)
        Jg = J[:, P + F:P + 2 * F] - J[:, P:P + F]                          # (N, F, 3, D)
        c = (g_vec * nail_target).sum(-1)                                   # (N, F)
        viol = nail_on & (c < s.nail_cos)
        rn = torch.where(viol, (c - s.nail_cos) * s.nail_weight, torch.zeros_like(c))
        Jn = (nail_target.unsqueeze(-1) * Jg).sum(-2) * (s.nail_weight * viol.to(q.dtype))[..., None]  # (N, F, D)
        xa = x[:, P + 2 * F:]
        sd, grad = problem.sdf.query_with_grad((R_inv @ xa.unsqueeze(-1)).squeeze(-1) + t_inv)
        g_world = (T_obj[:, None, :3, :3] @ grad.unsqueeze(-1)).squeeze(-1)
        ra = (ax_r + s.push_margin - sd).clamp_min(0)                       # (N, A)
        on = (ra > 0).to(q.dtype)
        Ja = -(g_world.unsqueeze(-1) * J[:, P + 2 * F:]).sum(-2) * on[..., None]   # (N, A, D)
        Jf, rf = [Jw.reshape(N, -1, D), Jn, Ja], [r.reshape(N, -1), rn, ra]
        if table is not None:
            # the table: every finger capsule stays above the plane z = table (one-sided, as the object)
            rt = (ax_r + s.push_margin - (xa[..., 2] - table)).clamp_min(0)         # (N, A)
            Jf.append(-J[:, P + 2 * F:, 2] * (rt > 0).to(q.dtype)[..., None])
            rf.append(rt)
        elif ground is not None:
            # a table block and a floor: the same, along the solids' outward normal
            gsd, gn = ground.point_distance(xa)                                     # (N, A), (N, A, 3)
            rt = (ax_r + s.push_margin - gsd).clamp_min(0)
            Jf.append(-(gn.unsqueeze(-1) * J[:, P + 2 * F:]).sum(-2) * (rt > 0).to(q.dtype)[..., None])
            rf.append(rt)
        Jf, rf = torch.cat(Jf, 1), torch.cat(rf, 1)
        cost = torch.zeros(N, G, dtype=q.dtype, device=q.device).index_add_(1, res_group, rf * rf)
        cost = cost.index_add_(1, joint_group, reg * (q - anchor) ** 2)   # (N, G)
        A = Jf.transpose(1, 2) @ Jf + reg * eye
        g = (Jf.transpose(1, 2) @ rf.unsqueeze(-1)).squeeze(-1) + reg * (q - anchor)
        better = cost <= best_cost                                          # (N, G)
        lam = torch.where(better, lam / 3, lam * 10).clamp(1e-9, 1e3)
        best_cost = torch.where(better, cost, best_cost)
        bj = better[:, joint_group] & ~stopped[:, None]                     # (N, D) per joint
        best_q = torch.where(bj, q, best_q)
        # A is block-diagonal by finger, so replacing whole rows keeps each finger's block consistent
        best_A = A if best_A is None else torch.where(bj[..., None], A, best_A)
        best_g = g if best_g is None else torch.where(bj, g, best_g)
        diag = best_A.diagonal(dim1=1, dim2=2)                              # (N, D)
        scale = torch.zeros(N, G, dtype=q.dtype, device=q.device).index_add_(1, joint_group, diag)
        count = torch.zeros(G, dtype=q.dtype, device=q.device).index_add_(0, joint_group, torch.ones_like(diag[0]))
        damp = (lam * scale / count.clamp_min(1))[:, joint_group] + s.damping     # (N, D)
        Ad = best_A + torch.diag_embed(damp)
        L, _ = torch.linalg.cholesky_ex(Ad)
        # two batched triangular solves (cholesky_solve on CUDA loops over the batch on the host)
        y = torch.linalg.solve_triangular(L, -best_g.unsqueeze(-1), upper=False)
        step = torch.linalg.solve_triangular(L.transpose(-1, -2), y, upper=True).squeeze(-1)
        q = torch.minimum(torch.maximum(best_q + step, lo), hi)
        # every 4 iterations a row whose steps fell below 1e-4 rad keeps its pose (its answer is its own, whatever
        # the other rows of the batch do); once all have: stop (a host sync)
        stopped = stopped | ((q - best_q).abs().amax(-1) < 1e-4) if it % 4 == 3 else stopped
        if it % 4 == 3 and bool(stopped.all()):
            break
    return best_q


def guide_targets(problem: SynthesisProblem, t: torch.Tensor, obj: torch.Tensor, s: NodeTestSettings):
    """World targets of guiding object points ``obj`` (N, F, 3, object frame) at frames t (N,), and the outward
    surface normals there (for the nail condition, Eq. 2): the hand point aims just outside the surface, where the
    capsules' non-penetration margin lets it be. Returns (target, normal), (N, F, 3) each."""
    T_obj = problem.object_pose[t]
    _, grad = problem.sdf.query_with_grad(obj)
    n_out = _rotate(T_obj[:, None], grad / grad.norm(dim=-1, keepdim=True).clamp_min(1e-9))
    return _transform(T_obj[:, None], obj) + s.push_margin * n_out, n_out


def rolled_local(problem: SynthesisProblem, t: torch.Tensor, q: torch.Tensor, guides: Guides,
                 s: NodeTestSettings) -> torch.Tensor:
    """The guiding hand points as the node test used them for poses q (N, H, D) at frames t: a rolling finger's
    is the point of its link's capsule facing its target, the others' their given point. (N, H, F, 3)."""
    out = guides.local.clone()
    if guides.roll is None:
        return out
    N = t.shape[0]
    rows = at_least_two(torch.arange(N, device=t.device))   # a batch of one would take other code paths
    t, q, obj, link = t[rows], q[rows], guides.obj[rows], guides.link[rows]
    for h, hand in enumerate(problem.hands):
        target, _ = guide_targets(problem, t, obj[:, h], s)
        facing = capsule_point_facing(hand, hand.forward_kinematics(q[:, h], problem.root[h, t]), link[:, h],
                                      target)[:N]
        out[:, h] = torch.where(guides.roll[:, h, :, None], facing, out[:, h])
    return out


def _hand_kinematic_test(problem: SynthesisProblem, h: int, t: torch.Tensor, q_prev: torch.Tensor,
                         first: torch.Tensor, guides: Guides, s: NodeTestSettings):
    """IK with penetration resolution for hand h. Returns q (N, D), link poses (N, L, 4, 4), guide error (N, F),
    and the penetration result of the final pose (all surface samples against the SDF)."""
    hand = problem.hands[h]
    N = t.shape[0]
    L, F, D = hand.num_links, hand.num_fingers, hand.num_joints
    dtype, device = q_prev.dtype, q_prev.device
    root = problem.root[h, t]
    T_obj = problem.object_pose[t]
    T_inv = problem.object_inv[t]
    lim = hand.joint_limits
    # Eq. 3's |q - q_prev| <= dq, lifted for every joint on the first frame (``first`` (N,)) and for the joints
    # of fingers that land on the object this frame (``first`` (N, H, F)): a free finger's path before it lands
    # carries no contact and is made smooth by the reconstruction (§6), so only where it lands is tested here.
    joint_finger = hand.link_finger[hand.chain.joint_link]              # (D,)
    if first.dim() == 1:
        lifted = first[:, None].expand(N, D)
    else:
        lifted = first[:, h].gather(1, joint_finger.clamp_min(0).expand(N, D)) & (joint_finger >= 0)
    # joints of unguided (free) fingers: start at q_prev moved toward rest (§6: free fingers assume a rest pose)
    # and move only as far as penetration resolution needs (the regularisation holds them there otherwise);
    # they may move ``dq_free`` per frame, since no contact constrains their path
    act = guides.active[:, h]                                           # (N, F)
    guided_joint = act.gather(1, joint_finger.clamp_min(0).expand(N, D)) & (joint_finger >= 0)
    dq = torch.where(lifted, torch.full_like(q_prev, 10.0),
                     torch.where(guided_joint, torch.full_like(q_prev, s.dq), torch.full_like(q_prev, s.dq_free)))
    lo = torch.maximum(lim[:, 0], q_prev - dq)
    hi = torch.minimum(lim[:, 1], q_prev + dq)
    q_free = torch.minimum(torch.maximum(hand.q_rest.expand(N, D), lo), hi)
    q_free = q_prev + 0.5 * (q_free - q_prev)
    q0 = torch.where(guided_joint, q_prev.clamp(lim[:, 0], lim[:, 1]), q_free)

    # guiding slots: one per link (the guide's link gets its point, weight 1)
    slot_link = torch.arange(L, device=device)
    onehot = torch.nn.functional.one_hot(guides.link[:, h], L).to(dtype) * act[..., None].to(dtype)   # (N, F, L)
    g_local = torch.einsum("nfl,nfc->nlc", onehot, guides.local[:, h])
    g_world, n_out = guide_targets(problem, t, guides.obj[:, h], s)     # (N, F, 3) each
    g_target = torch.einsum("nfl,nfc->nlc", onehot, g_world)
    g_weight = onehot.sum(1)                                             # (N, L)
    roll_f = None if guides.roll is None else guides.roll[:, h] & act   # (N, F)
    g_roll = None if roll_f is None else (onehot * roll_f[..., None].to(dtype)).sum(1) > 0       # (N, L)

    def solve(rows, start):
        return _lm_solve(problem, hand, root[rows], T_obj[rows], T_inv[rows], start, lo[rows], hi[rows], start,
                         slot_link, g_local[rows], g_target[rows], g_weight[rows], n_out[rows], act[rows],
                         s.ik_iters, s, roll=None if g_roll is None else g_roll[rows])

    q = solve(slice(None), q0)
    poses = hand.forward_kinematics(q, root)
    pen = hand_object_penetration(hand, poses, problem.sdf, T_obj)
    # A free finger that still penetrates started from a pose the object's motion brought into it (the rest pose
    # of a first frame, or the way toward rest), and Levenberg-Marquardt from inside a thin part (a mug handle)
    # finds no way out. Those rows are solved once more with the free fingers starting where nothing pulls them
    # into the object: the previous pose, or on a first frame the open hand. Fingers are independent in the IK
    # (every joint belongs to one finger), so each finger keeps the attempt in which it penetrates least.
    finger_depth = _finger_depth(hand, pen.deepest_value)
    retry = at_least_two(((finger_depth > s.pen_tol) & ~act).any(-1).nonzero().squeeze(-1))
    if retry.numel():
        R = retry.numel()
        open_q = torch.zeros(D, dtype=dtype, device=device).clamp(lim[:, 0], lim[:, 1])
        start_free = torch.where(lifted[retry], open_q.expand(R, D), q_prev[retry])
        start = torch.where(guided_joint[retry], q0[retry], start_free.clamp(lo[retry], hi[retry]))
        q2 = solve(retry, start)
        pen2 = hand_object_penetration(hand, hand.forward_kinematics(q2, root[retry]), problem.sdf, T_obj[retry])
        better = (_finger_depth(hand, pen2.deepest_value) < finger_depth[retry]) & ~act[retry]      # (R, F)
        take = better.gather(1, joint_finger.clamp_min(0).expand(R, D)) & (joint_finger >= 0)
        # only the retried rows change: their merged poses and penetration replace those rows
        q_r = torch.where(take, q2, q[retry])
        poses_r = hand.forward_kinematics(q_r, root[retry])
        pen_r = hand_object_penetration(hand, poses_r, problem.sdf, T_obj[retry])
        q, poses = q.index_copy(0, retry, q_r), poses.index_copy(0, retry, poses_r)
        pen = type(pen)(*(a.index_copy(0, retry, b) for a, b in zip(pen, pen_r)))
    tip_link = guides.link[:, h]
    T_g = poses.gather(1, tip_link[..., None, None].expand(N, F, 4, 4))
    g_local_f = guides.local[:, h]
    if roll_f is not None:
        g_local_f = torch.where(roll_f[..., None], capsule_point_facing(hand, poses, tip_link, g_world), g_local_f)
    err = (_transform(T_g, g_local_f) - g_world).norm(dim=-1) * act.to(dtype)
    return q, poses, err, pen
