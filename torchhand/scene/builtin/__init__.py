"""Built-in procedural scenes, registered by name.

Each built-in scene is made deterministically from code (no files, no randomness): the object mesh from trimesh
primitives, the object and wrist trajectories from smooth closed-form profiles. They follow the examples of Ye & Liu
(2012): turning and lifting a box on a table, turning a small bottle, a mug, and a two-hand box lift.
See :mod:`torchhand.scene.builtin.ye_liu` for what each one contains. The ``liu-*`` scenes
(:mod:`torchhand.scene.builtin.liu`) follow the examples of Liu (2009) and each ships the grasp that ``torchhand
manipulate`` starts from (:func:`torchhand.scene.builtin.liu.grasp_path`).

    >>> from torchhand.scene.builtin import list_builtin_scenes, builtin_scene
    >>> scene = builtin_scene("box-turn")
"""

from __future__ import annotations

from . import liu, ye_liu  # noqa: F401  (importing them registers their scenes)
from ._registry import builtin_scene, builtin_scene_description, list_builtin_scenes, register_scene

__all__ = ["register_scene", "list_builtin_scenes", "builtin_scene", "builtin_scene_description"]
