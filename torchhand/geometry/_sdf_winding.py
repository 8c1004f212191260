"""Inside and outside of a triangle mesh: the generalized winding number (Jacobson et al. 2013) with a Barnes-Hut
tree over Morton-ordered triangles (second-order far-field expansion, Barill et al. 2018; exact solid angles in the
near field), and :func:`inside_report`, the test of whether an open mesh still has an inside.

``w > 0.5`` is inside. Small holes and seams move the winding number only near the hole, so open scans keep a sign;
a mesh whose winding number is ambiguous (between 0.2 and 0.8) over a large part of the region it encloses is too
open. Used by the grid builder (:mod:`torchhand.geometry._sdf_build`) for the sign of the SDF and by
:class:`torchhand.geometry.objects.RigidObject`; re-exported by :mod:`torchhand.geometry.sdf`. Conventions (see
:mod:`torchhand.conventions`): metres, mesh (object) frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch
import trimesh

from ._sdf_common import _clean_arrays, _NullBar, _one_thread

__all__ = ["InsideReport", "inside_report", "winding_number"]

_AMBIGUOUS = (0.2, 0.8)     # winding numbers in this open interval count as ambiguous
_MAX_AMBIGUOUS_FRACTION = 0.25
_CHUNK = 2048               # query points per tree query


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
