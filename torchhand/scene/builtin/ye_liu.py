"""The built-in procedural scenes (after the examples of Ye & Liu 2012).

All scenes: 30 fps, a table plane at ``TABLE_HEIGHT`` (z-up, metres), objects at rest ON the table (lowest mesh
point exactly at the table height), hand-object friction 0.8, object-table friction 0.4.

Wrist trajectories are built from a grasp: the hand frame's pose in the object frame, chosen for the default hand
geometry (wrist origin, +x to the fingertips, palm facing -z, palm centre surface at about (0.05, 0, -0.015) in the
hand frame, hand length 0.19 m) so that the palm faces the object a few millimetres from its surface and the fingers
can reach around it. Each scene has three phases:

1. approach (10 frames): the wrist moves 6 cm along the palm normal onto the grasp while the object rests;
2. hold: the wrist moves rigidly with the object (``T_world_hand = T_world_object @ T_object_hand``);
3. retreat (10 frames): the reverse of the approach, the object at rest again.

Profiles are minimum-jerk (``10 s^3 - 15 s^4 + 6 s^5``), so velocities start and end at zero.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch
import trimesh

from ...geometry.objects import RigidObject
from .._model import Scene
from .._parts import Environment, HandTrack
from ..swap import offset_object
from ._registry import register_scene

__all__ = ["TABLE_HEIGHT", "FPS", "PALM_CENTRE", "make_mug_mesh"]

TABLE_HEIGHT = 0.75
"""z of the table plane in every built-in scene, metres."""

FPS = 30.0
"""Frame rate of every built-in scene, frames per second."""

PALM_CENTRE = np.array([0.05, 0.0, -0.015])
"""Centre of the palm surface in the hand frame of either side, (3,), metres."""

_APPROACH = 10       # frames of approach and of retreat
_APPROACH_DIST = 0.06  # metres along the palm normal
_GAP = 0.009         # palm-to-surface gap while holding, metres (the thenar eminence and the thumb
#                      metacarpal of the rest hand stand about 1 cm below the palm centre)
_HAND_FRICTION = 0.8
_TABLE = Environment(table=True, table_height=TABLE_HEIGHT, friction=0.4)


# ---------------------------------------------------------------------------------------------------------------
# small geometry helpers (NumPy, float64)


def _smooth(s: np.ndarray) -> np.ndarray:
    """Minimum-jerk ramp from 0 to 1 over s in [0, 1] (clipped outside)."""
    s = np.clip(s, 0.0, 1.0)
    return s ** 3 * (10 - 15 * s + 6 * s ** 2)


def _ramp(T: int, start: int, stop: int) -> np.ndarray:
    """(T,) smooth 0 -> 1 between frames start and stop."""
    k = np.arange(T, dtype=np.float64)
    return _smooth((k - start) / float(stop - start))


def _rot(axis: str, angle) -> np.ndarray:
    """Rotations about a coordinate axis, (..., 3, 3), angle in radians."""
    a = np.asarray(angle, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    one, zero = np.ones_like(a), np.zeros_like(a)
    rows = {
        "x": ((one, zero, zero), (zero, c, -s), (zero, s, c)),
        "y": ((c, zero, s), (zero, one, zero), (-s, zero, c)),
        "z": ((c, -s, zero), (s, c, zero), (zero, zero, one)),
    }[axis]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def _poses(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Homogeneous transforms from rotations (T, 3, 3) and positions (T, 3), (T, 4, 4)."""
    out = np.zeros(R.shape[:-2] + (4, 4))
    out[..., :3, :3] = R
    out[..., :3, 3] = p
    out[..., 3, 3] = 1.0
    return out


def _grasp(x_axis, z_axis, palm_target) -> np.ndarray:
    """Hand pose in the object frame, (4, 4): fingers along ``x_axis``, back of the hand along ``z_axis`` (the palm
    faces ``-z_axis``), the palm centre surface at ``palm_target`` (object frame, metres). ``y = z x x``: the thumb
    side of a right hand, the little-finger side of a left hand."""
    x = np.asarray(x_axis, dtype=np.float64)
    z = np.asarray(z_axis, dtype=np.float64)
    x, z = x / np.linalg.norm(x), z / np.linalg.norm(z)
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=1)
    return _poses(R, np.asarray(palm_target, dtype=np.float64) - R @ PALM_CENTRE)


def _wrist_track(object_pose: np.ndarray, T_obj_hand: np.ndarray, hold: tuple[int, int]) -> np.ndarray:
    """(T, 4, 4) wrist poses: approach before ``hold[0]``, rigid with the object in ``hold``, retreat after."""
    T = object_pose.shape[0]
    k0, k1 = hold
    wrist = object_pose @ T_obj_hand
    away = np.zeros(T)
    k = np.arange(T, dtype=np.float64)
    away[:k0] = 1.0 - _smooth(k[:k0] / k0)
    away[k1 + 1:] = _smooth((k[k1 + 1:] - k1) / (T - 1 - k1))
    wrist[:, :3, 3] += (_APPROACH_DIST * away)[:, None] * wrist[:, :3, 2]  # along the back of the hand
    return wrist


def _scene(name: str, description: str, obj: RigidObject, object_pose: np.ndarray,
           hands: list[tuple[str, np.ndarray]]) -> Scene:
    tracks = tuple(HandTrack(side=s, wrist_pose=torch.tensor(w, dtype=torch.float64)) for s, w in hands)
    return Scene(name=name, object=obj, object_pose=torch.tensor(object_pose, dtype=torch.float64), fps=FPS,
                 hands=tracks, friction=_HAND_FRICTION, environment=_TABLE, description=description)


def _resting_box(extents) -> tuple[trimesh.Trimesh, float]:
    """A box centred at its object-frame origin and the z of that origin when it rests on the table."""
    ext = np.asarray(extents, dtype=np.float64)
    return trimesh.creation.box(extents=ext), TABLE_HEIGHT + 0.5 * ext[2]


def _standing_cylinder(radius: float, height: float, mass: float, name: str,
                       sections: int = 32) -> tuple[RigidObject, float]:
    """A cylinder about its object-frame z axis and the z of its centre when it stands on the table."""
    mesh = trimesh.creation.cylinder(radius=radius, height=height, sections=sections)
    return RigidObject.from_trimesh(mesh, mass=mass, name=name), TABLE_HEIGHT + 0.5 * height


# ---------------------------------------------------------------------------------------------------------------
# scenes

_BOX_TURN = ("A 9 x 7 x 6 cm box (0.25 kg) on the table is turned 75 degrees about the vertical axis by one right "
             "hand grasping it from above; the box slides on the table.")


def _turn_from_above(name: str, description: str, extents, mass: float, obj_name: str, degrees: float) -> Scene:
    """A box resting on the table turned about the vertical by one right hand from above (66 frames): the palm on
    the top face, fingers along +x over the far edge, thumb (+y) toward the +y side face."""
    T = 66
    mesh, z0 = _resting_box(extents)
    obj = RigidObject.from_trimesh(mesh, mass=mass, name=obj_name)
    hold = (_APPROACH, T - 1 - _APPROACH)
    theta = math.radians(degrees) * _ramp(T, hold[0] + 4, hold[1] - 4)
    pose = _poses(_rot("z", theta), np.tile([0.0, 0.0, z0], (T, 1)))
    grasp = _grasp((1, 0, 0), (0, 0, 1), (0.0, 0.0, 0.5 * extents[2] + _GAP))
    return _scene(name, description, obj, pose, [("right", _wrist_track(pose, grasp, hold))])


@register_scene("box-turn", _BOX_TURN)
def box_turn() -> Scene:
    return _turn_from_above("box-turn", _BOX_TURN, (0.09, 0.07, 0.06), 0.25, "box", 75.0)


_BOX_PICKUP = ("A 7 x 7 x 14 cm milk-box-like carton (0.3 kg) standing on the table is grasped from above by one "
               "right hand, lifted 12 cm, held and put back down.")


@register_scene("box-pickup", _BOX_PICKUP)
def box_pickup() -> Scene:
    T = 72
    mesh, z0 = _resting_box((0.07, 0.07, 0.14))
    obj = RigidObject.from_trimesh(mesh, mass=0.3, name="box")
    hold = (_APPROACH, T - 1 - _APPROACH)
    lift = 0.12 * (_ramp(T, hold[0] + 4, 32) - _ramp(T, 42, hold[1] - 2))
    pose = _poses(np.broadcast_to(np.eye(3), (T, 3, 3)), np.stack([0 * lift, 0 * lift, z0 + lift], axis=-1))
    # from above, on the top face: fingers along +x curl down the +x face, thumb and little finger pinch the
    # y faces (a grasp from the side has nothing opposing the palm, which does not touch)
    grasp = _grasp((1, 0, 0), (0, 0, 1), (-0.01, 0.0, 0.07 + _GAP))
    return _scene("box-pickup", _BOX_PICKUP, obj, pose, [("right", _wrist_track(pose, grasp, hold))])


_BOTTLE_TURN = ("A small bottle (cylinder, radius 2.5 cm, height 10 cm, 0.2 kg) on the table is turned 80 degrees "
                "about its own vertical axis by a right hand gripping its upper part from above.")


@register_scene("bottle-turn", _BOTTLE_TURN)
def bottle_turn() -> Scene:
    T = 66
    height = 0.10
    obj, z0 = _standing_cylinder(0.025, height, 0.2, "bottle")
    hold = (_APPROACH, T - 1 - _APPROACH)
    theta = math.radians(80.0) * _ramp(T, hold[0] + 4, hold[1] - 4)
    pose = _poses(_rot("z", theta), np.tile([0.0, 0.0, z0], (T, 1)))
    # hand from above, palm 2.5 cm over the cap; the bottle axis lies at about (0.095, 0.02) in the hand frame,
    # between the curled fingertips (far side) and the thumb
    grasp = _grasp((1, 0, 0), (0, 0, 1), (0.05 - 0.095, 0.0 - 0.02, 0.5 * height + 0.025))
    return _scene("bottle-turn", _BOTTLE_TURN, obj, pose, [("right", _wrist_track(pose, grasp, hold))])


def make_mug_mesh(outer_radius: float = 0.04, wall: float = 0.005, height: float = 0.095, bottom: float = 0.008,
                  sections: int = 48) -> trimesh.Trimesh:
    """A watertight mug with a handle, object frame at the centre of its bottom face, axis +z, handle toward +y.

    The cup is a surface of revolution (closed profile: bottom, outer wall, flat rim, inner wall, inner bottom).
    The handle is a closed swept tube (rounded-rectangle section 12 x 8 mm) along a half ellipse in the y-z plane;
    its capped ends sit inside the cup wall, so the two closed shells overlap only inside the material (every edge
    is shared by exactly two faces: watertight). Units: metres.
    """
    r_in = outer_radius - wall
    profile = np.array([[0.0, 0.0], [outer_radius, 0.0], [outer_radius, height], [r_in, height],
                        [r_in, bottom], [0.0, bottom]])
    cup = trimesh.creation.revolve(profile, sections=sections)
    handle = _swept_handle(y0=outer_radius - 0.5 * wall, z_centre=0.52 * height, reach=0.028,
                           half_span=0.028, width=0.012, thickness=0.008)
    mesh = trimesh.util.concatenate([cup, handle])
    if mesh.volume < 0:  # pragma: no cover (both parts are built outward)
        mesh.invert()
    return mesh


def _swept_handle(y0, z_centre, reach, half_span, width, thickness, n_path=24) -> trimesh.Trimesh:
    phi = np.linspace(0.0, np.pi, n_path)
    path = np.stack([np.zeros_like(phi), y0 + reach * np.sin(phi), z_centre + half_span * np.cos(phi)], axis=-1)
    tangent = np.stack([np.zeros_like(phi), reach * np.cos(phi), -half_span * np.sin(phi)], axis=-1)
    tangent /= np.linalg.norm(tangent, axis=-1, keepdims=True)
    b = np.array([1.0, 0.0, 0.0])
    n = np.cross(tangent, b)
    # rounded rectangle section in (b, n) coordinates, counter-clockwise
    corner = 0.3 * min(width, thickness)
    pts = []
    for cx, cy, a0 in ((1, 1, 0.0), (-1, 1, 0.5 * np.pi), (-1, -1, np.pi), (1, -1, 1.5 * np.pi)):
        for a in a0 + np.linspace(0.0, 0.5 * np.pi, 4):
            pts.append((cx * (0.5 * width - corner) + corner * np.cos(a),
                        cy * (0.5 * thickness - corner) + corner * np.sin(a)))
    sec = np.asarray(pts)
    M = len(sec)
    verts = path[:, None, :] + sec[None, :, 0, None] * b + sec[None, :, 1, None] * n[:, None, :]
    verts = verts.reshape(-1, 3)
    faces = []
    for k in range(n_path - 1):
        for m in range(M):
            a, bb = k * M + m, k * M + (m + 1) % M
            c, d = a + M, bb + M
            faces += [(a, bb, d), (a, d, c)]
    for m in range(1, M - 1):  # caps (convex section: fans)
        faces.append((0, m + 1, m))
        last = (n_path - 1) * M
        faces.append((last, last + m, last + m + 1))
    mesh = trimesh.Trimesh(vertices=verts, faces=np.asarray(faces), process=False)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


_MUG_PICKUP = ("A mug with a handle (radius 4 cm, height 9.5 cm, 0.3 kg) is grasped around its body from the side by a "
               "right hand, lifted 10 cm while moving 5 cm sideways, and put down there.")


@register_scene("mug-pickup", _MUG_PICKUP)
def mug_pickup() -> Scene:
    T = 72
    obj = RigidObject.from_trimesh(make_mug_mesh(), mass=0.3, name="mug")
    hold = (_APPROACH, T - 1 - _APPROACH)
    up = _ramp(T, hold[0] + 4, 32) - _ramp(T, 42, hold[1] - 2)
    side = _ramp(T, 18, 48)  # sideways only while lifted
    p = np.stack([0.05 * side, 0.0 * side, TABLE_HEIGHT + 0.10 * up], axis=-1)
    pose = _poses(np.broadcast_to(np.eye(3), (T, 3, 3)), p)
    # palm on the body's -y side at mid-height, fingers along +x wrapping around, thumb up; handle points +y (away)
    grasp = _grasp((1, 0, 0), (0, -1, 0), (0.0, -0.04 - _GAP, 0.045))
    return _scene("mug-pickup", _MUG_PICKUP, obj, pose, [("right", _wrist_track(pose, grasp, hold))])


_TWO_HAND_BOX = ("A 30 x 20 x 15 cm box (1 kg) is lifted 15 cm off the table by both hands pressing on its left and "
                 "right faces, held, and put back down.")


def _big_box() -> tuple[RigidObject, float]:
    """two-hand-box's box (30 x 20 x 15 cm, 1 kg) and the z of its centre resting on the table."""
    mesh, z0 = _resting_box((0.30, 0.20, 0.15))
    return RigidObject.from_trimesh(mesh, mass=1.0, name="big-box"), z0


def _both_hands(name: str, description: str, obj: RigidObject, pose: np.ndarray, hold: tuple[int, int]) -> Scene:
    """Both hands on the big box through ``hold``: palms on the +x (right hand) and -x (left hand) faces, fingers
    pointing forward (+y), thumbs up."""
    right = _grasp((0, 1, 0), (1, 0, 0), (0.15 + _GAP, -0.04, 0.0))
    left = _grasp((0, 1, 0), (-1, 0, 0), (-0.15 - _GAP, -0.04, 0.0))
    return _scene(name, description, obj, pose,
                  [("right", _wrist_track(pose, right, hold)), ("left", _wrist_track(pose, left, hold))])


@register_scene("two-hand-box", _TWO_HAND_BOX)
def two_hand_box() -> Scene:
    T = 78
    obj, z0 = _big_box()
    hold = (_APPROACH, T - 1 - _APPROACH)
    lift = 0.15 * (_ramp(T, hold[0] + 4, 34) - _ramp(T, 44, hold[1] - 2))
    pose = _poses(np.broadcast_to(np.eye(3), (T, 3, 3)), np.stack([0 * lift, 0 * lift, z0 + lift], axis=-1))
    return _both_hands("two-hand-box", _TWO_HAND_BOX, obj, pose, hold)


_CUBE_TURN = ("A 7.5 cm cube (0.2 kg) on the table is turned 60 degrees about the vertical axis by one right hand "
              "from above; sized for robot hands as large as the Allegro hand (run it with "
              "`torchhand synthesize cube-turn --hand right=PATH/allegro_hand/right_hand.xml`).")


@register_scene("cube-turn", _CUBE_TURN)
def cube_turn() -> Scene:
    return _turn_from_above("cube-turn", _CUBE_TURN, (0.075, 0.075, 0.075), 0.2, "cube", 60.0)


_HANDLE_LIFT = ("A spatula-like handle (rod, radius 1.2 cm, height 18 cm, 0.12 kg) standing on the table is gripped "
                "from the side by a right hand, lifted 10 cm, held and put back down; the palm stays 1.5 cm clear of "
                "it, so the fingers grip it against the thumb (Ye & Liu Fig. 7, far).")
_HANDLE_PALM = ("handle-lift's motion with the handle 1.5 cm closer to the palm (the same wrist track, the palm 0.5 mm "
                "clear): the fingers curl around it and the palm pushes (Ye & Liu Fig. 7, near).")
HANDLE_PALM_OFFSET = (0.0, 0.0, 0.015)
"""How far handle-lift-palm moves the handle in the wrist frame (+z: toward the palm), metres."""


@register_scene("handle-lift", _HANDLE_LIFT)
def handle_lift() -> Scene:
    T = 72
    radius, height = 0.012, 0.18
    obj, z0 = _standing_cylinder(radius, height, 0.12, "handle")
    hold = (_APPROACH, T - 1 - _APPROACH)
    up = _ramp(T, hold[0] + 4, 32) - _ramp(T, 42, hold[1] - 2)
    p = np.stack([0.0 * up, 0.0 * up, z0 + 0.10 * up], axis=-1)
    pose = _poses(np.broadcast_to(np.eye(3), (T, 3, 3)), p)
    # palm toward +y, its centre 1.2 cm from the handle's -y side and 3 cm short of its axis (the handle stands in
    # front of the knuckles), 4 cm below its top; fingers along +x, thumb up
    grasp = _grasp((1, 0, 0), (0, -1, 0), (-0.03, -2 * radius, 0.5 * height - 0.04))
    return _scene("handle-lift", _HANDLE_LIFT, obj, pose, [("right", _wrist_track(pose, grasp, hold))])


@register_scene("handle-lift-palm", _HANDLE_PALM)
def handle_lift_palm() -> Scene:
    return dataclasses.replace(offset_object(handle_lift(), HANDLE_PALM_OFFSET), name="handle-lift-palm",
                               description=_HANDLE_PALM)


_BOX_ALTERNATE = ("A 9 x 7 x 6 cm box (0.25 kg) on the table is turned twice about the vertical, 40 degrees by the "
                  "right hand from above, then, the right hand gone, 40 degrees more by the left hand from above: the "
                  "hands' contacts alternate (Ye & Liu Fig. 8).")


def _timed_track(object_pose: np.ndarray, T_obj_hand: np.ndarray, hold: tuple[int, int], aside) -> np.ndarray:
    """(T, 4, 4) wrist poses rigid with the object in ``hold``; outside it the hand waits ``aside`` (3,) metres
    away (world), moving in over the ``_APPROACH`` frames before the hold and out over those after it."""
    T = object_pose.shape[0]
    k0, k1 = hold
    k = np.arange(T, dtype=np.float64)
    away = 1.0 - _smooth((k - (k0 - _APPROACH)) / _APPROACH) + _smooth((k - k1) / _APPROACH)
    wrist = object_pose[np.clip(np.arange(T), k0, k1)] @ T_obj_hand
    wrist[:, :3, 3] += away[:, None] * np.asarray(aside, dtype=np.float64)
    return wrist


@register_scene("box-alternate", _BOX_ALTERNATE)
def box_alternate() -> Scene:
    T = 112
    extents = (0.09, 0.07, 0.06)
    mesh, z0 = _resting_box(extents)
    obj = RigidObject.from_trimesh(mesh, mass=0.25, name="box")
    right, left = (_APPROACH, 50), (61, T - 1 - _APPROACH)
    theta = math.radians(40.0) * (_ramp(T, right[0] + 4, right[1] - 4) + _ramp(T, left[0] + 4, left[1] - 4))
    pose = _poses(_rot("z", theta), np.tile([0.0, 0.0, z0], (T, 1)))
    grasp = _grasp((1, 0, 0), (0, 0, 1), (0.0, 0.0, 0.5 * extents[2] + _GAP))
    return _scene("box-alternate", _BOX_ALTERNATE, obj, pose,
                  [("right", _timed_track(pose, grasp, right, (0.0, -0.15, 0.08))),
                   ("left", _timed_track(pose, grasp, left, (0.0, 0.15, 0.08)))])


_CUP_SPIN = ("A light paper-cup-like cylinder (radius 2 cm, height 9 cm, 0.03 kg) on a smooth table (friction 0.25) "
             "is spun 120 degrees about its axis under a still right hand gripping its top from above, in two pushes "
             "of 60 degrees with a rest between (140 frames): more than the thumb's reach, so contacts must relocate, "
             "which they can while the cup rests on the table (Ye & Liu's finger gaits). With --strategy gait: three "
             "checked solutions in 54162 node tests (docs/synthesis.md, 'Finger gaits').")
CUP_SPIN_PUSHES = ((14, 60), (72, 118))
"""cup-spin's two pushes, (first, last) frame of each 60 degree turn; the cup rests on the table between them."""


@register_scene("cup-spin", _CUP_SPIN)
def cup_spin() -> Scene:
    T = 140
    height = 0.09
    obj, z0 = _standing_cylinder(0.02, height, 0.03, "cup", sections=48)
    hold = (_APPROACH, T - 1 - _APPROACH)
    theta = math.radians(60.0) * sum(_ramp(T, a, b) for a, b in CUP_SPIN_PUSHES)
    still = _poses(np.broadcast_to(np.eye(3), (T, 3, 3)), np.tile([0.0, 0.0, z0], (T, 1)))
    pose = _poses(_rot("z", theta), np.tile([0.0, 0.0, z0], (T, 1)))
    # bottle-turn's grip (the cup's axis between the curled fingertips and the thumb), the wrist still
    grasp = _grasp((1, 0, 0), (0, 0, 1), (0.05 - 0.095, 0.0 - 0.02, 0.5 * height + 0.025))
    scene = _scene("cup-spin", _CUP_SPIN, obj, pose, [("right", _wrist_track(still, grasp, hold))])
    return dataclasses.replace(scene, environment=Environment(table=True, table_height=TABLE_HEIGHT, friction=0.25))


_BOX_CARRY = ("two-hand-box's box (30 x 20 x 15 cm, 1 kg) carried from the table to the floor by both hands pressing "
              "on its left and right faces: lifted 10 cm, carried 45 cm forward past the table's edge and set down on "
              "the floor 75 cm below (the table is a block with an edge, the floor a plane).")
CARRY_TABLE_EXTENT = (-0.6, 0.6, -0.6, 0.2)
"""box-carry's table top, (x_min, x_max, y_min, y_max) world metres: its edge at y = 0.2, 10 cm in front of the box."""


@register_scene("box-carry", _BOX_CARRY)
def box_carry() -> Scene:
    T = 120
    obj, z0 = _big_box()
    hold = (_APPROACH, T - 1 - _APPROACH)
    lift = 0.10 * _ramp(T, hold[0] + 4, 32) - (TABLE_HEIGHT + 0.10) * _ramp(T, 54, hold[1] - 5)
    forward = 0.45 * _ramp(T, 28, 58)
    pose = _poses(np.broadcast_to(np.eye(3), (T, 3, 3)), np.stack([0 * lift, forward, z0 + lift], axis=-1))
    scene = _both_hands("box-carry", _BOX_CARRY, obj, pose, hold)   # two-hand-box's grip
    env = Environment(table=True, table_height=TABLE_HEIGHT, friction=0.4, table_extent=CARRY_TABLE_EXTENT,
                      floor=True, floor_height=0.0)
    return dataclasses.replace(scene, environment=env)
