"""Benchmark of ``torchhand check``'s exact geometry on a result, beside trimesh's own queries in the same run.

For each result directory: the whole check (``check_result``, median of ``--repeats``), then, on the result's object
mesh, for the surface points of its first hand's MJCF geoms (or its capsule axes) at a few frames that lie in the
object's bounding box:

* inside/outside, for 1000 of those points: :class:`torchhand.check.crossing.CrossingTest` against
  ``mesh.ray.contains_points`` (trimesh's ray test, what ``trimesh.proximity.signed_distance`` signs with; it took
  7 GB for 4853 points on a 16k-triangle scan), and how many verdicts differ;
* closest points: ``ObjectMesh.closest`` against ``trimesh.proximity.closest_point``, and the largest amount by
  which either exceeds the minimum over every triangle (brute force, on a sample of 200 points).

    python scripts/bench_check.py RESULT_DIR [RESULT_DIR ...] [--repeats 3] [--json bench_check.json]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # scripts/ is not a package
from _timing import machine, print_table, write_json  # noqa: E402

from torchhand.check import check_result  # noqa: E402
from torchhand.check.crossing import CrossingTest  # noqa: E402
from torchhand.check.geometry import object_mesh  # noqa: E402
from torchhand.io.result import load_result  # noqa: E402


def _median_time(fn, repeats: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), out


def _hand_points(path: str, frames: int) -> np.ndarray:
    """Surface points of the first hand's MJCF geoms at ``frames`` frames spread over the solution, object frame;
    only those in the object's bounding box."""
    from torchhand.check.mjcf_geometry import _PosedGeoms

    res = load_result(path)
    sol = res.solution(0)
    hs = sol.hands[0]
    model = res.hand_models[hs.side]
    posed = _PosedGeoms.load(os.path.join(path, "hand.xml"), model, 0.002)
    if posed is None:
        raise SystemExit("bench_check: needs mujoco (the MJCF geoms)")
    mesh = res.scene.object.mesh
    out = []
    for t in np.linspace(0, sol.T - 1, frames).astype(int):
        posed.pose(hs.q[t], hs.root_pose[t])
        inv = np.linalg.inv(sol.object_pose[t])
        for g, _, pts, _ in posed.geoms:
            world = pts @ posed.data.geom_xmat[g].reshape(3, 3).T + posed.data.geom_xpos[g]
            out.append(world @ inv[:3, :3].T + inv[:3, 3])
    pts = np.concatenate(out)
    return pts[np.all((pts >= mesh.bounds[0]) & (pts <= mesh.bounds[1]), axis=1)]


def bench(path: str, repeats: int, frames: int) -> dict:
    import trimesh
    from trimesh.triangles import closest_point as triangle_closest_point

    check_s, report = _median_time(lambda: check_result(path), repeats)
    res = load_result(path)
    mesh = res.scene.object.mesh
    obj = object_mesh(mesh, float(res.scene.object.mass))
    pts = _hand_points(path, frames)
    tris = mesh.triangles.view(np.ndarray)
    crossing = CrossingTest(tris)
    few = pts[np.random.default_rng(1).choice(len(pts), size=min(1000, len(pts)), replace=False)]
    ours_s, ours = _median_time(lambda: crossing.contains(few), repeats)
    theirs_s, theirs = _median_time(lambda: mesh.ray.contains_points(few), 1)   # 7 GB for 4853 points on a scan
    closest_s, (_, dist, _) = _median_time(lambda: obj.closest(pts), repeats)
    tm_closest_s, (_, tm_dist, _) = _median_time(lambda: trimesh.proximity.closest_point(mesh, pts), 1)
    sample = np.random.default_rng(0).choice(len(pts), size=min(200, len(pts)), replace=False)
    brute = np.array([np.linalg.norm(triangle_closest_point(tris, np.repeat(pts[i][None], len(tris), 0)) - pts[i],
                                     axis=-1).min() for i in sample])
    return {"result": path, "scene": report.scene, "frames": int(res.solution(0).T), "triangles": len(tris),
            "check_s": check_s, "passed": sum(s.passed for s in report.solutions), "points": len(pts), "inside_points": len(few),
            "inside_ours_s": ours_s, "inside_trimesh_s": theirs_s, "inside_ratio": ours_s / theirs_s,
            "verdicts_differ": int((ours != theirs).sum()),
            "closest_ours_s": closest_s, "closest_trimesh_s": tm_closest_s, "closest_ratio": closest_s / tm_closest_s,
            "ours_over_brute_m": float((dist[sample] - brute).max()),
            "trimesh_over_brute_m": float((tm_dist[sample] - brute).max())}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("results", nargs="+")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--frames", type=int, default=4, help="frames whose geom points are queried (default 4)")
    p.add_argument("--json")
    a = p.parse_args(argv)
    rows = [bench(r, a.repeats, a.frames) for r in a.results]
    print_table(rows, ["scene", "frames", "triangles", "check_s", "passed", "points", "inside_points", "inside_ours_s",
                       "inside_trimesh_s", "inside_ratio", "verdicts_differ", "closest_ours_s", "closest_trimesh_s",
                       "closest_ratio", "ours_over_brute_m", "trimesh_over_brute_m"])
    if a.json:
        write_json(a.json, {"machine": machine(), "rows": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
