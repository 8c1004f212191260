"""Error types raised at torchhand's public boundaries.

Every error a user can cause is a subclass of :class:`TorchhandError` and of the matching built-in
(``ValueError``, ``TypeError`` or ``FileNotFoundError``), so callers can catch either. Messages name the argument,
what was expected and what was given. The CLI prints ``str(err)`` on one line and exits with code 2.
"""

from __future__ import annotations

__all__ = [
    "TorchhandError",
    "ShapeError",
    "InputValueError",
    "InputTypeError",
    "MissingFileError",
    "FileFormatError",
    "MeshError",
    "UnknownNameError",
    "MissingDependencyError",
]


class TorchhandError(Exception):
    """Base class of every error torchhand raises on bad input."""


class ShapeError(TorchhandError, ValueError):
    """A tensor or array has the wrong shape."""


class InputValueError(TorchhandError, ValueError):
    """A value is out of range, non-finite, or otherwise invalid (NaN, non-orthonormal rotation, ...)."""


class InputTypeError(TorchhandError, TypeError):
    """An argument has the wrong type."""


class MissingFileError(TorchhandError, FileNotFoundError):
    """A file or directory that was asked for does not exist."""


class FileFormatError(TorchhandError, ValueError):
    """A file exists but cannot be parsed (malformed BVH, TOML, MJCF, npz, mesh)."""


class MeshError(TorchhandError, ValueError):
    """A mesh is empty, degenerate, or too open to have an inside."""


class UnknownNameError(TorchhandError, KeyError):
    """A scene, joint, link or other name is not known. ``str()`` gives the plain message."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


class MissingDependencyError(TorchhandError, ImportError):
    """An optional extra that a requested feature needs is not installed; the message says how to install it."""
