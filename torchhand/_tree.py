"""One small helper that maps ``.to()``, indexing and ``where`` over the tensor fields of frozen dataclasses."""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, TypeVar

import torch

T = TypeVar("T")

__all__ = ["tree_map", "tree_to", "tree_index", "tree_where"]


def tree_map(fn: Callable[[torch.Tensor], torch.Tensor], obj: T) -> T:
    """Apply ``fn`` to every tensor field of a (nested) frozen dataclass, tuple or dict; other values are kept."""
    if isinstance(obj, torch.Tensor):
        return fn(obj)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        changes = {f.name: tree_map(fn, getattr(obj, f.name)) for f in dataclasses.fields(obj) if f.init}
        return dataclasses.replace(obj, **changes)
    if isinstance(obj, tuple) and hasattr(obj, "_fields"):  # NamedTuple
        return type(obj)(*(tree_map(fn, v) for v in obj))
    if isinstance(obj, tuple):
        return type(obj)(tree_map(fn, v) for v in obj)
    if isinstance(obj, dict):
        return type(obj)({k: tree_map(fn, v) for k, v in obj.items()})
    return obj


def tree_to(obj: T, device: Any = None, dtype: torch.dtype | None = None) -> T:
    """Move tensor fields to ``device``; floating fields are also cast to ``dtype`` (integer/bool fields keep theirs)."""

    def move(t: torch.Tensor) -> torch.Tensor:
        if t.is_floating_point() and dtype is not None:
            return t.to(device=device, dtype=dtype)
        return t.to(device=device) if device is not None else t

    return tree_map(move, obj)


def tree_index(obj: T, idx: Any) -> T:
    """Index the leading (batch) dimension of every tensor field."""
    return tree_map(lambda t: t[idx], obj)


def tree_where(mask: torch.Tensor, a: T, b: T) -> T:
    """Field-wise ``torch.where(mask, a, b)``; ``mask (B,)`` broadcasts over trailing dimensions."""
    fa = _leaves(a)
    fb = iter(_leaves(b))

    def pick(ta: torch.Tensor) -> torch.Tensor:
        tb = next(fb)
        m = mask.reshape(mask.shape + (1,) * (ta.dim() - mask.dim()))
        return torch.where(m, ta, tb)

    del fa
    return tree_map(pick, a)


def _leaves(obj: Any) -> list[torch.Tensor]:
    out: list[torch.Tensor] = []
    tree_map(lambda t: out.append(t) or t, obj)
    return out
