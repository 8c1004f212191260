"""Ye & Liu 2012's demonstrations side by side: one rendered frame of each run beside the paper's figure number, and
the Table 1 columns of each run.

    python scripts/ye_liu_figures.py --results out/ye_liu --run --out docs/img/ye_liu_grid.png

Each demonstration is a frame of a ``torchhand synthesize`` run in ``RESULTS/NAME`` (``RUNS`` below gives the runs'
arguments, ``DEMOS`` the panels: the paper's figure, the run, the frame). With ``--run`` a missing run is synthesized
first (seed 0, ``--solutions``, ``--max-nodes``); runs already there are read as they are, so a grid can be redrawn
from results alone. Writes the grid (one frame of solution 0 per panel, ``torchhand render``) and beside it
``NAME.md`` / ``NAME.json`` with the Table 1 columns (ε, T, time, solutions, dead ends, total frames, success
frames, success ratio, solution ratio) of each run, read from its ``stats.json``. A run without a solution gets an
empty panel saying so; one whose mesh is absent (``../shared/data``) is left out with a line on stderr.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"

# the runs: name -> (torchhand synthesize arguments, the scene's name first; mesh needed)
RUNS = {
    "box-turn": (["box-turn"], None),
    "bunny": (["box-turn", "--object", "{bunny}", "--object-up", "y", "--object-scale", "0.4"], "bunny"),
    "mug": (["box-turn", "--object", "{mug}", "--object-up", "y", "--object-scale", "0.6"], "mug"),
    "handle-far": (["handle-lift"], None),
    "handle-near": (["handle-lift-palm"], None),
    "box-alternate": (["box-alternate"], None),
    "box-carry": (["box-carry"], None),
    "cup-spin": (["cup-spin", "--strategy", "gait", "--max-nodes", "60000"], None),
}
# the panels: the paper's figure, what it shows, the run, the frame drawn (of solution 0)
DEMOS = (
    ("Table 1", "box turned on the table", "box-turn", 40),
    ("Fig. 9", "box-turn's motion, a bunny", "bunny", 40),
    ("Fig. 9", "box-turn's motion, a mug", "mug", 40),
    ("Fig. 7", "handle far from the palm: fingertip grip", "handle-far", 35),
    ("Fig. 7", "handle near the palm: palm pushes", "handle-near", 35),
    ("Fig. 8", "box turned by the right hand ...", "box-alternate", 30),
    ("Fig. 8", "... then by the left hand", "box-alternate", 80),
    ("Fig. 1", "a big box carried off the table ...", "box-carry", 45),
    ("Fig. 1", "... past its edge, down to the floor", "box-carry", 108),
    ("§7", "finger gait: a cup spun, first push ...", "cup-spin", 40),
    ("§7", "... second push (--strategy gait)", "cup-spin", 100),
)
WHOLE_VIEW = {"box-carry"}
"""Runs drawn from a camera framed on the whole motion (the table's edge and the floor in view), not on the frame."""
MESHES = {"bunny": SHARED / "meshes" / "trimesh" / "bunny.ply",
          "mug": SHARED / "meshes" / "bigym_props" / "mug" / "assets" / "mug.obj"}
COLUMNS = ("epsilon", "T", "time_s", "solutions", "dead_ends", "total_frames", "success_frames", "success_ratio",
           "solution_ratio")


def synthesize_args(name: str) -> list[str] | None:
    """The run's ``torchhand synthesize`` arguments, its mesh path filled in; None if the mesh is absent."""
    args, mesh = RUNS[name]
    if mesh is not None and not MESHES[mesh].exists():
        return None
    return [a.format(**{k: str(v) for k, v in MESHES.items()}) for a in args]


def ensure_run(name: str, results: Path, run: bool, solutions: int, max_nodes: int) -> Path | None:
    """The run's result directory, synthesized first with ``run`` when missing; None if unavailable."""
    out = results / name
    if (out / "stats.json").exists():
        return out
    args = synthesize_args(name)
    if args is None:
        print(f"ye_liu_figures: {name}: mesh {MESHES[RUNS[name][1]]} not found, left out", file=sys.stderr)
        return None
    if not run:
        print(f"ye_liu_figures: {name}: no run in {out} (--run synthesizes it)", file=sys.stderr)
        return None
    cmd = ["torchhand", "synthesize", args[0], "--out", str(out), "--solutions", str(solutions), "--max-nodes",
           str(max_nodes), "--no-progress", *args[1:]]          # a run's own options (its node budget) win
    print("ye_liu_figures: " + " ".join(cmd), file=sys.stderr)
    subprocess.run(cmd, check=False)
    return out if (out / "stats.json").exists() else None


def table_row(out: Path) -> dict:
    """The Table 1 columns of a run, from its ``stats.json``."""
    stats = json.loads((out / "stats.json").read_text())
    return {c: stats.get(c) for c in COLUMNS}


def render_frame(out: Path, frame: int, size: str, whole: bool = False) -> np.ndarray | None:
    """Frame ``frame`` of solution 0 of a run (``torchhand render``), (H, W, 3) uint8; None without a solution.
    ``whole``: the camera framed on the whole motion (every frame rendered, one kept)."""
    import imageio.v3 as iio

    if not any((out / "solutions").glob("sol_*.npz")):
        return None
    with tempfile.TemporaryDirectory() as tmp:
        if whole:
            T = json.loads((out / "stats.json").read_text())["T"]
            subprocess.run(["torchhand", "render", str(out), "--out", tmp, "--format", "png", "--frames", f"0:{T}",
                            "--size", size, "--no-progress"], check=True, capture_output=True)
            return iio.imread(Path(tmp) / f"frame_{frame:05d}.png")
        png = Path(tmp) / "frame.png"
        subprocess.run(["torchhand", "render", str(out), "--out", str(png), "--frames", f"{frame}:{frame + 1}",
                        "--size", size, "--no-progress"], check=True, capture_output=True)
        return iio.imread(png)


def draw_grid(panels: list[tuple[str, np.ndarray | None]], path: Path, columns: int = 3) -> Path:
    """The panels in a grid, each titled; an empty panel for a run without a solution."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from torchhand.fill.reference import save_png

    rows = -(-len(panels) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(4.2 * columns, 3.4 * rows), squeeze=False)
    for ax in axes.flat:
        ax.axis("off")
    for ax, (title, image) in zip(axes.flat, panels):
        if image is None:
            ax.text(0.5, 0.5, "no solution", ha="center", va="center", fontsize=12, color="#b00")
        else:
            ax.imshow(image)
        ax.set_title(title, fontsize=9)
    return save_png(fig, path, dpi=110)


def markdown(rows: dict) -> str:
    head = "| run | figure | " + " | ".join(COLUMNS) + " |\n|" + "---|" * (len(COLUMNS) + 2) + "\n"
    return head + "".join(f"| {name} | {fig} | " + " | ".join(_fmt(r[c]) for c in COLUMNS) + " |\n"
                          for name, (fig, r) in rows.items())


def _fmt(v) -> str:
    if v is None:
        return "—"
    return f"{v:.1%}" if isinstance(v, float) and v < 1 else f"{v:.0f}" if isinstance(v, float) else str(v)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", type=Path, default=Path("out/ye_liu"))
    ap.add_argument("--out", type=Path, default=Path("out/ye_liu/grid.png"))
    ap.add_argument("--run", action="store_true", help="synthesize the runs that are missing")
    ap.add_argument("--solutions", type=int, default=3)
    ap.add_argument("--max-nodes", type=int, default=30000)
    ap.add_argument("--size", default="400x300")
    args = ap.parse_args(argv)
    panels, rows = [], {}
    for fig, what, name, frame in DEMOS:
        out = ensure_run(name, args.results, args.run, args.solutions, args.max_nodes)
        if out is None:
            continue
        rows[name] = (fig, table_row(out))
        panels.append((f"{fig}: {what}\n({name}, frame {frame}, solution 0)",
                       render_frame(out, frame, args.size, whole=name in WHOLE_VIEW)))
    if not panels:
        print("ye_liu_figures: no run to draw", file=sys.stderr)
        return 1
    args.out.parent.mkdir(parents=True, exist_ok=True)
    draw_grid(panels, args.out)
    args.out.with_suffix(".md").write_text(markdown(rows))
    args.out.with_suffix(".json").write_text(json.dumps({k: {"figure": f, **r} for k, (f, r) in rows.items()},
                                                        indent=1))
    print(f"wrote {args.out}, {args.out.with_suffix('.md')}, {args.out.with_suffix('.json')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
