"""Per-finger contact states and forces of a solution, for plots and labels (NumPy).

A finger is *free* in a frame when none of its links has a contact, *sliding* when one of its contacts is marked in
the solution's stored ``contact_sliding`` (the synthesis' own rule; ``docs/result_format.md``), else *static*.
Forces are the contact forces of the hand on the object, split along each contact's normal (pointing into the
object): the normal magnitude sums ``f . n`` over the finger's contacts, the tangential magnitude is the norm of the
summed tangential parts; the friction-cone limit is ``mu * f_n``. Units: metres, seconds, newtons.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from torchhand.errors import FileFormatError

__all__ = ["FREE", "STATIC", "SLIDING", "STATE_NAMES", "FingerContacts", "finger_contacts", "solution_summary"]

FREE, STATIC, SLIDING = 0, 1, 2
STATE_NAMES = ("free", "static", "sliding")


@dataclass(frozen=True, eq=False)
class FingerContacts:
    """Per-finger contact data of one solution, N = fingers over all hands.

    labels: (N,) str, e.g. "thumb" or "right thumb"
    state: (T, N) int, FREE / STATIC / SLIDING
    normal: (T, N) newtons; tangential: (T, N) newtons
    friction: the hand-object friction coefficient
    fps: frames per second
    """

    labels: tuple
    state: np.ndarray
    normal: np.ndarray
    tangential: np.ndarray
    friction: float
    fps: float


def finger_contacts(solution, hand_models: dict, *, friction: float | None = None) -> FingerContacts:
    """Contact state and force magnitudes per finger and frame.

    solution: :class:`~torchhand.io.result.Solution`
    hand_models: side -> :class:`~torchhand.hand.HandModel` (for link -> finger)
    friction: friction coefficient for the cone limit (default: the solution's ``friction``)
    """
    s = solution
    mu = friction if friction is not None else s.friction
    if mu is None:
        raise FileFormatError(f"{s.path}: friction: the file has none; pass the scene's friction coefficient")
    T, K = s.contact_mask.shape
    side_idx, link_idx = s.contact_side_link()
    names = s.contact_link_names()
    sides = ("right", "left")
    columns = []  # (side, finger index, label)
    two = len(s.hands) > 1
    for h in s.hands:
        model = hand_models[h.side]
        for f, fname in enumerate(model.finger_names):
            columns.append((h.side, f, f"{h.side} {fname}" if two else str(fname)))
    col_of = {(side, f): j for j, (side, f, _) in enumerate(columns)}
    # Finger column of every contact slot, -1 when padding or not a finger link.
    finger_col = np.full((T, K), -1, dtype=np.int64)
    cache: dict = {}
    for t in range(T):
        for k in range(K):
            if not s.contact_mask[t, k] or link_idx[t, k] < 0:
                continue
            key = (int(side_idx[t, k]), int(link_idx[t, k]))
            if key not in cache:
                side = sides[key[0]] if 0 <= key[0] < 2 else s.hands[0].side
                model = hand_models.get(side)
                col = -1
                if model is not None:
                    lname = names[key[1]] if names else (model.link_names[key[1]] if key[1] < model.num_links
                                                         else None)
                    if lname in model.link_names:
                        f = int(model.link_finger[model.link_names.index(lname)])
                        col = col_of.get((side, f), -1) if f >= 0 else -1
                cache[key] = col
            finger_col[t, k] = cache[key]
    N = len(columns)
    in_contact = np.zeros((T, N), dtype=bool)
    sliding = np.zeros((T, N), dtype=bool)
    normal = np.zeros((T, N))
    tangential = np.zeros((T, N))
    n = s.contact_normal / np.maximum(np.linalg.norm(s.contact_normal, axis=-1, keepdims=True), 1e-12)
    for j in range(N):
        m = finger_col == j  # (T, K)
        in_contact[:, j] = m.any(1)
        sliding[:, j] = (m & s.contact_sliding).any(1)
        f = s.contact_force * m[..., None]
        fn = (f * n).sum(-1)  # (T, K)
        normal[:, j] = fn.sum(1)
        tangential[:, j] = np.linalg.norm((f - fn[..., None] * n).sum(1), axis=-1)
    state = np.where(in_contact, np.where(sliding, SLIDING, STATIC), FREE)
    return FingerContacts(labels=tuple(c[2] for c in columns), state=state, normal=normal, tangential=tangential,
                          friction=float(mu), fps=s.fps)


def solution_summary(solution) -> str:
    """One line of key numbers of a solution: mean contacts per frame and the largest contact force."""
    parts = [f"{solution.contact_mask.sum(1).mean():.1f} contacts/frame"]
    if solution.contact_mask.any():
        fmax = float(np.linalg.norm(solution.contact_force[solution.contact_mask], axis=-1).max())
        parts.append(f"max force {fmax:.1f} N")
    return ", ".join(parts)
