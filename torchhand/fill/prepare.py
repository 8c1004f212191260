"""A captured scene made ready for the search: its phases, the slide speed from its own noise, the wrist steadied.

:func:`prepare_capture` is what ``torchhand synthesize`` does first with an imported capture (a scene with a
``source``) and what ``torchhand fill`` does with a whole one: the phases (:mod:`torchhand.fill.phases`), the
slide speed (:mod:`torchhand.fill.noise`, unless given) and each hand's wrist steadied against the object while
it is held (:mod:`torchhand.fill.wrist`, unless the tolerance is zero). Built-in and hand-made scenes are left as
they are (slide speed 0.02 m/s, the wrist fixed), as in the paper.

Conventions: scene frames, metres, seconds, radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from ..errors import InputValueError
from .object_rest import ObjectAdjustment, ObjectRest, steady_object, with_object
from .wrist import WristAdjustment, WristTolerance, steady_wrist, with_wrist

__all__ = ["DEFAULT_SLIDE_SPEED", "PreparedCapture", "prepare_capture", "is_capture"]

DEFAULT_SLIDE_SPEED = 0.02
"""m/s: the slide speed of scenes that are not captures (the node test's default)."""


@dataclass(frozen=True, eq=False)
class PreparedCapture:
    """A scene ready for the search, and how it was made so.

    scene: the scene to search (wrists steadied); slide_speed: m/s; slide_source: "option", "capture noise" or
    "default"; phases: per hand side, the phases (tuple of :class:`~torchhand.fill.phases.Phase`), {} for a scene
    that is not a capture; noise: per side, :class:`~torchhand.fill.noise.CaptureNoise`; wrist: per side,
    :class:`~torchhand.fill.wrist.WristAdjustment` (only hands that were steadied); tolerance: the tolerance used;
    object: the object track's :class:`~torchhand.fill.object_rest.ObjectAdjustment`, None when it was kept
    """

    scene: object
    slide_speed: float
    slide_source: str
    tolerance: WristTolerance
    phases: dict = field(default_factory=dict)
    noise: dict = field(default_factory=dict)
    wrist: dict = field(default_factory=dict)
    object: ObjectAdjustment | None = None

    def to_json(self) -> dict:
        """The figures for ``stats.json`` (``capture``)."""
        return {"slide_speed": self.slide_speed, "slide_speed_source": self.slide_source,
                "wrist_tolerance": self.tolerance.to_json(),
                "noise": {s: n.to_json() for s, n in self.noise.items()},
                "wrist_deviation": {s: a.summary() for s, a in self.wrist.items()},
                "phases": {s: [p.to_json() for p in ph] for s, ph in self.phases.items()},
                "object_deviation": None if self.object is None else self.object.summary()}

    def describe(self) -> str:
        """One line for the terminal."""
        parts = [f"slide speed {self.slide_speed:.3g} m/s ({self.slide_source})"]
        for s, a in self.wrist.items():
            m = a.summary()
            parts.append(f"{s} wrist moved by median {m['translation_mm']['median']:.1f} mm / "
                         f"{m['rotation_deg']['median']:.1f} deg (max {m['translation_mm']['max']:.1f} mm / "
                         f"{m['rotation_deg']['max']:.1f} deg) on {m['frames_moved']} frames")
        if self.object is not None:
            parts.append(self.object.describe().replace("; ", ", "))
        return "; ".join(parts)


def is_capture(scene) -> bool:
    """Whether ``scene`` was imported from a motion capture (it has a ``source``)."""
    return getattr(scene, "source", None) is not None


def prepare_capture(scene, *, slide_speed: float | None = None, tolerance: WristTolerance | None = None,
                    phases: dict | None = None, object_rest: ObjectRest | None = ObjectRest()) -> PreparedCapture:
    """Phases, slide speed and steadied wrists of ``scene`` (module docstring).

    Args:
        scene: a :class:`~torchhand.scene.Scene`.
        slide_speed: m/s, or None: from the capture's noise (a capture) or :data:`DEFAULT_SLIDE_SPEED`.
        tolerance: the wrist tolerance, or None: :class:`WristTolerance()` for a capture, fixed otherwise.
        phases: per side, phases to use instead of :func:`~torchhand.fill.phases.segment_phases`'.
        object_rest: the limits of the object's adjustment (:mod:`torchhand.fill.object_rest`) of a capture, or
            None: the object track as captured.
    """
    capture = is_capture(scene)
    if slide_speed is not None and not (isinstance(slide_speed, (int, float)) and math.isfinite(slide_speed)
                                        and slide_speed > 0):
        raise InputValueError(f"slide_speed: expected a positive number of m/s, got {slide_speed!r}")
    if tolerance is None:
        tolerance = WristTolerance() if capture else WristTolerance(0.0, 0.0)
    needs_phases = capture and (slide_speed is None or not tolerance.fixed or object_rest is not None)
    if not needs_phases and phases is None:
        return PreparedCapture(scene, float(slide_speed or DEFAULT_SLIDE_SPEED),
                               "option" if slide_speed is not None else "default", tolerance)
    from .noise import capture_noise
    from .phases import segment_phases

    phases = dict(phases or {})
    for h in scene.hands:
        phases.setdefault(h.side, segment_phases(scene, h.side))
    scene.environment.require_plain("fill")
    obj = None
    if capture and object_rest is not None:
        obj = steady_object(scene.object_pose, scene.object.mesh, scene.environment.table_height
                            if scene.environment.table else None, scene.fps, object_rest)
        if not torch.equal(obj.used, obj.captured):
            scene = with_object(scene, obj.used)
        else:
            obj = None
    noise = {h.side: capture_noise(scene, h.side, phases[h.side]) for h in scene.hands}
    if slide_speed is None:
        slide_speed, source = max(n.slide_speed for n in noise.values()), "capture noise"
    else:
        source = "option"
    adjusted = {}
    for h in scene.hands:
        held = held_frames(phases[h.side], scene.T)
        adj: WristAdjustment = steady_wrist(h.wrist_pose, scene.object_pose, held, scene.fps, tolerance)
        if not tolerance.fixed and held.any():
            adjusted[h.side] = adj
            scene = with_wrist(scene, h.side, adj.used)
    return PreparedCapture(scene, float(slide_speed), source, tolerance, phases, noise, adjusted, obj)


def held_frames(phases, T: int) -> np.ndarray:
    """(T,) bool: the frames of contact phases."""
    held = np.zeros(T, dtype=bool)
    for p in phases:
        if p.kind == "contact":
            held[p.start:p.stop] = True
    return held
