"""Building signed distance grids from triangle meshes: the layout, the build driver and the disk cache.

The grid type and its queries live in :mod:`torchhand.geometry.sdf` (:class:`~torchhand.geometry.sdf.SDFGrid`); this
module is the machinery behind :meth:`SDFGrid.from_mesh <torchhand.geometry.sdf.SDFGrid.from_mesh>`. Conventions (see
:mod:`torchhand.conventions`): metres; the SDF is NEGATIVE INSIDE the object and positive outside; points are given
in the mesh (object) frame.

How a grid is built
    * layout: the mesh's bounding box plus padding, rounded up so that each axis has 8 m + 1 nodes
      (:func:`_grid_layout`); node (i, j, k) sits at ``origin + voxel_size * (i, j, k)``.
    * magnitude: exact point-triangle distances. Within two voxels of the surface every node gets the exact
      distance to its nearest triangle; farther out the nearest triangle is propagated (distance transform, then
      fast sweeping) and the exact distance to it is taken (:mod:`torchhand.geometry._sdf_distance`, with the
      measured error);
    * sign: generalized winding number (Jacobson et al. 2013), computed with a Barnes-Hut tree over Morton-ordered
      triangles (second-order far-field expansion, Barill et al. 2018; exact solid angles in the near field;
      :mod:`torchhand.geometry._sdf_winding`). ``w > 0.5`` is inside. Small holes and seams move the winding number
      only near the hole, so open scans keep a sign; a mesh whose winding number is ambiguous (between 0.2 and 0.8)
      over a large part of the region it encloses is reported as too open (:class:`~torchhand.errors.MeshError`).
    * each node's nearest triangle is kept (``face``), so that queries near the surface can measure exact distances
      and normals (:mod:`torchhand.geometry._sdf_surface`);
    * grids are cached on disk (npz, written atomically) keyed by the mesh content hash, voxel size, padding
      and the builder's version, in ``$TORCHHAND_CACHE`` or ``~/.cache/torchhand/sdf``.
    * a build (and :func:`~torchhand.geometry._sdf_winding.winding_number`) runs torch single-threaded and restores
      the thread count afterwards (:mod:`torchhand.geometry._sdf_common`): it is thousands of small operations that
      intra-op threads do not speed up and that stall on a shared CPU.

This module does not import :mod:`torchhand.geometry.sdf` (which imports it), so there is no import cycle.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import torch
import trimesh

from ..errors import InputValueError, MeshError
from ._sdf_common import _progress_bar
from ._sdf_distance import _grid_distance
from ._sdf_winding import _CHUNK, _winding, _WindingTree, inside_report

__all__ = ["BUILD_VERSION", "mesh_content_hash"]

BUILD_VERSION = "3"
"""Version of the grid builder; part of the cache key (bump it when the values a build produces change)."""

_MAX_NODES = 64_000_000      # refuse grids larger than this (memory); ask for a larger voxel
_STRIDE = 8                 # coarsest winding-number lattice, in voxels; grid sizes are 8 m + 1


def _build_values(vertices, faces, origin, voxel_size, shape, progress) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Signed distances at the grid nodes, (Nx, Ny, Nz) float32, negative inside; each node's nearest triangle
    (index into ``faces``), (Nx, Ny, Nz) int32; and each triangle's two-sided winding numbers, (F, 2) float32: at
    ``0.01 voxel_size`` in front of its centroid (along its normal) and behind it (above 0.5: inside; see
    :func:`_face_sides`).

    Winding numbers are evaluated directly on the stride-8 sub-lattice and, on the finer lattices (stride 4, 2, 1),
    only at nodes closer to the surface than the coarser-lattice nodes they would be interpolated from (stride
    times 1, sqrt 2 or sqrt 3 voxels for edge midpoints, face centres and cell centres); elsewhere they are
    interpolated: the ball of radius d(node) around such a node holds those coarser nodes and no surface, so the
    (harmonic, and for closed parts constant) winding number does not jump between them.
    """
    report = inside_report(trimesh.Trimesh(vertices, faces, process=False))  # the same test as RigidObject's
    if not report.robust:
        raise MeshError(f"mesh is too open to have an inside ({report.message}); repair it first "
                        "(torchhand.geometry.objects.repair_mesh or load_object(..., repair=True))")
    centre = 0.5 * (vertices.min(0) + vertices.max(0))  # float32 work relative to the mesh centre
    tri = torch.as_tensor(vertices[faces] - centre, dtype=torch.float32)
    org = torch.as_tensor(origin - centre, dtype=torch.float32)
    n_nodes = int(np.prod(shape))
    with _progress_bar(progress and n_nodes >= 100_000) as bar:
        dist, face = _grid_distance(tri, org, voxel_size, shape, bar)
        dist = dist.numpy()
        direct = np.zeros(shape, dtype=bool)
        direct[::_STRIDE, ::_STRIDE, ::_STRIDE] = True
        stride = _STRIDE // 2
        while stride >= 1:
            # nodes new at this stride: odd multiples of `stride` along 1, 2 or 3 axes
            idx = [np.arange(n) for n in shape]
            on = [i % stride == 0 for i in idx]
            odd = [(i % stride == 0) & ((i // stride) % 2 == 1) for i in idx]
            n_odd = (odd[0].astype(np.int8)[:, None, None] + odd[1].astype(np.int8)[None, :, None]
                     + odd[2].astype(np.int8)[None, None, :])
            on_all = on[0][:, None, None] & on[1][None, :, None] & on[2][None, None, :]
            reach = stride * voxel_size * np.sqrt(n_odd) * 1.01   # distance to the farthest coarse node used
            direct |= on_all & (n_odd > 0) & (dist <= reach)
            stride //= 2
        pos = [org[a] + voxel_size * torch.arange(shape[a], dtype=torch.float32) for a in range(3)]
        nodes = torch.stack(torch.meshgrid(*pos, indexing="ij"), -1)[torch.from_numpy(direct)]
        tree = _WindingTree.build(vertices - centre, faces)
        bar.total = (bar.total or 0) + -(-len(nodes) // _CHUNK)
        w = np.full(shape, np.nan)
        w[direct] = _winding(tree, nodes, 2.0, bar).numpy()
        sides = _face_sides(tree, tri, 0.01 * voxel_size, bar)
    stride = _STRIDE
    while stride > 1:
        half = stride // 2
        coarse = torch.from_numpy(np.ascontiguousarray(w[::stride, ::stride, ::stride]))
        fine = torch.nn.functional.interpolate(coarse[None, None], size=tuple(2 * n - 1 for n in coarse.shape),
                                               mode="trilinear", align_corners=True)[0, 0].numpy()
        target = w[::half, ::half, ::half]  # a view: filling it fills w
        missing = np.isnan(target)
        target[missing] = fine[missing]
        stride = half
    if report.inverted:
        w, sides = -w, -sides
    return np.where(w > 0.5, -dist, dist).astype(np.float32), face.numpy().astype(np.int32), sides


def _face_sides(tree: _WindingTree, tri: torch.Tensor, offset: float, bar) -> np.ndarray:
    """Winding numbers just in front of and behind every triangle's centroid, (F, 2) float32.

    A boundary triangle has about 0 on one side and 1 on the other; a triangle inside the solid (a part pushed into
    another, as a teapot's spout) has about 1 on both sides, and a flap outside about 0 on both: queries near the
    surface take the sign of the side they are on from here (:mod:`torchhand.kernels.sdf_surface`).
    """
    n = torch.linalg.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], dim=-1)
    n = n / n.norm(dim=-1, keepdim=True).clamp_min(1e-30)
    c = tri.mean(1)
    pts = torch.cat([c + offset * n, c - offset * n])
    bar.total = (bar.total or 0) + -(-len(pts) // _CHUNK)
    w = _winding(tree, pts, 2.0, bar).numpy()
    return np.stack([w[:len(tri)], w[len(tri):]], 1).astype(np.float32)


def _grid_layout(vertices: np.ndarray, voxel_size: float, padding: float) -> tuple[np.ndarray, tuple[int, int, int]]:
    lo, hi = vertices.min(0) - padding, vertices.max(0) + padding
    cells = np.ceil((hi - lo) / voxel_size / _STRIDE).astype(np.int64) * _STRIDE  # multiple of the stride
    n = np.maximum(cells, _STRIDE) + 1
    if int(np.prod(n)) > _MAX_NODES:
        raise InputValueError(
            f"voxel_size: {voxel_size} m gives a {tuple(int(x) for x in n)} grid (more than {_MAX_NODES} nodes); "
            "use a larger voxel_size or a smaller padding"
        )
    centre = 0.5 * (lo + hi)
    origin = centre - 0.5 * voxel_size * (n - 1)
    return origin, tuple(int(x) for x in n)


def mesh_content_hash(mesh: trimesh.Trimesh) -> str:
    """sha256 hex digest of ``mesh``'s vertices (float64, C order) and faces (int64, C order) bytes."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(mesh.vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(mesh.faces, dtype=np.int64).tobytes())
    return h.hexdigest()


def _cache_path(mesh: trimesh.Trimesh, voxel_size: float, padding: float, cache_dir) -> Path:
    """Cache file of the grid of ``mesh`` at ``voxel_size`` and ``padding`` (metres), in ``cache_dir`` or the default."""
    key = hashlib.sha256(
        f"{mesh_content_hash(mesh)}|{float(voxel_size)!r}|{float(padding)!r}|{BUILD_VERSION}".encode()
    ).hexdigest()[:32]
    return _cache_root(cache_dir) / f"sdf_{key}.npz"


def _cache_root(cache_dir) -> Path:
    if cache_dir is not None:
        return Path(cache_dir)
    env = os.environ.get("TORCHHAND_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "torchhand" / "sdf"


def _read_cache(path: Path, shape: tuple) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """Cached (values, origin, face, sides), or None when absent or unreadable (a bad file is rebuilt and
    overwritten)."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            values, origin = np.asarray(z["values"]), np.asarray(z["origin"])
            face, sides = np.asarray(z["face"]), np.asarray(z["sides"])
            version = str(z["version"])
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        return None
    if version != BUILD_VERSION or values.shape != tuple(shape) or origin.shape != (3,) or face.shape != values.shape:
        return None
    return values, origin, face, sides


def _write_cache(path: Path, values: np.ndarray, origin: np.ndarray, voxel_size: float, face: np.ndarray,
                 sides: np.ndarray) -> None:
    """Write atomically (temporary file in the same folder, then os.replace); an unwritable cache is skipped."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=path.stem, suffix=".tmp.npz", dir=path.parent)
    except OSError:
        return
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, values=values.astype(np.float32), origin=origin, voxel_size=voxel_size,
                     face=face.astype(np.int32), sides=sides.astype(np.float32), version=BUILD_VERSION)
        os.replace(tmp, path)
    except OSError:
        Path(tmp).unlink(missing_ok=True)
