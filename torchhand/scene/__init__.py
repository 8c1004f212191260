"""Scenes: an object trajectory, one or two wrist trajectories, and the environment they act in.

A :class:`Scene` is the input of every method: the object's 6-DOF motion and the wrists' 6-DOF motion are given;
the fingers are what torchhand fills in. Conventions (see :mod:`torchhand.conventions`): world z-up, metres,
seconds, kilograms; poses are 4x4 rigid transforms ``T_world_frame`` (column vectors), float64.

Scenes come from :func:`load_scene` (a built-in name, see :mod:`torchhand.scene.builtin`, or a scene directory, see
``docs/scene_format.md``), from :func:`torchhand.scene.mocap.import_mocap_scene`, or are built directly.

Modules
    ``_parts``     :class:`HandTrack`, :class:`Environment`, :class:`MocapSource`, constants and shared checks
    ``_model``     :class:`Scene`
    ``_contacts``  object-table contacts (:func:`environment_contacts`)
    ``_writer``    / ``_reader``: the scene directory format
    ``_load``      :func:`load_scene`
    ``builtin``    the built-in scenes (registry, Ye & Liu 2012 scenes, Liu 2009 scenes with their grasps)
    ``bvh``        BVH reading and writing; ``mocap``: scenes imported from BVH captures
"""

from __future__ import annotations

from ..geometry.poses import interpolate_poses, smooth_poses
from ._contacts import EnvContacts, environment_contacts
from ._load import load_scene
from ._model import Scene
from ._parts import DEFAULT_GRAVITY, FORMAT_VERSION, SIDES, Environment, HandTrack, MocapSource

__all__ = [
    "SIDES",
    "FORMAT_VERSION",
    "DEFAULT_GRAVITY",
    "HandTrack",
    "Environment",
    "MocapSource",
    "Scene",
    "EnvContacts",
    "environment_contacts",
    "load_scene",
    "interpolate_poses",
    "smooth_poses",
]
