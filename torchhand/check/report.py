"""The checker's vocabulary: figure names and units, acceptance limits, and the typed, JSON-ready report.

A *figure* is one checked quantity of a solution, reduced to its worst value over every frame (and every link,
contact or joint), with where that worst value occurred. Units are the house units (metres, radians, seconds,
newtons); penetrations and contact distances are positive depths/gaps in metres, balance errors and cone
violations are relative (dimensionless), see :data:`FIGURES`.
"""

from __future__ import annotations

import math
from contextvars import ContextVar
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from ..errors import InputTypeError, InputValueError, UnknownNameError

__all__ = ["FIGURES", "LIMITS", "Figure", "SolutionCheck", "CheckReport", "resolve_limits", "format_value"]


CHECKED_FRAMES: ContextVar = ContextVar("checked_frames", default=None)
"""(T,) bool of the solution being checked: frames it claims (a ``frame_status`` other than unsolved); None: all.
Per-frame figures ignore the other frames (rows of T - 1 or T - 2 differences: those touching one)."""


@dataclass(frozen=True)
class _Meta:
    label: str     # words used in tables and failure lines
    unit: str      # unit of the value: "m", "rel", "rad", "rad/s", "rad/s^2", "deg"
    at_least: bool = False  # True: the value must be >= its limit (the distinct figure); else <= its limit


FIGURES = MappingProxyType({
    "object_penetration_m": _Meta("object penetration", "m"),
    "table_penetration_m": _Meta("table penetration", "m"),
    "hand_penetration_m": _Meta("hand-hand penetration", "m"),
    "finger_penetration_m": _Meta("finger-finger penetration", "m"),
    "contact_object_m": _Meta("contact-object gap", "m"),
    "contact_hand_m": _Meta("contact-hand gap", "m"),
    "table_contact_m": _Meta("table contact off its surface", "m"),
    "cone_violation": _Meta("cone violation", "rel"),
    "force_error": _Meta("force error", "rel"),
    "torque_error": _Meta("torque error", "rel"),
    "joint_limit_rad": _Meta("joint limit violation", "rad"),
    "joint_speed_rad_s": _Meta("joint speed", "rad/s"),
    "joint_acceleration_rad_s2": _Meta("joint acceleration", "rad/s^2"),
    "distinct_deg": _Meta("difference to an earlier solution", "deg", at_least=True),
})
"""Every figure, in report order: name -> label, unit and sense."""

LIMITS = MappingProxyType({
    "object_penetration_m": 0.002,
    "table_penetration_m": 0.002,
    "hand_penetration_m": 0.002,
    "finger_penetration_m": 0.002,
    "contact_object_m": 0.002,
    "contact_hand_m": 0.002,
    "table_contact_m": 1e-4,
    "cone_violation": 1e-3,
    "force_error": 0.01,
    "torque_error": 0.01,
    "joint_limit_rad": 1e-6,
    "joint_speed_rad_s": 8.0,
    "joint_acceleration_rad_s2": None,
    "distinct_deg": 2.0,
})
"""Acceptance limits (immutable). A figure passes when its worst value is <= its limit (``distinct_deg``: >=).

* ``*_penetration_m``: depth of a hand capsule in the object, under the table plane, in the other hand's capsules,
  in a capsule of another finger of the same hand, metres.
* ``contact_object_m`` / ``contact_hand_m``: distance of a contact point to the object's surface / to its link's
  capsule surface, metres.
* ``table_contact_m``: height of an object-table (or object-floor) contact point above or below the surface under
  it (the table top over the table, the floor elsewhere; none: infinite), metres.
* ``cone_violation``: ``max(|f_t| - mu f_n, -f_n)`` over hand and table forces, divided by the frame's largest
  force (hand and table).
* ``force_error``: ``|sum f + m g - m a|`` over ``m |g|``; ``torque_error``: ``|sum (p - c) x f - (I alpha +
  omega x I omega)|`` over ``m |g|`` times the object's largest extent.
* ``joint_limit_rad``: how far a joint is beyond hand.xml's limits, radians.
* ``joint_speed_rad_s``: largest ``|dq/dt|`` between consecutive frames, rad/s. Nothing the result says changes
  it (``stats.json``'s ``max_joint_speed`` is the method's own bound, information only); the caller may.
* ``joint_acceleration_rad_s2``: largest ``|d2q/dt2|`` (central second difference), rad/s^2. ``None`` means
  ``2 * joint_speed_rad_s * fps``: a full reversal from the speed limit to minus the speed limit within one frame.
* ``distinct_deg``: mean over frames and joints (all hands) of ``|q_a - q_b|`` to the closest earlier solution,
  degrees; a solution closer than this to an earlier one is a duplicate.
"""


def resolve_limits(limits, *, fps: float) -> dict:
    """The limits in force: :data:`LIMITS`, then the caller's ``limits``; never anything read from a result.

    limits: mapping figure name -> number (or None for the acceleration's default), or None
    fps: frames per second of the solution (for the acceleration's default), > 0
    returns: figure name -> limit in the figure's unit, every name of :data:`LIMITS`, none None
    Raises UnknownNameError for a name not in :data:`LIMITS`, InputValueError / InputTypeError for a bad value.
    """
    out = dict(LIMITS)
    if limits is not None:
        if not hasattr(limits, "items"):
            raise InputTypeError(f"limits: expected a mapping of figure name to number, got {type(limits).__name__}")
        for name, value in limits.items():
            if name not in LIMITS:
                raise UnknownNameError(f"limits: unknown figure {name!r}; known: {', '.join(LIMITS)}")
            if value is None and name == "joint_acceleration_rad_s2":
                out[name] = None
                continue
            out[name] = _positive(value, f"limits[{name!r}]")
    if out["joint_acceleration_rad_s2"] is None:
        out["joint_acceleration_rad_s2"] = 2.0 * out["joint_speed_rad_s"] * float(fps)
    return out


def _positive(value, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) and not hasattr(value, "__float__"):
        raise InputTypeError(f"{what}: expected a number, got {type(value).__name__}")
    v = float(value)
    if not (math.isfinite(v) and v >= 0):
        raise InputValueError(f"{what}: expected a finite number >= 0, got {value}")
    return v


def format_value(name: str, value: float) -> str:
    """A figure's value in display units: millimetres for distances, degrees for ``distinct_deg``."""
    unit = FIGURES[name].unit
    if unit == "m":
        return f"{value * 1e3:.1f} mm"
    if unit == "rel":
        return f"{value:.2g}"
    if unit == "rad":
        return f"{value:.2g} rad"
    if unit == "deg":
        return f"{value:.1f} deg"
    return f"{value:.3g} {unit}"


@dataclass(frozen=True)
class Figure:
    """One figure of one solution.

    value: the worst value over the solution, in the figure's unit (:data:`FIGURES`)
    limit: its acceptance limit, same unit
    frame: the frame of the worst value, or None (figures of the whole solution)
    where: what it is at: a link ("right/index_distal"), a link pair, a contact ("contact 3, right/thumb_distal"),
        a joint ("right/index_pip"), an earlier solution ("sol_000"), or "" when nothing is checked
    ok: whether it passes

    When nothing penetrates, a penetration's value is 0 and ``frame`` / ``where`` name the closest approach.
    """

    value: float
    limit: float
    frame: int | None
    where: str
    ok: bool

    @classmethod
    def make(cls, name: str, value: float, limit: float, frame: int | None = None, where: str = "") -> "Figure":
        """A figure with ``ok`` decided by the figure's sense (<= limit, or >= for ``distinct_deg``)."""
        value = float(value)
        ok = value >= limit if FIGURES[name].at_least else value <= limit
        return cls(value=value, limit=float(limit), frame=None if frame is None else int(frame), where=where,
                   ok=bool(ok))

    @classmethod
    def worst(cls, name: str, values, limit: float, where=lambda t, x: "", floor: float | None = 0.0) -> "Figure":
        """The figure of the largest entry of ``values``.

        values: (T, X) array, NaN where nothing is measured (an empty or all-NaN array gives ``floor``, or 0)
        where: callable (frame, column) -> str naming the column
        floor: values below it are reported as it (a clearance is a penetration of 0), None for no floor
        """
        v = _checked_rows(np.asarray(values, dtype=np.float64))
        if v.size == 0 or np.isnan(v).all():
            return cls.make(name, 0.0 if floor is None else floor, limit)
        t, x = np.unravel_index(int(np.nanargmax(v)), v.shape)
        value = float(v[t, x]) if floor is None else max(float(v[t, x]), floor)
        return cls.make(name, value, limit, int(t), where(int(t), int(x)))

    def to_dict(self) -> dict:
        return {"value": self.value, "limit": self.limit, "frame": self.frame, "where": self.where, "ok": self.ok}


def _checked_rows(v: np.ndarray) -> np.ndarray:
    """``v`` (rows per frame, or per pair / triple of consecutive frames) with unclaimed frames' rows NaN."""
    m = CHECKED_FRAMES.get()
    if m is None or v.ndim == 0 or m.all():
        return v
    T = len(m)
    rows = {T: m, T - 1: m[:-1] & m[1:], T - 2: m[:-2] & m[1:-1] & m[2:]}.get(v.shape[0])
    if rows is None:
        return v
    v = v.copy()
    v[~rows] = np.nan
    return v


@dataclass(frozen=True)
class SolutionCheck:
    """The checked figures of one solution file.

    index: XXX of sol_XXX.npz; file: its name; frames: T
    figures: figure name -> :class:`Figure`, in :data:`FIGURES` order (a figure that does not apply to the scene,
        e.g. the table without a table or hand-hand with one hand, is absent)
    unsolved: frames the file flags unsolved (``frame_status`` 2): not claimed, so not checked, listed apart
    wrist: information, no verdict: per hand whose file keeps the captured wrist (``root_pose_captured``), the
        deviation of the used wrist from it per frame (:func:`torchhand.check.wrist.wrist_deviation`); {} otherwise
    object: information likewise for a file that keeps the captured object track (``object_pose_captured``)
        (:func:`torchhand.check.wrist.object_deviation`); {} otherwise
    """

    index: int
    file: str
    frames: int
    figures: MappingProxyType = field(default_factory=lambda: MappingProxyType({}))
    wrist: dict = field(default_factory=dict)
    unsolved: tuple = ()
    object: dict = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        return all(f.ok for f in self.figures.values())

    @property
    def name(self) -> str:
        return f"sol_{self.index:03d}"

    def failing(self) -> list[str]:
        """Names of the failing figures, worst first (by value over limit)."""
        def excess(n: str) -> float:
            f = self.figures[n]
            if FIGURES[n].at_least:
                return f.limit / max(f.value, 1e-12)
            return f.value / max(f.limit, 1e-300)
        return sorted((n for n, f in self.figures.items() if not f.ok), key=excess, reverse=True)

    def failure(self) -> str:
        """One line naming every failing figure, worst first ("" when the solution passes)."""
        parts = [describe(n, self.figures[n]) for n in self.failing()]
        return f"{self.name}: " + "; ".join(parts) if parts else ""

    def to_dict(self) -> dict:
        out = {"index": self.index, "file": self.file, "frames": self.frames, "passed": self.passed,
               "figures": {n: f.to_dict() for n, f in self.figures.items()}}
        if self.wrist:
            out["wrist_deviation"] = self.wrist
        if self.object:
            out["object_deviation"] = self.object
        if self.unsolved:
            out["unsolved_frames"] = list(self.unsolved)
        return out


def describe(name: str, fig: Figure) -> str:
    """``"table penetration 5.1 mm at frame 40 (right/little_distal) > 2.0 mm"``."""
    meta = FIGURES[name]
    if meta.at_least:
        return (f"duplicate of {fig.where}: mean joint difference {format_value(name, fig.value)} "
                f"< {format_value(name, fig.limit)}")
    at = "" if fig.frame is None else f" at frame {fig.frame}"
    where = f" ({fig.where})" if fig.where else ""
    sense = "<" if fig.ok else ">"
    return f"{meta.label} {format_value(name, fig.value)}{at}{where} {sense} {format_value(name, fig.limit)}"


@dataclass(frozen=True)
class CheckReport:
    """The check of a whole result directory.

    path: the result directory; scene: the scene's name; complete: False for a partial run (stats.json)
    solutions: one :class:`SolutionCheck` per solution file, in index order
    limits: the limits in force (:func:`resolve_limits`), name -> value
    notes: remarks on how the check was made (approximate geometry, open mesh), one line each
    """

    path: str
    scene: str
    complete: bool
    solutions: tuple[SolutionCheck, ...]
    limits: MappingProxyType
    notes: tuple[str, ...] = ()

    @property
    def passed(self) -> bool:
        """Every solution passes (and there is at least one)."""
        return bool(self.solutions) and all(s.passed for s in self.solutions)

    @property
    def failures(self) -> tuple[str, ...]:
        """One line per failing solution, naming its failing figures worst first."""
        return tuple(s.failure() for s in self.solutions if not s.passed)

    def worst(self) -> dict:
        """Figure name -> (solution index, :class:`Figure`) of the worst value over all solutions."""
        out: dict = {}
        for s in self.solutions:
            for n, f in s.figures.items():
                best = out.get(n)
                if best is None or (f.value < best[1].value if FIGURES[n].at_least else f.value > best[1].value):
                    out[n] = (s.index, f)
        return {n: out[n] for n in FIGURES if n in out}

    def to_dict(self) -> dict:
        return {"path": self.path, "scene": self.scene, "complete": self.complete, "passed": self.passed,
                "limits": dict(self.limits), "notes": list(self.notes), "failures": list(self.failures),
                "solutions": [s.to_dict() for s in self.solutions]}
