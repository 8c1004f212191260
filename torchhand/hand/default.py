"""The default 36-DOF human hand of Ye & Liu (2012), Figure 4.

6 DOF of the wrist are the root pose (an input); the 30 finger DOF are:

* index, middle, ring, little: a 2-DOF palm joint near the wrist (``*_cmc_flex``, ``*_cmc_roll``: small deformations
  of the palm), a 2-DOF MCP (``*_mcp_abd`` then ``*_mcp_flex``), a 1-DOF PIP and a 1-DOF DIP;
* thumb: a 3-DOF CMC ball joint (``thumb_cmc_flex``, ``thumb_cmc_abd``, ``thumb_cmc_roll``), a 2-DOF MCP
  (``thumb_mcp_flex``, ``thumb_mcp_abd``) and a 1-DOF IP.

Hand frame (right hand): origin at the wrist joint centre, +x toward the fingertips, the palm faces -z, +y toward the
thumb. Every finger link's frame has its x along the bone, its y on the flexion axis (positive angle = flexion
toward the palm) and its z on the dorsal (nail) side. The left hand is the mirror image through the x-z plane: positions
p -> M p and joint axes a -> -M a with M = diag(1, -1, 1), so a joint angle means the same anatomical motion on both
hands.

Proportions are those of an adult hand of 0.19 m (wrist to middle fingertip) and scale linearly with ``length``.
Joint ranges are the usual active ranges of motion, rounded. Collision geometry is one capsule per link plus a carpal
capsule on the palm link.

Mass: the hand segment (wrist axis to knuckle II of the middle finger) is 0.006 of body mass (Dempster 1955, as
tabulated in D. A. Winter, *Biomechanics and Motor Control of Human Movement*, 4th ed., Wiley 2009, Table 4.1).
For a 70 kg adult that is 0.42 kg at the reference length of 0.19 m, scaled with ``length ** 3``
(``HAND_MASS_FRACTION``, ``REFERENCE_BODY_MASS``). It is split between the links by the volume of their collision
geometry: one uniform density (about 1390 kg/m^3, above that of tissue because the capsules are slimmer than the
hand), and each link's centre of mass and inertia are those of its capsules at that density.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from kornia.geometry.conversions import axis_angle_to_rotation_matrix

from ..errors import InputValueError
from .dynamics import geom_inertial
from .model import FingerSpec, GeomSpec, HandModel, JointSpec, LinkSpec, build_hand_model

__all__ = ["default_hand", "FINGER_NAMES", "REFERENCE_LENGTH", "HAND_MASS_FRACTION", "REFERENCE_BODY_MASS"]

REFERENCE_LENGTH = 0.19
HAND_MASS_FRACTION = 0.006  # hand / body mass (Dempster 1955; Winter 2009, Table 4.1)
REFERENCE_BODY_MASS = 70.0  # kg, the adult whose hand is REFERENCE_LENGTH long
FINGER_NAMES = ("thumb", "index", "middle", "ring", "little")
_D2R = math.pi / 180

# Palm joint (CMC) and knuckle (MCP) positions in the hand frame, metres, for the 0.19 m right hand.
_FINGERS = {
    #          cmc                    mcp (knuckle)          phalanx lengths (prox, mid, dist)  radii (meta, prox, mid, dist)
    "index": ((0.012, 0.010, 0.0), (0.083, 0.024, 0.0), (0.041, 0.025, 0.025), (0.0115, 0.0095, 0.0085, 0.0078)),
    "middle": ((0.012, 0.002, 0.0), (0.086, 0.002, 0.0), (0.046, 0.029, 0.029), (0.0115, 0.0095, 0.0085, 0.0078)),
    "ring": ((0.011, -0.006, 0.0), (0.080, -0.018, 0.0), (0.043, 0.028, 0.026), (0.0110, 0.0090, 0.0080, 0.0075)),
    "little": ((0.010, -0.014, 0.0), (0.071, -0.036, 0.0), (0.034, 0.020, 0.023), (0.0100, 0.0082, 0.0075, 0.0070)),
}
# Joint ranges in degrees.
_FINGER_LIMITS = {
    "cmc_flex": {"index": (-6, 6), "middle": (-6, 6), "ring": (-6, 12), "little": (-6, 18)},
    "cmc_roll": {"index": (-8, 8), "middle": (-8, 8), "ring": (-10, 14), "little": (-10, 18)},
    "mcp_abd": (-20, 20),
    "mcp_flex": (-20, 90),
    "pip": (-3, 110),
    "dip": (-5, 80),
}
_THUMB = {
    "cmc": (0.020, 0.018, -0.010),
    "orientation_deg": (40.0, 15.0, -60.0),  # R = Rz(a) Ry(b) Rx(c): bone toward +x+y, pad toward the palm
    "lengths": (0.046, 0.032, 0.026),
    "radii": (0.0120, 0.0100, 0.0092),
    "limits": {
        "cmc_flex": (-20, 60), "cmc_abd": (-30, 30), "cmc_roll": (-30, 30),
        "mcp_flex": (-10, 60), "mcp_abd": (-15, 15), "ip": (-15, 80),
    },
}
_REST_DEG = {"cmc_flex": 0, "cmc_roll": 0, "mcp_abd": 0, "mcp_flex": 20, "pip": 25, "dip": 15,
             "thumb_cmc_flex": 10, "thumb_cmc_abd": 0, "thumb_cmc_roll": 0, "thumb_mcp_flex": 10,
             "thumb_mcp_abd": 0, "thumb_ip": 10}

_X, _Y, _Z = np.eye(3)


def _rot(axis, angle: float) -> np.ndarray:
    aa = torch.as_tensor(np.asarray(axis, dtype=np.float64) * angle).reshape(1, 3)
    return axis_angle_to_rotation_matrix(aa)[0].numpy()


def _pose(R=None, p=(0.0, 0.0, 0.0)) -> np.ndarray:
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    T[:3, 3] = p
    return T


def _capsule_along_x(link: str, x0: float, x1: float, radius: float) -> GeomSpec:
    """A capsule whose segment runs from (x0, 0, 0) to (x1, 0, 0) in the link frame (MJCF: geom z = link x)."""
    R = _rot(_Y, math.pi / 2)  # geom z -> link x
    return GeomSpec(link=link, type="capsule", size=np.array([radius, 0.5 * (x1 - x0), 0.0]),
                    pose=_pose(R, (0.5 * (x0 + x1), 0.0, 0.0)), name=f"{link}_capsule")


def default_hand(side: str = "right", length: float = REFERENCE_LENGTH, *, dtype: torch.dtype = torch.float64,
                 device=None) -> HandModel:
    """The 36-DOF human hand (30 finger DOF here; the wrist's 6 DOF are the root pose).

    side:   "right" or "left"
    length: wrist to middle fingertip, metres (proportions scale linearly)
    returns: HandModel with D = 30 joints, L = 20 links, F = 5 fingers (thumb, index, middle, ring, little);
        total mass ``HAND_MASS_FRACTION * REFERENCE_BODY_MASS * (length / REFERENCE_LENGTH) ** 3`` kg
    """
    if side not in ("right", "left"):
        raise InputValueError(f"side: expected 'right' or 'left', got {side!r}")
    if not (isinstance(length, (int, float)) and math.isfinite(length) and 0.05 <= length <= 0.5):
        raise InputValueError(f"length: expected a hand length in [0.05, 0.5] metres, got {length!r}")
    s = float(length) / REFERENCE_LENGTH
    links: list[LinkSpec] = [LinkSpec("palm", None, np.eye(4))]
    joints: list[JointSpec] = []
    geoms: list[GeomSpec] = [
        # Carpal region of the palm, across the wrist end of the metacarpals.
        GeomSpec("palm", "capsule", np.array([0.016 * s, 0.016 * s, 0.0]),
                 _pose(_rot(_X, math.pi / 2), (0.014 * s, -0.001 * s, -0.002 * s)), name="palm_carpal"),
    ]
    fingers: list[FingerSpec] = []
    rest: dict[str, float] = {}

    def hinge(name, link, axis, lo_deg, hi_deg):
        joints.append(JointSpec(name, link, "hinge", np.asarray(axis, dtype=np.float64), np.zeros(3),
                                np.array([lo_deg * _D2R, hi_deg * _D2R])))

    # Thumb.
    th = _THUMB
    a, b, c = (v * _D2R for v in th["orientation_deg"])
    R_th = _rot(_Z, a) @ _rot(_Y, b) @ _rot(_X, c)
    lm, lp, ld = (v * s for v in th["lengths"])
    rm, rp, rd = (v * s for v in th["radii"])
    links += [LinkSpec("thumb_metacarpal", "palm", _pose(R_th, np.array(th["cmc"]) * s)),
              LinkSpec("thumb_proximal", "thumb_metacarpal", _pose(None, (lm, 0, 0))),
              LinkSpec("thumb_distal", "thumb_proximal", _pose(None, (lp, 0, 0)))]
    lim = th["limits"]
    hinge("thumb_cmc_flex", "thumb_metacarpal", _Y, *lim["cmc_flex"])
    hinge("thumb_cmc_abd", "thumb_metacarpal", _Z, *lim["cmc_abd"])
    hinge("thumb_cmc_roll", "thumb_metacarpal", _X, *lim["cmc_roll"])
    hinge("thumb_mcp_flex", "thumb_proximal", _Y, *lim["mcp_flex"])
    hinge("thumb_mcp_abd", "thumb_proximal", _Z, *lim["mcp_abd"])
    hinge("thumb_ip", "thumb_distal", _Y, *lim["ip"])
    geoms += [_capsule_along_x("thumb_metacarpal", 0.0, lm, rm), _capsule_along_x("thumb_proximal", 0.0, lp, rp),
              _capsule_along_x("thumb_distal", 0.0, ld - rd, rd)]
    fingers.append(FingerSpec("thumb", ("thumb_metacarpal", "thumb_proximal", "thumb_distal"), _Z,
                              np.array([0.6 * ld, 0.0, -rd]), ("thumb_cmc_flex", "thumb_mcp_flex", "thumb_ip")))
    for j in ("thumb_cmc_flex", "thumb_cmc_abd", "thumb_cmc_roll", "thumb_mcp_flex", "thumb_mcp_abd", "thumb_ip"):
        rest[j] = _REST_DEG[j] * _D2R

    # Four fingers.
    for f, (cmc, mcp, lengths, radii) in _FINGERS.items():
        cmc, mcp = np.array(cmc) * s, np.array(mcp) * s
        d = mcp - cmc
        lmeta = float(np.linalg.norm(d))
        yaw = math.atan2(d[1], d[0])
        lp, lmid, ld = (v * s for v in lengths)
        rmeta, rp, rmid, rd = (v * s for v in radii)
        names = [f"{f}_metacarpal", f"{f}_proximal", f"{f}_middle", f"{f}_distal"]
        links += [LinkSpec(names[0], "palm", _pose(_rot(_Z, yaw), cmc)),
                  LinkSpec(names[1], names[0], _pose(None, (lmeta, 0, 0))),
                  LinkSpec(names[2], names[1], _pose(None, (lp, 0, 0))),
                  LinkSpec(names[3], names[2], _pose(None, (lmid, 0, 0)))]
        hinge(f"{f}_cmc_flex", names[0], _Y, *_FINGER_LIMITS["cmc_flex"][f])
        hinge(f"{f}_cmc_roll", names[0], _X, *_FINGER_LIMITS["cmc_roll"][f])
        hinge(f"{f}_mcp_abd", names[1], _Z, *_FINGER_LIMITS["mcp_abd"])
        hinge(f"{f}_mcp_flex", names[1], _Y, *_FINGER_LIMITS["mcp_flex"])
        hinge(f"{f}_pip", names[2], _Y, *_FINGER_LIMITS["pip"])
        hinge(f"{f}_dip", names[3], _Y, *_FINGER_LIMITS["dip"])
        geoms += [_capsule_along_x(names[0], 0.25 * lmeta, lmeta, rmeta), _capsule_along_x(names[1], 0.0, lp, rp),
                  _capsule_along_x(names[2], 0.0, lmid, rmid), _capsule_along_x(names[3], 0.0, ld - rd, rd)]
        fingers.append(FingerSpec(f, tuple(names), _Z, np.array([0.6 * ld, 0.0, -rd]),
                                  (f"{f}_mcp_flex", f"{f}_pip", f"{f}_dip")))
        for j in ("cmc_flex", "cmc_roll", "mcp_abd", "mcp_flex", "pip", "dip"):
            rest[f"{f}_{j}"] = _REST_DEG[j] * _D2R

    if side == "left":
        links, joints, geoms, fingers = _mirror(links, joints, geoms, fingers)
    q_rest = np.array([rest[j.name] for j in joints])
    # One density that gives the anthropometric mass: the mass split by collision-geometry volume.
    volume = sum(geom_inertial(g, 1.0)[0] for g in geoms)
    density = HAND_MASS_FRACTION * REFERENCE_BODY_MASS * s ** 3 / volume
    hand = build_hand_model(f"default_{side}", links, joints, geoms, fingers, side=side, length=float(length),
                            q_rest=q_rest, density=density)
    if dtype != torch.float64 or device is not None:
        hand = hand.to(device=device, dtype=dtype)
    return hand


def _mirror(links, joints, geoms, fingers):
    """Mirror through the x-z plane: positions p -> M p, rotations R -> M R M, axes a -> -M a (M = diag(1,-1,1)).

    Geometry and link frames keep right-handed frames (M R M is a rotation), so the mirrored model is a valid
    kinematic tree whose joint angles mean the same anatomical motions as the right hand's.
    """
    M = np.diag([1.0, -1.0, 1.0])
    M4 = np.diag([1.0, -1.0, 1.0, 1.0])

    def T(X):
        return M4 @ X @ M4

    links = [LinkSpec(l.name, l.parent, T(l.offset)) for l in links]
    joints = [JointSpec(j.name, j.link, j.type, -M @ j.axis if j.type == "hinge" else M @ j.axis, M @ j.anchor,
                        j.limits) for j in joints]
    geoms = [GeomSpec(g.link, g.type, g.size, T(g.pose), g.mesh, g.name) for g in geoms]
    fingers = [FingerSpec(f.name, f.links, M @ f.nail_normal, M @ f.tip, f.flexion_joints) for f in fingers]
    return links, joints, geoms, fingers
