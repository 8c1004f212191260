"""Randomized depth-first search over contact points (Ye & Liu 2012, Algorithms 1–2 and §5), many trees at once.

Every tree is a depth-first traversal whose nodes are windows of frames (sparse exploration, §5): a node keeps one
manipulation strategy per finger (static, sliding, relocating, free) for a window whose length is drawn uniformly
from ``[ceil(W/2), ceil(3W/2)]`` with ``W = T / epsilon``, so a path has about ``epsilon`` nodes whatever the clip
length. Expanding a node draws ``candidates`` guiding configurations from the contact-dynamics sampling rules of
§4.2 (force inside the cone: static; on its boundary: static or slide along the tangential force; zero: static
or relocate to a neighbouring point; free fingers may establish contact on their pruned patch samples) and tests
them frame by frame; the candidates of all trees form one batch per frame (:func:`~.node_test.run_node_test`).
The ``gait`` strategy adds rolling (§7, finger gaits): a rolling finger keeps its point on the object while its
point on the finger is re-chosen as the point of its capsule facing it, and a static contact that the finger
failed to keep is retried rolling ("fingers start rolling when it becomes kinematically difficult to maintain a
static contact"); a loaded finger never slides ("for the contacting fingers, rolling becomes the only feasible
strategy"): a force on its cone's boundary keeps it static, so a turn beyond a finger's range needs relocation.

Batched reading of Algorithm 2: the ``candidates`` siblings of an expansion are tested together; the first
feasible one in random order becomes the child (PickOneNode), the other feasible ones are kept and are the next
children when the search backtracks to this node, chosen most different from the explored children (§5,
diversity). A node gets 1 or 2 children (probability 1/2 each: "branch once in every two chances") and at most
``max_expansions`` expansions (maxBranchFactor); after a tree has produced 2 or 3 solutions from one initial sample
(mean 2.5, §5) it restarts from a new one. Informed backtracking (§5): after a failed expansion the next one
resamples only the finger that failed the kinematic test, one finger of an interpenetrating pair (the sample
farthest from the other finger), or every finger after a dynamic failure. One candidate after a kinematic
failure is a release plan: every finger that failed or carried no force lets go and the loaded ones stay static
(a deviation that the paper's rules imply but rarely draw: a hand leaving the object must release all its idle
fingers in one window, and independent per-finger draws give that with probability about 2^-5 per hand). Each
tree draws from its own ``torch.Generator`` (seeded ``seed + tree``), so a seed reproduces the run.

Stopping: after ``solutions`` accepted paths, after the round in which ``max_nodes`` node tests were run, or (with
``stall_nodes``) when no path has reached the last frame and the deepest frame has not advanced in that many node
tests: a wall no path gets through, where more of the same search is wasted. The deepest path grown is kept and
can be returned (``search(..., partial=[])``): a caller that covers a long clip in pieces goes on from it.
"""

from __future__ import annotations

import inspect
import math
import time
from dataclasses import dataclass, field

import torch

from .initial import InitialSamples
from .node_test import (CAUSE_FINGERS, CAUSE_KINEMATIC, FORCE_BOUNDARY, FORCE_INSIDE, FORCE_ZERO,
                        NodeTestSettings, pad_points)
from .problem import SynthesisProblem
from ._search_expand import _FREE, _RELOCATE, _ROLL, _SLIDE, _STATIC, KEEP, expand

__all__ = ["SearchSettings", "SearchStats", "Solution", "search", "STRATEGIES"]

STRATEGIES = ("static", "sliding", "relocating", "mixed", "gait")


@dataclass(frozen=True)
class SearchSettings:
    """Parameters of the search (Ye & Liu §5). Times in seconds, lengths in metres."""

    epsilon: float = 10.0          # expected number of nodes per path (sparse exploration)
    trees: int = 16                # trees grown in parallel
    candidates: int = 8            # guiding configurations tested per expansion
    max_expansions: int = 4        # expansions of one node before backtracking (maxBranchFactor)
    strategy: str = "mixed"        # manipulation-strategy preference
    slide_speed: float = 0.03      # how fast a sliding contact moves on the surface, m/s
    relocate_radius: float = 0.03  # neighbourhood of a relocation, metres
    establish: float = 0.35        # probability that a free finger with patch samples establishes contact
    free_weight: float = 3.0       # contact-force preference: weight of fingers that applied no force before
    solutions: int = 10            # stop after this many accepted solutions
    max_nodes: int | None = None   # stop after the round in which this many node tests (frames) were run: a
    #                                budget in work units, so a seed gives the same run on any machine
    time_budget: float | None = None   # wall-clock cap, seconds (None: none); a run stopped by it depends on the
    #                                machine's speed and load
    stall_nodes: int | None = None  # stop when no path has reached the last frame and the deepest frame has not
    #                                advanced in this many node tests (a wall; work units, None: never)


@dataclass
class SearchStats:
    """Counters of one run (Ye & Liu Table 1 and more)."""

    nodes_tested: int = 0            # frame tests (kinematic + dynamic)
    dead_ends: int = 0               # infeasible frames met
    rejections: dict = field(default_factory=lambda: {"kinematic": 0, "finger_finger": 0, "dynamic": 0})
    success_frames: int = 0
    time_s: float = 0.0
    restarts: int = 0
    deepest_frame: int = 0           # the furthest frame any path reached
    rejections_by_frame: list = field(default_factory=list)   # per frame [kinematic, finger_finger, dynamic]
    paths_found: int = 0             # distinct full paths found (accepted or not)
    stopped_by: str = ""             # "solutions", "max_nodes", "stalled" or "time_budget"


@dataclass(frozen=True)
class Solution:
    """One feasible path: per frame (T) the node-test outputs and the guiding configuration.

    q (T, H, D); c_mask (T, K); c_local, c_point, c_normal, c_force (T, K, 3); env_force (T, E, 3);
    guiding (T, H, F) bool; guide_obj (T, H, F, 3) object frame; guide_link (T, H, F); guide_local (T, H, F, 3);
    tree: the tree that found it
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
    guide_link: torch.Tensor
    guide_local: torch.Tensor
    tree: int


_KEEP = KEEP


class _Node:
    """A window of frames on a tree's current path (orchestration state, not a tensor type)."""

    __slots__ = ("t0", "t1", "frames", "guides", "children", "target", "expansions", "pending", "explored",
                 "fail", "template", "uid")

    def __init__(self, t0, t1, frames, guides, target, uid):
        self.t0, self.t1 = t0, t1
        self.frames = frames            # dict of stacked per-frame tensors (w, ...) or None for the root
        self.guides = guides            # per frame guiding: dict (w, ...) or None
        self.children = 0
        self.target = target            # children wanted (1 or 2)
        self.expansions = 0
        self.pending = []               # feasible siblings not explored yet: (frames, guides, end_obj)
        self.explored = []              # guiding points (H, F, 3) at the window end of explored children
        self.fail = None                # (cause, fingers) of the last failed expansion
        self.template = None            # strategy plan of the last failed candidate
        self.uid = uid


class _Tree:
    def __init__(self, index: int, seed: int):
        self.index = index
        self.gen = torch.Generator().manual_seed(seed)
        self.stack: list[_Node] = []
        self.cap = 0
        self.found = 0


def _rand(gen) -> float:
    return float(torch.rand((), generator=gen))


def _randint(gen, n: int) -> int:
    return int(torch.randint(n, (), generator=gen))


class _Search:
    def __init__(self, problem: SynthesisProblem, init: InitialSamples, s: SearchSettings, ns: NodeTestSettings,
                 seed: int):
        if s.strategy not in STRATEGIES:
            raise ValueError(f"strategy: expected one of {STRATEGIES}, got {s.strategy!r}")
        self.p, self.init, self.s, self.ns = problem, init, s, ns
        self.H, self.F = problem.H, problem.F
        self.T = problem.T
        self.window = max(1.0, self.T / max(s.epsilon, 1e-9))
        self.trees = [_Tree(i, seed * 1000 + i) for i in range(s.trees)]
        self.stats = SearchStats(rejections_by_frame=[[0, 0, 0] for _ in range(self.T)])
        self.solutions: list[tuple[int, list[_Node]]] = []   # accepted paths
        self.accepted: list[Solution] = []
        self.accept = None
        self.uid = 0
        self.solution_nodes: set = set()
        self.solution_q: list = []
        hand = problem.hands[0]
        self.tip_link = hand.distal_link
        self.tip_local = pad_points(hand)
        self.q_rest = torch.stack([h.q_rest for h in problem.hands])            # (H, D)
        self.deepest_path: list[_Node] = []      # the nodes of the deepest path any tree has grown
        self.deepest_tree = -1
        self.progress_at = 0                     # node tests spent when the deepest frame last advanced

    # --- tree bookkeeping -------------------------------------------------------------------------------------
    def _new_uid(self) -> int:
        self.uid += 1
        return self.uid

    def _restart(self, tree: _Tree):
        tree.stack = [_Node(0, 0, None, None, 1, self._new_uid())]
        tree.cap = 2 + (1 if _rand(tree.gen) < 0.5 else 0)
        tree.found = 0
        self.stats.restarts += 1

    def _window(self, tree: _Tree, t0: int) -> int:
        lo, hi = math.ceil(self.window / 2), math.ceil(1.5 * self.window)
        w = lo + _randint(tree.gen, hi - lo + 1)
        return max(1, min(w, self.T - t0))

    # --- candidate generation (§4.2 sampling rules, §5 preferences and informed backtracking) ----------------
    def _choices(self, tree: _Tree, node: _Node, h: int, f: int) -> int:
        """Strategy of finger (h, f) for the next window from its seed's force state."""
        g, pref = tree.gen, self.s.strategy
        on = node.frames is not None and bool(node.frames["seed_on"][-1, h, f])
        if not on:
            return _FREE
        cls = int(node.frames["seed_class"][-1, h, f])
        if cls == FORCE_INSIDE:
            return _STATIC
        alt = _SLIDE if cls == FORCE_BOUNDARY else _RELOCATE
        if pref == "static":
            return _STATIC
        if pref == "sliding":
            return _SLIDE if alt == _SLIDE else (_STATIC if _rand(g) < 0.5 else _RELOCATE)
        if pref == "relocating":
            return _RELOCATE if alt == _RELOCATE else (_STATIC if _rand(g) < 0.5 else _SLIDE)
        if pref == "gait":           # §7's paper cup: a loaded finger holds on (and rolls where it cannot), never
            return _STATIC if alt == _SLIDE else (_RELOCATE if _rand(g) < 0.5 else _STATIC)   # slides
        return alt if _rand(g) < 0.5 else _STATIC

    def _new_point(self, tree: _Tree, t: int, h: int, f: int, near=None, away=None) -> int:
        """A pruned patch sample of finger (h, f) at frame t: near ``near`` (object frame) if given, farthest from
        ``away`` among a few draws if given. -1 if there is none."""
        idx = self.init.samples(t, h, f)
        if idx.numel() == 0:
            return -1
        pts = self.p.surface[idx]
        if near is not None:
            close = idx[(pts - near).norm(dim=-1) <= self.s.relocate_radius]
            far_enough = close[(self.p.surface[close] - near).norm(dim=-1) > 0.005]
            idx = far_enough if far_enough.numel() else (close if close.numel() else idx)
        if away is not None:
            draws = idx[torch.randint(idx.numel(), (4,), generator=tree.gen)]
            d = (self.p.surface[draws] - away).norm(dim=-1)
            return int(draws[int(d.argmax())])
        return int(idx[_randint(tree.gen, idx.numel())])

    def _plan(self, tree: _Tree, node: _Node, w: int, resample=None, away=None, establish=None,
              land_max=None) -> list:
        """Per finger (kind, sample index or -1, first guided frame of the window) for a window of w frames
        starting after ``node``. A free finger that establishes contact does so at a uniformly drawn frame of the
        window (its initial frame, §4.2), on a pruned patch sample of that frame; a relocating finger lifts off
        for the first third of the window."""
        t0 = node.t1
        plan = []
        pref_gait = self.s.strategy == "gait"
        for h in range(self.H):
            for f in range(self.F):
                gi = h * self.F + f
                if node.template is not None and resample is not None and gi not in resample:
                    plan.append(node.template[gi])
                    continue
                kind = self._choices(tree, node, h, f)
                informed = gi in (resample or ()) and node.template is not None
                if informed and pref_gait and node.template[gi][0] in (_STATIC, _ROLL) and kind != _FREE and \
                        _rand(tree.gen) < 0.5:
                    kind = _ROLL if node.template[gi][0] == _STATIC else _RELOCATE   # hard to hold: roll on it
                elif informed and node.template[gi][0] == kind and kind == _STATIC and _rand(tree.gen) < 0.7:
                    kind = _RELOCATE if node.frames is not None and bool(node.frames["seed_on"][-1, h, f]) else _FREE
                if informed and kind == _RELOCATE and _rand(tree.gen) < 0.5:
                    kind = _FREE                       # a finger that failed to hold on: let it go
                    plan.append((kind, -1, 0))
                    continue
                sample, land = -1, 0
                if kind == _FREE and _rand(tree.gen) < (self.s.establish if establish is None else establish):
                    land = _randint(tree.gen, w if land_max is None else min(w, land_max + 1))
                    sample = self._new_point(tree, t0 + land, h, f, away=away.get(gi) if away else None)
                    kind = _RELOCATE if sample >= 0 else _FREE
                elif kind == _RELOCATE and _rand(tree.gen) < 0.4:
                    kind = _FREE                       # release: the finger leaves the object for this window
                elif kind == _RELOCATE:
                    near = node.frames["seed_obj"][-1, h, f]
                    sample = self._new_point(tree, t0, h, f, near=near, away=away.get(gi) if away else None)
                    land = max(1, w // 3)
                    if sample < 0:
                        kind = _FREE
                plan.append((kind, sample, land))
        return plan

    def _release(self, node: _Node, failed: set) -> list:
        """After a kinematic failure: the fingers that failed and every finger that carried no force at the end of
        ``node`` let go for the next window; the others keep their contacts (static, as the failed plan had them
        or as their seeds are). A hand that leaves the object (a retreat) needs all its idle fingers released in
        one window, which independent draws per finger almost never give."""
        plan = []
        for h in range(self.H):
            for f in range(self.F):
                gi = h * self.F + f
                on = bool(node.frames["seed_on"][-1, h, f])
                idle = not on or int(node.frames["seed_class"][-1, h, f]) == FORCE_ZERO
                if gi in failed or idle:
                    plan.append((_FREE, -1, 0))
                elif node.template is not None and node.template[gi][0] in (_STATIC, _SLIDE, _ROLL):
                    plan.append(node.template[gi])
                else:
                    plan.append((_STATIC, -1, 0))
        return plan

    def _informed(self, tree: _Tree, node: _Node, w: int) -> list:
        """Plans of one expansion: informed by the last failure where there is one, fresh otherwise."""
        plans, seen = [], set()
        for i in range(self.s.candidates):
            if node.fail is None or i >= self.s.candidates // 2 + 1:
                plans.append(self._plan(tree, node, w))
                continue
            cause, fingers, k_fail = node.fail
            if cause == CAUSE_KINEMATIC and i == 0 and node.frames is not None:
                plans.append(self._release(node, set(fingers)))
            elif cause == CAUSE_KINEMATIC:
                plans.append(self._plan(tree, node, w, resample=set(fingers)))
            elif cause == CAUSE_FINGERS:
                a, b = fingers
                mover, other = (a, b) if _rand(tree.gen) < 0.5 else (b, a)
                plan_o = node.template[other]
                away = None
                if plan_o[1] >= 0:
                    away = {mover: self.p.surface[plan_o[1]]}
                elif node.frames is not None:
                    ho, fo = divmod(other, self.F)
                    away = {mover: node.frames["seed_obj"][-1, ho, fo]}
                plans.append(self._plan(tree, node, w, resample={mover}, away=away))
            else:
                # a dynamic failure: new guiding points for every finger, and free fingers now establish contact
                # before the frame that failed (more contacts can carry the wrench)
                plans.append(self._plan(tree, node, w, establish=0.9, land_max=k_fail))
        unique = []
        for plan in plans:                     # identical plans would give identical children
            key = tuple(plan)
            if key not in seen:
                seen.add(key)
                unique.append(plan)
        return unique

    # --- one batched expansion of every tree ------------------------------------------------------------------
    def _expand(self, jobs):
        """jobs: list of (tree, node, plans, w). Tests every plan over its window; returns per job its
        :class:`~._search_expand.Expansion` (feasible (frames, guides), failure, template)."""
        return expand(self, jobs)

    # --- main loop --------------------------------------------------------------------------------------------
    def run(self, progress=None, accept=None) -> list[Solution]:
        """Grow the trees until ``solutions`` paths are accepted or a budget is spent (``max_nodes`` node tests,
        checked after every round, or the ``time_budget`` cap). ``accept(solution)`` on every new full path returns
        a bool, or a finishing program that returns one (:meth:`rounds`; its work is run here, ``work.run()``);
        only accepted paths count and are returned (default: all)."""
        rounds = self.rounds(progress, accept)
        try:
            step = next(rounds)
            while True:
                step = rounds.send(self._expand(step) if isinstance(step, list) else step.run())
        except StopIteration as done:
            return done.value

    def rounds(self, progress=None, accept=None):
        """The search of :meth:`run` as a generator of rounds: it yields each round's jobs (a list of (tree, node,
        plans, w)), is sent their :class:`~._search_expand.Expansion` list, and returns the accepted solutions.
        Where ``accept`` returns a generator (a path's finishing program), the work that program yields (anything
        not a list) is yielded too, and its result sent back to it. Whoever runs the expansions and the work (alone:
        :meth:`_expand` and ``work.run()``; many searches: :mod:`.multi`) gives the same run, as long as every
        candidate's node tests and every work's result are those it would get alone."""
        s = self.s
        self.accept = accept
        start = time.perf_counter()
        for tree in self.trees:
            self._restart(tree)

        def spent() -> bool:
            if len(self.solutions) >= s.solutions:
                self.stats.stopped_by = "solutions"
            elif s.max_nodes is not None and self.stats.nodes_tested >= s.max_nodes:
                self.stats.stopped_by = "max_nodes"
            elif s.stall_nodes is not None and self.stats.paths_found == 0 and \
                    self.stats.nodes_tested - self.progress_at >= s.stall_nodes:
                self.stats.stopped_by = "stalled"
            elif s.time_budget is not None and time.perf_counter() - start >= s.time_budget:
                self.stats.stopped_by = "time_budget"
            else:
                return False
            return True

        while not spent():
            jobs = []
            for tree in self.trees:
                node = yield from self._frontier(tree)
                if len(self.solutions) >= s.solutions:
                    break
                if node is None:
                    continue
                w = self._window(tree, node.t1)
                jobs.append((tree, node, self._informed(tree, node, w), w))
            if not jobs:
                continue
            results = yield jobs
            self._apply(jobs, results)
            self.stats.time_s = time.perf_counter() - start
            if progress is not None:
                progress(self)
        for tree in self.trees:          # a path completed in the round that spent the budget still counts
            if tree.stack and tree.stack[-1].t1 >= self.T:
                yield from self._record_path(tree)
        self.stats.time_s = time.perf_counter() - start
        self.stats.success_frames = sum(n.t1 - n.t0 for n in self.solution_nodes)
        return [sol for sol in self.accepted]

    def _apply(self, jobs, results) -> None:
        """A round's expansions: the first feasible child in random order is pushed, the others kept pending; a
        failed expansion remembers its failure for informed backtracking."""
        for (tree, node, plans, w), res in zip(jobs, results):
            node.expansions += 1
            if res.feasible:
                order = torch.randperm(len(res.feasible), generator=tree.gen).tolist()
                feas = [res.feasible[o] for o in order]
                self._push(tree, node, feas[0])
                node.pending.extend(feas[1:])
            else:
                node.fail, node.template = res.fail, res.template

    def _frontier(self, tree: _Tree):
        """Generator (passing on the work of the paths it records): the node this tree expands next, after
        backtracking and consuming pending siblings; None if it pushed a pending sibling instead."""
        while True:
            if not tree.stack or tree.found >= tree.cap:
                self._restart(tree)
            node = tree.stack[-1]
            if node.t1 >= self.T:                      # a full path: record it (unless seen), then backtrack
                yield from self._record_path(tree)
                tree.stack.pop()
                continue
            if node.children >= node.target or node.expansions >= self.s.max_expansions:
                tree.stack.pop()                       # backtrack
                continue
            if node.pending and node.children > 0:
                # diversity: the pending sibling most different from the explored children
                ends = [fr[1]["guide_obj"][-1] * fr[1]["guiding"][-1][..., None] for fr in node.pending]
                score = [sum(float((e - x).norm(dim=-1).sum()) for x in node.explored) for e in ends]
                best = max(range(len(ends)), key=lambda i: score[i])
                self._push(tree, node, node.pending.pop(best))
                return None
            return node

    def _record_path(self, tree: _Tree):
        """Generator (passing on the work of ``accept``'s program): record the full path on top of ``tree``'s
        stack as a solution, unless one as near was seen or enough were accepted; ``accept`` decides."""
        path = list(tree.stack[1:])
        q = torch.cat([n.frames["q"] for n in path])
        if len(self.solutions) < self.s.solutions and \
                not any(torch.allclose(q, other, atol=1e-4) for other in self.solution_q):
            self.solution_q.append(q)
            sol = self._solution(tree.index, path)
            self.stats.paths_found += 1
            verdict = True if self.accept is None else self.accept(sol)
            if (yield from verdict) if inspect.isgenerator(verdict) else verdict:
                self.solutions.append((tree.index, path))
                self.accepted.append(sol)
                self.solution_nodes.update(path)
                tree.found += 1

    def _push(self, tree: _Tree, node: _Node, feasible):
        frames, guides = feasible
        w = frames["q"].shape[0]
        node.children += 1
        node.explored.append(guides["guide_obj"][-1] * guides["guiding"][-1][..., None])
        target = 1 if _rand(tree.gen) < 0.5 else 2
        tree.stack.append(_Node(node.t1, node.t1 + w, frames, guides, target, self._new_uid()))
        if node.t1 + w > self.stats.deepest_frame:
            self.stats.deepest_frame = node.t1 + w
            self.deepest_path, self.deepest_tree = list(tree.stack[1:]), tree.index
            self.progress_at = self.stats.nodes_tested

    def partial(self) -> Solution | None:
        """The deepest path grown (frames ``[0, deepest_frame)``, as searched), or None before any node."""
        if not self.deepest_path:
            return None
        return self._solution(self.deepest_tree, self.deepest_path)

    def _solution(self, tree_index: int, path: list[_Node]) -> Solution:
        cat = {k: torch.cat([n.frames[k] for n in path]) for k in _KEEP}
        g = {k: torch.cat([n.guides[k] for n in path]) for k in path[0].guides}
        return Solution(q=cat["q"], c_mask=cat["c_mask"], c_local=cat["c_local"], c_point=cat["c_point"],
                        c_normal=cat["c_normal"], c_force=cat["c_force"], env_force=cat["env_force"],
                        guiding=g["guiding"], guide_obj=g["guide_obj"], guide_link=g["guide_link"],
                        guide_local=g["guide_local"], tree=tree_index)


def search(problem: SynthesisProblem, init: InitialSamples, settings: SearchSettings = SearchSettings(), *,
           node_settings: NodeTestSettings = NodeTestSettings(), seed: int = 0, progress=None,
           accept=None, partial: list | None = None) -> tuple[list[Solution], SearchStats]:
    """Run the search (see the module docstring). Returns the accepted solutions in the order found and the
    counters.

    progress: optional callable(search) after every batched expansion (it can read ``search.stats`` and
    ``len(search.solutions)``). accept: optional callable(Solution) -> bool on every new full path, as it is found
    (the pipeline reconstructs, checks and writes it there); a path it rejects does not count. partial: a list
    that receives the deepest path grown (a :class:`Solution` over frames ``[0, stats.deepest_frame)``, as
    searched, not checked as a whole) when no path was accepted and some node was.
    """
    runner = _Search(problem, init, settings, node_settings, seed)
    sols = runner.run(progress, accept)
    if partial is not None and not sols and runner.deepest_path:
        partial.append(runner.partial())
    return sols, runner.stats
