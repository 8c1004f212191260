"""Contact-sampling synthesis benchmarks: node-test throughput and Ye & Liu's Table 1 on our scenes.

``nodes``: the batched node test (kinematic + dynamic test of one frame, :func:`run_node_test`) on ``box-turn`` at
a frame of the hold, every candidate guiding all five fingers to pruned patch samples (five IK targets,
penetration resolution, a force solve with up to 20 hand and 4 table contacts), warm-started from the previous
frame's solve as in the search. Rows at several batch
sizes N, median of ``repeats`` runs, with (on the CPU) what one call launches, counted (:func:`launch_counts`:
``ops`` eager, ``launches`` and ``syncs`` on the GPU's paths with their loops as graph replays; on a GPU the
row has the graph captures and replays instead); the reference in the same run is the same test one candidate at a time
(N = 1 in a Python loop), and the paper's figure (about 5 node tests per second: 200 ms kinematic + 5-10 ms
dynamic test per frame, 2.8 GHz Core 2 Duo) is printed beside it.

``scenes``: ``torchhand synthesize`` on each scene with a node budget (default 60000 node tests: the same run on
any machine), the Table 1 columns of each run, the in-search node-test rate beside the one-at-a-time rate measured
in the same run (and the paper's), and the independent checks (:mod:`torchhand.check`) of every solution written.

    python scripts/bench_synthesis.py nodes --json bench_nodes.json [--hands default shadow allegro]
    python scripts/bench_synthesis.py scenes --max-nodes 60000 --json bench_scenes.json
    python scripts/bench_synthesis.py hands --max-nodes 40000 --json bench_hands.json [--hands shadow leap ...]

``batch``: K seeds of a scene (``--batch-seeds 16``, ``--solutions 3``, ``--max-nodes``) as one batched run
(``synthesize --seeds``) against the same K runs one at a time, in the same process: the ratio of the times, jobs per
hour, whether each seed's files are identical to its alone run's, and the checks of every result.

    python scripts/bench_synthesis.py batch --scenes box-turn --batch-seeds 16 --solutions 3 --max-nodes 2000

``hands``: each robot hand of the shared data (no sidecar; the mount fitted, docs/hand_model.md) on ``cube-turn``
(``--hand-scenes``), the same columns and checks, with the fitted mount.

``fill``: the windows of a real capture (ManipNet mug1's ``--fill-frames``, ``--fill-window``, ``--max-nodes`` per
window, ``--stall-nodes``, ``--solutions`` variants) searched together as ``torchhand fill`` does with one process,
against each window alone, in the same process: the ratio of the times and whether every window's run is its
alone run.

    python scripts/bench_synthesis.py fill --fill-frames 290:420 --max-nodes 900 --stall-nodes 300 --solutions 2

``finish``: the finishing of ``--solutions`` paths that one search of a scene found (``--scenes``, ``--seeds``),
one path after another against all side by side (each step's work of every path as one batch), ``--repeats``
alternations: the ratio of the medians and whether every path's result is its alone one.

    python scripts/bench_synthesis.py finish --scenes box-turn --solutions 8 --repeats 3
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time

import torch

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from _timing import machine, print_table, time_fn, write_json  # noqa: E402

PAPER_NODES_PER_S = 1 / 0.205
SCENES = ("box-turn", "box-pickup", "bottle-turn", "mug-pickup", "two-hand-box")


HANDS = {"default": "default", "shadow": "hands/shadow_hand/right_hand.xml",
         "allegro": "hands/allegro_hand/right_hand.xml", "leap": "hands/urdf/leap_hand/leap_hand_right.urdf",
         "allegro_urdf": "hands/urdf/allegro_hand/allegro_hand_right.urdf"}


def hand_path(hand: str) -> str:
    """The file of a named shared hand (``HANDS``), or ``hand`` itself (a path)."""
    path = HANDS.get(hand)
    if path is None:
        return os.path.abspath(hand)
    data = os.environ.get("TORCHHAND_SHARED_DATA", os.path.join(HERE, "..", "..", "shared", "data"))
    return os.path.abspath(os.path.join(data, path))


def scene_with_hand(hand: str):
    """box-turn with its right hand replaced: "default", "shadow", "allegro" (shared data) or an MJCF path."""
    import dataclasses

    import torchhand

    scene = torchhand.load_scene("box-turn")
    if hand == "default":
        return scene
    return dataclasses.replace(scene, hands=(dataclasses.replace(scene.hands[0], model=hand_path(hand)),))


def node_batch(N: int, device: str, dtype: torch.dtype, seed: int = 0, frame: int = 30, hand: str = "default"):
    """(problem, run) where run() tests N candidates of box-turn (with ``hand``) at ``frame``, all fingers
    guided."""
    from torchhand.synthesis.initial import prune_patches
    from torchhand.synthesis.node_test import Guides, pad_points, run_node_test
    from torchhand.synthesis.problem import build_problem

    gen = torch.Generator().manual_seed(seed)
    problem = build_problem(scene_with_hand(hand), gen, device=device, dtype=dtype)
    init = prune_patches(problem, gen)
    hand = problem.hands[0]
    F = hand.num_fingers
    # the hold frame nearest ``frame`` where the most fingers (every finger, for the built-in hand) have pruned
    # patch samples; those fingers are guided
    def count(t):
        return sum(bool(init.samples(t, 0, f).numel()) for f in range(F))

    frame = min(range(problem.T), key=lambda t: (-count(t), abs(t - frame)))
    active = torch.tensor([bool(init.samples(frame, 0, f).numel()) for f in range(F)], device=device)
    obj = torch.zeros(N, 1, F, 3, dtype=dtype, device=device)
    for f in range(F):
        idx = init.samples(frame, 0, f)
        if idx.numel():
            obj[:, 0, f] = problem.surface[idx[torch.randint(idx.numel(), (N,), generator=gen).to(idx.device)]]
    guides = Guides(active.expand(N, 1, F).clone(), hand.distal_link.expand(N, 1, F).clone(),
                    pad_points(hand).expand(N, 1, F, 3).clone(), obj, torch.zeros_like(obj))
    t = torch.full((N,), frame, device=device)
    # as in the search, most node tests start from the previous frame's pose: solve frame - 1 first (untimed)
    warm = run_node_test(problem, t - 1, hand.q_rest.expand(N, 1, -1).clone(),
                         torch.ones(N, dtype=torch.bool, device=device), guides)
    q_prev = warm.q
    first = torch.zeros(N, dtype=torch.bool, device=device)
    return problem, lambda: run_node_test(problem, t, q_prev, first, guides, prev_mask=warm.c_mask)


_VIEWS = ("aten.slice.", "aten.select.", "aten.unsqueeze", "aten.view.", "aten.squeeze", "aten.expand.",
          "aten._unsafe_view", "aten.transpose.", "aten.t.", "aten.permute.", "aten.alias", "aten.diagonal.",
          "aten.unbind", "aten.split.", "aten.as_strided.", "aten.detach")


def launch_counts(run) -> dict:
    """What one call of ``run`` launches, counted on its device's operator dispatch (no timing): ``ops``, the
    operators that are kernel launches on a GPU (views excluded) on this device's paths; ``launches``, the same
    on the GPU's paths (:func:`torchhand.kernels.graphs.gpu_paths`), a function given to ``replayed`` counting
    as one launch (its graph's replay); ``syncs``, the host reads left on the GPU's paths
    (:func:`torchhand.kernels.graphs.host_sync`; on the CPU also index checks that a GPU skips)."""
    from torch.utils._python_dispatch import TorchDispatchMode

    from torchhand.kernels import graphs

    class Count(TorchDispatchMode):
        def __init__(self):
            super().__init__()
            self.ops = self.outside = self.syncs = 0

        def __torch_dispatch__(self, func, types, args=(), kwargs=None):
            name = str(func)
            if not name.startswith(_VIEWS):
                self.ops += 1
                if not graphs.in_replayed():
                    self.outside += 1
                    self.syncs += graphs.host_sync(func, args, kwargs) is not None
            return func(*args, **(kwargs or {}))

    with Count() as eager:
        run()
    regions = graphs.STATS["regions"]
    with graphs.gpu_paths(), Count() as gpu:
        run()
    return {"ops": eager.ops, "launches": gpu.outside + graphs.STATS["regions"] - regions, "syncs": gpu.syncs}


def bench_nodes(device: str = "cpu", dtype=torch.float32, batches=(64, 256, 1024), repeats: int = 5,
                hand: str = "default") -> list[dict]:
    rows = []
    dname = str(dtype).replace("torch.", "")
    _, one = node_batch(1, device, dtype, hand=hand)
    loop = 16

    def sequential():
        for _ in range(loop):
            one()

    t = time_fn(sequential, device, repeats=repeats, warmup=1)
    seq_rate = loop / t["median_s"]
    rows.append({"name": "node test, one candidate at a time", "hand": hand, "device": device, "dtype": dname, "N": 1,
                 **t, "nodes_per_s": seq_rate, "vs_sequential": 1.0, "vs_paper": seq_rate / PAPER_NODES_PER_S})
    from torchhand.kernels import graphs
    for N in batches:
        _, run = node_batch(N, device, dtype, hand=hand)
        before = dict(graphs.STATS)
        t = time_fn(run, device, repeats=repeats, warmup=1)
        rate = N / t["median_s"]
        used = {k: graphs.STATS[k] - before.get(k, 0) for k in ("captures", "replays", "eager", "failed")}
        res = run()
        counts = launch_counts(run) if device == "cpu" else {"graphs": used}
        rows.append({"name": "node test, batched", "hand": hand, "device": device, "dtype": dname, "N": N, **t,
                     "nodes_per_s": rate, "vs_sequential": rate / seq_rate, "vs_paper": rate / PAPER_NODES_PER_S,
                     "feasible_frac": float(res.feasible.double().mean()), **counts})
    rows.append({"name": "Ye & Liu 2012 (paper, Core 2 Duo, one thread)", "device": "cpu", "N": 1,
                 "nodes_per_s": PAPER_NODES_PER_S, "vs_paper": 1.0})
    return rows


def one_at_a_time_rate(device: str = "cpu", dtype=torch.float32, loop: int = 16, repeats: int = 3) -> float:
    """Node tests per second of box-turn's hold frame tested one candidate at a time (the reference rate)."""
    _, one = node_batch(1, device, dtype)

    def sequential():
        for _ in range(loop):
            one()

    return loop / time_fn(sequential, device, repeats=repeats, warmup=1)["median_s"]


def bench_scenes(scenes=SCENES, max_nodes: int = 60000, seed: int = 0, mug: str | None = None,
                 mug_frames: str = "614:674", mug_slide_speed: float = 0.05, threads: int = 1) -> list[dict]:
    jobs = [(s, s, None, []) for s in scenes]
    if mug:
        jobs.append((f"manipnet-mug {mug_frames}", mug, mug_frames, ["--slide-speed", str(mug_slide_speed)]))
    return run_jobs(jobs, max_nodes, seed, threads)


def bench_hands(hands, scenes=("cube-turn",), max_nodes: int = 40000, seed: int = 0, solutions: int = 3,
                threads: int = 1) -> list[dict]:
    """Each robot hand (``HANDS`` names or paths) on each scene, no sidecar, the mount fitted: the Table 1 columns,
    the fitted mount and the checks of every solution written."""
    jobs = [(f"{s} {h}", s, None, ["--hand", f"right={hand_path(h)}", "--solutions", str(solutions)])
            for h in hands for s in scenes]
    return run_jobs(jobs, max_nodes, seed, threads)


def run_jobs(jobs, max_nodes: int, seed: int, threads: int) -> list[dict]:
    """``torchhand synthesize`` for each (label, scene, frames, extra args), then ``check_result``: one row each."""
    from torchhand.cli import main as cli
    from torchhand.check import check_result

    rows = []
    one = one_at_a_time_rate()
    for label, scene, frames, extra in jobs:
        out = tempfile.mkdtemp(prefix="bench-synth-")
        argv = ["synthesize", scene, "--out", out, "--max-nodes", str(max_nodes), "--seed", str(seed),
                "--threads", str(threads), "--no-progress", "--overwrite"] + (["--frames", frames] if frames else []) \
            + extra
        t0 = time.perf_counter()
        cli(argv)
        wall = time.perf_counter() - t0
        stats = json.load(open(os.path.join(out, "stats.json")))
        report = check_result(out)
        worst = {name: fig.value for name, (_, fig) in report.worst().items()}
        penetration = max(worst.get(k, 0.0) for k in ("object_penetration_m", "table_penetration_m",
                                                      "hand_penetration_m", "finger_penetration_m"))
        rows.append({"scene": label, "seed": seed, "epsilon": stats["epsilon"], "T": stats["T"], "time_s": wall,
                     "solutions": stats["solutions"], "dead_ends": stats["dead_ends"],
                     "total_frames": stats["total_frames"], "success_frames": stats["success_frames"],
                     "success_ratio": stats["success_ratio"], "solution_ratio": stats["solution_ratio"],
                     "nodes_tested": stats["nodes_tested"], "stopped_by": stats["stopped_by"],
                     "finalize_s": stats["timings_s"]["finalize_s"],
                     "nodes_per_s": stats["nodes_per_second"], "one_at_a_time_per_s": one,
                     "paper_per_s": PAPER_NODES_PER_S, "excluded": stats["excluded"],
                     "unsmoothed_excluded": stats["excluded_by_reason"]["unsmoothed"],
                     "duplicates": stats["excluded_by_reason"]["duplicate"],
                     "diversity_m": stats["diversity_m"], "checks_pass": report.passed,
                     "checks_failed": len(report.failures),
                     "worst_penetration_mm": 1000 * penetration,
                     "worst_balance_rel": max(worst.get("force_error", 0.0), worst.get("torque_error", 0.0)),
                     "mount": stats.get("mount"), "rest": stats.get("rest")})
    return rows


def bench_batch(scene: str = "box-turn", seeds=tuple(range(16)), solutions: int = 3, max_nodes: int = 2000,
                device: str = "cpu", alone: int | None = None) -> dict:
    """K seeds of ``scene`` as one batch (:func:`torchhand.synthesis.pipeline.synthesize_seeds`) against the same
    seeds run one at a time (the first ``alone`` of them; default all), in the same process: wall times, jobs per
    hour, whether every seed's solution files are identical to its alone run's (the result digest), the checks of
    every batched result, and the scheduler's batch sizes."""
    from torchhand import load_scene
    from torchhand.check import check_result
    from torchhand.io.digest import solutions_digest
    from torchhand.synthesis.multi import MultiStats
    from torchhand.synthesis.pipeline import synthesize, synthesize_seeds

    sc = load_scene(scene)
    seeds = list(seeds)
    opts = dict(solutions=solutions, max_nodes=max_nodes, device=device)
    tmp = tempfile.mkdtemp(prefix="bench-batch-")
    ms = MultiStats()
    t0 = time.perf_counter()
    together = synthesize_seeds(sc, seeds, multi_stats=ms, **opts)
    batch_s = time.perf_counter() - t0
    def digest(path, res):
        return solutions_digest(path) if res.finals else "no solution"

    digests, checks = {}, []
    for seed, res in zip(seeds, together):
        out = res.save(os.path.join(tmp, f"batch_{seed}"))
        digests[seed] = digest(out, res)
        if res.finals:
            checks.append(check_result(out).passed)
    alone_s, same = [], []
    for seed in seeds[:len(seeds) if alone is None else alone]:
        t0 = time.perf_counter()
        res = synthesize(sc, seed=seed, **opts)
        alone_s.append(time.perf_counter() - t0)
        same.append(digest(res.save(os.path.join(tmp, f"alone_{seed}")), res) == digests[seed]
                    and res.stats.nodes_tested == together[seeds.index(seed)].stats.nodes_tested)
    K = len(seeds)
    row = {"scene": scene, "device": device, "K": K, "solutions_asked": solutions, "max_nodes": max_nodes,
           "written": sum(len(r.finals) for r in together), "node_tests": sum(r.stats.nodes_tested for r in together),
           "batch_s": batch_s, "batch_jobs_per_h": 3600 * K / batch_s, "checks_pass": f"{sum(checks)}/{len(checks)}",
           "calls": ms.calls, "mean_batch": sum(ms.batch_sizes) / max(ms.calls, 1),
           "max_batch": max(ms.batch_sizes, default=0)}
    if alone_s:
        row.update({"alone_runs": len(alone_s), "alone_sum_s": sum(alone_s),
                    "alone_jobs_per_h": 3600 * len(alone_s) / sum(alone_s),
                    "batch_over_alone": batch_s / (sum(alone_s) * K / len(alone_s)),
                    "identical": f"{sum(same)}/{len(same)}"})
    return row


def bench_finish(scene: str = "box-turn", paths: int = 8, seed: int = 0, max_nodes: int = 60000,
                 device: str = "cpu", repeats: int = 3) -> dict:
    """The finishing (reconstruction and exact re-check, :mod:`torchhand.synthesis.finishing`) of ``paths`` paths
    that one search of ``scene`` found, one path after another (``drive``) against all side by side (``drive_many``:
    each step's work of all paths as one batch), alternating, ``repeats`` times each; medians, and whether every
    path's result is identical."""
    from torchhand import load_scene
    from torchhand.synthesis import finishing
    from torchhand.synthesis.initial import prune_patches
    from torchhand.synthesis.node_test import NodeTestSettings
    from torchhand.synthesis.problem import build_problem
    from torchhand.synthesis.search import SearchSettings, search

    gen = torch.Generator().manual_seed(seed)
    problem = build_problem(load_scene(scene), gen, device=device)
    sols, _ = search(problem, prune_patches(problem, gen), SearchSettings(solutions=paths, max_nodes=max_nodes,
                                                                          candidates=16), seed=seed)
    programs = lambda: [finishing.finalize_steps(problem, s, i, ns=NodeTestSettings())  # noqa: E731
                        for i, s in enumerate(sols)]
    times = {"alone": [], "together": []}
    for _ in range(repeats):
        t0 = time.perf_counter()
        alone = [finishing.drive(p) for p in programs()]
        times["alone"].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        together = finishing.drive_many(programs())
        times["together"].append(time.perf_counter() - t0)

    def same(a, b):
        if (a[0] is None) != (b[0] is None) or a[1] != b[1]:
            return False
        return a[0] is None or all(torch.equal(getattr(a[0], f), getattr(b[0], f)) for f in ("q", "c_force", "c_point"))

    alone_s, together_s = statistics.median(times["alone"]), statistics.median(times["together"])
    return {"scene": scene, "device": device, "paths": len(sols), "ok": sum(r[1] == "ok" for r in alone),
            "alone_s": alone_s, "together_s": together_s, "together_over_alone": together_s / alone_s,
            "per_path_alone_s": alone_s / max(len(sols), 1), "identical": f"{sum(map(same, alone, together))}/"
                                                                          f"{len(sols)}"}


def bench_fill(frames: str = "290:420", window: int = 30, overlap: int = 5, max_nodes: int = 900,
               stall_nodes: int = 300, variants: int = 2, device: str = "cpu",
               capture: str | None = None, alternations: int = 1) -> dict:
    """The windows of a capture (ManipNet mug1's ``frames``, right hand) searched together
    (:func:`torchhand.fill.run.search_windows` with one process) against each window alone, one after another, in
    the same process: wall times, whether every window's run (pieces, motions, node tests) is the alone one, and the
    scheduler's calls. capture: a ManipNet capture directory (default the shared data's mug1); alternations: runs
    of each, alternating, alone first (medians)."""
    from pathlib import Path

    from torchhand.fill.run import FillSettings, clip_phases, plan_fill, run_window, search_windows
    from torchhand.scene.mocap import manipnet_scene
    import torchhand.synthesis.multi as multi

    data = os.environ.get("TORCHHAND_SHARED_DATA", os.path.join(HERE, "..", "..", "shared", "data"))
    capture = capture or os.path.join(data, "mocap", "manipnet", "mug1")
    a, b = (int(x) for x in frames.split(":"))
    scene = manipnet_scene(Path(capture), fps=30.0, hands=("right",)).with_frames(a, b)
    settings = FillSettings(variants=variants, window=window, overlap=overlap, max_nodes=max_nodes,
                            stall_nodes=stall_nodes, device=device)
    plan = plan_fill(scene, settings)
    calls = []
    real = multi.search_lanes

    def counted(*args, **kw):
        ms = multi.MultiStats()
        calls.append(ms)
        return real(*args, **dict(kw, stats=ms))

    def together():
        multi.search_lanes = counted
        try:
            return search_windows(plan.prepared.scene, plan.windows, plan.settings, None, plan.phases)
        finally:
            multi.search_lanes = real

    def alone():
        return [run_window(plan.prepared.scene, w, plan.settings, clip_phases(plan.phases, w.start, w.stop) or None)
                for w in plan.windows]

    times: dict = {"alone": [], "together": []}
    runs: dict = {}
    for mode in ("alone", "together") * alternations:          # alone first: any warm-up favours it
        t0 = time.perf_counter()
        runs[mode] = alone() if mode == "alone" else together()
        times[mode].append(time.perf_counter() - t0)
    ms = calls[0]
    same = [_window_digest(a) == _window_digest(b) and a.nodes == b.nodes
            for a, b in zip(runs["alone"], runs["together"])]
    med = {k: statistics.median(v) for k, v in times.items()}
    return {"frames": frames, "device": device, "windows": len(plan.windows), "max_nodes": max_nodes,
            "node_tests": sum(r.nodes for r in runs["together"]),
            "statuses": " ".join(r.status for r in runs["together"]),
            "together_s": " / ".join(f"{x:.1f}" for x in times["together"]),
            "alone_s": " / ".join(f"{x:.1f}" for x in times["alone"]),
            "together_over_alone": med["together"] / med["alone"], "identical": f"{sum(same)}/{len(same)}",
            "calls": ms.calls, "mean_batch": sum(ms.batch_sizes) / max(ms.calls, 1),
            "max_batch": max(ms.batch_sizes, default=0)}


def _window_digest(run) -> str:
    """A window run's pieces (frames, kind, motions) as one hash."""
    import hashlib

    h = hashlib.sha256()
    for p in run.pieces:
        h.update(f"{p.start},{p.stop},{p.kind}".encode())
        for q in p.qs:
            h.update(q.numpy().tobytes())
    return h.hexdigest()


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("suite", choices=["nodes", "scenes", "hands", "batch", "fill", "finish", "all"])
    p.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    p.add_argument("--dtype", default="float32", choices=["float32", "float64"])
    p.add_argument("--batch", type=int, nargs="+", default=[64, 256, 1024])
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--max-nodes", type=int, default=60000, help="node budget per scene (default 60000)")
    p.add_argument("--threads", type=int, default=1, help="torch threads of each run (default 1)")
    p.add_argument("--scenes", nargs="+", default=list(SCENES))
    p.add_argument("--mug", help="a scene directory imported from ManipNet's mug1 (adds a 2 s segment)")
    p.add_argument("--mug-frames", default="614:674", help="scene frames of the segment (default 614:674, 2 s)")
    p.add_argument("--mug-slide-speed", type=float, default=0.05,
                   help="--slide-speed of the mocap segment (default 0.05 m/s)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0], help="one run per scene and seed (default 0)")
    p.add_argument("--hands", nargs="+", default=None,
                   help="nodes: hands on box-turn's track (default: default); hands: the robot hands run (default: "
                        "shadow allegro leap allegro_urdf); names of shared hands or MJCF/URDF paths")
    p.add_argument("--hand-scenes", nargs="+", default=["cube-turn"], help="hands: the scenes (default cube-turn)")
    p.add_argument("--solutions", type=int, default=3, help="hands: solutions asked per run (default 3)")
    p.add_argument("--batch-seeds", type=int, nargs="+", default=[16],
                   help="batch: K seeds 0..K-1 of --scenes' first scene in one batch, one row per K (default 16)")
    p.add_argument("--alone", type=int, default=None,
                   help="batch: run only the first N seeds alone for the comparison (default: all)")
    p.add_argument("--fill-frames", default="290:420",
                   help="fill: the frames of ManipNet mug1 whose windows are searched (default 290:420)")
    p.add_argument("--fill-window", type=int, nargs=2, default=[30, 5], metavar=("WINDOW", "OVERLAP"),
                   help="fill: window and overlap, frames (default 30 5)")
    p.add_argument("--stall-nodes", type=int, default=300, help="fill: stall rule in node tests (default 300)")
    p.add_argument("--json", help="write the results here (atomically)")
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    out = {"machine": machine(), "command": " ".join(sys.argv), "threads": a.threads}
    print(f"machine: {out['machine']}")
    if a.suite in ("nodes", "all"):
        rows = [r for hand in (a.hands or ["default"])
                for r in bench_nodes(a.device, getattr(torch, a.dtype), a.batch, a.repeats, hand=hand)]
        print("\n[node tests]")
        print_table(rows, ["name", "hand", "device", "dtype", "N", "median_s", "iqr_s", "nodes_per_s", "ops",
                           "launches", "syncs", "vs_sequential", "vs_paper", "feasible_frac"])
        out["nodes"] = rows
    if a.suite in ("scenes", "all"):
        rows = [r for seed in a.seeds
                for r in bench_scenes(a.scenes, a.max_nodes, seed, a.mug, a.mug_frames, a.mug_slide_speed, a.threads)]
        print("\n[scenes: Ye & Liu Table 1 columns]")
        print_table(rows, list(rows[0].keys()))
        out["scenes"] = rows
    if a.suite == "hands":
        rows = bench_hands(a.hands or ["shadow", "allegro", "leap", "allegro_urdf"], a.hand_scenes, a.max_nodes,
                           a.seeds[0], a.solutions, a.threads)
        print("\n[robot hands, no sidecar, mount fitted]")
        print_table(rows, ["scene", "solutions", "nodes_tested", "nodes_per_s", "stopped_by", "checks_pass",
                           "checks_failed", "worst_penetration_mm", "time_s"])
        out["hands"] = rows
    if a.suite == "batch":
        rows = [bench_batch(a.scenes[0], range(k), a.solutions, a.max_nodes, a.device, a.alone)
                for k in a.batch_seeds]
        print("\n[many seeds in one batch against the same seeds one at a time]")
        print_table(rows, list(rows[0].keys()))
        out["batch"] = rows
    if a.suite == "fill":
        rows = [bench_fill(a.fill_frames, a.fill_window[0], a.fill_window[1], a.max_nodes, a.stall_nodes,
                           a.solutions, a.device, alternations=a.repeats)]
        print("\n[a capture's windows together against each window alone]")
        print_table(rows, list(rows[0].keys()))
        out["fill"] = rows
    if a.suite == "finish":
        rows = [bench_finish(a.scenes[0], a.solutions, a.seeds[0], a.max_nodes, a.device, a.repeats)]
        print("\n[finishing many paths side by side against one after another]")
        print_table(rows, list(rows[0].keys()))
        out["finish"] = rows
    if a.json:
        write_json(a.json, out)
        print(f"wrote {a.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
