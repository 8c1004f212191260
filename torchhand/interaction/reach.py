"""Reaching for a missing contact: the grip adjustment of §8.1 extended to the reference's contacts, batched over B
rollouts (an extension of Kry & Pai 2006).

Kry & Pai adapt "the same motor program to handle a family of different shapes" by tightening the grip on slip
(:mod:`.grip`). A finger can also miss the object altogether: on a smaller object, or where the object lags the
reference and a finger's turn to push comes (a contact switch). The reference says when each finger pushes: the
interaction's deflection theta - theta_r = C tau of a finger's joints is the distance the object holds the finger
open by. Here a finger reaches when the reference says it pushes and it does not touch:

* the reference pushes with finger f at step k when ||theta_f - theta_r,f|| over f's joints exceeds ``min_squeeze``
  (0.005 rad); its closing direction is u_f(k) = (theta_r,f - theta_f) / ||theta_r,f - theta_f||, further along the
  way the reference already presses into the object;
* finger f of rollout b touches when one of its links pushes the object with a normal force above ``min_force``
  (0.2 N, the grip's threshold);
* a finger that should push and does not touch moves its reference on by ``rate`` h along u_f (``rate``: 0.5 rad/s),
  up to ``limit`` (0.25 rad) in all; one that touches keeps its offset; one the reference no longer pushes with
  gives its offset back at ``rate``.

The offset o (B, D) is added to theta_r of the next step. The written ``theta_r`` of a rollout includes it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..errors import InputValueError
from ._contacts import BODY_OBJECT

__all__ = ["ReachSettings", "ReachPlan", "reach_plan", "touching_fingers", "reach_update"]


@dataclass(frozen=True)
class ReachSettings:
    """Settings of the reach (module docstring): enabled; rate, rad/s; limit, rad (the offset's norm per finger);
    min_squeeze, rad; min_force, newtons."""

    enabled: bool = False
    rate: float = 0.5
    limit: float = 0.25
    min_squeeze: float = 0.005
    min_force: float = 0.2

    def __post_init__(self):
        for name in ("rate", "limit", "min_squeeze", "min_force"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and v >= 0):
                raise InputValueError(f"reach {name}: expected a number >= 0, got {v!r}")


@dataclass(frozen=True, eq=False)
class ReachPlan:
    """What the reference says, per step (T steps, D joints, F fingers): pushes (T, F) bool; direction (T, D), unit
    per finger on the joints of a pushing finger, 0 elsewhere; joint_finger (D,) long (-1: no finger)."""

    pushes: torch.Tensor
    direction: torch.Tensor
    joint_finger: torch.Tensor


def reach_plan(hand, theta: np.ndarray, theta_r: np.ndarray, settings: ReachSettings) -> ReachPlan:
    """The plan of the reference (module docstring): theta (T, D) the interaction's joints at the resynthesis' steps,
    theta_r (T, D), radians."""
    jl = hand.chain.joint_link.cpu()
    finger = hand.link_finger.cpu()[jl]                                             # (D,)
    F = len(hand.finger_names)
    gap = np.asarray(theta_r, dtype=np.float64) - np.asarray(theta, dtype=np.float64)   # (T, D): closing
    T, D = gap.shape
    pushes = np.zeros((T, F), dtype=bool)
    direction = np.zeros((T, D))
    for f in range(F):
        cols = np.nonzero(finger.numpy() == f)[0]
        if len(cols) == 0:
            continue
        norm = np.linalg.norm(gap[:, cols], axis=1)
        pushes[:, f] = norm > settings.min_squeeze
        direction[:, cols] = np.where(pushes[:, f, None], gap[:, cols] / np.maximum(norm, 1e-300)[:, None], 0.0)
    return ReachPlan(torch.from_numpy(pushes), torch.from_numpy(direction), finger.to(torch.long))


def touching_fingers(forces: torch.Tensor, contacts, hand, min_force: float) -> torch.Tensor:
    """(B, F) bool: a link of the finger pushes the object with a normal force above ``min_force``.

    forces: f^{k+1} on the hand, (B, N, 3); contacts: the step's slots."""
    fn = (forces * contacts.d0).sum(-1)
    loaded = contacts.mask & (contacts.body == BODY_OBJECT) & (fn > min_force)        # (B, N)
    link = contacts.link.clamp_min(0)
    finger = hand.link_finger.to(link.device)[link]                                    # (N,)
    F = len(hand.finger_names)
    onehot = (finger[:, None] == torch.arange(F, device=link.device)) & (contacts.link >= 0)[:, None]
    return (loaded.to(torch.float64) @ onehot.to(torch.float64)) > 0


def reach_update(offset: torch.Tensor, k: int, plan: ReachPlan, touching: torch.Tensor, h: float,
                 settings: ReachSettings) -> torch.Tensor:
    """The offset (B, D) after step k: reaching fingers move on, touching ones hold, released ones give back."""
    F = plan.pushes.shape[1]
    pushes = plan.pushes[k].to(offset.device)                                          # (F,)
    u = plan.direction[k].to(offset)                                                   # (D,)
    jf = plan.joint_finger.to(offset.device)
    on = jf >= 0
    jfi = jf.clamp_min(0)
    reach = pushes[None, :] & ~touching                                                # (B, F)
    release = ~pushes[None, :].expand_as(reach)
    step = settings.rate * h
    grown = offset + step * u[None, :] * (reach[:, jfi] & on).to(offset)
    # the norm of each finger's offset stays within the limit
    norm = torch.zeros(offset.shape[0], F, dtype=offset.dtype, device=offset.device)
    norm.index_add_(1, jfi[on], grown[:, on] ** 2)
    norm = norm.sqrt()
    scale = torch.where(norm > settings.limit, settings.limit / norm.clamp_min(1e-300), torch.ones_like(norm))
    grown = grown * torch.where(on, scale[:, jfi], torch.ones_like(grown))
    # released fingers: the offset shrinks towards 0 by rate h (as a vector per finger)
    norm = torch.zeros_like(scale)
    norm.index_add_(1, jfi[on], grown[:, on] ** 2)
    norm = norm.sqrt()
    shrink = torch.where(norm > step, (norm - step) / norm.clamp_min(1e-300), torch.zeros_like(norm))
    out = torch.where((release[:, jfi] & on), grown * shrink[:, jfi], grown)
    return out
