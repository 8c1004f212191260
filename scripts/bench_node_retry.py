"""What resuming unfinished force solves costs the search, and what it changes (NodeTestSettings.cone_retry_iters).

The same search (a built-in scene, seed 0, one tree set, no reconstruction) runs with the force solves cut at the
search's cap (``cone_retry_iters=None``, the reference) and resumed (the default), alternating, ``--repeats`` times
each. Rows: node tests, dynamic dead ends, solutions, search seconds (median) and seconds per 1000 node tests; the
ratio of the two. Counts do not depend on the machine; seconds do (name it when recording them).

    python scripts/bench_node_retry.py --scene box-turn --max-nodes 4000 --repeats 3 --json bench_node_retry.json
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
import time

import torch

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from _timing import machine, print_table, write_json  # noqa: E402

import torchhand  # noqa: E402
from torchhand.scene import load_scene  # noqa: E402
from torchhand.synthesis.node_test import NodeTestSettings  # noqa: E402


def run_once(scene, max_nodes: int, solutions: int, retry) -> dict:
    ns = dataclasses.replace(NodeTestSettings(), cone_retry_iters=retry)
    t0 = time.perf_counter()
    result = torchhand.synthesize(scene, solutions=solutions, max_nodes=max_nodes, seed=0, reconstruct=False,
                                  node_settings=ns)
    seconds = time.perf_counter() - t0
    st = result.stats
    return {"nodes": st.nodes_tested, "dynamic": st.rejections["dynamic"], "dead_ends": st.dead_ends,
            "paths": st.paths_found, "search_s": result.timings["search_s"], "total_s": seconds}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="box-turn")
    ap.add_argument("--max-nodes", type=int, default=4000)
    ap.add_argument("--solutions", type=int, default=10)
    ap.add_argument("--retry", type=int, default=NodeTestSettings().cone_retry_iters)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    scene = load_scene(args.scene)
    runs = {"cut at the cap": [], f"resumed to {args.retry}": []}
    for _ in range(args.repeats):
        for name, retry in zip(runs, (None, args.retry)):
            runs[name].append(run_once(scene, args.max_nodes, args.solutions, retry))
            print(name, runs[name][-1], file=sys.stderr)
    rows = []
    for name, rs in runs.items():
        med = statistics.median(r["search_s"] for r in rs)
        rows.append({"settings": name, "node tests": rs[0]["nodes"], "dynamic dead ends": rs[0]["dynamic"],
                     "dead ends": rs[0]["dead_ends"], "paths": rs[0]["paths"], "search s (median)": round(med, 1),
                     "s per 1000 nodes": round(1000 * med / max(rs[0]["nodes"], 1), 2)})
    ratio = rows[1]["s per 1000 nodes"] / rows[0]["s per 1000 nodes"]
    print_table(rows, list(rows[0]))
    print(f"resumed / cut, seconds per node test: {ratio:.2f}x ({machine()})")
    if args.json:
        write_json(args.json, {"scene": args.scene, "max_nodes": args.max_nodes, "rows": rows, "ratio": ratio,
                               "runs": runs})
    return 0


if __name__ == "__main__":
    sys.exit(main())
