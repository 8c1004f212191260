"""The interaction trajectory (C(t), theta_r(t), root reference) and its ``interaction.npz`` file.

:class:`Interaction` is what resynthesis (:mod:`torchhand.interaction.resynth`) replays; the file format is
docs/interaction_capture.md. Units: seconds, radians, metres; compliance rad/(N m) (root linear m/N).
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._atomic import atomic_bytes
from .._npz import read_npz
from ..errors import FileFormatError, InputValueError

__all__ = ["Interaction", "load_interaction", "save_interaction"]


@dataclass(frozen=True, eq=False)
class Interaction:
    """An interaction trajectory (C, theta_r) of T frames, NumPy float64.

    fps: frames per second; joint_names: (D,) str; C: compliance of the 6 + D coordinates, (T, 6 + D), rad/(N m)
    (root linear m/N); theta_r: reference joints, (T, D), radians; root_theta_r: reference root coordinates,
    (T, 6): rotation vector (rad) and translation (m) relative to ``root_origin``; root_origin: (4, 4) world pose
    the root coordinates are relative to, or None (the scene's first wrist pose); source: "measured" | "synthetic" |
    "inferred" | "constructed" | ""; theta: the captured coordinates the reference was made from, (T, 6 + D), or
    None (the file's optional ``theta``; theta - theta_r = C tau is how far the object holds each joint open)
    """

    fps: float
    joint_names: tuple
    C: np.ndarray
    theta_r: np.ndarray
    root_theta_r: np.ndarray
    root_origin: np.ndarray | None = None
    source: str = ""
    theta: np.ndarray | None = None

    @property
    def T(self) -> int:
        return int(self.theta_r.shape[0])

    @property
    def duration(self) -> float:
        return (self.T - 1) / self.fps


def _key(data, name: str, path, shape=None) -> np.ndarray:
    if name not in data:
        raise FileFormatError(f"{path}: missing key '{name}'")
    x = np.asarray(data[name])
    if shape is not None and (x.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, x.shape))):
        want = "(" + ", ".join("?" if s is None else str(s) for s in shape) + ")"
        raise FileFormatError(f"{path}: '{name}' has shape {x.shape}, expected {want}")
    return x


def load_interaction(path) -> Interaction:
    """Read ``interaction.npz`` (docs/interaction_capture.md): ``C``, ``theta_r``, ``root_theta_r``, ``fps``,
    ``joint_names``; optional ``root_origin`` (4, 4), ``source`` and ``theta`` (T, 6 + D).

    raises: MissingFileError, FileFormatError (missing key, wrong shape or dtype, T mismatch), InputValueError
        (NaN or inf with the first bad frame, fps <= 0, compliance < 0)
    """
    path = Path(path)
    data = read_npz(path, ("C", "theta_r", "root_theta_r", "fps", "joint_names"),
                    "an interaction (docs/interaction_capture.md)")
    theta_r = _key(data, "theta_r", path, (None, None)).astype(np.float64)
    T, D = theta_r.shape
    C = _key(data, "C", path, (T, 6 + D)).astype(np.float64)
    root = _key(data, "root_theta_r", path, (T, 6)).astype(np.float64)
    fps = float(_key(data, "fps", path, ()))
    names = tuple(str(n) for n in _key(data, "joint_names", path, (D,)))
    origin = _key(data, "root_origin", path, (4, 4)).astype(np.float64) if "root_origin" in data else None
    if not fps > 0:
        raise InputValueError(f"{path}: fps must be > 0, got {fps}")
    for name, x in (("theta_r", theta_r), ("C", C), ("root_theta_r", root)):
        bad = ~np.isfinite(x).reshape(T, -1).all(1)
        if bad.any():
            raise InputValueError(f"{path}: '{name}' is not finite at frame {int(np.argmax(bad))}")
    if (C < 0).any():
        raise InputValueError(f"{path}: 'C' has negative compliance at frame {int(np.argmax((C < 0).any(1)))}")
    if T < 2:
        raise InputValueError(f"{path}: needs at least 2 frames, got {T}")
    source = str(data["source"]) if "source" in data else ""
    theta = _key(data, "theta", path, (T, 6 + D)).astype(np.float64) if "theta" in data else None
    if theta is not None and not np.isfinite(theta).all():
        raise InputValueError(f"{path}: 'theta' is not finite at frame {int(np.argmax(~np.isfinite(theta).all(1)))}")
    return Interaction(fps, names, C, theta_r, root, origin, source, theta)


def save_interaction(inter: Interaction, path) -> Path:
    """Write an :class:`Interaction` as ``interaction.npz`` (atomically; the keys :func:`load_interaction` reads)."""
    data = {"C": inter.C, "theta_r": inter.theta_r, "root_theta_r": inter.root_theta_r, "fps": np.array(inter.fps),
            "joint_names": np.array(inter.joint_names), "source": np.array(inter.source),
            "names": np.array(("root_rx", "root_ry", "root_rz", "root_x", "root_y", "root_z") + inter.joint_names)}
    if inter.root_origin is not None:
        data["root_origin"] = inter.root_origin
    if inter.theta is not None:
        data["theta"] = inter.theta
    buf = io.BytesIO()
    np.savez_compressed(buf, **data)
    atomic_bytes(Path(path), buf.getvalue())
    return Path(path)
