"""Many independent searches advanced in rounds, their candidates tested together.

A single search tests at most trees × candidates guiding configurations per frame, and fewer as its candidates
die within a window: too small a batch for a GPU and, at its tails, for a CPU. :func:`search_many` runs K searches
(each with its own problem, seed, settings and generators) as coroutines (:meth:`.search._Search.rounds`): every
round, each search that is still running yields its jobs; the jobs of all searches that share a node-test context
are expanded as one batch (:func:`._search_expand.test_windows`: one node-test call per frame of the round's
windows), and each search is sent its own expansions.

**Grouping, not padding.** Searches share a call when the node test would read the same things for them: the same
prepared scene (hands, root poses, object poses, SDF, table contacts, mesh: the same objects, as
:func:`.problem.build_problem` gives to the seeds of one scene with ``share=``), the same node-test settings and
the same slide speed. Searches of other scenes, hands, dtypes or devices form other groups, each its own call per
frame; nothing is padded. The surface samples and contact patches, which differ by seed, are read only by the
search itself (its plans), never by the node test.

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

from .initial import InitialSamples
from .node_test import NodeTestSettings
from .problem import SynthesisProblem
from .search import SearchSettings, SearchStats, Solution, _Search
from ._search_expand import Candidates, WindowOutcome, candidates, regroup, test_windows

__all__ = ["SearchTask", "SearchOutcome", "MultiStats", "search_many", "node_context", "CPU_MAX_ROWS"]


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


_SHARED = ("hands", "root", "object_pose", "object_inv", "com", "wrench", "sdf", "env", "mesh", "ground")
_VALUES = ("env_friction", "friction", "mass", "weight", "fps", "table_height")


def node_context(problem: SynthesisProblem) -> tuple:
    """What the node test reads of ``problem``: the identities of its shared tensors and models and its
    scalars. Problems with the same context can be tested in one call."""
    return tuple(id(getattr(problem, f)) for f in _SHARED) + tuple(getattr(problem, f) for f in _VALUES)


def _group_key(run: _Search) -> tuple:
    return node_context(run.p), repr(run.ns), run.s.slide_speed


CPU_MAX_ROWS = 256
"""On a CPU a frame's gathered candidates are tested in calls of at most this many rows: the node test's rate on two
cores peaks between 64 and 256 candidates and falls beyond (its working set leaves the cache; BENCHMARKS.md). A GPU
takes them in one call."""


def search_many(tasks, *, stats: MultiStats | None = None, on_round=None,
                max_rows: int | None | str = "auto") -> list[SearchOutcome]:
    """Run every :class:`SearchTask` to its end (see the module docstring); returns their outcomes in order.

    stats: a :class:`MultiStats` to fill; on_round: optional callable(MultiStats, running) after every round,
    ``running`` the number of searches not yet finished; max_rows: the largest node-test call ("auto":
    :data:`CPU_MAX_ROWS` on a CPU, unlimited on a GPU; None: unlimited). No choice changes a result."""
    tasks = list(tasks)
    stats = MultiStats() if stats is None else stats
    runs = [_Search(t.problem, t.init, t.settings, t.node_settings, t.seed) for t in tasks]
    coroutines = [r.rounds(t.progress, t.accept) for r, t in zip(runs, tasks)]
    outcomes: list = [None] * len(tasks)
    waiting: dict[int, list] = {}

    def advance(i: int, sent) -> None:
        try:
            waiting[i] = next(coroutines[i]) if sent is None else coroutines[i].send(sent)
        except StopIteration as done:
            waiting.pop(i, None)
            run = runs[i]
            partial = run.partial() if not done.value and run.deepest_path else None
            outcomes[i] = SearchOutcome(tuple(done.value), run.stats, partial)

    for i in range(len(tasks)):
        advance(i, None)
    while waiting:
        groups: dict = {}
        for i in sorted(waiting):
            groups.setdefault(_group_key(runs[i]), []).append(i)
        results = {}
        for members in groups.values():
            results.update(_expand_group(runs, members, waiting, stats, max_rows))
        stats.rounds += 1
        for i in sorted(results):
            advance(i, results[i])
        if on_round is not None:
            on_round(stats, len(waiting))
    return outcomes


def _expand_group(runs: list, members: list, waiting: dict, stats: MultiStats, max_rows) -> dict:
    """The round's jobs of the searches ``members`` (one node-test context) expanded in one batch; per search
    its list of expansions."""
    parts = [(i, *candidates(runs[i], waiting[i])) for i in members]
    sizes = [len(cand) for _, cand, _ in parts]
    joined = Candidates(**{f.name: torch.cat([getattr(c, f.name) for _, _, c in parts])
                           for f in dataclasses.fields(Candidates)})
    owner = torch.repeat_interleave(torch.arange(len(parts)), torch.tensor(sizes))
    lead = runs[members[0]]
    if max_rows == "auto":
        max_rows = CPU_MAX_ROWS if lead.p.device.type == "cpu" else None
    calls = []
    outcome = test_windows(lead.p, lead.ns, lead.s.slide_speed, joined, [runs[i].stats for i in members], owner,
                           on_call=calls.append, max_rows=max_rows)
    stats.calls += len(calls)
    stats.batch_sizes.extend(calls)
    out, start = {}, 0
    for (i, cand, _), n in zip(parts, sizes):
        out[i] = regroup(waiting[i], cand, _rows(outcome, start, start + n))
        start += n
    return out


def _rows(o: WindowOutcome, a: int, b: int) -> WindowOutcome:
    """The rows [a, b) of a window outcome."""
    return WindowOutcome(alive=o.alive[a:b], frames={k: [x[a:b] for x in v] for k, v in o.frames.items()},
                         g_frames={k: [x[a:b] for x in v] for k, v in o.g_frames.items()},
                         fail_cause=o.fail_cause[a:b], fail_k=o.fail_k[a:b], fail_fingers=o.fail_fingers[a:b])
