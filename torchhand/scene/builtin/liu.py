"""Built-in scenes after the examples of Liu 2009 ("Dextrous Manipulation from a Grasping Pose", Sec. 6), each
shipped with the grasp it starts from (``torchhand/scenes/grasps/<name>.npz``, :func:`grasp_path`).

They are the inputs of ``torchhand manipulate`` (docs/manipulation.md): an object motion and a grasp. Every scene
follows the conventions of :mod:`torchhand.scene.builtin.ye_liu` (30 fps, z-up metres, the table at ``TABLE_HEIGHT``,
hand-object friction 0.8, object-table friction 0.4, minimum-jerk profiles, no randomness) and has three phases:

1. rest (6 frames): the object at rest, the hand holding it (the method starts from the grasp's equilibrium);
2. motion: the paper's example (a drag along the table, a lift, a tip about a bottom edge, a lift and hold against
   an external push, a two-finger roll of a small cylinder about its own axis);
3. rest (6 frames or more): the object at rest again (in ``liu-push`` the object stays lifted and the push ends
   6 frames before the last frame).

The hand track is the one right hand holding the object rigidly from frame 0: ``T_world_hand = T_world_object @
T_object_hand`` with the nominal grasp frame of :func:`torchhand.scene.builtin.ye_liu._grasp` (palm over the top face,
fingers along +x over the far edge, thumb toward +y). ``torchhand manipulate`` does not follow this track (it
synthesizes the wrist from the grasp); the track is the scene contract's, and the source of the packaged grasps:
:func:`approach_scene` is the scene's first pose with the builtin approach (the wrist moving 6 cm along the palm
normal onto the grasp), on which ``scripts/make_liu_grasps.py`` runs ``torchhand synthesize`` and takes the grasp
(``torchhand grasp from-result``). All four scenes hold the same box at the same frame-0 pose with the same hand,
so their packaged grasps are the same: the approach's frame 7, the wrist 1 cm farther along the palm normal than
the track's, seven contact links (thumb distal; index proximal, middle, distal; little proximal, middle, distal).

``liu-roll`` differs: a small cylinder held in the air, 20 cm above the table, by a thumb-index pinch. Its grasp is
built, not searched: :func:`roll_pinch` gives a fixed pinch posture and the cylinder's place between the two distal
capsules, and its hand track holds the cylinder rigidly with that pinch (``scripts/make_liu_grasps.py``,
``make_roll``, snaps it so that only the two fingertips touch). Two point contacts cannot make a torque about the
line through them: the planner's deficit allowance (``torchhand.manipulation.plan.BALANCE_ALLOWANCE``) lets the
pinch hold the cylinder (docs/manipulation.md, "Built-in examples").

``liu-press`` differs too: the paper's deformable object is a rigid plate on a linear spring to the table (the
spring's force is the scene's ``external_wrench``), pressed from above by the thumb, index and middle fingertips of
a fitted posture (:func:`press_pose`, ``make_press`` in the script).

``liu-shadow-lift`` is liu-lift with the Shadow hand of the shared reference data (:func:`shadow_hand_path`; not
shipped): a fitted posture (:func:`shadow_pose`) with three fingertips on the far face and the thumb on the near
one. Its packaged grasp names the hand relative to the shared data directory (:data:`SHADOW_HAND`);
:func:`torchhand.manipulation.grasp.load_packaged_grasp` resolves it.

``liu-two-hand-lift`` has two hands: the big box of ``two-hand-box`` pressed between two flat hands
(:func:`two_hand_pose`) and lifted; it ships one grasp per hand (``liu-two-hand-lift.npz``, the right hand, and
``liu-two-hand-lift-left.npz``; :func:`grasp_paths`).

The fitted postures and grasp frames (:func:`roll_pinch`, :func:`press_pose`, :func:`shadow_pose`,
:func:`two_hand_pose`) and the Shadow hand's path live in :mod:`torchhand.scene.builtin._liu_postures` and are
re-exported here; this module holds the scenes, their registration (in :data:`LIU_SCENES` order) and the packaged
grasps.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import torch
import trimesh

from ...errors import InputValueError
from ...geometry.objects import RigidObject
from .._model import Scene
from .._parts import DEFAULT_GRAVITY, HandTrack
from ._liu_postures import (
    ROLL_RADIUS,
    SHADOW_HAND,
    TWO_HAND_SNAP_TOL,
    press_pose,
    roll_pinch,
    shadow_hand_path,
    shadow_pose,
    shared_data_dir,
    two_hand_pose,
)
from ._registry import register_scene
from .ye_liu import (
    _APPROACH,
    _GAP,
    TABLE_HEIGHT,
    _grasp,
    _poses,
    _ramp,
    _resting_box,
    _rot,
    _scene,
    _wrist_track,
)

__all__ = ["LIU_SCENES", "PRESS_DEPTH", "PRESS_EXTENTS", "PRESS_HEIGHT", "PRESS_PRELOAD", "PRESS_STIFFNESS",
           "PUSH_FORCE", "REST", "SHADOW_HAND", "ROLL_CENTRE", "ROLL_DEGREES", "ROLL_HEIGHT", "ROLL_RADIUS",
           "TWO_HAND_SNAP_TOL", "approach_scene", "grasp_path", "grasp_paths", "press_pose", "roll_pinch",
           "shadow_hand_path", "shadow_pose", "shared_data_dir", "two_hand_pose"]

REST = 6
"""Frames at rest before each motion starts (and at least as many after it ends)."""

_GRASPS = Path(__file__).resolve().parent / "grasps"

_BOX = (0.09, 0.07, 0.06)          # the box of box-turn: the hand's reach over its top face is known to work
_FROM_ABOVE = _grasp((1, 0, 0), (0, 0, 1), (0.0, 0.0, 0.5 * _BOX[2] + _GAP))


def _held(name: str, description: str, obj: RigidObject, pose: np.ndarray) -> Scene:
    """A scene whose one right hand holds the object with the from-above grasp frame in every frame."""
    return _scene(name, description, obj, pose, [("right", pose @ _FROM_ABOVE)])


def _upright(centre: np.ndarray) -> np.ndarray:
    """Poses (T, 4, 4) of an object that keeps its rest orientation, its origin at ``centre`` (T, 3)."""
    return _poses(np.broadcast_to(np.eye(3), (len(centre), 3, 3)), centre)


def _box(mass: float, name: str = "box") -> tuple[RigidObject, float]:
    mesh, z0 = _resting_box(_BOX)
    return RigidObject.from_trimesh(mesh, mass=mass, name=name), z0


# ---------------------------------------------------------------------------------------------------------------
# scenes

_DRAG = ("Liu 2009 drag: a 9 x 7 x 6 cm box (0.5 kg) held from above by one right hand is dragged 12 cm along the "
         "table (+x) in 1.2 s; the box slides on the table (sliding table contacts).")


@register_scene("liu-drag", _DRAG)
def liu_drag() -> Scene:
    T = 48
    obj, z0 = _box(0.5)
    s = 0.12 * _ramp(T, REST, T - 1 - REST)
    pose = _upright(np.stack([s, 0 * s, z0 + 0 * s], axis=-1))
    return _held("liu-drag", _DRAG, obj, pose)


_LIFT = ("Liu 2009 heavy lift: a 9 x 7 x 6 cm box (2.0 kg) held from above by one right hand is lifted 10 cm off "
         "the table in 1 s and held; its grasp cannot hold it within the 30 N contact-force limit, so the planner "
         "adds a contact.")


@register_scene("liu-lift", _LIFT)
def liu_lift() -> Scene:
    """Liu's heavy lift adds contacts when the grasp cannot hold the box (Liu: 1.5 kg, with the contacts of the
    paper's grasp). The packaged grasp (seven contact links) lifts 1.5 kg without one (the thumb's normal force
    reaches about 26 N of the 30 N limit), so this box weighs 2.0 kg: the planner adds contacts during the lift, and
    they carry force once they touch. Near the grasp's limit the outcome depends on the mass (docs/manipulation.md,
    "Built-in examples")."""
    T = 48
    obj, z0 = _box(2.0)
    up = 0.10 * _ramp(T, REST, REST + 30)
    pose = _upright(np.stack([0 * up, 0 * up, z0 + up], axis=-1))
    return _held("liu-lift", _LIFT, obj, pose)


_PIVOT = ("Liu 2009 pivot: a 9 x 7 x 6 cm box (0.3 kg) held from above by one right hand is tipped 30 degrees about "
          "its bottom -x edge, which stays on the table, in 1.2 s, and held tipped.")


@register_scene("liu-pivot", _PIVOT)
def liu_pivot() -> Scene:
    T = 48
    obj, z0 = _box(0.3)
    theta = math.radians(30.0) * _ramp(T, REST, T - 1 - REST)
    edge = np.array([-0.5 * _BOX[0], 0.0, TABLE_HEIGHT])                  # world point on the pivot edge
    R = _rot("y", -theta)                                                  # -theta about +y lifts the +x side
    rest_centre = np.array([0.0, 0.0, z0])
    p = edge + np.einsum("tij,j->ti", R, rest_centre - edge)
    return _held("liu-pivot", _PIVOT, obj, _poses(R, p))


_PUSH = ("Liu 2009 external force: a 9 x 7 x 6 cm box (0.3 kg) held from above by one right hand is lifted 6 cm and "
         "held while an external force pushes it sideways, +3 N then -3 N along y (toward the thumb, then away), at "
         "its centre of mass.")

PUSH_FORCE = 3.0
"""Peak external force of liu-push, newtons."""


@register_scene("liu-push", _PUSH)
def liu_push() -> Scene:
    T = 60
    obj, z0 = _box(0.3)
    up = 0.06 * _ramp(T, REST, REST + 18)
    pose = _upright(np.stack([0 * up, 0 * up, z0 + up], axis=-1))
    push = PUSH_FORCE * (_ramp(T, 26, 34) - 2.0 * _ramp(T, 36, 44) + _ramp(T, 46, 54))
    wrench = np.zeros((T, 6))
    wrench[:, 1] = push
    scene = _held("liu-push", _PUSH, obj, pose)
    return dataclasses.replace(scene, external_wrench=torch.tensor(wrench, dtype=torch.float64))


# --- roll: a two-finger pinch rolls a small cylinder about its own axis ----------------------------------------

ROLL_HEIGHT = 0.03
"""Height (axial length) of the liu-roll cylinder, metres."""
ROLL_DEGREES = 40.0
"""Peak rotation of the liu-roll cylinder about its own axis, degrees."""
ROLL_CENTRE = (0.0, 0.0, TABLE_HEIGHT + 0.20)
"""World position of the liu-roll cylinder's centre (every frame), metres: 20 cm above the table."""

_ROLL_SECTIONS = 64          # facets around the cylinder: the flat facets deviate 0.024 mm from the circle
_ROLL_FRAMES = 27            # frames of each ramp (0 -> +40 degrees, +40 -> 0)

_ROLL = ("Liu 2009 rotate: a small cylinder (radius 2 cm, height 3 cm, 0.05 kg) held in the air by a two-finger "
         "pinch (thumb and index fingertips on opposite sides of its curved surface, thumb below, index above) is "
         "rotated 40 degrees about its own horizontal axis in 0.9 s and back in 0.9 s.")


@register_scene("liu-roll", _ROLL)
def liu_roll() -> Scene:
    """The cylinder's centre stays at ``ROLL_CENTRE``; its axis (object z) is the world x axis and the pinch line
    (object x, thumb to index) points up, so the thumb holds it from below and the weight lies along the pinch line.
    Two point contacts cannot make a torque about the line through them; the weight needs one only in proportion to
    the line's tilt from vertical times its offset from the centre of mass (1.7 degrees and 0.48 mm for the packaged
    grasp, whose contacts the hand's surface samples place). The hand track holds the cylinder rigidly with the pinch
    of :func:`roll_pinch` (the motion without rolling)."""
    T = 2 * REST + 2 * _ROLL_FRAMES
    mesh = trimesh.creation.cylinder(radius=ROLL_RADIUS, height=ROLL_HEIGHT, sections=_ROLL_SECTIONS)
    obj = RigidObject.from_trimesh(mesh, mass=0.05, name="cylinder")
    theta = math.radians(ROLL_DEGREES) * (_ramp(T, REST, REST + _ROLL_FRAMES)
                                          - _ramp(T, REST + _ROLL_FRAMES, REST + 2 * _ROLL_FRAMES))
    R0 = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]]).T   # columns: object x, y, z in the world
    R = R0 @ _rot("z", theta)
    pose = _poses(R, np.tile(ROLL_CENTRE, (T, 1)))
    _, T_hand_object = roll_pinch()
    return _scene("liu-roll", _ROLL, obj, pose, [("right", pose @ np.linalg.inv(T_hand_object))])


# --- press: three fingertips press a sprung pad down and let it back up ----------------------------------------

PRESS_EXTENTS = (0.10, 0.08, 0.02)
"""Extents of the liu-press plate, metres."""
PRESS_STIFFNESS = 1500.0
"""Stiffness of the liu-press spring, newtons per metre."""
PRESS_PRELOAD = 2.0
"""Force the fingertips already press with at rest (the spring's force beyond the plate's weight), newtons."""
PRESS_DEPTH = 0.02
"""How far the liu-press plate is pressed down, metres."""
PRESS_HEIGHT = 0.04
"""Height of the liu-press plate's underside above the table at rest (the uncompressed foam under it), metres."""

_PRESS_MASS = 0.1
_PRESS_RAMP = 24            # frames of each ramp (down, up)
_PRESS_HOLD = 6             # frames held fully pressed

_PRESS = ("Liu 2009 press: three fingertips (thumb, index, middle) press a 10 x 8 x 2 cm plate (0.1 kg) on a linear "
          "spring (1500 N/m, the foam under it) 2 cm down in 0.8 s, hold it, and let it back up; the spring pushes "
          "with 2 N beyond the plate's weight at rest and 32 N at the bottom.")


@register_scene("liu-press", _PRESS)
def liu_press() -> Scene:
    """Liu's press flattens a deformable object modelled as a linear spring. torchhand's objects are rigid, so the
    deformable object is a rigid plate (the object) on a spring to the table (the foam, not drawn): the plate moves
    down by the desired compression d(t), and the spring's force ``m g + PRESS_PRELOAD + PRESS_STIFFNESS d(t)``, up,
    at the plate's centre, is the scene's ``external_wrench``; the contact forces are those the compression needs,
    as in the paper. Deviation: the paper flattens the object between the fingers of a three-finger pinch; here the
    table holds the spring's other end, so the fingertips press from above."""
    T = 2 * REST + 2 * _PRESS_RAMP + _PRESS_HOLD
    ext = np.asarray(PRESS_EXTENTS)
    obj = RigidObject.from_trimesh(trimesh.creation.box(extents=ext), mass=_PRESS_MASS, name="plate")
    k0 = REST + _PRESS_RAMP + _PRESS_HOLD
    d = PRESS_DEPTH * (_ramp(T, REST, REST + _PRESS_RAMP) - _ramp(T, k0, k0 + _PRESS_RAMP))
    z0 = TABLE_HEIGHT + PRESS_HEIGHT + 0.5 * ext[2]
    pose = _upright(np.stack([0 * d, 0 * d, z0 - d], axis=-1))
    wrench = np.zeros((T, 6))
    wrench[:, 2] = -_PRESS_MASS * DEFAULT_GRAVITY[2] + PRESS_PRELOAD + PRESS_STIFFNESS * d
    _, T_object_hand = press_pose()
    scene = _scene("liu-press", _PRESS, obj, pose, [("right", pose @ T_object_hand)])
    return dataclasses.replace(scene, external_wrench=torch.tensor(wrench, dtype=torch.float64))


# --- shadow-lift: the heavy lift with the Shadow hand ------------------------------------------------------------

_SHADOW_LIFT = ("Liu 2009 heavy lift with the Shadow hand: the 9 x 7 x 6 cm box (2.0 kg) of liu-lift, lifted 10 cm "
                "off the table in 1 s and held, by the Shadow right hand of the shared reference data (three "
                "fingertips on the far face, the thumb on the near face).")


@register_scene("liu-shadow-lift", _SHADOW_LIFT)
def liu_shadow_lift() -> Scene:
    """liu-lift's box and motion; the hand track is the Shadow hand (:func:`shadow_hand_path`) holding the box
    rigidly with the grasp of :func:`shadow_pose`.

    Raises:
        MissingFileError: the shared reference data has no Shadow hand.
    """
    from ...hand.mount import track_hand

    lift = liu_lift()
    model = str(shadow_hand_path())
    hand = track_hand(HandTrack(side="right", wrist_pose=lift.hands[0].wrist_pose, model=model))
    _, T_object_hand = shadow_pose(hand)
    wrist = torch.as_tensor(lift.object_pose.numpy() @ T_object_hand)
    return dataclasses.replace(lift, name="liu-shadow-lift", description=_SHADOW_LIFT,
                               hands=(HandTrack(side="right", wrist_pose=wrist, model=model),))


# --- two hands: a big box lifted between two flat hands ----------------------------------------------------------

_BIG_BOX = (0.30, 0.20, 0.15)

_TWO_HAND_LIFT = ("Liu 2009 with two hands: a 30 x 20 x 15 cm box (1.0 kg) pressed between two flat hands on its left "
                  "and right faces is lifted 10 cm off the table in 1 s and held; both hands' contacts share one "
                  "force plan.")


@register_scene("liu-two-hand-lift", _TWO_HAND_LIFT)
def liu_two_hand_lift() -> Scene:
    """The box of the built-in two-hand-box scene, lifted as in liu-lift; the right and the left hand hold it
    rigidly with the grasps of :func:`two_hand_pose`."""
    T = 48
    mesh, z0 = _resting_box(_BIG_BOX)
    obj = RigidObject.from_trimesh(mesh, mass=1.0, name="big-box")
    up = 0.10 * _ramp(T, REST, REST + 30)
    pose = _upright(np.stack([0 * up, 0 * up, z0 + up], axis=-1))
    return _scene("liu-two-hand-lift", _TWO_HAND_LIFT, obj, pose,
                  [(side, pose @ two_hand_pose(side)[1]) for side in ("right", "left")])


LIU_SCENES = ("liu-drag", "liu-lift", "liu-pivot", "liu-push", "liu-roll", "liu-press", "liu-shadow-lift",
              "liu-two-hand-lift")
"""The Liu 2009 built-in scenes, each with a packaged grasp."""


# ---------------------------------------------------------------------------------------------------------------
# grasps


def grasp_path(scene_name: str) -> Path | None:
    """The packaged grasp file of a built-in scene (``torchhand/scenes/grasps/<name>.npz``; with two hands the first
    hand's), or None when the scene has none (other names included)."""
    paths = grasp_paths(scene_name)
    return paths[0] if paths else None


def grasp_paths(scene_name: str) -> list[Path]:
    """Every packaged grasp file of a built-in scene, one per hand in the scene's hand order: ``<name>.npz`` (the
    first hand) and ``<name>-<side>.npz`` for a second hand; empty when the scene has none."""
    if not isinstance(scene_name, str) or scene_name not in LIU_SCENES:
        return []
    first = _GRASPS / f"{scene_name}.npz"
    if not first.is_file():
        return []
    return [first] + sorted(p for p in _GRASPS.glob(f"{scene_name}-*.npz") if p.stem[len(scene_name) + 1:] in
                            ("right", "left"))


def approach_scene(scene: Scene, frames: int = _APPROACH + 4) -> Scene:
    """The approach onto ``scene``'s grasp, ``frames`` frames (>= 11): the object at rest at ``scene``'s frame-0 pose,
    the wrist moving 6 cm along the palm normal onto the scene's frame-0 hand pose over the first 10 frames and
    holding it after (the approach of :mod:`torchhand.scene.builtin.ye_liu`); no external wrench. Its ``torchhand
    synthesize`` result is the source of the packaged grasps (``scripts/make_liu_grasps.py``).

    Raises:
        InputValueError: ``frames`` is not an integer >= 11.
    """
    if isinstance(frames, bool) or not isinstance(frames, int) or frames <= _APPROACH:
        raise InputValueError(f"frames: expected an integer >= {_APPROACH + 1}, got {frames!r}")
    pose = np.repeat(scene.object_pose[:1].double().numpy(), frames, axis=0)
    tracks = []
    for h in scene.hands:
        T_obj_hand = np.linalg.solve(pose[0], h.wrist_pose[0].double().numpy())
        wrist = _wrist_track(pose, T_obj_hand, (_APPROACH, frames - 1))
        tracks.append(dataclasses.replace(h, wrist_pose=torch.tensor(wrist, dtype=torch.float64)))
    return dataclasses.replace(scene, name=f"{scene.name}-approach", object_pose=torch.tensor(pose),
                               hands=tuple(tracks), external_wrench=None,
                               description=f"approach onto the grasp of {scene.name}")
