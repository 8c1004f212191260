"""The node test of Ye & Liu 2012 §4.3, batched: kinematic test (IK, penetration resolution, finger–finger check,
contact collection) then dynamic test (friction-cone forces), for N candidate guiding configurations at once.

Each candidate n sits at its own frame ``t[n]`` with its own previous pose ``q_prev[n]``; all H hands of the scene
are solved together (their fingers are independent in the IK, their forces are solved jointly). Shapes: N
candidates, H hands, F fingers per hand, L links per hand, D finger joints per hand, K = H L + H F hand-contact
slots (one per link: the link's closest surface sample; then one area-contact proxy per fingertip, see
:func:`contact_slots`), E environment-contact slots.

IK (Eqs. 1–3) is a projected Levenberg–Marquardt on the guiding points, the nail-normal condition (Eq. 2, as a
one-sided penalty: nail · outward surface normal >= ``nail_cos``) and a weak pull toward q_prev, with the box
``max(limit_lo, q_prev - dq) <= q <= min(limit_hi, q_prev + dq)`` (Eq. 3 and the joint limits) enforced by
projection; damping and step acceptance are per finger (the problem separates by finger, so one finger's hard
target does not hold back the others). Free fingers that end inside the object are solved once more from the
previous pose (or, on a first frame, the open hand): from inside a thin part Levenberg–Marquardt finds no way out.
Penetration resolution (§4.3): deviation from the paper, which re-solves the IK a few times with the
deepest (hand point, surface point) pair of each colliding phalanx substituted in. Here every finger link's
collision capsule contributes one-sided residuals max(0, r + margin - sd) at points along its axis to the same
Levenberg–Marquardt problem, so penetration is resolved in one solve, for every finger link (the thumb's
metacarpal and the proximal phalanges too: in this hand they have 3- and 2-DOF joints and the wrist tracks often
bring them into the object), guided or free; the guiding point stays in the problem. The table is a collision constraint of the same kind
(deviation: the paper does not test hand against table): with a table in the scene, the same capsule-axis points
get one-sided residuals max(0, r + margin - (z - table)), and a link whose capsule reaches more than ``pen_tol``
below the plane fails its finger (the palm: the hand) in the kinematic test (:func:`table_depth`).

Contacts P: for every link, its surface sample with the smallest signed distance, when that distance is within
``contact_dist``; the contact point is that sample projected onto the object surface, the normal points into
the object. The dynamic test (Eqs. 4–8) solves the hand contacts and the object-table contacts together with the
friction-cone kernel (float64), sliding contacts restricted to their cone's boundary ray. Deviation: a frame whose
forces exceed ``max_force`` at any contact (30 N, or 5 times the object's weight) fails: the paper's objective
prefers small forces but accepts any; grips that balance only by squeezing with 100 N appeared on captured motion
and do not survive the mesh's exact normals in the final check.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from torchhand.kernels.frames import tangent_frame
from torchhand.kernels.friction_cone import solve_friction_cone
from torchhand.kernels.penetration import capsule_interpenetration
from torchhand.kernels.status import SolverStatus

from ..hand.collision import hand_object_penetration
from .exact import capsule_depth as link_capsule_depth, mesh_normals
from .reconstruct_bounds import table_depth as capsule_table_depth
from .problem import SynthesisProblem

__all__ = ["Guides", "NodeTestSettings", "FrameResult", "run_node_test", "evaluate_poses", "pad_points",
           "contact_slots", "table_depth", "CAUSE_NONE", "CAUSE_KINEMATIC", "CAUSE_FINGERS", "CAUSE_DYNAMIC"]

CAUSE_NONE, CAUSE_KINEMATIC, CAUSE_FINGERS, CAUSE_DYNAMIC = 0, 1, 2, 3
FORCE_ZERO, FORCE_INSIDE, FORCE_BOUNDARY = 0, 1, 2


@dataclass(frozen=True)
class Guides:
    """Guiding configurations c (Ye & Liu §3): at most one guiding point per finger, N candidates.

    active: finger has a guiding point, (N, H, F) bool
    link:   link (index within its hand) carrying the hand point p.h, (N, H, F) long
    local:  the hand point p.h in that link's frame, (N, H, F, 3), metres
    obj:    the object point p.o, (N, H, F, 3), object frame, metres
    slide:  unit direction in which p.o moves along the surface this frame (sliding contact), (N, H, F, 3), object
            frame; zeros for a static contact
    """

    active: torch.Tensor
    link: torch.Tensor
    local: torch.Tensor
    obj: torch.Tensor
    slide: torch.Tensor


@dataclass(frozen=True)
class NodeTestSettings:
    """Tolerances and iteration counts of the node test (metres, radians)."""

    dq: float = 0.3                # |q - q_prev| bound per frame (Eq. 3), radians
    dq_free: float = 0.6           # the same bound for fingers without a guiding point
    ik_iters: int = 20             # LM iterations
    ik_tol: float = 0.002          # a guiding point farther than this from its target fails the finger
    nail_cos: float = 0.0          # Eq. 2: nail . outward normal >= nail_cos
    nail_weight: float = 0.02      # metres per unit of nail misalignment
    reg_weight: float = 0.003      # pull toward the initial pose, metres per radian
    damping: float = 1e-7
    pen_tol: float = 0.001         # deepest allowed penetration of a link capsule (SDF), metres
    push_margin: float = 0.0003    # capsules are kept this far outside the surface, metres
    contact_dist: float = 0.0012   # a link's closest sample within this distance is a contact, metres
    finger_tol: float = 0.001      # finger-finger capsule overlap allowed, metres
    env_weight: float = 0.5        # objective weight of table contacts (Eq. 4); 0 makes the optimum degenerate
    balance_tol: float = 1e-3      # an unfinished force solve still counts when its wrench residual is below this
    #                                times the object's weight (forces are cone-feasible by construction)
    edge_proxies: bool = True      # area-contact proxies near sharp edges (Ye & Liu §7)
    proxy_radius: float = 0.003    # proxies are tried this far from a fingertip contact on the surface, metres
    proxy_cos: float = 0.9         # a proxy counts where its normal turns more than acos(proxy_cos) (~26 deg)
    proxy_dist: float = 0.0015     # ... and the fingertip's capsule is within this distance of it, metres
    boundary: float = 0.97         # |f_t| >= boundary mu f_n: the force is on the cone's boundary
    zero_force: float = 1e-3       # f_n below zero_force * weight: no force
    slide_speed: float = 0.02      # a held contact moving on the object faster than this slides, m/s
    cone_iters: int | None = 300   # iteration limit of the friction-cone solver (None: its default); a search
    #                                can drop the rare hard problem, the final check gives it more
    cone_polish: bool = True       # Newton polishing inside the friction-cone solver ...
    cone_polish_from: int | None = 250   # ... from this iteration on (of cone_iters = 300): plain ADMM settles
    #                                most search problems at cone_tol, Newton steps go to the slow ones only
    #                                (box-turn's search 1.4x faster than polishing from iteration 20; without
    #                                any polishing the ManipNet mug loses half its feasible frames to unfinished
    #                                solves)
    cone_tol: float | None = 1e-4  # its relative tolerance (None: its per-dtype default); the search needs the
    #                                verdict, not six digits; the final check of the pipeline uses the default
    exact: bool = False            # final-check mode: contact normals from the mesh (CPU, trimesh; :mod:`.exact`)
    max_force: float = 30.0        # a frame needing a larger force at any contact fails the dynamic test, newtons
    #                                (or max_force_weights times the object's weight, whichever is larger): a grip
    #                                that balances only by squeezing with 100 N is a degenerate contact set that the
    #                                mesh's exact normals no longer balance (Liu 2009 caps forces at 30 N too)
    max_force_weights: float = 5.0


@dataclass(frozen=True)
class FrameResult:
    """Outcome of the node test for N candidates.

    q:           finger joint angles, (N, H, D), radians
    feasible:    (N,) bool; cause: (N,) int, CAUSE_* of the first failure (kinematic > fingers > dynamic)
    kin_fail:    fingers that failed the kinematic test, (N, H, F) bool
    pair:        global finger indices (h F + f) of the deepest finger-finger overlap, (N, 2) long, -1 if none
    c_mask:      hand contacts, (N, K) bool, K = H L + H F (:func:`contact_slots`)
    c_local:     hand point of each contact in its link's frame, (N, K, 3); c_point: contact point on the object
                 surface, (N, K, 3) world; c_normal: into the object, (N, K, 3); c_force: force of the hand on the
                 object, (N, K, 3) world, newtons (zero unless the dynamic test ran and converged); c_sliding:
                 contacts held since the previous frame whose hand point slides on the object, (N, K) bool
    env_force:   (N, E, 3) world, newtons
    penetration: deepest penetration of any link capsule, (N,), metres (>= 0)
    guide_err:   distance of each guiding point from its target, (N, H, F), metres (0 where inactive)
    seed_*:      per finger, its most distal contact (Ye & Liu §4.2 seeds): seed_on (N, H, F) bool, seed_link
                 (N, H, F) long, seed_local (N, H, F, 3) link frame, seed_obj (N, H, F, 3) object frame,
                 seed_class (N, H, F) long FORCE_*, seed_tdir (N, H, F, 3) unit tangential force, object frame
    """

    q: torch.Tensor
    feasible: torch.Tensor
    cause: torch.Tensor
    kin_fail: torch.Tensor
    pair: torch.Tensor
    c_mask: torch.Tensor
    c_sliding: torch.Tensor
    c_local: torch.Tensor
    c_point: torch.Tensor
    c_normal: torch.Tensor
    c_force: torch.Tensor
    env_force: torch.Tensor
    penetration: torch.Tensor
    guide_err: torch.Tensor
    seed_on: torch.Tensor
    seed_link: torch.Tensor
    seed_local: torch.Tensor
    seed_obj: torch.Tensor
    seed_class: torch.Tensor
    seed_tdir: torch.Tensor


def _transform(T: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """T (..., 4, 4) applied to points p (..., 3)."""
    return (T[..., :3, :3] @ p.unsqueeze(-1)).squeeze(-1) + T[..., :3, 3]


def _rotate(T: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    return (T[..., :3, :3] @ v.unsqueeze(-1)).squeeze(-1)


def pad_points(hand) -> torch.Tensor:
    """The fingertip pads on the collision surface: ``hand.fingertip`` projected onto its distal link's capsule,
    (F, 3), distal-link frame, metres. The search guides these points, so a guided fingertip touches the object
    with the same surface the contact checks see."""
    a, b = hand.capsule_a[hand.distal_link], hand.capsule_b[hand.distal_link]
    r = hand.capsule_radius[hand.distal_link]
    tip = hand.fingertip
    u = (((tip - a) * (b - a)).sum(-1) / ((b - a) * (b - a)).sum(-1).clamp_min(1e-12)).clamp(0, 1)
    axis = a + u[:, None] * (b - a)
    d = tip - axis
    return axis + r[:, None] * d / d.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def contact_slots(problem: SynthesisProblem) -> tuple[torch.Tensor, torch.Tensor]:
    """The hand-contact slots of a node test's outputs: K = H L + H F. Slot ``h L + l`` is link l of hand h (its
    closest surface sample); slot ``H L + h F + f`` is the area-contact proxy of finger f's fingertip on hand h.
    Returns (hand (K,) long, link (K,) long: the link within its hand)."""
    F = problem.F
    hands, links = [], []
    for h, hand in enumerate(problem.hands):
        L = hand.num_links
        hands.append(torch.full((L,), h, dtype=torch.long))
        links.append(torch.arange(L))
    for h, hand in enumerate(problem.hands):
        hands.append(torch.full((F,), h, dtype=torch.long))
        links.append(hand.distal_link.cpu())
    return torch.cat(hands).to(problem.device), torch.cat(links).to(problem.device)


def _edge_proxies(problem: SynthesisProblem, t: torch.Tensor, hand, poses: torch.Tensor, on: torch.Tensor,
                  point: torch.Tensor, normal: torch.Tensor, s: NodeTestSettings):
    """Area-contact proxies near sharp edges (Ye & Liu §7): "forces on a few proxy points in the neighborhood of
    an actual contact point, capturing the local features of geometry".

    For each fingertip contact (on (N, F), point and normal (N, F, 3) world, normal into the object), four points
    ``proxy_radius`` away along the surface's tangent directions are projected onto the surface with the SDF; one
    counts where its normal turns by more than acos(``proxy_cos``) from the contact's (an edge or a corner is
    under the pad: on a flat face a proxy would add nothing) and the fingertip's capsule is within ``proxy_dist``
    of it (the pad covers it). The one whose normal turns most is kept. Returns mask (N, F), point (N, F, 3)
    world, normal (N, F, 3) into the object, local (N, F, 3) in the distal link's frame."""
    N, F = on.shape
    dl = hand.distal_link
    T_inv, T_obj = problem.object_inv[t], problem.object_pose[t]
    p0 = _transform(T_inv[:, None], point)                                  # object frame
    n0 = _rotate(T_inv[:, None], normal)
    t1, t2 = tangent_frame(n0 / n0.norm(dim=-1, keepdim=True).clamp_min(1e-9))
    x = p0[:, :, None] + s.proxy_radius * torch.stack([t1, -t1, t2, -t2], 2)    # (N, F, 4, 3)
    for _ in range(2):                                                      # onto the surface
        sd, g = problem.sdf.query_with_grad(x.reshape(N, -1, 3))
        g = g.reshape(x.shape)
        x = x - sd.reshape(x.shape[:-1])[..., None] * g / g.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    sd, g = problem.sdf.query_with_grad(x.reshape(N, -1, 3))
    n_in = -(g / g.norm(dim=-1, keepdim=True).clamp_min(1e-9)).reshape(x.shape)
    cos = (n_in * n0[:, :, None]).sum(-1)                                  # (N, F, 4)
    xw = _transform(T_obj[:, None, None], x)
    T_d = poses[:, dl]                                                      # (N, F, 4, 4)
    R_d, o_d = T_d[..., :3, :3], T_d[..., :3, 3]
    local = (R_d.transpose(-1, -2)[:, :, None] @ (xw - o_d[:, :, None]).unsqueeze(-1)).squeeze(-1)   # (N, F, 4, 3)
    a, b = hand.capsule_a[dl][:, None], hand.capsule_b[dl][:, None]         # (F, 1, 3)
    u = (((local - a) * (b - a)).sum(-1) / ((b - a) * (b - a)).sum(-1).clamp_min(1e-12)).clamp(0, 1)
    gap = (local - (a + u[..., None] * (b - a))).norm(dim=-1) - hand.capsule_radius[dl][:, None]
    ok = on[..., None] & (cos < s.proxy_cos) & (gap <= s.proxy_dist) & (gap >= -s.pen_tol) \
        & (sd.reshape(cos.shape).abs() <= 1e-4)
    pick = torch.where(ok, cos, torch.full_like(cos, 2.0)).argmin(-1, keepdim=True)   # (N, F, 1)
    mask = ok.any(-1)
    take = lambda v: v.gather(2, pick[..., None].expand(N, F, 1, 3)).squeeze(2)
    m3 = mask[..., None].to(point.dtype)
    return mask, take(xw) * m3, _rotate(T_obj[:, None], take(n_in)) * m3, take(local) * m3


def table_depth(problem: SynthesisProblem, hand, poses: torch.Tensor) -> torch.Tensor:
    """How far each link's collision capsule reaches below the table plane, (N, L) metres (<= 0 above it), from
    link poses (N, L, 4, 4). Zero everywhere without a table."""
    if problem.table_height is None:
        return poses.new_zeros(poses.shape[:2])
    return capsule_table_depth(hand, poses, problem.table_height)


def _finger_depth(hand, deepest_value: torch.Tensor) -> torch.Tensor:
    """Deepest penetration of each finger's links, (N, F) metres (>= 0), from a link's smallest signed distance
    ``deepest_value`` (N, L). A float scatter (CUDA has no scatter_reduce for bool)."""
    lf = hand.link_finger
    N = deepest_value.shape[0]
    depth = (-deepest_value).clamp_min(0) * (lf >= 0).to(deepest_value.dtype)
    return deepest_value.new_zeros(N, hand.num_fingers).scatter_reduce(1, lf.clamp_min(0).expand(N, -1), depth,
                                                                       reduce="amax")


def _axis_points(hand, per_link: int = 4):
    """Points along the capsule axis of every finger link: (link (P,) long, local (P, 3), radius (P,))."""
    links = hand.finger_links[hand.finger_links >= 0]
    u = torch.linspace(0, 1, per_link, dtype=hand.dtype, device=hand.device)
    a, b = hand.capsule_a[links], hand.capsule_b[links]                      # (M, 3)
    local = a[:, None] + u[None, :, None] * (b - a)[:, None]                 # (M, n, 3)
    return (links[:, None].expand(-1, per_link).reshape(-1), local.reshape(-1, 3),
            hand.capsule_radius[links][:, None].expand(-1, per_link).reshape(-1))


def _lm_solve(problem, hand, root, T_obj, T_inv, q, lo, hi, anchor, slot_link, slot_local, target, weight,
              nail_target, nail_on, iters: int, s: NodeTestSettings) -> torch.Tensor:
    """Projected Levenberg–Marquardt on weighted point targets, the nail condition and non-penetration.

    root, T_obj, T_inv (N, 4, 4); q, lo, hi, anchor (N, D); slot_link (P,) long; slot_local (N, P, 3); target
    (N, P, 3) world; weight (N, P) (0 = slot unused); nail_target (N, F, 3) outward unit normals; nail_on (N, F).
    Non-penetration: for points along every finger link's capsule axis, the one-sided residual
    max(0, radius + margin - sd(point)) with its SDF-gradient Jacobian.
    """
    N, D = q.shape
    F = hand.num_fingers
    P = slot_link.shape[0]
    nail_local = hand.fingertip + hand.nail_normal                      # (F, 3), distal frame
    ax_link, ax_local, ax_r = _axis_points(hand)
    A_ = ax_link.shape[0]
    link_all = torch.cat([slot_link, hand.distal_link, hand.distal_link, ax_link])
    eye = torch.eye(D, dtype=q.dtype, device=q.device)
    reg = s.reg_weight ** 2
    R_inv, t_inv = T_inv[:, None, :3, :3], T_inv[:, None, :3, 3]
    # The problem separates by finger: every joint moves one finger's links, and every residual depends on one
    # finger's joints (a guiding slot on its link, its nail, its capsule points; the palm's slot is constant).
    # So damping and step acceptance are per finger (group F collects what belongs to no finger): one finger's
    # rejected step does not hold back the others, as F independent solves would behave, in one batched solve.
    G = F + 1
    lf = hand.link_finger
    table = problem.table_height
    ax_group = torch.where(lf[ax_link] >= 0, lf[ax_link], F)
    res_group = torch.cat([torch.where(lf[slot_link] >= 0, lf[slot_link], F).repeat_interleave(3),
                           torch.arange(F, device=q.device), ax_group] + ([ax_group] if table is not None else []))
    jf = hand.link_finger[hand.chain.joint_link]
    joint_group = torch.where(jf >= 0, jf, F)                            # (D,)
    free = (hi > lo).to(q.dtype)                                         # (N, D)
    lam = torch.full((N, G), 1e-4, dtype=q.dtype, device=q.device)
    best_q, best_cost = q, torch.full((N, G), float("inf"), dtype=q.dtype, device=q.device)
    best_A = best_g = None
    for it in range(iters + 1):
        local = torch.cat([slot_local, hand.fingertip.expand(N, F, 3), nail_local.expand(N, F, 3),
                           ax_local.expand(N, A_, 3)], 1)
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
        Jf, rf = torch.cat(Jf, 1), torch.cat(rf, 1)
        cost = torch.zeros(N, G, dtype=q.dtype, device=q.device).index_add_(1, res_group, rf * rf)
        cost = cost.index_add_(1, joint_group, reg * (q - anchor) ** 2)   # (N, G)
        A = Jf.transpose(1, 2) @ Jf + reg * eye
        g = (Jf.transpose(1, 2) @ rf.unsqueeze(-1)).squeeze(-1) + reg * (q - anchor)
        better = cost <= best_cost                                          # (N, G)
        lam = torch.where(better, lam / 3, lam * 10).clamp(1e-9, 1e3)
        best_cost = torch.where(better, cost, best_cost)
        bj = better[:, joint_group]                                         # (N, D) per joint
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
        # converged everywhere (steps below 1e-4 rad): stop early; checked every 4 iterations (a host sync)
        if it % 4 == 3 and bool(((q - best_q).abs().amax() < 1e-4)):
            break
    return best_q


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
    g_world = _transform(T_obj[:, None], guides.obj[:, h])              # (N, F, 3)
    # nail condition (Eq. 2) against the outward normal at the target
    _, grad = problem.sdf.query_with_grad(guides.obj[:, h])
    n_out = _rotate(T_obj[:, None], grad / grad.norm(dim=-1, keepdim=True).clamp_min(1e-9))
    # the hand point aims just outside the surface, where the capsules' non-penetration margin lets it be
    g_world = g_world + s.push_margin * n_out
    g_target = torch.einsum("nfl,nfc->nlc", onehot, g_world)
    g_weight = onehot.sum(1)                                             # (N, L)

    def solve(rows, start):
        return _lm_solve(problem, hand, root[rows], T_obj[rows], T_inv[rows], start, lo[rows], hi[rows], start,
                         slot_link, g_local[rows], g_target[rows], g_weight[rows], n_out[rows], act[rows],
                         s.ik_iters, s)

    q = solve(slice(None), q0)
    poses = hand.forward_kinematics(q, root)
    pen = hand_object_penetration(hand, poses, problem.sdf, T_obj)
    # A free finger that still penetrates started from a pose the object's motion brought into it (the rest pose
    # of a first frame, or the way toward rest), and Levenberg-Marquardt from inside a thin part (a mug handle)
    # finds no way out. Those rows are solved once more with the free fingers starting where nothing pulls them
    # into the object: the previous pose, or on a first frame the open hand. Fingers are independent in the IK
    # (every joint belongs to one finger), so each finger keeps the attempt in which it penetrates least.
    finger_depth = _finger_depth(hand, pen.deepest_value)
    retry = ((finger_depth > s.pen_tol) & ~act).any(-1).nonzero().squeeze(-1)
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
    err = (_transform(T_g, guides.local[:, h]) - g_world).norm(dim=-1) * act.to(dtype)
    return q, poses, err, pen


def run_node_test(problem: SynthesisProblem, t: torch.Tensor, q_prev: torch.Tensor, first: torch.Tensor,
               guides: Guides, weights: torch.Tensor | None = None,
               settings: NodeTestSettings = NodeTestSettings(), dynamics: bool = True,
               prev_mask: torch.Tensor | None = None) -> FrameResult:
    """Kinematic and dynamic test of N candidates (see the module docstring).

    t: frame of each candidate, (N,) long; q_prev: previous pose, (N, H, D), radians; first: Eq. 3 is not applied,
    (N,) bool for whole candidates (no previous pose) or (N, H, F) bool per finger (fingers landing on the
    object); guides: :class:`Guides`; weights: objective weight of each hand contact's finger, (N, H, F) (default
    1; the palm's weight is 1); dynamics: False skips the dynamic test (forces zero, feasibility from the
    kinematic test alone); prev_mask: the hand contacts of the previous frame (pose ``q_prev`` at ``t - 1``),
    (N, K) bool, or None where there is no previous frame. A contact held over both frames whose hand point moves
    on the object faster than ``settings.slide_speed`` is sliding: its force must lie on the cone's boundary ray
    opposite the motion (the final check of the pipeline applies the same rule).
    """
    kin = [_hand_kinematic_test(problem, h, t, q_prev[:, h], first, guides, settings) for h in range(problem.H)]
    # sliding guided contacts: the object moves relative to the finger opposite to the contact's motion on it
    f64 = torch.float64
    slide_world = _rotate(problem.object_pose[t][:, None, None], guides.slide).to(f64)     # (N, H, F, 3)
    hand_slide = []
    for h in range(problem.H):
        L = problem.hands[h].num_links
        onehot = torch.nn.functional.one_hot(guides.link[:, h], L).to(f64) * guides.active[:, h, :, None].to(f64)
        hand_slide.append(-torch.einsum("nfl,nfc->nlc", onehot, slide_world[:, h]))
    prev = None if prev_mask is None else (q_prev, prev_mask)
    return _finish(problem, t, kin, torch.cat(hand_slide, 1), weights, settings, dynamics, prev)


def evaluate_poses(problem: SynthesisProblem, t: torch.Tensor, q: torch.Tensor, q_prev: torch.Tensor | None = None,
                   prev_mask: torch.Tensor | None = None,
                   settings: NodeTestSettings = NodeTestSettings(), dynamics: bool = True) -> FrameResult:
    """The contact and dynamic test of given poses, without IK (for reconstructed motion).

    t: (N,) frames; q: (N, H, D) radians; q_prev, prev_mask: the pose at ``t - 1`` (N, H, D) and its hand contacts
    (N, K) bool, for the sliding rule of :func:`run_node_test` (None: every contact static); dynamics: False
    collects the contacts only (forces zero, feasibility from the kinematic verdicts).
    """
    kin = []
    for h in range(problem.H):
        hand = problem.hands[h]
        poses = hand.forward_kinematics(q[:, h], problem.root[h, t])
        pen = hand_object_penetration(hand, poses, problem.sdf, problem.object_pose[t])
        kin.append((q[:, h], poses, q.new_zeros(t.shape[0], hand.num_fingers), pen))
    K = sum(hd.num_links for hd in problem.hands)                       # per-link slots (proxies: _finish)
    hand_slide = torch.zeros(t.shape[0], K, 3, dtype=torch.float64, device=q.device)
    prev = None if prev_mask is None else (q_prev, prev_mask)
    return _finish(problem, t, kin, hand_slide, None, settings, dynamics, prev)


def _motion_slide(problem: SynthesisProblem, t: torch.Tensor, q_prev: torch.Tensor, poses_now: list,
                  c_local: torch.Tensor, held: torch.Tensor, speed_tol: float):
    """Sliding of the contacts held since the previous frame: the hand point (``c_local``, fixed on its slot's link,
    :func:`contact_slots`) in the object frame at t - 1 (pose q_prev) and at t (link poses ``poses_now``, one
    (N, L, 4, 4) per hand). Returns the unit direction of the object's material point relative to the hand point,
    (N, K, 3) world float64 (zero where not sliding), and the sliding flags (N, K)."""
    slot_hand, slot_link = contact_slots(problem)
    tp = (t - 1).clamp_min(0)
    poses_prev = [hand.forward_kinematics(q_prev[:, h], problem.root[h, tp]) for h, hand in enumerate(problem.hands)]
    pos = []
    for when, hand_poses in ((tp, poses_prev), (t, poses_now)):
        world = torch.zeros_like(c_local)
        for h, poses in enumerate(hand_poses):
            sel = (slot_hand == h).nonzero().squeeze(-1)
            world[:, sel] = _transform(poses[:, slot_link[sel]], c_local[:, sel])
        pos.append(_transform(problem.object_inv[when][:, None], world))
    v_obj = (pos[1] - pos[0]) * problem.fps
    v_world = _rotate(problem.object_pose[t][:, None], v_obj).to(torch.float64)
    speed = v_world.norm(dim=-1)
    sliding = held & (speed > speed_tol)
    direction = torch.where(sliding[..., None], -v_world / speed.clamp_min(1e-12)[..., None],
                            torch.zeros_like(v_world))
    return direction, sliding


def _finish(problem: SynthesisProblem, t: torch.Tensor, kin: list, hand_slide: torch.Tensor,
            weights: torch.Tensor | None, s: NodeTestSettings, dynamics: bool, prev=None) -> FrameResult:
    """Kinematic verdicts, contact collection and the dynamic test from each hand's (q, poses, guide error,
    penetration)."""
    H, F = problem.H, problem.F
    N = t.shape[0]
    qs, kin_fail, errs, pens, c_mask, c_local, c_point, c_normal = [], [], [], [], [], [], [], []
    capsule_depth, capsule_pair = [], []
    link_weight = []
    for h in range(H):
        hand = problem.hands[h]
        L = hand.num_links
        q, poses, err, pen = kin[h]
        dtype, device = q.dtype, q.device
        lf = hand.link_finger                                                        # (L,)
        deep = pen.deepest_value                                                     # (N, L)
        fail = err > s.ik_tol                                                        # (N, F)
        # penetration by the links' capsules (the samples miss an edge pressing in between them, see .exact)
        cdepth = link_capsule_depth(hand, poses, problem.sdf, problem.object_inv[t])  # (N, L)
        fingers_deep = _finger_depth(hand, -cdepth) > s.pen_tol
        palm_deep = ((cdepth > s.pen_tol) & (lf < 0)).any(-1, keepdim=True)
        if problem.table_height is not None:
            # below the table: a link's capsule reaching deeper than pen_tol under the plane fails its finger
            # (or, for the palm, the hand)
            under = table_depth(problem, hand, poses) > s.pen_tol                    # (N, L)
            fingers_deep = fingers_deep | _finger_depth(hand, torch.where(under, -1.0, 0.0).to(deep.dtype)).bool()
            palm_deep = palm_deep | (under & (lf < 0)).any(-1, keepdim=True)
        fail = fail | fingers_deep | palm_deep
        kin_fail.append(fail)
        qs.append(q)
        errs.append(err)
        pens.append(cdepth.clamp_min(0).amax(-1))
        # finger-finger interpenetration (capsules)
        depth, _, _ = capsule_interpenetration(poses, hand.capsule_a, hand.capsule_b, hand.capsule_radius,
                                               hand.collision_pairs)
        capsule_depth.append(depth)
        capsule_pair.append(lf[hand.collision_pairs] + h * F)                      # (Q, 2)
        # contacts: each link's closest sample within contact_dist
        on = (deep <= s.contact_dist) & (deep >= -s.pen_tol)
        c_mask.append(on)
        c_local.append(hand.sample_points[pen.deepest_index.clamp_min(0)])
        c_point.append(pen.deepest_point - deep.clamp(-1, 1)[..., None] * pen.deepest_normal)
        c_normal.append(-pen.deepest_normal)
        w = torch.ones(N, L, dtype=dtype, device=device) if weights is None else \
            torch.where(lf >= 0, weights[:, h].gather(1, lf.clamp_min(0).expand(N, L)), torch.ones_like(deep))
        link_weight.append(w)
    # area-contact proxies of the fingertips (slots H L + h F + f), with their finger's weight and the sliding
    # direction of the fingertip's own slot
    proxy_slide = []
    for h in range(H):
        hand = problem.hands[h]
        L = hand.num_links
        dl = hand.distal_link
        if s.edge_proxies:
            pm, pp, pn, pl = _edge_proxies(problem, t, hand, kin[h][1], c_mask[h][:, dl], c_point[h][:, dl],
                                           c_normal[h][:, dl], s)
        else:
            pm = torch.zeros_like(c_mask[h][:, dl])
            pp = pn = pl = torch.zeros_like(c_point[h][:, dl])
        c_mask.append(pm)
        c_point.append(pp)
        c_normal.append(pn)
        c_local.append(pl)
        link_weight.append(link_weight[h][:, dl])
        proxy_slide.append(hand_slide[:, h * L + dl])
    hand_slide = torch.cat([hand_slide] + proxy_slide, 1)
    q = torch.stack(qs, 1)
    kin_fail = torch.stack(kin_fail, 1)
    guide_err = torch.stack(errs, 1)
    penetration = torch.stack(pens, 1).amax(1)
    c_mask, c_local = torch.cat(c_mask, 1), torch.cat(c_local, 1)
    c_point, c_normal = torch.cat(c_point, 1), torch.cat(c_normal, 1)
    depth = torch.cat(capsule_depth, 1)
    pairs = torch.cat(capsule_pair, 0)
    worst, which = depth.max(-1)
    fingers_bad = worst > s.finger_tol
    pair = torch.where(fingers_bad[:, None], pairs[which], torch.full_like(pairs[which], -1))
    kin_bad = kin_fail.flatten(1).any(-1)

    if s.exact and problem.mesh is not None:
        c_normal = _mesh_normals(problem, t, c_point, c_normal, c_mask)

    # --- sliding from the motion where the previous frame is known (it overrides the guides' intent there) ---
    c_sliding = torch.zeros_like(c_mask)
    if prev is not None:
        q_prev, prev_mask = prev
        held = c_mask & prev_mask
        direction, c_sliding = _motion_slide(problem, t, q_prev, [k[1] for k in kin], c_local, held,
                                             s.slide_speed)
        hand_slide = torch.where(held[..., None], direction, hand_slide)

    # --- dynamic test (Eqs. 4–8), float64, hand and table contacts together ----------------------------------
    K = c_mask.shape[1]
    E = problem.env.mask.shape[1]
    f64 = torch.float64
    com = problem.com[t].to(f64)
    env_on = problem.env.mask[t]
    pts = torch.cat([c_point.to(f64), problem.env.points[t].to(f64)], 1) - com[:, None]
    nrm = torch.cat([c_normal.to(f64), problem.env.normal.to(f64).expand(N, E, 3)], 1)
    mu = torch.cat([torch.full((N, K), problem.friction, dtype=f64, device=device),
                    torch.full((N, E), problem.env_friction, dtype=f64, device=device)], 1)
    w = torch.cat([torch.cat(link_weight, 1).to(f64), torch.full((N, E), s.env_weight, dtype=f64, device=device)], 1)
    env_slide = problem.env.sliding_velocity[t].to(f64)
    env_slide = env_slide / env_slide.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    mask = torch.cat([c_mask, env_on], 1)
    run = ~kin_bad & ~fingers_bad
    if not dynamics:
        run = torch.zeros_like(run)
    # only the candidates that passed the kinematic test are solved (a host sync; rows are gathered)
    rows = run.nonzero().squeeze(-1)
    forces = torch.zeros(N, K + E, 3, dtype=f64, device=device)
    dyn_ok = torch.zeros(N, dtype=torch.bool, device=device)
    if rows.numel():
        slide_all = torch.cat([hand_slide, env_slide], 1)
        res = solve_friction_cone(pts[rows], nrm[rows], mu[rows], problem.wrench[t[rows]].to(f64), mask=mask[rows],
                                  weights=w[rows], sliding_dir=slide_all[rows], max_iters=s.cone_iters,
                                  tol=s.cone_tol, polish=s.cone_polish, polish_from=s.cone_polish_from)
        ok = (res.status == int(SolverStatus.CONVERGED)) | (
            (res.status == int(SolverStatus.MAX_ITERATIONS)) & (res.residual <= s.balance_tol * problem.weight))
        cap = max(s.max_force, s.max_force_weights * problem.weight)
        ok = ok & (res.forces.norm(dim=-1).amax(-1) <= cap)
        dyn_ok[rows] = ok
        forces[rows] = res.forces
    forces = forces.to(dtype) * (run & dyn_ok)[:, None, None].to(dtype)
    c_force, env_force = forces[:, :K], forces[:, K:]
    cause = torch.where(kin_bad, CAUSE_KINEMATIC, torch.where(fingers_bad, CAUSE_FINGERS,
                        torch.where(dyn_ok | (not dynamics), CAUSE_NONE, CAUSE_DYNAMIC)))
    feasible = cause == CAUSE_NONE

    # --- seeds: the most distal contact of every finger ------------------------------------------------------
    seeds = _seeds(problem, t, c_mask, c_local, c_point, c_normal, c_force, s)
    return FrameResult(q=q, feasible=feasible, cause=cause, kin_fail=kin_fail, pair=pair, c_mask=c_mask,
                       c_sliding=c_sliding,
                       c_local=c_local, c_point=c_point, c_normal=c_normal, c_force=c_force, env_force=env_force,
                       penetration=penetration, guide_err=guide_err, **seeds)


def _mesh_normals(problem: SynthesisProblem, t: torch.Tensor, c_point: torch.Tensor, c_normal: torch.Tensor,
                  c_mask: torch.Tensor) -> torch.Tensor:
    """c_normal (N, K, 3) world with the active contacts' normals recomputed from the mesh (:mod:`.exact`)."""
    idx = c_mask.nonzero()
    if idx.shape[0] == 0:
        return c_normal
    n_, k_ = idx[:, 0], idx[:, 1]
    T_inv = problem.object_inv[t[n_]]
    p_obj = _transform(T_inv, c_point[n_, k_]).double().cpu().numpy()
    g_obj = _rotate(T_inv, c_normal[n_, k_]).double().cpu().numpy()
    exact = torch.as_tensor(mesh_normals(problem.mesh, p_obj, g_obj), dtype=c_normal.dtype, device=c_normal.device)
    out = c_normal.clone()
    out[n_, k_] = _rotate(problem.object_pose[t[n_]], exact)
    return out


def _seeds(problem, t, c_mask, c_local, c_point, c_normal, c_force, s: NodeTestSettings) -> dict:
    N = t.shape[0]
    H, F = problem.H, problem.F
    device = c_point.device
    T_inv = problem.object_inv[t]
    out = {k: [] for k in ("seed_on", "seed_link", "seed_local", "seed_obj", "seed_class", "seed_tdir")}
    for h in range(H):
        hand = problem.hands[h]
        L = hand.num_links
        fl = hand.finger_links                                                   # (F, 4) proximal -> distal
        sl = slice(h * L, (h + 1) * L)
        on = c_mask[:, sl][:, fl.clamp_min(0)] & (fl >= 0)                       # (N, F, 4)
        depth = torch.arange(fl.shape[1], device=device).expand_as(on)
        best = torch.where(on, depth, torch.full_like(depth, -1)).amax(-1)      # (N, F)
        seed_on = best >= 0
        link = fl.expand(N, F, -1).gather(2, best.clamp_min(0)[..., None]).squeeze(-1).clamp_min(0)   # (N, F)
        g3 = link[..., None].expand(N, F, 3)
        local = c_local[:, sl].gather(1, g3)
        point = c_point[:, sl].gather(1, g3)
        normal = c_normal[:, sl].gather(1, g3)
        force = c_force[:, sl].gather(1, g3)
        fn = (force * normal).sum(-1)
        ft = force - fn[..., None] * normal
        ftn = ft.norm(dim=-1)
        cls = torch.where(fn <= s.zero_force * problem.weight, FORCE_ZERO,
                          torch.where(ftn >= s.boundary * problem.friction * fn, FORCE_BOUNDARY, FORCE_INSIDE))
        tdir = _rotate(T_inv[:, None], ft / ftn.clamp_min(1e-12)[..., None])
        out["seed_on"].append(seed_on)
        out["seed_link"].append(link)
        out["seed_local"].append(local)
        out["seed_obj"].append(_transform(T_inv[:, None], point))
        out["seed_class"].append(cls)
        out["seed_tdir"].append(tdir)
    return {k: torch.stack(v, 1) for k, v in out.items()}
