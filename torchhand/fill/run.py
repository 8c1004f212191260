"""``torchhand fill``: finger motion for every frame of a whole capture.

Steps, each a pure stage over typed state:

1. prepare (:func:`torchhand.fill.prepare.prepare_capture`): phases per hand, the wrists steadied within capture
   noise;
2. plan (:func:`torchhand.fill.windows.plan_windows`): overlapping windows over the contact phases (of any hand);
3. search (:func:`run_window`): each window is an independent :func:`~torchhand.synthesis.pipeline.synthesize`
   with its own seed and the slide speed of its own noise (unless given); ``jobs`` windows run at once in separate
   processes (the same results: node budgets, one thread each);
4. stitch (:mod:`torchhand.fill.stitch`): variant v starts from solution v of the first window of each contact
   phase and takes, in each next window, the solution closest to it over their overlap; windows without a
   solution leave their frames to the free-hand transitions;
5. settle and evaluate (:func:`torchhand.fill.fill.finish`): the stitched motion is smoothed once by the synthesis'
   reconstruction, then the whole motion goes through the synthesis' final test (contacts, exact normals, forces with
   the table, the sliding rule) frame by frame; ``frame_status`` per frame: 0 solved (in a solved window, passes),
   1 free hand (no window, passes: transitions, rest), 2 unsolved (fails: not claimed; the checker lists these
   frames apart);
6. write: the result directory (docs/result_format.md) of the whole scene with one solution per variant, and
   ``phases.json`` (phases, windows with status, time, node tests and, for failed windows, the search's rejection
   summary).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..errors import InputValueError
from .fill import FRAME_FREE, FRAME_SOLVED, FRAME_UNSOLVED, finish, hand_phases, union_phases
from .phases import Phase, format_phases
from .windows import Window, plan_windows

__all__ = ["FillSettings", "WindowRun", "FillResult", "FillPlan", "plan_fill", "search_windows", "fill_capture", "run_window", "window_lane", "FRAME_SOLVED", "FRAME_FREE",
           "FRAME_UNSOLVED"]



@dataclass(frozen=True)
class FillSettings:
    """variants: solutions per window and written motions; window, overlap: frames; max_nodes: node tests per
    window (shared by its pieces, :mod:`torchhand.fill.pieces`); stall_nodes: node tests without a deeper frame
    after which a search of a window stops at a wall and the window goes on past it; seed: the run's seed; jobs:
    1, every window's searches in this process, advancing together (their node tests gathered into shared calls,
    :func:`_search_together`), or N > 1 processes each searching one window at a time (the same results either
    way); slide_speed: m/s or None (each window's noise); tolerance: :class:`~torchhand.fill.wrist.WristTolerance`
    or None (5 mm, 3 degrees); max_joint_speed: rad/s; device: where the searches run ("cpu" or "cuda"; the
    stitching and the whole-motion test run on the CPU)."""

    variants: int = 3
    window: int = 60
    overlap: int = 15
    max_nodes: int = 30000
    stall_nodes: int = 5000
    seed: int = 0
    jobs: int = 1
    slide_speed: float | None = None
    tolerance: object = None
    max_joint_speed: float = 8.0
    device: str = "cpu"

    def __post_init__(self):
        for name in ("variants", "max_nodes", "stall_nodes", "jobs", "window", "overlap"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise InputValueError(f"{name}: expected an integer >= 1, got {v!r}")
        if self.overlap < 2 or self.window < 3 * self.overlap:
            raise InputValueError(f"window, overlap: expected overlap >= 2 and window >= 3 x overlap (a frame in at "
                                  f"most two windows), got window {self.window}, overlap {self.overlap}")
        if self.device not in ("cpu", "cuda"):
            raise InputValueError(f"device: expected 'cpu' or 'cuda', got {self.device!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int):
            raise InputValueError(f"seed: expected an integer, got {self.seed!r}")
        for name in ("slide_speed", "max_joint_speed"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputValueError(f"{name}: expected a positive number, got {v!r}")


@dataclass
class WindowRun:
    """What one window's searches gave: its pieces (:class:`~torchhand.fill.pieces.Piece`: frames and motions),
    status ("solved": one search reached the window's end from its first frame; "partial": pieces cover part of
    it; "failed": none; "error": its search raised an error, in ``summary``), node tests, seconds, slide speed
    (None after an error), the searches (:class:`~torchhand.fill.pieces.Attempt`)
    and the last search's figures (rejections, deepest frame, paths not written)."""

    window: Window
    pieces: list
    status: str
    nodes: int
    time_s: float
    slide_speed: float | None
    attempts: list = field(default_factory=list)
    summary: dict = field(default_factory=dict)

    @property
    def qs(self) -> list:
        """The solutions of a window solved whole, each (frames, H, D); empty otherwise."""
        return list(self.pieces[0].qs) if self.status == "solved" else []

    @property
    def solved_frames(self) -> int:
        """Frames of the window inside a piece."""
        cover = set()
        for p in self.pieces:
            cover.update(range(p.start, p.stop))
        return len(cover)

    def to_json(self) -> dict:
        return {**self.window.to_json(), "status": self.status,
                "solutions": max([len(p.qs) for p in self.pieces if p.kind == "solved"] + [0]),
                "node_tests": self.nodes, "time_s": round(self.time_s, 2), "slide_speed": self.slide_speed,
                "pieces": [p.to_json() for p in self.pieces], "searches": [a.to_json() for a in self.attempts],
                **self.summary}


@dataclass
class FillResult:
    """out: the result directory; phases: per side; windows: the :class:`WindowRun` of each window;
    frame_status: (V, T) int8; coverage: fraction of contact-phase frames solved (of the best variant)."""

    out: Path
    phases: dict
    windows: list
    frame_status: np.ndarray
    coverage: float
    time_s: float


def run_window(scene, window: Window, settings: FillSettings, phases=None) -> WindowRun:
    """The independent search of one window, alone (picklable arguments: runs in a worker process as well).
    phases: the window's own phases (frames of the window), whose contact frames measure its noise when
    ``settings.slide_speed`` is None (default: every frame)."""
    from ..synthesis.lanes import run_lane

    return run_lane(window_lane(scene, window, settings, phases, shared={}))


def window_lane(scene, window: Window, settings: FillSettings, phases=None, shared: dict | None = None, say=None):
    """:func:`run_window` as a lane of :func:`~torchhand.synthesis.multi.search_lanes` (generator): it yields each
    of the window's searches (its pieces, :func:`~torchhand.fill.pieces.pieces_plan`) and returns its
    :class:`WindowRun`, the same as alone. shared: a dict shared by the windows of one scene (their problems reuse
    one SDF and hand models, so that their searches share node-test calls); say: optional callable(line) told as
    each search is prepared."""
    from ..synthesis.lanes import synthesis_lane
    from .pieces import pieces_plan

    t0 = time.perf_counter()
    slide, ns = _window_speeds(scene, window, settings, phases)
    plan = pieces_plan(scene, window.start, window.stop, budget=settings.max_nodes, stall_nodes=settings.stall_nodes)
    try:
        request = next(plan)
        while True:
            part, max_nodes, stall = request
            if say is not None:
                say(f"preparing a search of frames {window.stop - part.T}-{window.stop - 1} ({max_nodes} node tests "
                    f"left)")
            res = yield from synthesis_lane(part, seed=window.seed, solutions=settings.variants, max_nodes=max_nodes,
                                            node_settings=ns, max_joint_speed=settings.max_joint_speed,
                                            stall_nodes=stall, device=settings.device, shared=shared)
            request = plan.send(res)
    except StopIteration as done:
        pieces, attempts, res = done.value
    st = res.stats
    summary = {"rejections": {k: sum(a.rejections.get(k, 0) for a in attempts) for k in st.rejections},
               "deepest_frame": attempts[0].reached - window.start, "paths_found": st.paths_found,
               "not_written": dataclasses.asdict(res.excluded)}
    whole = bool(pieces) and pieces[0].kind == "solved" and pieces[0].start == window.start
    status = "solved" if whole else "partial" if pieces else "failed"
    return WindowRun(window, pieces, status, sum(a.nodes for a in attempts), time.perf_counter() - t0,
                     float(slide), attempts, summary)


def _window_speeds(scene, window: Window, settings: FillSettings, phases):
    """The window's slide speed (the option, or its capture noise) and its node-test settings."""
    from ..synthesis.node_test import NodeTestSettings
    from .noise import capture_noise
    from .prepare import is_capture

    slide = settings.slide_speed
    if slide is None:
        sub = scene.with_frames(window.start, window.stop)
        held = phases or (Phase("contact", 0, sub.T),)
        slide = max(capture_noise(sub, h.side, held).slide_speed for h in sub.hands)
    return slide, NodeTestSettings(slide_speed=slide, table_slide_speed=slide if is_capture(scene) else 1e-3)


def clip_phases(phases, start: int, stop: int) -> tuple:
    """The phases within frames ``[start, stop)``, renumbered from 0."""
    return tuple(Phase(p.kind, max(p.start, start) - start, min(p.stop, stop) - start) for p in phases
                 if p.stop > start and p.start < stop)


def search_windows(scene, windows, settings: FillSettings, progress=None, phases=()) -> list[WindowRun]:
    """Step 3 of the module docstring: the :class:`WindowRun` of every window of ``windows`` (in order), with
    ``settings.jobs`` (1: together in this process; N: N processes, a window at a time). phases: the planned
    phases (each window's own measure its noise); progress: callable(line) or None."""
    own = {w.index: clip_phases(phases, w.start, w.stop) or None for w in windows}
    if settings.jobs == 1 or len(windows) <= 1:
        return _search_together(scene, windows, settings, progress, own)
    import concurrent.futures as cf
    import multiprocessing as mp

    done: dict[int, WindowRun] = {}
    pool = cf.ProcessPoolExecutor(max_workers=settings.jobs, mp_context=mp.get_context("spawn"),
                                  initializer=torch.set_num_threads, initargs=(1,))   # one thread each
    try:
        futures = {pool.submit(run_window, scene, w, settings, own[w.index]): w for w in windows}
        for fut in cf.as_completed(futures):
            w = futures[fut]
            try:
                run = fut.result()
            except cf.process.BrokenProcessPool:
                raise
            except Exception as exc:                   # kept and reported: the other windows' work is not lost
                run = _errored(w, exc, progress)
            done[run.window.index] = run
            _report(progress, run, len(windows))
    except BaseException:
        # an error (or an interrupt) ends the run now: the windows still queued are not searched first
        pool.shutdown(wait=False, cancel_futures=True)
        for proc in list((getattr(pool, "_processes", None) or {}).values()):
            proc.terminate()
        raise
    pool.shutdown()
    return [done[w.index] for w in windows]


REPORT_EVERY_S = 30.0
"""With one process, a progress line at most this often (seconds) while the windows search (only the lines'
timing depends on the clock, never a result)."""


def _search_together(scene, windows, settings: FillSettings, progress, own: dict) -> list[WindowRun]:
    """Every window's searches in one process, advancing together (:func:`~torchhand.synthesis.multi.search_lanes`:
    the node tests of all windows gathered into one call per frame); each window's run is the one it gets alone.
    A window whose search raises an error is reported and kept (status "error"); the others go on."""
    from ..synthesis.multi import MultiStats, search_lanes

    shared: dict = {}
    runs: list = [None] * len(windows)

    def done(i: int, value) -> None:
        run = value if isinstance(value, WindowRun) else _errored(windows[i], value, progress)
        runs[i] = run
        _report(progress, run, len(windows))

    last = [time.monotonic()]

    def on_round(stats: MultiStats, running: int) -> None:
        if progress is not None and running and time.monotonic() - last[0] >= REPORT_EVERY_S:
            last[0] = time.monotonic()
            nodes = sum(stats.batch_sizes)
            progress(f"searching: {running} of {len(windows)} window(s) running; {nodes} node tests in {stats.calls} "
                     f"call(s) of {nodes / max(stats.calls, 1):.0f} candidates on average")

    def teller(w: Window):
        if progress is None:
            return None
        return lambda line: progress(f"window {w.index + 1}/{len(windows)}: {line}")

    lanes = [window_lane(scene, w, settings, own[w.index], shared, teller(w)) for w in windows]
    search_lanes(lanes, on_done=done, on_round=on_round)
    return runs


def _errored(window: Window, exc: BaseException, progress) -> WindowRun:
    """The run of a window whose search raised an error: no piece, status "error", the error in its summary and,
    in full, on the progress stream."""
    import traceback

    text = "".join(traceback.format_exception(exc))
    if progress is not None:
        progress(f"window {window.index + 1} frames {window.start}-{window.stop - 1}: error, its frames are flagged "
                 f"unsolved:\n{text}")
    return WindowRun(window, [], "error", 0, 0.0, None,
                     summary={"error": f"{type(exc).__name__}: {exc}", "traceback": text[-4000:]})


def _report(progress, run: WindowRun, n: int) -> None:
    if progress is not None and run.status == "error":
        progress(f"window {run.window.index + 1}/{n}: {run.summary['error']}")
    elif progress is not None:
        w = run.window
        progress(f"window {w.index + 1}/{n} frames {w.start}-{w.stop - 1}: {run.status}, {len(run.qs)} solution(s), "
                 f"{run.solved_frames}/{w.frames} frames in {len(run.pieces)} piece(s) from {len(run.attempts)} "
                 f"search(es), {run.nodes} node tests, {run.time_s:.0f} s, slide speed {run.slide_speed:.3g} m/s")


@dataclass(frozen=True)
class FillPlan:
    """What the search stage of :func:`fill_capture` starts from: the prepared capture
    (:class:`~torchhand.fill.prepare.PreparedCapture`), the settings with the slide speed resolved (None: each
    window's noise), where the slide speed comes from, the phases the windows are planned on and the windows."""

    prepared: object
    settings: FillSettings
    source: str
    phases: tuple
    windows: list


def plan_fill(scene, settings: FillSettings, *, side: str | None = None, phases=None,
              steady_object: bool = True) -> FillPlan:
    """Steps 1 and 2 of the module docstring for ``scene`` (a Scene, a built-in name or a scene directory): a robot
    hand mounted once for every window, the capture prepared, the windows planned. Arguments as
    :func:`fill_capture`'s."""
    from ..scene import Scene, load_scene
    from ..synthesis.mount_fit import fit_mounts
    from .object_rest import ObjectRest
    from .prepare import DEFAULT_SLIDE_SPEED, is_capture, prepare_capture

    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    if any(t.model != "default" and t.mount is None for t in scene.hands):
        scene, _ = fit_mounts(scene)               # a robot hand is mounted once, for every window alike
    given = settings.slide_speed
    source = "option" if given is not None else "capture noise (per window)" if is_capture(scene) else "default"
    # a capture's windows measure their own noise (torchhand.fill.noise); other scenes keep the default
    slide = given if given is not None else None if is_capture(scene) else DEFAULT_SLIDE_SPEED
    prepared = prepare_capture(scene, slide_speed=slide or DEFAULT_SLIDE_SPEED, tolerance=settings.tolerance,
                               phases=hand_phases(scene, side, phases),
                               object_rest=ObjectRest() if steady_object else None)
    settings = dataclasses.replace(settings, slide_speed=slide)
    chosen = {s: ph for s, ph in prepared.phases.items() if side is None or s == side}
    planned = union_phases(chosen, scene.T)
    windows = plan_windows(planned, scene.T, window=settings.window, overlap=settings.overlap, seed=settings.seed)
    return FillPlan(prepared, settings, source, planned, windows)


def fill_capture(scene, out, *, side: str | None = None, variants: int = 3, window: int = 60, overlap: int = 15,
                 max_nodes: int = 30000, seed: int = 0, phases=None, slide_speed: float | None = None,
                 progress=None, overwrite: bool = False, tolerance=None, jobs: int = 1,
                 max_joint_speed: float = 8.0, steady_object: bool = True, stall_nodes: int = 5000,
                 device: str = "cpu") -> FillResult:
    """Finger motion for every frame of ``scene`` (a :class:`~torchhand.scene.Scene`, a built-in scene name or a
    scene directory), written as the result directory ``out`` (docs/fill.md).

    side: the hand whose phases set the windows (None: all hands'); variants: motions written (at most the most
    solutions any window found); window, overlap: frames (:func:`~torchhand.fill.windows.plan_windows`);
    max_nodes: node tests per window, shared by its searches; stall_nodes: node tests without a deeper frame
    after which a window's search stops at a wall and the window goes on past it (:mod:`torchhand.fill.pieces`);
    seed: the main seed (each window's is derived from it); phases: the phases
    of ``side`` (or the first hand) instead of :func:`~torchhand.fill.phases.segment_phases`'; slide_speed: m/s or
    None (a capture's own noise, 0.02 for other scenes); progress: callable(line) or None; overwrite: replace an
    earlier result directory; tolerance: the wrist tolerance of a capture
    (:class:`~torchhand.fill.wrist.WristTolerance`, None: 5 mm, 3 degrees); jobs: 1 (every window's searches
    together in this process) or the number of processes searching one window at a time (:class:`FillSettings`);
    max_joint_speed: rad/s; steady_object: a capture's object put on the table and held at rest within capture
    noise (:mod:`torchhand.fill.object_rest`; False: as captured); device: where the searches run.
    Raises InputValueError (one line) for bad input or an output directory that may not be written, before any
    work.
    """
    from ..synthesis.output import ResultWriter

    settings = FillSettings(variants=variants, window=window, overlap=overlap, max_nodes=max_nodes,
                            stall_nodes=stall_nodes, seed=seed,
                            jobs=jobs, slide_speed=slide_speed, tolerance=tolerance, max_joint_speed=max_joint_speed,
                            device=device)
    t0 = time.perf_counter()
    writer = ResultWriter(out, overwrite=overwrite)           # validated before any work: nothing is lost
    try:
        plan = plan_fill(scene, settings, side=side, phases=phases, steady_object=steady_object)
    except BaseException:
        writer.abandon()
        raise
    prepared, settings, source, phases, windows = plan.prepared, plan.settings, plan.source, plan.phases, plan.windows
    say = progress or (lambda line: None)
    for s, ph in prepared.phases.items():
        say(f"{s} hand phases:\n{format_phases(ph, prepared.scene.fps)}")
    say(f"slide speed: {source}" + (f", {settings.slide_speed:.3g} m/s" if settings.slide_speed else ""))
    for line in prepared.describe().split("; ")[1:]:
        say(line)
    say(f"{len(windows)} window(s) of up to {settings.window} frames over "
        f"{sum(p.frames for p in phases if p.kind == 'contact')} contact frames")
    runs = search_windows(prepared.scene, windows, settings, say, phases)
    out, status, coverage = finish(prepared, phases, runs, settings, writer, t0, say, source)
    return FillResult(out=out, phases=prepared.phases, windows=runs, frame_status=status, coverage=coverage,
                      time_s=time.perf_counter() - t0)


