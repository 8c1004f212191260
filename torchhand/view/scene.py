"""The viewer's viser scene: the object, the table, every solution's hands, contacts and forces, posed per frame.

Node names (viser's scene tree, ``/parent/child``):

==================================== ===========================================================================
``/object``                          the object's mesh (translucent), posed by the shown solution's object pose
``/table``                           the table top (scenes with a table)
``/sol_XXX``                         one group per solution; hiding it hides everything below
``/sol_XXX/<side>/<link>``           one mesh per hand link (hand.xml's collision geoms), at ``T_world_link``
``/sol_XXX/contacts``                hand-object contact points (cyan; sliding ones orange)
``/sol_XXX/forces``                  hand forces on the object, arrows ending at their contact points (red)
``/sol_XXX/table_contacts``          object-table contact points (yellow)
``/sol_XXX/table_forces``            table forces on the object, arrows starting at their contact points
==================================== ===========================================================================

Every solution has its own hand colour. Arrows share one scale (:attr:`ViewData.force_scale`, metres per newton).
Poses are world, z-up, metres; viser takes a position and a wxyz quaternion per node.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from .frames import SolutionFrames, ViewData

__all__ = ["SceneNodes", "build_scene", "show_frame", "matrix_to_wxyz", "SOLUTION_COLOURS"]

SOLUTION_COLOURS = ((225, 170, 140), (110, 160, 230), (120, 200, 120), (230, 200, 90), (190, 130, 220),
                    (100, 200, 200), (230, 120, 150), (170, 170, 170), (160, 120, 80), (90, 110, 200))
"""Hand colour of solution i: ``SOLUTION_COLOURS[i % 10]``, RGB 0..255."""

_CONTACT = (0, 220, 230)
_SLIDING = (255, 150, 0)
_TABLE_CONTACT = (240, 220, 0)
_FORCE = (220, 30, 30)
_TABLE_FORCE = (200, 120, 0)
_DOT_M = 0.006


@dataclass(frozen=True, eq=False)
class SceneNodes:
    """Handles of the scene's nodes.

    object: the object's mesh node; table: the table's node, or None
    groups: solution index -> the ``/sol_XXX`` group node
    links: (solution index, side) -> tuple of (link index, mesh node), in :class:`LinkMeshes` order
    names: every node name the viewer made, sorted
    """

    object: object
    table: object | None
    groups: MappingProxyType
    links: MappingProxyType
    names: tuple


def build_scene(server, data: ViewData) -> SceneNodes:
    """Add every node of ``data`` to the viser ``server``'s scene, posed at frame 0."""
    scene = server.scene
    scene.set_up_direction("+z")
    # Plain lights, no image-based lighting: the environment map's prefiltering takes seconds per page load in a
    # software WebGL (remote desktops, headless browsers), while direct lights draw at once everywhere.
    scene.configure_environment_map(None)
    scene.configure_default_lights(True, cast_shadow=True)
    scene.add_light_ambient("/ambient", intensity=0.9)
    names = ["/object"]
    obj = scene.add_mesh_simple("/object", data.object_vertices, data.object_faces, color=(200, 200, 215),
                                opacity=0.55, side="double")
    table = None
    if data.table is not None:
        tb = data.table
        hy = tb.half_size if tb.half_size_y is None else tb.half_size_y
        thick = 0.02 if tb.bottom is None else tb.height - tb.bottom
        table = scene.add_box("/table", color=(185, 165, 140), dimensions=(2 * tb.half_size, 2 * hy, thick),
                              position=(tb.center[0], tb.center[1], tb.height - 0.5 * thick), cast_shadow=False)
        names.append("/table")
        if tb.floor is not None and tb.bottom is not None:
            scene.add_box("/floor", color=(150, 150, 150), dimensions=(2 * tb.half_size + 1.0, 2 * hy + 1.0, 0.02),
                          position=(tb.center[0], tb.center[1], tb.floor - 0.01), cast_shadow=False)
            names.append("/floor")
    groups, links = {}, {}
    for i, sol in enumerate(data.solutions):
        group = f"/{sol.name}"
        groups[sol.index] = scene.add_frame(group, show_axes=False)
        names.append(group)
        colour = SOLUTION_COLOURS[i % len(SOLUTION_COLOURS)]
        for hand in sol.hands:
            meshes = data.hand_meshes[hand.side]
            nodes = []
            for li, v, f in zip(meshes.link.tolist(), meshes.vertices, meshes.faces):
                name = f"{group}/{hand.side}/{meshes.link_names[li]}"
                nodes.append((li, scene.add_mesh_simple(name, v, f, color=colour)))
                names.append(name)
            links[(sol.index, hand.side)] = tuple(nodes)
        names += [f"{group}/{n}" for n in ("contacts", "forces", "table_contacts", "table_forces")]
    _camera(server, data)
    nodes = SceneNodes(object=obj, table=table, groups=MappingProxyType(groups), links=MappingProxyType(links),
                       names=tuple(sorted(names)))
    show_frame(server, data, nodes, 0, shown=[s.index for s in data.solutions])
    return nodes


def show_frame(server, data: ViewData, nodes: SceneNodes, t: int, *, shown, contacts: bool = True,
               forces: bool = True) -> None:
    """Pose every node at frame ``t`` (0 <= t < T); ``shown``: the solution indices to show (the others are
    hidden); ``contacts`` / ``forces``: draw contact points / force arrows."""
    shown = set(int(i) for i in shown)
    with server.atomic():
        first = next((s for s in data.solutions if s.index in shown), data.solutions[0])
        _place(nodes.object, first.object_pose[t])
        for sol in data.solutions:
            visible = sol.index in shown
            nodes.groups[sol.index].visible = visible
            if not visible:
                continue
            for hand in sol.hands:
                for li, node in nodes.links[(sol.index, hand.side)]:
                    _place(node, hand.link_pose[t, li])
            _contact_nodes(server, data, sol, t, contacts, forces)


def matrix_to_wxyz(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4), wxyz, of rotation matrices (..., 3, 3) (SciPy's conversion, w >= 0)."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(R, dtype=np.float64)
    xyzw = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()
    q = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1)
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q.reshape(R.shape[:-2] + (4,))


def _place(node, pose: np.ndarray) -> None:
    node.wxyz = matrix_to_wxyz(pose[:3, :3])
    node.position = np.asarray(pose[:3, 3], dtype=np.float64)


def _contact_nodes(server, data: ViewData, sol: SolutionFrames, t: int, contacts: bool, forces: bool) -> None:
    """(Re)make the solution's contact and force nodes for frame t (a node with nothing to draw is hidden)."""
    scene, c, g = server.scene, sol.contacts, f"/{sol.name}"
    m, em = c.mask[t], c.env_mask[t]
    colours = np.array([_SLIDING if s else _CONTACT for s in c.sliding[t][m]], dtype=np.uint8).reshape(-1, 3)
    _points(scene, f"{g}/contacts", c.point[t][m], colours, contacts)
    _points(scene, f"{g}/table_contacts", c.env_point[t][em],
            np.tile(np.array(_TABLE_CONTACT, np.uint8), (int(em.sum()), 1)), contacts)
    k = data.force_scale
    hand_tail = c.point[t][m] - k * c.force[t][m]          # a hand force ends at its contact point
    _arrows(scene, f"{g}/forces", np.stack([hand_tail, c.point[t][m]], axis=1), _FORCE, forces)
    env_tip = c.env_point[t][em] + k * c.env_force[t][em]  # a table force starts at its contact point
    _arrows(scene, f"{g}/table_forces", np.stack([c.env_point[t][em], env_tip], axis=1), _TABLE_FORCE, forces)


def _points(scene, name: str, points: np.ndarray, colours: np.ndarray, visible: bool) -> None:
    if len(points) == 0:
        points, colours, visible = np.zeros((1, 3)), np.zeros((1, 3), np.uint8), False
    scene.add_point_cloud(name, points.astype(np.float32), colours, point_size=_DOT_M, point_shape="circle",
                          visible=visible)


def _arrows(scene, name: str, ends: np.ndarray, colour: tuple, visible: bool) -> None:
    if len(ends) == 0:
        ends, visible = np.array([[[0.0, 0.0, 0.0], [0.0, 0.0, 1e-3]]]), False
    scene.add_arrows(name, ends.astype(np.float32), colour, shaft_radius=0.0015, head_radius=0.004,
                     head_length=0.008, visible=visible)


def _camera(server, data: ViewData) -> None:
    """Look at the middle of the object and the first solution's wrists at frame 0 from the front right, above."""
    pts = [data.solutions[0].object_pose[0, :3, 3]] + [h.link_pose[0, 0, :3, 3] for h in data.solutions[0].hands]
    centre = np.mean(pts, axis=0)
    offset = np.array([0.17, -0.25, 0.16])
    right = np.cross(-offset, [0.0, 0.0, 1.0])
    aim = centre + 0.05 * right / np.linalg.norm(right)      # the scene left of the panel, which sits on the right
    server.initial_camera.look_at = tuple(float(x) for x in aim)
    server.initial_camera.position = tuple(float(x) for x in centre + offset)
