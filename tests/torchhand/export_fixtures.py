"""Fixtures of the export tests: result directories whose scenes were imported from a body BVH.

:func:`body_result` imports a scene from a shared body capture (Mixamo ``test_freebvh.bvh`` or the CMU body with
frozen hands) with ``import_mocap_scene(body_bvh=..., wrist_joint=...)`` and an object carried 8 cm in front of the
wrist, then writes a result directory for it with :func:`tests.render.fixture_result.write_fixture_result` (the
default hand at the scene's wrist track, fingers closing over the clip). No synthesis runs: the export reads only
the result contract.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from tests.conftest import shared_path
from tests.render.fixture_result import write_fixture_result

BODIES = {
    # name: (file under mocap/, right wrist joint, metres per unit, up axis)
    "mixamo": (("bvh_python_tests", "test_freebvh.bvh"), "mixamorig:RightHand", 0.01, "y"),
    "cmu": (("cmu_body_frozen_hands", "01-01_v01.bvh"), "hand_R", 1.0, "z"),
}
FIRST = 10
"""The scene starts at this source frame and stops 10 frames before the end."""


def body_result(root: Path, body: str, *, q_ramp: float = 0.9, fps: float | None = None) -> tuple[Path, Path]:
    """(result directory, body BVH path) for ``body`` in :data:`BODIES`; ``fps`` resamples the scene."""
    from torchhand.scene.bvh import read_bvh
    from torchhand.scene.mocap import import_mocap_scene

    parts, wrist, units, up = BODIES[body]
    path = shared_path("mocap", *parts)
    clip = read_bvh(path)
    G = clip.global_transforms().numpy()[:, clip.joint_index(wrist)]
    obj = G.copy()
    obj[:, :3, 3] += (G[:, :3, :3] @ np.array([0.08, 0.0, 0.0])) / units
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    np.savez(root / "object.npz", object_pose=obj)
    trimesh.creation.box((0.05, 0.05, 0.05)).export(root / "box.obj")
    scene = import_mocap_scene(object_mesh=root / "box.obj", body_bvh=path, wrist_joint=wrist,
                               object_npz=root / "object.npz", units_scale=units, mesh_scale=1.0, up_axis=up,
                               frame_range=(FIRST, clip.num_frames - 10), fps=fps, name=f"{body}-box")
    out = write_fixture_result(root / "result", scene=scene, frames=scene.T, solutions=1, q_ramp=q_ramp)
    return out, path
