"""The BVH clip record (:class:`BVHClip`) and its forward kinematics (module docstring of
:mod:`torchhand.scene.bvh`: the local transform ``Translate(t) @ R(ch1) @ R(ch2) @ R(ch3)``, a position channel
replacing that axis of the OFFSET, global = ``parent_global @ local``, file units and axes, float64)."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import torch

from ..errors import InputValueError, ShapeError, UnknownNameError

__all__ = ["BVHClip", "CHANNEL_NAMES"]

CHANNEL_NAMES = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")
"""The six BVH channel names (matched case-insensitively, stored in this spelling)."""


@dataclass(frozen=True, eq=False)
class BVHClip:
    """A parsed BVH file.

    Fields
        path: the file it was read from, str
        names: joint names, tuple of J str (End Sites are ``<parent>_end``)
        parents: parent index of each joint, tuple of J int, -1 for a root; parents precede children
        offsets: rest offsets from the parent, (J, 3), file units, float64
        channels: channel names of each joint in file order, tuple of J tuples (empty for End Sites)
        is_end_site: whether each joint is an End Site, tuple of J bool
        frame_time: seconds per frame, float
        motion: channel values, (F, C), float64; positions in file units, rotations in degrees
        extra_lines_dropped: motion lines beyond ``Frames:`` that were dropped (0, or 1 for the tolerated quirk)
        extra_line_dropped_at: which motion line was dropped: ``"first"`` (an all-zero leading row, the Leap
            gestures), ``"last"``, or None when ``extra_lines_dropped`` is 0
    """

    path: str
    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    is_end_site: tuple[bool, ...]
    frame_time: float
    motion: np.ndarray
    extra_lines_dropped: int = 0
    extra_line_dropped_at: str | None = None

    @property
    def num_frames(self) -> int:
        """F, the number of frames."""
        return int(self.motion.shape[0])

    @property
    def num_joints(self) -> int:
        """J, the number of joints including End Sites."""
        return len(self.names)

    @property
    def fps(self) -> float:
        """Frames per second, ``1 / frame_time``."""
        return 1.0 / self.frame_time

    @property
    def channel_start(self) -> tuple[int, ...]:
        """Column of each joint's first channel in ``motion``, tuple of J int."""
        out, col = [], 0
        for ch in self.channels:
            out.append(col)
            col += len(ch)
        return tuple(out)

    def joint_index(self, name: str) -> int:
        """Index of the joint called ``name``; :class:`UnknownNameError` listing the joints if there is none."""
        try:
            return self.names.index(name)
        except ValueError:
            raise UnknownNameError(
                f"joint: '{name}' is not a joint of {self.path}; joints: {', '.join(self.names)}"
            ) from None

    def children(self, j: int) -> list[int]:
        """Indices of the direct children of joint ``j``."""
        return [i for i, p in enumerate(self.parents) if p == j]

    def rest_transforms(self) -> torch.Tensor:
        """Global transforms of the rest pose (every rotation zero, every position channel at its OFFSET, so each
        joint sits at its OFFSET from its parent), (J, 4, 4), file units, float64."""
        rest = np.zeros((1, self.motion.shape[1]), dtype=np.float64)
        for j, (start, chans) in enumerate(zip(self.channel_start, self.channels)):
            for i, ch in enumerate(chans):
                if ch.endswith("position"):
                    rest[0, start + i] = self.offsets[j, "XYZ".index(ch[0])]
        return self._global(rest)[0]

    def with_motion(self, motion, *, frame_time: float | None = None) -> "BVHClip":
        """A copy of this clip with other channel values (the hierarchy unchanged).

        Args:
            motion: channel values in this clip's column order, (F', C), positions in file units, rotations in
                degrees; array or tensor, stored as a read-only float64 array
            frame_time: seconds per frame of the new motion; None keeps this clip's

        Returns:
            the new :class:`BVHClip` (``extra_lines_dropped`` 0: the motion does not come from a file)

        Raises:
            ShapeError: ``motion`` is not (F', C) with F' >= 1.
            InputValueError: non-finite values, or a ``frame_time`` that is not positive and finite.
        """
        m = motion.detach().cpu().numpy() if isinstance(motion, torch.Tensor) else motion
        m = np.array(m, dtype=np.float64, copy=True)
        C = self.motion.shape[1]
        if m.ndim != 2 or m.shape[1] != C or m.shape[0] < 1:
            raise ShapeError(f"motion: expected shape (F, {C}) with F >= 1 for {self.path}, got {tuple(m.shape)}")
        if not np.isfinite(m).all():
            f, c = (int(v[0]) for v in np.nonzero(~np.isfinite(m)))
            raise InputValueError(f"motion: non-finite value at frame {f}, column {c}")
        ft = self.frame_time if frame_time is None else float(frame_time)
        if not (math.isfinite(ft) and ft > 0):
            raise InputValueError(f"frame_time: expected a positive number of seconds, got {frame_time}")
        m.setflags(write=False)
        return replace(self, motion=m, frame_time=ft, extra_lines_dropped=0, extra_line_dropped_at=None)

    def local_transforms(self, frames=None) -> torch.Tensor:
        """Local transforms ``T_parent_joint``, (F', J, 4, 4), file units, float64.

        Args:
            frames: optional frame selection (slice, int sequence or index array) applied to ``motion``.
        """
        return self._local(self._motion(frames))

    def global_transforms(self, frames=None) -> torch.Tensor:
        """Global transforms ``T_file_joint``, (F', J, 4, 4), file units and axes, float64.

        Args:
            frames: optional frame selection (slice, int sequence or index array) applied to ``motion``.
        """
        return self._global(self._motion(frames))

    # -----------------------------------------------------------------------------------------------------------

    def _motion(self, frames) -> np.ndarray:
        m = self.motion if frames is None else self.motion[frames]
        m = np.asarray(m, dtype=np.float64)
        return m[None] if m.ndim == 1 else m

    def _local_np(self, motion: np.ndarray) -> np.ndarray:
        F, J = motion.shape[0], self.num_joints
        out = np.broadcast_to(np.eye(4), (F, J, 4, 4)).copy()
        out[:, :, :3, 3] = self.offsets
        # one sin/cos over every rotation channel
        rot_cols = [c for c, ch in enumerate(ch for chans in self.channels for ch in chans) if ch.endswith("rotation")]
        rad = np.deg2rad(motion[:, rot_cols])
        cos, sin = np.cos(rad), np.sin(rad)
        k = 0
        for j, (start, chans) in enumerate(zip(self.channel_start, self.channels)):
            R = None
            for i, ch in enumerate(chans):
                axis = "XYZ".index(ch[0])
                if ch.endswith("position"):
                    out[:, j, axis, 3] = motion[:, start + i]        # replaces that axis of the OFFSET
                    continue
                Rk = _axis_rotation_np(cos[:, k], sin[:, k], axis)
                k += 1
                R = Rk if R is None else R @ Rk
            if R is not None:
                out[:, j, :3, :3] = R
        return out

    def _local(self, motion: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(self._local_np(motion))

    def _global(self, motion: np.ndarray) -> torch.Tensor:
        local = self._local_np(motion)
        glob = np.empty_like(local)
        for j, p in enumerate(self.parents):
            glob[:, j] = local[:, j] if p < 0 else glob[:, p] @ local[:, j]
        return torch.from_numpy(glob)


def _axis_rotation_np(c: np.ndarray, s: np.ndarray, axis: int) -> np.ndarray:
    """NumPy rotations about coordinate axis ``axis`` from cosines and sines (F,), (F, 3, 3)."""
    R = np.zeros(c.shape + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R[..., axis, axis] = 1.0
    R[..., i, i] = c
    R[..., j, j] = c
    R[..., i, j] = -s
    R[..., j, i] = s
    return R
