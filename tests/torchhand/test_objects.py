"""Rigid objects: loading (OBJ, STL, PLY, GLB, scenes), mass properties against closed-form references,
open and too-open meshes, repair, surface sampling, content hash, and errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

import torchhand
from torchhand.errors import FileFormatError, InputTypeError, InputValueError, MeshError, MissingFileError
from torchhand.geometry.objects import (
    DEFAULT_DENSITY,
    RigidObject,
    check_watertight,
    load_object,
    repair_mesh,
    sample_surface,
)

from tests.conftest import shared_path as shared

REPO = Path(__file__).resolve().parents[2]


def box(extents=(0.04, 0.06, 0.1)) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=extents)


def open_box() -> trimesh.Trimesh:
    """A box missing one of its two +z triangles (half the lid): open, but with a clear inside."""
    m = box()
    top = np.nonzero(m.face_normals[:, 2] > 0.5)[0]
    return trimesh.Trimesh(m.vertices, np.delete(m.faces, top[0], axis=0), process=False)


def box_inertia(mass, a, b, c):
    """Closed form for a solid cuboid about its centre (a reference nobody here wrote)."""
    return np.diag([mass * (b * b + c * c), mass * (a * a + c * c), mass * (a * a + b * b)]) / 12.0


def test_box_mass_properties_match_closed_form():
    obj = RigidObject.from_trimesh(box(), density=800.0, name="box")
    a, b, c = 0.04, 0.06, 0.1
    assert obj.watertight and obj.name == "box"
    assert obj.mass == pytest.approx(800.0 * a * b * c)
    np.testing.assert_allclose(obj.com, 0.0, atol=1e-12)
    np.testing.assert_allclose(obj.inertia, box_inertia(obj.mass, a, b, c), rtol=1e-9, atol=1e-15)
    # default density, and a given mass scales the inertia
    assert RigidObject.from_trimesh(box()).mass == pytest.approx(DEFAULT_DENSITY * a * b * c)
    obj2 = RigidObject.from_trimesh(box(), mass=0.3)
    assert obj2.mass == 0.3
    np.testing.assert_allclose(obj2.inertia, box_inertia(0.3, a, b, c), rtol=1e-9)


def test_shifted_box_com_and_frozen_fields():
    m = box()
    m.apply_translation([0.1, -0.2, 0.05])
    obj = RigidObject.from_trimesh(m, mass=1.0)
    np.testing.assert_allclose(obj.com, [0.1, -0.2, 0.05], atol=1e-12)
    with pytest.raises(Exception):
        obj.mass = 2.0  # frozen dataclass
    with pytest.raises(ValueError):
        obj.com[0] = 1.0  # read-only array


def test_inward_facing_mesh_is_flipped():
    m = box()
    m.invert()
    obj = RigidObject.from_trimesh(m, density=1000.0)
    assert obj.mass == pytest.approx(1000.0 * 0.04 * 0.06 * 0.1)
    assert obj.mesh.volume > 0


def test_stored_mesh_keeps_visuals():
    m = box()
    m.visual.vertex_colors = np.tile([10, 20, 30, 255], (len(m.vertices), 1)).astype(np.uint8)
    obj = RigidObject.from_trimesh(m)
    assert obj.mesh is not m
    np.testing.assert_array_equal(obj.mesh.visual.vertex_colors, m.visual.vertex_colors)


def test_from_trimesh_does_not_modify_input():
    m = open_box()
    before = m.vertices.copy(), m.faces.copy()
    RigidObject.from_trimesh(m, repair=True)
    np.testing.assert_array_equal(m.vertices, before[0])
    np.testing.assert_array_equal(m.faces, before[1])


def test_open_mesh_uses_convex_hull_and_repair_closes_it():
    obj = RigidObject.from_trimesh(open_box(), density=1000.0)
    assert not obj.watertight
    assert obj.mass == pytest.approx(1000.0 * 0.04 * 0.06 * 0.1, rel=1e-6)  # hull of an open box = the box
    with pytest.raises(MeshError, match="repair=True"):
        check_watertight(obj.mesh, "open box")
    fixed = RigidObject.from_trimesh(open_box(), density=1000.0, repair=True)
    assert fixed.watertight
    check_watertight(fixed.mesh, "fixed")
    assert fixed.mass == pytest.approx(1000.0 * 0.04 * 0.06 * 0.1, rel=1e-6)


def test_too_open_mesh_raises_mesh_error():
    plane = trimesh.creation.box(extents=(0.1, 0.1, 0.01))
    top = trimesh.Trimesh(plane.vertices, plane.faces[plane.face_normals[:, 2] > 0.5], process=False)
    with pytest.raises(MeshError, match="too open.*repair=True"):
        RigidObject.from_trimesh(top, name="sheet")


def test_repair_mesh_fills_small_holes_and_merges_uv_seams():
    m = open_box()
    fixed = repair_mesh(m)
    assert fixed.is_watertight and fixed.is_winding_consistent and fixed.volume > 0
    # split every face into its own vertices, as OBJ texture seams do
    soup = trimesh.Trimesh(box().triangles.reshape(-1, 3), np.arange(36).reshape(12, 3), process=False)
    assert not soup.is_watertight
    assert repair_mesh(soup).is_watertight
    check_watertight(soup, "seamed")  # merged before the check, like RigidObject.watertight
    assert RigidObject.from_trimesh(soup).watertight
    assert len(m.faces) == 11  # input untouched


@pytest.mark.parametrize("ext", ["obj", "stl", "ply", "glb"])
def test_load_object_formats(tmp_path, ext):
    path = tmp_path / f"thing.{ext}"
    box().export(path)
    obj = load_object(path, density=1000.0)
    assert obj.name == "thing" and obj.watertight
    assert obj.mass == pytest.approx(1000.0 * 0.04 * 0.06 * 0.1, rel=1e-6)


def test_load_object_scale_name_and_scene_concatenation(tmp_path):
    scene = trimesh.Scene()
    scene.add_geometry(box((0.01, 0.01, 0.01)), node_name="a", transform=trimesh.transformations.translation_matrix([0.1, 0, 0]))
    scene.add_geometry(box((0.01, 0.01, 0.01)), node_name="b", transform=trimesh.transformations.translation_matrix([-0.1, 0, 0]))
    path = tmp_path / "two.glb"
    scene.export(path)
    obj = load_object(path, density=1000.0, name="pair")
    assert obj.name == "pair" and len(obj.mesh.faces) == 24
    assert obj.mass == pytest.approx(2 * 1000.0 * 1e-6, rel=1e-6)
    np.testing.assert_allclose(obj.mesh.bounds, [[-0.105, -0.005, -0.005], [0.105, 0.005, 0.005]], atol=1e-9)
    scaled = load_object(path, scale=10.0)
    np.testing.assert_allclose(scaled.mesh.bounds, [[-1.05, -0.05, -0.05], [1.05, 0.05, 0.05]], atol=1e-7)


def test_load_object_errors(tmp_path):
    with pytest.raises(MissingFileError, match="nope.obj"):
        load_object(tmp_path / "nope.obj")
    bad = tmp_path / "bad.glb"
    bad.write_bytes(b"glTF garbage")
    with pytest.raises(FileFormatError, match="bad.glb"):
        load_object(bad)
    broken = tmp_path / "broken.ply"
    broken.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1 2\n")
    with pytest.raises(FileFormatError, match="broken.ply"):
        load_object(broken)
    unknown = tmp_path / "thing.xyz123"
    unknown.write_text("abc")
    with pytest.raises(FileFormatError, match="thing.xyz123"):
        load_object(unknown)
    empty = tmp_path / "empty.obj"
    empty.write_text("# nothing here\n")
    with pytest.raises((MeshError, FileFormatError), match="empty.obj"):
        load_object(empty)
    points_only = tmp_path / "points.obj"
    points_only.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    with pytest.raises(MeshError, match="points.obj"):
        load_object(points_only)
    with pytest.raises(InputValueError, match="scale"):
        load_object(points_only, scale=-1.0)


def test_from_trimesh_bad_input():
    with pytest.raises(InputValueError, match="mass and density"):
        RigidObject.from_trimesh(box(), mass=1.0, density=2.0)
    with pytest.raises(InputValueError, match="mass"):
        RigidObject.from_trimesh(box(), mass=-1.0)
    with pytest.raises(InputTypeError, match="mesh"):
        RigidObject.from_trimesh(np.zeros((3, 3)))
    with pytest.raises(MeshError, match="empty"):
        RigidObject.from_trimesh(trimesh.Trimesh())
    flat = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]], process=False)
    with pytest.raises(MeshError, match="degenerate"):
        RigidObject.from_trimesh(flat)
    with pytest.raises(MeshError, match="nothing"):
        check_watertight(trimesh.Trimesh(), "nothing")


def test_content_hash():
    a = RigidObject.from_trimesh(box())
    b = RigidObject.from_trimesh(box())
    c = RigidObject.from_trimesh(box((0.04, 0.06, 0.11)))
    assert a.content_hash() == b.content_hash() != c.content_hash()
    assert len(a.content_hash()) == 64


def test_sample_surface_determinism_area_and_normals():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    p1, n1 = sample_surface(sphere, 2000, torch.Generator().manual_seed(7))
    p2, n2 = sample_surface(sphere, 2000, torch.Generator().manual_seed(7))
    p3, _ = sample_surface(sphere, 2000, torch.Generator().manual_seed(8))
    assert p1.shape == (2000, 3) and n1.shape == (2000, 3) and p1.dtype == torch.get_default_dtype()
    assert torch.equal(p1, p2) and torch.equal(n1, n2) and not torch.equal(p1, p3)
    # on the surface (trimesh distance), outward unit normals
    _, dist, _ = trimesh.proximity.closest_point(sphere, p1.double().numpy())
    assert dist.max() < 1e-6
    torch.testing.assert_close(n1.norm(dim=-1), torch.ones(2000), atol=1e-5, rtol=0)
    assert ((n1 * p1).sum(-1) > 0).all()
    # an inward-wound mesh still gets outward normals
    inv = sphere.copy()
    inv.invert()
    _, ni = sample_surface(inv, 500, torch.Generator().manual_seed(7), dtype=torch.float64)
    pi, _ = sample_surface(inv, 500, torch.Generator().manual_seed(7), dtype=torch.float64)
    assert ((ni * pi).sum(-1) > 0).all()


def test_sample_surface_is_area_proportional():
    # two triangles with areas 1 : 3
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [3, 0, 0], [2, 3, 0]], dtype=float) * 0.01
    m = trimesh.Trimesh(v, [[0, 1, 2], [3, 4, 5]], process=False)
    p, _ = sample_surface(m, 20000, torch.Generator().manual_seed(0), dtype=torch.float64)
    frac_big = (p[:, 0] >= 0.0195).double().mean().item()
    assert frac_big == pytest.approx(0.75, abs=0.015)


def test_sample_surface_bad_input():
    g = torch.Generator().manual_seed(0)
    with pytest.raises(InputValueError, match="n"):
        sample_surface(box(), 0, g)
    with pytest.raises(InputTypeError, match="generator"):
        sample_surface(box(), 10, 0)
    with pytest.raises(MeshError):
        sample_surface(trimesh.Trimesh(), 10, g)


def test_lazy_top_level_attributes():
    assert torchhand.RigidObject is RigidObject
    assert torchhand.load_object is load_object


# ---------------------------------------------------------------------------------------------------------------
# reference meshes (skipped without ../shared/data)


def test_shared_mug_and_bunny_load():
    mug = load_object(shared("meshes", "bigym_props", "mug", "assets", "mug.obj"), mass=0.3)
    assert not mug.watertight and mug.mass == 0.3 and mug.inertia.shape == (3, 3)
    assert np.all(np.linalg.eigvalsh(mug.inertia) > 0)
    repaired = load_object(shared("meshes", "bigym_props", "mug", "assets", "mug.obj"), repair=True)
    assert repaired.watertight  # the mug's seams and small holes close
    bunny = load_object(shared("meshes", "trimesh", "bunny.ply"), density=1000.0)
    assert not bunny.watertight
    # open mesh: mass properties of the convex hull, which contains the bunny (true volume ~7.6e-4 m^3)
    hull = bunny.mesh.convex_hull
    assert bunny.mass == pytest.approx(1000.0 * hull.volume) and bunny.mass > 0.76
    np.testing.assert_allclose(bunny.com, hull.center_mass, atol=1e-12)


def test_a_pickled_object_keeps_working_proximity_queries():
    """A rigid object sent to a worker process (``torchhand fill --jobs N``) is pickled; trimesh's spatial index,
    once built, pickles empty and every closest-point query on the copy then fails. The object is pickled without
    the mesh's cache."""
    import pickle

    obj = RigidObject.from_trimesh(trimesh.creation.annulus(r_min=0.02, r_max=0.04, height=0.05), mass=0.2)
    pts = np.array([[0.03, 0.0, 0.04], [0.0, 0.0, 0.0], [0.1, 0.05, -0.02]])
    want = trimesh.proximity.closest_point(obj.mesh, pts)[1]              # builds the index
    again = pickle.loads(pickle.dumps(obj))
    np.testing.assert_allclose(trimesh.proximity.closest_point(again.mesh, pts)[1], want, rtol=0, atol=1e-12)
    assert (again.name, again.mass, again.watertight) == (obj.name, obj.mass, obj.watertight)
    np.testing.assert_array_equal(again.com, obj.com)
    np.testing.assert_array_equal(again.mesh.faces, obj.mesh.faces)
