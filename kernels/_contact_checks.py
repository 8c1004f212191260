"""Argument checks shared by :mod:`.contact_lcp` and :mod:`.contact_body`: a ValueError naming the function, the
argument, what was expected and what came."""

from __future__ import annotations

import torch


def _err(fn: str, name: str, expected, x) -> ValueError:
    got = tuple(x.shape) if isinstance(x, torch.Tensor) else type(x).__name__
    return ValueError(f"{fn}: {name} must have shape {expected}, got {got}")


def _check(fn: str, x, name: str, shape: tuple, like: torch.Tensor | None = None) -> None:
    if not isinstance(x, torch.Tensor) or tuple(x.shape) != tuple(shape):
        raise _err(fn, name, tuple(shape), x)
    if not x.is_floating_point():
        raise ValueError(f"{fn}: {name} must be floating point, got {x.dtype}")
    if like is not None and (x.dtype != like.dtype or x.device != like.device):
        raise ValueError(f"{fn}: {name} must be {like.dtype} on {like.device}, got {x.dtype} on {x.device}")
