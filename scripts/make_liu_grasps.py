"""Make the packaged grasps of the Liu 2009 built-in scenes: torchhand/scenes/grasps/<scene>.npz.

How each grasp is made (deterministic: a seeded search on one thread, node budgets in work units):

1. ``torchhand.scenes.liu.approach_scene(scene)``: the object at rest at the scene's frame-0 pose, the wrist moving
   6 cm along the palm normal onto the scene's frame-0 hand pose (the approach of the other built-in scenes),
   written as a scene directory.
2. ``torchhand synthesize`` on its first 8 frames with a small search (4 trees, 8 candidates, at most 2000 node
   tests, 1 solution, seed 0): finger motion with the fingers closing on the object (Ye & Liu 2012).
3. ``torchhand grasp from-result`` at frame ``GRASP_FRAME`` of that solution: the joint angles and the wrist in the
   object frame, snapped onto the object (links within 5 mm touch; a small finger IK closes the gaps).

Every scene here holds the same 9 x 7 x 6 cm box from above at frame 0 (only the mass and the later motion differ);
the search's dynamic checks pass at every one of these masses, so the four files come out byte-identical.

    python scripts/make_liu_grasps.py [--only liu-drag ...] [--work DIR] [--check]

``--check`` also runs ``torchhand manipulate`` and ``torchhand check`` on every scene with its new grasp.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

from torchhand.cli import main as cli
from torchhand.scene_io import export_scene_dir
from torchhand.scenes import builtin_scene
from torchhand.scenes.liu import _GRASPS, LIU_SCENES, approach_scene

SYNTH = ["--frames", "0:8", "--trees", "4", "--candidates", "8", "--max-nodes", "2000", "--solutions", "1",
         "--seed", "0", "--no-progress", "--threads", "1"]
GRASP_FRAME = 7
"""Frame of the approach the grasp is taken at (the wrist 1 cm farther along the palm normal than the scene's hold
pose): thumb, index and little finger on the box's sides, seven contact links after snapping (the little-proximal
gap of 2.95 mm is the largest). At frame 6 the index-proximal link is 4.5 mm off the far face and is released after
the first frame; with the five contacts left, liu-lift's 1.5 kg box makes the planner add contacts from about frame
11 and the motion fails `torchhand check` (added contacts that carry force while their link is still 8-26 mm from
the box, fingers through each other). At frame 7 the grasp holds every scene without added contacts."""


def make(name: str, work: Path) -> Path:
    scene = builtin_scene(name)
    sdir = export_scene_dir(approach_scene(scene), work / f"{name}-approach", overwrite=True)
    res = work / f"{name}-synth"
    if cli(["synthesize", str(sdir), "--out", str(res), "--overwrite"] + SYNTH) != 0:
        raise SystemExit(f"{name}: synthesis failed")
    _GRASPS.mkdir(exist_ok=True)
    out = _GRASPS / f"{name}.npz"
    if cli(["grasp", "from-result", str(res), "--solution", "0", "--frame", str(GRASP_FRAME), "--out", str(out),
            "--overwrite"]) != 0:
        raise SystemExit(f"{name}: grasp from-result failed")
    return out


def check(name: str, grasp: Path, work: Path) -> int:
    out = work / f"{name}-manip"
    rc = cli(["manipulate", name, "--grasp", str(grasp), "--out", str(out), "--overwrite", "--threads", "1",
              "--no-progress"])
    if rc != 0:
        return rc
    return cli(["check", str(out)])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", nargs="+", choices=LIU_SCENES, help="these scenes only")
    ap.add_argument("--work", help="keep the intermediate scenes and results here (default: a temporary folder)")
    ap.add_argument("--check", action="store_true", help="also run manipulate and check on each scene")
    args = ap.parse_args(argv)
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="liu-grasps-"))
    work.mkdir(parents=True, exist_ok=True)
    bad = []
    try:
        for name in args.only or LIU_SCENES:
            g = make(name, work)
            print(f"{name}: wrote {g}")
            if args.check and check(name, g, work) != 0:
                bad.append(name)
    finally:
        if not args.work:
            shutil.rmtree(work, ignore_errors=True)
    if bad:
        print(f"failed: {', '.join(bad)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
