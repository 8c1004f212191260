"""What contact-force planning (:mod:`.plan`) does with an infeasible window: leave a small wrench deficit
unbalanced (``BALANCE_ALLOWANCE``), or add contacts (Liu 2009 Sec. 4.3): the candidate hand point for a new contact,
its reachability in the frames before it carries force, and the loop that adds contacts until the window is feasible
(or raises :class:`GraspUnsuitable`)."""

from __future__ import annotations

import numpy as np
import torch

from ._plan_contacts import _add, _Contacts, _Geometry
from ._plan_records import GraspUnsuitable, PlanSettings
from ._plan_window import _frame_feasible, _wrench_fit
from .snap import signed_distance

TOUCH_TOL = 1e-3
"""An added contact touches when its hand point (its link capsule, in the synthesis) is within this of the object,
metres: half the checker's 2 mm contact-hand bound."""
REACH_FACTOR = 1.0
"""Fraction of the linearised approach (:func:`_reach`) an added contact may count on. An overestimate costs a
deferral, never a force before touching (:mod:`.manipulate`)."""


def _candidate(c: _Contacts, geo: _Geometry, i: int, frames: int | None = None, k: int = 0):
    """Sec. 4.3: the hand sample closest to contact i's hand point on a link of the same hand holding no contact,
    and its closest object point with that face's inward normal; None when every such link holds a contact.

    frames: the frames the hand has to close the new contact's gap (t_e - k, the synthesis of frames k+1 .. t_e;
    0 when the contact must carry force at the current frame). With the manipulation loop's reachability
    (``geo.reach_step`` set) the candidate must be reachable in them (:func:`_reach`); among the reachable links
    the one closest to h_i is taken (Liu: the closest point not on S_i)."""
    geo._refresh()
    free = ~np.isin(geo.sample_link, np.array(c.link)) & (geo.sample_hand == geo.hand_of(c.link[i]))
    if not free.any():
        return None
    d = np.linalg.norm(geo.samples - c.h_obj[i], axis=1)
    d[~free] = np.inf
    if geo.reach_step is None or frames is None:
        s = int(np.argmin(d))
        _, p, n_out = signed_distance(geo.mesh, geo.samples[s:s + 1])
        return int(geo.sample_link[s]), geo.sample_local[s], p[0], -n_out[0]
    # the closest sample of every free link, nearest link first
    links = np.unique(geo.sample_link[free])
    best = np.array([int(np.flatnonzero(geo.sample_link == l)[np.argmin(d[geo.sample_link == l])]) for l in links])
    best = best[np.argsort(d[best], kind="stable")]
    x = geo.samples[best]
    _, p, n_out = signed_distance(geo.mesh, x)
    gap = np.linalg.norm(p - x, axis=1)
    reach = _reach(c, geo, best, (p - x) / np.maximum(gap, 1e-12)[:, None], max(int(frames), 0), k)
    ok = np.flatnonzero(gap <= TOUCH_TOL + reach)
    if not len(ok):
        return None
    j = int(ok[0])
    s = int(best[j])
    return int(geo.sample_link[s]), geo.sample_local[s], p[j], -n_out[j]


def _reach(c: _Contacts, geo: _Geometry, samples: np.ndarray, direction: np.ndarray, frames: int,
           k: int) -> np.ndarray:
    """How far the hand can move each hand-surface sample along ``direction`` (P, 3), object frame, in ``frames``
    frames while the contacts active at frame k stay where they are, metres (P,).

    Linearised at the current pose, one small LP per sample (HiGHS): the largest ``g . J v`` over a per-frame joint
    step v with ``J_c v = 0`` (the active contacts' point Jacobians: they keep still, Eq. 7 without rolling) and
    ``|v_j|`` within the synthesis' per-frame bound ``geo.reach_step`` and the joint's room to its limits divided by
    ``frames``; J is the sample's Jacobian (3, D, object frame), g the direction. The samples are of one hand, and
    only that hand's active contacts are held. The sample closes
    ``REACH_FACTOR`` times ``frames`` times that maximum. The wrist is held: it follows the object and the holding
    contacts, and counting on its turn let a linearised estimate "reach" across the object with whole fingers. A
    link moved only by the wrist (a metacarpal of the default hand) reaches nothing; a link whose finger holds
    contacts further out reaches little. (An earlier estimate scaled the least-norm direction by the first
    per-frame bound it met; on liu-lift at 2.5 kg it found no candidate reachable and the grasp was judged
    unsuitable, while this one adds ring_proximal in time.)"""
    from scipy.optimize import linprog

    P = len(samples)
    out = np.zeros(P)
    if frames <= 0 or not P:
        return out
    which = int(geo.sample_hand[samples[0]])             # the candidates are one hand's (_candidate)
    hand, q, w, off = geo.hands[which], geo.q_now[which], geo.wrist_now[which], geo.link_offset[which]
    D = hand.num_joints
    act = [j for j in range(len(c.link)) if c.start[j] <= k and geo.hand_of(c.link[j]) == which]
    links = np.concatenate([geo.sample_link[samples], np.array([c.link[j] for j in act], dtype=np.int64)]) - off
    local = np.concatenate([geo.sample_local[samples], np.array([c.h[j] for j in act]).reshape(-1, 3)])
    J = hand.point_jacobian(torch.as_tensor(q)[None], torch.as_tensor(links), torch.as_tensor(local),
                            torch.as_tensor(w)[None], wrt_root=True)[0].numpy()[:, :, 6:]    # (P + A, 3, D)
    Jc = J[P:].reshape(-1, D)
    lim = hand.joint_limits.numpy()
    lo = np.maximum(-geo.reach_step, np.minimum((lim[:, 0] - q) / frames, 0.0))
    hi = np.minimum(geo.reach_step, np.maximum((lim[:, 1] - q) / frames, 0.0))
    bounds = list(zip(lo, hi))
    eq = dict(A_eq=Jc, b_eq=np.zeros(len(Jc))) if len(Jc) else {}
    for s in range(P):
        res = linprog(-(J[s].T @ direction[s]), bounds=bounds, method="highs", **eq)
        if res.status == 0 and -res.fun > 1e-12:
            out[s] = REACH_FACTOR * frames * float(-res.fun)
    return out

def _add_contacts(c: _Contacts, geo: _Geometry, k: int, n: int, feasible: np.ndarray, settings: PlanSettings,
                  records: list | None) -> int:
    """Sec. 4.3 at window k whose per-frame LPs ``feasible (n,)`` are not all true. Returns the frames of the window
    that can be planned now: n, or, in the manipulation loop (``geo.reach_step`` set) when no reachable contact makes
    a later frame t_bad > k feasible yet, t_bad - k (the next windows, with the hand moved on, try again); raises
    GraspUnsuitable when no set makes the window's first infeasible frame feasible and that frame is k (or, planning
    alone, whenever the window stays infeasible)."""
    t_a = k + int(np.argmin(feasible))
    added = 0
    if settings.added_contacts:
        used = sum(1 for s in c.source if s >= 0)
        tried: set = set()
        while used + added < settings.max_added and not feasible.all():
            forces, _ = _wrench_fit(c, geo, t_a, settings)
            H = len(c.link)
            active = [i for i in range(H) if c.start[i] <= t_a]
            order = sorted(active, key=lambda i: -float(np.linalg.norm(forces[i])))
            progress = False
            for i in order:
                if i in tried or used + added >= settings.max_added:
                    continue
                tried.add(i)
                cand = _candidate(c, geo, i, t_a - k, k)
                if cand is None:
                    continue
                _add(c, geo, cand[0], cand[1], cand[2], cand[3], t_a, i)
                added += 1
                progress = True
                feasible, _, _ = _frame_feasible(c, geo, k, n, settings, records)
                if feasible.all():
                    break
            if not progress:
                break
    if not feasible.all():
        t_bad = k + int(np.argmin(feasible))
        if geo.reach_step is not None and t_bad > k:
            return t_bad - k
        _, deficit = _wrench_fit(c, geo, t_bad, settings)
        raise GraspUnsuitable(t_bad, deficit, tuple(geo.link_name(l) for l in c.link), window=k)
    return n


BALANCE_ALLOWANCE = 5e-3
"""Largest wrench deficit a planned frame may keep (:func:`_allow_small_deficits`), relative to the object's weight
for the force and to its weight times its largest extent for the torque: half the independent checker's 1 %
balance bound. A soft fingertip's torsional friction over a 2 mm patch at 0.5 N, about 8e-4 N m, is eight times
the torque this allows for the 0.05 kg roll cylinder."""


def allowed_deficit(geo: _Geometry, d: np.ndarray) -> bool:
    """Whether a wrench deficit ``d`` (6,) (force, torque about the COM; N, N m) is within ``BALANCE_ALLOWANCE``."""
    return bool(np.linalg.norm(d[:3]) <= BALANCE_ALLOWANCE * geo.weight
                and np.linalg.norm(d[3:]) <= BALANCE_ALLOWANCE * geo.weight * geo.extent)


def _allow_small_deficits(c: _Contacts, geo: _Geometry, k: int, n: int, feasible: np.ndarray,
                          settings: PlanSettings) -> bool:
    """Frames whose contacts miss the required wrench by a deficit within ``BALANCE_ALLOWANCE`` are planned for the
    nearest wrench they can produce, ``w - d`` (the least-squares fit of :func:`_wrench_fit`), instead of adding
    contacts (a deviation from Liu's exact Eq. 1, where Sec. 4.3 would add a contact or give up). The case is a
    pinch: two point contacts cannot produce a torque about the line through them, and a pinch line that misses
    the centre of mass by half a millimetre (a grasp is snapped to 0.1 mm, the synthesis moves the contacts) asks
    for one. Real fingertips are soft and give such torques by friction over their contact patch; the point-contact
    model does not have it, so a deficit this small is left unbalanced (the checker allows twice as much). The
    frames' wrenches go back to the required ones at the next window. Returns True when every infeasible frame of
    the window was within the allowance (and its wrench was moved)."""
    fixes = []
    for j in np.flatnonzero(~feasible):
        _, d = _wrench_fit(c, geo, k + int(j), settings)
        if not allowed_deficit(geo, d):
            return False
        fixes.append((k + int(j), d))
    for t, d in fixes:
        geo.wrench[t] = geo.wrench_required[t] - d
    return True
