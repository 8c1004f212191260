"""Hand sessions with a known time warp, made from real body capture (the ground truth of splicing).

No file holds body and fingers of one performance, so timing truth is constructed (design note, GT-1): the
same arm, re-timed by a known smooth monotone warp ``tau = h(t)`` and degraded the way a separate hand session
differs from the body session.

Warp
    ``h'(t) = r (1 + c(t))`` with ``c(t) = sum_k a_k cos(k pi t / T_b)`` over k in {1, 2, 3, 5}, a_k drawn from
    the generator and scaled so that the local speed ``h'`` spans exactly ``speed_range`` (default 0.6-1.4 of
    real time, r = 1); ``h(0) = 0``, ``h(T_b) = r T_b`` (the sines vanish at both ends).

Levels (each includes the ones before)
    L0 the warp alone, resampled to ``hand_fps`` (60 Hz; rotations slerped);
    L1 noise: every joint rotated by a random 0.5 deg and the root moved by 1 mm per frame (independent per frame);
    L2 amplitude: shoulder and elbow rotations pulled toward their mean by a(tau) in [0.55, 0.9], the wrist's by
       [0.8, 1], smooth in tau (a performer at a small capture volume);
    L3 the whole hand clip turned 30 deg about the vertical;
    L4 the trunk (root and every joint above the shoulders) frozen at its first frame: a seated hand session;
    L5 L4 with doubled noise.

Truth: the hand time shown at body frame i is ``h(i / fps_b)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ..scene.bvh import BVHClip, euler_to_matrix
from ..errors import InputValueError
from ..geometry.poses import matrix_to_quat, quat_to_matrix, slerp
from .retime import local_rotations, retime_motion, rotation_order, rotations_to_channels

__all__ = ["Warp", "make_warp", "HandSession", "make_hand_session", "LEVELS"]

LEVELS = ("L0", "L1", "L2", "L3", "L4", "L5")


@dataclass(frozen=True)
class Warp:
    """A monotone time warp tau = h(t) on [0, T_b] (seconds).

    T_b: body duration, s; ratio: T_h / T_b; a: cosine coefficients for k = 1, 2, 3, 5
    """

    T_b: float
    ratio: float
    a: tuple[float, float, float, float]

    _K = (1, 2, 3, 5)

    def __call__(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        s = sum(a * self.T_b / (k * math.pi) * np.sin(k * math.pi * t / self.T_b) for a, k in zip(self.a, self._K))
        return self.ratio * (t + s)

    def speed(self, t: np.ndarray) -> np.ndarray:
        """h'(t), the hand clip's local speed."""
        t = np.asarray(t, dtype=np.float64)
        return self.ratio * (1 + sum(a * np.cos(k * math.pi * t / self.T_b) for a, k in zip(self.a, self._K)))

    def inverse(self, tau: np.ndarray) -> np.ndarray:
        """t with h(t) = tau (monotone: interpolation on a fine grid)."""
        grid = np.linspace(0.0, self.T_b, 20001)
        return np.interp(np.asarray(tau, dtype=np.float64), self(grid), grid)


def make_warp(T_b: float, generator: torch.Generator, *, speed_range=(0.6, 1.4)) -> Warp:
    """A random warp whose local speed spans ``speed_range`` (module docstring)."""
    lo, hi = speed_range
    if not (0 < lo < hi):
        raise InputValueError(f"speed_range: expected 0 < low < high, got {speed_range}")
    ratio = 0.5 * (lo + hi)
    raw = (torch.rand(4, generator=generator, dtype=torch.float64) * 2 - 1).numpy()
    grid = np.linspace(0, T_b, 4001)
    c = sum(a * np.cos(k * math.pi * grid / T_b) for a, k in zip(raw, Warp._K))
    half = 0.5 * (hi - lo) / ratio                        # c must span [-half, +half] at most, touching one end
    scale = half / max(abs(c.min()), abs(c.max()))
    return Warp(T_b=T_b, ratio=ratio, a=tuple(float(x) for x in raw * scale))


@dataclass(frozen=True)
class HandSession:
    """A degraded, re-timed copy of a body clip and its truth.

    clip: the hand session (the body's hierarchy), BVHClip at ``hand_fps``
    warp: the warp used
    truth: hand time (seconds) shown at each body frame, (n,)
    level: "L0".."L5"
    """

    clip: BVHClip
    warp: Warp
    truth: np.ndarray
    level: str


def _ancestors(clip: BVHClip, j: int) -> list[int]:
    out = []
    while j >= 0:
        out.append(j)
        j = clip.parents[j]
    return out


def make_hand_session(body: BVHClip, level: str, generator: torch.Generator, *, shoulders: list[int],
                      elbows: list[int], wrists: list[int], up_axis: str = "y", hand_fps: float = 60.0,
                      speed_range=(0.6, 1.4), yaw_deg: float = 30.0, noise_deg: float = 0.5,
                      noise_root: float = 0.001, units_scale: float = 1.0) -> HandSession:
    """Build a hand session from ``body`` at ``level`` (module docstring).

    Args:
        body: the body clip
        level: "L0".."L5"
        generator: source of every random draw
        shoulders, elbows, wrists: joint indices of the arms (amplitude reduction)
        up_axis: the file's up axis ("y" or "z"), for the yaw turn
        hand_fps: frame rate of the session
        speed_range: local speed range of the warp
        yaw_deg: L3's turn about the vertical, degrees
        noise_deg, noise_root: L1's noise: rotation per joint (deg) and root displacement (metres)
        units_scale: metres per file unit (for ``noise_root``)
    """
    if level not in LEVELS:
        raise InputValueError(f"level: expected one of {', '.join(LEVELS)}, got {level!r}")
    L = LEVELS.index(level)
    n = body.num_frames
    T_b = (n - 1) / body.fps
    warp = make_warp(T_b, generator, speed_range=speed_range)
    T_h = float(warp(T_b))
    m = int(math.floor(T_h * hand_fps + 1e-9)) + 1
    tau = np.arange(m) / hand_fps
    src_frames = warp.inverse(tau) * body.fps
    motion = retime_motion(body, src_frames)
    R = local_rotations(body, motion)                                          # (m, J, 3, 3)
    changed: dict[int, torch.Tensor] = {}

    if L >= 2:                                                                  # amplitude toward the mean
        def smooth_factor(lo: float, hi: float) -> torch.Tensor:
            ph = torch.rand(2, generator=generator, dtype=torch.float64).numpy() * 2 * math.pi
            u = 0.5 + 0.25 * (np.sin(2 * math.pi * tau / T_h + ph[0]) + np.sin(5 * math.pi * tau / T_h + ph[1]))
            return torch.from_numpy(lo + (hi - lo) * np.clip(u, 0, 1))

        for joints, (lo, hi) in ((shoulders + elbows, (0.55, 0.9)), (wrists, (0.8, 1.0))):
            for j in joints:
                q = matrix_to_quat(R[:, j])
                q = torch.where((q * q[:1]).sum(-1, keepdim=True) < 0, -q, q)
                mean = q.mean(0, keepdim=True)
                mean = (mean / mean.norm()).expand_as(q)
                changed[j] = quat_to_matrix(slerp(mean, q, smooth_factor(lo, hi)))
    for j, Rj in changed.items():
        R[:, j] = Rj
    if L >= 1:                                                                  # noise on every rotation
        scale = math.radians(noise_deg) * (2.0 if L >= 5 else 1.0)
        J = body.num_joints
        for j in range(J):
            if len(rotation_order(body.channels[j])) != 3:
                continue
            axis = torch.randn(m, 3, generator=generator, dtype=torch.float64)
            axis = axis / axis.norm(dim=-1, keepdim=True)
            ang = scale * torch.randn(m, 1, generator=generator, dtype=torch.float64).abs()
            changed[j] = R[:, j] @ _axis_angle(axis * ang)
            R[:, j] = changed[j]
    motion = rotations_to_channels(body, motion, changed)

    root = body.parents.index(-1)
    pos_cols = [body.channel_start[root] + i for i, c in enumerate(body.channels[root]) if c.endswith("position")]
    rot_cols = [body.channel_start[root] + i for i, c in enumerate(body.channels[root]) if c.endswith("rotation")]
    if L >= 4:                                                                  # trunk frozen at frame 0
        trunk = set()
        for s in shoulders:
            trunk.update(_ancestors(body, body.parents[s]))
        for j in trunk:
            cols = list(range(body.channel_start[j], body.channel_start[j] + len(body.channels[j])))
            motion[:, cols] = motion[:1, cols]
    if L >= 3 and len(pos_cols) == 3 and len(rot_cols) == 3:                     # a turn about the vertical
        up = "XYZ".index(up_axis.upper())
        axis = torch.zeros(3, dtype=torch.float64)
        axis[up] = 1.0
        Rz = _axis_angle(axis * math.radians(yaw_deg))
        order = rotation_order(body.channels[root])
        Rroot = euler_to_matrix(torch.deg2rad(torch.from_numpy(motion[:, rot_cols])), order)
        motion = rotations_to_channels(body, motion, {root: Rz @ Rroot})
        motion[:, pos_cols] = (Rz.numpy() @ motion[:, pos_cols].T).T
    if L >= 1 and len(pos_cols) == 3:
        k = 2.0 if L >= 5 else 1.0
        motion[:, pos_cols] += (k * noise_root / units_scale
                                * torch.randn(m, 3, generator=generator, dtype=torch.float64).numpy())
    clip = body.with_motion(motion, frame_time=1.0 / hand_fps)
    truth = warp(np.arange(n) / body.fps)
    return HandSession(clip=clip, warp=warp, truth=truth, level=level)


def _axis_angle(v: torch.Tensor) -> torch.Tensor:
    """Rotation matrices from rotation vectors (..., 3)."""
    th = v.norm(dim=-1, keepdim=True).unsqueeze(-1)
    k = v / v.norm(dim=-1, keepdim=True).clamp_min(1e-15)
    K = torch.zeros(v.shape[:-1] + (3, 3), dtype=v.dtype)
    K[..., 0, 1], K[..., 0, 2] = -k[..., 2], k[..., 1]
    K[..., 1, 0], K[..., 1, 2] = k[..., 2], -k[..., 0]
    K[..., 2, 0], K[..., 2, 1] = -k[..., 1], k[..., 0]
    eye = torch.eye(3, dtype=v.dtype).expand_as(K)
    return eye + torch.sin(th) * K + (1 - torch.cos(th)) * (K @ K)


def with_fingers(clip: BVHClip, rig, side: str, fingers: BVHClip, finger_rig, finger_frames: np.ndarray, *,
                 finger_handedness: str = "right", body_handedness: str = "right", up_axis: str | None = None):
    """A clip without fingers given real fingers: the finger rig's joints inserted under ``side``'s wrist and
    driven by ``fingers`` at fractional ``finger_frames`` (one per frame of ``clip``; rotations slerped, rest
    directions lined up as ``splice`` does). Used to put real finger motion on a synthetic clock (design note
    GT-2).

    Returns:
        (new clip, its rig)
    """
    from dataclasses import replace

    from .retarget import insert_fingers, retarget_fingers

    if len(finger_frames) != clip.num_frames:
        raise InputValueError(f"finger_frames: expected {clip.num_frames} frames, got {len(finger_frames)}")
    ins = insert_fingers(clip, rig, side, fingers, finger_rig, hand_handedness=finger_handedness,
                         body_handedness=body_handedness, up_axis=up_axis)
    joints = finger_rig.finger_joints(side)
    R = local_rotations(fingers, retime_motion(fingers, finger_frames, joints=joints))
    rt = retarget_fingers(fingers, finger_rig, ins.clip, ins.rig, side, R, src_handedness=finger_handedness,
                          dst_handedness=body_handedness, align_rest=True)
    motion = rotations_to_channels(ins.clip, np.array(ins.clip.motion), rt.rotations)
    motion.setflags(write=False)
    return replace(ins.clip, motion=motion), ins.rig
