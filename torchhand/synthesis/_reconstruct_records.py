"""Records of the motion reconstruction (:mod:`.reconstruct`): its inputs and results (ContactTrack, status,
result), its settings constants and the internal problem description (finger layout, constraints, problem)."""

from __future__ import annotations

import enum
from dataclasses import dataclass

import torch

from .._tree import tree_map, tree_to
from ..conventions import check_tensor
from ..errors import InputTypeError, ShapeError
from ..hand.model import HandModel


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
    ``normal . (p(q) - target) >= 0``. link, finger: (..., C) long (safe indices); local, target, normal:
    (..., C, 3); mask: (..., C) bool, only slots a finger joint can move. Leading dims: (P, T) for the P paths of
    a reconstruction, (R,) rows of a window (:meth:`rows`)."""

    link: torch.Tensor
    finger: torch.Tensor
    local: torch.Tensor
    target: torch.Tensor
    mask: torch.Tensor
    normal: torch.Tensor | None = None

    def rows(self, sl: slice) -> "_Constraints":
        """Frames ``sl`` of (P, T, C) constraints as rows (P S, C) (row ``p S + t``)."""
        return tree_map(lambda t: t[:, sl].flatten(0, 1), self)

    def cat(self, other: "_Constraints") -> "_Constraints":
        """The slots of both, (P, T, C + C')."""
        return _Constraints(*(torch.cat([a, b], dim=2) for a, b in zip(_fields(self), _fields(other))))


def _fields(c: _Constraints) -> tuple:
    return c.link, c.finger, c.local, c.target, c.mask, c.normal


@dataclass(frozen=True)
class _Problem:
    hand: HandModel
    layout: _Layout
    root: torch.Tensor          # (T, 4, 4), shared by the P paths
    prior_target: torch.Tensor  # (P, T, F, n) radians: q_search where a finger is held, q_rest where it is free
    prior_weight: torch.Tensor  # (P, T, F)
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
