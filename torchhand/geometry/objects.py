"""Rigid objects: a triangle mesh in its own frame plus mass properties.

Conventions (see :mod:`torchhand.conventions`): metres, kilograms; the object frame is the mesh's frame; the
inertia tensor is about the centre of mass, expressed in object-frame axes, kg m^2.

The public boundary types are trimesh / NumPy (static model data); batched tensors only appear in
:func:`sample_surface`, whose randomness comes only from the ``torch.Generator`` it is given.

Open meshes
    Most real meshes are not watertight (scans with holes, OBJ seams). A mesh whose generalized winding number
    still separates an inside from an outside is accepted as it is ("open but robust"); one that is too open to
    have an inside raises :class:`~torchhand.errors.MeshError` pointing to ``repair=True``. See
    :meth:`RigidObject.from_trimesh` for how mass properties are taken in each case.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import trimesh

from ..errors import (
    FileFormatError,
    InputTypeError,
    InputValueError,
    MeshError,
    MissingFileError,
)
from ._sdf_build import mesh_content_hash

__all__ = [
    "DEFAULT_DENSITY",
    "RigidObject",
    "load_object",
    "check_watertight",
    "repair_mesh",
    "sample_surface",
    "mesh_content_hash",
]

DEFAULT_DENSITY = 500.0
"""Density used when neither ``mass`` nor ``density`` is given, kg/m^3 (light wood / plastic)."""

_MAX_HOLE_EDGES = 200  # repair_mesh fills boundary loops with at most this many edges


@dataclass(frozen=True, eq=False)
class RigidObject:
    """A rigid object: mesh and mass properties, all in the object frame.

    Fields
        name: object name, str
        mesh: surface, trimesh.Trimesh, object frame, metres (a copy of the input with its visuals, normals made
            outward; the repaired mesh when built with ``repair=True``)
        mass: total mass, float, kg
        com: centre of mass, (3,), object frame, metres
        inertia: inertia tensor about ``com``, (3, 3), object-frame axes, kg m^2
        watertight: whether ``mesh``, with duplicate vertices merged, is a closed consistently wound 2-manifold
            (mass properties then come from it exactly)

    Instances are immutable; equality is identity (compare :meth:`content_hash` for mesh equality).
    """

    name: str
    mesh: trimesh.Trimesh
    mass: float
    com: np.ndarray
    inertia: np.ndarray
    watertight: bool

    def __reduce__(self):
        # pickled (to a worker process, say) without the mesh's cache: a trimesh spatial index (rtree) built
        # before pickling comes back empty, and every proximity query on the copy then fails
        return (type(self), (self.name, self.mesh.copy(include_cache=False), self.mass, self.com, self.inertia,
                             self.watertight))

    @classmethod
    def from_trimesh(
        cls,
        mesh: trimesh.Trimesh,
        *,
        mass: float | None = None,
        density: float | None = None,
        name: str = "object",
        repair: bool = False,
    ) -> "RigidObject":
        """Build a :class:`RigidObject` from a mesh in the object frame (metres).

        Args:
            mesh: triangle mesh, object frame, metres. It is copied, never modified.
            mass: total mass, kg. At most one of ``mass`` and ``density`` may be given.
            density: density, kg/m^3. Default :data:`DEFAULT_DENSITY` (500) when neither is given.
            name: object name.
            repair: run :func:`repair_mesh` first (merge vertices, drop degenerate/duplicate faces, fill small
                holes, make winding consistent and normals outward).

        Mass properties:
            * watertight mesh: exact volume integrals of the mesh (trimesh), with ``density`` or scaled to ``mass``.
            * open mesh whose generalized winding number still has a robust inside (see
              :func:`torchhand.geometry.sdf.inside_report`): mass properties are taken from the mesh's **convex hull**
              (an approximation: it over-estimates the volume of concave objects such as a mug, so prefer giving
              ``mass``; the centre of mass and inertia are then those of the hull). ``watertight`` is False.
            * open mesh too open to have an inside: :class:`MeshError` suggesting ``repair=True``.

        Raises:
            InputTypeError: ``mesh`` is not a ``trimesh.Trimesh``.
            InputValueError: both ``mass`` and ``density`` given, or a non-positive / non-finite value.
            MeshError: empty or degenerate mesh (no faces, zero area, non-finite vertices), or too open.
        """
        if not isinstance(mesh, trimesh.Trimesh):
            raise InputTypeError(f"mesh: expected a trimesh.Trimesh, got {type(mesh).__name__}")
        if mass is not None and density is not None:
            raise InputValueError(f"mass and density: give at most one, got mass={mass} and density={density}")
        for label, value in (("mass", mass), ("density", density)):
            if value is not None and not (np.isfinite(value) and value > 0):
                raise InputValueError(f"{label}: expected a finite positive number, got {value}")
        _check_nondegenerate(mesh, name)
        # `work` has duplicate vertices merged (OBJ UV seams) and is used for the analysis; the stored mesh keeps
        # the input's vertices and visuals unless it was repaired
        work = repair_mesh(mesh) if repair else _cleaned(mesh)
        _check_nondegenerate(work, name)
        stored = work if repair else mesh.copy()

        watertight = bool(work.is_watertight and work.is_winding_consistent)
        if watertight:
            inverted = work.volume < 0  # inward-facing normals
            source = work
        else:
            from .sdf import (
                inside_report,  # lazy: keeps `import torchhand.geometry.objects` light
            )

            report = inside_report(work)
            if not report.robust:
                raise MeshError(
                    f"mesh '{name}' is not watertight and too open to have an inside ({report.message}); "
                    "pass repair=True to merge vertices and fill small holes, or fix the mesh"
                )
            inverted = report.inverted
            source = work.convex_hull
        if inverted:
            work.invert()
            if stored is not work:
                stored.invert()

        volume = float(source.volume)
        if not (np.isfinite(volume) and volume > 0):
            raise MeshError(f"mesh '{name}': non-positive volume {volume:.3e} m^3, cannot take mass properties")
        if mass is None:
            mass = (DEFAULT_DENSITY if density is None else float(density)) * volume
        com = np.asarray(source.center_mass, dtype=np.float64).copy()
        # trimesh's moment_inertia is about the centre of mass, for unit density
        inertia = np.asarray(source.moment_inertia, dtype=np.float64) * (float(mass) / volume)
        inertia = 0.5 * (inertia + inertia.T)
        com.setflags(write=False)
        inertia.setflags(write=False)
        return cls(name=name, mesh=stored, mass=float(mass), com=com, inertia=inertia, watertight=watertight)

    def content_hash(self) -> str:
        """sha256 hex digest of the mesh's vertices (float64) and faces (int64) bytes."""
        return mesh_content_hash(self.mesh)


def load_object(
    path: str | os.PathLike,
    *,
    mass: float | None = None,
    density: float | None = None,
    scale: float = 1.0,
    name: str | None = None,
    repair: bool = False,
) -> RigidObject:
    """Load a mesh file (OBJ, STL, PLY, GLB, ... anything trimesh reads) as a :class:`RigidObject`.

    Scenes with several geometries (GLB, multi-object OBJ) are concatenated with their scene transforms applied.

    Args:
        path: mesh file.
        mass, density, repair: as in :meth:`RigidObject.from_trimesh`.
        scale: multiplies vertex coordinates (e.g. 0.001 for millimetres, 0.1 for decimetres) to get metres.
        name: object name; default the file's stem.

    Raises:
        MissingFileError: ``path`` does not exist.
        FileFormatError: trimesh cannot read the file.
        MeshError: the file holds no triangles, or see :meth:`RigidObject.from_trimesh`.
    """
    p = Path(path)
    if not p.is_file():
        raise MissingFileError(f"path: mesh file '{p}' does not exist")
    if not (np.isfinite(scale) and scale > 0):
        raise InputValueError(f"scale: expected a finite positive number, got {scale}")
    try:
        loaded = trimesh.load(str(p), force="mesh", process=True)
    except Exception as err:  # trimesh raises many types (ValueError, KeyError, struct.error, ...)
        raise FileFormatError(f"path: cannot read mesh file '{p}': {type(err).__name__}: {err}") from None
    if isinstance(loaded, trimesh.Scene):  # force="mesh" returns an empty Scene when there is no geometry
        geoms = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh)]
        loaded = trimesh.util.concatenate(geoms) if geoms else trimesh.Trimesh()
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise MeshError(f"path: mesh file '{p}' holds no triangles")
    mesh = loaded.copy()
    if scale != 1.0:
        mesh.apply_scale(scale)
    return RigidObject.from_trimesh(
        mesh, mass=mass, density=density, name=p.stem if name is None else name, repair=repair
    )


def check_watertight(mesh: trimesh.Trimesh, name: str) -> None:
    """Raise :class:`MeshError` unless ``mesh`` is a closed, consistently wound 2-manifold.

    Duplicate vertices (OBJ texture seams) are merged first, as for :attr:`RigidObject.watertight`. The message
    names the mesh, counts boundary / non-manifold edges and suggests ``repair=True``.
    """
    if not isinstance(mesh, trimesh.Trimesh):
        raise InputTypeError(f"{name}: expected a trimesh.Trimesh, got {type(mesh).__name__}")
    if len(mesh.faces) == 0:
        raise MeshError(f"mesh '{name}' is empty (no faces)")
    mesh = _cleaned(mesh)
    if mesh.is_watertight and mesh.is_winding_consistent:
        return
    counts = np.bincount(mesh.edges_unique_inverse, minlength=len(mesh.edges_unique))
    boundary, nonmanifold = int((counts == 1).sum()), int((counts > 2).sum())
    raise MeshError(
        f"mesh '{name}' is not watertight ({boundary} boundary edges, {nonmanifold} non-manifold edges, "
        f"winding consistent: {bool(mesh.is_winding_consistent)}); load it with repair=True to merge vertices "
        "and fill small holes"
    )


def repair_mesh(mesh: trimesh.Trimesh, *, max_hole_edges: int = _MAX_HOLE_EDGES) -> trimesh.Trimesh:
    """Return a repaired copy of ``mesh`` (the input is not modified).

    Steps, in order:
        1. merge duplicate vertices, ignoring texture coordinates and normals (closes OBJ UV seams);
        2. drop degenerate (zero-area) and duplicate faces, and unreferenced vertices;
        3. fill every hole bounded by a simple closed loop of at most ``max_hole_edges`` boundary edges with a fan
           around the loop's centroid (a new vertex per hole), oriented consistently with the neighbouring faces
           (boundaries that touch non-manifold edges or run into each other are left open);
        4. make the winding consistent and the normals point outward (trimesh ``fix_normals``).

    It does not remove self-intersections, fix non-manifold edges, or close larger or non-simple holes, so the
    result is not always watertight (check ``is_watertight``); the SDF's winding-number sign does not need it.
    """
    out = _cleaned(mesh)
    out = _fill_holes(out, max_hole_edges)
    trimesh.repair.fix_normals(out, multibody=True)
    return out


def sample_surface(
    mesh: trimesh.Trimesh, n: int, generator: torch.Generator, *, dtype: torch.dtype | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Sample ``n`` points uniformly by area on the surface of ``mesh``.

    Randomness comes only from ``generator`` (``torch.multinomial`` for faces, ``torch.rand`` for barycentric
    coordinates); the same generator state gives the same samples.

    Args:
        mesh: triangle mesh, object frame, metres.
        n: number of samples, int >= 1.
        generator: the torch.Generator of every draw; its device is the output device.
        dtype: output dtype, default ``torch.get_default_dtype()``.

    Returns:
        points: surface samples, (n, 3), object frame, metres
        normals: outward unit face normals at the samples, (n, 3), object frame
    """
    if not isinstance(mesh, trimesh.Trimesh):
        raise InputTypeError(f"mesh: expected a trimesh.Trimesh, got {type(mesh).__name__}")
    if not isinstance(generator, torch.Generator):
        raise InputTypeError(f"generator: expected a torch.Generator, got {type(generator).__name__}")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise InputValueError(f"n: expected an int >= 1, got {n!r}")
    _check_nondegenerate(mesh, "mesh")
    dtype = torch.get_default_dtype() if dtype is None else dtype
    device = generator.device
    tri = torch.tensor(np.asarray(mesh.triangles), dtype=torch.float64, device=device)  # (F, 3, 3), a copy
    cross = torch.linalg.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area2 = torch.linalg.norm(cross, dim=-1)
    sign = -1.0 if _is_inverted(mesh) else 1.0
    normals_f = sign * cross / area2.clamp_min(1e-300)[:, None]
    face = torch.multinomial(area2, int(n), replacement=True, generator=generator)
    r = torch.rand(int(n), 2, generator=generator, dtype=torch.float64, device=device)
    s = r[:, 0].sqrt()
    w1, w2 = s * (1 - r[:, 1]), s * r[:, 1]
    t = tri[face]
    points = t[:, 0] + w1[:, None] * (t[:, 1] - t[:, 0]) + w2[:, None] * (t[:, 2] - t[:, 0])
    return points.to(dtype), normals_f[face].to(dtype)


# ---------------------------------------------------------------------------------------------------------------
# helpers


def _check_nondegenerate(mesh: trimesh.Trimesh, name: str) -> None:
    if len(mesh.faces) == 0 or len(mesh.vertices) == 0:
        raise MeshError(f"mesh '{name}' is empty (no faces)")
    if not np.isfinite(mesh.vertices).all():
        raise MeshError(f"mesh '{name}' has non-finite vertex coordinates")
    area = float(mesh.area)
    extent = float(np.max(mesh.extents))
    if not (area > 1e-12 * max(extent, 1e-30) ** 2 and area > 0):
        raise MeshError(f"mesh '{name}' is degenerate (total area {area:.3e} m^2)")


def _cleaned(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Copy with vertices merged (ignoring UVs/normals) and degenerate/duplicate faces removed."""
    out = trimesh.Trimesh(vertices=np.asarray(mesh.vertices, dtype=np.float64).copy(),
                          faces=np.asarray(mesh.faces, dtype=np.int64).copy(), process=False)
    out.merge_vertices(merge_tex=True, merge_norm=True)
    keep = _nondegenerate(out) & _first_unique(out.faces)
    out.update_faces(keep)
    out.remove_unreferenced_vertices()
    return out


def _nondegenerate(mesh: trimesh.Trimesh) -> np.ndarray:
    f = mesh.faces
    distinct = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    return distinct & (mesh.area_faces > 0)


def _first_unique(faces: np.ndarray) -> np.ndarray:
    key = np.sort(faces, axis=1)
    _, first = np.unique(key, axis=0, return_index=True)
    keep = np.zeros(len(faces), dtype=bool)
    keep[first] = True
    return keep


def _fill_holes(mesh: trimesh.Trimesh, max_hole_edges: int) -> trimesh.Trimesh:
    """Fan-fill boundary loops with at most ``max_hole_edges`` edges (consistent orientation, one vertex each)."""
    directed = mesh.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    key = np.sort(directed, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    boundary = directed[counts[inverse.reshape(-1)] == 1]
    if len(boundary) == 0:
        return mesh
    import scipy.sparse
    import scipy.sparse.csgraph

    nv = len(mesh.vertices)
    graph = scipy.sparse.coo_matrix((np.ones(len(boundary)), (boundary[:, 0], boundary[:, 1])), shape=(nv, nv))
    _, label = scipy.sparse.csgraph.connected_components(graph, directed=False)
    comp = label[boundary[:, 0]]
    uniq, comp_idx, edge_count = np.unique(comp, return_inverse=True, return_counts=True)
    # only simple closed loops: every vertex of the component starts one boundary edge and ends one
    out_deg = np.bincount(boundary[:, 0], minlength=nv)
    in_deg = np.bincount(boundary[:, 1], minlength=nv)
    bad_vertex = (out_deg != 1) | (in_deg != 1)
    bad_comp = np.zeros(len(uniq), dtype=bool)
    np.logical_or.at(bad_comp, comp_idx, bad_vertex[boundary[:, 0]] | bad_vertex[boundary[:, 1]])
    small = (edge_count <= max_hole_edges) & (edge_count >= 3) & ~bad_comp
    if not small.any():
        return mesh
    verts = np.asarray(mesh.vertices)
    centroid = np.zeros((len(uniq), 3))
    np.add.at(centroid, comp_idx, verts[boundary[:, 0]])
    centroid /= edge_count[:, None]
    new_index = np.full(len(uniq), -1)
    new_index[small] = nv + np.arange(int(small.sum()))
    sel = small[comp_idx]
    # a boundary directed edge (u -> v) of a face is traversed (v -> u) by the filling triangle
    fan = np.column_stack((boundary[sel, 1], boundary[sel, 0], new_index[comp_idx[sel]]))
    out = trimesh.Trimesh(vertices=np.vstack((verts, centroid[small])), faces=np.vstack((mesh.faces, fan)),
                          process=False)
    out.merge_vertices(merge_tex=True, merge_norm=True)
    return out


def _is_inverted(mesh: trimesh.Trimesh) -> bool:
    """True when the mesh's normals point inward (negative signed volume of a closed or nearly closed mesh)."""
    t = np.asarray(mesh.triangles, dtype=np.float64)
    t = t - t.reshape(-1, 3).mean(0)  # about the centroid, so open meshes are judged fairly
    return bool(np.einsum("ij,ij->", t[:, 0], np.cross(t[:, 1], t[:, 2])) < 0)
