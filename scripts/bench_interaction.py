"""Time the quasi-static interaction step (torchhand.interaction.step.quasi_static_step), all stages included.

``python scripts/bench_interaction.py [--batch 64] [--repeats 15] [--threads 1] [--device cpu|cuda] [--json OUT]``

Scenes (the tests' builders, tests/torchhand/test_step.py):

- ``comb5``: five two-link fingers on a compliant root pressing a table, one contact per finger (N = 5 active
  of 12 slots, m = 4, LCP size 50), settled for 12 steps first;
- ``pinch``: two two-link fingers squeezing a free box (signed distance grid) under gravity, four contacts.

Each row times one step from the same loaded state (the step is a pure function of its inputs), median over
``--repeats`` runs, float64, CPU: B = 1 with Lemke's method (``solver="lemke"``), and B = ``--batch`` rollouts with
Lemke per rollout, with the batched projected Gauss-Seidel (``"pgs"``, tolerance 1e-7 m / N on the explicit LCP's
residual, at most 400 sweeps) and with ``"auto"`` (30 sweeps of PGS, then Lemke for the rollouts not converged).
Also: the share of the contact search (one call of ``find_contacts``). With ``--device cuda`` the scenes are built
on the CPU and moved (hand, state, compliance, object grid, references); Lemke runs per rollout on the CPU there too
(the LCPs are copied back), so the GPU rows that matter are ``pgs`` and ``auto`` at large ``--batch``. The target for one rollout is 1x real time at h = 1/120 s: <= 8.3 ms per step.
"""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import replace

import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from _timing import machine, print_table, time_fn, write_json  # noqa: E402

from tests.torchhand.test_step import comb_scene, pinch_scene, run, scene_to  # noqa: E402
from torchhand.interaction._contacts import find_contacts  # noqa: E402
from torchhand.interaction.step import quasi_static_step  # noqa: E402

COLUMNS = ["scene", "device", "B", "solver", "contacts", "ms_per_step", "iqr_ms", "rollout_steps_per_s", "contact_search_ms",
           "status_ok"]


def _case(scene: str, B: int, solver: str, device: str = "cpu", **options):
    if scene == "comb5":
        hand, state, C, env, settings, ref = comb_scene(B, "lemke")
        obj = None
    else:
        hand, state, C, obj, settings, ref = pinch_scene(B, "lemke")
        env = None
    hand, state, C, obj, ref = scene_to(device, hand, state, C, obj, ref)
    settings = replace(settings, solver=solver, **options)
    state, _ = run(state, hand, C, ref, 12, obj=obj, env=env, settings=settings)
    target = ref(13)

    def step():
        return quasi_static_step(state, hand, target, state.root_r, C, obj, env, settings)

    def contacts():
        return find_contacts(hand, state.q, state.root, sdf=None if obj is None else obj.sdf,
                             object_pose=state.object_pose if obj is not None else None, plane=env,
                             margin=settings.margin, geometry=settings.geometry)

    return step, contacts


def bench(scene: str, B: int, solver: str, repeats: int, device: str = "cpu", **options) -> dict:
    step, contacts = _case(scene, B, solver, device, **options)
    _, rep = step()
    t = time_fn(step, device, repeats=repeats, warmup=2)
    tc = time_fn(contacts, device, repeats=repeats, warmup=2)
    label = solver + "".join(f" {k}={v}" for k, v in options.items())
    return {"scene": scene, "device": device, "B": B, "solver": label, "contacts": float(rep.n_contacts.double().mean()),
            "ms_per_step": 1e3 * t["median_s"], "iqr_ms": 1e3 * t["iqr_s"],
            "rollout_steps_per_s": B / t["median_s"], "contact_search_ms": 1e3 * tc["median_s"],
            "status_ok": f"{int((rep.status == 0).sum())}/{B}"}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--batch", type=int, default=64)
    p.add_argument("--repeats", type=int, default=15)
    p.add_argument("--threads", type=int, default=1, help="torch intra-op threads (0: torch's default)")
    p.add_argument("--device", default="cpu", help="cpu or cuda (PGS and auto rows on the device)")
    p.add_argument("--big", type=int, nargs="*", default=[],
                   help="extra batch sizes timed with pgs and auto only (e.g. 1024 8192 on a GPU)")
    p.add_argument("--json", help="write the results here (atomically)")
    a = p.parse_args(argv)
    if a.threads:
        torch.set_num_threads(a.threads)
    out = {"machine": machine(), "command": " ".join(sys.argv), "rows": []}
    print(f"machine: {out['machine']}")
    dev = a.device
    for scene in ("comb5", "pinch"):
        out["rows"].append(bench(scene, 1, "lemke", a.repeats, dev))
        out["rows"].append(bench(scene, a.batch, "lemke", a.repeats, dev))
        for B in [a.batch, *a.big]:
            out["rows"].append(bench(scene, B, "pgs", a.repeats, dev, pgs_tol=1e-7, pgs_max_iters=400))
            out["rows"].append(bench(scene, B, "auto", a.repeats, dev, pgs_tol=1e-7, pgs_max_iters=30))
    print(f"\n[quasi-static step] float64 {dev}; target <= 8.3 ms per rollout step (h = 1/120 s)")
    print_table(out["rows"], COLUMNS)
    if a.json:
        write_json(a.json, out)
        print(f"\nwrote {a.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
