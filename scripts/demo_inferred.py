"""Demo of interaction resynthesis (Kry & Pai 2006 §7-8) from an inferred interaction: a Ye & Liu ``box-turn``
solution's contact forces as the capture.

The forces are *inferred*, not measured: they are the contact forces a ``torchhand synthesize box-turn`` solution
solved for the scene's object motion (the box turned 75 degrees about the vertical while sliding on the table). The
compliance is Kry & Pai's Table 1 (exploring) for every coordinate, as the paper did for its pressure-ball capture
(§8.2), and theta_r = theta - C tau (``torchhand capture from-result``). The interaction is resynthesised on

    same             the box-turn box (9 x 7 x 6 cm, 0.25 kg): the sanity case
    smaller          the box 12 % smaller along its grasped axis (the axis the loaded contact forces push along)
    heavy            the box at 3 x its mass, without grip adjustment
    heavy-imminent   the same with the imminent-slip grip response (Sec. 8.1)
    bunny            trimesh's Stanford bunny lying on its side, as wide as the box along the grasped axis and no
                     taller, resting where the box was, 0.25 kg

Each case is a result directory under --out (``torchhand render|plot|check DIR`` work on it); the table printed at the
end gives the object's turn (and lift) against the reference solution's, the largest object slip in the hand frame,
the grip events, the time per step and ``torchhand check``'s verdict with its worst figures.

    python scripts/demo_inferred.py --out /tmp/inferred_demo [--result out/box-turn] [--frames 12:54]

Without --result it first runs ``torchhand synthesize box-turn --solutions 1`` (a few minutes on 2 cores).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

_ROOT = Path(__file__).resolve().parents[1]
BUNNY = _ROOT.parent / "shared" / "data" / "meshes" / "trimesh" / "bunny.ply"


def _cli(args: list) -> int:
    from torchhand.cli import main

    print("$ torchhand " + " ".join(args), flush=True)
    return main(args)


def loaded_frames(result: Path, solution: int) -> str:
    """The hold/turn part of a solution: from 3 frames before the first frame whose hand forces are non-zero to 3
    frames after the last one (the hand then touches the object without load at both ends)."""
    from torchhand.io.result import load_result

    sol = load_result(result).solution(solution)
    total = np.linalg.norm(sol.contact_force * sol.contact_mask[..., None], axis=-1).sum(1)
    loaded = np.flatnonzero(total > 1e-6)
    if loaded.size == 0:
        raise SystemExit(f"{result}: solution {solution} has no loaded contact")
    return f"{max(int(loaded[0]) - 3, 0)}:{min(int(loaded[-1]) + 4, sol.T)}"


def reference_friction_use(result: Path, solution: int, frames: str) -> tuple[float, float, float]:
    """|f_t| / (mu f_n) of the solution's loaded hand forces (|f| > 0.05 N) about its own contact normals, over the
    frames used: (median, max, fraction of them at 0.99 or more). 1 is the friction cone's boundary."""
    from torchhand.io.result import load_result

    res = load_result(result)
    sol = res.solution(solution)
    mu = sol.friction if sol.friction is not None else res.scene.friction
    a, b = (int(x) for x in frames.split(":"))
    f, n, m = sol.contact_force[a:b], sol.contact_normal[a:b], sol.contact_mask[a:b]
    fn = (f * n).sum(-1)
    ft = np.linalg.norm(f - fn[..., None] * n, axis=-1)
    sel = m & (np.linalg.norm(f, axis=-1) > 0.05) & (fn > 0)
    use = ft[sel] / (mu * fn[sel])
    if use.size == 0:
        return 0.0, 0.0, 0.0
    return float(np.median(use)), float(use.max()), float((use >= 0.99).mean())


def grasped_axis(inferred: Path) -> int:
    """The object-frame axis the hand's loaded contact forces push along most (sum of |f . e_a|)."""
    from torchhand.interaction.capture import load_capture

    cap = load_capture(inferred / "capture.npz")
    R = cap.object_pose[:, :3, :3]
    f_obj = np.einsum("tji,tsj->tsi", R, cap.force)          # forces in the object frame
    return int(np.argmax(np.abs(f_obj).sum(axis=(0, 1))))


def write_scene(base: Path, out: Path, *, mesh=None, name: str, description: str) -> Path:
    """The inferred interaction's scene with another object mesh (same mass, same frame-0 pose)."""
    from torchhand.geometry.objects import RigidObject
    from torchhand.scene import load_scene

    scene = load_scene(base)
    obj = RigidObject.from_trimesh(mesh, mass=scene.object.mass, name=name, repair=True)
    new = dataclasses.replace(scene, name=f"{scene.name}-{name}", object=obj,
                              description=f"{scene.description} {description}".strip())
    return new.export(out, overwrite=True)


def bunny_mesh(box, axis: int):
    """trimesh's bunny lying on its side (its up axis horizontal: upright it stands taller than the space under the
    palm), scaled so that it spans the box along the grasped axis without being taller than the box, its bottom on
    the box's bottom face and its footprint centred on the box's."""
    import trimesh

    m = trimesh.load(BUNNY, force="mesh")
    ext, bext = m.extents, box.extents
    m.apply_scale(float(min(bext[axis] / ext[axis], bext[2] / ext[2])))
    lo, hi = m.bounds
    blo, bhi = box.bounds
    m.apply_translation([0.5 * (blo[0] + bhi[0]) - 0.5 * (lo[0] + hi[0]),
                         0.5 * (blo[1] + bhi[1]) - 0.5 * (lo[1] + hi[1]), blo[2] - lo[2]])
    return m


def turn_and_lift(object_pose: np.ndarray) -> tuple[float, float]:
    """Rotation angle of the last frame relative to the first (degrees) and the rise of the origin (mm)."""
    from scipy.spatial.transform import Rotation

    rel = object_pose[-1, :3, :3] @ object_pose[0, :3, :3].T
    return (float(np.degrees(np.linalg.norm(Rotation.from_matrix(rel).as_rotvec()))),
            1e3 * float(object_pose[-1, 2, 3] - object_pose[0, 2, 3]))


def turn_lag(object_pose: np.ndarray, dt: float, ref_pose: np.ndarray, ref_fps: float) -> tuple[float, float]:
    """How far the object's turn (the rotation angle since the first frame) trails the reference's at the same time:
    (largest lag, lag at the last frame), degrees (the reference interpolated linearly in its frames)."""
    from scipy.spatial.transform import Rotation

    def angles(P):
        rel = P[:, :3, :3] @ P[0, :3, :3].T
        return np.degrees(np.linalg.norm(Rotation.from_matrix(rel).as_rotvec(), axis=-1))

    t = np.arange(len(object_pose)) * dt * ref_fps
    ref = np.interp(t, np.arange(len(ref_pose)), angles(ref_pose))
    lag = ref - angles(object_pose)
    return float(lag.max()), float(lag[-1])


def contacts_per_finger(sol, min_force: float = 0.2) -> str:
    """Per finger (its links' name prefix: palm, thumb, index, ...), the share of frames where one of its links
    pushes the object with more than ``min_force`` newtons, e.g. "palm 12% thumb 42% index 0%"."""
    names = sol.contact_link_names()
    f = np.linalg.norm(sol.contact_force, axis=-1) * sol.contact_mask              # (T, Nc)
    link = np.asarray(sol.contact_link)
    per: dict = {}
    for i, name in enumerate(names):
        finger = name.split("_")[0]
        per.setdefault(finger, np.zeros(sol.T, dtype=bool))
        per[finger] |= ((link == i) & (f > min_force)).any(-1)
    return " ".join(f"{k} {100 * v.mean():.0f}%" for k, v in per.items())


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True, help="output folder (inputs and one result directory per case)")
    p.add_argument("--result", default=None, help="a `torchhand synthesize box-turn` result (default: run one)")
    p.add_argument("--solution", type=int, default=0, help="solution index (0)")
    p.add_argument("--frames", default=None, metavar="A:B",
                   help="solution frames to use (default: the loaded part, 3 frames either side)")
    p.add_argument("--dt", type=float, default=1 / 240, help="resynthesis step, s (1/240)")
    p.add_argument("--settle-steps", type=int, default=48,
                   help="steps at the first reference before frame 0 for the bunny, which is not placed in a rest "
                        "pose, so that it comes to rest (48)")
    p.add_argument("--box-settle-steps", type=int, default=8,
                   help="the same for the boxes (8): they rest from the start, but the quasi-rigid table contacts "
                        "(StepSettings.env_compliance) sink them by their static deflection in the first step, which "
                        "the checker reads at frame 0 as an acceleration of about 3 %% of g at 0.75 kg")
    p.add_argument("--heavy", type=float, default=3.0, help="mass factor of the heavy box (3)")
    p.add_argument("--smaller", type=float, default=0.88, help="scale of the smaller box's grasped axis (0.88)")
    p.add_argument("--max-nodes", type=int, default=60000, help="synthesis budget when --result is absent")
    p.add_argument("--friction-margin", type=float, default=0.8,
                   help="`capture from-result --friction-margin`: the inferred forces re-solved inside cones of F mu "
                        "for the same object wrench (0.8; 1 replays the solution's forces, on the cone's edge)")
    p.add_argument("--object-contacts", choices=["mesh", "sdf"], default=None,
                   help="hand-object contacts of the step (default: `capture resynthesize`'s, the exact mesh)")
    p.add_argument("--overwrite", action="store_true", help="replace earlier outputs")
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args(argv)

    import trimesh

    from torchhand.check import check_result
    from torchhand.io.result import load_result
    from torchhand.scene import load_scene

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    over = ["--overwrite"] if args.overwrite else []
    thr = ["--threads", str(args.threads)]
    result = Path(args.result) if args.result else out / "box-turn"
    if args.result is None and not (result / "stats.json").is_file():
        if _cli(["synthesize", "box-turn", "--out", str(result), "--solutions", "1", "--max-nodes",
                 str(args.max_nodes), "--seed", "0", "--no-progress", *thr, *over]) != 0:
            return 1
    frames = args.frames or loaded_frames(result, args.solution)
    inferred = out / "inferred"
    if _cli(["capture", "from-result", str(result), "--solution", str(args.solution), "--frames", frames,
             "--friction-margin", f"{args.friction_margin:g}", "--out", str(inferred), *thr, *over]) != 0:
        return 1
    base = inferred / "scene"
    box = load_scene(base).object.mesh
    axis = grasped_axis(inferred)
    S = np.eye(4)
    S[axis, axis] = args.smaller
    small = trimesh.Trimesh(vertices=box.vertices @ S[:3, :3].T, faces=box.faces, process=False)
    scenes = out / "scenes"
    smaller = write_scene(base, scenes / "smaller", mesh=small, name="box-smaller",
                          description=f"Box scaled by {args.smaller:g} along object axis {'xyz'[axis]}.")
    bunny = write_scene(base, scenes / "bunny", mesh=bunny_mesh(box, axis), name="bunny",
                        description="trimesh's Stanford bunny in place of the box.")
    mass = load_scene(base).object.mass
    heavy = f"{args.heavy * mass:g}"
    inter = str(inferred / "interaction.npz")
    common = ["--dt", f"{args.dt:.10g}", "--solver", "lemke", *thr, *over]
    if args.object_contacts is not None:
        common += ["--object-contacts", args.object_contacts]
    settle = ["--settle-steps", str(args.settle_steps)]
    box = ["--settle-steps", str(args.box_settle_steps)]
    cases = [("same", base, box, "none"), ("smaller", smaller, box, "none"),
             ("heavy", base, ["--mass", heavy, *box], "none"),
             ("heavy-imminent", base, ["--mass", heavy, *box], "imminent"),
             ("bunny", bunny, settle, "none")]
    ref_result = load_result(result)
    ref, ref_fps = ref_result.solution(args.solution), ref_result.scene.fps
    use = reference_friction_use(result, args.solution, frames)
    margin = json.loads((inferred / "summary.json").read_text()).get("friction_margin") or {}
    a, b = (int(x) for x in frames.split(":"))
    ref_turn, ref_lift = turn_and_lift(ref.object_pose[a:b])
    rows = [("case", "kg", "grip", "turn deg (ref)", "lag deg max / end", "lift mm (ref)", "max slip mm",
             "grip events", "ms/step", "check", "worst: obj pen mm / cone / force / torque", "failing figures",
             "frames with a contact > 0.2 N, per finger")]
    summary = {}
    for name, scene_dir, extra, grip in cases:
        dest = out / name
        rc = _cli(["capture", "resynthesize", inter, "--scene", str(scene_dir), "--out", str(dest), "--grip", grip,
                   *extra, *common])
        stats = json.loads((dest / "stats.json").read_text()) if (dest / "stats.json").is_file() else {}
        roll = (stats.get("rollouts") or [{}])[0]
        kg = extra[1] if extra[:1] == ["--mass"] else f"{mass:g}"
        if rc != 0 or roll.get("status") != "COMPLETED":
            rows.append((name, kg, grip, "-", "-", "-", "-", "-", f"{stats.get('per_step_ms', float('nan')):.1f}",
                         f"stopped at step {roll.get('failed_step')} ({roll.get('failed_status')})", "-", "-", "-"))
            summary[name] = {"completed": False, "rollout": roll}
            continue
        res = load_result(dest)
        sol = res.solution(0)
        turn, lift = turn_and_lift(sol.object_pose)
        rep = check_result(dest)
        sc = rep.solutions[0]
        f = sc.figures
        failing = [n for n, x in f.items() if not x.ok]
        worst = (f"{1e3 * f['object_penetration_m'].value:.1f} / {f['cone_violation'].value:.1e} / "
                 f"{f['force_error'].value:.4f} / {f['torque_error'].value:.4f}")
        lag_max, lag_end = turn_lag(sol.object_pose, args.dt, ref.object_pose[a:b], float(ref_fps))
        fingers = contacts_per_finger(sol)
        rows.append((name, kg, grip, f"{turn:.1f} ({ref_turn:.1f})", f"{lag_max:.1f} / {lag_end:.1f}",
                     f"{lift:.1f} ({ref_lift:.1f})", f"{1e3 * roll['max_object_slip_m']:.1f}",
                     str(roll["grip_events"]), f"{stats['per_step_ms']:.1f}", "pass" if sc.passed else "FAIL", worst,
                     ", ".join(failing) or "-", fingers))
        summary[name] = {"completed": True, "turn_deg": turn, "lag_deg_max": lag_max, "lag_deg_end": lag_end,
                         "contacts_per_finger": fingers, "lift_mm": lift, "ref_turn_deg": ref_turn,
                         "max_slip_mm": 1e3 * roll["max_object_slip_m"], "grip_events": roll["grip_events"],
                         "per_step_ms": stats["per_step_ms"], "check_passed": sc.passed,
                         "figures": {n: {"value": x.value, "limit": x.limit, "frame": x.frame, "where": x.where}
                                     for n, x in f.items()}}
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    table = "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows)
    print(f"\nsource: inferred (the forces of {result} solution {args.solution}, frames {frames}; Table 1 "
          f"exploring compliance); step {1e3 * args.dt:.2f} ms, Lemke\nreference: loaded hand forces use "
          f"|f_t| / (mu f_n) = {use[0]:.2f} (median), {use[1]:.2f} (max); {100 * use[2]:.0f} % of them lie on the "
          f"friction cone's boundary\ninferred forces: re-solved inside cones of {margin.get('margin', 1.0):g} mu "
          f"for the same object wrench in {margin.get('resolved', 0)} of {margin.get('frames', 0)} loaded frames "
          f"(largest |f_t| / (mu f_n) there {margin.get('use_resolved', use[1]):.2f}; "
          f"{margin.get('use_after', use[1]):.2f} with the frames that kept theirs)\n{table}")
    (out / "summary.json").write_text(json.dumps({"frames": frames, "result": str(result), "cases": summary,
                                                  "friction_margin": margin,
                                                  "reference_friction_use": {"median": use[0], "max": use[1],
                                                                             "on_boundary": use[2]}},
                                                 indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
