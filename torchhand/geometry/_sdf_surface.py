"""The mesh tables an SDF grid keeps for exact queries near the surface (:class:`SurfaceTables`), and the query.

Conventions (see :mod:`torchhand.conventions`): metres, mesh (object) frame; the SDF is negative inside; normals
here point OUT of the object. The query itself is the kernel :func:`torchhand.kernels.sdf_surface.surface_query`
(its docstring says what is exact and why); this module builds its tables from a mesh and picks the points near
the surface.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from torchhand.kernels.sdf_surface import surface_query

__all__ = ["SurfaceTables", "surface_tables", "query_near_surface"]


@dataclass(frozen=True, eq=False)
class SurfaceTables:
    """What a grid keeps of its mesh for exact queries near the surface.

    Fields
        node_face: each grid node's nearest triangle (index into ``triangles``), (Nx, Ny, Nz), int32
        triangles: the mesh's triangles as the grid was built from them, (F, 3, 3), metres, mesh frame
        pseudo_normals: unit pseudo-normal per triangle and Voronoi region, (F, 7, 3), on the side of the
            triangle's own normal (right-handed vertex order): the face, its edges AB, BC, CA (the normalised sum
            of the two faces' normals; the face's own on a boundary edge) and its vertices A, B, C (the
            angle-weighted sum over the vertex's triangles), in the region codes of
            :func:`torchhand.kernels.sdf_surface.closest_point_region`
        face_sides: winding number just in front of (along the triangle's normal) and behind each triangle, (F, 2):
            which of its sides is inside (above 0.5)
        neighbours: the triangle across each triangle's edges AB, BC, CA, (F, 3) long (itself across a boundary
            edge; one of them across an edge shared by more than two)
    """

    node_face: torch.Tensor
    triangles: torch.Tensor
    pseudo_normals: torch.Tensor
    face_sides: torch.Tensor
    neighbours: torch.Tensor


def surface_tables(vertices: np.ndarray, faces: np.ndarray, node_face: np.ndarray, face_sides: np.ndarray,
                   dtype: torch.dtype) -> SurfaceTables:
    """The tables of a mesh (``vertices (V, 3)``, ``faces (F, 3)``, the arrays the grid was built from), its
    nodes' nearest triangles ``node_face`` and its triangles' two-sided winding numbers ``face_sides (F, 2)``."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    tri = v[f]                                                                  # (F, 3, 3)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    pn = np.empty((len(f), 7, 3))
    pn[:, 0] = n
    pn[:, 1:4], nb = _edge_normals(f, n)
    pn[:, 4:7] = _vertex_normals(v, f, tri, n)[f]
    pn /= np.maximum(np.linalg.norm(pn, axis=-1, keepdims=True), 1e-300)
    return SurfaceTables(node_face=torch.from_numpy(np.ascontiguousarray(node_face, dtype=np.int32)),
                         triangles=torch.from_numpy(tri).to(dtype), pseudo_normals=torch.from_numpy(pn).to(dtype),
                         face_sides=torch.from_numpy(np.asarray(face_sides, np.float32)).to(dtype),
                         neighbours=torch.from_numpy(nb))


def _edge_normals(f: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per face and edge (AB, BC, CA): the sum of the normals of the faces sharing that edge, (F, 3, 3), and a face
    across it, (F, 3) int64 (the face itself on a boundary edge)."""
    a, b = f, np.roll(f, -1, axis=1)                                            # edges (a[:, e], b[:, e])
    key = np.sort(np.stack([a, b], -1).reshape(-1, 2), axis=1)                  # (3F, 2) undirected
    _, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    face_of = np.repeat(np.arange(len(f)), 3)
    total = np.zeros((inv.max() + 1, 3))
    np.add.at(total, inv, n[face_of])
    # the other face of each edge: per edge, the largest and smallest face index using it (one per side of a
    # manifold edge); a face takes whichever is not itself
    hi = np.full(inv.max() + 1, -1)
    lo = np.full(inv.max() + 1, len(f))
    np.maximum.at(hi, inv, face_of)
    np.minimum.at(lo, inv, face_of)
    other = np.where(hi[inv] != face_of, hi[inv], lo[inv])
    return total[inv].reshape(len(f), 3, 3), other.reshape(len(f), 3).astype(np.int64)


def _vertex_normals(v: np.ndarray, f: np.ndarray, tri: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(V, 3): the angle-weighted sum of the normals of each vertex's triangles."""
    out = np.zeros((len(v), 3))
    for k in range(3):
        e1 = tri[:, (k + 1) % 3] - tri[:, k]
        e2 = tri[:, (k + 2) % 3] - tri[:, k]
        cos = (e1 * e2).sum(-1) / (np.linalg.norm(e1, axis=-1) * np.linalg.norm(e2, axis=-1))
        np.add.at(out, f[:, k], np.arccos(np.clip(cos, -1.0, 1.0))[:, None] * n)
    return out


def query_near_surface(values: torch.Tensor, origin: torch.Tensor, voxel_size: float, tables: SurfaceTables,
                       points: torch.Tensor, grid_sd: torch.Tensor, grid_grad: torch.Tensor, band: float
                       ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Signed distance, outward normal and closest surface point at ``points`` (M, 3): exact (the kernel) where the
    grid's value ``grid_sd (M,)`` is within ``band`` metres of the surface, else the grid's value, its normalised
    gradient ``grid_grad (M, 3)`` and ``p - sd * normal``. Returns sd (M,), normal (M, 3), closest (M, 3)."""
    norm = grid_grad.norm(dim=-1, keepdim=True)
    normal = grid_grad / norm.clamp_min(1e-12)
    sd = grid_sd.clone()
    closest = points - sd[:, None] * normal
    near = (grid_sd.abs() <= band).nonzero().squeeze(-1)
    if near.numel() == 0:
        return sd, normal, closest
    p = points[near]
    n = torch.tensor(values.shape, device=p.device)
    cell = ((p - origin) / voxel_size).floor().long()
    cell = torch.minimum(cell.clamp_min(0), n - 2)                              # clamp into the grid
    corners = torch.tensor([[dx, dy, dz] for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)], device=p.device)
    ijk = cell[:, None] + corners                                               # (M', 8, 3)
    face = tables.node_face[ijk[..., 0], ijk[..., 1], ijk[..., 2]].long()       # (M', 8)
    sign_band = 0.5 * math.sqrt(3.0) * voxel_size
    s, nn, c, _ = surface_query(p, grid_sd[near], face, tables.triangles, tables.pseudo_normals, tables.face_sides,
                                sign_band, tables.neighbours)
    sd[near], normal[near], closest[near] = s, nn, c
    return sd, normal, closest
