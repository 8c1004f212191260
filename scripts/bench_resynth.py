"""Per-step time of one quasi-static resynthesis rollout (Kry & Pai 2006) with a whole hand, in three contact set-ups.

``python scripts/bench_resynth.py INFERRED_DIR [--dt 1/120] [--repeats 3] [--threads 1] [--json OUT]``

INFERRED_DIR is the output of ``torchhand capture from-result`` (its ``interaction.npz`` and ``scene/``), e.g. the
``inferred`` folder that ``scripts/demo_inferred.py`` writes. Each row runs ``resynthesize`` on that interaction and
scene (Lemke, float64, one rollout) at steps of ``--dt`` seconds (default 1/120: real time at 120 Hz is a step of
1/120 s done within 1/120 s; ``--dt 0`` steps at the scene's frame rate) and reports, over ``--repeats`` runs, the
median of each run's median step time (``median_ms``) and of each run's mean step time (``ms_per_step``), the rows
interleaved (each repeat runs every row once):

- the default: link capsules against the exact mesh, finger-finger contact slots;
- the same with Lemke's method from scratch every step (the reference for the warm start, in the same run);
- the exact mesh without finger-finger slots;
- the paper's set-up: an SDF grid (1 mm) and no finger-finger slots.

Real time at 120 Hz is <= 8.3 ms per step (``x_real_time_120hz``: 8.33 ms over the median step). ``--breakdown`` profiles one more run of each row and prints where a
step's time goes (wall-clock milliseconds per step spent in the stages of ``STAGES``, each timed in place).

``--variants N`` adds the batched variants: N rollouts of the default set-up (masses 0.5-2x the object's, frictions
0.6-1.2x the scene's, compliance scales 0.5-1.5, spread over the N) as one batched step, against the same N run
one at a time (the reference, in the same run), in rollout-steps per second; it also prints how far each batched
rollout's motion is from its run alone (max |q| and object-position difference).
"""

from __future__ import annotations

import argparse
import importlib
import os
import statistics
import sys

import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _timing import machine, print_table, write_json  # noqa: E402

from torchhand.interaction.resynth import ResynthSettings, Variant, load_interaction, resynthesize  # noqa: E402
from torchhand.scene import load_scene  # noqa: E402

CASES = (("exact mesh + finger-finger slots (default)", {}),
         ("the same, Lemke from scratch every step (reference)", {"lemke_warm": False}),
         ("exact mesh, no finger-finger slots", {"self_contacts": False}),
         ("SDF 1 mm, no finger-finger slots", {"object_contacts": "sdf", "self_contacts": False}))
# where a step's time goes (--breakdown): wall time spent in these functions, per step; each is timed where its
# callers look it up (module, name)
STAGES = (("contact search (step 9)", "torchhand.interaction.step", "_find_slots"),
          ("  of it: finger-finger pairs", "torchhand.interaction._contacts", "_self_slots"),
          ("  of it: capsules vs the exact mesh", "torchhand.interaction._contacts", "_object_capsules"),
          ("G, U_phi, s' (steps 2-7)", "torchhand.interaction.step", "step_terms"),
          ("LCP assembly", "torchhand.interaction.step", "compact_problem"),
          ("LCP solve", "torchhand.interaction.step", "_solve"),
          ("  of it: Lemke's pivoting", "torchhand.solvers.lcp", "lemke"),
          ("  of it: warm start", "torchhand.interaction.step", "_warm"),
          ("integration (step 8)", "torchhand.interaction.step", "_advance"),
          ("predicted motion, report", "torchhand.interaction.step", "predicted_motion"))


def breakdown(run, steps: int) -> dict:
    """Milliseconds per step spent in each stage of ``STAGES`` during one ``run()``: each function is wrapped by a
    wall-clock timer for the run (a few microseconds per call; unlike a profiler, the code itself runs unchanged)."""
    import time

    spent = {stage: 0.0 for stage, _, _ in STAGES}
    saved = []

    def timed(stage, fn):
        def wrapper(*args, **kwargs):
            t = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                spent[stage] += time.perf_counter() - t
        return wrapper

    for stage, module, name in STAGES:
        mod = importlib.import_module(module)
        saved.append((mod, name, getattr(mod, name)))
        setattr(mod, name, timed(stage, getattr(mod, name)))
    try:
        run()
    finally:
        for mod, name, fn in reversed(saved):
            setattr(mod, name, fn)
    return {stage: 1e3 * t / steps for stage, t in spent.items()}


def spread_variants(n: int, mass: float, friction: float) -> tuple:
    """n variants with masses 0.5-2x ``mass``, frictions 0.6-1.2x ``friction`` and compliance scales 0.5-1.5, each
    spread evenly over the n in a different order (so that no two variants are alike)."""
    u = [(i + 0.5) / n for i in range(n)]
    return tuple(Variant(mass=mass * (0.5 + 1.5 * u[i]), friction=friction * (0.6 + 0.6 * u[(7 * i + 3) % n]),
                         compliance_scale=0.5 + u[(11 * i + 5) % n]) for i in range(n))


def variant_rows(inter, scene, n: int, dt) -> tuple[list, dict]:
    """The batched variants against one at a time (module docstring): two rows and the batch/alone differences."""
    import time

    import numpy as np

    vs = spread_variants(n, scene.object.mass, scene.friction)
    t = time.perf_counter()
    batch = resynthesize(inter, scene, variants=vs, settings=ResynthSettings(dt=dt))
    t_batch = time.perf_counter() - t
    steps = int(batch.rollouts[0].q.shape[0])
    t_alone, dq, dp = 0.0, 0.0, 0.0
    for b, v in enumerate(vs):
        t = time.perf_counter()
        alone = resynthesize(inter, scene, variants=(v,), settings=ResynthSettings(dt=dt)).rollouts[0]
        t_alone += time.perf_counter() - t
        mine = batch.rollouts[b]
        dq = max(dq, float(np.abs(np.asarray(mine.q) - np.asarray(alone.q)).max()))
        pos = np.asarray(mine.object_pose)[:, :3, 3] - np.asarray(alone.object_pose)[:, :3, 3]
        dp = max(dp, float(np.abs(pos).max()))
    done = sum(r.ok for r in batch.rollouts)
    rows = [{"contacts": f"{n} variants, one batched step", "steps": steps, "rollout_steps_per_s": n * steps / t_batch,
             "completed": f"{done}/{n}"},
            {"contacts": f"the {n} variants one at a time (reference)", "steps": steps,
             "rollout_steps_per_s": n * steps / t_alone}]
    rows[0]["x_one_at_a_time"] = rows[0]["rollout_steps_per_s"] / rows[1]["rollout_steps_per_s"]
    return rows, {"max_q_diff_rad": dq, "max_object_position_diff_m": dp}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("inferred", help="output directory of `torchhand capture from-result`")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--dt", default="1/120", help="step, seconds, e.g. 0.00833 or 1/120 (0: the scene's frame time)")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--json", help="write the results here (atomically)")
    p.add_argument("--breakdown", action="store_true", help="print where a step's time goes, per row")
    p.add_argument("--variants", type=int, default=0, metavar="N",
                   help="also time N variants as one batch against one at a time (module docstring)")
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    num, _, den = a.dt.partition("/")
    dt = float(num) / float(den or 1)
    dt = dt if dt > 0 else None
    inter = load_interaction(os.path.join(a.inferred, "interaction.npz"))
    scene = load_scene(os.path.join(a.inferred, "scene"))
    rows = []
    times = {name: [] for name, _ in CASES}
    medians = {name: [] for name, _ in CASES}
    last = {}
    for _ in range(a.repeats):         # the rows interleaved, so that a busy spell of the machine hits them all
        for name, options in CASES:
            last[name] = resynthesize(inter, scene, settings=ResynthSettings(dt=dt, **options))
            times[name].append(last[name].timings["per_step_ms"])
            medians[name].append(last[name].timings["median_step_ms"])
    for name, options in CASES:
        times_, r = times[name], last[name].rollouts[0]
        med = statistics.median(medians[name])
        rows.append({"contacts": name, "steps": int(r.q.shape[0]), "median_ms": med,
                     "ms_per_step": statistics.median(times_), "spread_ms": max(times_) - min(times_),
                     "x_real_time_120hz": (1e3 / 120) / med, "status": r.status.name})
        if a.breakdown:
            rows[-1]["stages_ms"] = breakdown(lambda: resynthesize(inter, scene,
                                                                   settings=ResynthSettings(dt=dt, **options)),
                                              int(r.q.shape[0]))
    info = machine()
    print(f"machine: {info}; step {'1/fps of the scene' if dt is None else f'{dt:.6g} s'}")
    print_table(rows, ["contacts", "steps", "median_ms", "ms_per_step", "spread_ms", "x_real_time_120hz", "status"])
    for row in rows:
        if "stages_ms" in row:
            print(f"\n{row['contacts']}: ms per step, by stage")
            for stage, ms in row["stages_ms"].items():
                print(f"  {stage:<40} {ms:8.2f}")
    extra = {}
    if a.variants > 0:
        vrows, extra = variant_rows(inter, scene, a.variants, dt)
        print()
        print_table(vrows, ["contacts", "steps", "rollout_steps_per_s", "x_one_at_a_time", "completed"])
        print(f"batched against alone: max |q| difference {extra['max_q_diff_rad']:.2e} rad, object position "
              f"{extra['max_object_position_diff_m']:.2e} m")
        rows += vrows
    if a.json:
        write_json(a.json, {"machine": info, "command": " ".join(sys.argv), "dt": dt, "rows": rows, **extra})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
