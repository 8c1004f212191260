"""Finger gaits in synthesized results: which fingers relocate, which roll, and a contact timeline per solution.

    python scripts/gait_report.py out/cup-spin [--solutions 3] [--plot out/cup-spin/gait.png] [--json F]

Reads only the result files (the solutions, the hand files beside them, the scene). Per finger, its contact is the
set of active contact slots on its links, its point the mean of those points, taken in the object's frame and in
the frame of the finger's most distal touching link; a run is a stretch of frames in contact, split into static
stretches by the frames the solution marks sliding.

A finger **relocates** when a run ends and a later run of the same finger begins at least ``--relocate`` (default
1 cm) away on the object: it let go and came back elsewhere. A static stretch (three frames or more) **rolls** when
the contact moves on the finger (``--roll``, default 3 mm, within a phalanx, or onto another phalanx) while moving
less than half as far on the object, or moves on the object while staying on the finger. Distances are how far the
point gets from where the stretch began (the per-frame points jitter with the surface sampling; path lengths would
add that up). The plot draws, per finger, its runs (static grey, sliding orange, rolling without slipping blue)
with a mark at every relocation.

A stretch **rolls without slipping** when the contact moves at least ``--roll`` on both the finger and the object
while the finger's material point at the contact slips less than half as far on the object (summed frame to
frame). Between smooth surfaces rolling without slipping moves the contact equally far on both, so the rule above
(one surface only) is met only by slipping: a contact creeping on the object slower than the sliding threshold
(2 cm/s) is not flagged sliding and can pass it. Both are reported.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from torchhand.io.result import SIDES, load_result


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) of the runs of True in ``mask`` (T,)."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.nonzero(edges == 1)[0].tolist(), np.nonzero(edges == -1)[0].tolist()))


def _reach(p: np.ndarray) -> float:
    """How far a point track (n, 3) gets from where it started, metres (not its path length: the per-frame contact
    points jitter by the surface sampling, and that would add up)."""
    return float(np.linalg.norm(p - p[0], axis=-1).max()) if len(p) > 1 else 0.0


def finger_tracks(result, sol) -> list[dict]:
    """Per hand finger: its contact mask (T,), object-frame point (T, 3), link-frame point (T, 3) and touching link
    (T,) (-1 where free), and the sliding flag (T,)."""
    side_idx, name_idx = sol.contact_side_link()
    names = sol.contact_link_names()
    obj_inv = np.linalg.inv(sol.object_pose)
    tracks = []
    for hand in sol.hands:
        model = result.hand_models[hand.side]
        to_model = np.array([model.link_names.index(n) if n in model.link_names else -1 for n in names] + [-1])
        link_idx = np.where(side_idx == SIDES.index(hand.side), to_model[name_idx], -1)          # (T, K)
        poses = model.forward_kinematics(torch.as_tensor(hand.q), torch.as_tensor(hand.root_pose)).double().numpy()
        for f, links in enumerate(model.finger_links.tolist()):
            links = [x for x in links if x >= 0]
            on_slot = sol.contact_mask & np.isin(link_idx, links)                                     # (T, K)
            mask = on_slot.any(1)
            T = sol.T
            p_obj, p_link = np.zeros((T, 3)), np.zeros((T, 3))
            link = np.full(T, -1)
            slide = np.zeros(T, bool)
            for t in np.nonzero(mask)[0]:
                k = np.nonzero(on_slot[t])[0]
                p = sol.contact_point[t, k].mean(0)
                p_obj[t] = obj_inv[t, :3, :3] @ p + obj_inv[t, :3, 3]
                link[t] = max(link_idx[t, k], key=links.index)                               # most distal
                L = np.linalg.inv(poses[t, link[t]])
                p_link[t] = L[:3, :3] @ p + L[:3, 3]
                slide[t] = bool(sol.contact_sliding[t, k].any())
            tracks.append({"hand": hand.side, "finger": model.finger_names[f], "mask": mask, "p_obj": p_obj,
                           "p_link": p_link, "link": link, "slide": slide,
                           "slip": _slip(poses, obj_inv, mask, link, p_link)})
    return tracks


def _slip(poses: np.ndarray, obj_inv: np.ndarray, mask: np.ndarray, link: np.ndarray, p_link: np.ndarray):
    """Per frame t, how far the finger's material point that touched at t - 1 moved on the object from t - 1 to t,
    metres (T,), 0 where the finger did not touch at both frames. Rolling without slipping moves the contact on
    both surfaces while this stays near zero; sliding moves it."""
    out = np.zeros(len(mask))
    for t in np.nonzero(mask[1:] & mask[:-1])[0] + 1:
        x = np.append(p_link[t - 1], 1.0)
        a = obj_inv[t - 1] @ poses[t - 1, link[t - 1]] @ x
        b = obj_inv[t] @ poses[t, link[t - 1]] @ x
        out[t] = float(np.linalg.norm(a[:3] - b[:3]))
    return out


def _static_stretches(slide: np.ndarray, a: int, b: int) -> list[tuple[int, int]]:
    return [(a + s, a + e) for s, e in _runs(~slide[a:b])]


def _rolls(track: dict, a: int, b: int, roll: float) -> dict:
    """Whether the static stretch [a, b) of a run rolls: the contact moves on the finger (``roll`` metres within a
    phalanx, or onto another phalanx) while it moves less than half that on the object, or the reverse."""
    link = track["link"][a:b]
    cuts = [0] + (np.nonzero(np.diff(link))[0] + 1).tolist() + [b - a]
    on_finger = max(_reach(track["p_link"][a + s:a + e]) for s, e in zip(cuts[:-1], cuts[1:]))
    phalanx = len(cuts) > 2
    on_obj = _reach(track["p_obj"][a:b])
    finger_moves = on_finger >= roll or phalanx
    rolls = b - a >= 3 and ((finger_moves and on_obj < 0.5 * max(on_finger, roll)) or
                            (on_obj >= roll and on_finger < 0.5 * on_obj and not phalanx))
    slip = float(track["slip"][a + 1:b].sum())
    no_slip = b - a >= 3 and finger_moves and on_obj >= roll and slip < 0.5 * min(on_finger, on_obj)
    return {"start": a, "stop": b, "on_object_m": on_obj, "on_finger_m": on_finger, "phalanx_change": phalanx,
            "slip_m": slip, "rolls": bool(rolls), "rolls_without_slip": bool(no_slip)}


def analyse(track: dict, relocate: float, roll: float) -> dict:
    """The runs of one finger, its relocations and its rolling stretches (module docstring)."""
    runs, relocations = [], []
    for a, b in _runs(track["mask"]):
        stretches = [_rolls(track, s, e, roll) for s, e in _static_stretches(track["slide"], a, b)]
        runs.append({"start": a, "stop": b, "sliding_share": float(track["slide"][a:b].mean()),
                     "stretches": stretches, "rolls": any(x["rolls"] for x in stretches),
                     "rolls_without_slip": any(x["rolls_without_slip"] for x in stretches)})
        if len(runs) > 1:
            gap = float(np.linalg.norm(track["p_obj"][a] - track["p_obj"][runs[-2]["stop"] - 1]))
            if gap >= relocate:
                relocations.append({"frame": a, "distance_m": gap})
    return {"hand": track["hand"], "finger": track["finger"], "runs": runs, "relocations": relocations,
            "relocates": bool(relocations), "rolls": any(r["rolls"] for r in runs),
            "rolls_without_slip": any(r["rolls_without_slip"] for r in runs)}


def plot_gaits(per_solution: list[list[dict]], tracks: list[list[dict]], path: Path) -> Path:
    """One panel per solution: per finger, its runs (static grey, sliding orange, rolling blue) and relocations."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from torchhand.fill.reference import save_png

    fig, axes = plt.subplots(len(per_solution), 1, figsize=(9, 1.6 + 0.35 * len(per_solution[0])) if
                             len(per_solution) == 1 else (9, 2.2 * len(per_solution)), squeeze=False)
    for i, (ax, fingers, trk) in enumerate(zip(axes[:, 0], per_solution, tracks)):
        for row, (fa, tr) in enumerate(zip(fingers, trk)):
            for run in fa["runs"]:
                ax.broken_barh([(run["start"], run["stop"] - run["start"])], (row - 0.35, 0.7), color="#fd8d3c")
                for x in run["stretches"]:
                    ax.broken_barh([(x["start"], x["stop"] - x["start"])], (row - 0.35, 0.7),
                                   color="#3182bd" if x["rolls_without_slip"] else "#bdbdbd")
            for r in fa["relocations"]:
                ax.plot(r["frame"], row, marker="v", color="#b00", ms=7)
        ax.set_yticks(range(len(fingers)), [f"{f['hand'][0]} {f['finger']}" for f in fingers], fontsize=8)
        ax.set_xlim(0, len(trk[0]["mask"]))
        ax.set_title(f"solution {i}: grey static, orange sliding, blue rolling without slipping; red: relocation",
                     fontsize=8)
    axes[-1, 0].set_xlabel("frame")
    return save_png(fig, path, dpi=100)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("result", type=Path)
    ap.add_argument("--solutions", type=int, default=3)
    ap.add_argument("--relocate", type=float, default=0.01, help="metres on the object (default 0.01)")
    ap.add_argument("--roll", type=float, default=0.003, help="metres on one surface (default 0.003)")
    ap.add_argument("--plot", type=Path, default=None)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    result = load_result(args.result)
    n = min(args.solutions, len(result.solution_files))
    if n == 0:
        print(f"{args.result}: no solutions", file=sys.stderr)
        return 1
    tracks = [finger_tracks(result, result.solution(i)) for i in range(n)]
    per_solution = [[analyse(t, args.relocate, args.roll) for t in trk] for trk in tracks]
    for i, fingers in enumerate(per_solution):
        moves = [f["finger"] for f in fingers if f["relocates"]]
        rolls = [f["finger"] for f in fingers if f["rolls"]]
        free = [f["finger"] for f in fingers if f["rolls_without_slip"]]
        print(f"solution {i}: relocating: {', '.join(moves) or 'none'}; rolling: {', '.join(rolls) or 'none'}; "
              f"rolling without slipping: {', '.join(free) or 'none'}")
    every = all(any(f["relocates"] for f in s) and any(f["rolls"] for f in s) for s in per_solution)
    print(f"every solution has a relocating and a rolling finger: {every}")
    every = all(any(f["relocates"] for f in s) and any(f["rolls_without_slip"] for f in s) for s in per_solution)
    print(f"every solution has a relocating finger and one rolling without slipping: {every}")
    if args.plot:
        print(f"wrote {plot_gaits(per_solution, tracks, args.plot)}")
    if args.json:
        args.json.write_text(json.dumps(per_solution, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
