"""A table with an edge and a floor: the synthesis' Ground, the checker's own geometry against trimesh's exact
distances, environment contacts on two supports, scene files, and the methods that refuse such a scene."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from torchhand.check.ground import environment_capsule_depth, environment_point_depth, support_gap
from torchhand.errors import FileFormatError, InputValueError
from torchhand.geometry.ground import Ground
from torchhand.scene import Environment, environment_contacts, load_scene
from torchhand.scene.builtin import builtin_scene

EXTENT = (-0.6, 0.6, -0.6, 0.2)
TOP = 0.75
ENV = Environment(table=True, table_height=TOP, friction=0.4, table_extent=EXTENT, floor=True, floor_height=0.0)


def _box_mesh() -> trimesh.Trimesh:
    """The table block as a closed mesh, reaching far below the floor (the block's sides, exactly, near it)."""
    return trimesh.creation.box(bounds=[[EXTENT[0], EXTENT[2], -5.0], [EXTENT[1], EXTENT[3], TOP]])


def _exact_depth(p: np.ndarray) -> np.ndarray:
    """Depth in the table block (trimesh, exact, positive inside) or under the floor, whichever is deeper."""
    return np.maximum(trimesh.proximity.signed_distance(_box_mesh(), p), 0.0 - p[:, 2])


def _points(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform([-0.9, -0.9, -0.1], [0.9, 0.5, 1.0], size=(n, 3))


def test_point_depth_matches_trimesh():
    p = _points(2000, 0)
    exact = _exact_depth(p)
    ours = environment_point_depth(ENV, p)
    sd, _ = ENV.ground().point_distance(torch.as_tensor(p))
    np.testing.assert_allclose(ours, exact, atol=1e-9)
    np.testing.assert_allclose(-sd.numpy(), exact, atol=1e-9)


def test_point_normal_is_the_gradient():
    p = torch.as_tensor(_points(500, 1))
    g = ENV.ground()
    sd, n = g.point_distance(p)
    h = 1e-6
    for axis in range(3):
        e = torch.zeros(3, dtype=p.dtype)
        e[axis] = h
        fd = (g.point_distance(p + e)[0] - g.point_distance(p - e)[0]) / (2 * h)
        # away from the medial surfaces (where the nearest face changes) the normal is the gradient
        ok = (fd - n[:, axis]).abs() < 1e-4
        assert ok.float().mean() > 0.97


def _capsules(n: int, seed: int):
    rng = np.random.default_rng(seed)
    a = _points(n, seed)
    b = a + rng.normal(size=(n, 3)) * 0.04
    r = rng.uniform(0.005, 0.012, size=n)
    return a, b, r


def test_capsule_depth_matches_dense_sampling():
    a, b, r = _capsules(300, 2)
    u = np.linspace(0.0, 1.0, 2001)
    pts = a[:, None] + u[None, :, None] * (b - a)[:, None]                        # (n, 2001, 3)
    dense = r + _exact_depth(pts.reshape(-1, 3)).reshape(len(a), -1).max(1)
    # a sample spacing of 2e-5 m bounds the sampling's shortfall (the distance is 1-Lipschitz along the axis)
    ours = environment_capsule_depth(ENV, a, b, r)
    d, point, _ = ENV.ground().capsule_depth(torch.as_tensor(a), torch.as_tensor(b), torch.as_tensor(r))
    inside = dense > -0.02
    assert inside.sum() > 50
    np.testing.assert_allclose(ours[inside], dense[inside], atol=3e-5)
    np.testing.assert_allclose(d.numpy()[inside], ours[inside], atol=1e-9)
    # the deepest axis point lies on the axis and is as deep as the capsule
    seg = b - a
    s = ((point.numpy() - a) * seg).sum(-1) / (seg * seg).sum(-1)
    np.testing.assert_allclose(point.numpy(), a + s[:, None] * seg, atol=1e-12)
    np.testing.assert_allclose(r - (-environment_point_depth(ENV, point.numpy())), ours, atol=1e-9)


def test_a_capsule_beside_the_table_below_its_top_is_clear():
    """Beyond the table's edge a hand may go below the top (the plane of a table without an edge would not allow
    it); against the block's side it may not."""
    a = np.array([[0.0, 0.25, 0.3], [0.0, 0.21, 0.3], [0.0, 0.19, 0.3]])
    b = a + np.array([0.0, 0.0, 0.04])
    r = np.full(3, 0.01)
    depth = environment_capsule_depth(ENV, a, b, r)
    np.testing.assert_allclose(depth, [-0.04, 0.0, 0.02], atol=1e-12)
    plane = Environment(table=True, table_height=TOP)
    assert (environment_capsule_depth(plane, a, b, r) > 0.4).all()
    d, _, n = ENV.ground().capsule_depth(*(torch.as_tensor(x) for x in (a, b, r)))
    np.testing.assert_allclose(d.numpy(), depth, atol=1e-9)
    np.testing.assert_allclose(n[2].numpy(), [0.0, 1.0, 0.0], atol=1e-12)   # the side face's outward normal


def test_support_heights():
    p = np.array([[0.0, 0.0, 0.76], [0.0, 0.3, 0.01], [0.7, 0.0, 0.02]])
    np.testing.assert_allclose(support_gap(ENV, p), [0.01, 0.01, 0.02])
    np.testing.assert_allclose(ENV.ground().support_height(torch.as_tensor(p)).numpy(), [TOP, 0.0, 0.0])
    assert np.isinf(support_gap(Environment(), p)).all()


def test_environment_checks_its_fields():
    with pytest.raises(InputValueError, match="floor needs a table with a table_extent"):
        Environment(table=True, table_height=TOP, floor=True)
    with pytest.raises(InputValueError, match="below the table top"):
        Environment(table=True, table_height=TOP, table_extent=EXTENT, floor=True, floor_height=1.0)
    with pytest.raises(InputValueError, match="x_min < x_max"):
        Environment(table=True, table_height=TOP, table_extent=(0.6, -0.6, 0.0, 1.0))
    with pytest.raises(InputValueError, match="table_extent"):
        Environment(table=True, table_height=TOP, table_extent=(0.0, 1.0))
    assert Environment(floor=True, floor_height=0.0).ground() == Ground(floor_height=0.0)
    assert Environment(table=True).plain and not ENV.plain


def test_box_carry_rests_on_the_table_then_on_the_floor():
    scene = builtin_scene("box-carry")
    env = environment_contacts(scene)
    count = env.mask.sum(-1)
    assert count[0] == 4 and count[-1] == 4 and count[40:100].sum() == 0
    assert torch.allclose(env.points[0][env.mask[0]][:, 2], torch.tensor(TOP, dtype=torch.float64))
    assert torch.allclose(env.points[-1][env.mask[-1]][:, 2], torch.zeros(4, dtype=torch.float64))
    # the box never enters the table block nor the floor
    V = torch.as_tensor(np.asarray(scene.object.mesh.vertices))
    P = torch.einsum("tij,nj->tni", scene.object_pose[:, :3, :3], V) + scene.object_pose[:, None, :3, 3]
    assert environment_point_depth(scene.environment, P.numpy()).max() < 1e-9
    # and the wrists stay out of the table block while the box is carried below its top
    W = torch.stack([h.wrist_pose[:, :3, 3] for h in scene.hands])
    assert environment_point_depth(scene.environment, W.numpy()).max() < -0.02


def test_scene_files_keep_the_edge_and_the_floor(tmp_path):
    scene = builtin_scene("box-carry")
    scene.export(tmp_path / "carry")
    back = load_scene(tmp_path / "carry")
    assert back.environment == scene.environment
    # a scene without them writes neither key
    builtin_scene("box-turn").export(tmp_path / "turn")
    text = (tmp_path / "turn" / "scene.toml").read_text()
    assert "floor" not in text and "table_extent" not in text


def test_a_bad_edge_in_a_scene_file_is_named(tmp_path):
    builtin_scene("box-carry").export(tmp_path / "carry")
    toml = tmp_path / "carry" / "scene.toml"
    toml.write_text(toml.read_text().replace("floor_height = 0.0", "floor_height = 2.0"))
    with pytest.raises(FileFormatError, match="environment.*floor_height"):
        load_scene(tmp_path / "carry")


def test_a_floor_is_refused_by_name():
    with pytest.raises(InputValueError, match="manipulation: .*table edge or a floor"):
        ENV.require_plain("manipulation")
    Environment(table=True, table_height=TOP).require_plain("manipulation")


def test_exported_files_show_the_table_block_and_the_floor():
    from torchhand.export.gltf import _environment_boxes

    boxes = dict(_environment_boxes(ENV, np.array([-0.3, -0.2]), np.array([0.3, 0.9])))
    np.testing.assert_allclose(boxes["table"], [[-0.6, -0.6, 0.0], [0.6, 0.2, TOP]])
    floor = np.asarray(boxes["floor"])
    assert floor[1, 2] == 0.0 and (floor[0, :2] <= [-0.6, -0.6]).all() and (floor[1, :2] >= [0.6, 0.9]).all()
    plain = dict(_environment_boxes(Environment(table=True, table_height=TOP), np.zeros(2), np.ones(2)))
    assert list(plain) == ["table"] and plain["table"][1][2] == TOP


def test_reconstruction_keeps_fingers_out_of_the_table_side():
    """A free little finger reaches 4 mm through the side of a table block whose top is far above the hand: the
    collision rounds push it out along the side's normal (a table plane's +z would not), the contacts kept."""
    import torchhand
    from torchhand.synthesis.reconstruct import reconstruct_motion
    from torchhand.synthesis.reconstruct_bounds import ground_capsule_depth

    from .test_reconstruct import searched_motion

    hand = torchhand.default_hand("right")
    root, _, q_search, contacts = searched_motion(hand, 30, seed=1)
    ground = Ground(table_height=1.0, table_extent=(-1.0, 1.0, -1.0, -0.0598))
    before = ground_capsule_depth(ground, hand, hand.forward_kinematics(q_search, root))[0]
    little = hand.link_names.index("little_distal")
    assert float(before[:, little].max()) > 0.003
    res = reconstruct_motion(hand, root, q_search, contacts, ground=ground)
    poses = hand.forward_kinematics(res.q, root)
    after = ground_capsule_depth(ground, hand, poses)[0]
    assert float(after.max()) <= 1e-3 and float(res.contact_error.max()) <= 1e-3
    # the checker's own geometry agrees
    R, o = poses[..., :3, :3].numpy(), poses[..., :3, 3].numpy()
    a = (R @ hand.capsule_a.numpy()[..., None])[..., 0] + o
    b = (R @ hand.capsule_b.numpy()[..., None])[..., 0] + o
    env = Environment(table=True, table_height=1.0, table_extent=(-1.0, 1.0, -1.0, -0.0598))
    np.testing.assert_allclose(environment_capsule_depth(env, a, b, hand.capsule_radius.numpy()), after.numpy(),
                               atol=1e-9)


def test_the_node_test_measures_depth_in_the_ground():
    from types import SimpleNamespace

    import torchhand
    from torchhand.synthesis._node_geometry import table_depth

    hand = torchhand.default_hand("right")
    poses = hand.forward_kinematics(hand.q_rest[None].repeat(2, 1), torch.eye(4, dtype=torch.float64).repeat(2, 1, 1))
    ground = Ground(table_height=0.0, table_extent=(-1.0, 1.0, -1.0, -0.05), floor_height=-0.5)
    got = table_depth(SimpleNamespace(ground=ground, table_height=None), hand, poses)
    R, o = poses[..., :3, :3].numpy(), poses[..., :3, 3].numpy()
    a = (R @ hand.capsule_a.numpy()[..., None])[..., 0] + o
    b = (R @ hand.capsule_b.numpy()[..., None])[..., 0] + o
    env = Environment(table=True, table_height=0.0, table_extent=(-1.0, 1.0, -1.0, -0.05), floor=True,
                      floor_height=-0.5)
    want = environment_capsule_depth(env, a, b, hand.capsule_radius.numpy())
    np.testing.assert_allclose(got.numpy(), want, atol=1e-9)
    assert (want > 0).any() and (want < 0).any()
    plain = table_depth(SimpleNamespace(ground=None, table_height=0.0), hand, poses)
    assert (plain.numpy() >= want - 1e-12).all()   # the plane under the whole hand reaches at least as deep
