"""Splicing accuracy against known time warps on real body capture (design note GT-1, GT-2).

For each body clip, level and seed a hand session is made from the body itself (``torchhand.splice.synthetic``:
a known smooth warp with local speed 0.6-1.4x, 60 Hz, then noise, amplitude, yaw, a frozen trunk), aligned back to
the body, and the recovered hand time per body frame is compared with the truth. Methods, all in one run:

    uniform        hand time = body time scaled by the length ratio
    plain-dtw      one DTW on Euclidean distances of shoulder-relative, centred markers (30 % band)
    paper-1 / -2   the paper: Eq. 6 signs with Eq. 7's per-cell yaw; pass 1 only / both passes (Eq. 9 minimal
                   rotation)
    trunk-1 / -2   torchhand's default: trunk-frame features; pass 1 only / both passes (forearm-frame Eq. 9,
                   within phase)
    hand-only-2    the default with the session treated as a hand-only capture (no shoulder, no trunk: one
                   fitted rotation); L4 and L5 only, the levels whose session has a still trunk

Errors are |recovered - true| hand time in ms per body frame: median, p95 over all frames, and p95 over moving
frames (wrist speed above 25 % of its 95th percentile; holds cannot be timed from arm data).

With ``--fingers``: GT-2, real ManipNet finger rotations carried on the synthetic clock through the whole CLI
path (splice -> spliced.bvh -> read back), geodesic error per finger joint in degrees.

    python scripts/splice_accuracy.py                      # mocapbank and CMU, L0..L5, seeds 0-5
    python scripts/splice_accuracy.py --bodies mocapbank --levels L4 --seeds 0 --json out.json
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch

from torchhand.scene.bvh import read_bvh
from torchhand.kernels.dtw import dtw, pairwise_cost
from torchhand.splice.align import SpliceSettings, align, band_width, path_median
from torchhand.splice.markers import virtual_markers
from torchhand.splice.rigs import detect_rig
from torchhand.splice.splice import arm_joints, clip_axes
from torchhand.splice.synthetic import LEVELS, make_hand_session

DATA = Path(os.environ.get("TORCHHAND_SHARED_DATA", Path(__file__).resolve().parents[1].parent / "shared" / "data")) \
    / "mocap"
BODIES = {
    "mocapbank": DATA / "bvh_python_tests" / "test_mocapbank.bvh",
    "cmu": DATA / "cmu_body_frozen_hands" / "01-01_v01.bvh",
}
METHODS = ("uniform", "plain-dtw", "paper-1", "paper-2", "trunk-1", "trunk-2", "hand-only-2")


def _plain_dtw(mb, mh, band: float) -> np.ndarray:
    def feats(mk):
        x = mk.markers - (mk.shoulder.unsqueeze(1) if mk.shoulder is not None else 0)
        x = x - x.mean(0, keepdim=True)
        return x.reshape(x.shape[0], -1)

    a, b = feats(mb)[None], feats(mh)[None]
    n, m = a.shape[1], b.shape[1]
    W, _ = band_width(band, n, m)
    res = dtw(pairwise_cost(a, b), band=W)
    return path_median(res.path, n)[0].numpy() / mh.fps


def evaluate(body_name: str, level: str, seed: int, methods=METHODS) -> dict:
    body = read_bvh(BODIES[body_name])
    rig = detect_rig(body)
    units, up = clip_axes(body, rig, "right")
    aj = arm_joints(body, rig, "right")
    arms = [rig.arms[s] for s in ("right", "left") if s in rig.arms]
    g = torch.Generator().manual_seed(seed)
    hs = make_hand_session(body, level, g, shoulders=[a.shoulder for a in arms], elbows=[a.elbow for a in arms],
                           wrists=[a.wrist for a in arms], up_axis=up, units_scale=units)
    mb = virtual_markers(body, aj, units_scale=units, up_axis=up)
    mh = virtual_markers(hs.clip, aj, units_scale=units, up_axis=up)
    n, m = mb.num_frames, mh.num_frames
    wrist_speed = (mb.markers[1:, 0] - mb.markers[:-1, 0]).norm(dim=-1).numpy()
    wrist_speed = np.concatenate([wrist_speed[:1], wrist_speed])
    moving = wrist_speed > 0.25 * np.percentile(wrist_speed, 95)
    out = {"body": body_name, "level": level, "seed": seed, "n": n, "m": m, "methods": {}}
    for meth in methods:
        if meth == "hand-only-2" and LEVELS.index(level) < 4:
            continue                   # a hand-only capture implies a still trunk: only L4 and L5 make one
        t0 = time.perf_counter()
        note = ""
        if meth == "uniform":
            est = np.arange(n) / mb.fps * ((m - 1) / mh.fps) / ((n - 1) / mb.fps)
        elif meth == "plain-dtw":
            est = _plain_dtw(mb, mh, 0.30)
        else:
            feat = "paper" if meth.startswith("paper") else "trunk"
            passes = int(meth[-1])
            hand_only = meth.startswith("hand-only")
            al = align(mb.markers[None], mh.markers[None], body_fps=mb.fps, hand_fps=mh.fps,
                       body_shoulder=mb.shoulder[None], body_trunk=mb.trunk[None],
                       hand_shoulder=None if hand_only else mh.shoulder[None],
                       hand_trunk=None if hand_only else mh.trunk[None],
                       settings=SpliceSettings(features=feat, passes=passes))
            est = al.hand_time[0].numpy()
            note = al.pass2_note[0]
        dt = time.perf_counter() - t0
        e = np.abs(est - hs.truth) * 1000.0
        out["methods"][meth] = {"median_ms": float(np.median(e)), "p95_ms": float(np.percentile(e, 95)),
                                "moving_p95_ms": float(np.percentile(e[moving], 95)), "max_ms": float(e.max()),
                                "seconds": dt, "note": note}
    return out


def _geodesic_deg(Ra: torch.Tensor, Rb: torch.Tensor) -> np.ndarray:
    c = (((Ra.transpose(-1, -2) @ Rb).diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1, 1)
    return torch.rad2deg(torch.acos(c)).numpy()


def evaluate_fingers(level: str, seed: int, start: int = 600) -> dict:
    """GT-2: ManipNet's right-hand fingers (from ``start``, 120 Hz) on the mocapbank body's clock. The hand session
    carries them at the warped time; the spliced file, written and read back, is compared joint by joint with the
    fingers at the body's own time (geodesic angle, degrees)."""
    from torchhand.splice import prepare_out, splice, write_splice
    from torchhand.splice.retime import local_rotations, retime_motion
    from torchhand.splice.synthetic import with_fingers
    import tempfile

    body = read_bvh(BODIES["mocapbank"])
    rig = detect_rig(body)
    units, up = clip_axes(body, rig, "right")
    manip = read_bvh(DATA / "manipnet" / "mug1" / "rightHand.bvh")
    mrig = detect_rig(manip)
    arms = [rig.arms[s] for s in ("right", "left")]
    hs = make_hand_session(body, level, torch.Generator().manual_seed(seed), shoulders=[a.shoulder for a in arms],
                           elbows=[a.elbow for a in arms], wrists=[a.wrist for a in arms], up_axis=up,
                           units_scale=units)
    n, m = body.num_frames, hs.clip.num_frames
    body_time_of_hand = hs.warp.inverse(np.arange(m) / hs.clip.fps)
    hand, _ = with_fingers(hs.clip, rig, "right", manip, mrig, start + body_time_of_hand * manip.fps,
                           finger_handedness="left", up_axis=up)
    truth, trig = with_fingers(body, rig, "right", manip, mrig, start + np.arange(n) / body.fps * manip.fps,
                               finger_handedness="left", up_axis=up)
    res = splice(body, hand, side="right")
    with tempfile.TemporaryDirectory() as d:
        write_splice(res, prepare_out(Path(d) / "out"))
        back = read_bvh(Path(d) / "out" / "spliced.bvh")
    tj = trig.finger_joints("right")
    names = [truth.names[j] for j in tj]
    Rt = local_rotations(truth)[:, tj]
    Rb = local_rotations(back)[:, [back.names.index(x) for x in names]]
    uni = np.arange(n) * (m - 1) / (n - 1)
    Ru = local_rotations(hand, retime_motion(hand, uni))[:, [hand.names.index(x) for x in names]]
    e, eu = _geodesic_deg(Rb, Rt), _geodesic_deg(Ru, Rt)
    return {"level": level, "seed": seed, "mean_deg": float(e.mean()), "p95_deg": float(np.percentile(e, 95)),
            "uniform_mean_deg": float(eu.mean()), "uniform_p95_deg": float(np.percentile(eu, 95)),
            "frames_equal": back.num_frames == n, "frame_time_equal": abs(back.frame_time - body.frame_time) < 1e-12}


def _table(rows: list[dict], methods) -> str:
    lines = []
    keys = sorted({(r["body"], r["level"]) for r in rows}, key=lambda k: (k[0], LEVELS.index(k[1])))
    head = f"{'body':10s} {'level':5s} " + " ".join(f"{m:>21s}" for m in methods)
    lines += [head, " " * 17 + " ".join(f"{'median / p95 / mov95':>21s}" for _ in methods)]
    for body, level in keys:
        sel = [r for r in rows if r["body"] == body and r["level"] == level]
        cells = []
        for meth in methods:
            if meth not in sel[0]["methods"]:
                cells.append("-")
                continue
            # pool the seeds: medians of the per-seed figures
            med = np.median([r["methods"][meth]["median_ms"] for r in sel])
            p95 = np.median([r["methods"][meth]["p95_ms"] for r in sel])
            mov = np.median([r["methods"][meth]["moving_p95_ms"] for r in sel])
            cells.append(f"{med:6.1f} /{p95:6.0f} /{mov:5.0f}")
        lines.append(f"{body:10s} {level:5s} " + " ".join(f"{c:>21s}" for c in cells))
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bodies", default="mocapbank,cmu")
    ap.add_argument("--levels", default=",".join(LEVELS))
    ap.add_argument("--seeds", default="0-5", help="e.g. 0-5 or 0,3")
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--fingers", action="store_true", help="also GT-2: real fingers through the spliced BVH")
    ap.add_argument("--json", help="write every row here")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    if "-" in args.seeds:
        a, b = args.seeds.split("-")
        seeds = list(range(int(a), int(b) + 1))
    else:
        seeds = [int(s) for s in args.seeds.split(",")]
    methods = tuple(args.methods.split(","))
    rows = []
    for body in args.bodies.split(","):
        if not BODIES[body].is_file():
            print(f"skip {body}: {BODIES[body]} not found", file=sys.stderr)
            continue
        for level in args.levels.split(","):
            for seed in seeds:
                rows.append(evaluate(body, level, seed, methods))
                print(f"  {body} {level} seed {seed}: " + ", ".join(
                    f"{k} {v['median_ms']:.0f}/{v['p95_ms']:.0f}" for k, v in rows[-1]["methods"].items()),
                    file=sys.stderr, flush=True)
    print("hand-time error per body frame, ms (median over seeds of each seed's median / p95 / moving-frame p95)")
    print(_table(rows, methods))
    finger_rows = []
    if args.fingers:
        print("\nGT-2: finger rotations carried through the warp and spliced.bvh, geodesic error per joint, degrees")
        print(f"{'level':5s} {'seed':>4s} {'mean':>6s} {'p95':>6s}   uniform mean / p95")
        for level in ("L2", "L4"):
            for seed in seeds:
                r = evaluate_fingers(level, seed)
                finger_rows.append(r)
                print(f"{level:5s} {seed:4d} {r['mean_deg']:6.2f} {r['p95_deg']:6.2f}   "
                      f"{r['uniform_mean_deg']:6.2f} / {r['uniform_p95_deg']:6.2f}", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps({"timing": rows, "fingers": finger_rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
