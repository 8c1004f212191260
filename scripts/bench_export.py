"""Export speed: ``torchhand export`` of a result directory (every solution as BVH and glb), against reading the
same result (``load_result`` and every solution file) in the same run.

Cases (median of --repeat runs, one torch thread unless --threads):
  read       load_result(DIR) and every Solution: the reference, the export's own input
  bvh        export_result(..., formats=("bvh",))
  gltf       export_result(..., formats=("gltf",), contacts=True)
  both       export_result(...) with the defaults (bvh + glb), as the CLI runs it less the interpreter start

    python scripts/bench_export.py --result out/box-turn [--repeat 5] [--json out.json]

The result directory is any (``torchhand synthesize box-turn --out out/box-turn`` gives the 10-solution one of
BENCHMARKS.md).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import machine, time_fn  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--result", type=Path, required=True, help="a result directory")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    from torchhand.export import export_result
    from torchhand.io.result import load_result

    res = load_result(args.result)
    n = len(res.solution_files)
    T = res.solution(0).T
    tmp = Path(tempfile.mkdtemp(prefix="bench_export_"))

    def read():
        r = load_result(args.result)
        return [r.solution(i) for i in range(len(r.solution_files))]

    def export(formats, contacts=False):
        def run():
            export_result(args.result, tmp / "out", formats=formats, contacts=contacts, overwrite=True)
        return run

    cases = {"read": read, "bvh": export(("bvh",)), "gltf": export(("gltf",), True), "both": export(("bvh", "gltf"))}
    out = {"machine": machine(), "result": str(args.result), "solutions": n, "frames": T, "threads": args.threads,
           "cases": {}}
    try:
        for name, fn in cases.items():
            out["cases"][name] = time_fn(fn, repeats=args.repeat, warmup=1)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    ref = out["cases"]["read"]["median_s"]
    print(f"{n} solutions x {T} frames, {args.threads} thread(s), {out['machine'].get('cpu', '')}")
    for name, t in out["cases"].items():
        print(f"  {name:5s} {1000 * t['median_s']:8.1f} ms  ({t['median_s'] / ref:5.1f}x reading the result)")
    if args.json:
        args.json.write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
