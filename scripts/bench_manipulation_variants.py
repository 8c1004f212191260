"""Variants per second of the Liu 2009 loop: one grasp, one object motion, many external forces.

Liu 2009, Sec. 6 ("Withstand external forces"): "By varying the direction or the magnitude of the external forces
and torques, we can synthesize different responses of the hand from a single grasping pose." This script makes N
variants of the built-in scene ``liu-push`` (its packaged grasp, its lift and hold) whose push, PUSH_FORCE at the
centre of mass, points in N directions evenly spread in the horizontal plane (variant 0 is the scene's own +y push),
and times how many of them torchhand manipulates per second:

  sequential  the variants one after another in this process (``torchhand.manipulation.manipulate``), one thread
  batch       ``torchhand batch`` on a manifest of the N variant scene directories (each with the packaged grasp as
              its grasp.npz), ``--workers W`` processes of one thread each; every job's result is also checked by
              the independent checker (check.json), so this is the rate of checked results

Each case runs ``--repeat`` times (the batch into a new directory each time); the table gives the median seconds, the
variants and frames per second, and the outcomes (complete / grasp unsuitable, and for the batch how many results
passed the check). The variants are independent runs of the sequential per-frame loop: they are batched across
processes, not inside one solver call.

    python scripts/bench_manipulation_variants.py [--variants 8] [--workers 2] [--repeat 3] [--json out.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from torchhand.manipulation import manipulate
from torchhand.manipulation.grasp import load_grasp
from torchhand.manipulation.plan import GraspUnsuitable
from torchhand.scene._writer import export_scene_dir
from torchhand.scene.builtin import builtin_scene
from torchhand.scene.builtin.liu import grasp_path

SCENE = "liu-push"


def variants(n: int) -> list:
    """N copies of liu-push whose push is turned about z by 2 pi i / n (i = 0 .. n-1)."""
    base = builtin_scene(SCENE)
    w = base.external_wrench.double().numpy()
    out = []
    for i in range(n):
        a = 2.0 * math.pi * i / n
        R = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
        wi = w.copy()
        wi[:, :3] = w[:, :3] @ R.T
        wi[:, 3:] = w[:, 3:] @ R.T
        out.append(dataclasses.replace(base, name=f"{SCENE}-dir{i:02d}",
                                       external_wrench=torch.tensor(wi, dtype=torch.float64)))
    return out


def run_sequential(scenes, grasp) -> tuple[float, list]:
    t0 = time.perf_counter()
    outcomes = []
    for s in scenes:
        try:
            r = manipulate(s, grasp)
            outcomes.append(("complete", r.T))
        except GraspUnsuitable as e:
            outcomes.append(("unsuitable", 0 if e.partial is None else e.partial.T))
    return time.perf_counter() - t0, outcomes


def run_batch(manifest: Path, out: Path, workers: int) -> tuple[float, list, int]:
    t0 = time.perf_counter()
    rc = subprocess.run([sys.executable, "-m", "torchhand.cli", "batch", str(manifest), "--out", str(out),
                         "--workers", str(workers), "--threads", "1", "--no-progress"],
                        capture_output=True, text=True)
    dt = time.perf_counter() - t0
    if rc.returncode not in (0, 1):
        raise SystemExit(f"torchhand batch failed (exit {rc.returncode}): {rc.stderr.strip()[-400:]}")
    outcomes, passed = [], 0
    for job in sorted(p for p in (out / "jobs").iterdir() if (p / "stats.json").is_file()):
        stats = json.loads((job / "stats.json").read_text())
        outcomes.append(("complete" if stats.get("complete", True) else "unsuitable", int(stats.get("T", 0))))
        check = job / "check.json"
        if check.is_file() and json.loads(check.read_text()).get("passed"):
            passed += 1
    return dt, outcomes, passed


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--variants", type=int, default=8)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    scenes = variants(args.variants)
    gpath = grasp_path(SCENE)
    grasp = load_grasp(gpath)
    T = scenes[0].T
    rows, record = [], {"scene": SCENE, "variants": args.variants, "frames": T, "workers": args.workers}
    with tempfile.TemporaryDirectory(prefix="variants-") as tmp:
        tmp = Path(tmp)
        dirs = []
        for s in scenes:
            d = export_scene_dir(s, tmp / s.name)
            shutil.copyfile(gpath, d / "grasp.npz")
            dirs.append(d)
        manifest = tmp / "batch.toml"
        manifest.write_text('[[jobs]]\nmethod = "manipulate"\nscenes = [' +
                            ", ".join(f'"{d.name}"' for d in dirs) + "]\n")
        manipulate(scenes[0].with_frames(0, 3), grasp)                       # warm-up: SDF grid, imports
        seq, bat, outs_seq, outs_bat, passed = [], [], None, None, []
        for i in range(args.repeat):
            dt, outs_seq = run_sequential(scenes, grasp)
            seq.append(dt)
            dt, outs_bat, ok = run_batch(manifest, tmp / f"batch{i}", args.workers)
            bat.append(dt)
            passed.append(ok)
        for name, times, outs, extra in (("sequential", seq, outs_seq, ""),
                                         (f"batch x{args.workers}", bat, outs_bat, f", {min(passed)} checked ok")):
            med = statistics.median(times)
            done = sum(1 for o, _ in outs if o == "complete")
            frames = sum(n for _, n in outs)
            rows.append((name, med, args.variants / med, frames / med, max(times) - min(times),
                         f"{done} complete, {args.variants - done} unsuitable{extra}"))
            record[name] = {"seconds": times, "variants_per_second": args.variants / med,
                            "frames_per_second": frames / med, "complete": done}
    print(f"{SCENE}: {args.variants} push directions, {T} frames each, one thread per run")
    print(f"{'case':<12} {'median s':>9} {'variants/s':>11} {'frames/s':>9} {'spread s':>9}  outcomes")
    for name, med, vps, fps, spread, what in rows:
        print(f"{name:<12} {med:>9.2f} {vps:>11.3f} {fps:>9.1f} {spread:>9.2f}  {what}")
    if args.json:
        args.json.write_text(json.dumps(record, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
