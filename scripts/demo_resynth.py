"""Demo of interaction resynthesis (Kry & Pai 2006 §7-8, Fig. 13 analogue) on a two-finger pinch.

The interaction is constructed (``source: constructed``; tests/torchhand/test_resynth.py::pinch_files): a pinch
hand with Table-1-like compliance closes on a 4 x 4 x 6 cm box resting on a table over 0.3 s, then lifts the root
5 cm over 0.5 s and holds. It is resynthesised on

    same          the captured box, 50 g
    smaller       a 3.6 x 4 x 6 cm box, 50 g (the fingers travel further before they touch)
    heavy         the captured box at 0.35 kg, without grip adjustment, with the delayed (100 ms) response and
                  with the imminent-slip response

Each case is a result directory under --out (``torchhand render|plot|check DIR`` work on it); the table printed at the
end gives the object's lift, its slip in the hand frame, grip events and the delay of the first one after slip
onset, the per-step time and the checker's verdict.

    python scripts/demo_resynth.py --out /tmp/resynth_demo
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

_TESTS = Path(__file__).resolve().parents[1] / "tests" / "torchhand"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True, help="output folder (one result directory per case)")
    p.add_argument("--fps", type=float, default=120.0, help="interaction and scene frame rate, Hz (120)")
    p.add_argument("--solver", choices=["lemke", "pgs", "auto"], default="lemke", help="LCP solver (lemke)")
    p.add_argument("--overwrite", action="store_true", help="replace earlier results")
    args = p.parse_args(argv)

    sys.path.insert(0, str(_TESTS.parents[1]))
    from tests.torchhand.test_resynth import pinch_files

    from torchhand.check import check_result
    from torchhand.interaction.grip import GripSettings
    from torchhand.interaction.resynth import (ResynthSettings, Variant, load_interaction, resynthesize,
                                               write_resynthesis)
    from torchhand.scene import load_scene

    out = Path(args.out)
    cases = [("same", (0.02, 0.02, 0.03), 0.05, "none"), ("smaller", (0.018, 0.02, 0.03), 0.05, "none"),
             ("heavy", (0.02, 0.02, 0.03), 0.35, "none"), ("heavy-delayed", (0.02, 0.02, 0.03), 0.35, "delayed"),
             ("heavy-imminent", (0.02, 0.02, 0.03), 0.35, "imminent")]
    rows = [("case", "mass kg", "grip", "lift mm", "max slip mm", "grip events", "1st event after onset ms",
             "ms/step", "check")]
    for name, half, mass, grip in cases:
        scene_dir, inter_path = pinch_files(out / "inputs" / name, half=half, mass=mass, fps=args.fps)
        inter, scene = load_interaction(inter_path), load_scene(scene_dir)
        settings = ResynthSettings(solver=args.solver, grip=GripSettings(grip))
        t0 = time.perf_counter()
        result = resynthesize(inter, scene, variants=(Variant(),), settings=settings)
        wall = time.perf_counter() - t0
        path = write_resynthesis(result, out / name, overwrite=args.overwrite)
        r = result.rollouts[0]
        report = check_result(path)
        lift = 1e3 * (r.object_pose[-1, 2, 3] - r.object_pose[0, 2, 3])
        first = int(r.grip_events[:, 0].min()) if len(r.grip_events) else None
        delay = f"{1e3 * (first - r.grip_onset) / result.fps:.0f}" if first is not None and r.grip_onset >= 0 else "-"
        rows.append((name, f"{mass:g}", grip, f"{lift:.1f}", f"{1e3 * r.object_slip.max():.1f}",
                     str(len(r.grip_events)), delay, f"{1e3 * wall / r.q.shape[0]:.1f}",
                     "pass" if report.passed else "FAIL: " + "; ".join(report.failures)))
        print(f"{name}: wrote {path}", file=sys.stderr)
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    for row in rows:
        print("  ".join(c.ljust(w) for c, w in zip(row, widths)).rstrip())
    return 0


if __name__ == "__main__":
    sys.exit(main())
