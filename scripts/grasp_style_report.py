"""Grasp style of synthesized results: does the palm push (an envelope grasp) or only the fingers (a fingertip grip)?

    python scripts/grasp_style_report.py out/handle-lift out/handle-lift-palm [--min-force 0.02] [--json F]

Reads only the result files. The palm is the link named ``palm`` and the metacarpal of every four-link finger
(the links inside the palm; a three-link thumb's metacarpal is a finger link), the same links as
``torchhand.synthesis.clearance.palm_links``. Per solution: the share of the frames where the hand carries the
object (it touches it and the table pushes with less than ``--min-force`` times the weight) and of those where it
touches it at all, in which a palm contact carries a normal force of at least ``--min-force`` times the weight,
and the share of the hand's total normal force the palm carries over the clip. The weight is the object's mass
(the result's ``scene/scene.toml``) times the gravity there.
"""

from __future__ import annotations

import argparse
import json
import sys
import tomllib
from pathlib import Path

import numpy as np

FINGER_LINKS = ("metacarpal", "proximal", "middle", "distal")


def palm_names(names: list[str]) -> set[str]:
    """Palm links among a result's contact link names (module docstring)."""
    fingers = {n.rsplit("_", 1)[0] for n in names if "_" in n}
    four = {f for f in fingers if all(f"{f}_{s}" in names for s in FINGER_LINKS)}
    return {"palm"} & set(names) | {f"{f}_metacarpal" for f in four}


def scene_weight(result: Path) -> float:
    """The object's weight, newtons, from the scene written beside the solutions."""
    scene = tomllib.loads((result / "scene" / "scene.toml").read_text())
    return float(scene["object"]["mass"]) * float(np.linalg.norm(scene["scene"]["gravity"]))


def solution_style(path: Path, min_force: float, weight: float) -> dict:
    z = np.load(path)
    names = [str(n) for n in z["contact_link_name"]]
    palm = np.isin(z["contact_link"], [i for i, n in enumerate(names) if n in palm_names(names)]) & z["contact_mask"]
    fn = np.einsum("tkc,tkc->tk", z["contact_force"], z["contact_normal"]) * z["contact_mask"]
    touching = z["contact_mask"].any(1)
    carried = touching & (np.linalg.norm(z["env_contact_force"], axis=-1).sum(1) < min_force * weight)
    pushing = ((fn * palm) >= min_force * weight).any(1)
    return {"frames": int(len(touching)), "touching": int(touching.sum()), "carried": int(carried.sum()),
            "palm_pushing": int(pushing.sum()),
            "palm_share_of_carried": float((pushing & carried).sum() / max(carried.sum(), 1)),
            "palm_share_of_frames": float(pushing.sum() / max(touching.sum(), 1)),
            "palm_share_of_force": float((fn * palm).sum() / max(fn.sum(), 1e-12)), "weight_n": weight}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", type=Path, nargs="+")
    ap.add_argument("--min-force", type=float, default=0.02, help="palm force threshold, times the object's weight")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    report = {}
    for result in args.results:
        files = sorted((result / "solutions").glob("sol_*.npz"))
        if not files:
            print(f"{result}: no solutions", file=sys.stderr)
            continue
        weight = scene_weight(result)
        rows = [solution_style(f, args.min_force, weight) for f in files]
        report[str(result)] = rows
        def col(key):
            return ", ".join(f"{r[key]:.0%}" for r in rows)
        print(f"{result.name}: {len(rows)} solutions; the palm pushes (>= {args.min_force:g} weight) on "
              f"{col('palm_share_of_carried')} of the frames the hand carries the object (no table force), on "
              f"{col('palm_share_of_frames')} of the frames it touches it; the palm's share of the hand's normal "
              f"force: {col('palm_share_of_force')}")
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
