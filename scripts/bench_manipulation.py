"""Manipulation speed (Liu 2009, Sec. 6: "5 frames per second on average" on a 2.8 GHz Core 2 Duo).

Input (the builder of tests/torchhand/test_grasp.py and test_manipulate.py): a `torchhand synthesize box-turn` result
of frames 0:8 (small search, seed 0), its solution's frame-6 grasp snapped onto the box, and the built-in box-turn
motion from frame 6 (the grasp's pose) to the end, a single right hand turning the box 75 degrees on the table.

Cases (median of --repeat runs, one torch thread unless --threads):
  manipulate   the whole loop (planning, added contacts, per-frame synthesis, force re-projection), frames/s
  plan-only    the planner alone on the rigid grasp (plan_motion), the same frames, frames/s: the reference the
               synthesis is measured against (the ratio is the cost of Sec. 5 per frame)
  per-frame    median and 90th percentile of one frame of `manipulate` (plan + synthesis), ms

    python scripts/bench_manipulation.py [--repeat 3] [--frames 6:66] [--json out.json] [--threads 1]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from torchhand.cli import main as cli
from torchhand.manipulation import (ManipulationSettings, grasp_from_result, make_grasp, manipulate, plan_motion)
from torchhand.scene import load_scene

SYNTH = ["synthesize", "box-turn", "--frames", "0:8", "--trees", "4", "--candidates", "8", "--max-nodes", "2000",
         "--solutions", "1", "--seed", "0", "--no-progress", "--threads", "1"]
FRAME = 6


def build_inputs(work: Path, frames: tuple[int, int]):
    """(grasp, scene): the test fixtures' grasp and the box-turn frames A:B (A: a frame with the grasp's box pose)."""
    out = work / "bt"
    if cli(SYNTH + ["--out", str(out)]) != 0:
        raise SystemExit("the synthesize run that makes the grasp failed")
    g, base = grasp_from_result(out, solution=0, frame=FRAME)
    grasp, _ = make_grasp(g, base)
    scene = load_scene("box-turn").with_frames(*frames)
    if not np.allclose(scene.object_pose[0].numpy(), base.object_pose[FRAME].numpy(), atol=1e-9):
        raise SystemExit(f"--frames {frames[0]}:{frames[1]}: the box at frame {frames[0]} is not where the grasp holds it")
    return grasp, dataclasses.replace(scene, object=base.object)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--frames", default="6:66", metavar="A:B", help="box-turn frames (default 6:66)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    a, b = (int(v) for v in args.frames.split(":"))
    with tempfile.TemporaryDirectory() as tmp:
        grasp, scene = build_inputs(Path(tmp), (a, b))
    T = scene.T
    manipulate(scene.with_frames(0, 3), grasp)                     # warm-up: SDF grid, imports
    runs, per_frame, added = [], [], 0
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        res = manipulate(scene, grasp, ManipulationSettings())
        runs.append(time.perf_counter() - t0)
        per_frame += res.timings["per_frame_s"]
        added = res.num_added
    plans = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        plan_motion(scene, grasp)
        plans.append(time.perf_counter() - t0)
    m, p = statistics.median(runs), statistics.median(plans)
    pf = np.array(per_frame) * 1000
    rows = [("manipulate", T, m, T / m, max(runs) - min(runs)), ("plan-only", T, p, T / p, max(plans) - min(plans))]
    print(f"box-turn frames {a}:{b} (T = {T}), one right hand, {torch.get_num_threads()} thread(s), "
          f"{added} contact(s) added")
    print(f"{'case':<12} {'frames':>6} {'median s':>9} {'frames/s':>9} {'spread s':>9}")
    for name, n, t, fps, spread in rows:
        print(f"{name:<12} {n:>6} {t:>9.2f} {fps:>9.1f} {spread:>9.2f}")
    print(f"per frame (manipulate): median {np.median(pf):.0f} ms, 90th percentile {np.percentile(pf, 90):.0f} ms; "
          f"synthesis costs {m / p:.1f}x the planning alone")
    if args.json:
        args.json.write_text(json.dumps({"frames": [a, b], "T": T, "threads": torch.get_num_threads(),
                                         "manipulate_s": runs, "plan_only_s": plans,
                                         "frames_per_second": T / m, "per_frame_ms_median": float(np.median(pf)),
                                         "per_frame_ms_p90": float(np.percentile(pf, 90)), "added": added},
                                        indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
