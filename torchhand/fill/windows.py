"""The window plan of ``torchhand fill``: which frames each independent synthesis run covers.

A pure function of the phases (:mod:`torchhand.fill.phases`), the number of frames and three integers: no scene,
no randomness beyond the seeds it derives. A future batched engine can run the planned windows side by side.

Rules (docs/fill.md, "Windows"):

* A **segment** is a maximal run of consecutive phases that are not ``"free"`` (approach, contact, release) and
  holds at least one ``"contact"`` phase: the contact with its approach and release margins. A run of non-free
  phases without a contact phase (a hand that approaches and leaves without touching) is treated as free.
* A segment of L frames is covered by ``n = 1`` window when ``L <= window``, else by
  ``n = ceil((L - overlap) / (window - overlap))`` windows of nearly equal length (they differ by at most one
  frame, none longer than ``window``), each overlapping the next by exactly ``overlap`` frames. With
  ``window >= 3 overlap`` every window is at least ``2 overlap`` long, so a frame lies in at most two windows and
  the crossfades of :mod:`torchhand.fill.stitch` are pairwise.
* Each window's seed is derived from the main seed and the window's index
  (``numpy.random.SeedSequence([seed, index])``, 31 bits): deterministic, independent of the other windows, and far
  apart, so the search's per-tree generators (``seed + tree``) of two windows do not coincide.

Conventions: frame ranges are ``[start, stop)`` of the whole scene.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputValueError

__all__ = ["Window", "plan_windows", "segments", "window_seed"]


@dataclass(frozen=True)
class Window:
    """One independent synthesis run.

    index: position in the plan (0, 1, ...); start, stop: frames ``[start, stop)`` of the scene; phase: index into
    the phases of the segment's first contact phase; segment: index of the segment (windows of one segment overlap
    their neighbours); seed: the run's seed (:func:`window_seed`)
    """

    index: int
    start: int
    stop: int
    phase: int
    segment: int
    seed: int

    @property
    def frames(self) -> int:
        return self.stop - self.start

    def to_json(self) -> dict:
        return {"index": self.index, "start": self.start, "stop": self.stop, "phase": self.phase,
                "segment": self.segment, "seed": self.seed}


def window_seed(seed: int, index: int) -> int:
    """The seed of window ``index`` under the main ``seed``: a 31-bit integer from ``SeedSequence([seed, index])``."""
    state = np.random.SeedSequence([int(seed) & 0xFFFFFFFF, int(index)]).generate_state(1, dtype=np.uint32)
    return int(state[0]) >> 1


def segments(phases, T: int) -> tuple[tuple[int, int, int], ...]:
    """The segments (module docstring) as ``(start, stop, first contact phase index)``, in frame order.

    phases: contiguous :class:`~torchhand.fill.phases.Phase` objects covering ``[0, T)`` (anything with ``kind``,
    ``start``, ``stop``). Raises InputValueError when they do not cover ``[0, T)`` contiguously or a kind is unknown.
    """
    _check_phases(phases, T)
    out, run = [], []
    for i, p in enumerate(list(phases) + [None]):
        if p is not None and p.kind != "free":
            run.append(i)
            continue
        contact = [j for j in run if phases[j].kind == "contact"]
        if contact:
            out.append((phases[run[0]].start, phases[run[-1]].stop, contact[0]))
        run = []
    return tuple(out)


def plan_windows(phases, T: int, *, window: int, overlap: int, seed: int = 0) -> tuple[Window, ...]:
    """The windows of every segment (module docstring), in frame order.

    phases: contiguous phases covering ``[0, T)``; T: frames of the scene; window: the longest window, frames
    (>= 3 overlap); overlap: frames shared by consecutive windows of a segment (>= 2); seed: the main seed.
    Raises InputValueError for bad numbers or phases.
    """
    for name, v in (("T", T), ("window", window), ("overlap", overlap), ("seed", seed)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
            raise InputValueError(f"{name}: expected an integer, got {v!r}")
    if overlap < 2:
        raise InputValueError(f"overlap: expected at least 2 frames (a crossfade), got {overlap}")
    if window < 3 * overlap:
        raise InputValueError(f"window: expected at least 3 x overlap = {3 * overlap} frames (so that a frame lies "
                              f"in at most two windows), got {window}")
    out: list[Window] = []
    for s, (a, b, phase) in enumerate(segments(phases, T)):
        for start, stop in _split(a, b, window, overlap):
            out.append(Window(len(out), start, stop, phase, s, window_seed(seed, len(out))))
    return tuple(out)


def _split(a: int, b: int, window: int, overlap: int) -> list[tuple[int, int]]:
    """``[a, b)`` as windows of nearly equal length overlapping by exactly ``overlap`` (module docstring)."""
    L = b - a
    if L <= window:
        return [(a, b)]
    n = math.ceil((L - overlap) / (window - overlap))
    step = L - overlap                  # the windows' lengths minus the overlap add up to this
    bounds = [a + (k * step) // n for k in range(n + 1)]        # window k: [bounds[k], bounds[k+1] + overlap)
    return [(bounds[k], bounds[k + 1] + overlap) for k in range(n)]


def _check_phases(phases, T: int) -> None:
    from_ = 0
    for i, p in enumerate(phases):
        if p.kind not in ("free", "approach", "contact", "release"):
            raise InputValueError(f"phases[{i}]: unknown kind {p.kind!r}; expected free, approach, contact or release")
        if p.start != from_ or p.stop <= p.start:
            raise InputValueError(f"phases[{i}]: expected frames starting at {from_} and not empty, got "
                                  f"[{p.start}, {p.stop})")
        from_ = p.stop
    if from_ != T:
        raise InputValueError(f"phases: expected them to cover frames [0, {T}), they end at {from_}")
