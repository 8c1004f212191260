"""Euler angles as BVH uses them: intrinsic rotations in channel order (``Yrotation Xrotation Zrotation`` is
``Ry @ Rx @ Rz``), all six Tait-Bryan orders; matrices to angles and back, and unwrapping along time.

Conventions: angles in radians, (..., 3) in the order's axis order; rotation matrices (..., 3, 3), column vectors.
"""

from __future__ import annotations

import math

import torch

from ..errors import InputTypeError, InputValueError, ShapeError

__all__ = ["euler_to_matrix", "matrix_to_euler", "unwrap_euler"]


def euler_to_matrix(angles: torch.Tensor, order: str) -> torch.Tensor:
    """Rotation matrices from intrinsic Euler angles.

    Args:
        angles: rotation angles in the order of ``order``, (..., 3), radians
        order: three axis letters, e.g. ``"YXZ"``: ``R = Ry(a0) @ Rx(a1) @ Rz(a2)`` (BVH channel order)

    Returns:
        R: rotation matrices, (..., 3, 3)
    """
    order = order.upper()
    if len(order) != 3 or any(c not in "XYZ" for c in order):
        raise InputValueError(f"order: expected three letters from X, Y, Z, got '{order}'")
    if angles.shape[-1:] != (3,):
        raise InputValueError(f"angles: expected shape (..., 3), got {tuple(angles.shape)}")
    R = _axis_rotation(angles[..., 0], "XYZ".index(order[0]))
    for k in (1, 2):
        R = R @ _axis_rotation(angles[..., k], "XYZ".index(order[k]))
    return R


def matrix_to_euler(R: torch.Tensor, order: str, *, reference: torch.Tensor | None = None) -> torch.Tensor:
    """Intrinsic Euler angles of rotation matrices, the inverse of :func:`euler_to_matrix`.

    Args:
        R: rotation matrices, (..., 3, 3), float32 or float64 (not checked for orthonormality)
        order: three different axis letters, e.g. ``"ZXY"``: ``R = Rz(a0) @ Rx(a1) @ Ry(a2)`` (BVH channel order)
        reference: optional angles to stay close to, (..., 3) like the output, radians; of the two Euler
            solutions and their ``2 pi`` shifts per angle the one nearest to it (sum of squares) is returned, and
            at gimbal lock the first angle is taken from it

    Returns:
        angles: (..., 3), radians, dtype and device of ``R``, with ``euler_to_matrix(angles, order) == R``.
        Without ``reference``: middle angle in ``[-pi/2, pi/2]``, the others in ``(-pi, pi]``; at gimbal lock
        (middle angle +-pi/2, where only the sum or difference of the others is defined) the first angle is 0.

    Raises:
        InputValueError: ``order`` is not three different letters from X, Y, Z.
        InputTypeError: ``R`` is not a floating-point tensor.
        ShapeError: ``R`` is not (..., 3, 3) or ``reference`` does not have the output's shape.
    """
    i, j, k = _tait_bryan_axes(order)
    if not isinstance(R, torch.Tensor) or not R.is_floating_point():
        raise InputTypeError(f"R: expected a floating-point tensor, got {getattr(R, 'dtype', type(R).__name__)}")
    if R.ndim < 2 or R.shape[-2:] != (3, 3):
        raise ShapeError(f"R: expected shape (..., 3, 3), got {tuple(R.shape)}")
    out_shape = tuple(R.shape[:-2]) + (3,)
    ref = None if reference is None else torch.as_tensor(reference, dtype=R.dtype, device=R.device)
    if ref is not None and tuple(ref.shape) != out_shape:
        raise ShapeError(f"reference: expected shape {out_shape} (the output's), got {tuple(ref.shape)}")
    e = 1.0 if (j - i) % 3 == 1 else -1.0                      # +1 for the cyclic orders XYZ, YZX, ZXY
    # column k of R is (e sin b, -e sin a cos b, cos a cos b) on axes (i, j, k): the first angle, taking cos b >= 0
    y, x = -e * R[..., j, k], R[..., k, k]
    a = torch.atan2(y, x)
    lock = torch.hypot(y, x) <= 4 * torch.finfo(R.dtype).eps   # cos b == 0: only a +- c is defined
    a = torch.where(lock, torch.zeros_like(a) if ref is None else ref[..., 0], a)
    # M = Ri(a)^T R = Rj(b) Rk(c): its column k is (e sin b, 0, cos b), its row j is (e sin c, cos c, 0)
    M = _axis_rotation(a, i).transpose(-1, -2) @ R
    b = torch.atan2(e * M[..., i, k], M[..., k, k])
    c = torch.atan2(e * M[..., j, i], M[..., j, j])
    angles = torch.stack([a, b, c], dim=-1)
    return angles if ref is None else _nearest_equivalent(angles, ref)


def unwrap_euler(angles: torch.Tensor, order: str) -> torch.Tensor:
    """Make a sequence of Euler angles continuous: each frame becomes the equivalent triple (of the two Euler
    solutions and their ``2 pi`` shifts per angle) nearest to the previous frame's result; the first frame is
    kept. The rotations are unchanged.

    Args:
        angles: Euler angles per frame, (F, 3), radians, in the intrinsic ``order`` (three different axes)
        order: e.g. ``"YXZ"``

    Returns:
        (F, 3), radians, dtype and device of ``angles``

    Raises:
        InputValueError: ``order`` is not three different letters from X, Y, Z.
        ShapeError: ``angles`` is not (F, 3).
    """
    _tait_bryan_axes(order)
    if angles.ndim != 2 or angles.shape[-1] != 3:
        raise ShapeError(f"angles: expected shape (F, 3), got {tuple(angles.shape)}")
    if angles.shape[0] < 2:
        return angles.clone()
    two = torch.stack([angles, _twin(angles)])                        # (2, F, 3): solution 0 and its twin
    # transition per frame: the solution nearest (modulo 2 pi) to each solution of the previous frame
    d = _wrap(two[None, :, 1:] - two[:, None, :-1]).square().sum(-1)  # (prev 2, cur 2, F-1)
    nxt = (d[:, 1] < d[:, 0]).long()                                  # (2, F-1): chosen solution given prev
    const = nxt[0] == nxt[1]
    swap = (nxt[0] == 1) & (nxt[1] == 0)
    F = angles.shape[0]
    idx = torch.arange(F, device=angles.device)
    is_const = torch.cat([torch.ones(1, dtype=torch.bool, device=angles.device), const])
    value = torch.cat([torch.zeros(1, dtype=torch.long, device=angles.device), nxt[0]])
    last_const = torch.cummax(torch.where(is_const, idx, torch.zeros_like(idx)), 0).values
    swaps = torch.cumsum(torch.cat([torch.zeros(1, dtype=torch.long, device=angles.device), swap.long()]), 0)
    state = (value[last_const] + swaps - swaps[last_const]) % 2       # (F,) 0 or 1 per frame
    chosen = torch.where(state[:, None] == 1, two[1], two[0])
    # whole turns added to each frame, counted in integers so that nothing accumulates rounding error
    turns = torch.round((chosen[:-1] - chosen[1:]) / (2 * math.pi))
    turns = torch.cat([torch.zeros_like(turns[:1]), torch.cumsum(turns, 0)])
    return chosen + (2 * math.pi) * turns


def _tait_bryan_axes(order: str) -> tuple[int, int, int]:
    """Axis indices of an order with three different letters; InputValueError otherwise."""
    up = order.upper() if isinstance(order, str) else ""
    if len(up) != 3 or set(up) != set("XYZ"):
        raise InputValueError(f"order: expected three different letters from X, Y, Z (e.g. 'ZXY'), got '{order}'")
    return "XYZ".index(up[0]), "XYZ".index(up[1]), "XYZ".index(up[2])


def _twin(angles: torch.Tensor) -> torch.Tensor:
    """The other Euler solution of the same rotation, ``(a + pi, pi - b, c + pi)``, (..., 3), radians."""
    a, b, c = angles.unbind(-1)
    return torch.stack([a + math.pi, math.pi - b, c + math.pi], dim=-1)


def _wrap(x: torch.Tensor) -> torch.Tensor:
    """Angles wrapped to [-pi, pi)."""
    return torch.remainder(x + math.pi, 2 * math.pi) - math.pi


def _nearest_equivalent(angles: torch.Tensor, ref: torch.Tensor) -> torch.Tensor:
    """Of ``angles``, its twin and their 2 pi shifts per angle, the triple nearest to ``ref``, (..., 3)."""
    best = [ref + _wrap(cand - ref) for cand in (angles, _twin(angles))]
    d0 = (best[0] - ref).square().sum(-1, keepdim=True)
    d1 = (best[1] - ref).square().sum(-1, keepdim=True)
    return torch.where(d1 < d0, best[1], best[0])


def _axis_rotation(angle: torch.Tensor, axis: int) -> torch.Tensor:
    """Rotation by ``angle (...)`` radians about coordinate axis ``axis`` (0, 1, 2), (..., 3, 3)."""
    c, s = torch.cos(angle), torch.sin(angle)
    one, zero = torch.ones_like(angle), torch.zeros_like(angle)
    if axis == 0:
        rows = ((one, zero, zero), (zero, c, -s), (zero, s, c))
    elif axis == 1:
        rows = ((c, zero, s), (zero, one, zero), (-s, zero, c))
    else:
        rows = ((c, -s, zero), (s, c, zero), (zero, zero, one))
    return torch.stack([torch.stack(r, dim=-1) for r in rows], dim=-2)
