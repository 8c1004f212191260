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

import enum
import math
from dataclasses import dataclass

import torch

from .._tree import tree_map, tree_to
from ..hand.collision import rigid_inverse
from ..conventions import check_finite, check_tensor, check_transforms
from ..errors import InputTypeError, InputValueError, ShapeError
from ..hand.model import HandModel
from ..geometry.sdf import SDFGrid
from .exact import capsule_penetration
from .reconstruct_bounds import (SPEED_MARGIN, finger_pair_parts, speed_penalty, speed_terms, speed_update,
                                 speed_values, table_constraint_parts, table_depth)

__all__ = ["ContactTrack", "ReconstructStatus", "ReconstructResult", "reconstruct_motion"]

# The normal equations are assembled and factorised in float64 whatever the input dtype: the acceleration operator
# and the contact penalty span ~8 orders of magnitude of curvature, beyond float32's reach. Kinematics and SDF
# queries stay in the input dtype; the result is cast back.
_SOLVE_DTYPE = torch.float64
_MAX_STEP = 0.5            # largest joint change of one Gauss–Newton step, radians (a trust region)
_STEP_TOL = 1e-5           # default: Gauss–Newton stops when no joint moves more than this, radians ...
_RESIDUAL_FRACTION = 0.1   # ... and every constraint is within this fraction of its tolerance
_BACKTRACK_STEPS = 8       # most halvings of a Gauss–Newton step that does not lower the merit
_ACTIVE_SET_ROUNDS = 6     # most re-solves per step while the set of active collision constraints grows
_LOOKAHEAD = 3             # a window's last segment // _LOOKAHEAD frames are solved again by the next window
_FRAME_SCALE = 0.01        # length of the link-frame axes whose Jacobians give any link point's Jacobian, metres


# ----------------------------------------------------------------------------------------------------------------
# Inputs and results
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ContactTrack:
    """Contacts to keep, per frame, padded to K slots with a mask (one hand; T frames).

    link:        link index of the hand point, (T, K), long; any value where ``mask`` is False (-1 by convention)
    point_local: the hand point in its link's frame, (T, K, 3), metres
    target:      where that point must be, world frame, (T, K, 3), metres (a point on the object surface)
    mask:        which slots hold a contact, (T, K), bool

    Contacts on links that no finger joint moves (the palm) are reported in the contact error but cannot be
    enforced: the root pose places them.
    """

    link: torch.Tensor
    point_local: torch.Tensor
    target: torch.Tensor
    mask: torch.Tensor

    def __post_init__(self) -> None:
        if not isinstance(self.link, torch.Tensor):
            raise InputTypeError(f"ContactTrack.link: expected a torch.Tensor, got {type(self.link).__name__}")
        if self.link.dim() != 2:
            raise ShapeError(f"ContactTrack.link: expected shape (T, K), got {tuple(self.link.shape)}")
        if self.link.is_floating_point() or self.link.dtype == torch.bool or self.link.is_complex():
            raise InputTypeError(f"ContactTrack.link: expected an integer tensor, got dtype {self.link.dtype}")
        T, K = self.link.shape
        check_tensor(self.point_local, "ContactTrack.point_local", (T, K, 3))
        check_tensor(self.target, "ContactTrack.target", (T, K, 3))
        check_tensor(self.mask, "ContactTrack.mask", (T, K), floating=False)
        if self.mask.dtype != torch.bool:
            raise InputTypeError(f"ContactTrack.mask: expected a bool tensor, got dtype {self.mask.dtype}")
        if self.point_local.dtype != self.target.dtype:
            raise InputTypeError(f"ContactTrack.target: dtype {self.target.dtype} differs from point_local's "
                                 f"{self.point_local.dtype}")

    @property
    def frames(self) -> int:
        """Number of frames T."""
        return int(self.link.shape[0])

    @property
    def slots(self) -> int:
        """Number of contact slots K."""
        return int(self.link.shape[1])

    @classmethod
    def empty(cls, frames: int, *, dtype: torch.dtype = torch.float64, device=None) -> "ContactTrack":
        """A track of ``frames`` frames without contacts (K = 0)."""
        return cls(link=torch.zeros(frames, 0, dtype=torch.long, device=device),
                   point_local=torch.zeros(frames, 0, 3, dtype=dtype, device=device),
                   target=torch.zeros(frames, 0, 3, dtype=dtype, device=device),
                   mask=torch.zeros(frames, 0, dtype=torch.bool, device=device))

    def to(self, device=None, dtype: torch.dtype | None = None) -> "ContactTrack":
        """Copy on ``device``; point_local and target cast to ``dtype`` (link and mask keep theirs)."""
        return tree_to(self, device=device, dtype=dtype)


class ReconstructStatus(enum.IntEnum):
    """Outcome of a reconstruction, per frame (``frame_status``) and overall (``status``)."""

    OK = 0
    CONTACT_VIOLATED = 1
    PENETRATING = 2
    CONTACT_VIOLATED_AND_PENETRATING = 3
    DIVERGED = 4

    @property
    def message(self) -> str:
        return _MESSAGES[self]


_MESSAGES = {
    ReconstructStatus.OK: "ok: every kept contact is within contact_tol and penetration is within penetration_tol",
    ReconstructStatus.CONTACT_VIOLATED: "a kept contact is farther than contact_tol from its target: the target is "
                                        "out of the finger's reach within its joint limits, the contact is on the "
                                        "palm, or it conflicts with collision constraints; check the search's "
                                        "contacts or raise contact_weight",
    ReconstructStatus.PENETRATING: "the hand still penetrates the object by more than penetration_tol: raise "
                                   "max_outer, or the penetration is on the palm or a palm-level link that the "
                                   "root pose places",
    ReconstructStatus.CONTACT_VIOLATED_AND_PENETRATING: "both a contact and the penetration are out of tolerance; "
                                                        "see CONTACT_VIOLATED and PENETRATING",
    ReconstructStatus.DIVERGED: "non-finite joint angles: the inputs hold NaN/inf or the solve diverged; call with "
                                "check=True to locate bad inputs",
}


@dataclass(frozen=True)
class ReconstructResult:
    """Smoothed motion and how well it meets the constraints (T frames, D joints).

    q:             smoothed joint angles, (T, D), radians
    contact_error: largest distance of a kept contact point from its target, (T,), metres; 0 where none
    penetration:   deepest hand-object (or hand-table) penetration of any link capsule, (T,), metres, >= 0
    smoothness:    E1 + bend_weight * E2 of ``q`` (Eqs. 10-11), (T,), radians^2; E1 is 0 at the first and last frame
    frame_status:  :class:`ReconstructStatus` value of every frame, (T,), int8
    iterations:    smoothing/collision rounds used (1 .. max_outer)
    status:        overall :class:`ReconstructStatus`; ``status.message`` says what to do about it
    """

    q: torch.Tensor
    contact_error: torch.Tensor
    penetration: torch.Tensor
    smoothness: torch.Tensor
    frame_status: torch.Tensor
    iterations: int
    status: ReconstructStatus


# ----------------------------------------------------------------------------------------------------------------
# Internal problem description
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Layout:
    """Finger-local joint layout (F fingers, n = most joints of one finger).

    joints: global joint index of each finger's local joints, (F, n), long (0 where padded); valid: (F, n) bool
    bend:   Eq. 11 coefficients (1, -2, 1) on the finger's flexion joints, (F, n); 0 where not applicable
    lo, hi: joint limits in the local layout, (F, n), radians (0 where padded)
    movable: links a finger joint moves, excluding the palm-level link of 4-link fingers, (M,), long
    """

    joints: torch.Tensor
    valid: torch.Tensor
    bend: torch.Tensor
    lo: torch.Tensor
    hi: torch.Tensor
    movable: torch.Tensor


@dataclass(frozen=True)
class _Constraints:
    """Point constraints, C slots per frame: equalities ``p(q) = target`` (normal None) or one-sided
    ``normal . (p(q) - target) >= 0``. link, finger: (T, C) long (safe indices); local, target, normal: (T, C, 3);
    mask: (T, C) bool, only slots a finger joint can move."""

    link: torch.Tensor
    finger: torch.Tensor
    local: torch.Tensor
    target: torch.Tensor
    mask: torch.Tensor
    normal: torch.Tensor | None = None

    def frames(self, sl: slice) -> "_Constraints":
        return tree_map(lambda t: t[sl], self)

    def cat(self, other: "_Constraints") -> "_Constraints":
        """The slots of both, (T, C + C')."""
        return _Constraints(*(torch.cat([a, b], dim=1) for a, b in zip(_fields(self), _fields(other))))


def _fields(c: _Constraints) -> tuple:
    return c.link, c.finger, c.local, c.target, c.mask, c.normal


@dataclass(frozen=True)
class _Problem:
    hand: HandModel
    layout: _Layout
    root: torch.Tensor          # (T, 4, 4)
    prior_target: torch.Tensor  # (T, F, n) radians: q_search where a finger is held, q_rest where it is free
    prior_weight: torch.Tensor  # (T, F)
    bend_weight: float
    rho: float                  # augmented-Lagrangian penalty of every point constraint, 1/m^2
    contact_tol: float
    penetration_tol: float
    max_inner: int
    step_tol: float             # radians
    frame_links: torch.Tensor   # (4L,) long: every link four times (origin and three axes)
    frame_points: torch.Tensor  # (4L, 3) metres
    joint_step: float | None = None   # bound on |q[t+1] - q[t]| per joint, radians (reconstruct_bounds)
    rho_speed: float = 1e4            # augmented-Lagrangian penalty of the speed bound, 1/rad^2 relative to E1


def _finger_layout(hand: HandModel) -> _Layout:
    F, D, dev = hand.num_fingers, hand.num_joints, hand.device
    joint_finger = hand.link_finger[hand.chain.joint_link] if D else hand.link_finger.new_zeros(0)
    per = [torch.nonzero(joint_finger == f).flatten() for f in range(F)]
    n = max([len(p) for p in per] + [1])
    joints = torch.zeros(F, n, dtype=torch.long, device=dev)
    valid = torch.zeros(F, n, dtype=torch.bool, device=dev)
    bend = torch.zeros(F, n, dtype=hand.dtype, device=dev)
    coeff = (1.0, -2.0, 1.0)
    for f, p in enumerate(per):
        joints[f, : len(p)] = p
        valid[f, : len(p)] = True
        flex = hand.flexion_joints[f].tolist()
        local = [p.tolist().index(j) if j in p.tolist() else -1 for j in flex]
        if len(local) == 3 and min(local) >= 0:  # Eq. 11 needs three flexion joints of this finger
            for c, k in zip(coeff, local):
                bend[f, k] = c
    lim = hand.joint_limits[joints]  # (F, n, 2)
    lo = torch.where(valid, lim[..., 0], torch.zeros_like(lim[..., 0]))
    hi = torch.where(valid, lim[..., 1], torch.zeros_like(lim[..., 1]))
    # A link is movable if some finger joint supports it. Palm-level links of 4-link fingers (the metacarpals of
    # the default hand) only have the palm's small deformation joints, so they are left to the root pose.
    movable = []
    for link in range(hand.num_links):
        f = int(hand.link_finger[link])
        if f < 0 or not bool(hand.chain.support[link][joints[f][valid[f]]].any()):
            continue
        row = hand.finger_links[f]
        if int((row >= 0).sum()) == 4 and int(row[0]) == link:
            continue
        movable.append(link)
    return _Layout(joints, valid, bend, lo, hi, torch.tensor(movable, dtype=torch.long, device=dev))


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
    returns:     :class:`ReconstructResult`

    Raises ShapeError / InputTypeError / InputValueError naming the argument on bad input.
    """
    q_search, root, contacts, object_pose, free, q_rest, hand, sdf = _validate(
        hand, root, q_search, contacts, sdf, object_pose, free, q_rest, check)
    _check_settings(nonnegative=dict(bend_weight=bend_weight, rest_weight=rest_weight, search_weight=search_weight),
                    positive=dict(contact_weight=contact_weight, penetration_tol=penetration_tol,
                                  contact_tol=contact_tol, step_tol=step_tol),
                    counts=dict(max_outer=(max_outer, 1), max_inner=(max_inner, 1), segment=(segment, 8)))
    T, dt, dev = q_search.shape[0], q_search.dtype, q_search.device
    layout = _finger_layout(hand)
    q_rest = hand.clamp_to_limits(q_rest[None])[0]
    q = hand.clamp_to_limits(q_search)

    # Prior pose per frame and finger (Deviation from the paper: see the module docstring).
    F = hand.num_fingers
    free_l = free.unsqueeze(-1)
    prior_target = torch.where(free_l, q_rest[layout.joints].expand(T, F, -1), q[:, layout.joints])
    prior_weight = torch.where(free, q.new_tensor(rest_weight), q.new_tensor(search_weight))
    L = hand.num_links
    eye = torch.cat([torch.zeros(1, 3, dtype=dt, device=dev), _FRAME_SCALE * torch.eye(3, dtype=dt, device=dev)])
    problem = _Problem(hand=hand, layout=layout, root=root, prior_target=prior_target, prior_weight=prior_weight,
                       bend_weight=float(bend_weight), rho=float(contact_weight), contact_tol=float(contact_tol),
                       penetration_tol=float(penetration_tol), max_inner=max_inner, step_tol=float(step_tol),
                       frame_links=torch.arange(L, device=dev).repeat_interleave(4), frame_points=eye.repeat(L, 1),
                       joint_step=None if max_joint_step is None else SPEED_MARGIN * float(max_joint_step))

    link_safe = contacts.link.clamp(0, L - 1)
    finger = hand.link_finger[link_safe]
    used = contacts.mask[..., None]  # padding slots may hold anything, NaN included
    eq = _Constraints(link=link_safe, finger=finger.clamp(min=0), mask=contacts.mask & (finger >= 0),
                      local=torch.where(used, contacts.point_local, torch.zeros_like(contacts.point_local)),
                      target=torch.where(used, contacts.target, torch.zeros_like(contacts.target)))
    lam_eq = q.new_zeros(T, contacts.slots, 3, dtype=_SOLVE_DTYPE)
    ineq = _collision_constraints(hand, layout, None, 0.0, q)  # none yet
    lam_in = q.new_zeros(T, 0, dtype=_SOLVE_DTYPE)
    # Collision points are pushed this far past the surface, so that the next round finds the capsule outside.
    margin = 0.5 * penetration_tol

    penetration = q.new_zeros(T)
    object_inv = None if object_pose is None else rigid_inverse(object_pose)
    rounds = 0
    for rounds in range(1, max_outer + 1):
        if F > 0:
            q, lam_eq, lam_in = _smooth_sequence(problem, q, eq, ineq, lam_eq, lam_in, segment)
        if sdf is None and table_height is None and finger_tol is None:
            break
        poses = hand.forward_kinematics(q, root)
        new = []
        penetration = q.new_zeros(T)
        if sdf is not None:
            pen = capsule_penetration(hand, poses, sdf, object_pose, object_inv)
            penetration = pen[0].amax(1).clamp_min(0)
            new.append(_collision_constraints(hand, layout, pen, margin, q))
        if table_height is not None:
            below = table_depth(hand, poses, table_height)[:, layout.movable]
            penetration = torch.maximum(penetration, below.amax(1).clamp_min(0) if below.shape[1] else penetration)
            new.append(_table_constraints(hand, layout, poses, table_height, margin))
        over = False
        if finger_tol is not None:
            overlap, link, local, target, normal, mask = finger_pair_parts(hand, poses, layout.movable, margin)
            over = bool((overlap > finger_tol).any())
            new.append(_Constraints(link=link, finger=hand.link_finger[link].clamp(min=0), local=local, target=target,
                                    mask=mask & (overlap > 0.5 * finger_tol).repeat(1, 2), normal=normal))
        if rounds == max_outer or not (over or bool((penetration > penetration_tol).any())):
            break
        new = [c for c in new if bool(c.mask.any())]
        if not new:
            break  # what penetrates is the palm or a palm-level link: the root pose places it
        for c in new:
            ineq = ineq.cat(c)
            lam_in = torch.cat([lam_in, lam_in.new_zeros(T, c.mask.shape[1])], dim=1)

    return _result(problem, q, contacts, penetration, rounds)


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
    D = JX.shape[-1]
    JX = JX.to(wdt)
    out = []
    for con in cons:
        C = con.link.shape[1]
        u = con.local.to(wdt) / _FRAME_SCALE
        w = torch.cat([1 - u.sum(-1, keepdim=True), u], dim=-1)                   # (S, C, 4)
        idx = (4 * con.link[..., None] + torch.arange(4, device=x.device)).reshape(S, 4 * C)
        J = JX.gather(1, idx[..., None, None].expand(S, 4 * C, 3, D)).view(S, C, 4, 3, D)
        J = (J * w[..., None, None]).sum(2)                                       # (S, C, 3, D)
        cols = lay.joints[con.finger]                                              # (S, C, n)
        Jl = J.gather(3, cols[:, :, None, :].expand(S, C, 3, n)) * lay.valid[con.finger][:, :, None, :]
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


def _table_constraints(hand: HandModel, layout: _Layout, poses: torch.Tensor, table: float,
                       margin: float) -> _Constraints:
    """One-sided constraints keeping every movable link's capsule above the table (see
    :func:`.reconstruct_bounds.table_constraint_parts`), (T, M) slots."""
    m = layout.movable
    local, target, normal, mask = table_constraint_parts(hand, poses, m, table, margin)
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
