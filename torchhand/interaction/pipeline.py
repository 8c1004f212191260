"""Capture to interaction trajectory: torques, events, compliance, reference; and the ``interaction.npz`` output.

Stages (pure functions over the capture's arrays):

1. :func:`generalized_coordinates`: theta (T, 6 + D). The root's "angles": the rotation vector of
   ``R(t) R(0)^T`` (world frame, radians) and the translation ``p(t) - p(0)`` (world, metres), so that their rates
   are, to first order in the rotation since the first frame, the world angular velocity and the root origin's
   velocity: the root twist of :func:`torchhand.hand.dynamics.point_jacobian`. Then the D joint angles.
2. :func:`joint_torques`: tau(t) = sum_s J_s(theta(t))^T f_s(t), (T, 6 + D) (Eq. 2), the columns of
   ``point_jacobian(..., wrt_root=True)``: torque about the root origin (world, N m), force (world, N), joint
   torques. Inertia and gravity are ignored, as in the paper (§4.3). J is evaluated at joint angles smoothed over
   ``EstimateSettings.jacobian_smoothing`` (40 ms, Savitzky-Golay degree 2): with raw angles, angle noise enters
   tau through J(theta) correlated with the angle noise itself, an errors-in-variables bias of the compliance
   (+5-10 % at 0.2 degree noise on the MuJoCo captures). The root pose is used as captured.
3. :func:`~torchhand.interaction.events.detect_contact_events`.
4. :func:`~torchhand.interaction.estimate.estimate_compliance`.
5. :func:`~torchhand.interaction.estimate.reference_trajectory` with Table 1 defaults
   (:func:`~torchhand.interaction.compliance.default_compliance`).

``interaction.npz`` keys: ``C`` (T, 6 + D) rad/(N m) (root linear m/N), ``C_is_default`` (6 + D,),
``theta`` (T, 6 + D), ``theta_r`` (T, D) radians, ``root_theta_r`` (T, 6), ``tau`` (T, 6 + D),
``event_time`` (E,) s, ``event_frame`` (E,), ``event_sensor`` (E,), ``estimates`` (E, 6 + D) (NaN where
rejected), ``raw_estimates``, ``stderr``, ``reasons`` (E, 6 + D) int with names ``reason_names`` (code = index),
``windows`` (E, 3) frames, ``names`` (6 + D,), ``joint_names`` (D,), ``default_compliance`` (6 + D,),
``truth_compliance`` (when the capture has one), ``root_origin`` (4, 4) (the capture's first root pose: the
root coordinates are relative to it), ``fps``, ``settings`` (JSON string), ``source``.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from .._atomic import atomic_bytes, atomic_json
from ..errors import InputValueError
from .capture import Capture, capture_hand, check_against_hand
from .compliance import default_compliance, generalized_names
from .estimate import (REASON_NAMES, ComplianceEstimate, EstimateSettings, InteractionTrajectory,
                       estimate_compliance, reference_trajectory)
from .events import ContactEvents, detect_contact_events

__all__ = ["MIN_FPS", "CaptureEstimate", "NoContactError", "generalized_coordinates", "joint_torques",
           "estimate_capture", "write_interaction", "OUTPUT_FILES", "prepare_output_dir", "format_table"]

MIN_FPS = 200.0
"""Hz: below it the 100 ms reflex-free window holds fewer than 20 samples."""


class NoContactError(Exception):
    """No contact event above the threshold (the CLI exits 1); ``max_force`` newtons was the largest force."""

    def __init__(self, message: str, max_force: float):
        super().__init__(message)
        self.max_force = max_force


@dataclass(frozen=True)
class CaptureEstimate:
    """Everything the estimation produced (N = 6 + D).

    names:      (N,) generalized coordinate names; theta (T, N); tau (T, N)
    events:     :class:`ContactEvents`; estimate: :class:`ComplianceEstimate`
    trajectory: :class:`InteractionTrajectory`; defaults (N,) and default_source (N,) from Table 1
    settings:   :class:`EstimateSettings`; fps Hz; truth (N,) or None; source str or None
    """

    names: tuple
    theta: np.ndarray
    tau: np.ndarray
    events: ContactEvents
    estimate: ComplianceEstimate
    trajectory: InteractionTrajectory
    defaults: np.ndarray
    default_source: tuple
    settings: EstimateSettings
    fps: float
    truth: np.ndarray | None
    source: str | None
    root_origin: np.ndarray | None = None

    def summary(self) -> dict:
        """Per coordinate: median, IQR, counts, rejections by reason, and the error against the truth if known."""
        est = self.estimate
        rows = []
        for j, name in enumerate(self.names):
            v = est.values[:, j][est.valid[:, j]]
            counts = {REASON_NAMES[r]: int((est.reason[:, j] == r).sum()) for r in range(len(REASON_NAMES))}
            row = {"name": name, "valid": int(v.size), "events": int(est.reason.shape[0]),
                   "median": float(np.median(v)) if v.size else None,
                   "iqr": [float(np.percentile(v, 25)), float(np.percentile(v, 75))] if v.size else None,
                   "reasons": {k: n for k, n in counts.items() if n},
                   "default": float(self.defaults[j]), "default_source": self.default_source[j],
                   "uses_default": bool(self.trajectory.is_default[j])}
            if self.truth is not None and np.isfinite(self.truth[j]):
                row["truth"] = float(self.truth[j])
                row["relative_error"] = (float(np.median(v) / self.truth[j] - 1) if v.size else None)
            rows.append(row)
        return {"fps": self.fps, "frames": int(self.theta.shape[0]), "events": self.events.count,
                "force_threshold_N": self.events.threshold, "force_noise_N": self.events.noise,
                "max_force_N": self.events.max_force, "source": self.source, "settings": asdict(self.settings),
                "reason_names": list(REASON_NAMES), "coordinates": rows}


def _rotvec(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_rotvec()


def generalized_coordinates(capture: Capture) -> np.ndarray:
    """theta, (T, 6 + D): root rotation vector of R(t) R(0)^T (rad), root translation p(t) - p(0) (m), then q."""
    R = capture.root_pose[:, :3, :3]
    rel = R @ R[0].T
    root = np.concatenate([_rotvec(rel), capture.root_pose[:, :3, 3] - capture.root_pose[0, :3, 3]], axis=1)
    return np.concatenate([root, capture.q], axis=1)


def joint_torques(capture: Capture, hand, *, smoothing: float = 0.0, chunk: int = 8192) -> np.ndarray:
    """tau(t) = sum_s J_s^T f_s, (T, 6 + D): N m for rotations, N for the root translation (module docstring).

    capture:   :class:`Capture` whose joints and links match ``hand``; hand: HandModel
    smoothing: seconds; > 0 evaluates J at joint angles smoothed by a Savitzky-Golay filter (degree 2, that
               window), so that angle noise does not enter tau (see :func:`estimate_capture`)
    chunk:     frames per batch
    """
    check_against_hand(capture, hand)
    hand = hand.to(device="cpu", dtype=torch.float64)
    links = torch.tensor([hand.link_index(n) for n in capture.force_link], dtype=torch.long)
    q = torch.from_numpy(smooth_angles(capture.q, capture.fps, smoothing))
    root = torch.from_numpy(capture.root_pose)
    pts = torch.from_numpy(capture.force_point)
    f = torch.from_numpy(capture.force)
    out = []
    with torch.no_grad():
        for a in range(0, q.shape[0], chunk):
            b = a + chunk
            out.append(hand.contact_torques(q[a:b], root[a:b], links, pts[a:b], f[a:b]).numpy())
    return np.concatenate(out, axis=0)


def smooth_angles(q: np.ndarray, fps: float, window: float) -> np.ndarray:
    """Savitzky-Golay smoothing (degree 2) of joint angles (T, D) over ``window`` seconds (odd frame count >= 5);
    ``window <= 0`` or too few frames: q unchanged. Degree 2 keeps quadratic motion exactly."""
    n = int(round(window * fps)) // 2 * 2 + 1
    if window <= 0 or n < 5 or q.shape[0] < n:
        return q
    from scipy.signal import savgol_filter

    return savgol_filter(q, n, 2, axis=0, mode="interp")


def estimate_capture(capture: Capture, hand=None, settings: EstimateSettings = EstimateSettings(), *,
                     default: str = "table1-exploring", allow_low_rate: bool = False) -> CaptureEstimate:
    """Compliance and reference trajectory of a capture.

    capture:        :class:`Capture`
    hand:           HandModel, or None for the capture's own (``capture.hand``)
    settings:       :class:`EstimateSettings`
    default:        Table 1 preset for coordinates without a valid estimate
    allow_low_rate: accept fps < 200
    returns: :class:`CaptureEstimate`
    raises: InputValueError (fps too low, ...); NoContactError when no event is found
    """
    if capture.fps < MIN_FPS and not allow_low_rate:
        raise InputValueError(f"fps: {capture.fps:g} Hz; compliance estimation needs >= 20 samples in the 100 ms "
                              f"reflex window (fps >= {MIN_FPS:g}; the paper used 500 Hz); pass --allow-low-rate "
                              f"to try anyway")
    hand = capture_hand(capture) if hand is None else hand
    check_against_hand(capture, hand)
    theta = generalized_coordinates(capture)
    tau = joint_torques(capture, hand, smoothing=settings.jacobian_smoothing)
    finger = np.array([int(hand.link_finger[hand.link_index(n)]) for n in capture.force_link], dtype=np.int64)
    events = detect_contact_events(capture.force, capture.fps, force_threshold=settings.force_threshold,
                                   gap=settings.gap, finger=finger, merge=settings.merge)
    if events.count == 0:
        raise NoContactError(f"no contact event: the largest force is {events.max_force:.4g} N, below the threshold "
                             f"{events.threshold:.4g} N (or never after {settings.gap:g} s without contact)",
                             events.max_force)
    est = estimate_compliance(theta, tau, events, capture.fps, settings)
    defaults, source = default_compliance(hand, default)
    traj = reference_trajectory(theta, tau, est, events.frame, defaults, settings.mode)
    return CaptureEstimate(names=generalized_names(capture.joint_names), theta=theta, tau=tau, events=events,
                           estimate=est, trajectory=traj, defaults=defaults, default_source=source,
                           settings=settings, fps=capture.fps, truth=capture.truth_compliance, source=capture.source,
                           root_origin=np.asarray(capture.root_pose[0], dtype=np.float64))


OUTPUT_FILES = ("interaction.npz", "summary.json", "compliance_events.png")
_OUTPUT_PREFIX = "contact_event_"


def prepare_output_dir(out, overwrite: bool = False) -> Path:
    """Check ``--out`` before any work: new, empty, or (with ``overwrite``) an earlier estimate; created.

    With ``overwrite`` the earlier estimate's plots are removed (their number may differ, and ``--no-plots`` writes
    none), which is said on stderr; its interaction.npz and summary.json are replaced atomically when the new ones
    are written.

    raises: InputValueError naming ``--out`` when it is a file, holds other files, holds an earlier estimate and
        ``overwrite`` is not set, or cannot be written
    """
    import sys

    from .._atomic import claim_output_dir, writable_dir

    out, ours = claim_output_dir(
        out, lambda p: p.name in OUTPUT_FILES or (p.name.startswith(_OUTPUT_PREFIX) and p.suffix == ".png"),
        "estimate", overwrite)
    stale = sorted(p for p in ours if p.suffix == ".png")
    if stale:
        print(f"torchhand: --overwrite: removing {len(stale)} earlier plot(s) from {out}", file=sys.stderr)
        for p in stale:
            p.unlink()
    return writable_dir(out)


def write_interaction(result: CaptureEstimate, out) -> list[Path]:
    """Write ``interaction.npz`` and ``summary.json`` into ``out`` (atomically). returns: the paths written."""
    import io

    out = Path(out)
    est, tr = result.estimate, result.trajectory
    data = dict(C=tr.compliance, C_is_default=tr.is_default, theta=result.theta, theta_r=tr.theta_r[:, 6:],
                root_theta_r=tr.theta_r[:, :6], tau=result.tau, event_time=result.events.time,
                event_frame=result.events.frame, event_sensor=result.events.sensor, estimates=est.values,
                raw_estimates=est.raw, stderr=est.stderr, reasons=est.reason,
                reason_names=np.array(REASON_NAMES), windows=est.windows, names=np.array(result.names),
                joint_names=np.array(result.names[6:]), default_compliance=result.defaults, fps=np.array(result.fps),
                settings=np.array(json.dumps(asdict(result.settings))),
                source=np.array(result.source or ""))
    if result.truth is not None:
        data["truth_compliance"] = result.truth
    if result.root_origin is not None:
        data["root_origin"] = result.root_origin  # the world root pose the root coordinates are relative to
    buf = io.BytesIO()
    np.savez_compressed(buf, **data)
    atomic_bytes(out / "interaction.npz", buf.getvalue())
    atomic_json(out / "summary.json", result.summary())
    return [out / "interaction.npz", out / "summary.json"]



def format_table(result: CaptureEstimate, *, only_loaded: bool = True) -> str:
    """One row per coordinate: truth (if known), median estimate, error, valid/total events, rejection reasons."""
    rows = [["coordinate", "truth", "median", "error %", "valid/events", "reasons"]]
    for row in result.summary()["coordinates"]:
        reasons = {k: n for k, n in row["reasons"].items() if k != "valid"}
        if only_loaded and row["valid"] == 0 and set(reasons) <= {"fixed", "not_loaded"} and "truth" not in row:
            continue
        err = row.get("relative_error")
        rows.append([row["name"], f"{row['truth']:.4f}" if "truth" in row else "-",
                     f"{row['median']:.4f}" if row["median"] is not None else "-",
                     f"{100 * err:+.1f}" if err is not None else "-", f"{row['valid']}/{row['events']}",
                     ", ".join(f"{k} {n}" for k, n in sorted(reasons.items())) or "-"])
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return "\n".join("  ".join(c.ljust(w) if i in (0, 5) else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths)))
                     .rstrip() for r in rows)
