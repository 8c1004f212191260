"""The kinematic test of the node test (:mod:`.node_test`): a damped least-squares solve of each hand's fingers onto
the guiding points, then the verdicts on joint limits, guide error and penetration."""

from __future__ import annotations

import torch

from torchhand.kernels._rows import at_least_two

from ..hand.collision import hand_object_penetration
from .problem import SynthesisProblem
from ._node_geometry import _finger_depth, _rotate, _transform, capsule_point_facing
from ._node_lm import lm_solve
from ._node_records import Guides, NodeTestSettings


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
        return lm_solve(problem, hand, root[rows], T_obj[rows], T_inv[rows], start, lo[rows], hi[rows], start,
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
