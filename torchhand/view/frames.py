"""A result directory as per-frame geometry for the viewer: plain NumPy in frozen dataclasses.

Everything is read through :func:`torchhand.load_result` (``docs/result_format.md``): the scene (object mesh,
table), the hand models of ``hand.xml`` / ``hand_<side>.xml`` and the solution files. Hand links are posed by the
hand model's forward kinematics (:func:`torchhand.check.penetration.pose_hand`, the checker's own posing, float64).

Conventions (:mod:`torchhand.conventions`): world z-up, metres, newtons; poses ``T_world_frame`` as 4x4 column-vector
transforms; contact normals point into the object; a hand force is the force of the hand on the object. Arrays are
batch-first: the frame axis T comes first.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

import numpy as np
import trimesh

from ..errors import InputValueError
from ..io.result import Result, Solution, load_result

__all__ = ["LinkMeshes", "HandFrames", "ContactFrames", "SolutionFrames", "TableGeometry", "ViewData",
           "load_view", "link_meshes", "solution_frames", "FORCE_ARROW_M"]

FORCE_ARROW_M = 0.05
"""Length of the arrow of the largest force of the result, metres (all arrows share one scale)."""


@dataclass(frozen=True, eq=False)
class LinkMeshes:
    """How one hand model is drawn: its collision geoms (hand.xml), one triangle mesh per link that has any.

    side: "right" or "left"
    link: (M,) int64, the link index of each mesh (into ``link_names``)
    link_names: (L,) the model's link names
    vertices: M arrays (V_m, 3) float32, metres, in the link's frame
    faces: M arrays (F_m, 3) uint32, indices into the mesh's vertices
    """

    side: str
    link: np.ndarray
    link_names: tuple
    vertices: tuple
    faces: tuple


@dataclass(frozen=True, eq=False)
class HandFrames:
    """One hand of one solution, posed.

    side: "right" or "left"
    link_pose: ``T_world_link``, (T, L, 4, 4), float64, world, metres, in the model's ``link_names`` order
    """

    side: str
    link_pose: np.ndarray


@dataclass(frozen=True, eq=False)
class ContactFrames:
    """The contacts and forces of one solution, as the solution file holds them.

    mask: (T, K) bool, the slot holds a hand-object contact
    point: (T, K, 3) float64, world, metres, on the object surface
    force: (T, K, 3) float64, newtons, force of the hand on the object
    sliding: (T, K) bool, the contact slides
    env_mask: (T, E) bool, object-table contacts
    env_point: (T, E, 3) float64, world, metres
    env_force: (T, E, 3) float64, newtons, force of the table on the object
    """

    mask: np.ndarray
    point: np.ndarray
    force: np.ndarray
    sliding: np.ndarray
    env_mask: np.ndarray
    env_point: np.ndarray
    env_force: np.ndarray


@dataclass(frozen=True, eq=False)
class SolutionFrames:
    """One solution: its name (``sol_XXX``), index XXX, hands in the scene's order, contacts, and the object's
    pose ``T_world_object`` (T, 4, 4), float64, world, metres."""

    index: int
    name: str
    hands: tuple
    contacts: ContactFrames
    object_pose: np.ndarray


@dataclass(frozen=True)
class TableGeometry:
    """The table top drawn under the object: the plane z = ``height`` (metres), a square of side ``2 half_size``
    centred at ``center`` (x, y), world, metres; a table with an edge is its rectangle (``half_size_y`` along y)
    and a block reaching down to ``bottom``; ``floor``: z of a floor drawn under everything, or None."""

    height: float
    center: tuple
    half_size: float
    half_size_y: float | None = None
    bottom: float | None = None
    floor: float | None = None


@dataclass(frozen=True, eq=False)
class ViewData:
    """Everything the viewer draws, frame by frame.

    path: the result directory; scene: the scene's name; fps: frames per second (the first solution's, else the
    scene's); frames: T; complete: the run finished (``stats.json``)
    object_vertices: (V, 3) float32, metres, object frame; object_faces: (F, 3) uint32
    table: the table, or None when the scene has none
    hand_meshes: side -> :class:`LinkMeshes`
    solutions: every solution of the directory, in file order (:class:`SolutionFrames`)
    force_scale: metres of arrow per newton, one scale for every arrow of the result
    """

    path: Path
    scene: str
    fps: float
    frames: int
    complete: bool
    object_vertices: np.ndarray
    object_faces: np.ndarray
    table: TableGeometry | None
    hand_meshes: MappingProxyType
    solutions: tuple
    force_scale: float

    def solution(self, index: int) -> SolutionFrames:
        """The solution whose file is ``sol_<index>``; raises InputValueError naming those present."""
        for s in self.solutions:
            if s.index == index:
                return s
        have = ", ".join(str(s.index) for s in self.solutions) or "none"
        raise InputValueError(f"solution {index}: {self.path} has solutions {have}")


def load_view(result_dir) -> ViewData:
    """Read a result directory (``docs/result_format.md``) as :class:`ViewData`.

    Raises the loader's MissingFileError / FileFormatError / ShapeError (naming the file) for a missing or
    malformed directory, and InputValueError for a result without solutions.
    """
    result = load_result(result_dir)
    if not result.solution_files:
        raise InputValueError(f"{result.path}: no solution files in solutions/ (nothing to show)")
    raw = [result.solution(i) for i in range(len(result.solution_files))]
    sols = tuple(solution_frames(result, sol) for sol in raw)
    scene = result.scene
    mesh: trimesh.Trimesh = scene.object.mesh
    fps = float(raw[0].fps) if raw[0].fps > 0 else float(scene.fps)
    table = _table(result, sols) if scene.environment.table or scene.environment.floor else None
    return ViewData(path=Path(result.path), scene=scene.name, fps=fps, frames=int(sols[0].object_pose.shape[0]),
                    complete=result.complete, object_vertices=np.asarray(mesh.vertices, dtype=np.float32),
                    object_faces=np.asarray(mesh.faces, dtype=np.uint32), table=table,
                    hand_meshes=MappingProxyType({side: link_meshes(model, side)
                                                  for side, model in result.hand_models.items()}),
                    solutions=sols, force_scale=_force_scale(sols))


def solution_frames(result: Result, sol: Solution) -> SolutionFrames:
    """One solution's hands posed by forward kinematics of its hand models, and its contacts."""
    from ..check.penetration import pose_hand

    hands = []
    for hs in sol.hands:
        if hs.side not in result.hand_models:
            raise InputValueError(f"{sol.path}: has a {hs.side} hand, the result's hand models are "
                                  f"{', '.join(result.hand_models)}")
        posed = pose_hand(result.hand_models[hs.side], hs.side, hs.q, hs.joint_names, hs.root_pose, sol.path)
        hands.append(HandFrames(side=hs.side, link_pose=posed.link_pose))
    contacts = ContactFrames(mask=sol.contact_mask, point=sol.contact_point, force=sol.contact_force,
                             sliding=sol.contact_sliding, env_mask=sol.env_contact_mask,
                             env_point=sol.env_contact_point, env_force=sol.env_contact_force)
    return SolutionFrames(index=sol.index, name=f"sol_{sol.index:03d}", hands=tuple(hands), contacts=contacts,
                          object_pose=np.asarray(sol.object_pose, dtype=np.float64))


def link_meshes(model, side: str) -> LinkMeshes:
    """The collision geoms of a hand model as one mesh per link, in the link frame (capsules for the built-in
    hand; a robot hand's own boxes, cylinders and meshes)."""
    from ..hand._link_geometry import link_geom_meshes

    per_link = sorted(link_geom_meshes(model).items())
    links, verts, faces = [], [], []
    for li, parts in per_link:
        m = trimesh.util.concatenate(parts) if len(parts) > 1 else parts[0]
        if len(m.faces) == 0:
            continue
        links.append(li)
        verts.append(np.asarray(m.vertices, dtype=np.float32))
        faces.append(np.asarray(m.faces, dtype=np.uint32))
    return LinkMeshes(side=side, link=np.asarray(links, dtype=np.int64), link_names=tuple(model.link_names),
                      vertices=tuple(verts), faces=tuple(faces))


def _table(result: Result, sols: tuple) -> TableGeometry:
    """A table top under the object's path, 0.12 m beyond it on each side."""
    xy = np.concatenate([s.object_pose[:, :2, 3] for s in sols])
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    half = 0.5 * float(np.max(hi - lo)) + 0.12
    center = 0.5 * (lo + hi)
    env = result.scene.environment
    floor = float(env.floor_height) if env.floor else None
    if env.table and env.table_extent is not None:
        x0, x1, y0, y1 = env.table_extent
        return TableGeometry(height=float(env.table_height), center=(0.5 * (x0 + x1), 0.5 * (y0 + y1)),
                             half_size=0.5 * (x1 - x0), half_size_y=0.5 * (y1 - y0), bottom=floor, floor=floor)
    if not env.table:  # a floor only: drawn as a table top at the floor
        return TableGeometry(height=floor, center=(float(center[0]), float(center[1])), half_size=half)
    return TableGeometry(height=float(env.table_height), center=(float(center[0]), float(center[1])),
                         half_size=half)


def _force_scale(sols: tuple) -> float:
    """Metres per newton: the largest force of the result (hand or table) gets an arrow of FORCE_ARROW_M."""
    biggest = 0.0
    for s in sols:
        c = s.contacts
        for f, m in ((c.force, c.mask), (c.env_force, c.env_mask)):
            if m.any():
                biggest = max(biggest, float(np.linalg.norm(f[m], axis=-1).max()))
    return FORCE_ARROW_M / biggest if biggest > 0 else 0.0
