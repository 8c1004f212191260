"""Accuracy of SDF grid queries near the surface of real, thin-walled meshes, against exact references.

For each mesh (ManipNet's mug1, the bigym mug, trimesh's teapot, the Stanford bunny; scaled to metres as the scenes
use them), points are drawn near the surface (surface samples moved along a random direction by up to two voxels)
and compared, at the grid's voxel size (1.5 mm, the synthesis default), between

* ``grid``: the trilinear grid (:meth:`SDFGrid.query_with_grad`), and
* ``surface``: :meth:`SDFGrid.query_surface` (exact distances to the cell's candidate triangles),

against trimesh's exact unsigned distance (``closest_point``), the sign of the generalized winding number by its
definition (float64 sum of solid angles; points where it is ambiguous, |w - 0.5| < 0.1, are left out of the sign
count), and, for points whose closest point lies inside a face (not within 1e-6 m of an edge), the face's normal.

    python scripts/sdf_surface_accuracy.py [--voxel 0.0015] [--points 4000] [--json out.json]

Prints a table: max and p99 distance error (in voxels), sign errors, worst and p99 normal angle (degrees), and the
query time of ``surface`` relative to ``grid`` on the same points (median of 5).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
import trimesh

from torchhand.geometry.objects import load_object
from torchhand.geometry.sdf import SDFGrid

SHARED = Path(os.environ.get("TORCHHAND_SHARED_DATA", Path(__file__).resolve().parents[1].parent / "shared" / "data"))
MESHES = {  # name: (path under ../shared/data, scale to metres)
    "manipnet-mug1": ("mocap/manipnet/mug1/mug1.obj", 0.1),
    "bigym-mug": ("meshes/bigym_props/mug/assets/mug.obj", 1.0),
    "teapot": ("meshes/trimesh/teapot.stl", 0.003),
    "bunny": ("meshes/trimesh/bunny.ply", 1.0),
}


def winding(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    tri = torch.tensor(np.asarray(mesh.triangles))
    out = []
    for p in torch.as_tensor(points).split(128):
        v = tri[None] - p[:, None, None]
        a, b, c = v[:, :, 0], v[:, :, 1], v[:, :, 2]
        la, lb, lc = a.norm(dim=-1), b.norm(dim=-1), c.norm(dim=-1)
        det = (a * torch.linalg.cross(b, c, dim=-1)).sum(-1)
        den = la * lb * lc + (a * b).sum(-1) * lc + (a * c).sum(-1) * lb + (b * c).sum(-1) * la
        out.append((2 * torch.atan2(det, den)).sum(-1) / (4 * math.pi))
    return torch.cat(out).numpy()


def measure(name: str, voxel: float, n: int, seed: int) -> dict:
    rel, scale = MESHES[name]
    mesh = load_object(SHARED / rel, mass=0.3, scale=scale).mesh
    with tempfile.TemporaryDirectory() as cache:
        grid = SDFGrid.from_mesh(mesh, voxel, cache_dir=cache, progress=False, dtype=torch.float64)
    rng = np.random.default_rng(seed)
    surf, _ = trimesh.sample.sample_surface(mesh, n, seed=seed)
    d = rng.normal(size=surf.shape)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pts = surf + d * rng.uniform(-2 * voxel, 2 * voxel, size=(n, 1))
    closest, dist, face = trimesh.proximity.closest_point(mesh, pts)
    w = winding(mesh, pts)
    clear = np.abs(w - 0.5) > 0.1
    inside = w > 0.5
    P = torch.as_tensor(pts)[None]
    g_sd, g_grad = grid.query_with_grad(P)
    s_sd, s_n, _ = grid.query_surface(P)
    # normals where the closest point is inside a face (away from its edges)
    tri = mesh.triangles[face]
    bary = trimesh.triangles.points_to_barycentric(tri, closest)
    interior = (bary.min(1) > 1e-3) & (dist > 1e-5)
    fn = mesh.face_normals[face] * (1.0 if mesh.volume > 0 else -1.0)  # outward: the gradient on both sides
    out = {"mesh": name, "voxel_mm": voxel * 1e3, "points": n, "faces": len(mesh.faces),
           "watertight": bool(mesh.is_watertight)}
    for label, sd, nrm in (("grid", g_sd[0].numpy(), g_grad[0].numpy()), ("surface", s_sd[0].numpy(), s_n[0].numpy())):
        err = np.abs(np.abs(sd) - dist) / voxel
        sign_err = int(((sd < 0) != inside)[clear].sum())
        nn = nrm[interior] / np.linalg.norm(nrm[interior], axis=1, keepdims=True)
        ang = np.degrees(np.arccos(np.clip((nn * fn[interior]).sum(1), -1, 1)))
        out[label] = {"max_err_vox": float(err.max()), "p99_err_vox": float(np.percentile(err, 99)),
                      "sign_errors": sign_err, "sign_points": int(clear.sum()),
                      "normal_max_deg": float(ang.max()), "normal_p99_deg": float(np.percentile(ang, 99))}
    out["time_ratio"] = _time_ratio(grid, P)
    return out


def _time_ratio(grid: SDFGrid, P: torch.Tensor) -> float:
    def med(fn):
        ts = []
        for _ in range(5):
            t0 = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t0)
        return float(np.median(ts))
    return med(lambda: grid.query_surface(P)) / med(lambda: grid.query_with_grad(P))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--voxel", type=float, default=0.0015)
    ap.add_argument("--points", type=int, default=4000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--meshes", nargs="*", default=list(MESHES))
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    rows = []
    print("| mesh | faces | watertight | query | max error (voxels) | p99 error | sign errors | normal max / p99 (deg) "
          "|\n|---|---|---|---|---|---|---|---|")
    for name in a.meshes:
        r = measure(name, a.voxel, a.points, a.seed)
        rows.append(r)
        for label in ("grid", "surface"):
            m = r[label]
            print(f"| {name} | {r['faces']} | {r['watertight']} | {label} | {m['max_err_vox']:.3f} | "
                  f"{m['p99_err_vox']:.3f} | {m['sign_errors']} / {m['sign_points']} | "
                  f"{m['normal_max_deg']:.1f} / {m['normal_p99_deg']:.1f} |", flush=True)
        print(f"|  |  |  | surface time / grid time | {r['time_ratio']:.1f} |  |  |  |", flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
