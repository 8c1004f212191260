"""A picture of a fill: phases, windows and their pieces, and each motion's frame status over the capture's frames.

``timeline.png`` in the result directory (written by ``torchhand fill``); :func:`plot_timeline` draws it from the
``phases.json`` document and the ``frame_status`` of the written motions, so it can be redrawn from a result alone
(``python -m torchhand.fill.timeline RESULT_DIR``).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from .reference import save_png

__all__ = ["plot_timeline", "PHASE_COLOURS", "STATUS_COLOURS"]

PHASE_COLOURS = {"free": "#c8c8c8", "approach": "#9ecae1", "contact": "#fd8d3c", "release": "#a1d99b"}
STATUS_COLOURS = {0: "#2ca25f", 1: "#bdbdbd", 2: "#de2d26"}      # solved, free hand, unsolved


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, length) of the runs of True in ``mask`` (T,)."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return [(int(a), int(b - a)) for a, b in zip(np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0])]


def plot_timeline(doc: dict, frame_status: np.ndarray, path, *, title: str = "") -> Path:
    """A PNG at ``path`` (written atomically). doc: the ``phases.json`` document; frame_status: (V, T) int8 codes
    (0 solved, 1 free hand, 2 unsolved). Rows from the top: the phases of each hand; the windows (alternate lanes),
    each with its pieces (dark: solved by a search, light: a search's deepest path) and a tick where each of its
    searches started; one row per motion, coloured by frame status."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    status = np.atleast_2d(np.asarray(frame_status))
    V, T = status.shape
    sides = list(doc.get("phases", {}))
    rows = len(sides) + 2 + V
    fig = Figure(figsize=(12, 1.6 + 0.45 * rows))
    ax = fig.subplots()
    labels, y = [], rows - 1
    for side in sides:
        for p in doc["phases"][side]:
            ax.broken_barh([(p["start"], p["stop"] - p["start"])], (y - 0.35, 0.7),
                           color=PHASE_COLOURS.get(p["kind"], "#ffffff"))
        labels.append((y, f"{side} phases"))
        y -= 1
    for i, w in enumerate(doc.get("windows", [])):
        lane = y - 0.5 * (i % 2)
        ax.broken_barh([(w["start"], w["stop"] - w["start"])], (lane - 0.2, 0.4), facecolor="none",
                       edgecolor="#555555", lw=0.8)
        for p in w.get("pieces", []):
            ax.broken_barh([(p["start"], p["stop"] - p["start"])], (lane - 0.2, 0.4),
                           color="#3182bd" if p["kind"] == "solved" else "#9e9ac8")
        for s in w.get("searches", []):
            ax.plot([s["start"]] * 2, [lane - 0.25, lane + 0.25], color="black", lw=0.8)
    labels.append((y - 0.25, "windows, pieces"))
    y -= 2
    for v in range(V):
        for code, colour in STATUS_COLOURS.items():
            ax.broken_barh(_runs(status[v] == code), (y - 0.35, 0.7), color=colour)
        labels.append((y, f"motion {v}"))
        y -= 1
    ax.set_yticks([a for a, _ in labels], [b for _, b in labels], fontsize=8)
    ax.set_xlim(0, T)
    ax.set_ylim(y + 0.4, rows - 0.4)
    ax.set_xlabel(f"frame (at {doc.get('fps', 0):g} fps)")
    handles = [Patch(color=c, label=k) for k, c in PHASE_COLOURS.items()]
    handles += [Patch(color="#3182bd", label="piece: solved"), Patch(color="#9e9ac8", label="piece: partial path")]
    handles += [Patch(color=STATUS_COLOURS[k], label=n) for k, n in ((0, "solved"), (1, "free hand"),
                                                                     (2, "unsolved"))]
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.35 if rows < 8 else -0.15), ncol=9,
              fontsize=7, frameon=False)
    cov = doc.get("coverage")
    fig.suptitle((title + "  " if title else "") + (f"contact-phase frames solved {100 * cov:.1f} %"
                                                    if cov is not None else ""), fontsize=10)
    return save_png(fig, path)


def main(argv=None) -> int:
    """Redraw ``timeline.png`` of a fill result: ``python -m torchhand.fill.timeline RESULT_DIR [OUT.png]``."""
    args = sys.argv[1:] if argv is None else argv
    if not args:
        print("usage: python -m torchhand.fill.timeline RESULT_DIR [OUT.png]", file=sys.stderr)
        return 2
    out = Path(args[0])
    doc = json.loads((out / "phases.json").read_text())
    status = []
    for f in sorted((out / "solutions").glob("sol_*.npz")):
        with np.load(f) as z:
            status.append(z["frame_status"])
    path = plot_timeline(doc, np.stack(status), args[1] if len(args) > 1 else out / "timeline.png")
    print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
