"""Contact-sampling synthesis end to end (Ye & Liu 2012, Algorithm 1): prepare, search, reconstruct, check.

:func:`synthesize` runs the steps as a list of pure stages over typed state:

1. :func:`~.problem.build_problem`: hands, SDF, required wrenches, contact patches;
2. :func:`~.initial.prune_patches`: the initial case's kinematic pruning;
3. :func:`~.search.search`: the randomized depth-first search (time budget = what is left of ``time_budget``
   after preparation, less a reserve for the last stage);
4. :func:`finalize_solution` for every path found: spacetime reconstruction (§6) of each hand, then the contact and
   dynamic test of the reconstructed poses with every contact's actual sliding velocity (a contact held since the
   previous frame whose hand point moves on the object faster than ``NodeTestSettings.slide_speed`` is sliding and
   must have its force on the cone boundary: "solutions that violate sliding friction for non-guiding contacts are
   excluded", §6; the search applies the same rule, so its own poses pass it). A path whose reconstruction fails
   this test gets its searched poses blended back in around the failing frames, then falls back to its searched
   poses; a path that fails all three is excluded and counted.

Conventions: world frame, metres, newtons, radians; forces are those of the hand on the object.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import torch

from ..scene import Scene
from .initial import prune_patches
from .node_test import CAUSE_DYNAMIC, FrameResult, NodeTestSettings, evaluate_poses
from .problem import SynthesisProblem, build_problem
from .reconstruct import ContactTrack, reconstruct_motion
from .search import SearchSettings, SearchStats, Solution, search

__all__ = ["FinalSolution", "SynthesisResult", "synthesize", "finalize_solution"]


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


@dataclass
class SynthesisResult:
    """Everything :func:`synthesize` produced: the problem, the finished solutions and the run's figures."""

    problem: SynthesisProblem
    solutions: list
    stats: SearchStats
    settings: SearchSettings
    excluded: int = 0
    timings: dict = field(default_factory=dict)
    node_settings: NodeTestSettings = NodeTestSettings()


def _rows_replaced(res: FrameResult, index: torch.Tensor, values: FrameResult) -> FrameResult:
    """``res`` with the rows ``index`` (n,) replaced by those of ``values`` (n rows)."""
    def put(a, b):
        out = a.clone()
        out[index] = b
        return out
    return FrameResult(**{f.name: put(getattr(res, f.name), getattr(values, f.name))
                          for f in dataclasses.fields(FrameResult)})


def _evaluate_motion(problem: SynthesisProblem, q: torch.Tensor, ns: NodeTestSettings):
    """The contact and dynamic test of a whole motion q (T, H, D), with the search's sliding rule (a contact held
    since the previous frame whose hand point moves on the object faster than ``ns.slide_speed`` slides): one
    pass for the contacts, a second with each frame's predecessor. Returns the FrameResult of the second pass."""
    T = q.shape[0]
    t = torch.arange(T, device=q.device)
    ns = dataclasses.replace(ns, cone_tol=None, cone_iters=None, cone_polish=True, cone_polish_from=None)  # full accuracy
    first = evaluate_poses(problem, t, q, settings=ns, dynamics=False)     # contacts only
    prev_mask = torch.cat([torch.zeros_like(first.c_mask[:1]), first.c_mask[:-1]])
    q_prev = torch.cat([q[:1], q[:-1]])
    res = evaluate_poses(problem, t, q, q_prev, prev_mask, settings=ns)
    retry = (res.cause == CAUSE_DYNAMIC).nonzero().squeeze(-1)
    if retry.numel():
        # a force solve that stopped at its iteration limit gets a longer one before the frame counts as failed
        again = evaluate_poses(problem, t[retry], q[retry], q_prev[retry], prev_mask[retry],
                               settings=dataclasses.replace(ns, cone_iters=20000))
        res = _rows_replaced(res, retry, again)
    return res


def _blend_in(q_smooth: torch.Tensor, q_search: torch.Tensor, bad: torch.Tensor, width: float = 2.0) -> torch.Tensor:
    """q_smooth with the searched poses blended back in around the frames ``bad`` (T,) bool: weight 1 at a bad
    frame, falling off as exp(-(d / width)^2) with the distance d in frames."""
    T = q_smooth.shape[0]
    idx = bad.nonzero().squeeze(-1).to(q_smooth.dtype)
    t = torch.arange(T, device=q_smooth.device, dtype=q_smooth.dtype)
    w = torch.exp(-(((t[:, None] - idx[None]) / width) ** 2)).amax(-1).reshape(T, 1, 1)
    return (1 - w) * q_smooth + w * q_search


def finalize_solution(problem: SynthesisProblem, sol: Solution, index: int, *, ns: NodeTestSettings,
                      reconstruct: bool = True) -> FinalSolution | None:
    """Reconstruct and re-check one searched path (see the module docstring). Tried in turn: the smoothed motion;
    the smoothed motion with the searched poses blended back in around the frames that failed; the searched
    poses. None if none passes the contact and dynamic test in every frame."""
    def attempt(q):
        res = _evaluate_motion(problem, q, ns)
        return res, res.c_sliding

    candidates = []
    if reconstruct:
        qs = []
        for h, hand in enumerate(problem.hands):
            L = hand.num_links
            sl = slice(h * L, (h + 1) * L)
            poses = hand.forward_kinematics(sol.q[:, h], problem.root[h])
            link = torch.arange(L, device=sol.q.device).expand(sol.q.shape[0], L)
            loc = sol.c_local[:, sl]
            target = (poses[..., :3, :3] @ loc.unsqueeze(-1)).squeeze(-1) + poses[..., :3, 3]
            mask = sol.c_mask[:, sl] & (hand.link_finger >= 0)
            contacts = ContactTrack(link=link, point_local=loc, target=target, mask=mask)
            rec = reconstruct_motion(hand, problem.root[h], sol.q[:, h], contacts, sdf=problem.sdf,
                                     object_pose=problem.object_pose, penetration_tol=0.5 * ns.pen_tol,
                                     max_inner=8, step_tol=1e-3)
            qs.append(rec.q.to(sol.q.dtype))
        q_rec = torch.stack(qs, 1)
        res, sliding = attempt(q_rec)
        candidates.append((q_rec, res, sliding, True))
        if not bool(res.feasible.all()):
            q_mix = _blend_in(q_rec, sol.q, ~res.feasible)
            res, sliding = attempt(q_mix)
            candidates.append((q_mix, res, sliding, True))
    if not candidates or not bool(candidates[-1][1].feasible.all()):
        res, sliding = attempt(sol.q)
        candidates.append((sol.q, res, sliding, False))
    q, res, sliding, smoothed = candidates[-1]
    if not bool(res.feasible.all()):
        return None
    return FinalSolution(q=q, c_mask=res.c_mask, c_local=res.c_local, c_point=res.c_point, c_normal=res.c_normal,
                         c_force=res.c_force, env_force=res.env_force, guiding=sol.guiding, guide_obj=sol.guide_obj,
                         sliding=sliding, reconstructed=smoothed, index=index)


def synthesize(scene: Scene, *, solutions: int = 10, time_budget: float = 120.0, seed: int = 0,
               epsilon: float = 10.0, strategy: str = "mixed", device="cpu", dtype=torch.float32,
               trees: int = 16, candidates: int = 16, reconstruct: bool = True,
               node_settings: NodeTestSettings = NodeTestSettings(), progress=None) -> SynthesisResult:
    """Find up to ``solutions`` finger motions for ``scene`` within ``time_budget`` seconds (everything included).

    progress: optional callable(stage: str, info: dict) called at each stage and after every search round
    (info has nodes_tested, solutions, dead_ends, elapsed, budget).
    """
    t_start = time.perf_counter()
    gen = torch.Generator().manual_seed(int(seed))

    def report(stage, **info):
        if progress is not None:
            progress(stage, dict(info, elapsed=time.perf_counter() - t_start, budget=time_budget))

    report("prepare")
    problem = build_problem(scene, gen, device=device, dtype=dtype)
    report("prune")
    init = prune_patches(problem, gen, settings=node_settings)
    t_prep = time.perf_counter() - t_start
    settings = SearchSettings(epsilon=epsilon, trees=trees, candidates=candidates, strategy=strategy,
                              solutions=solutions, time_budget=max(1.0, time_budget - t_prep))

    def on_round(s):
        report("search", nodes_tested=s.stats.nodes_tested, solutions=len(s.solutions),
               dead_ends=s.stats.dead_ends)

    # every path found takes about 2 s of reconstruction and checking (T ~ 70 frames, one hand) off the budget
    paths, stats = search(problem, init, settings, node_settings=node_settings, seed=int(seed), progress=on_round,
                          reserve_per_solution=0.03 * problem.T * problem.H if reconstruct else 0.0)
    t_search = time.perf_counter() - t_start - t_prep
    paths = paths[:solutions]                 # the last round may have found more than were asked for
    finals, excluded = [], 0
    for i, path in enumerate(paths):
        report("reconstruct", solution=i, of=len(paths))
        # past the budget, the remaining paths are checked as searched (no smoothing)
        smooth = reconstruct and time.perf_counter() - t_start < time_budget
        fin = finalize_solution(problem, path, len(finals), ns=node_settings, reconstruct=smooth)
        if fin is None:
            excluded += 1
        else:
            finals.append(fin)
    t_total = time.perf_counter() - t_start
    return SynthesisResult(problem=problem, solutions=finals, stats=stats, settings=settings, excluded=excluded,
                           timings={"prepare_s": t_prep, "search_s": t_search,
                                    "reconstruct_s": t_total - t_prep - t_search, "total_s": t_total},
                           node_settings=node_settings)


def diversity(solutions: list) -> float:
    """Mean pairwise distance between the guiding-point trajectories of the solutions: the mean over frames and
    fingers of |p_a - p_b| (object frame, metres), a finger counted where either solution guides it (a missing
    guide counts as the object's origin). NaN with fewer than two solutions."""
    if len(solutions) < 2:
        return math.nan
    pts = [s.guide_obj * s.guiding[..., None] for s in solutions]
    on = [s.guiding for s in solutions]
    total, count = 0.0, 0
    for a in range(len(pts)):
        for b in range(a + 1, len(pts)):
            either = on[a] | on[b]
            d = (pts[a] - pts[b]).norm(dim=-1)
            total += float(d[either].mean()) if bool(either.any()) else 0.0
            count += 1
    return total / count
