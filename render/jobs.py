"""The ``torchhand render`` and ``torchhand plot`` jobs as library functions over a result directory or BVH files.

:func:`result_clips` turns chosen solutions (and an optional reference motion) into labelled clips;
:func:`render_result` writes them as a video; :func:`render_bvh` draws BVH skeletons side by side on one timeline;
:func:`plot_result` writes the PNG plots. The CLI modules only parse arguments and call these.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from torchhand.errors import InputValueError, MissingFileError
from torchhand.io.result import Result, Solution, load_result, load_solution, parse_solution_spec

from .clip import Clip, clip_from_solution
from .compose import RenderOptions, write_video
from .contact_analysis import finger_contacts, solution_summary

__all__ = ["parse_size", "parse_frames", "stats_line", "solution_title", "result_clips", "render_result",
           "plot_result", "open_result", "is_bvh", "per_file", "render_bvh"]


def parse_size(text: str) -> tuple[int, int]:
    """``"640x480"`` -> (640, 480); both between 16 and 8192 pixels."""
    try:
        w, h = (int(v) for v in str(text).lower().split("x"))
    except ValueError:
        raise InputValueError(f"--size: expected WIDTHxHEIGHT like 640x480, got {text!r}") from None
    if not (16 <= w <= 8192 and 16 <= h <= 8192):
        raise InputValueError(f"--size: width and height must be in [16, 8192] pixels, got {w}x{h}")
    return w, h


def parse_frames(text: str | None, T: int) -> tuple[int, int]:
    """``"A:B"`` (Python slice, either end may be empty) -> (start, stop) within ``T`` frames."""
    if text is None:
        return 0, T
    try:
        a, b = str(text).split(":")
        start, stop = int(a) if a.strip() else 0, int(b) if b.strip() else T
    except ValueError:
        raise InputValueError(f"--frames: expected A:B like 0:30, got {text!r}") from None
    if not 0 <= start < stop <= T:
        raise InputValueError(f"--frames: expected 0 <= A < B <= {T} (the clip has {T} frames), got {text!r}")
    return start, stop


def stats_line(stats: dict) -> str:
    """Key search statistics from ``stats.json`` on one line ('' when there are none)."""
    parts = []
    if "solutions" in stats:
        parts.append(f"{stats['solutions']} solutions")
    if "dead_ends" in stats:
        parts.append(f"{stats['dead_ends']} dead ends")
    if "time_s" in stats:
        try:
            parts.append(f"{float(stats['time_s']):.1f} s search")
        except (TypeError, ValueError):
            pass
    if "epsilon" in stats:
        parts.append(f"eps {stats['epsilon']}")
    return ", ".join(parts)


def solution_title(i: int, sol: Solution) -> str:
    """``"solution 2: sliding"``, with ``", unsmoothed"`` when ``q`` is not the smoothed motion."""
    return f"solution {i}" + (f": {sol.strategy}" if sol.strategy else "") + \
        ("" if sol.reconstructed else ", unsmoothed")


def open_result(path) -> tuple[Result | None, list]:
    """A result directory, or a lone solution npz (drawn as hands alone): (result or None, solution files)."""
    p = Path(path)
    if p.is_file() and p.suffix == ".npz":
        return None, [p]
    if not p.exists():
        raise MissingFileError(f"result directory {p} does not exist (expected the output of `torchhand "
                               f"synthesize` or a solution .npz)")
    result = load_result(p)
    return result, list(result.solution_files)


def _solution(result: Result | None, files: list, i: int) -> Solution:
    return result.solution(i) if result is not None else load_solution(files[i])


def _lone_solution_clip(sol: Solution, labels) -> Clip:
    from torchhand.hand import default_hand

    from .clip import HandTrackLinks, hand_link_poses

    hands = []
    for h in sol.hands:
        model = default_hand(h.side if h.side in ("right", "left") else "right")
        hands.append(HandTrackLinks(model, hand_link_poses(model, h.q, h.root_pose, h.joint_names)))
    return Clip(hands=tuple(hands), fps=sol.fps, contact_mask=sol.contact_mask, contact_point=sol.contact_point,
                contact_force=sol.contact_force, env_contact_mask=sol.env_contact_mask,
                env_contact_point=sol.env_contact_point, env_contact_force=sol.env_contact_force,
                labels=tuple(labels))


def result_clips(path, solutions: str | None = None, *, compare=None, labels: bool = True) -> list[Clip]:
    """Labelled clips for ``solutions`` ("0,1,2", "all", None = first) of the result at ``path``; with ``compare``
    (another result directory, whose first solution is used, or a solution npz) the reference comes first."""
    result, files = open_result(path)
    indices = parse_solution_spec(solutions, len(files))
    stats = stats_line(result.stats) if result is not None else ""
    clips = []
    if compare is not None:
        clips.append(_reference_clip(compare, result))
    for i in indices:
        sol = _solution(result, files, i)
        text = [solution_title(i, sol), solution_summary(sol), stats]
        if compare is not None:
            text[0] = f"synthesized, {text[0]}"
        text = [t for t in text if t] if labels else []
        clips.append(clip_from_solution(result, sol, labels=text) if result is not None
                     else _lone_solution_clip(sol, text))
    return clips


def _reference_clip(reference, result: Result | None) -> Clip:
    ref = Path(reference)
    if ref.is_dir():
        ref_result, files = open_result(ref)
        if not files:
            raise InputValueError(f"--compare {ref}: the result directory has no solutions")
        sol, where = ref_result.solution(0), ref_result
    else:
        sol, where = load_solution(ref), result  # an npz reference is drawn in the result's scene
    label = [f"reference: {ref.name}" + ("" if sol.reconstructed else ", unsmoothed"), solution_summary(sol)]
    return clip_from_solution(where, sol, labels=label) if where is not None else _lone_solution_clip(sol, label)


def render_result(path, out, *, solutions: str | None = None, grid: bool = False, size=(640, 480),
                  fps: float | None = None, fmt: str | None = None, frames: str | None = None, orbit: bool = False,
                  compare=None, shadows: bool = True, progress: bool | None = None) -> dict:
    """Render a result directory to ``out`` (see ``torchhand render --help``). Returns a summary dict with the
    output path, frame count, frame size and format.

    progress: True / False / None (= a bar only on a terminal).
    """
    from tqdm import tqdm

    from .video import check_writer, infer_format

    fmt = infer_format(out, fmt)
    check_writer(fmt)  # fail before the slow part
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise InputValueError(f"--fps: expected a positive number, got {fps}")
    if grid and solutions is None:
        solutions = "all"
    clips = result_clips(path, solutions, compare=compare, labels=grid or compare is not None
                         or (solutions is not None and solutions != "0"))
    T = max(c.T for c in clips)
    start, stop = parse_frames(frames, T)
    clips = [c.frames(min(start, c.T - 1), min(stop, c.T)) for c in clips]
    n = max(c.T for c in clips)
    opts = RenderOptions(width=size[0], height=size[1], orbit=orbit, shadows=shadows,
                         max_cols=None if grid or len(clips) <= 3 else 3)
    bar = tqdm(total=n, desc="render", unit="frame", disable=(not progress) if progress is not None else None)
    try:
        written = write_video(clips, out, fmt, opts, fps=fps, progress=bar)
    finally:
        bar.close()
    from .overlay import grid_shape

    rows, cols = grid_shape(len(clips), opts.max_cols)
    w, h = cols * size[0] + 2 * (cols - 1), rows * size[1] + 2 * (rows - 1)
    if fmt == "mp4":  # H.264 in yuv420p: even sizes
        w, h = w - w % 2, h - h % 2
    return {"out": str(written), "frames": n, "format": fmt, "panels": len(clips), "size": (w, h)}


def is_bvh(path) -> bool:
    """Whether ``path`` names a BVH file (by its suffix, any case)."""
    return Path(path).suffix.lower() == ".bvh"


def per_file(value: str | None, n: int, option: str, default: str = "auto") -> list[str]:
    """``value`` for each of ``n`` files: None gives ``default``, ``"cm"`` the same for all, ``"cm,mm"`` one per
    file in panel order."""
    if value is None:
        return [default] * n
    parts = [v.strip() for v in str(value).split(",")]
    if len(parts) == 1:
        return parts * n
    if len(parts) != n:
        raise InputValueError(f"{option}: expected one value or one per BVH file ({n}), got {len(parts)}: {value!r}")
    return parts


def render_bvh(paths, out, *, compare=(), size=(640, 480), fps: float | None = None, fmt: str | None = None,
               frames: str | None = None, orbit: bool = False, shadows: bool = True, units: str | None = None,
               up: str | None = None, handedness: str | None = None, follow: str | None = None,
               close_up: bool = True, progress: bool | None = None) -> dict:
    """Draw BVH files side by side on one timeline (see ``torchhand render --help`` and docs/render.md).

    paths: the BVH files drawn first; compare: BVH files drawn to their right (a hand capture beside the body it
    was spliced into, say). units / up / handedness: one value for all files or comma-separated, one per file in
    panel order (None: "auto", "auto", "right"). frames: "A:B", frames of the first file's clock. fps: output rate
    (default the first file's). Returns a summary dict (output path, frame count, size, format, panels).
    """
    from tqdm import tqdm

    from .bvh_clip import skeleton_from_bvh
    from .overlay import grid_shape
    from .skeleton_view import render_skeleton_frames, skeleton_panels, timeline, timeline_length
    from .video import FrameWriter, check_writer, infer_format

    files = [Path(p) for p in (*paths, *(compare or ()))]
    if not files:
        raise InputValueError("render_bvh: no BVH files given")
    fmt = infer_format(out, fmt)
    check_writer(fmt)  # fail before the slow part
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise InputValueError(f"--fps: expected a positive number, got {fps}")
    n = len(files)
    skeletons = [skeleton_from_bvh(f, units=u, up=a, handedness=h) for f, u, a, h in
                 zip(files, per_file(units, n, "--bvh-units"), per_file(up, n, "--bvh-up"),
                     per_file(handedness, n, "--bvh-handedness", "right"))]
    start, stop = parse_frames(frames, timeline_length(skeletons))
    fps, times = timeline(skeletons, start, stop, fps)
    opts = RenderOptions(width=size[0], height=size[1], orbit=orbit, shadows=shadows)
    panels = skeleton_panels(skeletons, times, fps, opts, follow=follow, close_up=close_up)
    bar = tqdm(total=len(times), desc="render", unit="frame", disable=(not progress) if progress is not None else None)
    try:
        with FrameWriter(out, fmt, fps, frames=len(times)) as writer:
            for frame in render_skeleton_frames(panels, opts, progress=bar):
                writer.write(frame)
    finally:
        bar.close()
    rows, cols = grid_shape(len(panels), opts.max_cols)
    w, h = cols * size[0] + 2 * (cols - 1), rows * size[1] + 2 * (rows - 1)
    if fmt == "mp4":  # H.264 in yuv420p: even sizes
        w, h = w - w % 2, h - h % 2
    return {"out": str(writer.out), "frames": len(times), "format": fmt, "panels": len(panels), "size": (w, h)}


def plot_result(path, out_dir, *, solution: int = 0, solutions: str | None = "all",
                max_series: int = 8) -> list[Path]:
    """Write contact_timeline.png, forces.png and joints.png for the result at ``path`` into ``out_dir``.

    solution: the solution whose contacts and forces are plotted; solutions: those overlaid in joints.png (at most
    ``max_series``). Sliding is the solution's stored ``contact_sliding``.
    Titles and legend entries of a solution written unsmoothed say "unsmoothed".
    """
    from .plots import plot_contact_timeline, plot_forces, plot_joints

    result, files = open_result(path)
    index = parse_solution_spec(str(solution), len(files))[0]
    sol = _solution(result, files, index)
    if result is None:
        from torchhand.hand import default_hand

        models = {h.side: default_hand(h.side) for h in sol.hands}
    else:
        models = result.hand_models
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputValueError(f"--out {out}: expected a directory, got a file")
    out.mkdir(parents=True, exist_ok=True)
    name = Path(path).name
    written = []
    fc = finger_contacts(sol, models, friction=sol.friction if sol.friction is not None else
                         (result.scene.friction if result is not None else None))
    tag = f"{name}, {solution_title(index, sol)}"
    written.append(plot_contact_timeline(fc, out / "contact_timeline.png", f"contact state per finger: {tag}"))
    written.append(plot_forces(fc, out / "forces.png", f"contact forces per finger: {tag}"))
    chosen = parse_solution_spec(solutions, len(files))[:max_series]
    loaded = [(i, _solution(result, files, i)) for i in chosen]
    for h in sol.hands:
        series = []
        for i, s in loaded:
            hs = s.hand(h.side)
            notes = ([s.strategy] if s.strategy else []) + ([] if s.reconstructed else ["unsmoothed"])
            series.append((f"solution {i}" + (f" ({', '.join(notes)})" if notes else ""), hs.q, hs.joint_names))
        suffix = "" if len(sol.hands) == 1 else f"_{h.side}"
        unsmoothed = [i for i, s in loaded if not s.reconstructed]
        note = f" (unsmoothed: solution {', '.join(map(str, unsmoothed))})" if unsmoothed else ""
        written.append(plot_joints(series, models[h.side], sol.fps, out / f"joints{suffix}.png",
                                   f"flexion joints per finger ({h.side} hand): {name}{note}"))
    return written
