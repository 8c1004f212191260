"""The checker's verdict, frame by frame, for the viewer's timeline.

:func:`torchhand.check.check_result` gives each solution's verdict and, per figure, its worst value and the frame of
it; it keeps no per-frame values. The timeline needs one pass/fail per frame, so :func:`frame_verdicts` runs
``check_result`` for the solutions' verdicts and, for the figures that are measured frame by frame, recomputes the
per-frame values with the checker's own measuring functions (:mod:`torchhand.check.penetration`,
:mod:`.contacts`, :mod:`.motion`) against the checker's limits:

- per frame: object, table, hand-hand and finger-finger penetration (hand.xml's capsules), contact-object and
  contact-hand distance, friction cones, force and torque balance, joint limits, joint speed (frame t against
  t - 1) and acceleration (t - 1, t, t + 1);
- not per frame: ``distinct_deg`` (a whole solution against the earlier ones) counts only in the solution's verdict.

Robot hands whose geometry is not all capsules are measured per frame on the capsules fitted to their links (the
checker measures their penetration on the MJCF geoms posed by MuJoCo), so for them a frame's mark is an
approximation of the figure the checker reports; the solution's verdict is always the checker's.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from ..check import check_result
from ..check.contacts import cone_violations, contact_gaps, contact_slots
from ..check.geometry import ObjectMesh, object_mesh
from ..check.motion import balance_errors, joint_acceleration, joint_limit_violation, joint_speed
from ..check.ground import hand_environment_depth
from ..check.penetration import finger_depth, finger_pairs, hand_hand_depth, object_depth, pose_hand, table_depth
from ..check.report import FIGURES, format_value, resolve_limits
from ..io.result import Result, Solution, load_result

__all__ = ["FrameVerdicts", "frame_verdicts", "frame_figures", "PER_FRAME"]

PER_FRAME = ("object_penetration_m", "table_penetration_m", "hand_penetration_m", "finger_penetration_m",
             "contact_object_m", "contact_hand_m", "cone_violation", "force_error", "torque_error",
             "joint_limit_rad", "joint_speed_rad_s", "joint_acceleration_rad_s2")
"""The checker's figures that :func:`frame_verdicts` judges frame by frame (``distinct_deg`` is not)."""


@dataclass(frozen=True, eq=False)
class FrameVerdicts:
    """The verdict of one solution, whole and per frame.

    index: XXX of ``sol_XXX.npz``; passed: the checker's verdict of the whole solution
    failures: the checker's failure line of the solution ("" when it passes)
    frame_ok: (T,) bool, every per-frame figure (:data:`PER_FRAME`) within its limit at that frame
    frame_failing: T tuples of the figure names failing at that frame (labels of :data:`torchhand.check.FIGURES`)
    values: figure name -> (T,) float64, the frame's worst value in the figure's unit, NaN where nothing is measured
    """

    index: int
    passed: bool
    failures: str
    frame_ok: np.ndarray
    frame_failing: tuple
    values: MappingProxyType

    def describe(self, t: int) -> str:
        """One line for frame ``t``: pass, or the failing figures' labels and values."""
        if self.frame_ok[t]:
            return "pass"
        parts = [f"{FIGURES[n].label} {format_value(n, float(self.values[n][t]))}" for n in self.frame_failing[t]]
        return "FAIL: " + "; ".join(parts)


def frame_verdicts(result_dir, limits=None) -> tuple:
    """:class:`FrameVerdicts` of every solution of a result directory, in file order.

    limits: figure name -> limit overriding the checker's :data:`torchhand.check.LIMITS`, or None
    Raises what :func:`torchhand.check.check_result` raises for a missing or malformed directory.
    """
    report = check_result(result_dir, limits=limits)
    result = load_result(result_dir)
    obj = object_mesh(result.scene.object.mesh, result.scene.object.mass)
    out = []
    for i, check in enumerate(report.solutions):
        sol = result.solution(i)
        lim = resolve_limits(limits, fps=sol.fps)
        values = frame_figures(sol, result, obj)
        failing = []
        for t in range(sol.T):
            failing.append(tuple(n for n, v in values.items() if np.isfinite(v[t]) and v[t] > lim[n]))
        out.append(FrameVerdicts(index=check.index, passed=check.passed, failures=check.failure if not check.passed
                                 else "", frame_ok=np.array([not f for f in failing], dtype=bool),
                                 frame_failing=tuple(failing), values=MappingProxyType(values)))
    return tuple(out)


def frame_figures(sol: Solution, result: Result, obj: ObjectMesh) -> dict:
    """Figure name -> (T,) worst value per frame (NaN: nothing measured) of :data:`PER_FRAME`'s figures that
    apply to the solution's scene, measured as :func:`torchhand.check.check_solution` measures them."""
    scene = result.scene
    hands = {hs.side: pose_hand(result.hand_models[hs.side], hs.side, hs.q, hs.joint_names, hs.root_pose,
                                sol.path) for hs in sol.hands}
    hl = list(hands.values())
    mass = float(sol.object_mass if sol.object_mass is not None else scene.object.mass)
    if mass != float(scene.object.mass):
        import dataclasses

        obj = dataclasses.replace(obj, inertia=obj.inertia * (mass / float(scene.object.mass)))
    out = {"object_penetration_m": _rows([object_depth(h, obj, sol.object_pose) for h in hl])}
    env = scene.environment
    if env.table and env.plain:
        out["table_penetration_m"] = _rows([table_depth(h, env.table_height) for h in hl])
    elif env.table or env.floor:  # a table with an edge, a floor
        out["table_penetration_m"] = _rows([hand_environment_depth(h, env) for h in hl])
    if len(hl) == 2:
        d = hand_hand_depth(hl[0], hl[1])
        out["hand_penetration_m"] = _rows([d.reshape(d.shape[0], -1)])
    out["finger_penetration_m"] = _rows([finger_depth(h, finger_pairs(h.model)) for h in hl])
    out.update(_contact_rows(sol, scene, hands, obj, mass))
    ext = getattr(scene, "external_wrench", None)
    f_err, t_err = balance_errors(sol, obj, mass, scene.gravity.numpy().astype(np.float64),
                                  **({"external": ext} if ext is not None else {}))
    out["force_error"], out["torque_error"] = f_err, t_err
    q_all = np.concatenate([h.q for h in hl], axis=1)
    bounds = np.concatenate([h.model.joint_limits.numpy().astype(np.float64) for h in hl], axis=0)
    out["joint_limit_rad"] = _rows([joint_limit_violation(q_all, bounds)])
    out["joint_speed_rad_s"] = _rows([joint_speed(q_all, sol.fps)])
    out["joint_acceleration_rad_s2"] = _rows([joint_acceleration(q_all, sol.fps)])
    return {n: out[n] for n in PER_FRAME if n in out}


def _contact_rows(sol: Solution, scene, hands: dict, obj: ObjectMesh, mass: float) -> dict:
    slots = contact_slots(hands, sol.contact_link_name, sol.contact_link, sol.contact_mask, sol.path)
    gap_obj, gap_hand, closest, tri = contact_gaps(hands, slots, sol.contact_point, obj, sol.object_pose)
    weight = mass * max(float(np.linalg.norm(scene.gravity.numpy())), 1e-12)
    hand_cone, table_cone = cone_violations(slots, sol.contact_force, closest, tri, obj, sol.object_pose,
                                            scene.friction, sol.env_contact_mask, sol.env_contact_force,
                                            scene.environment.friction, 1e-6 * weight)
    return {"contact_object_m": _rows([gap_obj]), "contact_hand_m": _rows([gap_hand]),
            "cone_violation": _rows([hand_cone, table_cone])}


def _rows(arrays: list) -> np.ndarray:
    """The largest finite value per frame of (T, X) arrays side by side, (T,); NaN where a frame has none."""
    v = np.concatenate([np.asarray(a, dtype=np.float64).reshape(a.shape[0], -1) for a in arrays], axis=1)
    finite = np.isfinite(v)
    best = np.where(finite, v, -np.inf).max(axis=1, initial=-np.inf)
    return np.where(finite.any(axis=1), best, np.nan)
