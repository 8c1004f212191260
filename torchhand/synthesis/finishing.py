"""Finishing a searched path (:func:`finalize_solution`) as a program of work that many paths can share.

A path is finished by reconstructing its motion (§6) and testing the result frame by frame with the exact geometry;
a motion that fails gets its searched poses blended back in, or the converged reconstruction, in the order the
:mod:`.pipeline` docstring gives. :func:`finalize_steps` writes that as a generator: it yields its two kinds of work,
:class:`Reconstruct` (one reconstruction of the path) and :class:`Evaluate` (the contact and dynamic test of one
motion), is sent each one's result and returns ``(FinalSolution | None, reason)``. :func:`drive` runs one program
alone (:func:`finalize_solution`); :func:`run_works` runs the pending work of many programs together, each kind in
batches where the math allows:

* **Evaluate**: the motions of problems that the node test cannot tell apart (the same models, SDF, mesh, ground,
  frames, scalars and settings: the seeds of one scene) are tested as one evaluation of their frames concatenated
  (:func:`evaluate_motions`). A row's outputs do not depend on the other rows of its call (the node test's
  contract, :mod:`.multi`), so each motion's result is the one it gets alone.
* **Reconstruct**: the paths of one problem and setting are reconstructed together per hand
  (:func:`~.reconstruct.reconstruct_motions`: every decision of the solve is taken per path, a path that is done
  is held while the others go on), each result the one it has alone.

The search hands its paths to such programs (:meth:`.search._Search.rounds`), and :func:`.multi.search_lanes` runs
the work of all searches waiting on one together, so that a result is byte-identical to the search run alone.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import torch

from .node_test import CAUSE_DYNAMIC, FrameResult, NodeTestSettings, evaluate_poses
from .problem import SynthesisProblem, frames_key, node_context
from .reconstruct import ContactTrack, reconstruct_motions
from .search import Solution

__all__ = ["FinalSolution", "Reconstruct", "Evaluate", "finalize_solution", "finalize_steps", "drive", "drive_many",
           "clocked", "run_works", "evaluate_motions", "reconstruct_paths", "reconstruct_paths_together",
           "paths_per_call", "CPU_MAX_PATHS", "held_before", "max_joint_speed"]


@dataclass(frozen=True)
class FinalSolution:
    """A finished motion (T frames, H hands, K = H L + H F contact slots (``node_test.contact_slots``), E table
    slots).

    q: (T, H, D) radians; c_mask (T, K) bool; c_local (T, K, 3) link frame; c_point (T, K, 3) world, on the
    object surface; c_normal (T, K, 3) into the object; c_force (T, K, 3) newtons, hand on object;
    env_force (T, E, 3); guiding (T, H, F) bool; sliding (T, K) bool: contacts whose hand point slides on the
    object; reconstructed: whether q is the smoothed motion (False: the searched poses); index: order found
    """

    q: torch.Tensor
    c_mask: torch.Tensor
    c_local: torch.Tensor
    c_point: torch.Tensor
    c_normal: torch.Tensor
    c_force: torch.Tensor
    env_force: torch.Tensor
    guiding: torch.Tensor
    guide_obj: torch.Tensor
    sliding: torch.Tensor
    reconstructed: bool
    index: int


@dataclass(frozen=True, eq=False)
class Reconstruct:
    """Work: the reconstruction of ``sol`` with one of :data:`_RECONSTRUCTIONS`; its result is q (T, H, D)."""

    problem: SynthesisProblem
    sol: Solution
    ns: NodeTestSettings
    joint_speed: float
    settings: dict
    clock: list | None = None      # [seconds]: this work's time is added to clock[0] (:func:`clocked`)

    def run(self) -> torch.Tensor:
        return run_works([self])[0]

    def key(self) -> tuple:
        return ("reconstruct", node_context(self.problem), frames_key(self.problem), self.joint_speed,
                self.ns.pen_tol, self.ns.finger_tol, tuple(sorted(self.settings.items())))


@dataclass(frozen=True, eq=False)
class Evaluate:
    """Work: the contact and dynamic test of a motion q (T, H, D) (:func:`evaluate_motions`); its result is a
    :class:`~.node_test.FrameResult` of T rows."""

    problem: SynthesisProblem
    q: torch.Tensor
    ns: NodeTestSettings
    plan_mask: torch.Tensor | None = None
    exact: bool = True
    clock: list | None = None      # as :attr:`Reconstruct.clock`

    def run(self) -> FrameResult:
        return run_works([self])[0]

    def key(self) -> tuple:
        return ("evaluate", node_context(self.problem), frames_key(self.problem), repr(self.ns), self.exact)


def drive(program):
    """Run a generator of work (:func:`finalize_steps`) alone: each work is run as it is yielded; returns what the
    program returns."""
    try:
        work = next(program)
        while True:
            work = program.send(work.run())
    except StopIteration as done:
        return done.value


def drive_many(programs) -> list:
    """Run many generators of work (:func:`finalize_steps`) side by side: every step, the pending work of all that
    have not ended runs as one :func:`run_works`; returns what each program returns, in order. Each result is the
    one :func:`drive` gives it alone."""
    programs = list(programs)
    out: list = [None] * len(programs)
    pending: dict = {}

    def advance(k: int, sent=None, first: bool = False) -> None:
        try:
            pending[k] = next(programs[k]) if first else programs[k].send(sent)
        except StopIteration as done:
            pending.pop(k, None)
            out[k] = done.value

    for k in range(len(programs)):
        advance(k, first=True)
    while pending:
        keys = sorted(pending)
        for k, result in zip(keys, run_works([pending[k] for k in keys])):
            advance(k, result)
    return out


def clocked(program, clock: list):
    """The generator of work ``program`` with the time of its own steps and of its works (each work's share of
    the batch it ran in, :func:`run_works`) added to ``clock[0]``, seconds."""
    t0 = time.perf_counter()
    try:
        work = next(program)
        while True:
            clock[0] += time.perf_counter() - t0
            result = yield dataclasses.replace(work, clock=clock)
            t0 = time.perf_counter()
            work = program.send(result)
    except StopIteration as done:
        clock[0] += time.perf_counter() - t0
        return done.value


def run_works(works: list) -> list:
    """The results of ``works`` (of many programs), in order: the works of one kind and key (:meth:`Evaluate.key`,
    :meth:`Reconstruct.key`) run as one batch, whose time is shared evenly by its works' clocks."""
    groups: dict = {}
    for k, w in enumerate(works):
        groups.setdefault(w.key(), []).append(k)
    out: list = [None] * len(works)
    for idx in groups.values():
        batch = [works[k] for k in idx]
        t0 = time.perf_counter()
        results = evaluate_motions(batch) if isinstance(batch[0], Evaluate) else reconstruct_paths(batch)
        share = (time.perf_counter() - t0) / len(batch)
        for k, r in zip(idx, results):
            out[k] = r
            if works[k].clock is not None:
                works[k].clock[0] += share
    return out


def _rows(res: FrameResult, a: int, b: int) -> FrameResult:
    """The rows [a, b) of a frame result."""
    return FrameResult(**{f.name: getattr(res, f.name)[a:b] for f in dataclasses.fields(FrameResult)})


def evaluate_motions(works: list) -> list:
    """The contact and dynamic test of several whole motions (:class:`Evaluate` works of one key), each q (T_i, H, D),
    with the search's sliding rule (a contact held since the previous frame whose hand point moves on the object
    faster than ``ns.slide_speed`` slides): one pass for the contacts, a second with each frame's predecessor, and
    a longer force solve for the frames whose solve stopped at its iteration limit. Every pass tests the frames of
    all motions in one call. Returns each motion's :class:`~.node_test.FrameResult` of the second pass.

    plan_mask: the searched path's contact slots (T, K) bool. A slot the path establishes at frame t is landing
    there: it counts as new at t (it cannot slide), as in the search, even where the smoothed finger came within the
    contact distance a frame earlier, on its way in."""
    lead = works[0]
    problem = lead.problem
    sizes = [w.q.shape[0] for w in works]
    t = torch.cat([torch.arange(n, device=w.q.device) for n, w in zip(sizes, works)])
    q = torch.cat([w.q for w in works])
    ns = dataclasses.replace(lead.ns, cone_tol=None, cone_iters=None, cone_polish=True, cone_polish_from=None,
                             exact=lead.exact)                             # full accuracy, the mesh's normals
    # contacts only (their normals do not matter here: the grid's, not the mesh's)
    first = evaluate_poses(problem, t, q, settings=dataclasses.replace(ns, exact=False), dynamics=False)
    starts = [sum(sizes[:k]) for k in range(len(works))]
    prev_mask = torch.cat([held_before(first.c_mask[a:a + n], w.plan_mask) for a, n, w in zip(starts, sizes, works)])
    q_prev = torch.cat([torch.cat([w.q[:1], w.q[:-1]]) for w in works])
    res = evaluate_poses(problem, t, q, q_prev, prev_mask, settings=ns)
    retry = (res.cause == CAUSE_DYNAMIC).nonzero().squeeze(-1)
    if retry.numel():
        # a force solve that stopped at its iteration limit gets a longer one before the frame counts as failed
        again = evaluate_poses(problem, t[retry], q[retry], q_prev[retry], prev_mask[retry],
                               settings=dataclasses.replace(ns, cone_iters=20000))
        res = _rows_replaced(res, retry, again)
    return [_rows(res, a, a + n) for a, n in zip(starts, sizes)]


def _evaluate_motion(problem: SynthesisProblem, q: torch.Tensor, ns: NodeTestSettings, exact: bool = True,
                     plan_mask: torch.Tensor | None = None) -> FrameResult:
    """:func:`evaluate_motions` of one motion q (T, H, D)."""
    return evaluate_motions([Evaluate(problem, q, ns, plan_mask, exact)])[0]


def held_before(c_mask: torch.Tensor, plan_mask: torch.Tensor | None = None) -> torch.Tensor:
    """Which contact slots (T, K) were held at the previous frame (and so may slide), from a motion's contacts
    ``c_mask`` (T, K) bool; with the searched path's ``plan_mask`` (T, K), a slot the path establishes at frame t
    (off at t - 1, on at t) counts as landing: not held at t."""
    prev = torch.cat([torch.zeros_like(c_mask[:1]), c_mask[:-1]])
    if plan_mask is None:
        return prev
    landing = plan_mask & ~torch.cat([torch.zeros_like(plan_mask[:1]), plan_mask[:-1]])
    return prev & ~landing


def _blend_in(q_smooth: torch.Tensor, q_search: torch.Tensor, bad: torch.Tensor, width: float = 2.0) -> torch.Tensor:
    """q_smooth with the searched poses blended back in around the frames ``bad`` (T,) bool: weight 1 at a bad
    frame, falling off as exp(-(d / width)^2) with the distance d in frames."""
    T = q_smooth.shape[0]
    idx = bad.nonzero().squeeze(-1).to(q_smooth.dtype)
    t = torch.arange(T, device=q_smooth.device, dtype=q_smooth.dtype)
    w = torch.exp(-(((t[:, None] - idx[None]) / width) ** 2)).amax(-1).reshape(T, 1, 1)
    return (1 - w) * q_smooth + w * q_search


def max_joint_speed(q: torch.Tensor, fps: float) -> float:
    """Largest |dq/dt| of a motion q (T, ...) radians, by forward differences, rad/s (0 for one frame)."""
    return float((q[1:] - q[:-1]).abs().amax()) * fps if q.shape[0] > 1 else 0.0


def finalize_solution(problem: SynthesisProblem, sol: Solution, index: int, *, ns: NodeTestSettings,
                      reconstruct: bool = True, joint_speed: float = 8.0,
                      keep_unsmoothed: bool = False) -> tuple[FinalSolution | None, str]:
    """Reconstruct and re-check one searched path (see the :mod:`.pipeline` docstring): :func:`finalize_steps` run
    alone."""
    return drive(finalize_steps(problem, sol, index, ns=ns, reconstruct=reconstruct, joint_speed=joint_speed,
                                keep_unsmoothed=keep_unsmoothed))


def finalize_steps(problem: SynthesisProblem, sol: Solution, index: int, *, ns: NodeTestSettings,
                   reconstruct: bool = True, joint_speed: float = 8.0, keep_unsmoothed: bool = False):
    """Generator: the finishing of one searched path, yielding its work (:class:`Reconstruct`, :class:`Evaluate`)
    and sent each one's result. Tried in turn, for the fast reconstruction and then the converged one
    (``_RECONSTRUCTIONS``): the smoothed motion (table and the joint-speed bound ``joint_speed`` rad/s are
    constraints of the reconstruction); the smoothed motion with the searched poses blended back in around the
    frames that failed, if it keeps the speed bound. Then, with ``keep_unsmoothed`` (or ``reconstruct`` False),
    the searched poses. Contacts the path establishes at a frame count as landing there (``plan_mask``). Returns
    (the first that passes the contact and dynamic test in every frame, "ok") or (None, "failed_check" |
    "unsmoothed")."""
    def attempt(q):
        res = yield Evaluate(problem, q, ns, sol.c_mask)
        return res, res.c_sliding

    speed_ok = lambda q: max_joint_speed(q, problem.fps) <= joint_speed * (1 + 1e-3)  # noqa: E731
    candidates = []
    for settings in (_RECONSTRUCTIONS if reconstruct else ()):
        q_rec = yield Reconstruct(problem, sol, ns, joint_speed, settings)
        if not speed_ok(q_rec):
            continue
        res, sliding = yield from attempt(q_rec)
        candidates.append((q_rec, res, sliding, True))
        if not bool(res.feasible.all()):
            q_mix = _blend_in(q_rec, sol.q, ~res.feasible)
            if speed_ok(q_mix):
                res, sliding = yield from attempt(q_mix)
                candidates.append((q_mix, res, sliding, True))
        if bool(candidates[-1][1].feasible.all()):
            break
    smoothed_ok = bool(candidates) and bool(candidates[-1][1].feasible.all())
    if not smoothed_ok:
        res, sliding = yield from attempt(sol.q)
        if reconstruct and not keep_unsmoothed:
            return None, "unsmoothed" if bool(res.feasible.all()) else "failed_check"
        candidates.append((sol.q, res, sliding, False))
    q, res, sliding, smoothed = candidates[-1]
    if not bool(res.feasible.all()):
        return None, "failed_check"
    return FinalSolution(q=q, c_mask=res.c_mask, c_local=res.c_local, c_point=res.c_point, c_normal=res.c_normal,
                         c_force=res.c_force, env_force=res.env_force, guiding=sol.guiding, guide_obj=sol.guide_obj,
                         sliding=sliding, reconstructed=smoothed, index=index), "ok"


_RECONSTRUCTIONS = (dict(max_inner=8, step_tol=1e-3), dict(max_inner=30, step_tol=1e-4))
"""Reconstruction settings tried in turn by :func:`finalize_solution`: the fast one (a quarter of the time, enough
on most paths), then Gauss-Newton converged to 1e-4 rad where the fast one's motion fails the final test."""


def _reconstruct_path(problem: SynthesisProblem, sol: Solution, ns: NodeTestSettings, joint_speed: float,
                      settings: dict) -> torch.Tensor:
    """The searched path's reconstruction (§6) per hand, with its contacts kept, the table and the joint-speed bound,
    (T, H, D)."""
    return reconstruct_paths([Reconstruct(problem, sol, ns, joint_speed, settings)])[0]


CPU_MAX_PATHS = 1
"""On a CPU, :func:`reconstruct_paths` reconstructs at most this many paths per call (None: all). The reconstruction's
time on a CPU is its dense float64 factorisations and the (S n)^2 matrices of every finger, which leave the cache as
the batch grows: on two cores 8 of box-turn's paths took 16.7 s one at a time, 17.8 s in pairs and 19.5 s in fours
(BENCHMARKS.md, "Finishing side by side"). A GPU takes them in one call. No choice changes a result."""


def reconstruct_paths(works: list) -> list:
    """The reconstructions of :class:`Reconstruct` works of one key (one problem and setting), q (T, H, D) each: per
    hand, the paths in one :func:`~.reconstruct.reconstruct_motions` (each result is its path's alone; on a CPU in
    calls of :data:`CPU_MAX_PATHS`)."""
    most = paths_per_call(works[0].problem, works[0].sol.q.device)
    if most is not None and len(works) > most:
        return [q for i in range(0, len(works), most) for q in reconstruct_paths_together(works[i:i + most])]
    return reconstruct_paths_together(works)


def paths_per_call(problem: SynthesisProblem, device: torch.device) -> int | None:
    """How many paths :func:`reconstruct_paths` reconstructs per call (None: all): :data:`CPU_MAX_PATHS` on a CPU, and
    one path per call for a problem with a one-finger hand, whose lone finger matrices a batch would multiply with
    other kernels than alone (with two fingers or more, alone is already a batch of matrices)."""
    if any(hand.num_fingers < 2 for hand in problem.hands):
        return 1
    return CPU_MAX_PATHS if torch.device(device).type == "cpu" else None


def reconstruct_paths_together(works: list) -> list:
    """:func:`reconstruct_paths` in one call per hand, whatever the device."""
    lead = works[0]
    problem, ns = lead.problem, lead.ns
    per_hand = []
    for h, hand in enumerate(problem.hands):
        q = torch.stack([w.sol.q[:, h] for w in works])
        recs = reconstruct_motions(hand, problem.root[h], q, [_contact_track(problem, h, w.sol) for w in works],
                                   sdf=problem.sdf, object_pose=problem.object_pose, penetration_tol=0.5 * ns.pen_tol,
                                   table_height=problem.table_height, finger_tol=0.5 * ns.finger_tol,
                                   max_joint_step=lead.joint_speed / problem.fps, ground=problem.ground,
                                   **lead.settings)
        per_hand.append([r.q.to(q.dtype) for r in recs])
    return [torch.stack([qs[k] for qs in per_hand], 1) for k in range(len(works))]


def _contact_track(problem: SynthesisProblem, h: int, sol: Solution) -> ContactTrack:
    """Hand ``h``'s contacts of a searched path, kept by its reconstruction: each contact's hand point and where the
    searched pose puts it."""
    hand = problem.hands[h]
    L = hand.num_links
    sl = slice(h * L, (h + 1) * L)
    poses = hand.forward_kinematics(sol.q[:, h], problem.root[h])
    link = torch.arange(L, device=sol.q.device).expand(sol.q.shape[0], L)
    loc = sol.c_local[:, sl]
    target = (poses[..., :3, :3] @ loc.unsqueeze(-1)).squeeze(-1) + poses[..., :3, 3]
    return ContactTrack(link=link, point_local=loc, target=target, mask=sol.c_mask[:, sl] & (hand.link_finger >= 0))


def _rows_replaced(res: FrameResult, index: torch.Tensor, values: FrameResult) -> FrameResult:
    """``res`` with the rows ``index`` (n,) replaced by those of ``values`` (n rows)."""
    def put(a, b):
        out = a.clone()
        out[index] = b
        return out
    return FrameResult(**{f.name: put(getattr(res, f.name), getattr(values, f.name))
                          for f in dataclasses.fields(FrameResult)})
