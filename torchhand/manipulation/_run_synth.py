"""The synthesis step of the manipulation loop (:mod:`.manipulate`, Liu 2009 Sec. 5): every hand at frame k from the
planned forces, with the contacts' states (active, closing, sliding) and the added contacts' receding slack; and
the world positions of the hands' contact points."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .synth import HandFrame, synthesize_frame


@dataclass(frozen=True, eq=False)
class _Hands:
    """Every hand at one frame: (q (D_j,), root (4, 4)) per hand, and the contacts' points (H, 3) in their link's
    frame (h) and the object frame (p), in contact order (the contacts of all hands)."""

    frames: list
    h: np.ndarray
    p: np.ndarray


def _of_hand(geo, links: np.ndarray, j: int) -> np.ndarray:
    """(H,) bool: the contacts (numbered links ``links``) of hand j."""
    links = np.asarray(links)
    return (links >= geo.link_offset[j]) & (links < geo.link_offset[j + 1])


def _hand_points(geo, ts: list, links: np.ndarray, local: np.ndarray) -> np.ndarray:
    """World positions (H, 3) of the link-frame points ``local`` on the numbered ``links``, each from its hand's
    :func:`~.torque_derivs.tree_state` in ``ts``."""
    out = np.zeros((len(links), 3))
    for j, t in enumerate(ts):
        sel = _of_hand(geo, links, j)
        if sel.any():
            out[sel] = _link_points(t, links[sel] - geo.link_offset[j], np.asarray(local)[sel])
    return out


def _boundary(f: np.ndarray, n: np.ndarray, t1: np.ndarray, mu: float, ratio: float) -> bool:
    fn = float(f @ n)
    t2 = np.cross(n, t1)
    return fn > 0 and abs(f @ t1) + abs(f @ t2) >= ratio * mu * fn


@dataclass(frozen=True, eq=False)
class _SynthFrame:
    """Every hand synthesized at frame k (:func:`_synth_frame`; H contacts of all hands, in contact order).

    frames: (q (D_j,), root (4, 4)) per hand; h: contact points in their link frame, (H, 3); gap: each closing
    contact's distance to the object, (H,), metres (0 for the others); objective: summed over the hands;
    iterations, violation: the largest; converged: all hands'
    closing: added contacts active from k on, (H,) bool; active (H,) bool (the caller may release grasp contacts in
    it at k = 0); slide: sliding or on the cone boundary, (H,) bool; links: numbered links, (H,)
    prev: the frame k-1 with the added contacts' points appended; lam: lambda_k as planned, (H + E, 4)
    """

    frames: list
    h: np.ndarray
    gap: np.ndarray
    objective: float
    iterations: int
    converged: bool
    violation: float
    closing: np.ndarray
    active: np.ndarray
    slide: np.ndarray
    links: np.ndarray
    prev: _Hands
    lam: np.ndarray


def _synth_frame(run, ctxs, k: int, f_k: np.ndarray, prev: _Hands, pose_prev: np.ndarray, H_before: int,
                 added_k: dict, ss, older: list | None = None):
    """Synthesize frame k with the forces F_k just planned (Sec. 5), each hand with its own contacts: the contacts'
    states at k (active, closing, sliding) and the receding slack of the added contacts that are not active yet,
    ``sigma_j(k) = d_j (t_e - k) / (t_e - t_a)`` (t_a the frame that added it, t_e its first active frame, d_j its
    gap at t_a). Records (t_a, d_j) of contacts added since frame k-1 in ``added_k``. The hands share only the
    object and its forces (planned together); their syntheses are separate. ``older``: (q, root) per hand at frame
    k-2 for the inertial term (None: at rest).
    Returns a :class:`_SynthFrame`."""
    c, geo, pose = run.c, run.geo, run.geo.pose
    lam_k = run.out[-1][1]
    H = len(c.link)
    links = np.array(c.link)
    for i in range(H_before, H):                       # contacts added by this window
        if i not in added_k:
            j = geo.hand_of(links[i])
            q, root = prev.frames[j]
            x = _frame_points(geo.hands[j], HandFrame(q=q, root=root, h=None, p=None),
                              links[i:i + 1] - geo.link_offset[j], np.stack(c.h)[i:i + 1])[0]
            added_k[i] = (k, float(np.linalg.norm(x - (pose[k][:3, :3] @ c.p[i] + pose[k][:3, 3]))))
    start = np.array(c.start)
    source = np.array(c.source)
    active = start <= k
    closing = active & (start == k) & (source >= 0)
    approach = {}
    for i, (ta, d) in added_k.items():
        te = start[i]
        if k < te:
            approach[i] = d * (te - k) / max(te - ta, 1)
    Hp = len(prev.h)
    h_prev = np.concatenate([prev.h, np.stack(c.h)[Hp:]], 0) if H > Hp else prev.h
    p_prev = np.concatenate([prev.p, np.stack(c.p)[Hp:]], 0) if H > Hp else prev.p
    prev = _Hands(prev.frames, h_prev, p_prev)
    normals_prev = np.stack(c.n)
    n_w = normals_prev @ pose[k][:3, :3].T
    t1_w = np.stack(c.t1) @ pose[k][:3, :3].T
    slide = np.zeros(H, dtype=bool)                     # hand contacts are static unless Liu's rule is on
    if ss.sliding:
        slide = np.array([(i in c.slide) or (active[i] and _boundary(f_k[i], n_w[i], t1_w[i], geo.mu, ss.boundary))
                          for i in range(H)], dtype=bool)
    rel = pose[k] @ np.linalg.inv(pose_prev)
    out_frames, h_new, gap = [], h_prev.copy(), np.zeros(H)
    objective, iterations, converged, violation = 0.0, 0, True, 0.0
    for j, ctx in enumerate(ctxs):
        sel = np.flatnonzero(_of_hand(geo, links, j))
        local = {int(i): a for a, i in enumerate(sel)}
        q, root = prev.frames[j]
        before = HandFrame(q=q, root=root, h=h_prev[sel], p=p_prev[sel])
        guess = HandFrame(q=q.copy(), root=rel @ root, h=h_prev[sel].copy(), p=p_prev[sel])
        res = synthesize_frame(ctx, before, guess, links[sel] - geo.link_offset[j], f_k[:H][sel], active[sel],
                               pose[k], pose_prev, normals_prev[sel], slide[sel],
                               {local[i]: v for i, v in approach.items() if i in local}, closing[sel],
                               settle=k == 0,
                               before=None if older is None else HandFrame(q=older[j][0], root=older[j][1], h=None,
                                                                            p=None))
        out_frames.append((res.frame.q, res.frame.root))
        h_new[sel] = res.frame.h
        if res.gap is not None:
            gap[sel] = res.gap
        objective += res.objective
        iterations = max(iterations, res.iterations)
        converged = converged and res.converged
        violation = max(violation, res.violation)
    return _SynthFrame(frames=out_frames, h=h_new, gap=gap, objective=objective, iterations=iterations,
                       converged=converged, violation=violation, closing=closing, active=active, slide=slide,
                       links=links, prev=prev, lam=lam_k)


def _frame_points(hand, frame: HandFrame, links, local) -> np.ndarray:
    from .synth import _points
    return _points(hand, frame.q, frame.root, np.asarray(links), np.asarray(local))


def _link_points(ts, links, local) -> np.ndarray:
    """World positions (P, 3) of link-frame points ``local`` (P, 3) on ``links`` (P,), from a
    :func:`~.torque_derivs.tree_state` (the arithmetic of :func:`.synth._points`)."""
    links = np.asarray(links)
    if len(links) == 0:
        return np.zeros((0, 3))
    Tl = ts.T[links]
    return np.einsum("pij,pj->pi", Tl[:, :3, :3], np.asarray(local)) + Tl[:, :3, 3]
