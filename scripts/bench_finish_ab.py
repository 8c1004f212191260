"""Finishing searched paths (reconstruction and the exact re-check) and pruning a seed's patch samples, checkout
against checkout, in one run.

``python scripts/bench_finish_ab.py PATHS.pt CHECKOUT [CHECKOUT ...] [--alternations 5]``
``python scripts/bench_finish_ab.py PATHS.pt --record [--scene box-turn] [--seed 0] [--count 3]``

``--record`` runs a search (one thread, the scene's default node test) and saves the first ``--count`` full paths it
finds, with the scene and seed, to PATHS.pt. Then each CHECKOUT (a source tree imported through ``PYTHONPATH``: ``.``
for the current one; an older commit: ``git worktree add /tmp/old <sha>``, then link
``/tmp/old/torchhand/kernels -> ../kernels`` and ``/tmp/old/torchhand/render -> ../render``) runs in turn,
``--alternations`` times, each in its own process with one thread: it rebuilds the seed's problem and finishes every
saved path (``finalize_solution``, the synthesis' own settings) and prunes the seed's patch samples
(``prune_patches``), the first round a warm-up, then two timed rounds. Printed per checkout and stage: the seconds
(per path; per pruning) of every alternation (the median of its rounds), their median, its ratio to the first
checkout, and a digest of what it computed (the finished motions; the samples kept), which shows whether the
checkouts compute the same.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _timing import alternate, print_ratios  # noqa: E402


def _problem(scene_name: str, seed: int):
    import torch

    from torchhand.scene import load_scene
    from torchhand.synthesis.problem import build_problem

    return build_problem(load_scene(scene_name), torch.Generator().manual_seed(seed))


def record(path: str, scene_name: str, seed: int, paths: int) -> None:
    """Search the scene and save its first full paths (as searched, before finishing)."""
    import torch

    from torchhand.synthesis import pipeline

    torch.set_num_threads(1)
    found = []
    finalize = pipeline.finalize_solution

    def keep(problem, sol, index, **kwargs):
        found.append(sol)
        return finalize(problem, sol, index, **kwargs)

    pipeline.finalize_solution = keep
    pipeline.synthesize(scene_name, seed=seed, solutions=paths)
    torch.save({"scene": scene_name, "seed": seed, "paths": found[:paths]}, path)
    print(f"saved {len(found[:paths])} paths of {scene_name} seed {seed} to {path}")


def one(path: str) -> dict:
    """This process's measurement (run under the checkout's PYTHONPATH)."""
    import time

    import torch

    torch.set_num_threads(1)
    from torchhand.synthesis.initial import prune_patches
    from torchhand.synthesis.node_test import NodeTestSettings
    from torchhand.synthesis.pipeline import finalize_solution

    saved = torch.load(path, weights_only=False)
    problem = _problem(saved["scene"], saved["seed"])
    finish, prune = [], []
    for r in range(3):
        t = time.perf_counter()
        fins = [finalize_solution(problem, sol, i, ns=NodeTestSettings())[0] for i, sol in enumerate(saved["paths"])]
        t_finish = (time.perf_counter() - t) / len(saved["paths"])
        t = time.perf_counter()
        init = prune_patches(problem, torch.Generator().manual_seed(saved["seed"]))
        t_prune = time.perf_counter() - t
        if r:
            finish.append(t_finish)
            prune.append(t_prune)
    motions = hashlib.sha256()
    for fin in fins:
        motions.update(b"none" if fin is None else fin.q.detach().cpu().numpy().tobytes())
    kept = hashlib.sha256(init.ok.cpu().numpy().tobytes())
    return {"finish_s": statistics.median(finish), "prune_s": statistics.median(prune),
            "finish_digest": motions.hexdigest()[:16], "prune_digest": kept.hexdigest()[:16]}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("paths", help="the saved paths (written by --record)")
    p.add_argument("checkouts", nargs="*", help="source trees to compare (default: the current one)")
    p.add_argument("--alternations", type=int, default=5)
    p.add_argument("--record", action="store_true", help="search and save the paths first")
    p.add_argument("--scene", default="box-turn")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--count", type=int, default=3, help="--record: paths saved (default 3)")
    p.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.record:
        record(a.paths, a.scene, a.seed, a.count)
        return 0
    if a.one:
        print(json.dumps(one(a.paths)))
        return 0
    runs = alternate(__file__, [os.path.abspath(a.paths)], a.checkouts or ["."], a.alternations,
                     env={"OMP_NUM_THREADS": "1"})
    for stage, unit in (("finish", "s per path"), ("prune", "s per pruning")):
        print_ratios(runs, f"{stage}_s", unit, f"{stage} ", lambda r: f"; digest {r[stage + '_digest']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
