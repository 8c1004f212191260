"""The Liu 2009 acceptance figures of every built-in example, measured on the written results.

For each ``liu-*`` scene (``liu-shadow-lift`` only where the shared data has the Shadow hand): ``torchhand manipulate``
with its packaged grasp and the ablation without the objective (``--no-objective``), each written to WORK/<scene>/
and WORK/<scene>-ablation/; then, on the files:

* ``torchhand check`` (the independent checker);
* the stored torques against MuJoCo's on the written ``hand.xml`` (``torchhand.manipulation.audit``);
* static contacts: their largest tangential speed (bound 1 mm/s); sliding contacts (moving faster than 1 mm/s and
  loaded): the share whose friction force lies within 18 degrees of the hand point's velocity relative to the
  object (cos >= 0.95, Eq. 7), and the smallest cos;
* the torque deviation sum_t |u - u_bar|^2 of the finger joints, with the objective and in the ablation;
* ``torchhand plot RESULT --compare ABLATION`` (torque_deviation.png against the ablation) and one rendered frame
  (the middle one) in WORK/<scene>/plots/ and WORK/<scene>.png;
* the verdict's robustness: the same run with every object pose moved by (+1e-9, -1e-9, 0) m, and with 2 threads
  (``--threads 2``): the same verdict? the largest joint-angle and torque differences from the first run;
* the frames whose synthesis converged (stats.json ``frames_converged``) and the wrist's part of sum |u - u_bar|^2
  (the six root rows), with the objective and in the ablation.

    python scripts/liu_acceptance.py [--work DIR] [--only liu-drag ...] [--no-render] [--no-robustness]

Prints two Markdown tables; exit 1 when a run fails, a check fails or a torque differs from MuJoCo's by more than
1e-6 of the largest.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from torchhand.check import check_result
from torchhand.cli import main as cli
from torchhand.manipulation.audit import contact_motion, mujoco_torque_error
from torchhand.manipulation.plots import load_trace, torque_deviation
from torchhand.scene.builtin.liu import LIU_SCENES, SHADOW_HAND, shared_data_dir


def finger_deviation(result_dir: Path) -> float:
    """sum over frames of |u - u_bar|^2 over the finger joints (the generalised forces after the root's six; two
    hands: both), as the torque-deviation plot adds them."""
    return float(torque_deviation(load_trace(result_dir))["joints"].sum())


def wrist_deviation(result_dir: Path) -> float:
    """sum over frames of |u - u_bar|^2 over the root's six rows (both hands for two)."""
    return float(np.sum(torque_deviation(load_trace(result_dir))["wrist"]))


def _solution(d: Path) -> dict:
    with np.load(d / "solutions" / "sol_000.npz") as f:
        return {"q": f["q"], "torque": f["torque"]}


def robustness(name: str, work: Path, base: Path) -> dict:
    """The run again with the object's path moved by 1e-9 m, and with 2 threads: verdicts and differences."""
    import dataclasses

    from torchhand.manipulation import GraspUnsuitable, manipulate, write_manipulation
    from torchhand.manipulation.grasp import load_packaged_grasp
    from torchhand.scene.builtin import builtin_scene

    out = {}
    scene = builtin_scene(name)
    pose = scene.object_pose.clone()
    pose[:, 0, 3] += 1e-9
    pose[:, 1, 3] -= 1e-9
    moved = work / f"{name}-moved"
    try:
        res = manipulate(dataclasses.replace(scene, object_pose=pose), load_packaged_grasp(name))
        write_manipulation(res, moved, overwrite=True)
    except GraspUnsuitable as err:
        if err.partial is not None:
            write_manipulation(err.partial, moved, overwrite=True, unsuitable=err)
    two = work / f"{name}-2threads"
    cli(["manipulate", name, "--out", str(two), "--overwrite", "--threads", "2", "--no-progress"])
    ref = _solution(base)
    ref_complete = json.loads((base / "stats.json").read_text())["complete"]
    for key, d in (("moved", moved), ("threads", two)):
        if not (d / "stats.json").is_file():
            out[key] = ("nothing written", float("nan"), float("nan"))
            continue
        other, st = _solution(d), json.loads((d / "stats.json").read_text())
        T = min(len(ref["q"]), len(other["q"]))
        same = st["complete"] == ref_complete and len(other["q"]) == len(ref["q"])
        out[key] = ("same" if same else "DIFFERENT", float(np.abs(ref["q"][:T] - other["q"][:T]).max()),
                    float(np.abs(ref["torque"][:T] - other["torque"][:T]).max()))
    return out


def run(name: str, work: Path, render: bool, robust: bool = True) -> dict:
    out, abl = work / name, work / f"{name}-ablation"
    row = {"scene": name}
    common = ["--overwrite", "--threads", "1", "--no-progress"]
    rc = cli(["manipulate", name, "--out", str(out)] + common)
    rc_abl = cli(["manipulate", name, "--out", str(abl), "--no-objective"] + common)
    stats = json.loads((out / "stats.json").read_text())
    row.update(rc=rc, frames=stats["T"], complete=stats["complete"], added=stats["added_contacts"],
               fps=stats["frames_per_second"])
    rep = check_result(out)
    figs = rep.solutions[0].figures
    row["check"] = "pass" if rep.passed else "FAIL"
    row["obj_mm"] = 1e3 * figs["object_penetration_m"].value
    row["chand_mm"] = 1e3 * figs["contact_hand_m"].value
    worst, scale = mujoco_torque_error(out)
    row["torque_err_pct"] = 100 * worst / scale
    m = contact_motion(out)
    row.update(static_pairs=m.static_pairs, static_mm_s=1e3 * m.static_speed, sliding_pairs=m.sliding_pairs,
               eq7_share=m.share_along(0.95), eq7_min=float(m.cos.min()) if len(m.cos) else float("nan"))
    row["dev"], row["dev_ablation"] = finger_deviation(out), (finger_deviation(abl) if rc_abl in (0, 1) else None)
    row["wrist"], row["wrist_ablation"] = wrist_deviation(out), (wrist_deviation(abl) if rc_abl in (0, 1) else None)
    row["ablation_frames"] = json.loads((abl / "stats.json").read_text())["T"] if rc_abl in (0, 1) else 0
    row["converged"] = stats.get("frames_converged")
    row["robust"] = robustness(name, work, out) if robust else None
    cli(["plot", str(out), "--compare", str(abl), "--out", str(out / "plots")])
    if render:
        mid = row["frames"] // 2
        cli(["render", str(out), "--frames", f"{mid}:{mid + 1}", "--out", str(work / f"{name}.png")])
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", default="out/liu-acceptance", help="results, plots and frames go here")
    ap.add_argument("--only", nargs="+", choices=LIU_SCENES, help="these scenes only")
    ap.add_argument("--no-render", action="store_true", help="no rendered frame")
    ap.add_argument("--no-robustness", action="store_true", help="no perturbed and 2-thread runs")
    args = ap.parse_args(argv)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    names = list(args.only or LIU_SCENES)
    if "liu-shadow-lift" in names and not (shared_data_dir() / SHADOW_HAND).is_file():
        print(f"liu-shadow-lift skipped: no {shared_data_dir() / SHADOW_HAND}", file=sys.stderr)
        names.remove("liu-shadow-lift")
    rows = [run(n, work, not args.no_render, not args.no_robustness) for n in names]
    print("| scene | frames | complete | added | check | object / contact-hand mm | torque vs MuJoCo (% of max) "
          "| static: contact-frames, max mm/s | sliding moving: contact-frames, cos >= 0.95, min cos "
          "| finger sum abs(u - u_bar)^2: objective / ablation | frames/s |")
    print("|" + "---|" * 11)
    bad = False
    for r in rows:
        abl = "-" if r["dev_ablation"] is None else f"{r['dev_ablation']:.3g}"
        print(f"| `{r['scene']}` | {r['frames']} | {r['complete']} | {r['added']} | {r['check']} | "
              f"{r['obj_mm']:.1f} / {r['chand_mm']:.1f} | {r['torque_err_pct']:.1e} | {r['static_pairs']}, "
              f"{r['static_mm_s']:.3f} | {r['sliding_pairs']}, {100 * r['eq7_share']:.0f} %, {r['eq7_min']:.2f} | "
              f"{r['dev']:.3g} / {abl} | {r['fps']:.1f} |")
        bad |= r["rc"] != 0 or r["check"] != "pass" or r["torque_err_pct"] > 1e-4
    print()
    print("| scene | frames converged | wrist sum abs(u - u_bar)^2: objective / ablation (ablation frames) "
          "| path moved 1e-9 m: verdict, max dq rad, max du | 2 threads: verdict, max dq rad, max du |")
    print("|" + "---|" * 5)
    for r in rows:
        wa = "-" if r["wrist_ablation"] is None else f"{r['wrist_ablation']:.3g}"
        rb = r["robust"] or {}
        cells = [f"{v[0]}, {v[1]:.1e}, {v[2]:.1e}" for v in (rb.get(key, ("-", 0, 0)) for key in ("moved", "threads"))]
        print(f"| `{r['scene']}` | {r['converged']} / {r['frames']} | {r['wrist']:.3g} / {wa} ({r['ablation_frames']}) "
              f"| {cells[0]} | {cells[1]} |")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
