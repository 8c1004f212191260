"""The last stages of ``torchhand fill`` (:func:`finish`): stitch, settle, test every frame, write the result.

Also the phases the windows are planned on (:func:`hand_phases`, :func:`union_phases`) and the ``frame_status``
codes. :mod:`torchhand.fill.run` runs the stages; docs/fill.md is the user's view.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import torch

from .._atomic import atomic_json
from ..errors import InputValueError
from .phases import PHASE_KINDS, Phase, phases_from_codes
from .stitch import clamp_speed, stitch_variants

__all__ = ["FRAME_SOLVED", "FRAME_FREE", "FRAME_UNSOLVED", "finish", "hand_phases", "union_phases"]

FRAME_SOLVED, FRAME_FREE, FRAME_UNSOLVED = 0, 1, 2
"""``frame_status`` codes: solved (in a solved window, passes the final test), free hand (in no window, passes),
unsolved (in a window without a solution, or fails the test: not claimed)."""


def union_phases(phases: dict, T: int) -> tuple[Phase, ...]:
    """Contact where any hand is in contact; other frames take the first hand's kind (free when none)."""
    kind = np.zeros(T, dtype=np.int8)
    for ph in phases.values():
        for p in ph:
            code = PHASE_KINDS.index(p.kind)
            seg = kind[p.start:p.stop]
            kind[p.start:p.stop] = np.where(code == 2, 2, np.where(seg == 2, 2, np.maximum(seg, code)))
    return phases_from_codes(kind)


def hand_phases(scene, side: str | None, given) -> dict:
    """Per hand side, its phases: ``given`` for ``side`` (or the first hand), the others segmented."""
    from .phases import segment_phases
    from .windows import segments

    if side is not None and side not in scene.sides:
        raise InputValueError(f"side: scene '{scene.name}' has no {side!r} hand; hands: {', '.join(scene.sides)}")
    out = {}
    if given is not None:
        given = tuple(given)
        segments(given, scene.T)                       # contiguous, known kinds, covering [0, T): else one line
        out[side or scene.sides[0]] = given
    for h in scene.hands:
        if h.side not in out:
            out[h.side] = segment_phases(scene, h.side)
    return out


def finish(prepared, phases, runs, settings, writer, t0: float, say, source: str) -> tuple:
    """Stitch the window runs into motions, settle and test them frame by frame, write the result directory.
    settings: the run's settings (:mod:`torchhand.fill.run`). Returns (the directory, frame_status (V, T) int8,
    coverage)."""
    from ..synthesis.node_test import NodeTestSettings
    from .prepare import is_capture
    from ..synthesis.pipeline import Exclusions, SynthesisResult
    from ..synthesis.problem import build_problem
    from ..synthesis.search import SearchSettings, SearchStats

    scene = prepared.scene
    problem = build_problem(scene, torch.Generator().manual_seed(settings.seed))
    rest = torch.stack([h.q_rest for h in problem.hands]).double().cpu()
    # as many motions as the richest window has solutions (a window with fewer repeats its own, v mod n)
    variants = min(settings.variants, max([len(p.qs) for r in runs for p in r.pieces] + [1]))
    motions, known = stitch_variants(runs, phases, scene.T, rest, variants, settings.max_joint_speed, scene.fps)
    # the whole motion's test: the largest slide speed of any window (the most permissive of their sliding rules)
    slide = max([r.slide_speed for r in runs if r.slide_speed is not None] or [settings.slide_speed or 0.02])
    ns = NodeTestSettings(slide_speed=slide, table_slide_speed=slide if is_capture(prepared.scene) else 1e-3)
    failed = np.zeros(scene.T, dtype=bool)          # frames of windows that no piece of any window covers
    for r in runs:
        failed[r.window.start:r.window.stop] = True
    failed &= ~known
    contact = np.zeros(scene.T, dtype=bool)
    for p in phases:
        if p.kind == "contact":
            contact[p.start:p.stop] = True
    finals, status = [], []
    say(f"checking {len(motions)} stitched motion(s) of {scene.T} frames")
    for v, q in enumerate(motions):
        q, res = _settle(problem, q.to(problem.object_pose.dtype), known, ns, settings)
        ok = res.feasible.cpu().numpy()
        st = np.where(ok & known, FRAME_SOLVED, np.where(ok & ~failed, FRAME_FREE, FRAME_UNSOLVED)).astype(np.int8)
        status.append(st)
        finals.append((q, res))
    keep = _distinct([q for q, _ in finals], status)
    if len(keep) < len(finals):
        say(f"{len(finals) - len(keep)} stitched motion(s) left out: within 2 degrees of mean joint angle of an "
            f"earlier one over their solved frames")
    finals = [_final(finals[v][1], finals[v][0], i, problem) for i, v in enumerate(keep)]
    status = [status[v] for v in keep]
    stats = SearchStats(nodes_tested=sum(r.nodes for r in runs),
                        rejections={k: sum(r.summary.get("rejections", {}).get(k, 0) for r in runs)
                                    for k in ("kinematic", "finger_finger", "dynamic")},
                        paths_found=sum(r.summary.get("paths_found", 0) for r in runs), stopped_by="windows")
    result = SynthesisResult(problem=problem, scene=scene, finals=finals, stats=stats,
                             settings=SearchSettings(max_nodes=settings.max_nodes, solutions=settings.variants),
                             excluded=Exclusions(), node_settings=ns, seed=settings.seed,
                             max_joint_speed=settings.max_joint_speed, keep_unsmoothed=False, complete=True)
    result.timings = {"total_s": time.perf_counter() - t0, "search_s": sum(r.time_s for r in runs)}
    frame_status = np.stack(status)
    coverage = float((frame_status[:, contact] == FRAME_SOLVED).mean(1).max()) if contact.any() else 1.0
    out = _write(writer, result, frame_status, prepared, phases, runs, settings, coverage, contact, source)
    say(f"wrote {out}: {len(finals)} motion(s); contact-phase frames solved {100 * coverage:.1f} %; unsolved "
        f"frames per motion {[int((s == FRAME_UNSOLVED).sum()) for s in frame_status]}")
    return out, frame_status, coverage


def _settle(problem, q: torch.Tensor, known: np.ndarray, ns, settings):
    """The stitched motion smoothed by the synthesis' reconstruction (Eqs. 9-11) with the contacts of its solved
    frames kept, free fingers pulled to rest, and the object, the table and the other fingers as collision
    constraints; solved frames the smoothing breaks get their stitched pose back (blended in, as the synthesis
    does). Returns (q (T, H, D), the final evaluation)."""
    from ..synthesis.finishing import _blend_in, _evaluate_motion
    from ..synthesis.reconstruct import ContactTrack, reconstruct_motion

    first = _evaluate_motion(problem, q, ns)
    kn = torch.as_tensor(known)
    qs = []
    for h, hand in enumerate(problem.hands):
        L = hand.num_links
        sl = slice(h * L, (h + 1) * L)
        poses = hand.forward_kinematics(q[:, h], problem.root[h])
        loc = first.c_local[:, sl]
        target = (poses[..., :3, :3] @ loc.unsqueeze(-1)).squeeze(-1) + poses[..., :3, 3]
        mask = first.c_mask[:, sl] & (hand.link_finger >= 0) & kn[:, None] & first.feasible[:, None]
        link = torch.arange(L).expand(q.shape[0], L)
        rec = reconstruct_motion(hand, problem.root[h], q[:, h], ContactTrack(link=link, point_local=loc,
                                 target=target, mask=mask), sdf=problem.sdf, object_pose=problem.object_pose,
                                 penetration_tol=0.5 * ns.pen_tol, max_inner=8, step_tol=1e-3,
                                 table_height=problem.table_height,
                                 max_joint_step=settings.max_joint_speed / problem.fps,
                                 finger_tol=0.5 * ns.finger_tol)
        qs.append(rec.q.to(q.dtype))
    q_rec = torch.stack(qs, 1)
    res = _evaluate_motion(problem, q_rec, ns)
    broken = first.feasible & ~res.feasible & kn
    if bool(broken.any()):
        q_rec = _blend_in(q_rec, q, broken)
        res = _evaluate_motion(problem, q_rec, ns)
    # the searched poses blended back (and a partial path's own steps) may move faster than the bound: every step
    # is clipped to it, and the clipped motion is what is tested and written
    step = settings.max_joint_speed / problem.fps
    clipped = clamp_speed(q_rec, step * (1 - 1e-3))   # a margin for the written file's float32 rounding
    if not torch.equal(clipped, q_rec):
        q_rec = clipped
        res = _evaluate_motion(problem, q_rec, ns)
    return q_rec, res


def _distinct(motions: list, status: list, min_difference: float = math.radians(2.0)) -> list[int]:
    """Indices of the motions kept: each one's mean absolute joint difference to every motion kept before it, over
    the frames it claims solved, is at least ``min_difference`` radians (variants stitched from the same one-motion
    pieces are otherwise copies)."""
    keep = []
    for v, q in enumerate(motions):
        rows = torch.as_tensor(status[v] == FRAME_SOLVED)
        if not rows.any() or all(float((q[rows] - motions[u][rows]).abs().mean()) >= min_difference for u in keep):
            keep.append(v)
    return keep or [0]


def _final(res, q: torch.Tensor, v: int, problem):
    from ..synthesis.finishing import FinalSolution

    T, H = q.shape[:2]
    F = problem.hands[0].num_fingers
    return FinalSolution(q=q.to(res.c_point.dtype), c_mask=res.c_mask, c_local=res.c_local, c_point=res.c_point,
                         c_normal=res.c_normal, c_force=res.c_force, env_force=res.env_force,
                         guiding=torch.zeros(T, H, F, dtype=torch.bool), guide_obj=torch.zeros(T, H, F, 3),
                         sliding=res.c_sliding, reconstructed=True, index=v)


def _write(writer, result, frame_status, prepared, phases, runs, settings, coverage, contact, source) -> Path:
    from ..synthesis.output import solution_arrays, stats_dict
    from .captured import result_reference
    from .timeline import plot_timeline

    writer.start(result.problem, result.scene)
    for v in range(len(result.finals)):
        arrays = solution_arrays(result, v)
        arrays["frame_status"] = frame_status[v]
        writer.write_solution(v, arrays, result.scene.name)
    doc = {"format_version": 1, "frames": result.scene.T, "fps": result.scene.fps,
           "phases": {s: [p.to_json() for p in ph] for s, ph in prepared.phases.items()},
           "contact_phases": [p.to_json() for p in phases if p.kind == "contact"],
           "windows": [r.to_json() for r in runs],
           "slide_speed": {"value": result.node_settings.slide_speed, "source": source,
                           "per_window": [r.slide_speed for r in runs]},
           "wrist": prepared.to_json()["wrist_deviation"], "wrist_tolerance": prepared.tolerance.to_json(),
           "object": prepared.to_json()["object_deviation"],
           "frame_status_codes": {"0": "solved", "1": "free hand", "2": "unsolved"},
           "coverage": coverage,
           "unsolved_frames": [np.nonzero(s == FRAME_UNSOLVED)[0].tolist() for s in frame_status]}
    atomic_json(writer.stage / "phases.json", doc)
    plot_timeline(doc, frame_status, writer.stage / "timeline.png", title=result.scene.name)
    stats = stats_dict(result)
    stats["fill"] = {"window": settings.window, "overlap": settings.overlap, "variants": settings.variants,
                     "max_nodes_per_window": settings.max_nodes,
                     "stall_nodes": settings.stall_nodes, "jobs": settings.jobs, "device": settings.device,
                     "windows": len(runs),
                     "windows_solved": sum(r.status == "solved" for r in runs),
                     "windows_partial": sum(r.status == "partial" for r in runs), "coverage": coverage,
                     "contact_frames": int(contact.sum()),
                     "window_time_s": [round(r.time_s, 2) for r in runs]}
    stats["capture"] = prepared.to_json()
    reference = result_reference(result, writer.stage, frames=[s == FRAME_SOLVED for s in frame_status])
    if reference is not None:
        stats["reference"] = reference
    return writer.complete(stats)


