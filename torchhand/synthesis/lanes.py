"""A synthesis as a lane of :func:`.multi.search_lanes`: many syntheses whose searches share node-test calls.

:func:`synthesis_lane` is :func:`.pipeline.synthesize` of a mounted scene cut in two at its search: it prepares
the problem and the pruned samples, yields its :class:`~.multi.SearchTask`, is sent the search's outcome, finishes
and returns the :class:`~.pipeline.SynthesisResult`. Each path is reconstructed and checked as the search finds it,
as alone. The windows of a capture (:mod:`torchhand.fill`) are such syntheses over frame ranges of one scene: with a
``shared`` dict the first one's hand models, SDF, mesh and ground are reused by the others
(:func:`.problem.build_problem`'s ``statics``), so that their searches can be tested together
(:func:`.multi.stack_frames`).
"""

from __future__ import annotations

import dataclasses
import inspect
import time

from ..scene import Scene
from .multi import SearchTask, search_lanes
from .pipeline import _check_arguments, _finish, _Options, _start, synthesize

__all__ = ["synthesis_lane", "run_lane"]

_DEFAULTS = {f.name: inspect.signature(synthesize).parameters[f.name].default for f in dataclasses.fields(_Options)}
"""The options :func:`synthesis_lane` is not given: :func:`~.pipeline.synthesize`'s defaults."""


def synthesis_lane(scene: Scene, *, seed: int = 0, progress=None, on_solution=None, shared: dict | None = None,
                   **options):
    """Generator: the synthesis of ``scene`` (a :class:`~torchhand.scene.Scene`, its robot hands mounted) with
    ``seed``; yields its one :class:`~.multi.SearchTask`, is sent its :class:`~.multi.SearchOutcome`, returns the
    :class:`~.pipeline.SynthesisResult` that :func:`~.pipeline.synthesize` (``mount_fit=False``) gives it.
    options: :func:`~.pipeline.synthesize`'s (``solutions``, ``max_nodes``, ``node_settings``, ...); progress,
    on_solution: as there; shared: a dict shared by the lanes of one scene's frame ranges (above), or None."""
    o = _Options(**{**_DEFAULTS, **options})
    _check_arguments(solutions=o.solutions, trees=o.trees, candidates=o.candidates, max_nodes=o.max_nodes,
                     stall_nodes=o.stall_nodes, time_budget=o.time_budget, max_joint_speed=o.max_joint_speed,
                     epsilon=o.epsilon)
    statics = None if shared is None else shared.get("statics")
    run = _start(scene, (), int(seed), time.perf_counter(), o, progress, on_solution, statics=statics)
    if shared is not None:
        shared.setdefault("statics", run.problem)
    outcome = yield SearchTask(run.problem, run.init, run.result.settings, o.node_settings, int(seed), run.on_round,
                               run.accept)
    return _finish(run, outcome.stats, outcome.partial)

def run_lane(lane) -> object:
    """A lane run alone (:func:`.multi.search_lanes` of one); returns its result, raises its error."""
    return search_lanes([lane], keep_errors=False)[0]
