"""``torchhand inspect SCENE --out DIR``: load a scene, build its hands and the object's SDF, and check them.

For every frame the hands are posed at rest on their wrist trajectories; the job reports how far each fingertip is
from the object's surface, the deepest hand–object penetration, finger–finger interpenetration and the
object–table contacts, and writes the exported scene, the hand MJCF and ``inspect.json`` to DIR.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import torch

from ..errors import InputValueError
from ._common import add_threads_argument, apply_threads


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("inspect", help="check a scene: hands at rest along the wrists, SDF, contacts",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene", help="a built-in scene name (see `torchhand scene list`) or a scene directory")
    p.add_argument("--out", required=True, help="output directory (created; files in it are replaced)")
    p.add_argument("--voxel", type=float, default=0.002, help="SDF voxel size in metres (default 0.002)")
    p.add_argument("--device", default="cpu", choices=["cpu", "cuda"], help="device (default cpu)")
    p.add_argument("--dtype", default="float32", choices=["float32", "float64"], help="dtype (default float32)")
    p.add_argument("--no-progress", action="store_true", help="hide progress bars")
    add_threads_argument(p)
    p.set_defaults(func=run)


def run(args) -> int:
    apply_threads(args.threads)
    from tqdm import tqdm

    from ..hand.collision import finger_interpenetration, hand_object_penetration
    from ..hand.mount import track_hand
    from ..hand.mjcf import save_mjcf
    from ..scene import environment_contacts, load_scene
    from ..geometry.sdf import SDFGrid

    if args.device == "cuda" and not torch.cuda.is_available():
        raise InputValueError("--device cuda: no CUDA device is available; use --device cpu")
    dtype = getattr(torch, args.dtype)
    out = Path(args.out)
    t0 = time.perf_counter()
    scene = load_scene(args.scene)  # before anything is written: a bad scene leaves no output behind
    # disable=None: the bar shows only on a terminal.
    steps = tqdm(total=5, desc="inspect", unit="step", disable=True if args.no_progress else None)
    out.mkdir(parents=True, exist_ok=True)
    scene.export(out / "scene", overwrite=True)
    steps.update()

    hands = {track.side: track_hand(track) for track in scene.hands}
    for side, hand in hands.items():
        save_mjcf(hand, out / ("hand.xml" if side == scene.hands[0].side else f"hand_{side}.xml"))
    steps.update()

    t_sdf = time.perf_counter()
    sdf = SDFGrid.from_mesh(scene.object.mesh, args.voxel, progress=not args.no_progress and sys.stderr.isatty()).to(args.device, dtype)
    t_sdf = time.perf_counter() - t_sdf
    steps.update()

    object_pose = scene.object_pose.to(args.device, dtype)
    report = {"scene": scene.name, "frames": scene.T, "fps": scene.fps, "duration_s": scene.duration,
              "object": {"mass_kg": scene.object.mass, "extent_m": [float(v) for v in scene.object.mesh.extents],
                         "watertight": bool(scene.object.watertight)},
              "sdf": {"voxel_m": args.voxel, "shape": list(sdf.shape), "build_or_load_s": round(t_sdf, 3)},
              "hands": {}}
    t_fk = time.perf_counter()
    for track in scene.hands:
        hand = hands[track.side].to(args.device, dtype)
        root = track.wrist_pose.to(args.device, dtype)
        q = hand.q_rest.expand(scene.T, -1)
        links = hand.forward_kinematics(q, root)
        pen = hand_object_penetration(hand, links, sdf, object_pose)
        # Fingertip pads: signed distance of the pad point of each finger to the object.
        tip_links = links[:, hand.distal_link]  # (T, F, 4, 4)
        tips = (tip_links[..., :3, :3] @ hand.fingertip.unsqueeze(-1)).squeeze(-1) + tip_links[..., :3, 3]
        inv = torch.linalg.inv(object_pose)
        tips_obj = (inv[:, None, :3, :3] @ tips.unsqueeze(-1)).squeeze(-1) + inv[:, None, :3, 3]
        tip_sd = sdf.query(tips_obj)  # (T, F)
        ff = finger_interpenetration(hand, links)
        report["hands"][track.side] = {
            "fingers": list(hand.finger_names),
            "fingertip_distance_min_m": [round(float(v), 5) for v in tip_sd.min(0).values],
            "fingertip_distance_mean_m": [round(float(v), 5) for v in tip_sd.mean(0)],
            "max_penetration_m": round(float((-pen.sd).clamp(min=0).max()), 5),
            "frames_penetrating": int((pen.deepest_value.min(-1).values < 0).sum()),
            "max_finger_interpenetration_m": round(float(ff.clamp(min=0).max()) if ff.numel() else 0.0, 5),
        }
    t_fk = time.perf_counter() - t_fk
    steps.update()

    env = environment_contacts(scene)
    report["environment"] = {"table": scene.environment.table, "floor": scene.environment.floor,
                             "frames_with_table_contact": int((env.count > 0).sum()),
                             "max_contacts": int(env.count.max()) if env.count.numel() else 0}
    report["timing_s"] = {"total": round(time.perf_counter() - t0, 3), "kinematics_and_collision": round(t_fk, 4)}
    tmp = out / "inspect.json.tmp"
    tmp.write_text(json.dumps(report, indent=2))
    os.replace(tmp, out / "inspect.json")
    steps.update()
    steps.close()

    print(f"scene {scene.name}: {scene.T} frames at {scene.fps:g} fps, object {scene.object.mass:.3f} kg, "
          f"SDF {tuple(sdf.shape)} at {args.voxel * 1000:g} mm")
    for side, h in report["hands"].items():
        dist = ", ".join(f"{f} {d * 1000:.0f}" for f, d in zip(h["fingers"], h["fingertip_distance_min_m"]))
        print(f"  {side} hand at rest: closest fingertip approach (mm): {dist}; max penetration "
              f"{h['max_penetration_m'] * 1000:.1f} mm in {h['frames_penetrating']} frames")
    print(f"  table contact in {report['environment']['frames_with_table_contact']} of {scene.T} frames")
    print(f"wrote {out}/scene/, {out}/hand.xml, {out}/inspect.json")
    return 0
