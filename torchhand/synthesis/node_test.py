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
below the plane fails its finger (the palm: the hand) in the kinematic test (:func:`table_depth`). A table with an
edge and a floor (``problem.ground``) work the same way with the solids' signed distance and outward normal.

Contacts P: for every link, its surface sample with the smallest signed distance (the grid's), when that
sample's exact distance (:meth:`~torchhand.geometry.sdf.SDFGrid.query_surface`: to the mesh's triangles nearest to
its grid cell) is within ``contact_dist``; the contact point is the closest point of the mesh, the normal the
mesh's there (a face's normal, or at an edge the normal cone's direction toward the sample), into the object. The
grid's trilinear normals leaned up to 30 degrees off a mug's faces at its rim and handle, which the final check
with the mesh's normals then refused. The dynamic test (Eqs. 4–8) solves the hand contacts and the object-table contacts together with the
friction-cone kernel (float64), sliding contacts restricted to their cone's boundary ray. Deviation: a frame whose
forces exceed ``max_force`` at any contact (30 N, or 5 times the object's weight) fails: the paper's objective
prefers small forces but accepts any; grips that balance only by squeezing with 100 N appeared on captured motion
and do not survive the mesh's exact normals in the final check.
"""

from __future__ import annotations

import dataclasses

import torch

from torchhand.kernels._rows import at_least_two
from torchhand.kernels.friction_cone import solve_friction_cone
from torchhand.kernels.penetration import capsule_interpenetration
from torchhand.kernels.status import SolverStatus

from ..hand.collision import hand_object_penetration
from ._node_geometry import (
    _edge_proxies,
    _finger_depth,
    _rotate,
    _transform,
    contact_slots,
    pad_points,
    surface_contacts,
    table_depth,
)
from ._node_kinematics import _hand_kinematic_test
from ._node_records import (
    CAUSE_DYNAMIC,
    CAUSE_FINGERS,
    CAUSE_KINEMATIC,
    CAUSE_NONE,
    FORCE_BOUNDARY,
    FORCE_INSIDE,
    FORCE_ZERO,
    FrameResult,
    Guides,
    NodeTestSettings,
)
from .exact import capsule_depth as link_capsule_depth
from .exact import mesh_normals
from .problem import SynthesisProblem

__all__ = ["Guides", "NodeTestSettings", "FrameResult", "run_node_test", "kinematic_verdicts", "evaluate_poses",
           "pad_points", "contact_slots", "table_depth", "CAUSE_NONE", "CAUSE_KINEMATIC", "CAUSE_FINGERS",
           "CAUSE_DYNAMIC"]


def run_node_test(problem: SynthesisProblem, t: torch.Tensor, q_prev: torch.Tensor, first: torch.Tensor,
               guides: Guides, weights: torch.Tensor | None = None,
               settings: NodeTestSettings = NodeTestSettings(), dynamics: bool = True,
               prev_mask: torch.Tensor | None = None, speeds: torch.Tensor | None = None) -> FrameResult:
    """Kinematic and dynamic test of N candidates (see the module docstring).

    t: frame of each candidate, (N,) long; q_prev: previous pose, (N, H, D), radians; first: Eq. 3 is not applied,
    (N,) bool for whole candidates (no previous pose) or (N, H, F) bool per finger (fingers landing on the
    object); guides: :class:`Guides`; weights: objective weight of each hand contact's finger, (N, H, F) (default
    1; the palm's weight is 1); dynamics: False skips the dynamic test (forces zero, feasibility from the
    kinematic test alone); prev_mask: the hand contacts of the previous frame (pose ``q_prev`` at ``t - 1``),
    (N, K) bool, or None where there is no previous frame. A contact held over both frames whose hand point moves
    on the object faster than ``settings.slide_speed`` is sliding: its force must lie on the cone's boundary ray
    opposite the motion (the final check of the pipeline applies the same rule). speeds: per row
    (``slide_speed``, ``table_slide_speed``), (N, 2) float64, in place of the settings' two (the searches of many
    windows tested together, :mod:`.multi`); None: the settings'.
    """
    if t.shape[0] == 1:     # a batch of one would take other code paths than the same row among others
        two = torch.zeros(2, dtype=torch.long, device=t.device)
        guides = guides.rows(two)
        res = run_node_test(problem, t[two], q_prev[two], first[two], guides, None if weights is None else
                            weights[two], settings, dynamics, None if prev_mask is None else prev_mask[two],
                            None if speeds is None else speeds[two])
        return FrameResult(**{f.name: getattr(res, f.name)[:1] for f in dataclasses.fields(res)})
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
    return _finish(problem, t, kin, torch.cat(hand_slide, 1), weights, settings, dynamics, prev, speeds)


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


def kinematic_verdicts(problem: SynthesisProblem, t: torch.Tensor, q_prev: torch.Tensor, first: torch.Tensor,
                       guides: Guides, settings: NodeTestSettings = NodeTestSettings()) -> torch.Tensor:
    """The kinematic test of :func:`run_node_test` alone, without the contacts and forces: ``kin_fail``, (N, H, F)
    bool, the same verdicts as :func:`run_node_test` gives (its arguments)."""
    if t.shape[0] == 1:     # a batch of one would take other code paths than the same row among others
        two = torch.zeros(2, dtype=torch.long, device=t.device)
        return kinematic_verdicts(problem, t[two], q_prev[two], first[two], guides.rows(two), settings)[:1]
    fails = []
    for h in range(problem.H):
        _, poses, err, _ = _hand_kinematic_test(problem, h, t, q_prev[:, h], first, guides, settings)
        fails.append(_kinematic_verdict(problem, problem.hands[h], t, poses, err, settings)[0])
    return torch.stack(fails, 1)


def _kinematic_verdict(problem: SynthesisProblem, hand, t: torch.Tensor, poses: torch.Tensor, err: torch.Tensor,
                       s: NodeTestSettings):
    """A hand's kinematic verdict per finger from its link poses (N, L, 4, 4) and guide error (N, F): the guide
    missed, a finger's capsule in the object (or the table), or the palm's (every finger fails). Returns (fail
    (N, F) bool, the links' capsule depth in the object (N, L))."""
    lf = hand.link_finger                                                        # (L,)
    fail = err > s.ik_tol                                                        # (N, F)
    # penetration by the links' capsules (the samples miss an edge pressing in between them, see .exact)
    cdepth = link_capsule_depth(hand, poses, problem.sdf, problem.object_inv[t])  # (N, L)
    fingers_deep = _finger_depth(hand, -cdepth) > s.pen_tol
    palm_deep = ((cdepth > s.pen_tol) & (lf < 0)).any(-1, keepdim=True)
    if problem.table_height is not None or problem.ground is not None:
        # below the table (into the table block, under the floor): a link's capsule reaching deeper than pen_tol
        # into them fails its finger (or, for the palm, the hand)
        under = table_depth(problem, hand, poses) > s.pen_tol                    # (N, L)
        fingers_deep = fingers_deep | _finger_depth(hand, torch.where(under, -1.0, 0.0).to(cdepth.dtype)).bool()
        palm_deep = palm_deep | (under & (lf < 0)).any(-1, keepdim=True)
    return fail | fingers_deep | palm_deep, cdepth


def _finish(problem: SynthesisProblem, t: torch.Tensor, kin: list, hand_slide: torch.Tensor,
            weights: torch.Tensor | None, s: NodeTestSettings, dynamics: bool, prev=None,
            speeds: torch.Tensor | None = None) -> FrameResult:
    """Kinematic verdicts, contact collection and the dynamic test from each hand's (q, poses, guide error,
    penetration); speeds: as :func:`run_node_test`'s."""
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
        fail, cdepth = _kinematic_verdict(problem, hand, t, poses, err, s)
        kin_fail.append(fail)
        qs.append(q)
        errs.append(err)
        pens.append(cdepth.clamp_min(0).amax(-1))
        # finger-finger interpenetration (capsules)
        depth, _, _ = capsule_interpenetration(poses, hand.capsule_a, hand.capsule_b, hand.capsule_radius,
                                               hand.collision_pairs)
        capsule_depth.append(depth)
        capsule_pair.append(lf[hand.collision_pairs] + h * F)                      # (Q, 2)
        # contacts: each link's closest sample within contact_dist, measured and projected exactly near the surface
        sd_c, point_c, normal_c = surface_contacts(problem, t, pen.deepest_point)
        on = (sd_c <= s.contact_dist) & (sd_c >= -s.pen_tol)
        c_mask.append(on)
        c_local.append(hand.sample_points[pen.deepest_index.clamp_min(0)])
        c_point.append(point_c)
        c_normal.append(normal_c)
        w = torch.ones(N, L, dtype=dtype, device=device) if weights is None else \
            torch.where(lf >= 0, weights[:, h].gather(1, lf.clamp_min(0).expand(N, L)), torch.ones_like(deep))
        link_weight.append(w)
    # area-contact proxies of the fingertips (slots H L + h F + f)
    hand_slide = _fingertip_proxies(problem, t, kin, c_mask, c_point, c_normal, c_local, link_weight, hand_slide, s)
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
                                             s.slide_speed if speeds is None else speeds[:, :1])
        hand_slide = torch.where(held[..., None], direction, hand_slide)

    # --- dynamic test (Eqs. 4–8), float64, hand and table contacts together ----------------------------------
    forces, dyn_ok = _dynamic_test(problem, t, c_point, c_normal, c_mask, link_weight, hand_slide, kin_bad,
                                   fingers_bad, dynamics, s, dtype,
                                   s.table_slide_speed if speeds is None else speeds[:, 1:, None])
    K = c_mask.shape[1]
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


def _fingertip_proxies(problem: SynthesisProblem, t: torch.Tensor, kin: list, c_mask: list, c_point: list,
                       c_normal: list, c_local: list, link_weight: list, hand_slide: torch.Tensor,
                       s: NodeTestSettings) -> torch.Tensor:
    """Area-contact proxies of the fingertips (slots H L + h F + f), appended to the contact lists, with their
    finger's weight and the sliding direction of the fingertip's own slot. Returns ``hand_slide`` with the proxies'
    directions appended."""
    H = problem.H
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
    return hand_slide


def _dynamic_test(problem: SynthesisProblem, t: torch.Tensor, c_point, c_normal, c_mask, link_weight: list,
                  hand_slide, kin_bad, fingers_bad, dynamics: bool, s: NodeTestSettings, dtype, table_tol):
    """The dynamic test (Eqs. 4–8) of the candidates that passed the kinematic test: the hand contacts and the
    object-table contacts solved together by the friction-cone kernel, float64. Returns the contact forces
    (N, K + E, 3) in ``dtype`` (zero where a test failed or did not run) and whether it passed, (N,) bool.
    table_tol: the table's slide speed, a number or (N, 1, 1)."""
    N, device = t.shape[0], c_point.device
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
    speed = env_slide.norm(dim=-1, keepdim=True)
    env_slide = torch.where(speed < table_tol, torch.zeros_like(env_slide),
                            env_slide / speed.clamp_min(1e-12))
    mask = torch.cat([c_mask, env_on], 1)
    run = ~kin_bad & ~fingers_bad
    if not dynamics:
        run = torch.zeros_like(run)
    # only the candidates that passed the kinematic test are solved (a host sync; rows are gathered)
    rows = at_least_two(run.nonzero().squeeze(-1))
    forces = torch.zeros(N, K + E, 3, dtype=f64, device=device)
    dyn_ok = torch.zeros(N, dtype=torch.bool, device=device)
    if rows.numel():
        slide_all = torch.cat([hand_slide, env_slide], 1)
        args = (pts[rows], nrm[rows], mu[rows], problem.wrench[t[rows]].to(f64))
        opts = dict(mask=mask[rows], weights=w[rows], sliding_dir=slide_all[rows])
        res = solve_friction_cone(*args, **opts, max_iters=s.cone_iters, tol=s.cone_tol, polish=s.cone_polish,
                                  polish_from=s.cone_polish_from)
        status, residual, res_forces = _resume_undecided(res, args, opts, s, problem.weight)
        ok = (status == int(SolverStatus.CONVERGED)) | (
            (status == int(SolverStatus.MAX_ITERATIONS)) & (residual <= s.balance_tol * problem.weight))
        cap = max(s.max_force, s.max_force_weights * problem.weight)
        ok = ok & (res_forces.norm(dim=-1).amax(-1) <= cap)
        dyn_ok[rows] = ok
        forces[rows] = res_forces
    forces = forces.to(dtype) * (run & dyn_ok)[:, None, None].to(dtype)
    return forces, dyn_ok


def _resume_undecided(res, args: tuple, opts: dict, s: NodeTestSettings, weight: float):
    """The status, residual and forces of the force solves ``res``, with those left undecided at the iteration cap
    (MAX_ITERATIONS with a residual above ``balance_tol`` times the weight) resumed from their forces for up to
    ``s.cone_retry_iters`` iterations of plain ADMM (on these slow problems Newton polishing costs 2.8 times as
    much for the same verdicts): a verdict is taken once a solve has converged, proved infeasibility or run its
    whole budget, not where a short cap happened to stop it."""
    status, residual, forces = res.status, res.residual, res.forces
    if s.cone_retry_iters is None:
        return status, residual, forces
    undecided = ((status == int(SolverStatus.MAX_ITERATIONS)) & (residual > s.balance_tol * weight)).nonzero()
    undecided = at_least_two(undecided.squeeze(-1))
    if not undecided.numel():
        return status, residual, forces
    sub = {k: v[undecided] for k, v in opts.items()}
    again = solve_friction_cone(*(a[undecided] for a in args), **sub, warm_start=forces[undecided],
                                max_iters=s.cone_retry_iters, tol=s.cone_tol, polish=False)
    status, residual, forces = status.clone(), residual.clone(), forces.clone()
    status[undecided], residual[undecided], forces[undecided] = again.status, again.residual, again.forces
    return status, residual, forces


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
