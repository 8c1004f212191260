"""Built-in scenes after the examples of Liu 2009 ("Dextrous Manipulation from a Grasping Pose", Sec. 6), each
shipped with the grasp it starts from (``torchhand/scenes/grasps/<name>.npz``, :func:`grasp_path`).

They are the inputs of ``torchhand manipulate`` (docs/manipulation.md): an object motion and a grasp. Every scene
follows the conventions of :mod:`torchhand.scenes.builtin` (30 fps, z-up metres, the table at ``TABLE_HEIGHT``,
hand-object friction 0.8, object-table friction 0.4, minimum-jerk profiles, no randomness) and has three phases:

1. rest (6 frames): the object at rest, the hand holding it (the method starts from the grasp's equilibrium);
2. motion: the paper's example (a drag along the table, a lift, a tip about a bottom edge, a lift and hold against
   an external push);
3. rest (6 frames or more): the object at rest again (in ``liu-push`` the object stays lifted and the push ends
   6 frames before the last frame).

The hand track is the one right hand holding the object rigidly from frame 0: ``T_world_hand = T_world_object @
T_object_hand`` with the nominal grasp frame of :func:`torchhand.scenes.builtin._grasp` (palm over the top face,
fingers along +x over the far edge, thumb toward +y). ``torchhand manipulate`` does not follow this track (it
synthesizes the wrist from the grasp); the track is the scene contract's, and the source of the packaged grasps:
:func:`approach_scene` is the scene's first pose with the builtin approach (the wrist moving 6 cm along the palm
normal onto the grasp), on which ``scripts/make_liu_grasps.py`` runs ``torchhand synthesize`` and takes the grasp
(``torchhand grasp from-result``). All four scenes hold the same box at the same frame-0 pose with the same hand,
so their packaged grasps are the same: the approach's frame 7, the wrist 1 cm farther along the palm normal than
the track's, seven contact links (thumb distal; index proximal, middle, distal; little proximal, middle, distal).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import torch

from ..errors import InputValueError
from ..objects import RigidObject
from ..scene import Scene
from . import register_scene
from .builtin import (
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

__all__ = ["LIU_SCENES", "PUSH_FORCE", "REST", "approach_scene", "grasp_path"]

REST = 6
"""Frames at rest before each motion starts (and at least as many after it ends)."""

_GRASPS = Path(__file__).resolve().parent / "grasps"

_BOX = (0.09, 0.07, 0.06)          # the box of box-turn: the hand's reach over its top face is known to work
_FROM_ABOVE = _grasp((1, 0, 0), (0, 0, 1), (0.0, 0.0, 0.5 * _BOX[2] + _GAP))


def _held(name: str, description: str, obj: RigidObject, pose: np.ndarray) -> Scene:
    """A scene whose one right hand holds the object with the from-above grasp frame in every frame."""
    return _scene(name, description, obj, pose, [("right", pose @ _FROM_ABOVE)])


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
    pose = _poses(np.broadcast_to(np.eye(3), (T, 3, 3)), np.stack([s, 0 * s, z0 + 0 * s], axis=-1))
    return _held("liu-drag", _DRAG, obj, pose)


_LIFT = ("Liu 2009 heavy lift: a 9 x 7 x 6 cm box (1.5 kg) held from above by one right hand is lifted 10 cm off "
         "the table in 1 s and held, near the most its grasp can hold within the 30 N contact-force limit.")


@register_scene("liu-lift", _LIFT)
def liu_lift() -> Scene:
    """Liu's heavy lift adds contacts when the grasp cannot hold the box. With the packaged grasp (seven contact
    links) it needs none: the thumb's normal force reaches about 26 N. A grasp with fewer contacts (the approach's
    frame 6, ``scripts/make_liu_grasps.py``) makes the planner add contacts from about frame 11."""
    T = 48
    obj, z0 = _box(1.5)
    up = 0.10 * _ramp(T, REST, REST + 30)
    pose = _poses(np.broadcast_to(np.eye(3), (T, 3, 3)), np.stack([0 * up, 0 * up, z0 + up], axis=-1))
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
    pose = _poses(np.broadcast_to(np.eye(3), (T, 3, 3)), np.stack([0 * up, 0 * up, z0 + up], axis=-1))
    push = PUSH_FORCE * (_ramp(T, 26, 34) - 2.0 * _ramp(T, 36, 44) + _ramp(T, 46, 54))
    wrench = np.zeros((T, 6))
    wrench[:, 1] = push
    scene = _held("liu-push", _PUSH, obj, pose)
    return dataclasses.replace(scene, external_wrench=torch.tensor(wrench, dtype=torch.float64))


LIU_SCENES = ("liu-drag", "liu-lift", "liu-pivot", "liu-push")
"""The Liu 2009 built-in scenes, each with a packaged grasp."""


# ---------------------------------------------------------------------------------------------------------------
# grasps


def grasp_path(scene_name: str) -> Path | None:
    """The packaged grasp file of a built-in scene (``torchhand/scenes/grasps/<name>.npz``), or None when the scene
    has none (other names included)."""
    if not isinstance(scene_name, str):
        return None
    path = _GRASPS / f"{scene_name}.npz"
    return path if scene_name in LIU_SCENES and path.is_file() else None


def approach_scene(scene: Scene, frames: int = _APPROACH + 4) -> Scene:
    """The approach onto ``scene``'s grasp, ``frames`` frames (>= 11): the object at rest at ``scene``'s frame-0 pose,
    the wrist moving 6 cm along the palm normal onto the scene's frame-0 hand pose over the first 10 frames and
    holding it after (the approach of :mod:`torchhand.scenes.builtin`); no external wrench. Its ``torchhand
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
