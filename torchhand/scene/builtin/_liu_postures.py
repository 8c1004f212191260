"""The hand side of the Liu 2009 built-in scenes (:mod:`torchhand.scene.builtin.liu`): the fitted postures and
grasp frames each scene's hand track holds its object with, and where the Shadow hand of liu-shadow-lift is found.

* liu-roll: :func:`roll_pinch`, a thumb-index pinch of the default right hand and the cylinder's place in it;
* liu-press: :func:`press_pose`, thumb, index and middle fingertips over the plate;
* liu-shadow-lift: :func:`shadow_pose` of the Shadow hand (:func:`shadow_hand_path`, in :func:`shared_data_dir`);
* liu-two-hand-lift: :func:`two_hand_pose`, two flat hands on the big box's side faces.

Every posture was fitted once by ``scripts/make_liu_grasps.py`` and is stored here rounded to 0.1 degree. Conventions:
metres, radians (postures are written in degrees), column-vector 4x4 transforms, ``T_object_hand`` the wrist in the
object frame (see :mod:`torchhand.conventions`).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import torch

from ...errors import MissingFileError

__all__ = ["ROLL_RADIUS", "SHADOW_HAND", "TWO_HAND_SNAP_TOL", "press_pose", "roll_pinch", "shadow_hand_path",
           "shadow_pose", "shared_data_dir", "two_hand_pose"]


def _posture(hand, degrees: dict, *, rest: bool = True) -> tuple:
    """(hand, q (D,) radians): ``hand`` (the default right hand when None) at its rest angles (``rest=False``: at
    0) with the joints named in ``degrees`` set."""
    from ...hand import default_hand

    hand = default_hand() if hand is None else hand
    names = list(hand.joint_names)
    q = hand.q_rest.detach().cpu().double().numpy().copy() if rest else np.zeros(len(names))
    for name, deg in degrees.items():
        q[names.index(name)] = math.radians(deg)
    return hand, q


# --- roll: the liu-roll pinch --------------------------------------------------------------------------------------

ROLL_RADIUS = 0.02
"""Radius of the liu-roll cylinder, metres."""

# The pinch posture of the default right hand (degrees): thumb and index from a coarse search over their joint
# ranges refined by least squares with every joint kept at least 4 degrees inside its limits
# (scripts/make_liu_grasps.py, ``make_roll``), rounded to 0.1 degree; the middle, ring and little fingers curled into
# the palm, out of the way. A 4 cm cylinder is near the edge of this thumb's reach: without the 4-degree margin six
# thumb and index joints end at their limits, and the fingers can then hardly move in the roll's direction.
_ROLL_POSTURE = {
    "thumb_cmc_flex": 21.5, "thumb_cmc_abd": 26.0, "thumb_cmc_roll": -26.0, "thumb_mcp_flex": -6.0,
    "thumb_mcp_abd": 11.0, "thumb_ip": 5.7,
    "index_mcp_abd": 16.0, "index_mcp_flex": 49.7, "index_pip": 23.0, "index_dip": -1.0,
    "middle_mcp_flex": 85.0, "middle_pip": 100.0, "middle_dip": 60.0,
    "ring_mcp_flex": 85.0, "ring_pip": 100.0, "ring_dip": 60.0,
    "little_mcp_flex": 85.0, "little_pip": 100.0, "little_dip": 60.0,
}
# Where each distal capsule touches: the fraction s of its axis (0 at the joint, 1 at the fingertip end).
_ROLL_TOUCH = {"thumb_distal": 0.79, "index_distal": 0.74}


def roll_pinch(hand=None) -> tuple[np.ndarray, np.ndarray]:
    """The liu-roll pinch: the default right hand's joint angles and the cylinder in the hand frame.

    The posture is ``_ROLL_POSTURE`` (the other joints at their rest angles). The cylinder is placed between the
    two distal capsules: with P_t, P_i the points at ``_ROLL_TOUCH`` on the thumb's and the index's capsule axes,
    m the mean direction of the two axes (they are within 14 degrees of parallel), u the unit component of
    ``P_i - P_t`` normal to m and a = m x u, the cylinder's axis is a (about the hand's -y, the palm's lateral
    direction), its centre ``P_t + (ROLL_RADIUS + r_thumb) u`` moved along a to halfway between the two points, so
    the thumb capsule touches it and the index capsule is 0.5 mm from it (snapping closes that gap).

    Args:
        hand: the default right hand (built when None)

    Returns:
        (q (D,) radians, T_hand_object (4, 4)): the object frame has its origin at the cylinder's centre, z along
        its axis and x along u (from the thumb's contact toward the index's).
    """
    hand, q = _posture(hand, _ROLL_POSTURE)
    T = hand.forward_kinematics(torch.as_tensor(q, dtype=hand.dtype)[None])[0].detach().cpu().double().numpy()
    a_loc, b_loc = hand.capsule_a.detach().cpu().double().numpy(), hand.capsule_b.detach().cpu().double().numpy()
    r = hand.capsule_radius.detach().cpu().double().numpy()
    links = [list(hand.link_names).index(n) for n in _ROLL_TOUCH]
    P = [T[l, :3, :3] @ (a_loc[l] + s * (b_loc[l] - a_loc[l])) + T[l, :3, 3]
         for l, s in zip(links, _ROLL_TOUCH.values())]
    x = [T[l, :3, 0] for l in links]
    m = x[0] + np.sign(x[0] @ x[1]) * x[1]
    m /= np.linalg.norm(m)
    w = P[1] - P[0]
    u = w - (w @ m) * m
    u /= np.linalg.norm(u)
    a = np.cross(m, u)
    centre = P[0] + (ROLL_RADIUS + r[links[0]]) * u + 0.5 * (w @ a) * a
    T_hand_object = np.eye(4)
    T_hand_object[:3, :3] = np.stack([u, np.cross(a, u), a], axis=1)
    T_hand_object[:3, 3] = centre
    return q, T_hand_object


# --- press: the liu-press fingertips -------------------------------------------------------------------------------

# The press posture of the default right hand (degrees): the thumb, index and middle fingertips on the plate's top
# face around its centre (a least-squares fit of the fingertip capsules onto the face near chosen points, every joint
# at least 3 degrees inside its limits, the other links at least 4 mm clear of the plate; scripts/make_liu_grasps.py,
# ``make_press``), rounded to 0.1 degree; the ring and little fingers curled above the plate.
_PRESS_POSTURE = {
    "thumb_cmc_flex": 16.5, "thumb_cmc_abd": 25.3, "thumb_cmc_roll": -2.1, "thumb_mcp_flex": 50.5,
    "thumb_mcp_abd": -4.7, "thumb_ip": 35.2,
    "index_cmc_roll": -5.0, "index_mcp_abd": -0.5, "index_mcp_flex": 51.3, "index_pip": 37.8, "index_dip": 39.5,
    "middle_cmc_roll": -5.0, "middle_mcp_abd": -1.3, "middle_mcp_flex": 34.6, "middle_pip": 60.5, "middle_dip": 33.6,
    "ring_mcp_flex": 60.0, "ring_pip": 70.0, "ring_dip": 40.0,
    "little_mcp_flex": 60.0, "little_pip": 70.0, "little_dip": 40.0,
}
_PRESS_WRIST = (-0.0886, -0.0041, 0.0908)   # the wrist in the plate frame (palm down, fingers along +x), metres


def press_pose(hand=None) -> tuple[np.ndarray, np.ndarray]:
    """The liu-press grasp before snapping: the default right hand's joint angles (``_PRESS_POSTURE``, the other
    joints at rest) and ``T_object_hand`` (the palm facing down over the plate, fingers along +x, the wrist at
    ``_PRESS_WRIST``). The three fingertips are within 3 mm of the top face (snapping closes the gaps), about
    (-20, 8), (11, 16) and (20, -10) mm from its centre, so the plate's centre, where the spring pushes, lies inside
    their triangle."""
    _, q = _posture(hand, _PRESS_POSTURE)
    T_object_hand = np.eye(4)
    T_object_hand[:3, 3] = _PRESS_WRIST
    return q, T_object_hand


# --- shadow-lift: the heavy lift with the Shadow hand --------------------------------------------------------------

SHADOW_HAND = "hands/shadow_hand/right_hand.xml"
"""The hand of liu-shadow-lift, relative to the shared reference data directory (:func:`shared_data_dir`): MuJoCo
Menagerie's Shadow right hand. It is not shipped with torchhand; the packaged grasp names it by this relative path."""

# The Shadow grasp (degrees; the other joints at 0, the file's rest): the first, middle and ring fingertips on the
# box's far (+x) face pointing into it, the thumb tip on the near (-x) face, the little finger curled clear. A
# least-squares fit of the wrist and the finger joints (scripts/make_liu_grasps.py, ``make_shadow_lift``), rounded
# to 0.1 degree. The fingertips press with the ends of their distal links: there the fitted capsules lie within
# 0.6 mm of the Shadow's fingertip meshes, against about 2 mm on the pads, and the checker measures the meshes.
_SHADOW_POSTURE = {
    "rh_FFJ4": 10.9, "rh_FFJ3": 22.9, "rh_FFJ2": 53.8, "rh_FFJ1": 69.8,
    "rh_MFJ4": 9.2, "rh_MFJ3": 32.2, "rh_MFJ2": 57.0, "rh_MFJ1": 57.7,
    "rh_RFJ4": -0.5, "rh_RFJ3": 34.3, "rh_RFJ2": 56.3, "rh_RFJ1": 60.2,
    "rh_LFJ5": 3.0, "rh_LFJ3": 60.0, "rh_LFJ2": 60.0, "rh_LFJ1": 40.0,
    "rh_THJ5": -38.5, "rh_THJ4": 67.0, "rh_THJ3": 9.0, "rh_THJ2": 16.5, "rh_THJ1": 36.4,
}
_SHADOW_WRIST = ((0.0589, 0.2355, 0.3101), (-0.0497, -0.0566, 0.0914))   # rotation vector, position (m), box frame


def shared_data_dir() -> Path:
    """The shared reference data directory: ``$TORCHHAND_SHARED_DATA``, or ``shared/data`` beside the source tree
    (``../shared/data`` from a checkout)."""
    env = os.environ.get("TORCHHAND_SHARED_DATA")
    # parents[3]: the checkout (torchhand/scene/builtin/ is three levels down); shared/ sits beside it
    return Path(env) if env else Path(__file__).resolve().parents[3].parent / "shared" / "data"


def shadow_hand_path() -> Path:
    """The Shadow hand's MJCF file in the shared reference data.

    Raises:
        MissingFileError: it is not there (names the path and ``TORCHHAND_SHARED_DATA``).
    """
    path = shared_data_dir() / SHADOW_HAND
    if not path.is_file():
        raise MissingFileError(f"liu-shadow-lift: the Shadow hand ({SHADOW_HAND} of the shared reference data) is not "
                               f"at {path}; set TORCHHAND_SHARED_DATA to the data directory")
    return path


def shadow_pose(hand) -> tuple[np.ndarray, np.ndarray]:
    """The liu-shadow-lift grasp before snapping: the Shadow hand's joint angles (``_SHADOW_POSTURE``) and
    ``T_object_hand`` (the box frame of the lift at frame 0)."""
    _, q = _posture(hand, _SHADOW_POSTURE, rest=False)
    return q, _rotvec_pose(*_SHADOW_WRIST)


# --- two hands: the flat hands of liu-two-hand-lift ----------------------------------------------------------------

TWO_HAND_SNAP_TOL = 0.0015
"""Snap tolerance of the liu-two-hand-lift grasps, metres: five contact links per hand (thumb metacarpal, index and
middle middle and distal phalanges). With the default 5 mm every link of the flat hands (16 per hand) becomes a
contact, more than the result format's 32 slots."""

# The flat-hand posture of both hands (degrees; the default hand's other joints at 0, not at rest): fingers nearly straight along
# the face, the thumb turned up out of it. A least-squares fit (scripts/make_liu_grasps.py, ``make_two_hand_lift``)
# of the wrist and the finger joints, with the palm and the fingers' middle links on the side face and every other
# link at least 3 mm off it; rounded to 0.1 degree.
_TWO_HAND_POSTURE = {
    "thumb_cmc_flex": -11.3, "thumb_cmc_abd": -19.2, "index_mcp_flex": 10.2, "index_dip": -2.0,
    "middle_mcp_flex": 7.2, "middle_dip": -2.0, "ring_cmc_flex": 4.4, "ring_mcp_flex": -3.3,
    "little_cmc_flex": 4.7, "little_mcp_flex": -4.0,
}
_TWO_HAND_WRIST = {                      # rotation vector, position (m), box frame
    "right": ((1.2491, 1.2679, 1.1895), (0.1713, -0.0913, 0.0)),
    "left": ((-1.2636, -1.2448, 1.1667), (-0.1713, -0.0913, 0.0)),
}


def _rotvec_pose(rotvec, pos) -> np.ndarray:
    """(4, 4) from a rotation vector (radians) and a position."""
    rotvec = np.asarray(rotvec, dtype=np.float64)
    angle = float(np.linalg.norm(rotvec))
    k = rotvec / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    T = np.eye(4)
    T[:3, :3] = np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * K @ K
    T[:3, 3] = pos
    return T


def two_hand_pose(side: str) -> tuple[np.ndarray, np.ndarray]:
    """The liu-two-hand-lift grasp of one hand before snapping: the default ``side`` hand's joint angles and
    ``T_object_hand`` (the palm flat on the box's +x face for the right hand, -x for the left, fingers along +y,
    thumbs up)."""
    from ...hand import default_hand

    _, q = _posture(default_hand(side), _TWO_HAND_POSTURE, rest=False)     # not the rest pose: flat fingers
    return q, _rotvec_pose(*_TWO_HAND_WRIST[side])
