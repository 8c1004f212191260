"""Penetration kernels: link-sample SDF penetration against a brute-force loop, capsule distances against dense
sampling; shapes for B = 1 and 7, bad input, gradients."""

from __future__ import annotations

import math

import pytest
import torch

from torchhand.kernels.penetration import (
    capsule_interpenetration,
    closest_points_segment_segment,
    link_sample_penetration,
)
from torchhand.kernels.sdf import pack_corners, sdf_trilinear_with_grad

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


def random_rotation(n, g, dtype=torch.float64):
    q = torch.randn(n, 4, generator=g, dtype=torch.float64)
    q = q / q.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    R = torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], -1).reshape(n, 3, 3)
    return R.to(dtype)


def random_poses(shape, g, scale=0.05, dtype=torch.float64):
    n = math.prod(shape)
    T = torch.eye(4, dtype=dtype).repeat(n, 1, 1)
    T[:, :3, :3] = random_rotation(n, g, dtype)
    T[:, :3, 3] = (torch.rand(n, 3, generator=g, dtype=torch.float64) * 2 - 1).to(dtype) * scale
    return T.reshape(*shape, 4, 4)


def sphere_grid(dtype=torch.float64, device="cpu", radius=0.03, voxel=0.004, n=21):
    origin = torch.full((3,), -voxel * (n - 1) / 2, dtype=torch.float64)
    axes = [origin[a] + voxel * torch.arange(n, dtype=torch.float64) for a in range(3)]
    values = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1).norm(dim=-1) - radius
    return values.to(device, dtype), origin.to(device, dtype), voxel


def make_case(b, n_links=5, s=40, dtype=torch.float64, device="cpu", seed=0):
    g = torch.Generator().manual_seed(seed)
    link_poses = random_poses((b, n_links), g, dtype=dtype).to(device)
    pts = ((torch.rand(s, 3, generator=g, dtype=torch.float64) * 2 - 1) * 0.02).to(device, dtype)
    sample_link = torch.randint(0, n_links - 1, (s,), generator=g).to(device)  # the last link has no samples
    T_world_obj = random_poses((b,), g, scale=0.01, dtype=dtype).to(device)
    return link_poses, pts, sample_link, torch.linalg.inv(T_world_obj)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["f32", "f64"])
@pytest.mark.parametrize("b", [1, 7])
def test_link_sample_penetration_matches_brute_force_loop(device, dtype, b):
    values, origin, voxel = sphere_grid(dtype, device)
    link_poses, pts, sample_link, T_obj_world = make_case(b, dtype=dtype, device=device)
    res = link_sample_penetration(link_poses, pts, sample_link, T_obj_world, values, origin, voxel,
                                  corners=pack_corners(values))
    n_links, s = link_poses.shape[1], pts.shape[0]
    assert res.sd.shape == (b, s) and res.deepest_value.shape == (b, n_links)
    assert res.deepest_index.shape == (b, n_links) and res.deepest_index.dtype == torch.long
    assert res.deepest_point.shape == (b, n_links, 3) and res.deepest_normal.shape == (b, n_links, 3)
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    for bi in range(b):
        T_world_obj = torch.linalg.inv(T_obj_world[bi])
        for si in range(s):
            T = link_poses[bi, sample_link[si]]
            p_world = T[:3, :3] @ pts[si] + T[:3, 3]
            p_obj = T_obj_world[bi, :3, :3] @ p_world + T_obj_world[bi, :3, 3]
            sd, _ = sdf_trilinear_with_grad(values, origin, voxel, p_obj[None, None])
            assert abs(res.sd[bi, si].item() - sd.item()) < tol
        for li in range(n_links):
            members = (sample_link == li).nonzero().flatten().tolist()
            if not members:
                assert res.deepest_value[bi, li].item() == math.inf and res.deepest_index[bi, li].item() == -1
                assert res.deepest_point[bi, li].abs().sum().item() == 0
                continue
            best = min(members, key=lambda k: (res.sd[bi, k].item(), k))
            assert res.deepest_index[bi, li].item() == best
            assert res.deepest_value[bi, li].item() == res.sd[bi, best].item()
            T = link_poses[bi, li]
            torch.testing.assert_close(res.deepest_point[bi, li], T[:3, :3] @ pts[best] + T[:3, 3])
            # the normal is the unit outward sphere normal, in world coordinates
            p_obj = torch.linalg.inv(T_world_obj) @ torch.cat([res.deepest_point[bi, li], torch.ones_like(pts[0, :1])])
            outward_obj = p_obj[:3] / p_obj[:3].norm()
            outward_world = T_world_obj[:3, :3] @ outward_obj
            assert res.deepest_normal[bi, li].norm().item() == pytest.approx(1.0, abs=1e-5)
            assert torch.dot(res.deepest_normal[bi, li], outward_world).item() > 0.97


def test_link_sample_penetration_values_follow_the_true_sphere_distance():
    values, origin, voxel = sphere_grid(voxel=0.002, n=41)
    link_poses, pts, sample_link, T_obj_world = make_case(3)
    res = link_sample_penetration(link_poses, pts, sample_link, T_obj_world, values, origin, voxel)
    p_world = (link_poses[:, sample_link, :3, :3] @ pts[..., None]).squeeze(-1) + link_poses[:, sample_link, :3, 3]
    p_obj = (T_obj_world[:, None, :3, :3] @ p_world[..., None]).squeeze(-1) + T_obj_world[:, None, :3, 3]
    true = p_obj.norm(dim=-1) - 0.03
    inside_box = (p_obj.abs() < 0.04).all(-1)
    assert inside_box.sum() > 20
    assert (res.sd - true)[inside_box].abs().max().item() < 0.5 * voxel  # trilinear interpolation of |x| - r


def test_link_sample_penetration_gradients_reach_the_link_poses():
    values, origin, voxel = sphere_grid()
    link_poses, pts, sample_link, T_obj_world = make_case(2)
    lp = link_poses.clone().requires_grad_(True)
    res = link_sample_penetration(lp, pts, sample_link, T_obj_world, values, origin, voxel)
    res.deepest_value[:, :-1].clamp(max=0).sum().backward()
    assert torch.isfinite(lp.grad).all()
    lp2 = link_poses.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(
        lambda x: link_sample_penetration(x, pts[:6], sample_link[:6], T_obj_world, values, origin, voxel).sd,
        (lp2,), eps=1e-7, atol=1e-6)


def test_link_sample_penetration_bad_input():
    values, origin, voxel = sphere_grid()
    link_poses, pts, sample_link, T_obj_world = make_case(2)
    with pytest.raises(ValueError, match="link_poses"):
        link_sample_penetration(link_poses[0], pts, sample_link, T_obj_world, values, origin, voxel)
    with pytest.raises(ValueError, match="sample_points"):
        link_sample_penetration(link_poses, pts[:, :2], sample_link, T_obj_world, values, origin, voxel)
    with pytest.raises(ValueError, match="sample_link"):
        link_sample_penetration(link_poses, pts, sample_link.int(), T_obj_world, values, origin, voxel)
    with pytest.raises(ValueError, match="T_obj_world"):
        link_sample_penetration(link_poses, pts, sample_link, T_obj_world[:1], values, origin, voxel)


# ---------------------------------------------------------------------------------------------------------------
# capsules


def brute_force_segment_distance(p1, q1, p2, q2, n=401):
    """Minimum distance between densely sampled segments (an upper bound of the exact distance)."""
    t = torch.linspace(0, 1, n, dtype=torch.float64)
    a = p1[:, None] + t[None, :, None] * (q1 - p1)[:, None]
    b = p2[:, None] + t[None, :, None] * (q2 - p2)[:, None]
    return torch.cdist(a, b, compute_mode="donot_use_mm_for_euclid_dist").amin(dim=(1, 2))


def special_segments(dtype=torch.float64):
    cases = [
        # p1, q1, p2, q2
        ([0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]),          # parallel, overlapping
        ([0, 0, 0], [1, 0, 0], [2, 1, 0], [3, 1, 0]),          # parallel, disjoint
        ([0, 0, 0], [1, 0, 0], [0.5, 0, 0], [2, 0, 0]),        # collinear, overlapping
        ([0, 0, 0], [1, 0, 0], [3, 0, 0], [4, 0, 0]),          # collinear, disjoint
        ([0, 0, 0], [0, 0, 0], [1, 1, 0], [1, -1, 0]),         # first degenerate
        ([0, 0, 0], [1, 0, 0], [0.3, 2, 0], [0.3, 2, 0]),      # second degenerate
        ([0, 0, 0], [0, 0, 0], [1, 2, 3], [1, 2, 3]),          # both degenerate
        ([0, 0, 0], [1, 0, 0], [0.5, -1, 0], [0.5, 1, 0]),     # crossing
        ([0, 0, 0], [1, 0, 0], [0.5, -1, 1], [0.5, 1, 1]),     # skew, interior closest points
        ([0, 0, 0], [1, 0, 0], [2, -1, 0], [2, 1, 0]),         # closest at an end
        ([0, 0, 0], [1, 0, 0], [1, 1e-9, 0], [2, 2e-9, 1e-9]), # nearly parallel, nearly touching
    ]
    arr = torch.tensor(cases, dtype=dtype) * 0.01
    return arr[:, 0], arr[:, 1], arr[:, 2], arr[:, 3]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["f32", "f64"])
def test_segment_segment_against_dense_sampling(dtype):
    g = torch.Generator().manual_seed(3)
    p1, q1, p2, q2 = (torch.rand(4, 200, 3, generator=g, dtype=torch.float64) * 0.04).unbind(0)
    sp = special_segments()
    p1, q1, p2, q2 = (torch.cat([a, b_]) for a, b_ in zip((p1, q1, p2, q2), sp))
    c1, c2 = closest_points_segment_segment(*(x.to(dtype) for x in (p1, q1, p2, q2)))
    ours = (c1 - c2).norm(dim=-1).double()
    brute = brute_force_segment_distance(p1, q1, p2, q2)
    seg = torch.maximum((q1 - p1).norm(dim=-1), (q2 - p2).norm(dim=-1))
    tol = 1e-6 if dtype == torch.float32 else 1e-12
    assert (ours <= brute + tol).all()                      # never above an actual pair distance
    assert (ours >= brute - seg / 400 - tol).all()          # dense sampling is within a step of the exact value
    # the closest points lie on their segments
    for c, p, q in ((c1, p1, q1), (c2, p2, q2)):
        d = (q - p).to(dtype)
        s = ((c - p.to(dtype)) * d).sum(-1) / (d * d).sum(-1).clamp_min(1e-30)
        assert ((s >= -1e-6) & (s <= 1 + 1e-6)).all()
        assert ((p.to(dtype) + s[:, None] * d - c).norm(dim=-1) < 10 * tol + 1e-9).all()


@pytest.mark.parametrize("b", [1, 7])
def test_capsule_interpenetration_shapes_and_values(b):
    g = torch.Generator().manual_seed(5)
    n_links = 6
    link_poses = random_poses((b, n_links), g, scale=0.02)
    a = torch.rand(n_links, 3, generator=g, dtype=torch.float64) * 0.01
    bb = a + torch.rand(n_links, 3, generator=g, dtype=torch.float64) * 0.03
    bb[2] = a[2]  # a sphere
    radius = torch.rand(n_links, generator=g, dtype=torch.float64) * 0.01 + 0.004
    pairs = torch.tensor([[0, 3], [1, 4], [2, 5], [0, 5], [2, 3]])
    res = capsule_interpenetration(link_poses, a, bb, radius, pairs)
    assert res.depth.shape == (b, 5) and res.point_i.shape == (b, 5, 3) and res.point_j.shape == (b, 5, 3)
    R, t = link_poses[..., :3, :3], link_poses[..., :3, 3]
    aw = (R @ a[..., None]).squeeze(-1) + t
    bw = (R @ bb[..., None]).squeeze(-1) + t
    for qi, (i, j) in enumerate(pairs.tolist()):
        brute = brute_force_segment_distance(aw[:, i], bw[:, i], aw[:, j], bw[:, j])
        expect = radius[i] + radius[j] - brute
        assert (res.depth[:, qi] >= expect - 1e-12).all() and (res.depth[:, qi] <= expect + 1e-4).all()
        torch.testing.assert_close((res.point_i[:, qi] - res.point_j[:, qi]).norm(dim=-1),
                                   radius[i] + radius[j] - res.depth[:, qi])


def test_capsule_interpenetration_gradients_are_finite_in_degenerate_cases():
    p1, q1, p2, q2 = special_segments()
    n = len(p1)
    # put each case's two segments on two links with identity poses
    link_poses = torch.eye(4, dtype=torch.float64).repeat(1, 2 * n, 1, 1).requires_grad_(True)
    a = torch.cat([p1, p2])
    b = torch.cat([q1, q2])
    radius = torch.full((2 * n,), 0.005, dtype=torch.float64)
    pairs = torch.stack([torch.arange(n), torch.arange(n) + n], -1)
    res = capsule_interpenetration(link_poses, a, b, radius, pairs)
    assert torch.isfinite(res.depth).all()
    res.depth.clamp(min=0).sum().backward()
    assert torch.isfinite(link_poses.grad).all()
    # crossing segments interpenetrate by the sum of the radii
    assert res.depth[0, 7].item() == pytest.approx(0.01)


def test_capsule_interpenetration_gradcheck():
    g = torch.Generator().manual_seed(8)
    link_poses = random_poses((2, 4), g, scale=0.02).requires_grad_(True)
    a = torch.rand(4, 3, generator=g, dtype=torch.float64) * 0.01
    b = a + 0.02
    radius = torch.full((4,), 0.006, dtype=torch.float64)
    pairs = torch.tensor([[0, 2], [1, 3]])
    assert torch.autograd.gradcheck(lambda x: capsule_interpenetration(x, a, b, radius, pairs).depth,
                                    (link_poses,), eps=1e-7, atol=1e-6)


def test_capsule_interpenetration_bad_input():
    link_poses = torch.eye(4, dtype=torch.float64).repeat(1, 3, 1, 1)
    a = torch.zeros(3, 3, dtype=torch.float64)
    r = torch.ones(3, dtype=torch.float64)
    pairs = torch.tensor([[0, 1]])
    with pytest.raises(ValueError, match="link_poses"):
        capsule_interpenetration(link_poses[0], a, a, r, pairs)
    with pytest.raises(ValueError, match="capsule_b"):
        capsule_interpenetration(link_poses, a, a[:2], r, pairs)
    with pytest.raises(ValueError, match="capsule_radius"):
        capsule_interpenetration(link_poses, a, a, r[:2], pairs)
    with pytest.raises(ValueError, match="pairs"):
        capsule_interpenetration(link_poses, a, a, r, pairs.float())


def test_sorted_samples_path_matches_general_path():
    """Hand models store samples link by link, which takes the per-link fast path; a shuffled copy of the same
    samples takes the general gather/scatter path. Both must give the same distances and deepest samples."""
    import trimesh

    from torchhand.hand import default_hand
    from torchhand.geometry.sdf import SDFGrid

    hand = default_hand(dtype=torch.float64)
    sdf = SDFGrid.from_mesh(trimesh.creation.box((0.08, 0.06, 0.05)), 0.002).to("cpu", torch.float64)
    gen = torch.Generator().manual_seed(3)
    B = 12
    q = hand.random_q(B, gen)
    root = torch.eye(4, dtype=torch.float64).expand(B, 4, 4).clone()
    root[:, :3, 3] = 0.04 * torch.randn(B, 3, generator=gen, dtype=torch.float64)
    poses = hand.forward_kinematics(q, root)
    T_inv = torch.eye(4, dtype=torch.float64).expand(B, 4, 4).clone()
    assert bool((hand.sample_link[1:] >= hand.sample_link[:-1]).all())
    perm = torch.randperm(hand.sample_link.numel(), generator=gen)
    fast = link_sample_penetration(poses, hand.sample_points, hand.sample_link, T_inv, sdf.values, sdf.origin,
                                   sdf.voxel_size, corners=sdf.corners)
    slow = link_sample_penetration(poses, hand.sample_points[perm], hand.sample_link[perm], T_inv, sdf.values,
                                   sdf.origin, sdf.voxel_size, corners=sdf.corners)
    assert (fast.deepest_value < 0).any(), "the poses should put some links inside the box"
    torch.testing.assert_close(fast.sd, slow.sd[:, torch.argsort(perm)])
    torch.testing.assert_close(fast.deepest_value, slow.deepest_value)
    torch.testing.assert_close(fast.deepest_point, slow.deepest_point)
    torch.testing.assert_close(fast.deepest_normal, slow.deepest_normal)
    assert torch.equal(perm[slow.deepest_index], fast.deepest_index)
