"""Grip adjustment on slip (Kry & Pai 2006 §8.1, Figs. 13-14), batched over B rollouts.

The interaction trajectory preserves the intent of the captured grasp, so a heavier or differently shaped object can
slip out of it. Two human-like responses tighten the grip by scaling the compliance C down:

* ``"delayed"`` (an unanticipated change, §8.1, Fig. 13 c-d): a loaded hand-object contact that slides is felt and
  the grip tightens about ``delay`` (100 ms) later. A contact slides at step k when its normal force exceeds
  ``min_force`` and its maximal-dissipation multiplier lambda_i (the sliding displacement of the step, metres) exceeds
  ``slide_tol``. At step k the compliance is scaled for the contacts that slid at step k - round(delay / h): the
  reaction follows the slip by the delay, and stops a delay after the slip stops.
* ``"imminent"`` (an anticipated change, §8.1, Figs. 13 e, 14): the ratio rho_i = |f_t| / f_n of a contact with
  normal force above ``min_force`` (0.2 N) is compared with ``ratio`` mu_i (0.9 mu); above it, the grip tightens at
  the next step.
* ``"none"``: C stays as the interaction gives it.

Tightening (the paper: "decrease the compliances by a small factor"; design note §3 item 7): every generalized
coordinate between the root and the offending contact's link (the six root coordinates and the joints that move
the link, ``Chain.support``) is multiplied by ``factor`` (0.95) per step, never below ``floor`` (0.2) times the
interaction's own compliance C_0(t) at that step; there is no recovery. The scale is kept as a per-coordinate
multiplier of C_0(t), so that compliance changes of the interaction itself still apply.

Events: one row (step, link) per offending contact per step at which the grip was tightened.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch

from ..errors import InputValueError
from ._contacts import BODY_OBJECT

__all__ = ["GRIP_MODES", "GripSettings", "GripState", "slip_ratio", "path_mask", "init_grip", "grip_update"]

GRIP_MODES = ("none", "delayed", "imminent")


@dataclass(frozen=True)
class GripSettings:
    """Settings of the grip adjustment (module docstring).

    mode: "none" | "delayed" | "imminent"; ratio: imminent-slip threshold as a fraction of mu (0.9);
    min_force: normal force below which a contact is not watched, newtons (0.2); factor: compliance scale per step
    (0.95); floor: lowest scale of the interaction's compliance (0.2); delay: reaction time of the delayed mode,
    seconds (0.1); slide_tol: sliding displacement per step above which a loaded contact slips, metres (1e-6)
    """

    mode: str = "none"
    ratio: float = 0.9
    min_force: float = 0.2
    factor: float = 0.95
    floor: float = 0.2
    delay: float = 0.1
    slide_tol: float = 1e-6

    def __post_init__(self):
        if self.mode not in GRIP_MODES:
            raise InputValueError(f"--grip: expected one of {', '.join(GRIP_MODES)}, got {self.mode!r}")
        if not 0 < self.factor <= 1:
            raise InputValueError(f"grip factor: expected in (0, 1], got {self.factor}")
        if not 0 < self.floor <= 1:
            raise InputValueError(f"grip floor: expected in (0, 1], got {self.floor}")
        if not self.ratio > 0 or not self.min_force >= 0 or not self.delay >= 0 or not self.slide_tol >= 0:
            raise InputValueError(f"grip settings: ratio > 0, min_force, delay, slide_tol >= 0 expected, got "
                                  f"{self.ratio}, {self.min_force}, {self.delay}, {self.slide_tol}")


@dataclass(frozen=True, eq=False)
class GripState:
    """Grip state of B rollouts.

    scale:   multiplier of the interaction's compliance, (B, 6 + D), in [floor, 1]
    history: slip flags of the last ``delay`` steps, (B, H, N), bool, oldest first (H = round(delay / h), >= 1)
    onset:   first step with a slipping (delayed) or imminent-slip (imminent) contact, (B,), long, -1 if none
    """

    scale: torch.Tensor
    history: torch.Tensor
    onset: torch.Tensor


def slip_ratio(forces: torch.Tensor, d0: torch.Tensor, mask: torch.Tensor, min_force: float) -> torch.Tensor:
    """rho_i = |f_t| / f_n of the contacts with normal force f_n = d0 . f > ``min_force``, 0 elsewhere.

    forces: (B, N, 3), newtons; d0: outward normals, (B, N, 3); mask: (B, N) bool; returns (B, N)
    """
    fn = (forces * d0).sum(-1)
    ft = (forces - fn[..., None] * d0).norm(dim=-1)
    loaded = mask & (fn > min_force)
    return torch.where(loaded, ft / fn.clamp_min(1e-12), torch.zeros_like(fn))


def path_mask(hand, slot_link: torch.Tensor) -> torch.Tensor:
    """The generalized coordinates between the root and each slot's link: (N, 6 + D) bool (root six always; none
    for slots without a link, ``slot_link < 0``)."""
    support = hand.chain.support.to(torch.bool).cpu()
    L, _D = support.shape
    rows = torch.cat([torch.ones(L, 6, dtype=torch.bool), support], 1)
    link = slot_link.cpu()
    out = rows[link.clamp_min(0)]
    return out & (link >= 0)[:, None]


def init_grip(B: int, n_coords: int, N: int, h: float, settings: GripSettings, like: torch.Tensor) -> GripState:
    """The untightened grip of B rollouts with N contact slots; h is the step, seconds."""
    H = max(1, round(settings.delay / h))
    return GripState(like.new_ones(B, n_coords), torch.zeros(B, H, N, dtype=torch.bool, device=like.device),
                     torch.full((B,), -1, dtype=torch.long, device=like.device))


def grip_update(grip: GripState, step: int, forces: torch.Tensor, lam: torch.Tensor, contacts, mu: torch.Tensor,
                paths: torch.Tensor, settings: GripSettings) -> tuple[GripState, list]:
    """Watch step ``step``'s solved contacts and tighten the grip for the next step (module docstring).

    forces: f^{k+1} on the hand per slot, (B, N, 3), newtons; lam: lambda_i of the step, (B, N), metres;
    contacts: the step's :class:`~torchhand.interaction.Contacts` (slots, normals, mask); mu: friction per slot,
    (B, N); paths: :func:`path_mask` of the slots, (N, 6 + D)
    returns: (new :class:`GripState`, events: list of (rollout, step, link) tuples)
    """
    if settings.mode == "none":
        return grip, []
    hand_slot = contacts.mask & (contacts.body == BODY_OBJECT)
    rho = slip_ratio(forces, contacts.d0, hand_slot, settings.min_force)
    fn = (forces * contacts.d0).sum(-1)
    loaded = hand_slot & (fn > settings.min_force)
    if settings.mode == "imminent":
        flags = loaded & (rho > settings.ratio * mu)
        act = flags
        history = grip.history
    else:
        flags = loaded & (lam > settings.slide_tol)
        act = grip.history[:, 0]                                   # slipped ``delay`` ago
        history = torch.cat([grip.history[:, 1:], flags[:, None]], 1)
    onset = torch.where((grip.onset < 0) & flags.any(1), step, grip.onset)
    tighten = (act[..., None] & paths.to(act.device)[None]).any(1)          # (B, 6 + D)
    scale = torch.where(tighten, (grip.scale * settings.factor).clamp_min(settings.floor), grip.scale)
    events = [(int(b), step, int(contacts.link[n])) for b, n in act.nonzero().tolist()]
    return replace(grip, scale=scale, history=history, onset=onset), events
