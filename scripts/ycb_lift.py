"""The DexYCB-style grasp-and-lift on a real scanned YCB object, end to end (docs/manipulation.md, "A DexYCB-style
grasp from a qpos (real scanned object)").

Builds the case from the shared reference data (:func:`torchhand.scene.builtin.ycb.ycb_lift_case`: the YCB scan with
its published mass on the table and a 10 cm minimum-jerk lift, the Shadow hand under a 6-joint arm, the qpos of the
fitted grasp; DexYCB-style, not DexYCB data) and runs

    torchhand grasp from-qpos OUT/arm/scene.xml --qpos OUT/qpos.npy --scene OUT/scene --frame 0 --out OUT/grasp.npz
    torchhand manipulate OUT/scene --grasp OUT/grasp.npz --out OUT/result
    torchhand check OUT/result

then prints the figures: frames, contacts (grasp and added), frames/s, the check's verdict and its worst
penetration and contact distances.

    python scripts/ycb_lift.py --shared ../shared/data --out /tmp/ycb-lift [--object 006_mustard_bottle]

Exit 0 when the lift completes and the check passes, 1 otherwise, 2 when the shared data is absent.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from torchhand.check import check_result
from torchhand.cli import main as cli
from torchhand.errors import TorchhandError
from torchhand.scene.builtin.ycb import YCB_MASS, ycb_lift_case


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shared", default=None, help="shared reference data directory (default: $TORCHHAND_SHARED_DATA "
                                                   "or ../shared/data beside the checkout)")
    ap.add_argument("--out", required=True, help="output directory (scene, arm, qpos, grasp, result)")
    ap.add_argument("--object", default="006_mustard_bottle", choices=sorted(YCB_MASS))
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    out = Path(args.out)
    try:
        case = ycb_lift_case(args.shared, out, object=args.object)
    except TorchhandError as err:
        print(f"ycb_lift: {err}", file=sys.stderr)
        return 2
    print(f"case: scene {case.scene}, arm {case.arm}, qpos {case.qpos} ({case.object}, {case.mass} kg)")
    grasp, res = out / "grasp.npz", out / "result"
    t0 = time.perf_counter()
    rc = cli(["grasp", "from-qpos", str(case.arm), "--qpos", str(case.qpos), "--scene", str(case.scene),
              "--frame", str(case.frame), "--out", str(grasp), "--overwrite"])
    t_grasp = time.perf_counter() - t0
    if rc != 0:
        print(f"grasp from-qpos failed (exit {rc})", file=sys.stderr)
        return 1
    t0 = time.perf_counter()
    rc = cli(["manipulate", str(case.scene), "--grasp", str(grasp), "--out", str(res), "--overwrite",
              "--threads", str(args.threads), "--no-progress"])
    t_manip = time.perf_counter() - t0
    if not (res / "stats.json").is_file():
        print(f"manipulate wrote nothing (exit {rc})", file=sys.stderr)
        return 1
    stats = json.loads((res / "stats.json").read_text())
    t0 = time.perf_counter()
    report = check_result(res)
    t_check = time.perf_counter() - t0
    sol = report.solutions[0]
    fig = sol.figures
    frames = sol.frames
    added = stats.get("added_contacts")
    print(f"grasp from-qpos: {t_grasp:.1f} s")
    print(f"manipulate: {'complete' if report.complete else 'INCOMPLETE'}, {frames} frames, added contacts "
          f"{added}, {t_manip:.1f} s ({frames / max(t_manip, 1e-9):.1f} frames/s)")
    mm = {k: 1e3 * fig[k].value for k in ("object_penetration_m", "table_penetration_m", "finger_penetration_m",
                                           "contact_object_m", "contact_hand_m") if k in fig}
    print(f"check: {'pass' if sol.passed else 'FAIL'} ({t_check:.1f} s); worst (mm): "
          + ", ".join(f"{k[:-2].replace('_', ' ')} {v:.2f}" for k, v in mm.items()))
    if not sol.passed:
        print(f"check: {sol.failure()}")
    return 0 if (rc == 0 and report.complete and sol.passed) else 1


if __name__ == "__main__":
    sys.exit(main())
