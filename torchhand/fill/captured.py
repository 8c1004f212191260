"""The captured fingers as a solution file: the built-in hand posed to the capture's fingertips, to draw beside a fill.

``torchhand render DIR --compare DIR/captured_right.npz`` draws a written motion beside the capture's own fingers.
The capture's finger joints live in its BVH's skeleton, not in the hand model's joints, so the model is fitted to
them: per frame, the joint angles (within the model's limits) whose fingertip pad points
(:func:`~torchhand.fill.reference.solution_fingertips`) come closest to the captured finger ends
(:func:`~torchhand.fill.reference.captured_fingertips`), least squares with a weak pull toward the rest pose
(``reg`` square metres per radian squared), by Levenberg-Marquardt steps projected onto the limits from the rest
pose, every frame with its own damping, all frames at once (Jacobians by central differences in float64). A pad point lies a few
millimetres back of a finger's end, and the capture's hand is not the model's, so the fit is a picture of the
captured grasp, not a measurement: its residual per finger is reported with it. The file has no contacts and no
forces (it claims nothing physical); its ``reconstructed`` is False.

Conventions: world z-up, metres, radians; the solution-file keys of docs/result_format.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

import io
from pathlib import Path

from .._atomic import atomic_bytes
from ..errors import InputValueError, TorchhandError
from .reference import FINGERS, captured_fingertips, reference_report

__all__ = ["CapturedFit", "fit_captured_fingers", "captured_solution_arrays", "write_captured", "result_reference"]


@dataclass(frozen=True, eq=False)
class CapturedFit:
    """q: joint angles, (T, D) radians, float64; residual: fitted pad point to captured finger end, (T, F) metres
    (NaN where the capture has no finite finger end)."""

    q: torch.Tensor
    residual: np.ndarray

    def summary(self) -> dict:
        r = 1e3 * self.residual
        return {"residual_mm": {"median": float(np.nanmedian(r)), "p90": float(np.nanpercentile(r, 90))}}


def fit_captured_fingers(scene, side: str, hand, root: torch.Tensor | None = None, *, steps: int = 60,
                         reg: float = 1e-6, damping: float = 1e-4, max_step: float = 0.3,
                         tol: float = 1e-7) -> CapturedFit:
    """The model ``hand`` (five fingers of :data:`~torchhand.fill.reference.FINGERS`) fitted to the captured finger
    ends of hand ``side`` (module docstring). root: the wrist poses to pose it on, (T, 4, 4) (default: the scene's
    track); steps: at most this many Levenberg-Marquardt steps (per frame: a step is kept when it lowers the cost,
    and the damping, from ``damping``, falls by 3, else rises by 4; joints move at most ``max_step`` radians a
    step; ``reg`` in m^2 per rad^2), stopping when no kept step moves a joint more than ``tol`` radians. Raises InputValueError for a scene without captured fingers or a model without the five fingers."""
    if tuple(hand.finger_names) != FINGERS:
        raise InputValueError(f"hand: expected the fingers {', '.join(FINGERS)} (the built-in hand), got "
                              f"{', '.join(hand.finger_names)}")
    target = captured_fingertips(scene, side)
    if target is None:
        raise InputValueError(f"scene: '{scene.name}' has no captured fingers for the {side} hand")
    model = hand.to("cpu", torch.float64)
    track = next(h for h in scene.hands if h.side == side)
    root = (track.wrist_pose if root is None else root).detach().cpu().double()
    goal = torch.as_tensor(target, dtype=torch.float64)
    ok = torch.isfinite(goal).all(-1)                                        # (T, F)
    goal = torch.where(ok[..., None], goal, torch.zeros_like(goal))
    lim = model.joint_limits.double()
    rest = model.q_rest.double().expand(root.shape[0], -1).clone()
    q = torch.minimum(torch.maximum(rest, lim[:, 0]), lim[:, 1])
    w = ok.double().repeat_interleave(3, dim=1)                              # (T, 3F) residual weights
    eye = torch.eye(q.shape[1], dtype=q.dtype)
    lam = torch.full((q.shape[0],), damping, dtype=q.dtype)

    def cost(qq):
        r = (_pads(model, qq, root) - goal).reshape(qq.shape[0], -1) * w
        return r, r.square().sum(-1) + reg * (qq - rest).square().sum(-1)

    r, c = cost(q)
    for _ in range(steps):
        J = _jacobian(model, q, root) * w[..., None]                       # (T, 3F, D)
        JT = J.transpose(1, 2)
        A = JT @ J + reg * eye + lam[:, None, None] * eye
        b = -(JT @ r[..., None])[..., 0] - reg * (q - rest)
        step = torch.linalg.solve(A, b).clamp(-max_step, max_step)
        q_new = torch.minimum(torch.maximum(q + step, lim[:, 0]), lim[:, 1])
        r_new, c_new = cost(q_new)
        better = c_new < c                                                 # per frame: accept, or damp more
        moved = float(((q_new - q).abs().amax(-1) * better).max())
        q = torch.where(better[:, None], q_new, q)
        r = torch.where(better[:, None], r_new, r)
        c = torch.where(better, c_new, c)
        lam = torch.where(better, lam / 3, lam * 4).clamp(1e-12, 1e6)
        if moved < tol and bool((lam > 1e3 * damping).logical_or(better).all()):
            break
    res = (_pads(model, q, root) - goal).norm(dim=-1)
    residual = torch.where(ok, res, torch.full_like(res, float("nan"))).numpy()
    return CapturedFit(q.detach(), residual)


def _jacobian(model, q: torch.Tensor, root: torch.Tensor, h: float = 1e-6) -> torch.Tensor:
    """d pads / d q by central differences, (T, 3F, D)."""
    T, D = q.shape
    e = h * torch.eye(D, dtype=q.dtype)
    qq = torch.cat([(q[:, None] + e).reshape(-1, D), (q[:, None] - e).reshape(-1, D)])
    rr = root.repeat_interleave(D, dim=0).repeat(2, 1, 1)
    p = _pads(model, qq, rr).reshape(2, T, D, -1)
    return ((p[0] - p[1]) / (2 * h)).transpose(1, 2)


def _pads(model, q: torch.Tensor, root: torch.Tensor) -> torch.Tensor:
    links = model.forward_kinematics(q, root)[:, model.distal_link]                       # (T, F, 4, 4)
    return (links[..., :3, :3] @ model.fingertip[None, :, :, None]).squeeze(-1) + links[..., :3, 3]


def captured_solution_arrays(scene, side: str, hand, fit: CapturedFit, root: torch.Tensor | None = None) -> dict:
    """The arrays of a one-hand solution file (docs/result_format.md) holding the fitted captured fingers on the
    wrist ``root`` (default the scene's track), the scene's object track, and no contacts."""
    from ..io.result import FORMAT_VERSION

    T = scene.T
    track = next(h for h in scene.hands if h.side == side)
    root = (track.wrist_pose if root is None else root).detach().cpu().double().numpy()
    z3 = np.zeros((T, 0, 3))
    return {"format_version": np.array(FORMAT_VERSION), "q": fit.q.numpy(), "joint_names": np.array(hand.joint_names),
            "root_pose": root, "side": np.array(side), "fps": np.array(float(scene.fps)),
            "object_pose": scene.object_pose.detach().cpu().double().numpy(),
            "contact_mask": np.zeros((T, 0), bool), "contact_link": np.zeros((T, 0), np.int64),
            "contact_link_name": np.array([], dtype="<U1"), "contact_point": z3, "contact_normal": z3.copy(),
            "contact_force": z3.copy(), "contact_sliding": np.zeros((T, 0), bool),
            "env_contact_mask": np.zeros((T, 0), bool), "env_contact_point": z3.copy(),
            "env_contact_force": z3.copy(), "reconstructed": np.array(False)}


def result_reference(result, out_dir, frames=None) -> dict | None:
    """:func:`reference_report` of a :class:`~torchhand.synthesis.pipeline.SynthesisResult`'s written motions
    (``result.finals``) when its scene is a capture with fingers, and the captured fingers as a solution file
    (:func:`write_captured`): ``{side: {"motions": [summary per motion], "captured_fit": {...}}}``; None for other
    scenes. A capture whose source files cannot be read any more gives ``{"error": message}`` (the comparison is
    information, never a failure)."""
    scene = result.scene
    if getattr(scene, "source", None) is None or not result.finals:
        return None
    root = result.problem.root.detach().double().cpu()
    motions = [(f.q.detach().double().cpu(), root) for f in result.finals]
    try:
        report = reference_report(scene, result.problem.hands, motions, out_dir, frames=frames)
        out = {}
        for h, track in enumerate(scene.hands):
            if track.side in report:
                out[track.side] = {"motions": report[track.side],
                                   "captured_fit": write_captured(scene, track.side, result.problem.hands[h],
                                                                  root[h], out_dir)}
        return out or None
    except TorchhandError as err:
        return {"error": str(err)}


def write_captured(scene, side: str, hand, root, out_dir) -> dict:
    """``captured_<side>.npz`` in ``out_dir``: the captured fingers as a solution file
    (:mod:`torchhand.fill.captured`), written atomically. Returns the fit's summary and the file name."""
    fit = fit_captured_fingers(scene, side, hand, root)
    buf = io.BytesIO()
    np.savez(buf, **captured_solution_arrays(scene, side, hand, fit, root))
    name = f"captured_{side}.npz"
    atomic_bytes(Path(out_dir) / name, buf.getvalue())
    return {"file": name, **fit.summary()}
