"""The record of B resynthesis rollouts over T frames (what :func:`torchhand.interaction.resynth.simulate` returns)
and one rollout's typed :class:`~torchhand.interaction.resynth.Rollout` made from it.

Frame k holds the state at t_k (q, root, object pose, contact slots) and the contact forces f^{k+1} solved at step
k (module docstring of :mod:`torchhand.interaction.resynth`). Units: metres, seconds, radians, newtons; forces on the
hand (on the object for object-table slots).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import torch

from ..kernels.status import SolverStatus
from ._contacts import BODY_OBJECT, BODY_OBJECT_ENV
from ._resynth_types import Rollout, RolloutStatus, Variant

__all__ = ["FrameRecord", "RolloutRecord", "object_slip", "hold_frame", "rollout_result"]


@dataclass(frozen=True, eq=False)
class FrameRecord:
    """Frame k of B rollouts, on the CPU (N contact slots, D joints).

    q: theta^k, (B, D), radians; theta_r: the reference of frame k (the reach's offset included), (B, D), radians;
    root: root pose, (B, 4, 4); object_pose: E^k, (B, 4, 4); C: the compliance applied
    at step k (variant scale and grip included), (B, 6 + D), rad/(N m) (root linear m/N); points: slot points, (B, N,
    3), world, metres; d0: slot normals, (B, N, 3); sep: separations, (B, N), metres; body_mask: active slots, (B, N);
    forces: f^{k+1}, (B, N, 3), newtons; lam: slip lambda_i, (B, N), metres; mu: friction per slot, (B, N); status:
    LCP status, (B,) int8; residual: (B,); theta_err: ||theta_err^k||_inf, (B,); joint_clamp: (B,), radians
    """

    q: torch.Tensor
    theta_r: torch.Tensor
    root: torch.Tensor
    object_pose: torch.Tensor
    C: torch.Tensor
    points: torch.Tensor
    d0: torch.Tensor
    sep: torch.Tensor
    body_mask: torch.Tensor
    forces: torch.Tensor
    lam: torch.Tensor
    mu: torch.Tensor
    status: torch.Tensor
    residual: torch.Tensor
    theta_err: torch.Tensor
    joint_clamp: torch.Tensor


@dataclass(frozen=True, eq=False)
class RolloutRecord:
    """B rollouts over T frames, on the CPU: every :class:`FrameRecord` field stacked on dimension 1, (B, T, ...),
    and per rollout:

    failed_step: step whose LCP failed, (B,) long, -1: completed; failed_status: the solver status there, (B,) int8;
    grip_events: list of (rollout, frame, link); onset: first slip frame, (B,), -1: none; slot_link, slot_body: each
    slot's link and body, (N,); hand_obj: hand-object slots, (N,) bool; step_time_s: seconds per step (the mean);
    step_times_s: each step's wall time, (T,) seconds (reported, never used to decide anything)

    ``rec["q"]`` reads a field by name, as the dict this record replaces did.
    """

    q: torch.Tensor
    theta_r: torch.Tensor
    root: torch.Tensor
    object_pose: torch.Tensor
    C: torch.Tensor
    points: torch.Tensor
    d0: torch.Tensor
    sep: torch.Tensor
    body_mask: torch.Tensor
    forces: torch.Tensor
    lam: torch.Tensor
    mu: torch.Tensor
    status: torch.Tensor
    residual: torch.Tensor
    theta_err: torch.Tensor
    joint_clamp: torch.Tensor
    failed_step: torch.Tensor
    failed_status: torch.Tensor
    grip_events: list
    onset: torch.Tensor
    slot_link: torch.Tensor
    slot_body: torch.Tensor
    hand_obj: torch.Tensor
    step_time_s: float
    step_times_s: tuple = ()

    def __getitem__(self, name: str):
        if name not in self.__dataclass_fields__:
            raise KeyError(name)
        return getattr(self, name)

    @classmethod
    def from_frames(cls, frames: list, **per_rollout) -> "RolloutRecord":
        """Stack the :class:`FrameRecord` s of frames 0 .. T - 1; ``per_rollout``: the remaining fields."""
        stacked = {f.name: torch.stack([getattr(fr, f.name) for fr in frames], 1) for f in fields(FrameRecord)}
        return cls(**stacked, **per_rollout)


def object_slip(root_pose: np.ndarray, object_pose: np.ndarray, com: np.ndarray, start: int) -> np.ndarray:
    """Displacement of the object's centre in the hand (root) frame since frame ``start``, (T,), metres."""
    c = object_pose[:, :3, :3] @ com + object_pose[:, :3, 3]
    R, p = root_pose[:, :3, :3], root_pose[:, :3, 3]
    local = np.einsum("tji,tj->ti", R, c - p)
    return np.linalg.norm(local - local[min(max(start, 0), len(local) - 1)], axis=-1)


def hold_frame(root_r: np.ndarray, given: int | None) -> int:
    """The frame the object slip is measured from: ``given``, or the first frame at which the reference root
    ``root_r`` (T, 4, 4) has moved more than 1 mm from its start (0 if it never does)."""
    if given is not None:
        return int(given)
    moved = np.linalg.norm(root_r[:, :3, 3] - root_r[0, :3, 3], axis=-1) > 1e-3
    return int(np.argmax(moved)) if moved.any() else 0


def rollout_result(rec: RolloutRecord, b: int, variant: Variant, com: np.ndarray, hold: int) -> Rollout:
    """Rollout ``b`` of the record as a :class:`Rollout`, NumPy float64: hand-object slots that push (f_n > 1 nN)
    become contacts with points on the object surface and forces on the object; object-table slots the env arrays,
    with points on the table (the object's support point moved along the table normal by its height above it: a
    corner that closes a gap during step k carries force at frame k, as a hand contact does).

    variant: the rollout's :class:`Variant`; com: the object's centre of
    mass, (3,), object frame, metres; hold: the frame :func:`object_slip` is measured from
    """
    f64 = lambda x: x[b].double().numpy()
    body = rec.slot_body.numpy()
    hs, es = np.nonzero(body == BODY_OBJECT)[0], np.nonzero(body == BODY_OBJECT_ENV)[0]
    d0, pts, sep, force = f64(rec.d0), f64(rec.points), f64(rec.sep), f64(rec.forces)
    active = rec.body_mask[b].numpy()
    fn = (force * d0).sum(-1)
    # hand-object: force on the object = -f (f is on the hand); normal into the object = -d0
    # a slot is written as a contact when it pushes (f_n > 1 nN: the LCP's zero forces come out at round-off level)
    hmask = active[:, hs] & (fn[:, hs] > 1e-9)
    m3 = hmask[..., None]
    point = (pts[:, hs] - sep[:, hs, None] * d0[:, hs]) * m3
    fh = -force[:, hs] * m3
    ft = np.linalg.norm(force[:, hs] - fn[:, hs, None] * d0[:, hs], axis=-1)
    rho = np.where(hmask & (fn[:, hs] > 0.2), ft / np.maximum(fn[:, hs], 1e-12), 0.0)
    lam = f64(rec.lam)[:, hs]
    emask = active[:, es] & (fn[:, es] > 0)
    failed = int(rec.failed_step[b])
    ev = np.array([(k, l) for bb, k, l in rec.grip_events if bb == b], dtype=np.int64).reshape(-1, 2)
    root, obj = f64(rec.root), f64(rec.object_pose)
    clamp = np.concatenate([[0.0], f64(rec.joint_clamp)[:-1]])        # step k clamps the joints of frame k + 1
    return Rollout(
        variant=variant, status=RolloutStatus.COMPLETED if failed < 0 else RolloutStatus.LCP_FAILED,
        failed_step=failed, failed_status="" if failed < 0 else SolverStatus(int(rec.failed_status[b])).name,
        q=f64(rec.q), root_pose=root, object_pose=obj, theta_r=f64(rec.theta_r), compliance=f64(rec.C),
        slot_link=rec.slot_link.numpy()[hs], contact_mask=hmask, contact_point=point,
        contact_normal=-d0[:, hs] * m3, contact_force=fh, contact_sliding=hmask & (lam > 1e-9), slip_ratio=rho,
        env_mask=emask, env_point=(pts[:, es] - sep[:, es, None] * d0[:, es]) * emask[..., None],
        env_force=force[:, es] * emask[..., None],
        lcp_status=rec.status[b].numpy().astype(np.int8), lcp_residual=f64(rec.residual),
        theta_err=f64(rec.theta_err), joint_clamp=clamp, grip_events=ev, grip_onset=int(rec.onset[b]),
        object_slip=object_slip(root, obj, com, hold), hold_frame=hold)
