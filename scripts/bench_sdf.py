"""Benchmark of SDF grid queries (torchhand.kernels.sdf through SDFGrid) against trimesh's exact signed distance.

Runs without ../shared: the mesh is procedural (a mug-sized capsule, 16 cm long, 4 cm radius; a 2 mm voxel gives
a 65 x 65 x 105 grid). Query points are drawn uniformly in the grid box enlarged by 1 cm (seeded
torch.Generator). Timings are medians over ``repeats`` runs with the spread given as min-max; the GPU is
synchronised inside the timed region.

    python scripts/bench_sdf.py --device cpu --dtype float32 --json bench_sdf.json
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from typing import Callable

import numpy as np
import torch
import trimesh

from torchhand.kernels.sdf import sdf_trilinear
from torchhand.sdf import SDFGrid

MILLION = 1_048_576
VOXEL = 0.002


def bench_mesh() -> trimesh.Trimesh:
    """The benchmark's procedural mesh (metres)."""
    return trimesh.creation.capsule(height=0.08, radius=0.04, count=[32, 32])


def _grid(mesh: trimesh.Trimesh) -> SDFGrid:
    with tempfile.TemporaryDirectory() as cache:
        return SDFGrid.from_mesh(mesh, VOXEL, cache_dir=cache, progress=False)


def _points(grid: SDFGrid, b: int, p: int, generator: torch.Generator) -> torch.Tensor:
    lo, hi = grid.box
    lo, hi = lo.double().cpu() - 0.01, hi.double().cpu() + 0.01
    return lo + torch.rand(b, p, 3, generator=generator, dtype=torch.float64) * (hi - lo)


def _time(fn: Callable[[], object], repeats: int, device: torch.device) -> list[float]:
    fn()  # warm-up
    out = []
    for _ in range(repeats):
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        t0 = time.perf_counter()
        fn()
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        out.append(time.perf_counter() - t0)
    return out


def _row(name: str, device: str, dtype: torch.dtype, b: int, points: int, times: list[float]) -> dict:
    median = statistics.median(times)
    return {
        "name": name,
        "device": str(device),
        "dtype": str(dtype).replace("torch.", ""),
        "B": int(b),
        "points": int(points),
        "median_s": median,
        "spread_s": max(times) - min(times),
        "points_per_s": points / median,
    }


def bench_sdf(
    device: str,
    dtype: torch.dtype,
    batch_sizes=(1, 64, 4096, 65536),
    points_per_batch: int = 16,
    repeats: int = 7,
    seed: int = 0,
) -> list[dict]:
    """Time SDFGrid queries for every batch size (plus one row at B x P = 1,048,576 points).

    Rows: ``sdf_query`` (value, one 8-corner gather), ``sdf_query_with_grad`` (value and analytic gradient) and
    ``sdf_query_gather8`` (value from the plain grid, eight gathers, no corner table).
    """
    dev = torch.device(device)
    grid = _grid(bench_mesh()).to(dev, dtype)
    gen = torch.Generator().manual_seed(seed)
    sizes = list(batch_sizes)
    if MILLION % points_per_batch == 0 and MILLION // points_per_batch not in sizes:
        sizes.append(MILLION // points_per_batch)
    rows = []
    with torch.no_grad():
        for b in sizes:
            pts = _points(grid, b, points_per_batch, gen).to(dev, dtype)
            n = b * points_per_batch
            rows.append(_row("sdf_query", device, dtype, b, n, _time(lambda: grid.query(pts), repeats, dev)))
            rows.append(_row("sdf_query_with_grad", device, dtype, b, n,
                             _time(lambda: grid.query_with_grad(pts), repeats, dev)))
            rows.append(_row("sdf_query_gather8", device, dtype, b, n, _time(
                lambda: sdf_trilinear(grid.values, grid.origin, grid.voxel_size, pts), repeats, dev)))
    return rows


def bench_trimesh_reference(n_points: int = 2000, repeats: int = 3, seed: int = 0) -> dict:
    """Time trimesh's exact signed distance (``trimesh.proximity.signed_distance``) on the same mesh and points."""
    mesh = bench_mesh()
    grid = _grid(mesh)
    pts = _points(grid, 1, n_points, torch.Generator().manual_seed(seed))[0].numpy()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        trimesh.proximity.signed_distance(mesh, pts)
        times.append(time.perf_counter() - t0)
    return _row("trimesh_signed_distance", "cpu", torch.float64, 1, n_points, times)


def _table(rows: list[dict], reference: dict | None) -> str:
    head = f"{'name':<24} {'device':<6} {'dtype':<8} {'B':>7} {'points':>9} {'median ms':>10} {'spread ms':>10} " \
           f"{'M pts/s':>9}" + (f" {'x trimesh':>10}" if reference else "")
    lines = [head, "-" * len(head)]
    for r in rows + ([reference] if reference else []):
        line = (f"{r['name']:<24} {r['device']:<6} {r['dtype']:<8} {r['B']:>7} {r['points']:>9} "
                f"{r['median_s'] * 1e3:>10.3f} {r['spread_s'] * 1e3:>10.3f} {r['points_per_s'] / 1e6:>9.3f}")
        if reference:
            line += f" {r['points_per_s'] / reference['points_per_s']:>10.0f}"
        lines.append(line)
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--dtype", default="float32", choices=["float32", "float64"])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--points-per-batch", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--batch-sizes", type=int, nargs="+", default=[1, 64, 4096, 65536])
    parser.add_argument("--no-reference", action="store_true", help="skip the trimesh reference")
    parser.add_argument("--json", "--out", dest="json", default=None, help="write the rows to this JSON file")
    args = parser.parse_args(argv)
    dtype = getattr(torch, args.dtype)
    rows = bench_sdf(args.device, dtype, tuple(args.batch_sizes), args.points_per_batch, args.repeats, args.seed)
    reference = None if args.no_reference else bench_trimesh_reference(seed=args.seed)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, mesh: capsule, voxel {VOXEL} m")
    print(_table(rows, reference))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"rows": rows, "reference": reference, "torch": torch.__version__,
                       "threads": torch.get_num_threads(), "numpy": np.__version__}, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
