"""Benchmark of SDF grid queries (torchhand.kernels.sdf through SDFGrid) against trimesh's exact signed distance.

Runs without ../shared: the mesh is procedural (a mug-sized capsule, 16 cm long, 4 cm radius; a 2 mm voxel gives
a 65 x 65 x 105 grid). Query points are drawn uniformly in the grid box enlarged by 1 cm (seeded
torch.Generator). Timings come from the shared ``scripts/_timing.py`` (``time_fn``): medians over ``repeats`` runs
after one warm-up, with the spread given as max - min; the GPU is synchronised inside the timed region.

    python scripts/bench_sdf.py --device cpu --dtype float32 --json bench_sdf.json
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile

import numpy as np
import torch
import trimesh

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # scripts/ is not a package
from _timing import machine, print_table, time_fn, write_json  # noqa: E402

from torchhand.kernels.sdf import sdf_trilinear  # noqa: E402
from torchhand.geometry.sdf import SDFGrid  # noqa: E402

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


def _row(name: str, device: str, dtype: torch.dtype, b: int, points: int, timing: dict) -> dict:
    """One result row from a :func:`_timing.time_fn` result (median and max - min spread of the per-call seconds)."""
    return {
        "name": name,
        "device": str(device),
        "dtype": str(dtype).replace("torch.", ""),
        "B": int(b),
        "points": int(points),
        "median_s": timing["median_s"],
        "spread_s": timing["max_s"] - timing["min_s"],
        "points_per_s": points / timing["median_s"],
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
            rows.append(_row("sdf_query", device, dtype, b, n,
                             time_fn(lambda: grid.query(pts), dev, repeats, warmup=1)))
            rows.append(_row("sdf_query_with_grad", device, dtype, b, n,
                             time_fn(lambda: grid.query_with_grad(pts), dev, repeats, warmup=1)))
            rows.append(_row("sdf_query_gather8", device, dtype, b, n, time_fn(
                lambda: sdf_trilinear(grid.values, grid.origin, grid.voxel_size, pts), dev, repeats, warmup=1)))
    return rows


def bench_trimesh_reference(n_points: int = 2000, repeats: int = 3, seed: int = 0) -> dict:
    """Time trimesh's exact signed distance (``trimesh.proximity.signed_distance``) on the same mesh and points."""
    mesh = bench_mesh()
    grid = _grid(mesh)
    pts = _points(grid, 1, n_points, torch.Generator().manual_seed(seed))[0].numpy()
    timing = time_fn(lambda: trimesh.proximity.signed_distance(mesh, pts), "cpu", repeats, warmup=0)
    return _row("trimesh_signed_distance", "cpu", torch.float64, 1, n_points, timing)


COLUMNS = ["name", "device", "dtype", "B", "points", "median_s", "spread_s", "points_per_s"]


def _print_rows(rows: list[dict], reference: dict | None) -> None:
    """The rows (and the reference) as a table; with a reference, each row's speed-up over it as ``x_trimesh``."""
    if reference is None:
        print_table(rows, COLUMNS)
        return
    shown = [dict(r, x_trimesh=r["points_per_s"] / reference["points_per_s"]) for r in rows + [reference]]
    print_table(shown, COLUMNS + ["x_trimesh"])


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
    info = machine()
    print(f"machine: {info}, mesh: capsule, voxel {VOXEL} m")
    _print_rows(rows, reference)
    if args.json:
        write_json(args.json, {"machine": info, "rows": rows, "reference": reference, "torch": torch.__version__,
                               "threads": torch.get_num_threads(), "numpy": np.__version__})
    return 0


if __name__ == "__main__":
    sys.exit(main())
