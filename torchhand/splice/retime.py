"""Resampling BVH motion at fractional frames: rotations by slerp, positions linearly.

A joint with three rotation channels is resampled as a rotation: its local rotation matrices at the two
neighbouring frames are slerped (shortest arc, wxyz quaternions) and written back as Euler angles in the joint's
own channel order, each frame unwrapped to the equivalent angles closest to the previous frame's (so channels do
not jump by 360 degrees; ``bvh.unwrap_euler``). Joints with one or two rotation channels and every position
channel are interpolated linearly in their channel values (exact for a single axis).
"""

from __future__ import annotations

import numpy as np
import torch

from ..scene.bvh import BVHClip, matrix_to_euler, unwrap_euler
from ..errors import InputValueError
from ..geometry.poses import matrix_to_quat, quat_to_matrix, slerp

__all__ = ["rotation_order", "local_rotations", "retime_motion", "rotations_to_channels"]


def rotation_order(channels: tuple[str, ...]) -> str:
    """The rotation channels' axes in file order, e.g. ("Zrotation", "Xrotation", "Yrotation") -> "ZXY"."""
    return "".join(c[0] for c in channels if c.endswith("rotation"))


def _rotation_columns(clip: BVHClip, j: int) -> list[int]:
    s = clip.channel_start[j]
    return [s + i for i, c in enumerate(clip.channels[j]) if c.endswith("rotation")]


def local_rotations(clip: BVHClip, motion: np.ndarray | None = None) -> torch.Tensor:
    """Local rotation matrices of every joint from channel values, (F, J, 3, 3), float64 (identity for joints
    without rotation channels)."""
    m = clip.motion if motion is None else motion
    return clip._local(np.asarray(m, dtype=np.float64).reshape(-1, clip.motion.shape[1]))[..., :3, :3]


def rotations_to_channels(clip: BVHClip, motion: np.ndarray, joints: dict[int, torch.Tensor], *,
                          continue_from: np.ndarray | None = None) -> np.ndarray:
    """Write local rotations into the rotation channels of the given joints (a copy of ``motion``).

    Args:
        clip: the clip whose hierarchy ``motion`` follows
        motion: channel values, (F, C), degrees for rotations
        joints: joint index -> local rotations (F, 3, 3); the joint must have exactly three rotation channels
        continue_from: optional channel values of the frame just before ``motion``, (C,): the angles then continue
            from that frame's (the nearest equivalent Euler triple), so a segment written into a clip joins its
            neighbours without a 360-degree or twin-solution jump

    Returns:
        (F, C) float64, with those joints' rotation channels replaced (angles unwrapped along time)
    """
    out = np.array(motion, dtype=np.float64, copy=True)
    for j, R in joints.items():
        cols = _rotation_columns(clip, j)
        order = rotation_order(clip.channels[j])
        if len(order) != 3:
            raise InputValueError(f"joint '{clip.names[j]}' of {clip.path} has rotation channels '{order}'; "
                                  "three are needed to carry a rotation")
        ang = matrix_to_euler(R.to(torch.float64), order)
        if continue_from is not None:
            prev = torch.from_numpy(np.deg2rad(np.asarray(continue_from, dtype=np.float64)[cols]))
            ang = unwrap_euler(torch.cat([prev[None], ang]), order)[1:]
        else:
            ang = unwrap_euler(ang, order)
        out[:, cols] = np.rad2deg(ang.numpy())
    return out


def retime_motion(clip: BVHClip, frames: torch.Tensor | np.ndarray, *, joints: list[int] | None = None
                  ) -> np.ndarray:
    """The clip's channel values at fractional source frames.

    Args:
        clip: the source clip
        frames: source frame per output frame, (n,), fractional, clamped to [0, F - 1]
        joints: only these joints' channels are resampled (others: taken from the nearest frame); None = all

    Returns:
        motion: (n, C) float64 channel values of the clip's hierarchy (degrees, file units)
    """
    t = torch.as_tensor(np.asarray(frames, dtype=np.float64)).clamp(0, clip.num_frames - 1)
    F = clip.num_frames
    i0 = t.floor().long().clamp(max=F - 1)
    i1 = (i0 + 1).clamp(max=F - 1)
    w = (t - i0.double())
    src = clip.motion
    a, b = src[i0.numpy()], src[i1.numpy()]
    out = a + (b - a) * w.numpy()[:, None]                 # linear for every channel first
    chosen = range(clip.num_joints) if joints is None else joints
    R_all0 = R_all1 = None
    for j in chosen:
        cols = _rotation_columns(clip, j)
        order = rotation_order(clip.channels[j])
        if len(order) != 3:
            continue
        if R_all0 is None:
            R_all0 = local_rotations(clip, a)
            R_all1 = local_rotations(clip, b)
        q = slerp(matrix_to_quat(R_all0[:, j]), matrix_to_quat(R_all1[:, j]), w)
        R = quat_to_matrix(q)
        ref = torch.deg2rad(torch.from_numpy(a[:, cols]))
        ang = matrix_to_euler(R, order, reference=ref)
        out[:, cols] = np.rad2deg(unwrap_euler(ang, order).numpy())
    return out

