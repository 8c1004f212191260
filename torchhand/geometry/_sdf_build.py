"""Building signed distance grids from triangle meshes: winding numbers, unsigned distances, layout, disk cache.

The grid type and its queries live in :mod:`torchhand.geometry.sdf` (:class:`~torchhand.geometry.sdf.SDFGrid`); this module is the
machinery behind :meth:`SDFGrid.from_mesh <torchhand.geometry.sdf.SDFGrid.from_mesh>`. Conventions (see
:mod:`torchhand.conventions`): metres; the SDF is NEGATIVE INSIDE the object and positive outside; points are given
in the mesh (object) frame.

How a grid is built
    * layout: the mesh's bounding box plus padding, rounded up so that each axis has 8 m + 1 nodes
      (:func:`_grid_layout`); node (i, j, k) sits at ``origin + voxel_size * (i, j, k)``.
    * magnitude: exact point-triangle distances. Within two voxels of the surface every node gets the exact
      distance to its nearest triangle; farther out the nearest triangle is propagated (distance transform, then
      fast sweeping) and the exact distance to it is taken (see :func:`_grid_distance` for the measured error);
    * sign: generalized winding number (Jacobson et al. 2013), computed with a Barnes-Hut tree over Morton-ordered
      triangles (second-order far-field expansion, Barill et al. 2018; exact solid angles in the near field).
      ``w > 0.5`` is inside. Small holes and seams move the winding number only near the hole, so open scans keep
      a sign; a mesh whose winding number is ambiguous (between 0.2 and 0.8) over a large part of the region it
      encloses is reported as too open (:class:`~torchhand.errors.MeshError`).
    * grids are cached on disk (npz, written atomically) keyed by the mesh content hash, voxel size, padding
      and the builder's version, in ``$TORCHHAND_CACHE`` or ``~/.cache/torchhand/sdf``.
    * a build (and :func:`winding_number`) runs torch single-threaded and restores the thread count afterwards:
      it is thousands of small operations that intra-op threads do not speed up and that stall on a shared CPU.

This module does not import :mod:`torchhand.geometry.sdf` (which imports it), so there is no import cycle.
"""

from __future__ import annotations

import contextlib
import hashlib
import math
import os
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
import trimesh

from ..errors import InputTypeError, InputValueError, MeshError

__all__ = [
    "InsideReport",
    "inside_report",
    "winding_number",
    "BUILD_VERSION",
]

BUILD_VERSION = "2"
"""Version of the grid builder; part of the cache key (bump it when the values a build produces change)."""

_MAX_NODES = 64_000_000      # refuse grids larger than this (memory); ask for a larger voxel
_AMBIGUOUS = (0.2, 0.8)     # winding numbers in this open interval count as ambiguous
_MAX_AMBIGUOUS_FRACTION = 0.25
_CHUNK = 2048
_BAND = 2.0                 # exact-distance band half-width, voxels
_SWEEPS = 1                 # fast-sweeping rounds (6 directions each) outside the band
_PAIRS_PER_CHUNK = 2_000_000
_STRIDE = 8                 # coarsest winding-number lattice, in voxels; grid sizes are 8 m + 1


# --------------------------------------------------------------------------------------------------------------
# inside / outside


class InsideReport(NamedTuple):
    """Whether a mesh's generalized winding number separates an inside from an outside.

    robust: True when the mesh has an inside (few ambiguous winding numbers)
    inverted: True when the winding number is about -1 inside (inward-facing normals)
    inside_fraction: fraction of probe points inside, float in [0, 1]
    ambiguous_fraction: ambiguous probes / (ambiguous + inside probes), float in [0, 1]
    message: one line describing the result
    """

    robust: bool
    inverted: bool
    inside_fraction: float
    ambiguous_fraction: float
    message: str


def inside_report(mesh: trimesh.Trimesh, *, resolution: int = 16) -> InsideReport:
    """Whether ``mesh`` has an inside, from its winding number on a ``resolution``^3 lattice in its bounding box.

    A probe is inside when w >= 0.8 and ambiguous when 0.2 < w < 0.8 (after flipping the sign of w for meshes
    with inward normals). The mesh is robust when some probe is inside and at most 25 % of the inside-or-ambiguous
    probes are ambiguous: small holes and seams pass (the Stanford bunny: 0.1 %, the bigym mug: 2 %); single
    sheets, triangle soups and zero-thickness shells do not (trimesh's soup.stl: 62 %). :meth:`SDFGrid.from_mesh`
    and :meth:`torchhand.geometry.objects.RigidObject.from_trimesh` both use this test.
    """
    vertices, faces = _clean_arrays(mesh)
    lo, hi = vertices.min(0), vertices.max(0)
    axes = [np.linspace(lo[a], hi[a], resolution + 2)[1:-1] for a in range(3)]
    probes = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    w = winding_number(vertices, faces, probes)
    return _report(w)


def _report(w: np.ndarray) -> InsideReport:
    inverted = bool((w < -0.5).sum() > (w > 0.5).sum())
    if inverted:
        w = -w
    inside = int((w >= _AMBIGUOUS[1]).sum())
    ambiguous = int(((w > _AMBIGUOUS[0]) & (w < _AMBIGUOUS[1])).sum())
    amb_frac = ambiguous / max(inside + ambiguous, 1)
    robust = inside > 0 and amb_frac <= _MAX_AMBIGUOUS_FRACTION
    msg = (
        f"winding number >= {_AMBIGUOUS[1]} at {inside} of {w.size} probes and ambiguous "
        f"({_AMBIGUOUS[0]} < w < {_AMBIGUOUS[1]}) at {ambiguous}: {amb_frac:.0%} of the enclosed region is "
        f"ambiguous (limit {_MAX_AMBIGUOUS_FRACTION:.0%})"
    )
    return InsideReport(robust, inverted, inside / max(w.size, 1), amb_frac, msg)


def winding_number(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, *, beta: float = 2.0) -> np.ndarray:
    """Generalized winding number of a triangle soup at ``points`` (Barnes-Hut, second-order far field).

    Args:
        vertices: mesh vertices, (V, 3), metres
        faces: triangles, (F, 3), int vertex indices
        points: query points, (N, 3), metres
        beta: far-field acceptance ratio (distance > beta * node radius); 2 as in Barill et al. 2018.

    Computed in float32 relative to the mesh centre (absolute error about 1e-2 near the surface, from the
    far-field expansion; the near field is exact).

    Returns:
        w: winding numbers, (N,), float64; about 1 inside a closed outward-oriented surface, 0 outside.
    """
    vertices = np.asarray(vertices, np.float64)
    centre = 0.5 * (vertices.min(0) + vertices.max(0))
    with _one_thread():
        tree = _WindingTree.build(vertices - centre, np.asarray(faces, np.int64))
        pts = torch.as_tensor(np.asarray(points, np.float64).reshape(-1, 3) - centre, dtype=torch.float32)
        return _winding(tree, pts, beta, _NullBar()).numpy().astype(np.float64)


def _winding(tree: "_WindingTree", pts: torch.Tensor, beta: float, bar) -> torch.Tensor:
    out = torch.empty(len(pts), dtype=pts.dtype)
    for s in range(0, len(pts), _CHUNK):
        out[s:s + _CHUNK] = tree.query(pts[s:s + _CHUNK], beta)
        bar.update(1)
    return out


@dataclass(frozen=True)
class _WindingTree:
    """Implicit 8-ary tree over Morton-sorted triangles: level k node i holds triangles [i 8^k, (i+1) 8^k).

    ``levels[k-1]`` packs per node (n, 14): centre c (area-weighted centroid, 3), area vector A (3), the symmetric
    second moment S = sym(sum_t a_t (x_t - c)^T) as (Sxx, Syy, Szz, 2Sxy, 2Sxz, 2Syz), trace S, radius^2.
    Far field (|c - p| > beta r): Omega ~= A.d / |d|^3 + (tr S - 3 d^T S d / |d|^2) / |d|^3 with d = c - p.
    """

    tris: torch.Tensor                 # (F_pad, 3, 3) sorted, padded with degenerate triangles
    levels: tuple                      # levels[k-1]: (n_k, 14)

    @staticmethod
    def build(vertices: np.ndarray, faces: np.ndarray, dtype: torch.dtype = torch.float32) -> "_WindingTree":
        tri = torch.as_tensor(vertices[faces], dtype=torch.float64)  # (F, 3, 3)
        cen = tri.mean(1)
        lo, hi = cen.min(0).values, cen.max(0).values
        q = ((cen - lo) / (hi - lo).clamp_min(1e-12) * 1023).round().long()
        order = torch.argsort(_spread_bits(q[:, 0]) | (_spread_bits(q[:, 1]) << 1) | (_spread_bits(q[:, 2]) << 2))
        tri = tri[order]
        f = len(tri)
        depth = max(1, math.ceil(math.log(max(f / 64.0, 1.0), 8))) if f > 8 else 1
        pad = (-f) % (8 ** depth)
        if pad:
            tri = torch.cat([tri, tri[-1:, :1].expand(pad, 3, 3)], 0)  # degenerate: zero area, zero solid angle
        cen = tri.mean(1)
        av = 0.5 * torch.linalg.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        area = av.norm(dim=-1)
        levels = []
        for k in range(1, depth + 1):
            s = 8 ** k
            n = len(tri) // s
            a_sum = area.view(n, s).sum(1)
            c = torch.where(
                (a_sum > 0)[:, None],
                (area[:, None] * cen).view(n, s, 3).sum(1) / a_sum.clamp_min(1e-300)[:, None],
                cen.view(n, s, 3).mean(1),
            )
            y = cen.view(n, s, 3) - c[:, None]
            A = av.view(n, s, 3).sum(1)
            M = torch.einsum("nsi,nsj->nij", av.view(n, s, 3), y)
            S = 0.5 * (M + M.transpose(1, 2))
            six = torch.stack([S[:, 0, 0], S[:, 1, 1], S[:, 2, 2], 2 * S[:, 0, 1], 2 * S[:, 0, 2], 2 * S[:, 1, 2]], -1)
            r2 = (tri.view(n, s * 3, 3) - c[:, None]).square().sum(-1).amax(1)
            levels.append(torch.cat([c, A, six, six[:, :3].sum(-1, keepdim=True), r2[:, None]], -1).to(dtype))
        return _WindingTree(tri.to(dtype), tuple(levels))

    def query(self, p: torch.Tensor, beta: float) -> torch.Tensor:
        """Winding numbers at ``p (N, 3)`` (same dtype as the tree)."""
        n_top = len(self.levels[-1])
        w = p.new_zeros(len(p))
        q = torch.arange(len(p)).repeat_interleave(n_top)
        node = torch.arange(n_top).repeat(len(p))
        eight = torch.arange(8)
        for data in reversed(self.levels):
            nd = data.index_select(0, node)
            d = nd[:, :3] - p.index_select(0, q)
            dsq = d * d
            d2 = dsq.sum(-1)
            far = d2 > (beta * beta) * nd[:, 13]
            prod = torch.stack([d[:, 0] * d[:, 1], d[:, 0] * d[:, 2], d[:, 1] * d[:, 2]], -1)
            dsd = (dsq * nd[:, 6:9]).sum(-1) + (prod * nd[:, 9:12]).sum(-1)
            inv2 = 1.0 / d2
            term = ((nd[:, 3:6] * d).sum(-1) + nd[:, 12] - 3.0 * dsd * inv2) * inv2 * inv2.sqrt()
            w.index_add_(0, q, torch.where(far, term, torch.zeros_like(term)))
            keep = (~far).nonzero().squeeze(1)
            q = q.index_select(0, keep).repeat_interleave(8)
            node = (node.index_select(0, keep)[:, None] * 8 + eight).reshape(-1)
        w.index_add_(0, q, _solid_angle(self.tris.index_select(0, node) - p.index_select(0, q)[:, None]))
        return w / (4.0 * math.pi)


def _solid_angle(t: torch.Tensor) -> torch.Tensor:
    """Signed solid angle of triangles ``t (M, 3, 3)`` relative to the origin (Van Oosterom & Strackee)."""
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    la, lb, lc = a.norm(dim=-1), b.norm(dim=-1), c.norm(dim=-1)
    det = (a * torch.linalg.cross(b, c)).sum(-1)
    den = la * lb * lc + (a * b).sum(-1) * lc + (a * c).sum(-1) * lb + (b * c).sum(-1) * la
    return 2.0 * torch.atan2(det, den)


def _spread_bits(x: torch.Tensor) -> torch.Tensor:
    """Insert two zero bits between the low 10 bits of ``x`` (Morton code helper)."""
    x = x & 0x3FF
    x = (x | (x << 16)) & 0x030000FF
    x = (x | (x << 8)) & 0x0300F00F
    x = (x | (x << 4)) & 0x030C30C3
    x = (x | (x << 2)) & 0x09249249
    return x


# --------------------------------------------------------------------------------------------------------------
# unsigned distance on the grid


def _grid_distance(tri: torch.Tensor, origin: torch.Tensor, voxel_size: float, shape: tuple, bar) -> torch.Tensor:
    """Unsigned distance from every grid node to the triangles ``tri (F, 3, 3)``, (Nx, Ny, Nz), float32.

    1. Band: every node within ``_BAND`` voxels of a triangle gets its exact distance. Nodes are enumerated per
       triangle from the bounding boxes of a subdivision of the triangle into pieces at most two voxels long, so
       large triangles do not enumerate their whole bounding box.
    2. Outside the band, each node takes the closest triangle of its nearest band node (Euclidean distance
       transform), then one fast-sweeping pass in the six axis directions lets every node try the closest
       triangle of its predecessor. Distances stay exact distances to a real triangle (upper bounds of the true
       distance); the propagated closest triangle is almost always the right one (measured against trimesh on 2000
       random nodes: mean error below 0.01 voxel, 99th percentile about 0.06 voxel, worst 0.2 voxel, on an
       icosphere, the Stanford bunny and the bigym mug).
    """
    from scipy import ndimage

    n_nodes = int(np.prod(shape))
    band = _BAND * voxel_size
    strides = torch.tensor([shape[1] * shape[2], shape[2], 1])
    best = torch.full((n_nodes,), math.inf, dtype=tri.dtype)
    pieces = _band_boxes(tri, origin, voxel_size, shape, band)
    bar.total = (bar.total or 0) + len(pieces) + 6 * _SWEEPS
    kept_flat, kept_d, kept_tid = [], [], []
    for lo, count, owner in pieces:
        total = count.prod(1)
        box = torch.repeat_interleave(torch.arange(len(total)), total)
        local = torch.arange(int(total.sum())) - torch.repeat_interleave(torch.cumsum(total, 0) - total, total)
        c = count[box]
        iz, rest = local % c[:, 2], local // c[:, 2]
        idx = lo[box] + torch.stack([rest // c[:, 1], rest % c[:, 1], iz], -1)
        p = origin + voxel_size * idx.to(tri.dtype)
        tid = owner[box]
        t = tri[tid]
        d = (_closest_point_on_triangle(p, t[:, 0], t[:, 1], t[:, 2]) - p).norm(dim=-1)
        ok = d <= band
        kept_flat.append((idx[ok] * strides).sum(-1))
        kept_d.append(d[ok])
        kept_tid.append(tid[ok])
        bar.update(1)
    flat, d, tid = torch.cat(kept_flat), torch.cat(kept_d), torch.cat(kept_tid)
    best.scatter_reduce_(0, flat, d, "amin")
    win = d == best[flat]
    n_tri = len(tri)
    closest = torch.full((n_nodes,), n_tri, dtype=torch.long)
    closest.scatter_reduce_(0, flat[win], tid[win], "amin")  # ties: the smallest triangle index (deterministic)
    closest = torch.where(closest == n_tri, torch.full_like(closest, -1), closest)
    in_band = (closest >= 0).view(shape).numpy()
    if not in_band.any():  # cannot happen for a non-empty mesh inside the grid; keep the sweep well defined
        raise MeshError("mesh: no grid node lies near the surface")
    _, nearest = ndimage.distance_transform_edt(~in_band, return_indices=True)
    closest = closest.view(shape)[tuple(torch.from_numpy(i) for i in nearest)].contiguous()
    best = best.view(shape).clone()
    far = torch.from_numpy(~in_band)
    pos = [origin[a] + voxel_size * torch.arange(shape[a], dtype=tri.dtype) for a in range(3)]
    nodes = torch.stack(torch.meshgrid(*pos, indexing="ij"), -1)
    t = tri[closest[far]]
    best[far] = (_closest_point_on_triangle(nodes[far], t[:, 0], t[:, 1], t[:, 2]) - nodes[far]).norm(dim=-1)
    for axis in [0, 1, 2] * _SWEEPS:
        bm, cm, pm = best.movedim(axis, 0), closest.movedim(axis, 0), nodes.movedim(axis, 0)
        n = bm.shape[0]
        for order, step in ((range(1, n), -1), (range(n - 2, -1, -1), 1)):
            for i in order:
                cand = cm[i + step].reshape(-1)
                p = pm[i].reshape(-1, 3)
                t = tri[cand]
                d = (_closest_point_on_triangle(p, t[:, 0], t[:, 1], t[:, 2]) - p).norm(dim=-1).view(bm[i].shape)
                better = d < bm[i]
                bm[i] = torch.where(better, d, bm[i])
                cm[i] = torch.where(better, cand.view(cm[i].shape), cm[i])
            bar.update(1)
    return best


def _band_boxes(tri: torch.Tensor, origin: torch.Tensor, voxel_size: float, shape: tuple, band: float):
    """Node-index boxes (lo (K, 3), count (K, 3), owner (K,)) covering the band of every triangle, in chunks."""
    tri64 = tri.double()
    edges = (tri64 - tri64[:, [1, 2, 0]]).norm(dim=-1).amax(1)
    m_all = (edges / (2.0 * voxel_size)).ceil().clamp_min(1).long()
    los, his, owners = [], [], []
    for m in torch.unique(m_all).tolist():
        sel = (m_all == m).nonzero().squeeze(1)
        i, j = torch.meshgrid(torch.arange(m), torch.arange(m), indexing="ij")
        keep = (i + j) <= m - 1
        i, j = i[keep].double(), j[keep].double()
        u = torch.stack([i, i + 1, i, i + 1], -1) / m      # parallelogram cells covering the triangle
        v = torch.stack([j, j, j + 1, j + 1], -1) / m
        t = tri64[sel]
        e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
        pts = t[:, None, None, 0] + u[None, :, :, None] * e1[:, None, None] + v[None, :, :, None] * e2[:, None, None]
        los.append(pts.amin(2).reshape(-1, 3))
        his.append(pts.amax(2).reshape(-1, 3))
        owners.append(sel.repeat_interleave(len(i)))
    lo, hi, owner = torch.cat(los), torch.cat(his), torch.cat(owners)
    n = torch.tensor(shape)
    org = origin.double()
    ilo = torch.minimum(torch.maximum(((lo - band - org) / voxel_size).ceil().long(), torch.zeros(3, dtype=torch.long)), n - 1)
    ihi = torch.minimum(torch.maximum(((hi + band - org) / voxel_size).floor().long(), torch.zeros(3, dtype=torch.long)), n - 1)
    count = (ihi - ilo + 1).clamp_min(0)
    total = count.prod(1)
    chunk = (torch.cumsum(total, 0) - total) // _PAIRS_PER_CHUNK
    bounds = [0] + ((chunk[1:] != chunk[:-1]).nonzero().squeeze(1) + 1).tolist() + [len(total)]
    return [(ilo[s:e], count[s:e], owner[s:e]) for s, e in zip(bounds[:-1], bounds[1:])]


def _closest_point_on_triangle(p: torch.Tensor, a: torch.Tensor, b: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
    """Closest point to ``p`` on triangle (a, b, c), all (M, 3) -> (M, 3) (Ericson, Real-Time Collision Detection 5.1.5)."""
    ab, ac = b - a, c - a
    ap, bp, cp = p - a, p - b, p - c
    d1, d2 = (ab * ap).sum(-1), (ac * ap).sum(-1)
    d3, d4 = (ab * bp).sum(-1), (ac * bp).sum(-1)
    d5, d6 = (ab * cp).sum(-1), (ac * cp).sum(-1)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    tiny = torch.finfo(p.dtype).tiny

    def safe(num, den):
        return num / torch.where(den.abs() > tiny, den, torch.full_like(den, tiny))

    denom = va + vb + vc
    v, w = safe(vb, denom), safe(vc, denom)
    res = a + ab * v[:, None] + ac * w[:, None]                       # interior
    e43, e56 = d4 - d3, d5 - d6
    m = (va <= 0) & (e43 >= 0) & (e56 >= 0)                             # edge BC
    res = torch.where(m[:, None], b + (c - b) * safe(e43, e43 + e56)[:, None], res)
    m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)                               # edge AC
    res = torch.where(m[:, None], a + ac * safe(d2, d2 - d6)[:, None], res)
    res = torch.where(((d6 >= 0) & (d5 <= d6))[:, None], c, res)        # vertex C
    m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)                               # edge AB
    res = torch.where(m[:, None], a + ab * safe(d1, d1 - d3)[:, None], res)
    res = torch.where(((d3 >= 0) & (d4 <= d3))[:, None], b, res)        # vertex B
    res = torch.where(((d1 <= 0) & (d2 <= 0))[:, None], a, res)         # vertex A
    return res


# --------------------------------------------------------------------------------------------------------------
# grid build and cache


def _build_values(vertices, faces, origin, voxel_size, shape, progress) -> np.ndarray:
    """Signed distances at the grid nodes, (Nx, Ny, Nz) float32, negative inside.

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
        dist = _grid_distance(tri, org, voxel_size, shape, bar).numpy()
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
        w = -w
    return np.where(w > 0.5, -dist, dist).astype(np.float32)


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


def _clean_arrays(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) float64 and non-degenerate faces (F, 3) int64; MeshError if nothing is left."""
    if not isinstance(mesh, trimesh.Trimesh):
        raise InputTypeError(f"mesh: expected a trimesh.Trimesh, got {type(mesh).__name__}")
    v = np.asarray(mesh.vertices, np.float64)
    f = np.asarray(mesh.faces, np.int64).reshape(-1, 3)
    if len(f) == 0 or len(v) == 0:
        raise MeshError("mesh is empty (no faces)")
    if not np.isfinite(v).all():
        raise MeshError("mesh has non-finite vertex coordinates")
    t = v[f]
    area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=-1)
    keep = area > 0
    if not keep.any():
        raise MeshError("mesh is degenerate (all faces have zero area)")
    return v, f[keep]


def mesh_content_hash(mesh: trimesh.Trimesh) -> str:
    """sha256 hex digest of ``mesh``'s vertices (float64, C order) and faces (int64, C order) bytes."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(mesh.vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(mesh.faces, dtype=np.int64).tobytes())
    return h.hexdigest()


def _cache_path(mesh: trimesh.Trimesh, voxel_size: float, padding: float, cache_dir) -> Path:
    """Cache file of the grid of ``mesh`` at ``voxel_size`` and ``padding`` (metres), in ``cache_dir`` or the default."""
    key = hashlib.sha256(
        f"{mesh_content_hash(mesh)}|{voxel_size!r}|{padding!r}|{BUILD_VERSION}".encode()
    ).hexdigest()[:32]
    return _cache_root(cache_dir) / f"sdf_{key}.npz"


def _cache_root(cache_dir) -> Path:
    if cache_dir is not None:
        return Path(cache_dir)
    env = os.environ.get("TORCHHAND_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "torchhand" / "sdf"


def _read_cache(path: Path, shape: tuple) -> tuple[np.ndarray, np.ndarray] | None:
    """Cached (values, origin), or None when absent or unreadable (a bad file is rebuilt and overwritten)."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            values, origin = np.asarray(z["values"]), np.asarray(z["origin"])
            version = str(z["version"])
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        return None
    if version != BUILD_VERSION or values.shape != tuple(shape) or origin.shape != (3,):
        return None
    return values, origin


def _write_cache(path: Path, values: np.ndarray, origin: np.ndarray, voxel_size: float) -> None:
    """Write atomically (temporary file in the same folder, then os.replace); an unwritable cache is skipped."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=path.stem, suffix=".tmp.npz", dir=path.parent)
    except OSError:
        return
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, values=values.astype(np.float32), origin=origin, voxel_size=voxel_size,
                     version=BUILD_VERSION)
        os.replace(tmp, path)
    except OSError:
        Path(tmp).unlink(missing_ok=True)


@contextlib.contextmanager
def _one_thread():
    """Run torch single-threaded inside the block, then restore the thread count.

    Grid builds and winding numbers are thousands of small tensor operations: intra-op threads gain little on
    them and stall badly when the CPU is shared (measured on 2 busy cores: 6 s with one thread, 24 s with two).
    """
    n = torch.get_num_threads()
    if n == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)


class _NullBar:
    total = None

    def update(self, n: int = 1) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        pass


def _progress_bar(enabled: bool):
    if not enabled:
        return _NullBar()
    from tqdm.auto import tqdm

    return tqdm(total=0, desc="SDF grid", unit="step", leave=False)
