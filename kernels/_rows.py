"""Batches of at least two rows.

A batched matrix-vector product of one row takes another code path than the same row in a larger batch (BLAS's
``gemv`` instead of the batched product; torch's ``matmul`` also folds a batch of one into a single matrix
product), and its last bits differ. A kernel whose answer for a row must not depend on the rest of its batch (the
synthesis search runs one search alone or many together, docs/synthesis.md) therefore never works on a batch of one:
a lone row is doubled, and the copy computes the same numbers as the original.
"""

from __future__ import annotations

import torch

__all__ = ["at_least_two"]


def at_least_two(index: torch.Tensor) -> torch.Tensor:
    """Row indices (n,) long, a lone index repeated (2,): writing the results back through them writes the same
    value twice."""
    return index.repeat(2) if index.numel() == 1 else index
