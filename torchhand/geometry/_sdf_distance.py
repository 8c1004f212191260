"""Unsigned distance from the nodes of an SDF grid to a triangle mesh: exact point-triangle distances in a band
around the surface, propagated outward by a distance transform and fast sweeping (:func:`_grid_distance`).

A stage of the grid builder (:mod:`torchhand.geometry._sdf_build`). Conventions (see :mod:`torchhand.conventions`):
metres; grid node (i, j, k) at ``origin + voxel_size * (i, j, k)``.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from torchhand.kernels.sdf_surface import closest_point_region

from ..errors import MeshError

_BAND = 2.0                 # exact-distance band half-width, voxels
_SWEEPS = 1                 # fast-sweeping rounds (6 directions each) outside the band
_PAIRS_PER_CHUNK = 2_000_000


def _grid_distance(tri: torch.Tensor, origin: torch.Tensor, voxel_size: float, shape: tuple,
                   bar) -> tuple[torch.Tensor, torch.Tensor]:
    """Unsigned distance from every grid node to the triangles ``tri (F, 3, 3)``, (Nx, Ny, Nz), float32, and the
    index of the triangle it was measured to, (Nx, Ny, Nz) long (the nearest triangle as far as steps 1-2 find it).

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
    return best, closest


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
    return closest_point_region(p, a, b, c)[0]
