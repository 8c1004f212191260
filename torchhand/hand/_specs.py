"""The plain specs a hand model is built from (NumPy, float64): links, joints, geoms, fingers, inertials, and the
whole-hand :class:`HandSpec` that the MJCF reader produces.

Nothing here depends on torch or on :class:`~torchhand.hand.model.HandModel`: :func:`torchhand.hand.model.build_hand_model`
turns specs into a model. Conventions (see :mod:`torchhand.conventions`): metres, radians, kilograms, column-vector
4x4 transforms.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["GEOM_TYPES", "LinkSpec", "JointSpec", "GeomSpec", "FingerSpec", "InertialSpec", "CouplingSpec", "HandSpec"]

GEOM_TYPES = ("capsule", "box", "sphere", "cylinder", "mesh")


@dataclass(frozen=True)
class LinkSpec:
    """name; parent link name (None for the root, which must come first); offset: parent -> link at q = 0, (4, 4)."""

    name: str
    parent: str | None
    offset: np.ndarray


@dataclass(frozen=True)
class JointSpec:
    """A 1-DOF joint moving ``link``. axis (3,) and anchor (3,) in the link frame; limits (2,) radians or metres."""

    name: str
    link: str
    type: str  # "hinge" | "slide"
    axis: np.ndarray
    anchor: np.ndarray
    limits: np.ndarray


@dataclass(frozen=True)
class GeomSpec:
    """Collision geometry on a link, with MJCF's size semantics.

    type: capsule (radius, half-length), cylinder (radius, half-length), sphere (radius), box (half-extents),
    mesh (vertices (V, 3) and faces (F, 3) in the geom frame); pose: geom frame in the link frame, (4, 4); the axis
    of capsules and cylinders is the geom frame's z.
    """

    link: str
    type: str
    size: np.ndarray
    pose: np.ndarray
    mesh: tuple[np.ndarray, np.ndarray] | None = None
    name: str | None = None


@dataclass(frozen=True)
class FingerSpec:
    """A finger (digit): its links from proximal to distal, the nail normal and pad point in the distal link's frame,
    and up to three consecutive flexion joints coupled in Eq. 11 (proximal first; empty when not applicable)."""

    name: str
    links: tuple[str, ...]
    nail_normal: np.ndarray
    tip: np.ndarray
    flexion_joints: tuple[str, ...] = ()


@dataclass(frozen=True)
class InertialSpec:
    """Mass properties of a link: mass, kg; com: centre of mass in the link frame, (3,), metres; inertia: about the
    centre of mass in link-frame axes, (3, 3), kg m^2 (symmetric positive semi-definite)."""

    link: str
    mass: float
    com: np.ndarray
    inertia: np.ndarray


@dataclass(frozen=True)
class CouplingSpec:
    """A coupling of the hand's joints in the source file, reported (the kinematics keep every joint free).

    kind: "tendon" (a fixed tendon: length = sum coef_i q_i) or "equality" (a joint equality: q1 = poly(q2), coef
    the polynomial's five coefficients); name; joints: the joint names it couples
    """

    kind: str
    name: str
    joints: tuple[str, ...]
    coef: tuple[float, ...]


@dataclass(frozen=True)
class HandSpec:
    """A whole hand as plain specs: the arguments of :func:`torchhand.hand.model.build_hand_model`.

    name: model name; links: parents first, the root first; joints: in the order of the model's q; geoms: collision
    geometry; fingers: finger annotations; side: "right" | "left" | "none"; length: metres; q_rest: (D,) radians /
    metres, or None (zero clamped into the limits); inertials: one per link at most (the others from their geoms); couplings: the joint couplings the source file
    declares (reported only)
    """

    name: str
    links: tuple[LinkSpec, ...]
    joints: tuple[JointSpec, ...]
    geoms: tuple[GeomSpec, ...]
    fingers: tuple[FingerSpec, ...] = ()
    side: str = "none"
    length: float = 0.0
    q_rest: np.ndarray | None = None
    inertials: tuple[InertialSpec, ...] = ()
    couplings: tuple[CouplingSpec, ...] = ()
