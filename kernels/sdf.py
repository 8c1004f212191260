"""Batched trilinear queries of a signed distance grid, with the analytic gradient.

Pure tensor math (imports torch and math only). Conventions: metres; the SDF is negative inside.

Grid layout
    ``values[i, j, k]`` is the signed distance at the node ``origin + voxel_size * (i, j, k)``, so the grid box is
    ``[origin, origin + voxel_size * (N - 1)]`` per axis (N = number of nodes along that axis, at least 2).

Query
    Inside the box the value is the trilinear interpolation of the 8 nodes around the point. Outside, the point
    is clamped to the box and the Euclidean distance from the point to the box is added:
    ``sdf(p) = trilinear(clamp(p)) + |p - clamp(p)|``. For a grid holding a true distance field this is an upper
    bound of the true distance (the field is 1-Lipschitz) that grows like the distance far away, and it is
    continuous across the box faces. The gradient returned is the exact gradient of this function: the analytic
    trilinear gradient on the axes that are not clamped plus the unit vector ``(p - clamp(p)) / |p - clamp(p)|``.

Speed
    All arithmetic runs on contiguous per-axis vectors (B*P,). The 8 corner values come either from 8
    one-dimensional ``index_select`` gathers of the flattened grid, or, when the caller passes the optional
    ``corners = pack_corners(values)`` table (computed once per grid, 8x its memory), from one gather of a row of 8
    (up to twice as fast on large batches of scattered points when the grid does not fit in the CPU cache; about
    the same on small grids). Indices are int32 when the grid allows it.
    NaN points give NaN results (indices are clamped into the grid, so they never read out of bounds).

Autograd
    Differentiable with respect to ``points`` (the backward multiplies by the analytic gradient computed in the
    forward pass). Not differentiable with respect to ``values``, ``origin`` or ``voxel_size``, and not twice
    differentiable (the trilinear Hessian is not provided).
"""

from __future__ import annotations

import torch
from torch.autograd.function import once_differentiable

__all__ = ["sdf_trilinear", "sdf_trilinear_with_grad", "pack_corners"]


def sdf_trilinear(
    values: torch.Tensor,
    origin: torch.Tensor,
    voxel_size: float,
    points: torch.Tensor,
    *,
    corners: torch.Tensor | None = None,
) -> torch.Tensor:
    """Signed distance at ``points`` by trilinear interpolation of a grid.

    Args:
        values: signed distance at the grid nodes, (Nx, Ny, Nz), metres, negative inside; N >= 2 per axis
        origin: position of node (0, 0, 0), (3,), metres
        voxel_size: node spacing, float, metres
        points: query points in the grid's frame, (B, P, 3), metres; same device and dtype as ``values``
        corners: optional ``pack_corners(values)``, (C, 8): one gather per point instead of eight (up to twice as
            fast on large batches and large grids; costs 8x the grid's memory, so compute it once per grid)

    Returns:
        sd: signed distance, (B, P), metres; differentiable w.r.t. ``points``.
    """
    _check(values, origin, voxel_size, points, corners)
    return _SDFTrilinear.apply(values, origin, float(voxel_size), points, False, corners)


def sdf_trilinear_with_grad(
    values: torch.Tensor,
    origin: torch.Tensor,
    voxel_size: float,
    points: torch.Tensor,
    *,
    corners: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Signed distance and its analytic gradient at ``points``.

    Args: as :func:`sdf_trilinear`.

    Returns:
        sd: signed distance, (B, P), metres; differentiable w.r.t. ``points``
        grad: d sd / d points, (B, P, 3), unitless (not differentiable)
    """
    _check(values, origin, voxel_size, points, corners)
    return _SDFTrilinear.apply(values, origin, float(voxel_size), points, True, corners)


# ---------------------------------------------------------------------------------------------------------------


def _check(values: torch.Tensor, origin: torch.Tensor, voxel_size: float, points: torch.Tensor,
           corners: torch.Tensor | None) -> None:
    """Shape/dtype checks only (no tensor values are read). Kernels raise built-in errors."""
    if values.dim() != 3 or min(values.shape) < 2:
        raise ValueError(f"values: expected shape (Nx, Ny, Nz) with N >= 2, got {tuple(values.shape)}")
    if tuple(origin.shape) != (3,):
        raise ValueError(f"origin: expected shape (3,), got {tuple(origin.shape)}")
    if points.dim() != 3 or points.shape[-1] != 3:
        raise ValueError(f"points: expected shape (B, P, 3), got {tuple(points.shape)}")
    if not values.is_floating_point() or points.dtype != values.dtype or origin.dtype != values.dtype:
        raise TypeError(
            f"values, origin, points: expected one floating dtype, got {values.dtype}, {origin.dtype}, {points.dtype}"
        )
    if points.device != values.device or origin.device != values.device:
        raise ValueError(f"values, origin, points: expected one device, got {values.device}, {origin.device}, "
                         f"{points.device}")
    if not float(voxel_size) > 0:
        raise ValueError(f"voxel_size: expected a positive float, got {voxel_size}")
    if corners is not None:
        cells = (values.shape[0] - 1) * (values.shape[1] - 1) * (values.shape[2] - 1)
        if tuple(corners.shape) != (cells, 8) or corners.dtype != values.dtype:
            raise ValueError(f"corners: expected pack_corners(values) of shape ({cells}, 8) and dtype {values.dtype}, "
                             f"got {tuple(corners.shape)} {corners.dtype}")


def _sdf_impl(
    values: torch.Tensor,
    origin: torch.Tensor,
    voxel_size: float,
    points: torch.Tensor,
    need_grad: bool,
    corners: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Forward: sd (B, P) and, if ``need_grad``, the gradient (B, P, 3)."""
    b, p_count, _ = points.shape
    p = points.reshape(-1, 3)
    nx, ny, nz = values.shape
    inv = 1.0 / voxel_size
    index_dtype = torch.int32 if values.numel() < 2**31 - 1 else torch.int64
    fs, out, idx = [], [], []
    for a, n in enumerate((nx, ny, nz)):
        u = (p[:, a] - origin[a]) * inv          # grid coordinate along axis a
        uc = u.clamp(0.0, n - 1.0)               # clamped into the box
        i0 = uc.clamp(max=n - 2.0).floor_()      # cell index, so that i0 + 1 is a node
        fs.append(uc - i0)                       # fraction in the cell, [0, 1]
        out.append(u - uc)                       # offset outside the box, voxels (0 inside)
        idx.append(i0.to(index_dtype))
    if corners is not None:  # one gather of the 8 corners of each cell
        base = torch.add(torch.add(idx[2], idx[1], alpha=nz - 1), idx[0], alpha=(ny - 1) * (nz - 1))
        base.clamp_(0, corners.shape[0] - 1)   # NaN points: any valid cell, the result stays NaN
        packed = corners.index_select(0, base)
        g = [packed[:, k] for k in range(8)]
    else:  # 8 gathers of the flattened grid
        flat = values.reshape(-1)
        sx, sy = ny * nz, nz
        base = torch.add(torch.add(idx[2], idx[1], alpha=sy), idx[0], alpha=sx)
        base.clamp_(0, flat.numel() - 1 - (sx + sy + 1))
        g = [flat.index_select(0, base + (dz + dy * sy + dx * sx) if (dx or dy or dz) else base)
             for dz in (0, 1) for dy in (0, 1) for dx in (0, 1)]
    fx, fy, fz = fs
    a = [torch.lerp(g[k], g[k + 4], fz) for k in range(4)]       # z done: a[2 dy + dx]
    b0, b1 = torch.lerp(a[0], a[2], fy), torch.lerp(a[1], a[3], fy)
    dist_out = torch.sqrt(out[0] * out[0] + out[1] * out[1] + out[2] * out[2])
    sd = torch.add(torch.lerp(b0, b1, fx), dist_out, alpha=voxel_size)
    if not need_grad:
        return sd.view(b, p_count), None
    dvx = b1 - b0
    dvy = torch.lerp(a[2] - a[0], a[3] - a[1], fx)
    dvz = torch.lerp(torch.lerp(g[4] - g[0], g[6] - g[2], fy), torch.lerp(g[5] - g[1], g[7] - g[3], fy), fx)
    inv_out = 1.0 / dist_out.clamp_min(torch.finfo(sd.dtype).tiny)
    grad = sd.new_empty(sd.shape[0], 3)
    for a, (dv, o) in enumerate(zip((dvx, dvy, dvz), out)):
        # inside the box along this axis: the trilinear slope; clamped: the box-distance direction
        torch.where(o == 0, dv * inv, o * inv_out, out=grad[:, a])
    return sd.view(b, p_count), grad.view(b, p_count, 3)


def pack_corners(values: torch.Tensor) -> torch.Tensor:
    """The 8 corner values of every grid cell, for a single-gather query.

    Args:
        values: grid node values, (Nx, Ny, Nz)

    Returns:
        corners: (C, 8) with C = (Nx-1)(Ny-1)(Nz-1); row ``i (Ny-1)(Nz-1) + j (Nz-1) + k`` holds the cell whose
        lowest node is (i, j, k), corner ``4 dz + 2 dy + dx`` being node (i+dx, j+dy, k+dz). 8x the grid's memory.
    """
    if values.dim() != 3 or min(values.shape) < 2:
        raise ValueError(f"values: expected shape (Nx, Ny, Nz) with N >= 2, got {tuple(values.shape)}")
    nx, ny, nz = values.shape
    cells = [values[dx:nx - 1 + dx, dy:ny - 1 + dy, dz:nz - 1 + dz] for dz in (0, 1) for dy in (0, 1) for dx in (0, 1)]
    return torch.stack(cells, -1).reshape(-1, 8)


def _sdf_backward_impl(grad_sd: torch.Tensor, grad: torch.Tensor) -> torch.Tensor:
    """Backward: d loss / d points (B, P, 3) from d loss / d sd (B, P) and the saved gradient (B, P, 3)."""
    return grad_sd.unsqueeze(-1) * grad


class _SDFTrilinear(torch.autograd.Function):
    @staticmethod
    def forward(ctx, values, origin, voxel_size, points, with_grad, corners):
        need = bool(ctx.needs_input_grad[3])
        sd, grad = _sdf_impl(values, origin, voxel_size, points, need or with_grad, corners)
        if need:
            ctx.save_for_backward(grad)
        if with_grad:
            ctx.mark_non_differentiable(grad)
            return sd, grad
        return sd

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_sd, *unused):
        (grad,) = ctx.saved_tensors
        return None, None, None, _sdf_backward_impl(grad_sd, grad), None, None
