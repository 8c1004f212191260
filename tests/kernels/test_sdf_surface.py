"""Closest point on a triangle with its Voronoi region, and the candidate-triangle surface query: smoke, shapes,
agreement with trimesh's exact closest points, the sign from each triangle's sides."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from torchhand.kernels.sdf_surface import closest_point_region, surface_query


def test_closest_point_region_against_trimesh():
    """Random points against random triangles: the point matches trimesh's closest point, and the region code is
    the feature it lies on (barycentric coordinates: an interior point, one zero coordinate, two zeros)."""
    rng = np.random.default_rng(0)
    tri = rng.normal(size=(500, 3, 3))
    p = rng.normal(scale=2.0, size=(500, 3))
    ours, region = closest_point_region(*(torch.as_tensor(x) for x in (p, tri[:, 0], tri[:, 1], tri[:, 2])))
    ref = trimesh.triangles.closest_point(tri, p)
    np.testing.assert_allclose(ours.numpy(), ref, atol=1e-10)
    bary = trimesh.triangles.points_to_barycentric(tri, ours.numpy())
    zero = bary < 1e-9
    region = region.numpy()
    assert set(np.unique(region)) <= set(range(7)) and len(np.unique(region)) == 7  # every region occurs
    assert np.all(zero[region == 0].sum(1) == 0)
    for code, (i, j) in {1: (0, 1), 2: (1, 2), 3: (2, 0)}.items():      # edge AB: the C coordinate is zero, ...
        k = 3 - i - j
        assert np.all(zero[region == code][:, k]) and not np.any(zero[region == code][:, [i, j]].all(1))
    for code, i in {4: 0, 5: 1, 6: 2}.items():                          # vertex A: the A coordinate is one
        np.testing.assert_allclose(bary[region == code][:, i], 1.0, atol=1e-9)


@pytest.mark.parametrize("n", [1, 7])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_surface_query_one_triangle_sign_and_normal(n, dtype):
    """A single triangle in the z = 0 plane, inside below it: points above are outside with the normal +z,
    points below inside with -z... i.e. sd = z and normal = +z over the face; beyond an edge the normal points
    from the edge toward the point."""
    tri = torch.tensor([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], dtype=dtype)
    pn = torch.tensor([[[0, 0, 1.0]] * 7], dtype=dtype)
    sides = torch.tensor([[0.0, 1.0]], dtype=dtype)                     # front (+z) outside, back inside
    g = torch.Generator().manual_seed(n)
    xy = torch.rand(n, 2, generator=g, dtype=dtype) * 0.4 + 0.05
    z = (torch.rand(n, generator=g, dtype=dtype) - 0.5) * 0.02
    pts = torch.cat([xy, z[:, None]], 1)
    faces = torch.zeros(n, 8, dtype=torch.long)
    sd, normal, closest, face = surface_query(pts, torch.ones(n, dtype=dtype), faces, tri, pn, sides, 0.05)
    tol = 1e-6 if dtype == torch.float32 else 1e-12
    torch.testing.assert_close(sd, z, atol=tol, rtol=0)
    torch.testing.assert_close(normal, torch.tensor([0, 0, 1.0], dtype=dtype).expand(n, 3), atol=tol, rtol=0)
    torch.testing.assert_close(closest[:, :2], xy, atol=tol, rtol=0)
    assert face.shape == (n,) and (face == 0).all()
    # beyond the hypotenuse, above the plane: distance to the edge, normal from the edge to the point
    p = torch.tensor([[0.6, 0.6, 0.1]], dtype=dtype)
    sd, normal, closest, _ = surface_query(p, torch.ones(1, dtype=dtype), faces[:1], tri, pn, sides, 1.0)
    expect = p - torch.tensor([[0.5, 0.5, 0.0]], dtype=dtype)
    torch.testing.assert_close(sd, expect.norm(dim=-1), atol=tol, rtol=0)
    torch.testing.assert_close(normal, expect / expect.norm(), atol=tol, rtol=0)


def test_surface_query_keeps_the_grid_sign_beyond_the_band_and_at_unclean_triangles():
    """Beyond ``sign_band`` the grid's sign is used; so it is at a triangle inside the solid on both sides."""
    tri = torch.tensor([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], dtype=torch.float64)
    pn = torch.tensor([[[0, 0, 1.0]] * 7], dtype=torch.float64)
    p = torch.tensor([[0.2, 0.2, 0.01], [0.2, 0.2, 0.3]], dtype=torch.float64)
    faces = torch.zeros(2, 8, dtype=torch.long)
    clean = torch.tensor([[0.0, 1.0]], dtype=torch.float64)
    sd, _, _, _ = surface_query(p, torch.tensor([-1.0, -1.0], dtype=torch.float64), faces, tri, pn, clean, 0.1)
    assert sd[0] > 0 and sd[1] < 0                  # in the band: the triangle's side; beyond: the grid's sign
    internal = torch.tensor([[0.9, 1.1]], dtype=torch.float64)   # inside on both sides (a part pushed into another)
    sd, normal, _, _ = surface_query(p, torch.tensor([-1.0, -1.0], dtype=torch.float64), faces, tri, pn, internal, 0.1)
    assert (sd < 0).all()
    torch.testing.assert_close(normal[0], torch.tensor([0, 0, -1.0], dtype=torch.float64))  # grad of sd = -z
