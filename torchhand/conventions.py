"""Conventions used everywhere in torchhand, declared once.

Units
    metres, seconds, radians, newtons, kilograms.
Rotations
    quaternions are (w, x, y, z); rotation matrices act on column vectors.
Transforms
    4x4 homogeneous, column-vector convention: ``p_world = T_world_link @ p_link``. A link pose
    ``T_world_link`` maps link-frame coordinates to world coordinates.
Hand frame
    The root (wrist) frame of a hand: origin at the wrist joint centre, +x from the wrist toward the
    fingertips, -z out of the palm (the palm faces -z), +y toward the thumb for a right hand. A left hand is
    the mirror image through the x-z plane, so its thumb points to -y.
Signed distance
    negative inside the object, positive outside, metres.
Contacts
    contact normals point INTO the object (the direction of the normal force the hand applies to it).
Wrenches
    (force, torque) about the object's centre of mass, world coordinates, (..., 6).
Shapes
    every batched tensor has one explicit leading batch dimension ``B``; variable-size sets are padded and come
    with a boolean mask.
"""

from __future__ import annotations


from dataclasses import dataclass
from types import MappingProxyType

import torch

from .errors import InputTypeError, InputValueError, ShapeError

__all__ = [
    "Tolerances",
    "TOLERANCES",
    "tolerances",
    "check_tensor",
    "check_finite",
    "check_transforms",
    "as_tensor",
]


@dataclass(frozen=True)
class Tolerances:
    """Per-dtype numerical tolerances (one immutable table, used by code and tests)."""

    eps: float          # machine epsilon of the dtype
    rotation: float     # allowed |R^T R - I| entry and |det R - 1| for a valid rotation
    fk: float           # FK agreement against references, metres
    jacobian: float     # Jacobian agreement against autograd
    sdf_grad: float     # finite-difference step for SDF gradient checks, metres


TOLERANCES = MappingProxyType(
    {
        torch.float32: Tolerances(eps=float(torch.finfo(torch.float32).eps), rotation=1e-4, fk=1e-5,
                                  jacobian=1e-4, sdf_grad=1e-3),
        torch.float64: Tolerances(eps=float(torch.finfo(torch.float64).eps), rotation=1e-6, fk=1e-9,
                                  jacobian=1e-8, sdf_grad=1e-5),
    }
)


def tolerances(dtype: torch.dtype) -> Tolerances:
    """Tolerances for ``dtype`` (float32 or float64)."""
    try:
        return TOLERANCES[dtype]
    except KeyError:
        raise InputTypeError(f"dtype: expected torch.float32 or torch.float64, got {dtype}") from None


def as_tensor(x, name: str, *, dtype: torch.dtype | None = None, device=None) -> torch.Tensor:
    """Convert array-likes to a floating tensor, naming ``name`` in the error if that is impossible."""
    if isinstance(x, torch.Tensor):
        t = x
    else:
        try:
            t = torch.as_tensor(x)
        except (TypeError, ValueError, RuntimeError) as err:
            raise InputTypeError(f"{name}: expected a tensor or array, got {type(x).__name__} ({err})") from None
    if dtype is None and not t.is_floating_point():
        dtype = torch.get_default_dtype()
    return t.to(device=device if device is not None else t.device, dtype=dtype if dtype is not None else t.dtype)


def check_tensor(x: torch.Tensor, name: str, shape: tuple, *, floating: bool = True) -> torch.Tensor:
    """Check ``x.shape`` against ``shape`` (ints are exact, ``None`` matches any size, ``str`` names a size).

    Returns ``x``. Raises :class:`ShapeError` naming the argument, the expected and the actual shape.
    """
    if not isinstance(x, torch.Tensor):
        raise InputTypeError(f"{name}: expected a torch.Tensor, got {type(x).__name__}")
    desc = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
    if x.dim() != len(shape) or any(isinstance(s, int) and s != d for s, d in zip(shape, x.shape)):
        raise ShapeError(f"{name}: expected shape {desc}, got {tuple(x.shape)}")
    if floating and not x.is_floating_point():
        raise InputTypeError(f"{name}: expected a floating-point tensor, got dtype {x.dtype}")
    return x


def check_finite(x: torch.Tensor, name: str) -> torch.Tensor:
    """Raise :class:`InputValueError` if ``x`` holds NaN or inf (forces a host sync: call at boundaries only)."""
    if not bool(torch.isfinite(x).all()):
        bad = (~torch.isfinite(x)).nonzero()
        raise InputValueError(f"{name}: contains NaN or inf (first at index {tuple(bad[0].tolist())})")
    return x


def check_transforms(T: torch.Tensor, name: str) -> torch.Tensor:
    """Check that ``T (..., 4, 4)`` are finite rigid transforms: orthonormal rotation with det +1, last row 0 0 0 1.

    Forces a host sync: public boundaries only.
    """
    if not isinstance(T, torch.Tensor) or T.dim() < 2 or tuple(T.shape[-2:]) != (4, 4):
        shape = tuple(T.shape) if isinstance(T, torch.Tensor) else type(T).__name__
        raise ShapeError(f"{name}: expected shape (..., 4, 4), got {shape}")
    check_finite(T, name)
    tol = tolerances(T.dtype if T.dtype in TOLERANCES else torch.float32).rotation
    tol = max(tol, 1e-6 * 100) if T.dtype == torch.float64 else tol
    R = T[..., :3, :3]
    eye = torch.eye(3, dtype=T.dtype, device=T.device)
    orth = (R.transpose(-1, -2) @ R - eye).abs().amax(dim=(-1, -2))
    det = torch.linalg.det(R)
    bottom = (T[..., 3, :] - T.new_tensor([0.0, 0.0, 0.0, 1.0])).abs().amax(dim=-1)
    bad = (orth > tol) | ((det - 1).abs() > tol) | (bottom > tol)
    if bool(bad.any()):
        idx = tuple(bad.nonzero()[0].tolist())
        raise InputValueError(
            f"{name}: transform at index {idx} is not rigid "
            f"(|R^T R - I| = {float(orth[idx]):.2e}, det R = {float(det[idx]):.6f}, tolerance {tol:.0e})"
        )
    return T


