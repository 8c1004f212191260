"""One expansion round of the contact search (:mod:`.search`): every candidate plan of every job tested frame by
frame over its window by the batched node test, and the outcome regrouped per job.

The candidates' guiding state is one :class:`Candidates` record of batched tensors (the rows are candidates);
the per-frame outputs of the node test are collected in :class:`WindowOutcome`; each job gets an
:class:`Expansion`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch

from ._node_kinematics import rolled_local
from .node_test import (CAUSE_DYNAMIC, CAUSE_FINGERS, CAUSE_KINEMATIC, CAUSE_NONE, FORCE_ZERO, Guides,
                        contact_slots, run_node_test)

if TYPE_CHECKING:  # pragma: no cover
    from .search import _Search

__all__ = ["Candidates", "WindowOutcome", "Expansion", "expand", "candidates", "test_windows", "regroup"]

_STATIC, _SLIDE, _RELOCATE, _FREE, _ROLL = 0, 1, 2, 3, 4   # a finger's part in a plan: keep, slide, relocate, let
#                                                            go, roll (keep the object point, the finger's moves)
KEEP = ("q", "c_mask", "c_local", "c_point", "c_normal", "c_force", "env_force", "seed_on", "seed_link",
        "seed_local", "seed_obj", "seed_class", "seed_tdir")


@dataclass(frozen=True)
class Candidates:
    """The guiding state of N candidates (one per plan of every job), batched; some tensors are advanced in place
    while the window is tested (``obj``, ``slide`` of sliding contacts, ``q_prev``, ``prev_mask``).

    t0: the frame each window starts at, (N,); w: window lengths, (N,); active, link, local, obj, slide: the
    guiding points per hand and finger, (N, H, F[, 3]); land: the first guided frame of a relocation, (N, H, F);
    was_on: the finger touched at the previous frame; q_prev: previous joint angles, (N, H, D); first: the window
    starts the motion, (N,); weights: the fingers' force weights; prev_mask: the previous frame's contacts, (N, K);
    roll: the finger rolls (its guiding point on the finger is re-chosen every frame as the point of its link's
    capsule facing its object point), (N, H, F).
    """

    t0: torch.Tensor
    w: torch.Tensor
    active: torch.Tensor
    link: torch.Tensor
    local: torch.Tensor
    obj: torch.Tensor
    slide: torch.Tensor
    land: torch.Tensor
    was_on: torch.Tensor
    q_prev: torch.Tensor
    first: torch.Tensor
    weights: torch.Tensor
    prev_mask: torch.Tensor
    roll: torch.Tensor


@dataclass(frozen=True)
class WindowOutcome:
    """Per candidate: still feasible after its window (``alive``), the node test's per-frame outputs (``frames``:
    :data:`KEEP` names -> list over frames of (N, ...); ``g_frames``: the guiding points per frame), and for the
    failed ones the cause, the frame within the window and the fingers involved."""

    alive: torch.Tensor
    frames: dict
    g_frames: dict
    fail_cause: torch.Tensor
    fail_k: torch.Tensor
    fail_fingers: list


@dataclass(frozen=True)
class Expansion:
    """What one job's expansion found: its feasible windows as (frames, guides) pairs, and for the first failed
    candidate the failure (cause, fingers, frame) and the plan it tried (``template``)."""

    feasible: list
    fail: tuple | None
    template: object


def expand(search: "_Search", jobs) -> list[Expansion]:
    """jobs: list of (tree, node, plans, w). Tests every plan over its window; returns per job its
    :class:`Expansion`."""
    cand, c = candidates(search, jobs)
    outcome = run_windows(search, cand, c)
    return regroup(jobs, cand, outcome)


def candidates(search: "_Search", jobs) -> tuple[list, Candidates]:
    """The candidates of ``jobs`` flattened, (job, node, plan, w) each, and their batched guiding state."""
    p, H, F = search.p, search.H, search.F
    device, dtype = p.device, p.dtype
    # flatten candidates
    cand = []
    for j, (tree, node, plans, w) in enumerate(jobs):
        for plan in plans:
            cand.append((j, node, plan, w))
    N = len(cand)
    t0 = torch.tensor([c[1].t1 for c in cand], device=device)
    w = torch.tensor([c[3] for c in cand], device=device)
    active = torch.zeros(N, H, F, dtype=torch.bool, device=device)
    link = search.tip_link.expand(N, H, F).clone()
    local = search.tip_local.expand(N, H, F, 3).clone()
    obj = torch.zeros(N, H, F, 3, dtype=dtype, device=device)
    slide = torch.zeros(N, H, F, 3, dtype=dtype, device=device)
    land = torch.zeros(N, H, F, dtype=torch.long, device=device)       # first guided frame of a relocation
    was_on = torch.zeros(N, H, F, dtype=torch.bool, device=device)     # finger touched at the previous frame
    q_prev = search.q_rest.expand(N, H, -1).clone()
    first = torch.zeros(N, dtype=torch.bool, device=device)
    weights = torch.ones(N, H, F, dtype=dtype, device=device)
    K = contact_slots(p)[0].numel()
    prev_mask = torch.zeros(N, K, dtype=torch.bool, device=device)   # hand contacts of the previous frame
    roll = torch.zeros(N, H, F, dtype=torch.bool, device=device)
    for i, (j, node, plan, wi) in enumerate(cand):
        if node.frames is None:
            first[i] = True
        else:
            q_prev[i] = node.frames["q"][-1]
            was_on[i] = node.frames["seed_on"][-1]
            prev_mask[i] = node.frames["c_mask"][-1]
            zero = node.frames["seed_class"][-1] == FORCE_ZERO
            if search.s.strategy in ("relocating", "mixed", "gait"):
                weights[i] = torch.where(zero | ~node.frames["seed_on"][-1],
                                         torch.full_like(weights[i], search.s.free_weight), weights[i])
        for gi, (kind, sample, land_k) in enumerate(plan):
            h, f = divmod(gi, F)
            if kind in (_STATIC, _SLIDE, _ROLL):
                active[i, h, f] = True
                roll[i, h, f] = kind == _ROLL
                link[i, h, f] = node.frames["seed_link"][-1, h, f]
                local[i, h, f] = node.frames["seed_local"][-1, h, f]
                obj[i, h, f] = node.frames["seed_obj"][-1, h, f]
                if kind == _SLIDE:
                    slide[i, h, f] = node.frames["seed_tdir"][-1, h, f]
            elif kind == _RELOCATE and sample >= 0:
                active[i, h, f] = True
                obj[i, h, f] = p.surface[sample]
                land[i, h, f] = min(land_k, wi - 1)
    return cand, Candidates(t0=t0, w=w, active=active, link=link, local=local, obj=obj, slide=slide, land=land, was_on=was_on, q_prev=q_prev, first=first, weights=weights, prev_mask=prev_mask, roll=roll)


def run_windows(search: "_Search", cand: list, c: Candidates) -> WindowOutcome:
    """Run the node test over every candidate's window, frame by frame, the sliding guides advanced along the
    surface; a candidate stops at its first infeasible frame."""
    owner = torch.zeros(len(cand), dtype=torch.long)
    return test_windows(search.p, search.ns, search.s.slide_speed, c, [search.stats], owner)


def _tally(books: list, owner: torch.Tensor, rows: torch.Tensor) -> list[int]:
    """How many of ``rows`` (indices into ``owner``) belong to each of the ``books``."""
    return torch.bincount(owner[rows.cpu()], minlength=len(books)).tolist()


def _count(books: list, owner: torch.Tensor, sel: torch.Tensor, cause: torch.Tensor, frames: torch.Tensor) -> None:
    """A frame's counters, each row's to the search that owns it: node tests, dead ends, rejections by cause and
    by frame. sel: the rows tested (n,); cause: their verdicts (n,); frames: their frames (n,)."""
    bad = cause != CAUSE_NONE
    for book, n_run, n_bad in zip(books, _tally(books, owner, sel), _tally(books, owner, sel[bad])):
        book.nodes_tested += n_run
        book.dead_ends += n_bad
    for cause_id, name in ((CAUSE_KINEMATIC, "kinematic"), (CAUSE_FINGERS, "finger_finger"),
                           (CAUSE_DYNAMIC, "dynamic")):
        for book, n in zip(books, _tally(books, owner, sel[cause == cause_id])):
            book.rejections[name] += n
    for r, tf, c_id in zip(sel[bad].tolist(), frames[bad].tolist(), cause[bad].tolist()):
        books[int(owner[r])].rejections_by_frame[tf][c_id - 1] += 1


def test_windows(p, ns, slide_speed: float, c: Candidates, books: list, owner: torch.Tensor,
                 on_call=None, max_rows: int | None = None, shift: torch.Tensor | None = None,
                 speeds: torch.Tensor | None = None) -> WindowOutcome:
    """:func:`run_windows` for candidates of one or many searches that share the problem's node-test fields (the
    same scene prepared once, :mod:`.multi`): the rows are tested together and each frame's counters go to the
    :class:`~.search.SearchStats` in ``books`` that owns the row (``owner`` (N,) long, CPU). A row's outputs do
    not depend on the other rows of the batch. on_call: optional callable(n) with each node-test call's batch size;
    max_rows: a frame's rows are tested in calls of at most this many (None: one call). shift: per row, where its
    search's frame 0 lies in ``p``'s frames (N,) long (problems of many frame ranges stacked into one, :mod:`.multi`;
    the counters keep the search's own frames); speeds: per row (slide speed, table slide speed), (N, 2) float64,
    in place of ``ns``'s (:func:`.node_test.run_node_test`)."""
    device = p.device
    N = int(c.t0.shape[0])
    t0, w, active, link, local, obj, slide, land = c.t0, c.w, c.active, c.link, c.local, c.obj, c.slide, c.land
    q_prev, prev_mask, roll = c.q_prev, c.prev_mask, c.roll
    any_roll = bool(roll.any())
    out = WindowOutcome(alive=torch.ones(N, dtype=torch.bool, device=device), frames={k: [] for k in KEEP},
                        g_frames={k: [] for k in ("guiding", "guide_obj", "guide_link", "guide_local")},
                        fail_cause=torch.zeros(N, dtype=torch.long, device=device),
                        fail_k=torch.zeros(N, dtype=torch.long, device=device), fail_fingers=[None] * N)
    for k in range(int(w.max())):
        sel = (out.alive & (k < w)).nonzero().squeeze(-1)
        if sel.numel() == 0:
            break
        if k > 0:
            _advance_slides(p, obj, slide, sel, slide_speed / p.fps)
        act_k = active[sel] & (land[sel] <= k)
        guides = Guides(act_k, link[sel], local[sel], obj[sel], slide[sel] * act_k[..., None],
                        roll=roll[sel] & act_k if any_roll else None)
        lands = active[sel] & (land[sel] == k) & ((k > 0) | ~c.was_on[sel])
        t_p = t0[sel] + k if shift is None else t0[sel] + k + shift[sel]
        res = _node_tests(p, t_p, q_prev[sel], lands | (c.first[sel] & (k == 0))[:, None, None], guides,
                          c.weights[sel], ns, prev_mask[sel], max_rows, on_call,
                          None if speeds is None else speeds[sel])
        _count(books, owner, sel, res.cause, t0[sel] + k)
        _record_failures(out, sel, res, k)
        q_prev[sel] = res.q
        prev_mask[sel] = res.c_mask
        if any_roll:                 # a rolling finger's guiding hand point is where the test put it this frame
            local[sel] = rolled_local(p, t_p, res.q, guides, ns)
        _record_frame(out, sel, res, act_k, c)
    return out


def _advance_slides(p, obj: torch.Tensor, slide: torch.Tensor, sel: torch.Tensor, step: float) -> None:
    """Sliding guides of rows ``sel`` advance ``step`` metres along the surface, re-projected with the SDF; their
    directions stay tangent (``obj``, ``slide`` (N, H, F, 3) object frame, in place)."""
    moving = slide[sel].norm(dim=-1, keepdim=True) > 0
    pnew = obj[sel] + step * slide[sel]
    sd, grad = p.sdf.query_with_grad(pnew.reshape(1, -1, 3))
    n = grad.reshape(pnew.shape) / grad.reshape(pnew.shape).norm(dim=-1, keepdim=True).clamp_min(1e-9)
    pnew = pnew - sd.reshape(pnew.shape[:-1])[..., None] * n
    sdir = slide[sel] - (slide[sel] * n).sum(-1, keepdim=True) * n
    sdir = sdir / sdir.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    obj[sel] = torch.where(moving, pnew, obj[sel])
    slide[sel] = torch.where(moving, sdir, slide[sel])


def _record_failures(out: WindowOutcome, sel: torch.Tensor, res, k: int) -> None:
    """Rows of ``sel`` that failed frame k of their window: their cause, frame and the fingers (kinematic) or the
    finger pair (finger-finger) to blame; they stop here."""
    ok = res.feasible
    bad = sel[~ok]
    out.fail_cause[bad] = res.cause[~ok]
    out.fail_k[bad] = k
    for r in (~ok).nonzero().squeeze(-1).tolist():
        gi = sel[r].item()
        if res.cause[r] == CAUSE_KINEMATIC:
            out.fail_fingers[gi] = res.kin_fail[r].flatten().nonzero().squeeze(-1).tolist()
        elif res.cause[r] == CAUSE_FINGERS:
            out.fail_fingers[gi] = res.pair[r].tolist()
    out.alive[bad] = False


def _record_frame(out: WindowOutcome, sel: torch.Tensor, res, act_k: torch.Tensor, c: Candidates) -> None:
    """This frame's outputs for every candidate (rows not run stay unused) and the guides as they stand."""
    N, H, F = c.active.shape
    for key in KEEP:
        full = getattr(res, key)
        buf = torch.zeros((N,) + tuple(full.shape[1:]), dtype=full.dtype, device=full.device)
        buf[sel] = full
        out.frames[key].append(buf)
    gl = torch.zeros(N, H, F, dtype=torch.bool, device=act_k.device)
    gl[sel] = act_k
    out.g_frames["guiding"].append(gl)
    out.g_frames["guide_obj"].append(c.obj.clone())
    out.g_frames["guide_link"].append(c.link.clone())
    out.g_frames["guide_local"].append(c.local.clone())


def _node_tests(p, t, q_prev, first, guides: Guides, weights, ns, prev_mask, max_rows, on_call, speeds=None):
    """:func:`run_node_test` of the rows, in calls of at most ``max_rows`` rows of near-equal size (every row's
    answer is its own, so the split changes nothing but the time)."""
    n = int(t.shape[0])
    parts = 1 if max_rows is None or n <= max_rows else -(-n // max_rows)
    results = []
    for idx in torch.arange(n, device=t.device).tensor_split(parts):
        g = guides.rows(idx) if parts > 1 else guides
        rows = (lambda x: x[idx]) if parts > 1 else (lambda x: x)
        results.append(run_node_test(p, rows(t), rows(q_prev), rows(first), g, rows(weights), settings=ns,
                                     prev_mask=rows(prev_mask), speeds=None if speeds is None else rows(speeds)))
        if on_call is not None:
            on_call(int(idx.numel()))
    if parts == 1:
        return results[0]
    return type(results[0])(**{f.name: torch.cat([getattr(r, f.name) for r in results])
                               for f in dataclasses.fields(results[0])})


def regroup(jobs, cand: list, o: WindowOutcome) -> list[Expansion]:
    """Per job: the feasible candidates' windows (frames stacked over the window) and the first failure."""
    alive, frames, g_frames, fail_cause, fail_k, fail_fingers = (o.alive, o.frames, o.g_frames, o.fail_cause, o.fail_k,
                                                                 o.fail_fingers)
    feasible: list[list] = [[] for _ in jobs]
    fail: list = [None] * len(jobs)
    template: list = [None] * len(jobs)
    for i, (j, node, plan, wi) in enumerate(cand):
        if bool(alive[i]):
            fr = {key: torch.stack([frames[key][k][i] for k in range(wi)]) for key in KEEP}
            gd = {key: torch.stack([g_frames[key][k][i] for k in range(wi)]) for key in g_frames}
            feasible[j].append((fr, gd))
        elif fail[j] is None:
            fail[j] = (int(fail_cause[i]), fail_fingers[i] or [], int(fail_k[i]))
            template[j] = plan
    return [Expansion(feasible[j], fail[j], template[j]) for j in range(len(jobs))]
