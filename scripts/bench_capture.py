"""Time ``torchhand capture estimate``'s computation (no file output or plots) on a long capture of the default hand.

The capture: ``--seconds`` at ``--rate`` Hz of the default hand (D = 30, so 6 + D = 36 coordinates) with a slowly
moving root, joint angles that follow smooth sinusoids, and ``--sensors`` fingertip sensors, each tapping once
every 1-1.5 s (a 0.3 s force ramp), 0.2 degree and 0.01 N noise. Reports the median and spread of ``--repeats``
runs of :func:`torchhand.interaction.estimate_capture` and of its stages; ``--json FILE`` writes them.

    python scripts/bench_capture.py                      # 60 s, 500 Hz, 5 sensors: target < 2 s on 2 CPU cores
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time

import numpy as np
import torch


def build_capture(seconds: float = 60.0, rate: float = 500.0, sensors: int = 5, seed: int = 0):
    """A default-hand :class:`~torchhand.interaction.Capture` for timing (module docstring)."""
    from scipy.spatial.transform import Rotation

    from torchhand.hand.default import default_hand
    from torchhand.interaction import Capture

    rng = np.random.default_rng(seed)
    hand = default_hand("right")
    T = int(seconds * rate)
    t = np.arange(T) / rate
    D = hand.num_joints
    phase = rng.uniform(0, 2 * np.pi, D)
    q = hand.q_rest.numpy() + 0.2 * np.sin(2 * np.pi * 0.3 * t[:, None] + phase)
    q += rng.normal(0, np.radians(0.2), q.shape)
    root = np.tile(np.eye(4), (T, 1, 1))
    root[:, :3, :3] = Rotation.from_rotvec(0.2 * np.stack([np.sin(0.5 * t), np.cos(0.3 * t), 0 * t], 1)).as_matrix()
    root[:, :3, 3] = 0.05 * np.stack([np.sin(0.2 * t), np.cos(0.1 * t), np.sin(0.4 * t)], 1)
    links = [hand.link_names[int(hand.distal_link[f])] for f in range(sensors % 6)][:sensors]
    point = np.broadcast_to(hand.fingertip.numpy()[:sensors], (T, sensors, 3)).copy()
    force = np.zeros((T, sensors, 3))
    for s in range(sensors):
        start = rng.uniform(0.2, 1.0)
        while start < seconds - 0.5:
            k0, k1 = int(start * rate), int((start + 0.3) * rate)
            force[k0:k1, s, 2] = np.linspace(0.0, 3.0, k1 - k0)
            start += rng.uniform(1.0, 1.5)
    force += rng.normal(0, 0.01, force.shape)
    return Capture(q=q, joint_names=hand.joint_names, root_pose=root, fps=rate, force=force, force_point=point,
                   force_link=tuple(links), hand="default", source="synthetic"), hand


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seconds", type=float, default=60.0)
    p.add_argument("--rate", type=float, default=500.0)
    p.add_argument("--sensors", type=int, default=5)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", metavar="FILE")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    from torchhand.interaction import estimate_capture, generalized_coordinates, joint_torques

    capture, hand = build_capture(args.seconds, args.rate, args.sensors, args.seed)
    estimate_capture(capture, hand)  # warm-up (imports, scipy tables)
    stages = {"generalized_coordinates": [], "joint_torques": [], "estimate_capture (total)": []}
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        generalized_coordinates(capture)
        t1 = time.perf_counter()
        joint_torques(capture, hand)
        t2 = time.perf_counter()
        res = estimate_capture(capture, hand)
        t3 = time.perf_counter()
        stages["generalized_coordinates"].append(t1 - t0)
        stages["joint_torques"].append(t2 - t1)
        stages["estimate_capture (total)"].append(t3 - t2)
    print(f"capture: {args.seconds:g} s at {args.rate:g} Hz ({capture.num_frames} frames), 6 + D = "
          f"{6 + capture.num_joints}, {capture.num_sensors} sensors, {res.events.count} events; "
          f"{args.threads} torch thread(s)")
    print(f"{'stage':28s} {'median s':>9s} {'min s':>7s} {'max s':>7s}")
    for name, v in stages.items():
        print(f"{name:28s} {statistics.median(v):9.3f} {min(v):7.3f} {max(v):7.3f}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"args": vars(args), "events": res.events.count,
                       "seconds": {k: {"median": statistics.median(v), "min": min(v), "max": max(v)}
                                   for k, v in stages.items()}}, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
