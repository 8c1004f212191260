"""One window of ``torchhand fill`` searched in pieces: past a frame no path gets through, the window goes on.

A window is first searched whole. A search that stops at a wall (no path has reached the window's last frame and
the deepest frame reached has not advanced in ``stall_nodes`` node tests) or at the window's budget keeps its
deepest path as a **partial piece**: frames ``[start, start + d)`` as searched, each of which passed the node test.
A new search then starts at ``start + d - back`` (``back`` frames shared with the piece before, crossfaded by the
stitcher, at most :data:`BACK` and half the piece) with a fresh grasp, and so on, until a search reaches the
window's end (a **solved piece**: its solutions), the window's node budget is spent, or fewer than
:data:`MIN_FRAMES` frames are left. A search that dies where the one before it died (no frame gained) restarts
past the wall: 1, 2, 4, ... frames beyond it on consecutive failures there; the skipped frames stay unsolved.

Every search is bounded in node tests (the window's budget is shared by its pieces), so a seed gives the same
pieces on any machine. The frames of a piece are claimed only after the stitched motion passes the whole-motion
test frame by frame (:mod:`torchhand.fill.fill`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

__all__ = ["Piece", "Attempt", "search_pieces", "pieces_plan", "BACK", "MIN_FRAMES"]

BACK = 5          # frames a new search shares with the partial piece before it (crossfaded)
MIN_FRAMES = 4    # no search on fewer frames than this


@dataclass(frozen=True)
class Piece:
    """Frames ``[start, stop)`` of the scene with motions ``qs`` (each (stop - start, H, D) radians): a search's
    solutions (``kind`` "solved") or its deepest path (``kind`` "partial", one motion)."""

    start: int
    stop: int
    qs: tuple
    kind: str

    def to_json(self) -> dict:
        return {"start": self.start, "stop": self.stop, "kind": self.kind, "motions": len(self.qs)}


@dataclass(frozen=True)
class Attempt:
    """One search of a window: its first frame, node tests, how it stopped, the deepest frame it reached (scene
    frames) and its rejection counts."""

    start: int
    nodes: int
    stopped_by: str
    reached: int
    solutions: int
    rejections: dict

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


def search_pieces(scene, start: int, stop: int, *, budget: int, stall_nodes: int, search) -> tuple:
    """The pieces of frames ``[start, stop)`` of ``scene`` (module docstring) within ``budget`` node tests.
    search(sub_scene, max_nodes, stall_nodes) -> :class:`~torchhand.synthesis.pipeline.SynthesisResult` runs one
    search with the window's settings.
    Returns (pieces, attempts, the last result)."""
    plan = pieces_plan(scene, start, stop, budget=budget, stall_nodes=stall_nodes)
    try:
        request = next(plan)
        while True:
            request = plan.send(search(*request))
    except StopIteration as done:
        return done.value


def pieces_plan(scene, start: int, stop: int, *, budget: int, stall_nodes: int):
    """:func:`search_pieces` as a generator: yields each search as (sub_scene, max_nodes, stall_nodes), is sent its
    :class:`~torchhand.synthesis.pipeline.SynthesisResult`, returns (pieces, attempts, the last result). Whoever
    runs the searches (one at a time, or beside other windows' in one batch) gives the same pieces."""
    pieces: list[Piece] = []
    attempts: list[Attempt] = []
    c, left, covered, fails, res = start, budget, start, 0, None
    while left > 0 and stop - c >= MIN_FRAMES:
        res = yield scene.with_frames(c, stop), left, stall_nodes
        st = res.stats
        left -= st.nodes_tested
        d = st.deepest_frame
        attempts.append(Attempt(c, st.nodes_tested, st.stopped_by, c + d, len(res.finals), dict(st.rejections)))
        if res.finals:
            pieces.append(Piece(c, stop, tuple(f.q.detach().double().cpu() for f in res.finals), "solved"))
            break
        if res.partial is not None and c + d > covered:      # frames gained: keep them, start again just before
            pieces.append(Piece(c, c + d, (res.partial.q.detach().double().cpu(),), "partial"))
            covered, fails = c + d, 0
            if covered >= stop:
                break
            c = covered - min(BACK, d // 2)
        else:                                                # nothing gained: at the wall, then past it
            fails += 1
            c = covered + 2 ** (fails - 1) - 1
    return pieces, attempts, res
