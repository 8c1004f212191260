"""Compliance estimation against MuJoCo ground truth: simulate a planar finger with joint springs 1/c pressing a
plane (torchhand.interaction.mujoco_truth), estimate the compliance from the noisy capture and print, per joint,
the truth, the median estimate over the events, its error, valid/total events and the rejection reasons; the same
for the noise-free capture; and the quasi-static check theta - theta_r = C J^T f on the simulated data.

    python scripts/capture_mujoco_truth.py [--seed 0] [--presses 80] [--task exploring] [--method joint|slopes]
        [--out DIR]   # also keep capture.npz, planar_finger.xml and the estimate's outputs there
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def run(seed: int = 0, presses: int = 80, task: str = "exploring", method: str = "joint", out: Path | None = None):
    """Simulate, estimate both captures; returns (truth run, noisy result, noise-free result, residuals, seconds)."""
    from torchhand.hand.model import HandModel
    from torchhand.interaction import EstimateSettings, estimate_capture, joint_torques
    from torchhand.interaction.mujoco_truth import TruthSettings, equilibrium_residual, write_truth_capture

    folder = Path(out) if out is not None else Path(tempfile.mkdtemp(prefix="capture_truth_"))
    t0 = time.perf_counter()
    path, truth = write_truth_capture(folder, TruthSettings(task=task, presses=presses), np.random.default_rng(seed))
    t_sim = time.perf_counter() - t0
    hand = HandModel.from_mjcf(folder / truth.capture.hand)
    settings = EstimateSettings(method=method)
    t0 = time.perf_counter()
    noisy = estimate_capture(truth.capture, hand, settings)
    t_est = time.perf_counter() - t0
    clean = estimate_capture(truth.clean, hand, settings)
    residual = equilibrium_residual(truth, joint_torques(truth.clean, hand))
    return truth, noisy, clean, residual, {"simulate": t_sim, "estimate": t_est}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--presses", type=int, default=80)
    p.add_argument("--task", choices=["exploring", "scratching"], default="exploring")
    p.add_argument("--method", choices=["joint", "slopes"], default="joint")
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args(argv)
    from torchhand.interaction.pipeline import format_table

    truth, noisy, clean, residual, seconds = run(args.seed, args.presses, args.task, args.method, args.out)
    s = truth.capture
    print(f"MuJoCo planar finger, {args.task}, {args.presses} presses, seed {args.seed}: {s.num_frames} frames at "
          f"{s.fps:g} Hz, noise 0.2 deg and 0.01 N; method {args.method}")
    print(f"quasi-static check |theta - theta_r - C J^T f| / max |C J^T f| over loaded frames: median "
          f"{np.median(residual):.2%}, 90th percentile {np.percentile(residual, 90):.2%}, max {residual.max():.2%}")
    print(f"\nnoisy capture ({noisy.events.count} events; simulated in {seconds['simulate']:.1f} s, estimated in "
          f"{seconds['estimate']:.2f} s):")
    print(format_table(noisy))
    print(f"\nnoise-free capture ({clean.events.count} events):")
    print(format_table(clean))
    raw = clean.estimate.raw[:, 6:] / s.truth_compliance[6:] - 1
    print("noise-free, all events before rejection: median relative error per joint "
          + ", ".join(f"{n} {100 * v:+.2f} %" for n, v in zip(s.joint_names, np.nanmedian(raw, axis=0))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
