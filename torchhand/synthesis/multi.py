"""Many independent searches advanced in rounds, their candidates tested together.

A single search tests at most trees × candidates guiding configurations per frame, and fewer as its candidates
die within a window: too small a batch for a GPU and, at its tails, for a CPU. :func:`search_many` runs K searches
(each with its own problem, seed, settings and generators) as coroutines (:meth:`.search._Search.rounds`): every
round, each search that is still running yields its jobs; the jobs of all searches that share a node-test context
are expanded as one batch (:func:`._search_expand.test_windows`: one node-test call per frame of the round's
windows), and each search is sent its own expansions.

**Grouping and stacking, not padding.** Searches share a call when the node test would read the same things for
them apart from their frames: the same hand models, SDF, mesh and ground (the same objects, as
:func:`.problem.build_problem` gives to the seeds of one scene with ``share=`` and to the frame ranges of one scene
with ``statics=``), the same scalars and number of table-contact slots, dtype and device, the same node-test
settings apart from the two slide speeds, and the same guide slide speed. Searches of one problem (the seeds of a
scene) are tested on it; searches of different frame ranges (the windows of a capture, :mod:`torchhand.fill`) on
:func:`stack_frames` of their problems, each row's frames shifted to its own block, and, where their slide speeds
differ (each window's capture noise), with per-row speeds. Searches of other scenes, hands, dtypes or devices form
other groups, each its own call per frame; nothing is padded. The surface samples and contact patches, which
differ by seed and window, are read only by the search itself (its plans), never by the node test.

**Finishing.** A search whose ``accept`` returns a finishing program (:mod:`.finishing`) yields that program's work
instead of jobs while it waits on its path. Such searches pause while the others search, until at least half of the
searches still running wait on work (or none is searching); then the work of all of them runs together
(:func:`.finishing.run_works`: evaluations and reconstructions of several paths per call), and each gets its own
result back. A paused search's run is unchanged: only when it runs, never what it computes, depends on the others.

**Lanes.** :func:`search_lanes` runs generators of searches (a capture window's searches run one after another,
each starting where the one before stopped): a lane yields a task, is sent its outcome, and yields the next.

**Determinism.** A search's run is byte-identical to running it alone (:func:`.search.search`) with the same seed
and node budget, on the same device, dtype and thread count: a candidate's node-test outputs do not depend on the
other rows of its batch (tests/torchhand/test_multi_search.py compares them), each search's random draws come from
its own generators in its own order, and its counters count its own rows. Only a ``time_budget`` (wall clock)
depends on what else runs.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Callable

import torch

from .finishing import run_works
from .initial import InitialSamples
from .node_test import NodeTestSettings
from .problem import SynthesisProblem, frames_key, node_context
from .search import SearchSettings, SearchStats, Solution, _Search
from ._search_expand import Candidates, WindowOutcome, candidates, regroup, test_windows

__all__ = ["SearchTask", "SearchOutcome", "MultiStats", "search_many", "search_lanes", "node_context", "stack_frames",
           "CPU_MAX_ROWS"]


@dataclass(frozen=True)
class SearchTask:
    """One search of :func:`search_many`: what :func:`.search.search` takes."""

    problem: SynthesisProblem
    init: InitialSamples
    settings: SearchSettings = SearchSettings()
    node_settings: NodeTestSettings = NodeTestSettings()
    seed: int = 0
    progress: Callable | None = None      # callable(search) after each of its rounds
    accept: Callable | None = None        # callable(Solution) -> bool on each new full path


@dataclass(frozen=True)
class SearchOutcome:
    """A finished search: its accepted solutions in the order found, its counters, and (no solution accepted)
    the deepest path grown, or None."""

    solutions: tuple
    stats: SearchStats
    partial: Solution | None


@dataclass
class MultiStats:
    """The scheduler's counters: rounds run, node-test calls made (one per frame of a group's round) and the
    candidates of each call (the batch sizes)."""

    rounds: int = 0
    calls: int = 0
    batch_sizes: list = field(default_factory=list)
    finish_batches: int = 0                            # batches of finishing work run (:func:`.finishing.run_works`)
    finish_sizes: list = field(default_factory=list)   # the works of each


_SPEEDS = ("slide_speed", "table_slide_speed")


def _group_key(run: _Search) -> tuple:
    return node_context(run.p), repr(dataclasses.replace(run.ns, **dict.fromkeys(_SPEEDS, 0.0))), run.s.slide_speed


def stack_frames(problems) -> tuple[SynthesisProblem, list[int]]:
    """One problem whose frames are those of every problem of ``problems`` (same :func:`node_context`) one after
    another, each block led by a copy of its first frame; returns it and where each problem's frame 0 lies. The
    copy makes a row's "previous frame" at its own frame 0 its frame 0 again, as alone (the node test's sliding
    rule reads frame t - 1, clamped at 0), so a row's inputs are the same values as in its own problem."""
    def cat(get, dim: int = 0) -> torch.Tensor:
        return torch.cat([torch.cat([get(p).narrow(dim, 0, 1), get(p)], dim) for p in problems], dim)

    starts, at = [], 0
    for p in problems:
        starts.append(at + 1)
        at += p.T + 1
    lead = problems[0]
    env = type(lead.env)(points=cat(lambda p: p.env.points), mask=cat(lambda p: p.env.mask),
                         sliding_velocity=cat(lambda p: p.env.sliding_velocity),
                         support_index=cat(lambda p: p.env.support_index), normal=lead.env.normal)
    stacked = dataclasses.replace(lead, root=cat(lambda p: p.root, 1), object_pose=cat(lambda p: p.object_pose),
                                  object_inv=cat(lambda p: p.object_inv), com=cat(lambda p: p.com),
                                  wrench=cat(lambda p: p.wrench), env=env)
    return stacked, starts


CPU_MAX_ROWS = 256
"""On a CPU a frame's gathered candidates are tested in calls of at most this many rows: the node test's rate on two
cores peaks between 64 and 256 candidates and falls beyond (its working set leaves the cache; BENCHMARKS.md). A GPU
takes them in one call."""


def search_many(tasks, *, stats: MultiStats | None = None, on_round=None,
                max_rows: int | None | str = "auto") -> list[SearchOutcome]:
    """Run every :class:`SearchTask` to its end (see the module docstring); returns their outcomes in order. An
    error in any search is raised at once.

    stats: a :class:`MultiStats` to fill; on_round: optional callable(MultiStats, running) after every round,
    ``running`` the number of searches not yet finished; max_rows: the largest node-test call ("auto":
    :data:`CPU_MAX_ROWS` on a CPU, unlimited on a GPU; None: unlimited). No choice changes a result."""
    return search_lanes([_one(t) for t in tasks], stats=stats, on_round=on_round, max_rows=max_rows,
                        keep_errors=False)


def _one(task: SearchTask):
    outcome = yield task
    return outcome


def search_lanes(lanes, *, stats: MultiStats | None = None, on_round=None, on_done=None,
                 max_rows: int | None | str = "auto", keep_errors: bool = True) -> list:
    """Run every lane to its end; returns what each returned, in order.

    A lane is a generator of searches run one after another (the pieces of a window, :mod:`torchhand.fill`): it
    yields a :class:`SearchTask`, is sent that search's :class:`SearchOutcome` when it ends, and yields the next
    task or returns its result. The searches of all lanes advance together as in :func:`search_many`: each is the
    same as run alone. An error raised by a search is thrown into its lane; an error that ends a lane is, with
    ``keep_errors``, its result (the other lanes go on), otherwise raised at once. on_done: optional
    callable(index, result) as each lane ends; stats, on_round, max_rows: as :func:`search_many`'s."""
    lanes = list(lanes)
    stats = MultiStats() if stats is None else stats
    results: list = [None] * len(lanes)
    runs: dict[int, _Search] = {}
    searches: dict = {}
    waiting: dict[int, list] = {}

    def end(i: int, value) -> None:
        results[i] = value
        if on_done is not None:
            on_done(i, value)

    def step_lane(i: int, sent=None, error: Exception | None = None) -> None:
        try:
            task = lanes[i].send(sent) if error is None else lanes[i].throw(error)
        except StopIteration as done:
            return end(i, done.value)
        except Exception as exc:
            if not keep_errors:
                raise
            return end(i, exc)
        try:
            runs[i] = _Search(task.problem, task.init, task.settings, task.node_settings, task.seed)
            searches[i] = runs[i].rounds(task.progress, task.accept)
        except Exception as exc:
            return step_lane(i, error=exc)
        step_search(i, None)

    def step_search(i: int, sent, error: Exception | None = None) -> None:
        try:
            if error is not None:
                waiting[i] = searches[i].throw(error)
            else:
                waiting[i] = next(searches[i]) if sent is None else searches[i].send(sent)
            return
        except StopIteration as done:
            run = runs[i]
            partial = run.partial() if not done.value and run.deepest_path else None
            outcome, error = SearchOutcome(tuple(done.value), run.stats, partial), None
        except Exception as exc:
            outcome, error = None, exc
        waiting.pop(i, None)
        step_lane(i, outcome, error)

    for i in range(len(lanes)):
        step_lane(i)
    stack_cache: dict = {}
    while waiting:
        work = sorted(i for i, w in waiting.items() if not isinstance(w, list))
        if work and 2 * len(work) >= len(waiting):          # half of the searches wait on their paths' finishing
            for i, result, error in _finish_work([waiting[i] for i in work], work, stats):
                step_search(i, result, error)
            continue
        groups: dict = {}
        for i in sorted(i for i in waiting if i not in work):
            groups.setdefault(_group_key(runs[i]), []).append(i)
        expansions = {}
        for members in groups.values():
            expansions.update(_expand_group(runs, members, waiting, stats, max_rows, stack_cache))
        stats.rounds += 1
        for i in sorted(expansions):
            step_search(i, expansions[i])
        if on_round is not None:
            on_round(stats, len(waiting))
    return results


def _finish_work(works: list, owners: list, stats: MultiStats) -> list:
    """The finishing work the searches ``owners`` wait on, run together (:func:`.finishing.run_works`): (owner,
    result, None) each, or, where a batch raised, each work run alone: (owner, None, its error) for those that
    raise."""
    stats.finish_batches += 1
    stats.finish_sizes.append(len(works))
    try:
        return [(i, r, None) for i, r in zip(owners, run_works(works))]
    except Exception:
        out = []
        for i, w in zip(owners, works):
            try:
                out.append((i, w.run(), None))
            except Exception as exc:
                out.append((i, None, exc))
        return out


def _expand_group(runs: dict, members: list, waiting: dict, stats: MultiStats, max_rows, cache: dict) -> dict:
    """The round's jobs of the searches ``members`` (one node-test context) expanded in one batch; per search
    its list of expansions."""
    parts = [(i, *candidates(runs[i], waiting[i])) for i in members]
    sizes = torch.tensor([len(cand) for _, cand, _ in parts])
    joined = Candidates(**{f.name: torch.cat([getattr(c, f.name) for _, _, c in parts])
                           for f in dataclasses.fields(Candidates)})
    owner = torch.repeat_interleave(torch.arange(len(parts)), sizes)
    lead = runs[members[0]]
    if max_rows == "auto":
        max_rows = CPU_MAX_ROWS if lead.p.device.type == "cpu" else None
    problem, shift = _stacked(cache, [runs[i].p for i in members], owner)
    per = torch.tensor([[getattr(runs[i].ns, f) for f in _SPEEDS] for i in members], dtype=torch.float64)
    row_speeds = per[owner].to(lead.p.device) if bool((per != per[0]).any()) else None     # only where they differ
    calls = []
    outcome = test_windows(problem, lead.ns, lead.s.slide_speed, joined, [runs[i].stats for i in members], owner,
                           on_call=calls.append, max_rows=max_rows, shift=shift, speeds=row_speeds)
    stats.calls += len(calls)
    stats.batch_sizes.extend(calls)
    out, start = {}, 0
    for (i, cand, _), n in zip(parts, sizes.tolist()):
        out[i] = regroup(waiting[i], cand, _rows(outcome, start, start + n))
        start += n
    return out


def _stacked(cache: dict, problems: list, owner: torch.Tensor):
    """The problem to test the rows of ``problems`` (one per member search) with, and each row's frame shift: the
    members' own problem when they share its frames (the seeds of one scene), else :func:`stack_frames` of the
    distinct ones (cached while the same set runs)."""
    distinct: dict = {}
    for p in problems:
        distinct.setdefault(frames_key(p), p)
    if len(distinct) == 1:
        return problems[0], None
    key = tuple(distinct)
    if key not in cache:
        if len(cache) >= 8:             # the sets change only as searches end or start
            cache.pop(next(iter(cache)))
        cache[key] = (tuple(distinct.values()),) + stack_frames(list(distinct.values()))
    _, stacked, starts = cache[key]
    where = dict(zip(key, starts))
    per_member = torch.tensor([where[frames_key(p)] for p in problems])
    return stacked, per_member[owner].to(problems[0].device)


def _rows(o: WindowOutcome, a: int, b: int) -> WindowOutcome:
    """The rows [a, b) of a window outcome."""
    return WindowOutcome(alive=o.alive[a:b], frames={k: [x[a:b] for x in v] for k, v in o.frames.items()},
                         g_frames={k: [x[a:b] for x in v] for k, v in o.g_frames.items()},
                         fail_cause=o.fail_cause[a:b], fail_k=o.fail_k[a:b], fail_fingers=o.fail_fingers[a:b])
