"""Why a filled capture's frames fail: the captured fingers under the search's own test, and what the search can
reach at chosen frames.

    python scripts/fill_walls.py RESULT_DIR [--frames 100 286 818] [--captured] [--shifts 0 5 10]

RESULT_DIR is a ``torchhand fill`` result (its ``scene/`` is the prepared capture: object and wrist as used).

* ``--captured``: the fitted captured fingers (``captured_<side>.npz``) on the used wrist, through the synthesis'
  whole-motion test: per frame ``.`` passes, ``K`` kinematic (penetration, limits), ``F`` finger-finger, ``D``
  dynamic; with the deepest object penetration.
* per frame of ``--frames``: per finger the object-surface samples in the fingertip's reachable volume (the
  patch) and those that survive kinematic pruning (IK from the rest pose without penetration), for the wrist as
  used and moved ``--shifts`` millimetres toward the object's centre of mass.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
import torch


def captured_verdicts(result: Path) -> None:
    from torchhand.scene import load_scene
    from torchhand.synthesis.node_test import NodeTestSettings
    from torchhand.synthesis.finishing import _evaluate_motion
    from torchhand.synthesis.problem import build_problem

    scene = load_scene(result / "scene")
    problem = build_problem(scene, torch.Generator().manual_seed(0))
    side = scene.hands[0].side
    z = np.load(result / f"captured_{side}.npz")
    q = torch.tensor(z["q"], dtype=problem.dtype)[:, None]
    res = _evaluate_motion(problem, q, NodeTestSettings(slide_speed=0.1, table_slide_speed=0.1))
    cause, pen = res.cause.numpy(), res.penetration.numpy()
    counts = {name: int((cause == c).sum()) for c, name in enumerate(("pass", "kinematic", "finger_finger",
                                                                       "dynamic"))}
    print(f"captured fingers, {len(cause)} frames: {counts}")
    for a in range(0, len(cause), 50):
        row = "".join(".KFD"[c] for c in cause[a:a + 50])
        print(f"{a:5d} {row}  deepest {1e3 * pen[a:a + 50].max():5.1f} mm")


def reach(result: Path, frames: list[int], shifts: list[float]) -> None:
    from torchhand.scene import load_scene
    from torchhand.synthesis.initial import prune_patches
    from torchhand.synthesis.node_test import NodeTestSettings
    from torchhand.synthesis.problem import build_problem

    ns = NodeTestSettings(slide_speed=0.1, table_slide_speed=0.1)
    for fr in frames:
        base = load_scene(result / "scene").with_frames(fr, fr + 2)
        for shift in shifts:
            hands = []
            for h in base.hands:
                W = h.wrist_pose.clone()
                com = (base.object_pose[:, :3, :3] @ torch.tensor(np.array(base.object.com), dtype=W.dtype)
                       + base.object_pose[:, :3, 3])
                d = com - W[:, :3, 3]
                W[:, :3, 3] += 1e-3 * shift * d / d.norm(dim=-1, keepdim=True)
                hands.append(dataclasses.replace(h, wrist_pose=W))
            scene = dataclasses.replace(base, hands=tuple(hands))
            p = build_problem(scene, torch.Generator().manual_seed(0))
            init = prune_patches(p, torch.Generator().manual_seed(0), settings=ns)
            names = p.hands[0].finger_names
            patch = {n: int(p.patch[0, f, 0].sum()) for f, n in enumerate(names)}
            kept = {n: int(init.ok[0, 0, f].sum()) for f, n in enumerate(names)}
            print(f"frame {fr}, wrist {shift:g} mm toward the object: patch {patch}; after pruning {kept}",
                  flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("result", type=Path)
    ap.add_argument("--frames", type=int, nargs="*", default=[])
    ap.add_argument("--shifts", type=float, nargs="*", default=[0.0])
    ap.add_argument("--captured", action="store_true")
    args = ap.parse_args()
    if args.captured:
        captured_verdicts(args.result)
    if args.frames:
        reach(args.result, args.frames, args.shifts)


if __name__ == "__main__":
    main()
