"""The viewer's panel: which solutions to show, what to draw, and the timeline with the checker's verdicts.

Controls (viser GUI elements, by label):

- ``solution``: a dropdown, ``all`` or one ``sol_XXX`` (with its checker verdict, ``pass`` / ``FAIL``);
- ``contacts``, ``forces``: checkboxes;
- ``frame``: a slider over the frames 0..T-1 (scrub); ``play`` / ``pause``: a button; ``fps``: the playback rate,
  the result's frame rate at first;
- a verdict line (markdown): the frame, its time, and per shown solution the checker's verdict of that frame
  (:mod:`.verdict`: pass, or the failing figures with their values);
- a strip (HTML): one cell per frame and shown solution, green where the frame passes, red where it fails, the
  current frame outlined.

:class:`Timeline` is the panel's state (current frame, playing or not); the playback thread advances the slider at
``fps`` while playing. Every change of a control redraws the frame through :func:`.scene.show_frame`.
"""

from __future__ import annotations

import threading
import time

from .frames import ViewData
from .scene import SceneNodes, show_frame

__all__ = ["Timeline", "ALL", "strip_html"]

ALL = "all"
"""The dropdown's value that shows every solution."""


class Timeline:
    """The panel of one viewer server and its playback thread.

    server: the viser server; data: what is drawn; nodes: :func:`.scene.build_scene`'s nodes; verdicts: the
    :class:`.verdict.FrameVerdicts` of every solution (in ``data.solutions`` order), or None (no check run);
    solution: the solution index to show first, or None for all.
    """

    def __init__(self, server, data: ViewData, nodes: SceneNodes, verdicts, solution: int | None):
        self.server, self.data, self.nodes = server, data, nodes
        self.verdicts = {v.index: v for v in verdicts} if verdicts is not None else None
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self.playing = False
        self.redraws = 0
        gui = server.gui
        labels = [ALL] + [self._label(s.index, s.name) for s in data.solutions]
        first = ALL if solution is None else self._label(solution, data.solution(solution).name)
        self.choice = gui.add_dropdown("solution", tuple(labels), initial_value=first)
        self.contacts = gui.add_checkbox("contacts", True)
        self.forces = gui.add_checkbox("forces", True)
        self.slider = gui.add_slider("frame", 0, max(data.frames - 1, 0), 1, 0)
        self.play = gui.add_button("play")
        self.fps = gui.add_number("fps", float(data.fps), min=0.1, max=480.0, step=0.1)
        self.verdict = gui.add_markdown(self._verdict_text(0))
        self.strip = gui.add_html(strip_html(self.data, self.verdicts, self.shown(), 0))
        for handle in (self.choice, self.contacts, self.forces, self.slider):
            handle.on_update(lambda _event: self.redraw())
        self.play.on_click(lambda _event: self.toggle())
        self._thread = threading.Thread(target=self._run, name="torchhand-view-playback", daemon=True)
        self._thread.start()
        self.redraw()

    def shown(self) -> list[int]:
        """The solution indices the dropdown selects."""
        value = self.choice.value
        if value == ALL:
            return [s.index for s in self.data.solutions]
        return [int(value.split()[0].removeprefix("sol_"))]

    @property
    def frame(self) -> int:
        return int(self.slider.value)

    def set_frame(self, t: int) -> None:
        """Show frame ``t`` (0 <= t < T): moves the slider, which redraws."""
        self.slider.value = int(t)

    def set_solution(self, index: int | None) -> None:
        """Show solution ``index`` only, or every solution for None."""
        self.choice.value = ALL if index is None else self._label(index, self.data.solution(index).name)

    def toggle(self) -> None:
        """Play or pause."""
        with self._lock:
            self.playing = not self.playing
            self.play.label = "pause" if self.playing else "play"

    def redraw(self) -> None:
        """Draw the current frame with the current choices."""
        with self._lock:
            t = min(max(self.frame, 0), self.data.frames - 1)
            shown = self.shown()
            show_frame(self.server, self.data, self.nodes, t, shown=shown, contacts=bool(self.contacts.value),
                       forces=bool(self.forces.value))
            self.verdict.content = self._verdict_text(t)
            self.strip.content = strip_html(self.data, self.verdicts, shown, t)
            self.redraws += 1
        self.server.flush()

    def close(self) -> None:
        """Stop the playback thread."""
        self._stop.set()
        self._thread.join(timeout=2.0)

    def _run(self) -> None:
        while not self._stop.is_set():
            if not self.playing:
                time.sleep(0.05)
                continue
            fps = max(float(self.fps.value), 0.1)
            self.set_frame((self.frame + 1) % self.data.frames)
            time.sleep(1.0 / fps)

    def _label(self, index: int, name: str) -> str:
        if self.verdicts is None or index not in self.verdicts:
            return name
        return f"{name} ({'pass' if self.verdicts[index].passed else 'FAIL'})"

    def _verdict_text(self, t: int) -> str:
        lines = [f"**frame {t} / {self.data.frames - 1}** (t = {t / self.data.fps:.3f} s)"]
        if self.verdicts is None:
            return lines[0] + "  \nno check run"
        for i in self.shown():
            v = self.verdicts.get(i)
            if v is not None:
                lines.append(f"sol_{i:03d}: {v.describe(t)}")
        return "  \n".join(lines)


def strip_html(data: ViewData, verdicts: dict | None, shown, t: int) -> str:
    """The per-frame pass/fail strip: one row per shown solution, one cell per frame (green pass, red fail, grey
    unchecked), the current frame outlined."""
    rows = []
    for i in shown:
        v = None if verdicts is None else verdicts.get(i)
        cells = []
        for k in range(data.frames):
            colour = "#bbb" if v is None else ("#3a3" if v.frame_ok[k] else "#d33")
            edge = "outline:2px solid #000;" if k == t else ""
            cells.append(f'<span style="flex:1;height:10px;background:{colour};{edge}"></span>')
        rows.append(f'<div style="display:flex;align-items:center;gap:1px;margin:1px 0">'
                    f'<span style="font:10px monospace;width:52px">sol_{i:03d}</span>{"".join(cells)}</div>')
    return f'<div class="torchhand-strip" style="padding:0 8px">{"".join(rows)}</div>'
