"""The captured object put on the table and held at rest within capture noise (torchhand.fill.object_rest)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch
import trimesh

from torchhand.errors import InputValueError
from torchhand.fill.object_rest import ObjectRest, steady_object, with_object
from torchhand.geometry.poses import quat_to_matrix
from torchhand.scene._contacts import environment_contacts

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"
MUG1 = DATA / "mocap" / "manipnet" / "mug1"
TABLE = 0.1


def _pose(axis, deg, pos):
    axis = torch.as_tensor(axis, dtype=torch.float64)
    axis = axis / axis.norm()
    a = math.radians(deg) / 2
    P = torch.eye(4, dtype=torch.float64)
    P[:3, :3] = quat_to_matrix(torch.cat([torch.tensor([math.cos(a)], dtype=torch.float64), math.sin(a) * axis]))
    P[:3, 3] = torch.as_tensor(pos, dtype=torch.float64)
    return P


def _box_track(seed=0, T=90):
    """A 6 x 4 x 8 cm box standing on the table for 30 frames (floating 3 mm, tilted 4 degrees, jittering 0.3 mm), then
    lifted 20 cm."""
    g = torch.Generator().manual_seed(seed)
    mesh = trimesh.creation.box((0.06, 0.04, 0.08))
    base = _pose([1.0, 0.3, 0.0], 4.0, [0.0, 0.0, TABLE + 0.04 + 0.003 + 0.06 * math.sin(math.radians(4)) / 2])
    poses = base.repeat(T, 1, 1)
    poses[:, :3, 3] += 3e-4 * torch.randn(T, 3, generator=g, dtype=torch.float64)
    lift = torch.clamp(torch.arange(T, dtype=torch.float64) - 40, min=0) / 50
    poses[:, 2, 3] += 0.2 * lift * lift * (3 - 2 * lift)
    return mesh, poses


def _lowest(poses, mesh):
    V = torch.as_tensor(mesh.convex_hull.vertices, dtype=torch.float64)
    return (torch.einsum("tj,nj->tn", poses[:, 2, :3], V) + poses[:, 2, 3, None]).min(-1).values


def test_a_standing_box_is_put_flat_on_the_table_and_held_still():
    mesh, poses = _box_track()
    adj = steady_object(poses, mesh, TABLE, 30.0)
    low = _lowest(adj.used, mesh)
    assert (low[:30] - TABLE).abs().max() < 1e-9                          # on the plane, not 3 mm above it
    up = adj.used[:30, :3, 2]                                              # the box's z axis: its base normal
    assert torch.rad2deg(torch.arccos(up[:, 2].clamp(-1, 1))).max() < 1e-3  # flat on its base
    assert adj.resting[:25].all() and not adj.resting[60:].any()
    step = (adj.used[1:25, :3, 3] - adj.used[:24, :3, 3]).norm(dim=-1)
    assert step.max() < 1e-12                                              # held: no jitter left
    assert torch.equal(adj.used[70:], poses[70:])                          # lifted: the capture as is
    z = adj.used[38:70, 2, 3]
    assert (z[1:] - z[:-1]).min() > -1e-4                                  # a lift is never pulled back down
    assert torch.equal(adj.used[46:], poses[46:])    # from 0.1 s into the lift on (gap 11 mm): the capture as is
    assert adj.rotation.max() <= math.radians(8.0) + 1e-9
    assert adj.translation[:30].max() < 0.01


def test_table_contacts_of_the_steadied_box_span_its_base_and_are_static():
    from torchhand.geometry.objects import RigidObject
    from torchhand.scene import Environment, HandTrack, Scene

    mesh, poses = _box_track()
    obj = RigidObject.from_trimesh(mesh, mass=0.2, name="box")
    wrist = _pose([0, 0, 1], 0, [0.0, -0.2, 0.3]).repeat(poses.shape[0], 1, 1)
    scene = Scene(name="box", object=obj, object_pose=poses, fps=30.0, hands=(HandTrack(side="right", wrist_pose=wrist),),
                  friction=0.8, environment=Environment(table=True, table_height=TABLE, friction=0.5))
    before = environment_contacts(scene)
    adj = steady_object(scene.object_pose, mesh, TABLE, scene.fps)
    moved = with_object(scene, adj.used)
    after = environment_contacts(moved)
    assert int(before.mask[:25].sum(-1).max()) < 4                        # tilted and floating: at most an edge
    assert (after.mask[:25].sum(-1) == 4).all()                           # the four base corners
    assert float(after.sliding_velocity[:25].abs().max()) == 0.0           # static
    assert torch.equal(moved.captured_object_pose, scene.object_pose)
    again = with_object(moved, adj.used)                                   # the capture stays the capture
    assert torch.equal(again.captured_object_pose, scene.object_pose)
    sub = moved.with_frames(10, 40)
    assert torch.equal(sub.captured_object_pose, scene.object_pose[10:40])


def test_far_from_the_table_or_without_one_nothing_changes():
    mesh, poses = _box_track()
    high = poses.clone()
    high[:, 2, 3] += 0.05
    adj = steady_object(high, mesh, TABLE, 30.0)
    assert torch.equal(adj.used, high) and not adj.resting.any()
    adj = steady_object(poses, mesh, None, 30.0)
    assert torch.equal(adj.used, poses)


def test_a_round_object_is_not_levelled_and_a_slow_drift_is_not_frozen():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.04)
    T = 60
    poses = torch.eye(4, dtype=torch.float64).repeat(T, 1, 1)
    poses[:, :3, :3] = _pose([1, 0, 0], 10.0, [0, 0, 0])[:3, :3]
    poses[:, 0, 3] = torch.linspace(0, 0.03, T, dtype=torch.float64)         # rolls 3 cm at 1.5 cm/s
    poses[:, 2, 3] = TABLE + 0.04 + 0.002
    adj = steady_object(poses, sphere, TABLE, 30.0)
    assert adj.rotation.max() < 1e-12                                     # no flat face: no levelling
    assert not adj.resting.any()                                         # drifts beyond the hold limit
    assert (_lowest(adj.used, sphere) - TABLE).abs().max() < 1e-9


def test_steadying_is_stable_under_tiny_perturbations():
    mesh, poses = _box_track()
    a = steady_object(poses, mesh, TABLE, 30.0)
    b = steady_object(poses + 1e-10 * torch.randn(poses.shape, generator=torch.Generator().manual_seed(3),
                                                   dtype=torch.float64), mesh, TABLE, 30.0)
    assert torch.equal(a.resting, b.resting)
    assert (a.used - b.used).abs().max() < 1e-8


def test_bad_settings_are_refused():
    with pytest.raises(InputValueError, match="far > near"):
        ObjectRest(near=0.02, far=0.01)
    with pytest.raises(InputValueError, match="rest_speed"):
        ObjectRest(rest_speed=-1.0)


@pytest.mark.skipif(not MUG1.is_dir(), reason="../shared/data/mocap/manipnet/mug1 is not present")
def test_manipnet_mug_rests_on_its_base_within_the_limits(tmp_path):
    from torchhand.scene.mocap import manipnet_scene

    scene = manipnet_scene(MUG1, fps=30.0, hands=("right",))
    adj = steady_object(scene.object_pose, scene.object.mesh, scene.environment.table_height, scene.fps)
    before = environment_contacts(scene)
    after = environment_contacts(with_object(scene, adj.used))
    free = slice(0, 40)                                                    # the hand 15-20 cm away
    assert int(before.mask[free].sum(-1).min()) >= 0
    assert float(before.sliding_velocity[free].norm(dim=-1).max()) > 0.002  # the capture jitters ...
    assert float(after.sliding_velocity[free].norm(dim=-1).max()) == 0.0    # ... the used track rests
    assert int(after.mask[free].sum(-1).min()) >= 8                          # on its rim, not on a point
    assert adj.translation.max() < 0.015 and adj.rotation.max() <= math.radians(8.0) + 1e-9
    lifted = _lowest(scene.object_pose, scene.object.mesh) - scene.environment.table_height > 0.02
    assert torch.equal(adj.used[lifted], scene.object_pose[lifted].double())


@pytest.mark.skipif(not MUG1.is_dir(), reason="../shared/data/mocap/manipnet/mug1 is not present")
def test_prepare_capture_steadies_the_object_unless_asked_not_to_and_scenes_keep_the_capture(tmp_path):
    from torchhand.fill.prepare import prepare_capture
    from torchhand.scene import load_scene
    from torchhand.scene.mocap import manipnet_scene

    scene = manipnet_scene(MUG1, fps=30.0, hands=("right",)).with_frames(0, 120)
    kept = prepare_capture(scene, object_rest=None)
    assert kept.object is None and kept.scene.captured_object_pose is None
    assert torch.equal(kept.scene.object_pose, scene.object_pose)
    moved = prepare_capture(scene)
    assert moved.object is not None and moved.to_json()["object_deviation"]["frames_resting"] > 0
    assert torch.equal(moved.scene.captured_object_pose, scene.object_pose)
    assert "object moved by" in moved.describe()
    moved.scene.export(tmp_path / "s")
    back = load_scene(tmp_path / "s")
    torch.testing.assert_close(back.captured_object_pose, scene.object_pose, rtol=0, atol=1e-12)
    torch.testing.assert_close(back.object_pose, moved.scene.object_pose, rtol=0, atol=1e-12)
