"""Manipulation speed (Liu 2009, Sec. 6: "5 frames per second on average" on a 2.8 GHz Core 2 Duo).

Input (the builder of tests/torchhand/test_grasp.py and test_manipulate.py): a `torchhand synthesize box-turn` result
of frames 0:8 (small search, seed 0), its solution's frame-6 grasp snapped onto the box, and the built-in box-turn
motion from frame 6 (the grasp's pose) to the end, a single right hand turning the box 75 degrees on the table.

Cases (median of --repeat runs, one torch thread unless --threads):
  manipulate   the whole loop (planning, added contacts, per-frame synthesis, force re-projection), frames/s, once
               per --derivatives mode of the synthesis' Gauss-Newton Jacobians (SynthSettings.derivatives:
               "analytic", or "finite" forward differences), the modes interleaved run by run so that a load
               change on a shared machine hits both alike; with two modes the table adds their ratio and the
               largest difference of the joint angles between the two motions
  plan-only    the planner alone on the rigid grasp (plan_motion), the same frames, frames/s: the reference the
               synthesis is measured against (the ratio is the cost of Sec. 5 per frame)
  per-frame    median and 90th percentile of one frame of `manipulate` (plan + synthesis), ms, and the loop's
               split per frame: planning (plan_s) and the rest (synthesis, force re-projection: synth_s), ms

    python scripts/bench_manipulation.py [--repeat 3] [--frames 6:66] [--json out.json] [--threads 1]
                                         [--derivatives analytic,finite] [--out DIR]

--out DIR writes the first analytic run's result directory (for `torchhand check DIR`).
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
from torchhand.manipulation import (
    ManipulationSettings,
    SynthSettings,
    grasp_from_result,
    make_grasp,
    manipulate,
    plan_motion,
    write_manipulation,
)
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
    ap.add_argument("--derivatives", default="analytic",
                    help="comma-separated SynthSettings.derivatives modes to time: analytic, finite")
    ap.add_argument("--out", type=Path, help="write the first analytic (else first) run's result directory here")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    a, b = (int(v) for v in args.frames.split(":"))
    modes = [m.strip() for m in args.derivatives.split(",") if m.strip()]
    settings = {m: ManipulationSettings(synth=SynthSettings(derivatives=m)) for m in modes}   # validates the names
    with tempfile.TemporaryDirectory() as tmp:
        grasp, scene = build_inputs(Path(tmp), (a, b))
    T = scene.T
    manipulate(scene.with_frames(0, 3), grasp)                     # warm-up: SDF grid, imports
    runs = {m: [] for m in modes}
    per_frame = {m: [] for m in modes}
    split = {m: [] for m in modes}
    motion, added = {}, 0
    for _ in range(args.repeat):
        for mode in modes:
            t0 = time.perf_counter()
            res = manipulate(scene, grasp, settings[mode])
            runs[mode].append(time.perf_counter() - t0)
            per_frame[mode] += res.timings["per_frame_s"]
            split[mode].append((res.timings["plan_s"] / T, res.timings["synth_s"] / T))
            added = res.num_added
            if mode not in motion:
                motion[mode] = np.asarray(res.q)
                if args.out is not None and mode == ("analytic" if "analytic" in modes else modes[0]):
                    write_manipulation(res, args.out)
                    print(f"wrote {args.out} ({mode} derivatives)")
    plans = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        plan_motion(scene, grasp)
        plans.append(time.perf_counter() - t0)
    p = statistics.median(plans)
    med = {mode: statistics.median(runs[mode]) for mode in modes}
    label = {mode: "manipulate" if len(modes) == 1 else f"manip-{mode[:6]}" for mode in modes}
    rows = [(label[mode], T, med[mode], T / med[mode], max(runs[mode]) - min(runs[mode])) for mode in modes]
    rows.append(("plan-only", T, p, T / p, max(plans) - min(plans)))
    print(f"box-turn frames {a}:{b} (T = {T}), one right hand, {torch.get_num_threads()} thread(s), "
          f"{added} contact(s) added")
    print(f"{'case':<14} {'frames':>6} {'median s':>9} {'frames/s':>9} {'spread s':>9}")
    for name, n, t, fps, spread in rows:
        print(f"{name:<14} {n:>6} {t:>9.2f} {fps:>9.1f} {spread:>9.2f}")
    out = {"frames": [a, b], "T": T, "threads": torch.get_num_threads(), "plan_only_s": plans, "added": added,
           "modes": {}}
    for mode in modes:
        pf = np.array(per_frame[mode]) * 1000
        sp = np.median(np.array(split[mode]), 0) * 1000
        print(f"per frame ({label[mode]}): median {np.median(pf):.0f} ms, 90th percentile {np.percentile(pf, 90):.0f} "
              f"ms (planning {sp[0]:.1f} ms, synthesis and re-projection {sp[1]:.1f} ms); the loop costs "
              f"{med[mode] / p:.1f}x the planning alone")
        out["modes"][mode] = {"manipulate_s": runs[mode], "frames_per_second": T / med[mode],
                              "per_frame_ms_median": float(np.median(pf)),
                              "per_frame_ms_p90": float(np.percentile(pf, 90)),
                              "plan_ms_per_frame": float(sp[0]), "synth_ms_per_frame": float(sp[1])}
    if len(modes) == 2:
        m0, m1 = modes
        dq = float(np.abs(motion[m0] - motion[m1]).max()) if motion[m0].shape == motion[m1].shape else float("nan")
        print(f"{m0} / {m1}: {med[m1] / med[m0]:.2f}x faster; largest joint-angle difference between the two "
              f"motions {dq:.2e} rad")
        out["speedup"] = med[m1] / med[m0]
        out["max_dq_rad"] = dq
    if len(modes) == 1:                                              # the keys of the single-mode report
        out.update(manipulate_s=runs[modes[0]], **{k: v for k, v in out["modes"][modes[0]].items()
                                                    if k != "manipulate_s"})
    if args.json:
        args.json.write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
