"""Signed distance grids of object meshes, robust to open meshes.

Conventions (see :mod:`torchhand.conventions`): metres; the SDF is NEGATIVE INSIDE the object and positive
outside; points are given in the mesh (object) frame.

Grid layout
    ``values[i, j, k]`` is the signed distance at the grid node ``origin + voxel_size * (i, j, k)``: ``origin``
    is the position of node (0, 0, 0) (the centre of voxel (0, 0, 0) when each node is seen as a voxel centre).
    The grid box is ``[origin, origin + voxel_size * (N - 1)]`` per axis. Queries interpolate trilinearly between
    nodes; outside the box a point is clamped to the box and its distance to the box is added (see
    :func:`torchhand.kernels.sdf.sdf_trilinear`).

How a grid is built (:meth:`SDFGrid.from_mesh`)
    Exact point-triangle distances for the magnitude, the generalized winding number (Barnes-Hut tree) for the
    sign, so open scans keep a sign and meshes too open to have an inside are refused; grids are cached on disk
    keyed by the mesh content hash, voxel size, padding and :data:`BUILD_VERSION`. The machinery lives in
    :mod:`torchhand.geometry._sdf_build` and its stages; :func:`inside_report` / :func:`winding_number` (re-exported
    here) in :mod:`torchhand.geometry._sdf_winding`.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
import trimesh

from .._tree import tree_to
from ..conventions import check_finite, check_tensor
from ..errors import InputTypeError, InputValueError, ShapeError
from ..kernels.sdf import _sdf_impl, pack_corners, sdf_trilinear, sdf_trilinear_with_grad
# The builder's helpers are looked up in this module's namespace by SDFGrid.from_mesh (tests patch them here).
from ._sdf_build import BUILD_VERSION, _build_values, _cache_path, _grid_layout, _read_cache, _write_cache
from ._sdf_common import _clean_arrays, _one_thread
from ._sdf_surface import SurfaceTables, query_near_surface, surface_tables
from ._sdf_winding import InsideReport, inside_report, winding_number

__all__ = [
    "SDFGrid",
    "SurfaceTables",
    "InsideReport",
    "inside_report",
    "winding_number",
    "BUILD_VERSION",
]

_PACK_MAX_NODES = 4_000_000  # grids up to this size keep an 8-corner table for faster queries


@dataclass(frozen=True, eq=False)
class SDFGrid:
    """A signed distance field sampled on a regular grid (negative inside, metres).

    Fields
        values: signed distance at the grid nodes, (Nx, Ny, Nz), metres, negative inside
        origin: position of node (0, 0, 0) in the mesh frame, (3,), metres; node (i, j, k) sits at
            ``origin + voxel_size * (i, j, k)`` (node = voxel centre)
        voxel_size: node spacing, float, metres
        surface: the mesh tables for exact queries near the surface (:meth:`query_surface`), each node's nearest
            triangle among them, :class:`SurfaceTables`; None for a grid made of values only (then
            :meth:`query_surface` falls back to the grid's values and gradient). :meth:`from_mesh` fills it.
        corners: derived, not a constructor argument: ``pack_corners(values)``, ((Nx-1)(Ny-1)(Nz-1), 8), the
            8 corner values of every cell for single-gather queries; None for grids above 4M nodes (8x memory)

    ``values`` and ``origin`` share device and dtype; use :meth:`to` to move both.
    """

    values: torch.Tensor
    origin: torch.Tensor
    voxel_size: float
    surface: SurfaceTables | None = field(default=None, repr=False)
    corners: torch.Tensor | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        check_tensor(self.values, "values", (None, None, None))
        check_tensor(self.origin, "origin", (3,))
        if min(self.values.shape) < 2:
            raise ShapeError(f"values: expected at least 2 nodes per axis, got {tuple(self.values.shape)}")
        if self.origin.dtype != self.values.dtype or self.origin.device != self.values.device:
            raise InputTypeError(
                f"origin: expected dtype {self.values.dtype} on {self.values.device} like values, "
                f"got {self.origin.dtype} on {self.origin.device}"
            )
        if not (isinstance(self.voxel_size, (float, int)) and math.isfinite(self.voxel_size) and self.voxel_size > 0):
            raise InputValueError(f"voxel_size: expected a finite positive float, got {self.voxel_size!r}")
        packed = pack_corners(self.values.detach()) if self.values.numel() <= _PACK_MAX_NODES else None
        object.__setattr__(self, "corners", packed)

    # ------------------------------------------------------------------------------------------------ building
    @classmethod
    def from_mesh(
        cls,
        mesh: trimesh.Trimesh,
        voxel_size: float,
        *,
        padding: float | None = None,
        cache_dir: str | os.PathLike | None = None,
        progress: bool = True,
        dtype: torch.dtype = torch.float32,
    ) -> "SDFGrid":
        """Build (or load from the disk cache) the SDF grid of ``mesh``.

        Args:
            mesh: triangle mesh, mesh frame, metres; need not be watertight (see :mod:`torchhand.geometry._sdf_build`).
            voxel_size: node spacing, metres (e.g. 0.002).
            padding: margin around the mesh's bounding box, metres; default ``max(0.15 * largest extent,
                6 * voxel_size)``. The grid box is then rounded up so that each axis has 8 m + 1 nodes.
            cache_dir: cache directory; default ``$TORCHHAND_CACHE`` or ``~/.cache/torchhand/sdf``.
            progress: show a tqdm progress bar on long builds.
            dtype: the grid's dtype; the node values are float32 (as stored in the cache) cast to it, the same
                values as ``from_mesh(...).to(dtype=dtype)`` without building the corner table twice.

        Returns:
            a CPU grid (use :meth:`to` for another device).

        Raises:
            InputTypeError, InputValueError: bad ``mesh``, ``voxel_size`` or ``padding``.
            MeshError: empty or degenerate mesh, or a mesh too open to have an inside.
        """
        if not isinstance(mesh, trimesh.Trimesh):
            raise InputTypeError(f"mesh: expected a trimesh.Trimesh, got {type(mesh).__name__}")
        voxel_size = _positive(voxel_size, "voxel_size")
        vertices, faces = _clean_arrays(mesh)
        extent = float(np.max(vertices.max(0) - vertices.min(0)))
        if padding is None:
            padding = max(0.15 * extent, 6.0 * voxel_size)
        padding = _positive(padding, "padding", allow_zero=True)
        origin, shape = _grid_layout(vertices, voxel_size, padding)

        path = _cache_path(mesh, voxel_size, padding, cache_dir)
        cached = _read_cache(path, shape)
        if cached is not None:
            values, origin, face, sides = cached
        else:
            with _one_thread():
                values, face, sides = _build_values(vertices, faces, origin, voxel_size, shape, progress)
            _write_cache(path, values, origin, voxel_size, face, sides)
        return cls(values=torch.from_numpy(values.astype(np.float32)).to(dtype),
                   origin=torch.from_numpy(origin.astype(np.float32)).to(dtype), voxel_size=float(voxel_size),
                   surface=surface_tables(vertices, faces, face, sides, dtype))

    # ------------------------------------------------------------------------------------------------ queries
    def query(self, points: torch.Tensor, *, check: bool = False) -> torch.Tensor:
        """Signed distance at ``points``.

        Args:
            points: query points, (B, P, 3), mesh frame, metres; same device and dtype as the grid.
            check: also raise :class:`InputValueError` on NaN/inf points (forces a host sync).

        Returns:
            sd: signed distance, (B, P), metres, negative inside. Differentiable w.r.t. ``points``.
        """
        self._check_points(points, check)
        return sdf_trilinear(self.values, self.origin, self.voxel_size, points, corners=self.corners)

    def query_with_grad(self, points: torch.Tensor, *, check: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
        """Signed distance and its analytic gradient at ``points``.

        Args:
            points: query points, (B, P, 3), mesh frame, metres; same device and dtype as the grid.
            check: also raise :class:`InputValueError` on NaN/inf points (forces a host sync).

        Returns:
            sd: signed distance, (B, P), metres, negative inside
            grad: gradient of ``sd`` w.r.t. the points (the outward direction near the surface), (B, P, 3)
        """
        self._check_points(points, check)
        return sdf_trilinear_with_grad(self.values, self.origin, self.voxel_size, points, corners=self.corners)

    def query_with_grad_unchecked(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`query_with_grad` without its point checks and outside autograd (nothing to differentiate): the
        same values for a caller that queries a few hundred points many times and differentiates by itself (the
        per-frame synthesis of :mod:`torchhand.manipulation.synth`, where the wrapper costs a fifth of a query).
        ``points`` (B, P, 3) on the grid's device and dtype; returns (sd (B, P), grad (B, P, 3))."""
        with torch.no_grad():
            return _sdf_impl(self.values, self.origin, float(self.voxel_size), points, True, self.corners)

    def query_surface(self, points: torch.Tensor, *, band: float | None = None
                      ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Signed distance, outward normal and closest surface point, exact near the surface.

        Within ``band`` of the surface (by the grid's value; default two voxel diagonals) the distance is measured
        to the nearest of the triangles nearest to the point's cell corners, the normal is the exact gradient (the
        face normal on a face, inside the normal cone at an edge or a vertex) and the sign comes from the
        pseudo-normal within half a voxel diagonal of the surface (so a wall thinner than a voxel has an inside);
        see :mod:`torchhand.kernels.sdf_surface`. Elsewhere, or for a grid without :attr:`surface`, the grid's
        trilinear value and normalised gradient. Not differentiable (no autograd graph).

        Args:
            points: query points, (B, P, 3), mesh frame, metres; same device and dtype as the grid.
            band: metres; None: ``2 sqrt(3) voxel_size``.

        Returns:
            sd: signed distance, (B, P), metres, negative inside
            normal: outward unit normal, (B, P, 3)
            closest: closest surface point, (B, P, 3), mesh frame
        """
        self._check_points(points, False)
        B, P, _ = points.shape
        with torch.no_grad():
            sd, grad = _sdf_impl(self.values, self.origin, float(self.voxel_size), points, True, self.corners)
            flat = points.reshape(-1, 3)
            if self.surface is None:
                n = grad.reshape(-1, 3)
                n = n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)
                s = sd.reshape(-1)
                out = (s, n, flat - s[:, None] * n)
            else:
                band = 2.0 * math.sqrt(3.0) * self.voxel_size if band is None else float(band)
                out = query_near_surface(self.values, self.origin, float(self.voxel_size), self.surface, flat,
                                         sd.reshape(-1), grad.reshape(-1, 3), band)
        return out[0].view(B, P), out[1].view(B, P, 3), out[2].view(B, P, 3)

    def to(self, device: Any = None, dtype: torch.dtype | None = None) -> "SDFGrid":
        """Copy with ``values`` and ``origin`` on ``device`` and cast to ``dtype``."""
        return tree_to(self, device=device, dtype=dtype)

    @property
    def shape(self) -> tuple[int, int, int]:
        """Number of nodes per axis, (Nx, Ny, Nz)."""
        return tuple(self.values.shape)  # type: ignore[return-value]

    @property
    def box(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Grid box corners (lo (3,), hi (3,)), mesh frame, metres."""
        n = torch.tensor(self.values.shape, dtype=self.origin.dtype, device=self.origin.device) - 1
        return self.origin, self.origin + self.voxel_size * n

    def _check_points(self, points: torch.Tensor, check: bool) -> None:
        check_tensor(points, "points", (None, None, 3))
        if points.dtype != self.values.dtype or points.device != self.values.device:
            raise InputTypeError(
                f"points: expected dtype {self.values.dtype} on {self.values.device} like the grid, got "
                f"{points.dtype} on {points.device}; convert the points or call SDFGrid.to()"
            )
        if check:
            check_finite(points, "points")


def _positive(x: Any, name: str, *, allow_zero: bool = False) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float, np.floating, np.integer)):
        raise InputTypeError(f"{name}: expected a float, got {type(x).__name__}")
    x = float(x)
    if not math.isfinite(x) or x < 0 or (x == 0 and not allow_zero):
        raise InputValueError(f"{name}: expected a finite {'non-negative' if allow_zero else 'positive'} "
                              f"number, got {x}")
    return x

