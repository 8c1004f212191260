"""The captured-finger comparison of a written result, from its files alone (BENCHMARKS.md "Whole captures").

``python scripts/capture_reference.py RESULT_DIR [--out DIR]``: for a result of a motion capture (its ``scene/``
keeps the capture's source) whose hand is the built-in one, the fingertip distance to the captured fingers and the
contact-set agreement per solution (over the frames its ``frame_status`` flags solved, or every frame), printed and
written to ``DIR/reference.json`` with a plot per solution and ``captured_<side>.npz`` (the captured fingers as a
solution file for ``torchhand render RESULT_DIR --compare``). The same figures ``fill`` and ``synthesize`` now write
into ``stats.json``; this reads results written before that, or elsewhere.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("result", type=Path)
    ap.add_argument("--out", type=Path, default=None, help="default: RESULT_DIR")
    args = ap.parse_args()
    from torchhand.fill.captured import write_captured
    from torchhand.fill.reference import reference_report
    from torchhand.hand.mount import track_hand
    from torchhand.io.result import load_result

    out = args.out or args.result
    out.mkdir(parents=True, exist_ok=True)
    result = load_result(args.result)
    scene = result.scene
    hands = [track_hand(h) for h in scene.hands]
    motions, frames = [], []
    for i in range(len(result.solutions)):
        sol = result.solution(i)
        by_side = {h.side: h for h in sol.hands}
        q = torch.stack([torch.as_tensor(by_side[h.side].q) for h in scene.hands], 1)
        roots = torch.stack([torch.as_tensor(by_side[h.side].root_pose) for h in scene.hands])
        motions.append((q, roots))
        status = np.load(sol.path)["frame_status"] if "frame_status" in np.load(sol.path).files else None
        frames.append(np.ones(scene.T, bool) if status is None else status == 0)
    report = reference_report(scene, hands, motions, out, frames=frames)
    fits = {s: write_captured(scene, s, hands[k], motions[0][1][k], out)
            for k, s in enumerate(h.side for h in scene.hands) if s in report}
    doc = {"result": str(args.result), "reference": report, "captured_fit": fits}
    (out / "reference.json").write_text(json.dumps(doc, indent=1))
    for side, rows in report.items():
        for i, r in enumerate(rows):
            d = r["tip_distance_mm"]
            print(f"{side} sol_{i:03d}: {r['frames']} frames, tip distance median {d['median']} mm, p90 {d['p90']} mm, "
                  f"contact sets agree {r['contact_agreement']}, per finger {r['contact_agreement_per_finger']}")
    for side, f in fits.items():
        print(f"captured {side}: {f['file']}, fit residual median {f['residual_mm']['median']:.1f} mm, "
              f"p90 {f['residual_mm']['p90']:.1f} mm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
