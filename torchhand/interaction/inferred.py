"""Inferred interactions: a synthesis result's contact forces as a capture, and its interaction trajectory.

A ``torchhand synthesize`` result (Ye & Liu 2012; docs/result_format.md) holds, per frame, the finger joints ``q``,
the wrist pose ``root_pose`` and the contact forces of the hand on the object at points on the object surface. That
is a full record for Kry & Pai (2006): the forces on the hand are ``-contact_force``, and tau = sum_s J_s^T f_s
over the 6 + D generalized coordinates (:func:`torchhand.interaction.pipeline.joint_torques`). The forces are
*inferred* (solved by the synthesis for the scene's object motion), not measured, and so is the compliance: there
are no contact events to estimate it from, so C(t) is a Kry & Pai Table 1 preset for every coordinate
(:func:`~torchhand.interaction.compliance.default_compliance`), as the paper did for its pressure-ball capture
(§8.2). The reference trajectory is then theta_r = theta - C tau.

Pipeline (pure stages)::

    inf = infer_interaction("out/box-turn", solution=0, frames=(12, 54))   # InferredInteraction
    write_inferred(inf, prepare_inferred_dir("out/inferred"))             # capture.npz, interaction.npz, ...

Sensors of the capture: one per (link, occurrence) of the solution's contacts. A link that holds two contacts in
one frame (a fingertip's contact and its area-contact proxy) gets two sensors. A sensor's force is zero in frames
where it has no contact, and its point is then the origin of its link frame. The contact point, which lies on the
object surface, is expressed in the link frame at that frame's pose.

Friction margin (a deviation from a plain replay, on by default): a synthesis solves the smallest normal forces that
produce the object's wrench (Ye & Liu 2012, Eq. 4), so its forces lie on the friction cone's boundary (|f_t| = mu f_n).
Replayed as a capture, every resynthesised contact then starts on the verge of sliding and the object lags and slips in
the hand. Kry & Pai treat a tangential to normal force ratio above a threshold below mu as imminent slip (§8.1, "on the
verge of slipping", the grip response the paper models after Johansson 1998); it does not say how far below mu its
captured forces were. With ``friction_margin`` F < 1, each frame's hand forces are re-solved by the synthesis' own force
solve (:func:`torchhand.kernels.friction_cone.solve_friction_cone`: minimum total normal force, exact second-order
cones) for the SAME net wrench on the object (force and torque about its centre of mass, from the solution's forces) at
the same contacts with the friction coefficient F mu; tau and theta_r then come from those forces. The object's motion
is unchanged (the wrench is), the grip squeezes harder, and every force lies inside the true cone with |f_t| <= F mu
f_n. A frame whose wrench cannot be made within F mu (INFEASIBLE: the contacts' geometry needs more friction) tries F +
(1 - F) j / 4, j = 1, 2, 3, and failing those keeps the solution's forces; ``summary.json`` counts them. F = 1 (or None)
is the plain replay.
Units: metres, seconds, radians, newtons; compliance rad/(N m), root linear m/N.
"""

from __future__ import annotations

import dataclasses
import io
import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .._atomic import atomic_bytes, atomic_json, claim_output_dir, writable_dir
from ..errors import InputValueError
from ._interaction_file import Interaction
from .capture import Capture, save_capture
from .compliance import PRESETS, default_compliance, generalized_names

__all__ = [
    "OUTPUT_NAMES",
    "InferredInteraction",
    "MarginReport",
    "with_friction_margin",
    "capture_from_solution",
    "infer_interaction",
    "interaction_arrays",
    "parse_frames",
    "prepare_inferred_dir",
    "write_inferred",
]

OUTPUT_NAMES = ("capture.npz", "interaction.npz", "summary.json", "hand.xml", "hand_assets", "scene")
"""What :func:`write_inferred` writes into its directory."""


@dataclass(frozen=True, eq=False)
class InferredInteraction:
    """A synthesis solution turned into a capture and an interaction trajectory (N = 6 + D coordinates).

    capture: :class:`~torchhand.interaction.capture.Capture` (source "inferred", hand "hand.xml")
    names: (N,) generalized coordinate names
    theta: (T, N) generalized coordinates (root rotation vector and translation relative to the first frame's
        root pose, then the joints), rad / m
    tau: (T, N) generalized torques sum_s J_s^T f_s of the forces on the hand, N m / N
    C: (T, N) compliance, rad/(N m) (root linear m/N); the Table 1 preset ``compliance`` in every frame
    compliance_source: (N,) the rule of each coordinate's compliance ("table1:mp", "assumed:0.1*mp", ...)
    theta_r: (T, N) reference trajectory theta - C tau
    root_origin: (4, 4) world root pose the root coordinates are relative to (the first selected frame's)
    object_pose: (T, 4, 4) the solution's object poses
    frames: (start, stop) of the solution's frames used; solution: solution index; result: the result directory
    compliance: the preset name; scene: the result's scene restricted to ``frames``; hand: HandModel (float64)
    hand_file: the result's MJCF of the hand (``hand.xml``) or None
    margin: :class:`MarginReport` of the friction-margin re-solve, or None
    """

    capture: Capture
    names: tuple
    theta: np.ndarray
    tau: np.ndarray
    C: np.ndarray
    compliance_source: tuple
    theta_r: np.ndarray
    root_origin: np.ndarray
    object_pose: np.ndarray
    frames: tuple
    solution: int
    result: Path
    compliance: str
    scene: object
    hand: object
    hand_file: Path | None
    margin: MarginReport | None = None

    @property
    def T(self) -> int:
        return int(self.theta.shape[0])

    def interaction(self):
        """The :class:`~torchhand.interaction.resynth.Interaction` that ``capture resynthesize`` reads."""
        return Interaction(fps=float(self.capture.fps), joint_names=tuple(self.capture.joint_names), C=self.C,
                           theta_r=self.theta_r[:, 6:], root_theta_r=self.theta_r[:, :6],
                           root_origin=self.root_origin, source="inferred", theta=self.theta)

    def summary(self) -> dict:
        """Where the data came from, the sensors, the largest force and torque, the compliance rules."""
        fmag = np.linalg.norm(self.capture.force, axis=-1)
        return {"source": "inferred", "result": str(self.result), "solution": self.solution,
                "frames": list(self.frames), "fps": float(self.capture.fps), "compliance": self.compliance,
                "sensors": [{"link": n, "frames_loaded": int((fmag[:, s] > 0).sum())}
                            for s, n in enumerate(self.capture.force_link)],
                "max_total_force_N": float(fmag.sum(1).max()) if fmag.size else 0.0,
                "max_abs_tau": {n: float(np.abs(self.tau[:, j]).max()) for j, n in enumerate(self.names)},
                "compliance_rules": dict(zip(self.names, self.compliance_source)),
                "friction_margin": None if self.margin is None else dataclasses.asdict(self.margin)}


def parse_frames(text: str | None, T: int) -> tuple[int, int]:
    """``"A:B"`` (either side may be empty) -> (A, B) with 0 <= A, A + 2 <= B <= T; None -> (0, T)."""
    if text is None:
        a, b = 0, T
    else:
        parts = str(text).split(":")
        try:
            if len(parts) != 2:
                raise ValueError
            a = int(parts[0]) if parts[0].strip() else 0
            b = int(parts[1]) if parts[1].strip() else T
        except ValueError:
            raise InputValueError(f"--frames: expected START:STOP with integers, got {text!r}") from None
    if not (0 <= a and a + 2 <= b <= T):
        raise InputValueError(f"--frames: expected 0 <= START and START + 2 <= STOP <= {T} (the solution's frames; "
                              f"an interaction needs 2 frames), got {text!r}")
    return a, b


def _sensors(mask: np.ndarray, link: np.ndarray) -> tuple[list, np.ndarray]:
    """Sensor keys (link, occurrence), sorted, and the sensor of every slot (T, K) (-1 where no contact)."""
    T, K = mask.shape
    occ = np.full((T, K), -1, dtype=np.int64)
    for t in range(T):
        seen: dict = {}
        for k in range(K):
            if mask[t, k]:
                n = seen.get(int(link[t, k]), 0)
                occ[t, k] = n
                seen[int(link[t, k])] = n + 1
    keys = sorted({(int(link[t, k]), int(occ[t, k])) for t, k in zip(*np.nonzero(mask))})
    index = {key: s for s, key in enumerate(keys)}
    sensor = np.full((T, K), -1, dtype=np.int64)
    for t, k in zip(*np.nonzero(mask)):
        sensor[t, k] = index[(int(link[t, k]), int(occ[t, k]))]
    return keys, sensor


def capture_from_solution(sol, hand, *, hand_spec: str = "hand.xml") -> Capture:
    """The capture of a one-hand solution: forces on the hand (``-contact_force``) at the contact points in their
    link frames, one sensor per (link, occurrence) (module docstring).

    sol: :class:`torchhand.io.result.Solution` (already restricted to the frames wanted); hand: HandModel of the
    solution's joints; hand_spec: the capture's ``hand`` entry
    returns: :class:`Capture` with source "inferred" and the object poses
    raises: InputValueError (two hands, no contact in any frame), UnknownNameError (a contact link the hand lacks)
    """
    if len(sol.hands) != 1:
        raise InputValueError(f"{sol.path}: inferred interactions are made from one-hand results; this solution has "
                              f"{len(sol.hands)} hands")
    hs = sol.hands[0]
    if tuple(hs.joint_names) != tuple(hand.joint_names):
        raise InputValueError(f"{sol.path}: joint_names differ from the result's hand.xml")
    mask, link = sol.contact_mask, sol.contact_link
    if not mask.any():
        raise InputValueError(f"{sol.path}: no contact in the frames chosen; choose frames where the hand holds the "
                              f"object (--frames)")
    names = sol.contact_link_names()
    keys, sensor = _sensors(mask, link)
    links = tuple(names[l] for l, _ in keys)
    idx = [hand.link_index(n) for n in links]
    T, S = mask.shape[0], len(keys)
    h = hand.to(device="cpu", dtype=torch.float64)
    with torch.no_grad():
        poses = h.forward_kinematics(torch.from_numpy(hs.q), torch.from_numpy(hs.root_pose)).numpy()  # (T, L, 4, 4)
    force = np.zeros((T, S, 3))
    point = np.zeros((T, S, 3))
    for t, k in zip(*np.nonzero(mask)):
        s = sensor[t, k]
        P = poses[t, idx[s]]
        force[t, s] = -sol.contact_force[t, k]                                    # on the hand
        point[t, s] = P[:3, :3].T @ (sol.contact_point[t, k] - P[:3, 3])          # link frame
    return Capture(q=hs.q.copy(), joint_names=tuple(hs.joint_names), root_pose=hs.root_pose.copy(), fps=sol.fps,
                   force=force, force_point=point, force_link=links, hand=hand_spec,
                   object_pose=sol.object_pose.copy(), source="inferred")


@dataclass(frozen=True)
class MarginReport:
    """What the friction-margin re-solve did (module docstring).

    margin: F (1.0: not applied); frames: frames with hand forces; resolved: frames whose forces were re-solved (within
    F mu, or within F' mu for the smallest F' of F + (1 - F) j / 4 that works); kept: frames that kept the solution's
    forces; use_before, use_after: the largest |f_t| / (mu f_n) of the loaded hand forces (|f| > 0.05 N) before and
    after; wrench_residual: the largest ||sum f - F_req|| + ||sum p x f - tau_req|| of the re-solved frames, N + N m;
    use_resolved: the largest |f_t| / (mu f_n) over the re-solved frames only
    """

    margin: float
    frames: int
    resolved: int
    kept: int
    use_before: float
    use_after: float
    wrench_residual: float
    use_resolved: float


def _friction_use(force, normal, mask, mu: float) -> float:
    fn = (force * normal).sum(-1)
    ft = np.linalg.norm(force - fn[..., None] * normal, axis=-1)
    sel = mask & (np.linalg.norm(force, axis=-1) > 0.05) & (fn > 0)
    return float((ft[sel] / (mu * fn[sel])).max()) if sel.any() and mu > 0 else 0.0


def with_friction_margin(sol, com, mu: float, margin: float):
    """The solution with each frame's hand forces re-solved inside cones of ``margin * mu`` for the same object
    wrench (module docstring).

    sol: :class:`torchhand.io.result.Solution` (one hand); com: the object's centre of mass, (3,), object frame,
    metres; mu: the hand-object friction coefficient; margin: F in (0, 1]
    returns: (solution, :class:`MarginReport`)
    """
    import dataclasses

    from torchhand.kernels.friction_cone import solve_friction_cone
    from torchhand.kernels.status import SolverStatus

    if not 0 < margin <= 1:
        raise InputValueError(f"--friction-margin: expected 0 < F <= 1, got {margin}")
    mask = sol.contact_mask & (np.linalg.norm(sol.contact_force, axis=-1) > 0)
    f0, n, p = sol.contact_force, sol.contact_normal, sol.contact_point
    before = _friction_use(f0, n, mask, mu)
    loaded = mask.any(1)
    if margin >= 1 or mu <= 0 or not loaded.any():
        return sol, MarginReport(1.0 if margin >= 1 else margin, int(loaded.sum()), 0, int(loaded.sum()), before,
                                 before, 0.0, 0.0)
    R, pos = sol.object_pose[:, :3, :3], sol.object_pose[:, :3, 3]
    c = np.einsum("tij,j->ti", R, np.asarray(com, dtype=np.float64)) + pos
    r = p - c[:, None]
    fm = f0 * mask[..., None]
    wrench = np.concatenate([fm.sum(1), np.cross(r, fm).sum(1)], -1)
    force = f0.copy()
    todo = np.nonzero(loaded)[0]
    done = np.zeros(len(loaded), dtype=bool)
    resolved, res = 0, 0.0
    # F first; frames whose wrench needs more friction than F mu try F + (1 - F) j / 4, j = 1, 2, 3
    for F in [margin + (1.0 - margin) * j / 4 for j in range(4)]:
        if len(todo) == 0:
            break
        tt = lambda x: torch.from_numpy(np.ascontiguousarray(x[todo], dtype=np.float64))  # noqa: E731
        out = solve_friction_cone(tt(r), tt(n), torch.full(mask[todo].shape, float(F * mu), dtype=torch.float64),
                                  tt(wrench), mask=torch.from_numpy(mask[todo]), warm_start=tt(fm))
        ok = (out.status == int(SolverStatus.CONVERGED)).numpy()
        force[todo[ok]] = out.forces.numpy()[ok] * mask[todo[ok]][..., None]
        done[todo[ok]] = True
        resolved += int(ok.sum())
        res = max(res, float(out.residual.numpy()[ok].max()) if ok.any() else 0.0)
        todo = todo[~ok]
    new = dataclasses.replace(sol, contact_force=force)
    return new, MarginReport(float(margin), int(loaded.sum()), resolved, len(todo), before,
                             _friction_use(force, n, mask, mu), res, _friction_use(force, n, mask & done[:, None], mu))


def _restrict(sol, a: int, b: int):
    """The solution's frames a <= t < b (the per-frame arrays sliced)."""
    import dataclasses

    s = slice(a, b)
    hands = tuple(dataclasses.replace(h, q=h.q[s], root_pose=h.root_pose[s],
                                      guiding=None if h.guiding is None else h.guiding[s]) for h in sol.hands)
    per_frame = ("object_pose", "contact_mask", "contact_link", "contact_point", "contact_normal", "contact_force",
                 "contact_sliding", "env_contact_mask", "env_contact_point", "env_contact_force")
    return dataclasses.replace(sol, hands=hands, **{n: getattr(sol, n)[s] for n in per_frame})


def infer_interaction(result_dir, *, solution: int = 0, frames: str | tuple | None = None,
                      compliance: str = "table1-exploring", friction_margin: float | None = 0.8) -> InferredInteraction:
    """Capture and interaction trajectory of one solution of a result directory (module docstring).

    result_dir: a ``torchhand synthesize`` result (read with :func:`torchhand.io.result.load_result`)
    solution: solution index; frames: "A:B" or (A, B) of the solution's frames, None for all
    compliance: Table 1 preset, "table1-exploring" or "table1-scratching"
    friction_margin: F in (0, 1]: re-solve the hand forces inside cones of F mu for the same object wrench (module
        docstring; 0.8 by default); 1 or None: the solution's forces as they are
    returns: :class:`InferredInteraction`
    raises: MissingFileError / FileFormatError (no or a malformed result), InputValueError (bad solution index,
        bad frames, a two-hand result, no contact in the frames, unknown preset)
    """
    from ..io.result import load_result
    from .capture import check_against_hand
    from .pipeline import generalized_coordinates, joint_torques

    if compliance not in PRESETS:
        raise InputValueError(f"--compliance: expected one of {', '.join(PRESETS)}, got {compliance!r}")
    res = load_result(result_dir)
    n = len(res.solution_files)
    if isinstance(solution, bool) or not isinstance(solution, (int, np.integer)) or not 0 <= solution < n:
        raise InputValueError(f"--solution: {solution!r} is not a solution of {res.path} (it has {n}"
                              + (f": 0..{n - 1})" if n else ")"))
    if len(res.scene.hands) != 1:
        raise InputValueError(f"{res.path}: inferred interactions are made from one-hand results; the scene has "
                              f"{len(res.scene.hands)} hands")
    sol = res.solution(int(solution))
    if isinstance(frames, tuple):
        a, b = parse_frames(f"{frames[0]}:{frames[1]}", sol.T)
    else:
        a, b = parse_frames(frames, sol.T)
    sol = _restrict(sol, a, b)
    mu = sol.friction if sol.friction is not None else res.scene.friction
    sol, margin = with_friction_margin(sol, res.scene.object.com, float(mu),
                                       1.0 if friction_margin is None else float(friction_margin))
    side = res.scene.hands[0].side
    hand = res.hand_models[side].to(device="cpu", dtype=torch.float64)
    hand_file = Path(res.path) / "hand.xml"
    cap = capture_from_solution(sol, hand)
    check_against_hand(cap, hand)
    theta = generalized_coordinates(cap)
    tau = joint_torques(cap, hand, smoothing=0.0)
    c0, rules = default_compliance(hand, compliance)
    C = np.broadcast_to(c0, theta.shape).copy()
    return InferredInteraction(
        capture=cap, names=generalized_names(cap.joint_names), theta=theta, tau=tau, C=C,
        compliance_source=tuple(rules), theta_r=theta - C * tau, root_origin=cap.root_pose[0].copy(),
        object_pose=sol.object_pose.copy(), frames=(a, b), solution=int(solution), result=Path(res.path),
        compliance=compliance, scene=res.scene.with_frames(a, b), hand=hand,
        hand_file=hand_file if hand_file.is_file() else None, margin=margin)


def prepare_inferred_dir(out, overwrite: bool = False) -> Path:
    """Check ``--out`` before any work: new, empty, or (with ``overwrite``) an earlier output of
    :func:`write_inferred`; created.

    raises: InputValueError naming ``--out`` when it is a file, holds other files, holds an earlier output and
        ``overwrite`` is not set, or cannot be written
    """
    claim_output_dir(out, lambda p: p.name in OUTPUT_NAMES, "inferred interaction", overwrite)
    return writable_dir(out)


def interaction_arrays(inf: InferredInteraction) -> dict:
    """The arrays of ``interaction.npz``: the keys ``capture estimate`` writes (docs/interaction_capture.md), with
    no contact events (E = 0), every coordinate flagged as a default, and ``source`` "inferred"."""
    N = len(inf.names)
    settings = {"result": str(inf.result), "solution": inf.solution, "frames": list(inf.frames),
                "compliance": inf.compliance, "tau": "pipeline.joint_torques, no smoothing",
                "friction_margin": None if inf.margin is None else inf.margin.margin}
    return dict(C=inf.C, C_is_default=np.ones(N, dtype=bool), theta=inf.theta, theta_r=inf.theta_r[:, 6:],
                root_theta_r=inf.theta_r[:, :6], tau=inf.tau, event_time=np.zeros(0),
                event_frame=np.zeros(0, dtype=np.int64), event_sensor=np.zeros(0, dtype=np.int64),
                names=np.array(inf.names), joint_names=np.array(inf.names[6:]),
                default_compliance=inf.C[0].copy(), default_source=np.array(inf.compliance_source),
                fps=np.array(float(inf.capture.fps)), root_origin=inf.root_origin, object_pose=inf.object_pose,
                settings=np.array(json.dumps(settings)), source=np.array("inferred"))


def write_inferred(inf: InferredInteraction, out) -> list[Path]:
    """Write ``capture.npz``, ``interaction.npz``, ``summary.json``, the result's ``hand.xml`` (and
    ``hand_assets/``; the capture's ``hand`` names it) and ``scene/`` (the result's scene over the frames used,
    for ``capture resynthesize``) into ``out`` (a directory :func:`prepare_inferred_dir` accepted); every file
    atomically. returns: the paths written."""
    out = Path(out)
    written = []
    if inf.hand_file is not None:
        atomic_bytes(out / "hand.xml", inf.hand_file.read_bytes())
        assets = inf.hand_file.parent / "hand_assets"
        if assets.is_dir():
            shutil.rmtree(out / "hand_assets", ignore_errors=True)
            shutil.copytree(assets, out / "hand_assets")
        cap = inf.capture
    else:  # an older result without hand.xml: its hand is the default one
        import dataclasses

        cap = dataclasses.replace(inf.capture, hand="default")
    written.append(save_capture(cap, out / "capture.npz"))
    buf = io.BytesIO()
    np.savez_compressed(buf, **interaction_arrays(inf))
    atomic_bytes(out / "interaction.npz", buf.getvalue())
    written.append(out / "interaction.npz")
    atomic_json(out / "summary.json", inf.summary())
    written.append(out / "summary.json")
    written.append(inf.scene.export(out / "scene", overwrite=True))
    return written
