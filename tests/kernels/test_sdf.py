"""Trilinear SDF kernel: smoke, shapes (B = 1, 7), bad input, references (PyTorch grid_sample, SciPy), gradcheck."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torchhand.kernels.sdf import pack_corners, sdf_trilinear, sdf_trilinear_with_grad

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
ATOL = {torch.float32: 1e-5, torch.float64: 1e-12}


def make_grid(dtype=torch.float64, device="cpu", shape=(9, 11, 8), voxel=0.01, seed=0):
    """A sphere SDF (radius 3 cm) plus a smooth random perturbation, sampled on a grid; returns values, origin."""
    g = torch.Generator().manual_seed(seed)
    origin = torch.tensor([-0.04, -0.05, -0.035], dtype=torch.float64)
    axes = [origin[a] + voxel * torch.arange(n, dtype=torch.float64) for a, n in enumerate(shape)]
    x = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1)
    values = x.norm(dim=-1) - 0.03 + 0.002 * torch.randn(shape, generator=g, dtype=torch.float64)
    return values.to(device, dtype), origin.to(device, dtype)


def random_points(b, p, origin, shape, voxel, margin=0.02, seed=1):
    g = torch.Generator().manual_seed(seed)
    lo = origin.cpu().double() - margin
    ext = (torch.tensor(shape, dtype=torch.float64) - 1) * voxel + 2 * margin
    pts = lo + torch.rand(b, p, 3, generator=g, dtype=torch.float64) * ext
    return pts.to(origin.device, origin.dtype)


def reference(values, origin, voxel, points):
    """PyTorch's grid_sample (trilinear, border clamp, align_corners) plus the distance to the grid box."""
    n = torch.tensor(values.shape, dtype=points.dtype, device=points.device)
    u = (points - origin) / voxel
    uc = torch.minimum(torch.maximum(u, torch.zeros_like(n)), n - 1)
    grid = (uc * 2 / (n - 1) - 1).flip(-1).reshape(1, -1, 1, 1, 3)  # grid_sample wants (x=W, y=H, z=D)
    v = torch.nn.functional.grid_sample(values[None, None], grid, mode="bilinear", padding_mode="border",
                                        align_corners=True).reshape(points.shape[:-1])
    return v + (u - uc).norm(dim=-1) * voxel


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["f32", "f64"])
@pytest.mark.parametrize("b", [1, 7])
@pytest.mark.parametrize("packed", [False, True], ids=["gather8", "corners"])
def test_shapes_and_agreement_with_grid_sample(device, dtype, b, packed):
    values, origin = make_grid(dtype, device)
    pts = random_points(b, 50, origin, values.shape, 0.01)
    corners = pack_corners(values) if packed else None
    sd = sdf_trilinear(values, origin, 0.01, pts, corners=corners)
    sd2, grad = sdf_trilinear_with_grad(values, origin, 0.01, pts, corners=corners)
    assert sd.shape == (b, 50) and grad.shape == (b, 50, 3)
    assert sd.dtype == dtype and sd.device.type == device
    ref = reference(values, origin, 0.01, pts)
    tol = 1e-6 if dtype == torch.float32 else 1e-12
    torch.testing.assert_close(sd, ref, atol=tol, rtol=0)
    torch.testing.assert_close(sd2, sd, atol=0, rtol=0)


def test_agrees_with_scipy_regular_grid_interpolator():
    from scipy.interpolate import RegularGridInterpolator

    values, origin = make_grid()
    axes = [origin[a].item() + 0.01 * np.arange(n) for a, n in enumerate(values.shape)]
    interp = RegularGridInterpolator(axes, values.numpy(), method="linear")
    pts = random_points(3, 200, origin, values.shape, 0.01, margin=-0.001)  # strictly inside the box
    ours = sdf_trilinear(values, origin, 0.01, pts)
    np.testing.assert_allclose(ours.numpy(), interp(pts.numpy().reshape(-1, 3)).reshape(3, 200), atol=1e-12)


def test_grad_matches_autograd_of_grid_sample_reference():
    values, origin = make_grid()
    pts = random_points(7, 100, origin, values.shape, 0.01)
    p = pts.clone().requires_grad_(True)
    reference(values, origin, 0.01, p).sum().backward()
    _, grad = sdf_trilinear_with_grad(values, origin, 0.01, pts)
    torch.testing.assert_close(grad, p.grad, atol=1e-9, rtol=0)


def test_exact_at_nodes_and_outside_adds_box_distance():
    values, origin = make_grid()
    idx = torch.tensor([[0, 0, 0], [8, 10, 7], [3, 4, 5]])
    nodes = (origin + 0.01 * idx.double())[None]
    torch.testing.assert_close(sdf_trilinear(values, origin, 0.01, nodes)[0], values[tuple(idx.T)], atol=1e-14, rtol=0)
    # a point 5 cm beyond the -x face, level with node (0, 4, 5)
    far = (origin + 0.01 * torch.tensor([0.0, 4.0, 5.0], dtype=torch.float64) - torch.tensor([0.05, 0, 0], dtype=torch.float64))[None, None]
    sd, grad = sdf_trilinear_with_grad(values, origin, 0.01, far)
    assert sd.item() == pytest.approx(values[0, 4, 5].item() + 0.05, abs=1e-12)
    assert grad[0, 0, 0].item() == pytest.approx(-1.0)  # the box term dominates along the clamped axis


@pytest.mark.parametrize("margin", [-0.001, 0.03], ids=["inside", "around"])
def test_gradcheck_float64(margin):
    values, origin = make_grid()
    pts = random_points(2, 6, origin, values.shape, 0.01, margin=margin).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: sdf_trilinear(values, origin, 0.01, x), (pts,), eps=1e-7, atol=1e-6)
    corners = pack_corners(values)
    assert torch.autograd.gradcheck(lambda x: sdf_trilinear(values, origin, 0.01, x, corners=corners), (pts,),
                                    eps=1e-7, atol=1e-6)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["f32", "f64"])
def test_backward_equals_returned_gradient(dtype):
    values, origin = make_grid(dtype)
    pts = random_points(7, 30, origin, values.shape, 0.01).requires_grad_(True)
    w = torch.linspace(0.5, 2.0, 30, dtype=dtype)
    (sdf_trilinear(values, origin, 0.01, pts) * w).sum().backward()
    _, grad = sdf_trilinear_with_grad(values, origin, 0.01, pts.detach())
    torch.testing.assert_close(pts.grad, grad * w[:, None], atol=ATOL[dtype], rtol=1e-5)


def test_double_backward_is_refused():
    values, origin = make_grid()
    pts = random_points(1, 4, origin, values.shape, 0.01).requires_grad_(True)
    (g,) = torch.autograd.grad(sdf_trilinear(values, origin, 0.01, pts).sum(), pts, create_graph=True)
    with pytest.raises(RuntimeError):
        g.sum().backward()


def test_far_away_value_is_an_upper_bound_of_the_true_distance():
    # exact sphere SDF on the grid: outside the box the clamped value + box distance >= true distance
    shape, voxel = (9, 9, 9), 0.01
    origin = torch.full((3,), -0.04, dtype=torch.float64)
    axes = [origin[a] + voxel * torch.arange(9, dtype=torch.float64) for a in range(3)]
    values = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1).norm(dim=-1) - 0.03
    pts = random_points(1, 500, origin, shape, voxel, margin=0.3)
    sd = sdf_trilinear(values, origin, voxel, pts)
    true = pts.norm(dim=-1) - 0.03
    outside = ((pts - origin).abs() > 0.085).any(-1)
    assert bool((sd[outside] >= true[outside] - 1e-3).all())


def test_nan_points_give_nan_and_never_index_out_of_bounds():
    values, origin = make_grid()
    pts = random_points(2, 5, origin, values.shape, 0.01)
    pts[0, 1, 2] = float("nan")
    pts[1, 3] = float("inf")
    for corners in (None, pack_corners(values)):
        sd = sdf_trilinear(values, origin, 0.01, pts, corners=corners)
        assert torch.isnan(sd[0, 1]) and torch.isfinite(sd[0, [0, 2, 3, 4]]).all()
        assert not torch.isfinite(sd[1, 3])


def test_bad_input():
    values, origin = make_grid()
    pts = random_points(1, 5, origin, values.shape, 0.01)
    with pytest.raises(ValueError, match="points"):
        sdf_trilinear(values, origin, 0.01, pts[0])
    with pytest.raises(ValueError, match="values"):
        sdf_trilinear(values[0], origin, 0.01, pts)
    with pytest.raises(ValueError, match="values"):
        sdf_trilinear(values[:1], origin, 0.01, pts)
    with pytest.raises(ValueError, match="origin"):
        sdf_trilinear(values, origin[:2], 0.01, pts)
    with pytest.raises(TypeError, match="dtype"):
        sdf_trilinear(values, origin, 0.01, pts.float())
    with pytest.raises(ValueError, match="voxel_size"):
        sdf_trilinear(values, origin, 0.0, pts)
    with pytest.raises(ValueError, match="corners"):
        sdf_trilinear(values, origin, 0.01, pts, corners=pack_corners(values)[:-1])


def test_pack_corners_layout():
    values, _ = make_grid()
    c = pack_corners(values)
    nx, ny, nz = values.shape
    assert c.shape == ((nx - 1) * (ny - 1) * (nz - 1), 8)
    i, j, k = 2, 3, 4
    row = c[i * (ny - 1) * (nz - 1) + j * (nz - 1) + k]
    for dz in (0, 1):
        for dy in (0, 1):
            for dx in (0, 1):
                assert row[4 * dz + 2 * dy + dx] == values[i + dx, j + dy, k + dz]
    assert bool(torch.isfinite(c).all())
