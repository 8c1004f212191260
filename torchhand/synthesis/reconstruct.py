"""Spacetime reconstruction of smooth finger motion from a searched contact path (Ye & Liu 2012, §6).

The search gives, per frame, a hand pose that satisfies that frame's contacts. :func:`reconstruct_motion` turns it
into smooth motion that keeps the contacts and does not penetrate the object, by solving Eq. 9::

    min_q  sum_t E1(t) + w E2(t)     subject to   f(q(t), p.h) = p.o(t)   for every kept contact

    E1(t) = |q(t+1) - 2 q(t) + q(t-1)|^2                              (Eq. 10, joint accelerations)
    E2(t) = sum_fingers (q_c(t) - 2 q_b(t) + q_a(t))^2                 (Eq. 11, a, b, c = ``hand.flexion_joints``)

Method
    * Fingers are independent: a finger's contacts depend only on its own joints (the palm is placed by ``root``),
      so every finger's trajectory is its own least-squares problem, and the F problems are solved as one batch.
    * Contacts are linearised with the analytic point Jacobian (Gauss–Newton); each linearised problem is a banded
      quadratic (E1 couples frames t-2..t+2, everything else couples joints of one frame), factorised exactly.
      Steps are backtracked on the merit function, per finger.
    * Contact equalities are a quadratic penalty with augmented-Lagrangian multipliers, updated whenever
      Gauss–Newton has converged with a contact still out of tolerance.
    * Joint limits are bounds handled by a primal active set: a joint that leaves its range is clamped and held at
      the bound until the model gradient points back inside.
    * Long motions are solved in overlapping windows of ``segment`` frames (see :func:`_smooth_sequence`).
    * Many paths: :func:`reconstruct_motions` solves P motions of one hand and root together, every decision taken
      per path (a converged path is held while the others go on), so each result is :func:`reconstruct_motion`'s.
    * Collisions (§6, last paragraph, with §4.3's deepest-point rule): after smoothing, the deepest capsule-axis point
      of every penetrating phalanx becomes a constraint of the next round, and so does the lower end of every capsule
      that reaches below the table (:mod:`.reconstruct_bounds`); rounds alternate until no penetration is left.
    * Joint speed: with ``max_joint_step`` every finger joint's step between frames is bounded, a linear inequality
      in the same augmented Lagrangian (:mod:`.reconstruct_bounds`).

Deviations from the paper
    * Weak priors: a non-free finger is pulled to its searched pose with ``search_weight`` and a free one to the
      rest pose with ``rest_weight`` (the paper uses these poses as the initial guess only). Without them the
      directions that neither the contacts nor E1 fix (a whole finger drifting at constant velocity) are free and
      the problem has no unique answer. Free fingers copying a neighbour's pose is not offered.
    * Contacts are a penalty with multipliers rather than hard equalities, so that unreachable targets degrade
      gracefully (reported as CONTACT_VIOLATED) instead of making the problem infeasible.
    * Collision constraints are one-sided (see :func:`_collision_constraints`), include proximal phalanges, and do
      not add §4.3's nail-normal alignment (Eq. 2).
    * Windows: the paper breaks long motions into segments without saying how they join; here each window starts
      with two frames fixed to the previous window's answer and ends with a look-ahead.
    * Each window's banded system is factorised as a dense matrix (the window bounds its size at ``segment * n``,
      n = joints of one finger); torch has no banded Cholesky.
    * Joints that move no finger link (none in the default hand) keep their searched values.

Conventions (:mod:`torchhand.conventions`): metres, radians, column-vector transforms ``p_world = T @ p_link``;
SDF negative inside; frames are the leading dimension ``T`` (one hand).
"""
from __future__ import annotations

import math

import torch

from .._tree import tree_map
from ..hand.collision import rigid_inverse
from ..conventions import check_finite, check_tensor, check_transforms
from ..errors import InputTypeError, InputValueError, ShapeError
from ..hand.model import HandModel
from ..geometry.sdf import SDFGrid
from .exact import capsule_penetration
from .reconstruct_bounds import (SPEED_MARGIN, finger_pair_parts, ground_capsule_depth, ground_constraint_parts,
                                 table_constraint_parts, table_depth)

__all__ = ["ContactTrack", "ReconstructStatus", "ReconstructResult", "reconstruct_motion", "reconstruct_motions"]
from ._reconstruct_records import (_Layout, _FRAME_SCALE, _SOLVE_DTYPE, _STEP_TOL, ContactTrack, ReconstructResult,
                                   ReconstructStatus, _Constraints, _finger_layout, _Problem)
from ._reconstruct_windows import _smooth_sequence


# ----------------------------------------------------------------------------------------------------------------
# Public entry point
# ----------------------------------------------------------------------------------------------------------------
def reconstruct_motion(
    hand: HandModel,
    root: torch.Tensor,
    q_search: torch.Tensor,
    contacts: ContactTrack,
    *,
    sdf: SDFGrid | None = None,
    object_pose: torch.Tensor | None = None,
    free: torch.Tensor | None = None,
    q_rest: torch.Tensor | None = None,
    bend_weight: float = 0.1,
    rest_weight: float = 1e-3,
    search_weight: float = 1e-3,
    contact_weight: float = 1e5,
    max_outer: int = 5,
    max_inner: int = 30,
    step_tol: float = _STEP_TOL,
    penetration_tol: float = 1e-3,
    contact_tol: float = 1e-3,
    segment: int = 60,
    check: bool = False,
    table_height: float | None = None,
    max_joint_step: float | None = None,
    finger_tol: float | None = None,
    ground=None,
) -> ReconstructResult:
    """Smooth a searched finger-motion path while keeping its contacts and removing penetration (Eqs. 9-11).

    hand:        the hand model; moved to ``q_search``'s device and dtype if needed
    root:        wrist poses ``T_world_root``, (T, 4, 4), world, metres
    q_search:    joint angles found by the search, (T, D), radians; the initial guess, and the pose a finger is
                 weakly held at while it is not free
    contacts:    :class:`ContactTrack` of T frames, same dtype and device as ``q_search``
    sdf:         the object's signed distance grid (object frame); with ``object_pose``, enables collision rounds
    object_pose: object poses ``T_world_object``, (T, 4, 4); required with ``sdf``
    free:        whether finger f is free (not in contact) at frame t, (T, F), bool; default: no masked contact
                 on any link of the finger in that frame
    q_rest:      rest pose free fingers are pulled to, (D,), radians; default ``hand.q_rest``
    bend_weight: w of Eq. 9 (Eq. 11's coupling of the flexion joints), dimensionless
    rest_weight: pull of a free finger to ``q_rest``, per frame and joint, dimensionless (relative to E1)
    search_weight: pull of a non-free finger to ``q_search``, per frame and joint; small, it only fixes the
                 directions the contacts and E1 leave free
    contact_weight: augmented-Lagrangian penalty of contact and collision constraints, 1/m^2 relative to E1
    max_outer:   most smoothing/collision rounds (>= 1)
    max_inner:   most Gauss–Newton steps per window and round (>= 1)
    step_tol:    Gauss–Newton has converged (for the current multipliers) when no joint moves more than this,
                 radians; the synthesis pipeline uses 1e-3 with ``max_inner=8`` (a quarter of the time, the same
                 smoothness on its scenes, and every result is checked again afterwards)
    penetration_tol: allowed penetration depth, metres
    contact_tol: allowed distance of a kept contact from its target, metres
    segment:     window length in frames (>= 8); consecutive windows overlap by ``segment // 3 + 2`` frames
    check:       also check inputs for NaN/inf and root/object poses for rigidity (forces a host sync)
    table_height: z of a table plane, world, metres: finger capsules are kept above it (collision rounds)
    max_joint_step: bound on |q[t+1] - q[t]| of every finger joint, radians (a joint-speed bound times the frame
                 time), a constraint of every window (:mod:`.reconstruct_bounds`)
    finger_tol:  with it, capsules of different fingers (``hand.collision_pairs``) that overlap by more than this
                 are pushed apart in the collision rounds, metres
    ground:      a table block and floor (:class:`~torchhand.geometry.ground.Ground`) kept clear, for ``table_height``
    returns:     :class:`ReconstructResult`

    Raises ShapeError / InputTypeError / InputValueError naming the argument on bad input.
    """
    return reconstruct_motions(
        hand, root, q_search[None] if isinstance(q_search, torch.Tensor) and q_search.dim() == 2 else q_search,
        [contacts], sdf=sdf, object_pose=object_pose, free=None if free is None else [free], q_rest=q_rest,
        bend_weight=bend_weight, rest_weight=rest_weight, search_weight=search_weight, contact_weight=contact_weight,
        max_outer=max_outer, max_inner=max_inner, step_tol=step_tol, penetration_tol=penetration_tol,
        contact_tol=contact_tol, segment=segment, check=check, table_height=table_height,
        max_joint_step=max_joint_step, finger_tol=finger_tol, ground=ground)[0]


def reconstruct_motions(hand: HandModel, root: torch.Tensor, q_search: torch.Tensor, contacts, *, sdf=None,
                        object_pose=None, free=None, q_rest=None, bend_weight: float = 0.1, rest_weight: float = 1e-3,
                        search_weight: float = 1e-3, contact_weight: float = 1e5, max_outer: int = 5,
                        max_inner: int = 30, step_tol: float = _STEP_TOL, penetration_tol: float = 1e-3,
                        contact_tol: float = 1e-3, segment: int = 60, check: bool = False,
                        table_height: float | None = None, max_joint_step: float | None = None,
                        finger_tol: float | None = None, ground=None) -> list[ReconstructResult]:
    """:func:`reconstruct_motion` of P paths of one hand in one root motion, solved together.

    q_search: (P, T, D) radians; contacts: P :class:`ContactTrack` of T frames and the same number of slots;
    free: None or P (T, F) bool masks; every other argument as :func:`reconstruct_motion`'s, shared by the paths.
    Returns the P results, each the one :func:`reconstruct_motion` gives its path alone: every decision of the solve
    (a window's convergence, multiplier steps, active sets, step lengths, collision rounds) is taken per path, and a
    path that is done is held while the others go on; the paths share every kernel call.
    """
    if not isinstance(q_search, torch.Tensor) or q_search.dim() != 3 or q_search.shape[0] < 1:
        raise ShapeError(f"q_search: expected shape (P, T, D) with P >= 1, got "
                         f"{tuple(q_search.shape) if isinstance(q_search, torch.Tensor) else type(q_search).__name__}")
    P = q_search.shape[0]
    contacts = list(contacts)
    if len(contacts) != P or (free is not None and len(free) != P):
        raise ShapeError(f"contacts, free: expected {P} (one per path), got {len(contacts)}"
                         f"{'' if free is None else f' and {len(free)}'}")
    checked = [_validate(hand, root, q_search[k], contacts[k], sdf, object_pose, None if free is None else free[k],
                         q_rest, check) for k in range(P)]
    if len({c[2].slots for c in checked}) > 1:
        raise ShapeError(f"contacts: expected the same number of slots for every path, got "
                         f"{sorted({c[2].slots for c in checked})}")
    _, root, _, object_pose, _, q_rest, hand, sdf = checked[0]
    _check_settings(nonnegative=dict(bend_weight=bend_weight, rest_weight=rest_weight, search_weight=search_weight),
                    positive=dict(contact_weight=contact_weight, penetration_tol=penetration_tol,
                                  contact_tol=contact_tol, step_tol=step_tol),
                    counts=dict(max_outer=(max_outer, 1), max_inner=(max_inner, 1), segment=(segment, 8)))
    tracks = [c[2] for c in checked]
    T, F = q_search.shape[1], hand.num_fingers
    layout = _finger_layout(hand)
    q_rest = hand.clamp_to_limits(q_rest[None])[0]
    q = hand.clamp_to_limits(torch.stack([c[0] for c in checked]).flatten(0, 1)).view(P, T, -1)

    problem, eq, lam_eq, ineq, lam_in = _build_problem(
        hand, layout, root, q, q_rest, torch.stack([c[4] for c in checked]), tracks, bend_weight=bend_weight,
        rest_weight=rest_weight, search_weight=search_weight, contact_weight=contact_weight, contact_tol=contact_tol,
        penetration_tol=penetration_tol, max_inner=max_inner, step_tol=step_tol, max_joint_step=max_joint_step)
    # Collision points are pushed this far past the surface, so that the next round finds the capsule outside.
    margin = 0.5 * penetration_tol

    penetration = q.new_zeros(P, T)
    object_inv = None if object_pose is None else rigid_inverse(object_pose)
    table = ground if ground is not None else table_height
    running = torch.ones(P, dtype=torch.bool, device=q.device)
    rounds = [0] * P
    for r in range(1, max_outer + 1):
        rounds = [r if go else k for go, k in zip(running.tolist(), rounds)]
        if F > 0:
            q, lam_eq, lam_in = _smooth_sequence(problem, q, eq, ineq, lam_eq, lam_in, segment, running)
        if sdf is None and table is None and finger_tol is None:
            break
        new, pen, over = _collision_round(hand, layout, q, root, sdf, object_pose, object_inv, table, finger_tol,
                                          margin)
        penetration = torch.where(running[:, None], pen, penetration)
        kept = [c.mask.flatten(1).any(1) for c in new]          # per path: blocks with a constraint
        go_on = running & (over | (pen > penetration_tol).any(1)) & torch.stack(kept).any(0) if kept else \
            torch.zeros_like(running)
        if r == max_outer or not bool(go_on.any()):
            break
        # what penetrates where no block has a constraint is the palm or a palm-level link: the root pose places it
        for c, has in zip(new, kept):
            ineq = ineq.cat(_masked(c, (has & go_on)[:, None, None]))
            lam_in = torch.cat([lam_in, lam_in.new_zeros(P, T, c.mask.shape[2])], dim=2)
        running = go_on

    return [_result(problem, q[k], tracks[k], penetration[k], rounds[k]) for k in range(P)]


def _masked(c: _Constraints, keep: torch.Tensor) -> _Constraints:
    """Constraints (P, T, C) with only the slots where ``keep`` (broadcast to (P, T, C)) stays set; the others hold
    zeros (they add exact zeros to the normal equations and the merit)."""
    mask = c.mask & keep
    zero = lambda t: torch.where(mask[..., None], t, torch.zeros_like(t))  # noqa: E731
    return _Constraints(link=c.link, finger=c.finger, local=zero(c.local), target=zero(c.target), mask=mask,
                        normal=zero(c.normal))


def _build_problem(hand, layout, root, q, q_rest, free, contacts, *, bend_weight, rest_weight, search_weight,
                   contact_weight, contact_tol, penetration_tol, max_inner, step_tol, max_joint_step):
    """The smoothing problem of :func:`reconstruct_motions` for q (P, T, D), free (P, T, F) and P contact tracks: the
    prior pose per path, frame and finger, the settings, the contact constraints (equalities) and no collision
    constraints yet, with zero multipliers. Returns problem, eq, lam_eq, ineq, lam_in (all (P, T, ...))."""
    P, T, dt, dev = q.shape[0], q.shape[1], q.dtype, q.device
    # Prior pose per frame and finger (Deviation from the paper: see the module docstring).
    F = hand.num_fingers
    free_l = free.unsqueeze(-1)
    prior_target = torch.where(free_l, q_rest[layout.joints].expand(P, T, F, -1), q[:, :, layout.joints])
    prior_weight = torch.where(free, q.new_tensor(rest_weight), q.new_tensor(search_weight))
    L = hand.num_links
    eye = torch.cat([torch.zeros(1, 3, dtype=dt, device=dev), _FRAME_SCALE * torch.eye(3, dtype=dt, device=dev)])
    problem = _Problem(hand=hand, layout=layout, root=root, prior_target=prior_target, prior_weight=prior_weight,
                       bend_weight=float(bend_weight), rho=float(contact_weight), contact_tol=float(contact_tol),
                       penetration_tol=float(penetration_tol), max_inner=max_inner, step_tol=float(step_tol),
                       frame_links=torch.arange(L, device=dev).repeat_interleave(4), frame_points=eye.repeat(L, 1),
                       joint_step=None if max_joint_step is None else SPEED_MARGIN * float(max_joint_step))

    link, mask = torch.stack([c.link for c in contacts]), torch.stack([c.mask for c in contacts])
    point_local, target = torch.stack([c.point_local for c in contacts]), torch.stack([c.target for c in contacts])
    link_safe = link.clamp(0, L - 1)
    finger = hand.link_finger[link_safe]
    used = mask[..., None]  # padding slots may hold anything, NaN included
    eq = _Constraints(link=link_safe, finger=finger.clamp(min=0), mask=mask & (finger >= 0),
                      local=torch.where(used, point_local, torch.zeros_like(point_local)),
                      target=torch.where(used, target, torch.zeros_like(target)))
    lam_eq = q.new_zeros(P, T, link.shape[2], 3, dtype=_SOLVE_DTYPE)
    ineq = _per_path(_collision_constraints(hand, layout, None, 0.0, q.flatten(0, 1)), P)  # none yet
    lam_in = q.new_zeros(P, T, 0, dtype=_SOLVE_DTYPE)
    return problem, eq, lam_eq, ineq, lam_in


def _per_path(c: _Constraints, P: int) -> _Constraints:
    """Constraints of P T rows as (P, T, ...)."""
    return tree_map(lambda t: t.view(P, t.shape[0] // P, *t.shape[1:]), c)


def _collision_round(hand, layout, q, root, sdf, object_pose, object_inv, table, finger_tol, margin):
    """One collision round of :func:`reconstruct_motions`: the penetration of the smoothed motions q (P, T, D) (object,
    table) and the new inequality constraints that push capsules out (object, table, other fingers). ``table``: a
    table height, a :class:`~torchhand.geometry.ground.Ground` or None. Returns the new constraint blocks
    (P, T, ...), the penetration per path and frame (P, T) and whether a path's fingers overlap beyond
    ``finger_tol`` (P,) bool."""
    P = q.shape[0]
    q = q.flatten(0, 1)
    T = q.shape[0]                                   # rows: P T
    root = root.repeat(P, 1, 1)
    if object_pose is not None:
        object_pose, object_inv = object_pose.repeat(P, 1, 1), object_inv.repeat(P, 1, 1)
    poses = hand.forward_kinematics(q, root)
    new = []
    penetration = q.new_zeros(T)
    if sdf is not None:
        pen = capsule_penetration(hand, poses, sdf, object_pose, object_inv)
        penetration = pen[0].amax(1).clamp_min(0)
        new.append(_collision_constraints(hand, layout, pen, margin, q))
    if table is not None:
        ground = None if isinstance(table, (int, float)) else table
        below = (table_depth(hand, poses, table) if ground is None
                 else ground_capsule_depth(ground, hand, poses)[0])[:, layout.movable]
        penetration = torch.maximum(penetration, below.amax(1).clamp_min(0) if below.shape[1] else penetration)
        new.append(_table_constraints(hand, layout, poses, table, margin))
    over = torch.zeros(P, dtype=torch.bool, device=q.device)
    if finger_tol is not None:
        overlap, link, local, target, normal, mask = finger_pair_parts(hand, poses, layout.movable, margin)
        over = (overlap > finger_tol).view(P, -1).any(1)
        new.append(_Constraints(link=link, finger=hand.link_finger[link].clamp(min=0), local=local, target=target,
                                mask=mask & (overlap > 0.5 * finger_tol).repeat(1, 2), normal=normal))
    return [_per_path(c, P) for c in new], penetration.view(P, -1), over


# ----------------------------------------------------------------------------------------------------------------
# Validation
# ----------------------------------------------------------------------------------------------------------------
def _validate(hand, root, q_search, contacts, sdf, object_pose, free, q_rest, check):
    if not isinstance(hand, HandModel):
        raise InputTypeError(f"hand: expected a HandModel, got {type(hand).__name__}")
    D, F, L = hand.num_joints, hand.num_fingers, hand.num_links
    check_tensor(q_search, "q_search", (None, D))
    if q_search.dtype not in (torch.float32, torch.float64):
        raise InputTypeError(f"q_search: expected float32 or float64, got {q_search.dtype}")
    T = q_search.shape[0]
    if T < 1:
        raise ShapeError(f"q_search: expected shape (T, {D}) with T >= 1, got {tuple(q_search.shape)}")
    dt, dev = q_search.dtype, q_search.device

    def same(x, name):
        if x.dtype != dt or x.device != dev:
            raise InputTypeError(f"{name}: expected dtype {dt} on {dev} like q_search, got {x.dtype} on {x.device}")
        return x

    same(check_tensor(root, "root", (T, 4, 4)), "root")
    if not isinstance(contacts, ContactTrack):
        raise InputTypeError(f"contacts: expected a ContactTrack, got {type(contacts).__name__}")
    if contacts.frames != T:
        raise ShapeError(f"contacts.link: expected shape ({T}, K) (T from q_search), got "
                         f"{tuple(contacts.link.shape)}")
    same(contacts.point_local, "contacts.point_local")
    same(contacts.target, "contacts.target")
    if contacts.link.device != dev or contacts.mask.device != dev:
        raise InputTypeError(f"contacts: link and mask must be on {dev} like q_search")
    # Link range of the used slots: a host sync on GPUs, where a bad index fails inside torch instead.
    if dev.type == "cpu" and bool(contacts.mask.any()):
        used = contacts.link[contacts.mask]
        if int(used.min()) < 0 or int(used.max()) >= L:
            raise InputValueError(f"contacts.link: masked entries must be in [0, {L}), got "
                                  f"[{int(used.min())}, {int(used.max())}]")
    if (sdf is None) != (object_pose is None):
        raise InputValueError("sdf, object_pose: give both (collision rounds) or neither, got "
                              f"sdf={'None' if sdf is None else 'SDFGrid'}, "
                              f"object_pose={'None' if object_pose is None else 'tensor'}")
    if sdf is not None:
        if not isinstance(sdf, SDFGrid):
            raise InputTypeError(f"sdf: expected an SDFGrid, got {type(sdf).__name__}")
        same(check_tensor(object_pose, "object_pose", (T, 4, 4)), "object_pose")
        if sdf.values.dtype != dt or sdf.values.device != dev:
            sdf = sdf.to(dev, dt)
    if free is None:
        finger = hand.link_finger.to(dev)[contacts.link.clamp(0, L - 1)]
        onehot = (finger.unsqueeze(-1) == torch.arange(F, device=dev)) & contacts.mask.unsqueeze(-1)
        free = ~onehot.any(dim=1)
    else:
        check_tensor(free, "free", (T, F), floating=False)
        if free.dtype != torch.bool:
            raise InputTypeError(f"free: expected a bool tensor, got dtype {free.dtype}")
        free = free.to(dev)
    if q_rest is None:
        q_rest = hand.q_rest
    else:
        same(check_tensor(q_rest, "q_rest", (D,)), "q_rest")
    if hand.dtype != dt or hand.device != dev:
        hand = hand.to(dev, dt)
    q_rest = q_rest.to(dev, dt)
    if check:
        check_finite(q_search, "q_search")
        check_transforms(root, "root")
        check_finite(contacts.point_local[contacts.mask], "contacts.point_local")
        check_finite(contacts.target[contacts.mask], "contacts.target")
        check_finite(q_rest, "q_rest")
        if object_pose is not None:
            check_transforms(object_pose, "object_pose")
    return q_search, root, contacts, object_pose, free, q_rest, hand, sdf


def _check_settings(nonnegative: dict, positive: dict, counts: dict) -> None:
    for name, v in (*nonnegative.items(), *positive.items()):
        strict = name in positive
        number = not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)
        if not number or v < 0 or (strict and v == 0):
            raise InputValueError(f"{name}: expected a finite {'positive' if strict else 'non-negative'} number, "
                                  f"got {v!r}")
    for name, (v, least) in counts.items():
        if isinstance(v, bool) or not isinstance(v, int) or v < least:
            raise InputValueError(f"{name}: expected an integer >= {least}, got {v!r}")


# ----------------------------------------------------------------------------------------------------------------
# Collisions and results
# ----------------------------------------------------------------------------------------------------------------
def _collision_constraints(hand: HandModel, layout: _Layout, pen, margin: float, like: torch.Tensor) -> _Constraints:
    """One-sided constraints for the deepest capsule-axis point of every penetrating movable link, (T, M) slots (no
    slots if ``pen`` is None). ``pen``: :func:`.exact.capsule_penetration` of the motion.

    Deviation from the paper: §4.3 substitutes the deepest penetrating point and its surface point into the contact
    equation (an equality). Here the link's capsule is kept out: its deepest axis point stays on the outer side of
    the plane through the surface point, offset by the radius plus ``margin``, so it may slide along the surface
    or leave it; an equality would pin it and fight the smoothing. Proximal phalanges are included, not only
    intermediate and distal ones.
    """
    T = like.shape[0]
    if pen is None:
        z3, zl = like.new_zeros(T, 0, 3), torch.zeros(T, 0, dtype=torch.long, device=like.device)
        return _Constraints(zl, zl, z3, z3, zl.bool(), z3)
    depth, local, point, normal, sd = pen
    m = layout.movable
    depth, local, point, normal, sd = depth[:, m], local[:, m], point[:, m], normal[:, m], sd[:, m]
    mask = (depth > margin) & torch.isfinite(depth)
    # the axis point must get to sd = radius + margin: move it out along the normal by the difference
    push = torch.where(mask, depth + margin, torch.zeros_like(depth))
    target = point + push.unsqueeze(-1) * normal
    link = m.expand(T, -1)
    return _Constraints(link=link, finger=hand.link_finger[link].clamp(min=0), local=local, target=target, mask=mask,
                        normal=normal)


def _table_constraints(hand: HandModel, layout: _Layout, poses: torch.Tensor, table,
                       margin: float) -> _Constraints:
    """One-sided constraints keeping every movable link's capsule above the table plane ``table`` (a height) or out
    of a :class:`~torchhand.geometry.ground.Ground`'s solids (see :func:`.reconstruct_bounds.table_constraint_parts`
    and ``ground_constraint_parts``), (T, M) slots."""
    m = layout.movable
    if isinstance(table, (int, float)):
        local, target, normal, mask = table_constraint_parts(hand, poses, m, table, margin)
    else:
        local, target, normal, mask = ground_constraint_parts(table, hand, poses, m, margin)
    link = m.expand(poses.shape[0], -1)
    return _Constraints(link=link, finger=hand.link_finger[link].clamp(min=0), local=local, target=target, mask=mask,
                        normal=normal)


def _result(p: _Problem, q: torch.Tensor, contacts: ContactTrack, penetration: torch.Tensor,
            rounds: int) -> ReconstructResult:
    hand = p.hand
    T = q.shape[0]
    poses = hand.forward_kinematics(q, p.root)
    L = hand.num_links
    Tl = poses[torch.arange(T, device=q.device)[:, None], contacts.link.clamp(0, L - 1)]  # (T, K, 4, 4)
    pos = (Tl[..., :3, :3] @ contacts.point_local.unsqueeze(-1)).squeeze(-1) + Tl[..., :3, 3]
    dist = torch.linalg.vector_norm(pos - contacts.target, dim=-1)
    dist = torch.where(contacts.mask, dist, torch.zeros_like(dist))
    contact_error = dist.amax(dim=1) if contacts.slots else q.new_zeros(T)

    lay = p.layout
    acc = q.new_zeros(T)
    if T >= 3:
        acc[1:-1] = ((q[2:] - 2 * q[1:-1] + q[:-2]) ** 2).sum(-1)
    bend = ((q[:, lay.joints] * lay.bend).sum(-1) ** 2).sum(-1)
    smoothness = acc + p.bend_weight * bend

    violated = contact_error > p.contact_tol
    penetrating = penetration > p.penetration_tol
    code = violated.to(torch.int8) * int(ReconstructStatus.CONTACT_VIOLATED) \
        + penetrating.to(torch.int8) * int(ReconstructStatus.PENETRATING)
    finite = torch.isfinite(q).all(dim=1) & torch.isfinite(contact_error) & torch.isfinite(penetration)
    frame_status = torch.where(finite, code, torch.full_like(code, int(ReconstructStatus.DIVERGED)))
    if not bool(finite.all()):
        status = ReconstructStatus.DIVERGED
    else:
        status = ReconstructStatus(int(bool(violated.any())) * int(ReconstructStatus.CONTACT_VIOLATED)
                                   + int(bool(penetrating.any())) * int(ReconstructStatus.PENETRATING))
    return ReconstructResult(q=q, contact_error=contact_error, penetration=penetration, smoothness=smoothness,
                             frame_status=frame_status, iterations=rounds, status=status)
