"""Contact-sampling synthesis end to end (Ye & Liu 2012, Algorithm 1): prepare, search, reconstruct, check.

:func:`synthesize` runs the steps as a list of pure stages over typed state:

1. :func:`~.problem.build_problem`: hands, SDF, required wrenches, table, contact patches;
2. :func:`~.initial.prune_patches`: the initial case's kinematic pruning;
3. :func:`~.search.search`: the randomized depth-first search, bounded by a node budget (``max_nodes`` node
   tests: the same run on any machine) and optionally capped by wall-clock time;
4. :func:`finalize_solution` for every path as soon as the search finds it (its time is inside the budget, and the
   caller can checkpoint it at once): spacetime reconstruction (§6) of each hand with the table and a joint-speed
   bound as constraints, then the contact and dynamic test of the reconstructed poses with every contact's actual
   sliding velocity (a contact held since the previous frame whose hand point moves on the object faster than
   ``NodeTestSettings.slide_speed`` is sliding and must have its force on the cone boundary: "solutions that
   violate sliding friction for non-guiding contacts are excluded", §6; the search applies the same rule, so its
   own poses pass it; a contact the path establishes at a frame is landing there, not held, as in the search). A
   path whose fast reconstruction fails this test gets its searched poses blended back in around the failing
   frames (kept only within the speed bound), then a reconstruction converged to 1e-4 rad, blended the same way. A path that cannot be smoothed is not written (unless
   ``keep_unsmoothed``, which writes its searched poses flagged ``reconstructed = False``), nor is one closer than
   ``min_difference`` (mean joint angle) to an earlier solution; neither counts toward ``solutions``.

Deviation: the paper smooths after the search; here every path is finished as it is found, which gives the same
motions (each path is reconstructed alone) and lets rejected paths not count.

Conventions: world frame, metres, newtons, radians; forces are those of the hand on the object.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import torch

from ..errors import InputValueError
from ..scene import Scene, load_scene
from . import DEFAULT_MAX_NODES
from .initial import prune_patches
from .mount_fit import fit_mounts
from .finishing import FinalSolution, clocked, finalize_solution, finalize_steps  # noqa: F401 (finalize_solution: API)
from .node_test import NodeTestSettings
from .problem import SynthesisProblem, build_problem
from .search import SearchSettings, SearchStats, Solution, search
from ._diversity import diversity  # noqa: F401  (re-exported: the diversity of a result)

__all__ = ["FinalSolution", "SynthesisResult", "synthesize", "synthesize_seeds", "finalize_solution"]




@dataclass(frozen=True)
class Exclusions:
    """Paths the search found that were not written, by reason."""

    failed_check: int = 0      # no motion of the path (smoothed, blended, searched) passed the final check
    unsmoothed: int = 0        # passed only as searched (not smoothed) and ``keep_unsmoothed`` was off
    duplicate: int = 0         # closer than ``min_difference`` (mean joint angle) to an earlier solution

    @property
    def total(self) -> int:
        return self.failed_check + self.unsmoothed + self.duplicate


@dataclass
class SynthesisResult:
    """Everything :func:`synthesize` produced: the problem, the finished solutions and the run's figures.

    finals: the written motions as :class:`FinalSolution` (torch, (T, H, D) joint angles); ``solutions`` gives them
    as :class:`torchhand.io.result.Solution` (NumPy, the result contract: ``solutions[i].q`` (T, D) for one hand,
    ``solutions[i].hand("left").q`` for either). ``save(dir)`` writes the result directory.
    """

    problem: SynthesisProblem
    scene: Scene
    finals: list
    stats: SearchStats
    settings: SearchSettings
    excluded: Exclusions = Exclusions()
    timings: dict = field(default_factory=dict)
    node_settings: NodeTestSettings = NodeTestSettings()
    seed: int = 0
    max_joint_speed: float = 8.0
    keep_unsmoothed: bool = False
    complete: bool = True
    mount_fits: tuple = ()
    partial: Solution | None = None    # no solution written: the deepest path the search grew, as searched

    @property
    def solutions(self) -> tuple:
        from .output import solution_view
        return tuple(solution_view(self, i) for i in range(len(self.finals)))

    def save(self, directory, *, overwrite: bool = False):
        """Write the result directory (docs/result_format.md) atomically; an existing result directory is
        replaced only with ``overwrite``. Returns its path."""
        from .output import write_result
        return write_result(self, directory, overwrite=overwrite)



def _duplicate(q: torch.Tensor, earlier: list, min_difference: float) -> bool:
    """Whether q (T, H, D) is within ``min_difference`` radians of mean absolute joint difference of any earlier
    solution's q."""
    return any(float((q - f.q).abs().mean()) < min_difference for f in earlier)


def _check_arguments(**a) -> None:
    """One line (InputValueError) for the first bad count, budget or positive number of :func:`synthesize`."""
    for name in ("solutions", "trees", "candidates"):
        if not isinstance(a[name], int) or a[name] < 1:
            raise InputValueError(f"{name}: expected an integer >= 1, got {a[name]!r}")
    for name in ("max_nodes", "stall_nodes"):
        v = a[name]
        if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < 1):
            raise InputValueError(f"{name}: expected an integer >= 1 or None, got {v!r}")
    for name in ("time_budget", "max_joint_speed", "epsilon"):
        if a[name] is not None and not a[name] > 0:
            raise InputValueError(f"{name}: expected a positive number, got {a[name]!r}")


def synthesize(scene, *, solutions: int = 10, max_nodes: int | None = DEFAULT_MAX_NODES,
               time_budget: float | None = None, seed: int = 0, epsilon: float = 10.0, strategy: str = "mixed",
               device="cpu", dtype=torch.float32, trees: int = 16, candidates: int = 16, reconstruct: bool = True,
               max_joint_speed: float = 8.0, keep_unsmoothed: bool = False,
               min_difference: float = math.radians(2.0),
               node_settings: NodeTestSettings = NodeTestSettings(), progress=None,
               on_solution=None, mount_fit: bool = True, stall_nodes: int | None = None) -> SynthesisResult:
    """Find up to ``solutions`` finger motions for ``scene`` (a :class:`~torchhand.scene.Scene`, a built-in scene
    name or a scene directory).

    Work is bounded by ``max_nodes`` node tests (frames tested by the search; None: unbounded): with it, a seed gives
    the same solutions on any machine, whatever its speed or load (same device, dtype and thread count).
    ``time_budget`` (seconds, everything included; None: none) is a wall-clock cap on top. Every path is
    reconstructed and checked as soon as the search finds it (so its time is inside the budget), and only
    accepted paths count toward ``solutions``: reconstructed within the joint-speed bound ``max_joint_speed``
    (rad/s), passing the final check, and differing from every earlier solution by ``min_difference`` radians of
    mean joint angle. ``keep_unsmoothed`` also accepts paths that pass only as searched (flagged ``reconstructed``
    False); ``reconstruct`` False writes searched poses only.

    progress: optional callable(stage: str, info: dict) called at each stage and after every search round (info
    has elapsed, and in the search nodes_tested, max_nodes, solutions, dead_ends). on_solution: optional
    callable(result, index) called with the (growing) result as each solution is accepted (checkpointing).

    mount_fit: a robot hand (a track with a hand file, no ``mount`` and no sidecar ``[mount]``) is first mounted by
    :func:`~torchhand.synthesis.mount_fit.fit_mount`; ``result.scene`` carries the fitted ``mount`` and
    ``result.mount_fits`` the fits. False: the hand-frame rule's mount as it is.

    stall_nodes: stop the search when no path has reached the last frame and the deepest frame reached has not
    advanced in this many node tests (None: never). When nothing is written, ``result.partial`` holds the deepest
    path the search grew (:class:`~.search.Solution` over frames ``[0, stats.deepest_frame)``, as searched).
    """
    _check_arguments(solutions=solutions, trees=trees, candidates=candidates, max_nodes=max_nodes,
                     stall_nodes=stall_nodes, time_budget=time_budget, max_joint_speed=max_joint_speed, epsilon=epsilon)
    t_start = time.perf_counter()
    scene, fits = _scene_for(scene, mount_fit, _reporter(progress, t_start))
    run = _start(scene, fits, int(seed), t_start, _Options(
        solutions=solutions, max_nodes=max_nodes, time_budget=time_budget, epsilon=epsilon, strategy=strategy,
        device=device, dtype=dtype, trees=trees, candidates=candidates, reconstruct=reconstruct,
        max_joint_speed=max_joint_speed, keep_unsmoothed=keep_unsmoothed, min_difference=min_difference,
        node_settings=node_settings, stall_nodes=stall_nodes), progress, on_solution)
    partial = []
    _, stats = search(run.problem, run.init, run.result.settings, node_settings=node_settings, seed=int(seed),
                      progress=run.on_round, accept=run.accept, partial=partial)
    return _finish(run, stats, partial[0] if partial else None)


@dataclass(frozen=True)
class _Options:
    """The settings of :func:`synthesize` that every seed of a run shares."""

    solutions: int
    max_nodes: int | None
    time_budget: float | None
    epsilon: float
    strategy: str
    device: object
    dtype: torch.dtype
    trees: int
    candidates: int
    reconstruct: bool
    max_joint_speed: float
    keep_unsmoothed: bool
    min_difference: float
    node_settings: NodeTestSettings
    stall_nodes: int | None


@dataclass(frozen=True)
class _Run:
    """One seed's synthesis between its preparation and its end: the problem, the pruned samples, the growing
    result, the search's callbacks and the counters they fill."""

    problem: SynthesisProblem
    init: object
    result: SynthesisResult
    accept: object
    on_round: object
    excluded: dict
    t_final: list
    t_start: float
    t_prep: float


def _reporter(progress, t_start: float):
    def report(stage, **info):
        if progress is not None:
            progress(stage, dict(info, elapsed=time.perf_counter() - t_start))
    return report


def _scene_for(scene, mount_fit: bool, report):
    """The scene loaded (a name or directory) and its robot hands mounted (``mount_fit``); with the fits."""
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    fits = ()
    if mount_fit and any(t.model != "default" and t.mount is None for t in scene.hands):
        report("mount")
        scene, fits = fit_mounts(scene)
    return scene, fits


def _start(scene: Scene, fits: tuple, seed: int, t_start: float, o: _Options, progress, on_solution,
           share: SynthesisProblem | None = None, statics: SynthesisProblem | None = None) -> _Run:
    """Prepare one seed's search: its problem (``share``: another seed's problem of the scene, whose SDF and
    models it reuses; ``statics``: a problem of other frames of the scene, whose SDF and models it reuses), its
    pruned patch samples, and the callbacks that finish each path it finds."""
    report = _reporter(progress, t_start)
    gen = torch.Generator().manual_seed(seed)
    report("prepare", seed=seed)
    problem = build_problem(scene, gen, device=o.device, dtype=o.dtype, share=share, statics=statics)
    report("prune", seed=seed)
    init = prune_patches(problem, gen, settings=o.node_settings)
    t_prep = time.perf_counter() - t_start
    settings = SearchSettings(epsilon=o.epsilon, trees=o.trees, candidates=o.candidates, strategy=o.strategy,
                              solutions=o.solutions, max_nodes=o.max_nodes, stall_nodes=o.stall_nodes,
                              time_budget=None if o.time_budget is None else max(0.0, o.time_budget - t_prep))
    result = SynthesisResult(problem=problem, scene=scene, finals=[], stats=SearchStats(), settings=settings,
                             node_settings=o.node_settings, seed=seed, max_joint_speed=float(o.max_joint_speed),
                             keep_unsmoothed=bool(o.keep_unsmoothed or not o.reconstruct), complete=False,
                             mount_fits=fits)
    excluded = {"failed_check": 0, "unsmoothed": 0, "duplicate": 0}
    t_final = [0.0]
    searched = []                           # the searched poses of the accepted paths

    def accept(path: Solution):
        # a generator (the path's finishing program, :mod:`.finishing`): the search passes its work on
        t0 = time.perf_counter()
        if _duplicate(path.q, searched, o.min_difference):
            excluded["duplicate"] += 1      # as searched already: no need to reconstruct it
            t_final[0] += time.perf_counter() - t0
            return False
        report("reconstruct", solution=len(result.finals), seed=seed)
        t_final[0] += time.perf_counter() - t0
        fin, reason = yield from clocked(finalize_steps(problem, path, len(result.finals), ns=o.node_settings,
                                                        reconstruct=o.reconstruct, joint_speed=o.max_joint_speed,
                                                        keep_unsmoothed=o.keep_unsmoothed), t_final)
        t0 = time.perf_counter()
        if fin is not None and _duplicate(fin.q, result.finals, o.min_difference):
            fin, reason = None, "duplicate"
        t_final[0] += time.perf_counter() - t0
        if fin is None:
            excluded[reason] += 1
            return False
        result.finals.append(fin)
        searched.append(path)
        if on_solution is not None:
            on_solution(result, len(result.finals) - 1)
        return True

    def on_round(s):
        report("search", nodes_tested=s.stats.nodes_tested, max_nodes=o.max_nodes, solutions=len(s.solutions),
               dead_ends=s.stats.dead_ends, seed=seed)

    return _Run(problem=problem, init=init, result=result, accept=accept, on_round=on_round, excluded=excluded,
                t_final=t_final, t_start=t_start, t_prep=t_prep)


def _finish(run: _Run, stats: SearchStats, partial: Solution | None) -> SynthesisResult:
    """The seed's result once its search has ended: counters, exclusions, timings, the partial path."""
    result = run.result
    result.partial = partial if not result.finals else None
    t_total = time.perf_counter() - run.t_start
    result.stats = stats
    result.excluded = Exclusions(**run.excluded)
    result.timings = {"prepare_s": run.t_prep, "search_s": t_total - run.t_prep - run.t_final[0],
                      "finalize_s": run.t_final[0], "total_s": t_total}
    result.complete = True
    return result


def synthesize_seeds(scene, seeds, *, solutions: int = 10, max_nodes: int | None = DEFAULT_MAX_NODES,
                     time_budget: float | None = None, epsilon: float = 10.0, strategy: str = "mixed",
                     device="cpu", dtype=torch.float32, trees: int = 16, candidates: int = 16,
                     reconstruct: bool = True, max_joint_speed: float = 8.0, keep_unsmoothed: bool = False,
                     min_difference: float = math.radians(2.0),
                     node_settings: NodeTestSettings = NodeTestSettings(), progress=None,
                     on_solution=None, mount_fit: bool = True, stall_nodes: int | None = None,
                     multi_stats=None) -> list[SynthesisResult]:
    """:func:`synthesize` for every seed of ``seeds`` in one batched run: the scene is prepared once (its SDF and
    models shared), and the searches advance together, their candidates tested in one node-test call per frame
    (:func:`.multi.search_many`). Each seed's result is the one :func:`synthesize` gives it alone (the same
    solutions, byte for byte, with a node budget); its timings are its own preparation and finishing and the batch's
    search and total (:func:`_batch_timings`).

    progress: callable(stage, info) as in :func:`synthesize`, ``info["seed"]`` naming the seed; on_solution:
    callable(result, index) as each seed's solution is accepted; multi_stats: a :class:`.multi.MultiStats` to
    fill."""
    from .multi import SearchTask, search_many

    seeds = [int(s) for s in seeds]
    if not seeds or len(set(seeds)) != len(seeds):
        raise InputValueError(f"seeds: expected distinct integers, got {seeds!r}")
    _check_arguments(solutions=solutions, trees=trees, candidates=candidates, max_nodes=max_nodes,
                     stall_nodes=stall_nodes, time_budget=time_budget, max_joint_speed=max_joint_speed, epsilon=epsilon)
    t_start = time.perf_counter()
    scene, fits = _scene_for(scene, mount_fit, _reporter(progress, t_start))
    o = _Options(solutions=solutions, max_nodes=max_nodes, time_budget=time_budget, epsilon=epsilon,
                 strategy=strategy, device=device, dtype=dtype, trees=trees, candidates=candidates,
                 reconstruct=reconstruct, max_joint_speed=max_joint_speed, keep_unsmoothed=keep_unsmoothed,
                 min_difference=min_difference, node_settings=node_settings, stall_nodes=stall_nodes)
    runs: list[_Run] = []
    own_prep = []
    for seed in seeds:
        t_seed = time.perf_counter()
        runs.append(_start(scene, fits, seed, t_start, o, progress, on_solution,
                           share=runs[0].problem if runs else None))
        own_prep.append(time.perf_counter() - t_seed)
    t_search = time.perf_counter()
    outcomes = search_many([SearchTask(r.problem, r.init, r.result.settings, node_settings, seed, r.on_round,
                                       r.accept) for r, seed in zip(runs, seeds)], stats=multi_stats)
    results = [_finish(r, out.stats, out.partial) for r, out in zip(runs, outcomes)]
    _batch_timings(results, runs, own_prep, time.perf_counter() - t_search)
    return results


def _batch_timings(results: list, runs: list, own_prep: list, search_wall: float) -> None:
    """Timings of the seeds of one batch: each seed's own preparation and finishing, the batch's shared search (its
    wall time less all finishing) and total, the number of seeds (``batched``) and of node tests (``batch_nodes``),
    whose ratio to ``search_s`` is the batch's node-test rate."""
    search_s = search_wall - sum(r.t_final[0] for r in runs)
    nodes = sum(res.stats.nodes_tested for res in results)
    for res, r, prep in zip(results, runs, own_prep):
        res.timings.update(prepare_s=prep, search_s=search_s, finalize_s=r.t_final[0], batched=len(results),
                           batch_nodes=nodes)
