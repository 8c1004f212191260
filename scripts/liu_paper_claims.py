"""Liu 2009's observations, measured on torchhand's built-in examples (docs/manipulation.md, "The paper's claims").

* **E1** (Sec. 6): the same drag with a heavier object moves the hand further from its equilibrium torques.
  ``liu-drag`` (0.5 kg) and the same scene at 1.5 kg (``PlanSettings(mass=1.5)``): sum over frames of |u - u_bar|^2
  over the finger joints and over the wrist's six rows, and their ratios (heavy / light; the aim is >= 1.5).
* **Press** (Sec. 6, Fig. 5(c)): "the distal phalanges turn toward the surface normal under load". ``liu-press``:
  the angle between the index and middle fingers' distal capsule axes and the plate's normal at the first frame and at
  the bottom of the press (the frame of the largest spring force), degrees.
* **Roll** (Fig. 5(b)): ``liu-roll`` turns the cylinder 40 degrees: the wrist's rotation over the motion and the
  largest change of the thumb's and index finger's joints, or where the run stopped.

    python scripts/liu_paper_claims.py [--work DIR] [--only e1 press roll]

Each run goes to WORK/<name>/ (``--overwrite``); prints one Markdown table per claim.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from torchhand.manipulation import GraspUnsuitable, ManipulationSettings, manipulate, write_manipulation
from torchhand.manipulation.grasp import load_packaged_grasp
from torchhand.manipulation.plan import PlanSettings
from torchhand.manipulation.plots import load_trace, torque_deviation
from torchhand.scene.builtin import builtin_scene


def _run(name: str, out: Path, mass: float | None = None) -> dict:
    """manipulate the built-in scene (optionally at another mass), write it; returns the run's figures."""
    settings = ManipulationSettings(plan=PlanSettings(mass=mass)) if mass is not None else ManipulationSettings()
    try:
        res = manipulate(builtin_scene(name), load_packaged_grasp(name), settings)
        write_manipulation(res, out, overwrite=True)
        stop = None
    except GraspUnsuitable as err:
        res, stop = err.partial, err
        if res is not None:
            write_manipulation(res, out, overwrite=True, unsuitable=err)
    row = {"result": res, "stop": None if stop is None else f"unsuitable at frame {stop.frame}"}
    if res is not None:
        dev = torque_deviation(load_trace(out))
        row.update(fingers=float(np.sum(dev["joints"])), wrist=float(np.sum(dev["wrist"])), frames=res.T,
                   converged=json.loads((out / "stats.json").read_text())["frames_converged"])
    return row


def e1(work: Path) -> None:
    light, heavy = _run("liu-drag", work / "e1-0.5kg"), _run("liu-drag", work / "e1-1.5kg", mass=1.5)
    print("| drag | frames (converged) | outcome | finger sum abs(u - u_bar)^2 | wrist sum |")
    print("|---|---|---|---|---|")
    for label, r in (("0.5 kg", light), ("1.5 kg", heavy)):
        print(f"| {label} | {r.get('frames', 0)} ({r.get('converged', 0)}) | {r['stop'] or 'complete'} | "
              f"{r.get('fingers', float('nan')):.4g} | {r.get('wrist', float('nan')):.4g} |")
    if "fingers" in light and "fingers" in heavy:
        print(f"\nratio heavy / light: fingers {heavy['fingers'] / light['fingers']:.2f}, wrist "
              f"{heavy['wrist'] / light['wrist']:.2f} (aim >= 1.5; the heavy run over its {heavy['frames']} frames, "
              f"the light over {light['frames']})")


def _distal_angles(res, finger_links: dict, normal: np.ndarray, t: int) -> dict:
    """Angle (degrees) between each named distal link's capsule axis and the line of ``normal`` at frame t."""
    hand = res.hand
    T = hand.forward_kinematics(torch.as_tensor(res.q[t])[None], torch.as_tensor(res.root[t])[None])[0].numpy()
    out = {}
    for label, name in finger_links.items():
        i = hand.link_names.index(name)
        a, b = hand.capsule_a[i].numpy(), hand.capsule_b[i].numpy()
        axis = T[i, :3, :3] @ (b - a)
        c = abs(float(axis @ normal)) / float(np.linalg.norm(axis))
        out[label] = float(np.degrees(np.arccos(min(1.0, c))))
    return out


def _table(header: tuple, row: dict, cells: tuple) -> None:
    """One Markdown table: the header, then the run's frames (converged) and outcome, then ``cells``."""
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    print(f"| {header[0]} | {row['frames']} ({row['converged']}) | {row['stop'] or 'complete'} | "
          + " | ".join(cells) + " |")


def press(work: Path) -> None:
    r = _run("liu-press", work / "press")
    res = r["result"]
    if res is None:
        print(f"liu-press: {r['stop']}, nothing written")
        return
    z = res.scene.object_pose[:, 2, 3].numpy()
    bottom = int(np.argmin(z))
    normal = res.scene.object_pose[bottom, :3, 2].numpy()
    links = {"index": "index_distal", "middle": "middle_distal"}
    first, low = _distal_angles(res, links, normal, 0), _distal_angles(res, links, normal, bottom)
    _table(("liu-press", "frames (converged)", "outcome", "index distal to normal: first / bottom", "middle"), r,
           (f"{first['index']:.1f}° / {low['index']:.1f}°", f"{first['middle']:.1f}° / {low['middle']:.1f}°"))


def roll(work: Path) -> None:
    r = _run("liu-roll", work / "roll")
    res = r["result"]
    if res is None:
        print(f"liu-roll: {r['stop']}, nothing written")
        return
    R0 = res.root[0, :3, :3]
    cos = [(np.trace(R @ R0.T) - 1) / 2 for R in res.root[:, :3, :3]]
    turn = float(np.degrees(np.arccos(np.clip(min(cos), -1, 1))))
    sel = [i for i, n in enumerate(res.hand.joint_names) if n.startswith(("thumb", "index"))]
    change = float(np.abs(res.q[:, sel] - res.q[0, sel]).max())
    _table(("liu-roll", "frames (converged)", "outcome", "largest wrist turn",
            "thumb and index joints, largest change"), r, (f"{turn:.1f}°", f"{change:.3f} rad"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", default="out/liu-claims")
    ap.add_argument("--only", nargs="+", choices=("e1", "press", "roll"), default=("e1", "press", "roll"))
    args = ap.parse_args(argv)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)
    for claim in args.only:
        print(f"\n## {claim}\n")
        {"e1": e1, "press": press, "roll": roll}[claim](work)
    return 0


if __name__ == "__main__":
    sys.exit(main())
