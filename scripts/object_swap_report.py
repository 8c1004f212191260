"""Object swap, side by side with the original object's run: is the wrist track the same, and which fingers touch.

    python scripts/object_swap_report.py out/box-turn out/bunny out/mug [--solutions 3]

The first result is the reference (the scene's own object). For every result: the largest difference of its
solutions' wrist poses (``root_pose``) from the reference's (0 when the track is kept exactly), and per finger the
fraction of frames in contact (over its first ``--solutions`` solutions); for the others, the fraction of frames
whose set of touching fingers differs from the reference solution of the same index.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from torchhand.fill.reference import FINGERS


def finger_sets(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(T, 5) bool fingers in contact, and the wrist poses (T, 4, 4), of one solution file."""
    z = np.load(path)
    names = [str(n) for n in z["contact_link_name"]]
    link = z["contact_link"]
    on = z["contact_mask"]
    out = np.zeros((on.shape[0], len(FINGERS)), dtype=bool)
    for f, finger in enumerate(FINGERS):
        ids = [i for i, n in enumerate(names) if n.startswith(finger)]
        out[:, f] = (on & np.isin(link, ids)).any(1)
    return out, z["root_pose"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", type=Path, nargs="+")
    ap.add_argument("--solutions", type=int, default=3)
    args = ap.parse_args()
    ref = [finger_sets(p) for p in sorted((args.results[0] / "solutions").glob("sol_*.npz"))[:args.solutions]]
    for result in args.results:
        runs = [finger_sets(p) for p in sorted((result / "solutions").glob("sol_*.npz"))[:args.solutions]]
        if not runs:
            print(f"{result}: no solutions")
            continue
        wrist = max(float(np.abs(r[1] - ref[0][1]).max()) for r in runs)
        frac = np.mean([r[0].mean(0) for r in runs], 0)
        line = ", ".join(f"{f} {v:.2f}" for f, v in zip(FINGERS, frac))
        diff = [float((r[0] != q[0]).any(1).mean()) for r, q in zip(runs, ref)]
        print(f"{result.name}: {len(runs)} solutions; wrist poses differ from the reference's by at most {wrist:.1e}; "
              f"fingers in contact (fraction of frames): {line}; frames whose finger set differs from the "
              f"reference solution of the same index: {', '.join(f'{d:.2f}' for d in diff)}")


if __name__ == "__main__":
    main()
