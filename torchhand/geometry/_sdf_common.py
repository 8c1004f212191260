"""Shared by the SDF grid builder's stages (:mod:`torchhand.geometry._sdf_build`): the mesh arrays a build starts
from, torch single-threaded while it runs, and its progress bar.

Conventions (see :mod:`torchhand.conventions`): metres, mesh (object) frame.
"""

from __future__ import annotations

import contextlib

import numpy as np
import torch
import trimesh

from ..errors import InputTypeError, MeshError


def _clean_arrays(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) float64 and non-degenerate faces (F, 3) int64; MeshError if nothing is left."""
    if not isinstance(mesh, trimesh.Trimesh):
        raise InputTypeError(f"mesh: expected a trimesh.Trimesh, got {type(mesh).__name__}")
    v = np.asarray(mesh.vertices, np.float64)
    f = np.asarray(mesh.faces, np.int64).reshape(-1, 3)
    if len(f) == 0 or len(v) == 0:
        raise MeshError("mesh is empty (no faces)")
    if not np.isfinite(v).all():
        raise MeshError("mesh has non-finite vertex coordinates")
    t = v[f]
    area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=-1)
    keep = area > 0
    if not keep.any():
        raise MeshError("mesh is degenerate (all faces have zero area)")
    return v, f[keep]


@contextlib.contextmanager
def _one_thread():
    """Run torch single-threaded inside the block, then restore the thread count.

    Grid builds and winding numbers are thousands of small tensor operations: intra-op threads gain little on
    them and stall badly when the CPU is shared (measured on 2 busy cores: 6 s with one thread, 24 s with two).
    """
    n = torch.get_num_threads()
    if n == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)


class _NullBar:
    total = None

    def update(self, n: int = 1) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        pass


def _progress_bar(enabled: bool):
    if not enabled:
        return _NullBar()
    from tqdm.auto import tqdm

    return tqdm(total=0, desc="SDF grid", unit="step", leave=False)
