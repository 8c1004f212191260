"""Scenes: built-in scenes, environment contacts, export/load round trip, editing, and bad input at load."""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial.transform import Rotation, Slerp

from torchhand.conventions import check_transforms
from torchhand.errors import (FileFormatError, InputValueError, MissingFileError, ShapeError, TorchhandError,
                              UnknownNameError)
from torchhand.scene import (Environment, HandTrack, Scene, environment_contacts, interpolate_poses, load_scene)
from torchhand.scene.builtin import builtin_scene, builtin_scene_description, list_builtin_scenes
from torchhand.scene.builtin.ye_liu import PALM_CENTRE, make_mug_mesh

REQUIRED = ("box-turn", "box-pickup", "bottle-turn", "mug-pickup", "two-hand-box", "handle-lift", "handle-lift-palm")
TAKING_TURNS = ("box-alternate", "cup-spin")   # hands not rigid with the object through one hold: one hand at a
#                                                time (test_box_alternate_hands_take_turns), a still hand over a
#                                                spinning cup (test_cup_spin_turns_under_a_still_hand)
ONTO_THE_FLOOR = ("box-carry",)   # ends on the floor, not the table (tests/torchhand/test_ground.py)


@pytest.fixture(scope="module")
def scenes():
    """The scenes these tests look at (the liu-* scenes have tests of their own; liu-shadow-lift needs the shared
    reference data)."""
    return {n: builtin_scene(n) for n in REQUIRED + TAKING_TURNS + ONTO_THE_FLOOR}


def world_vertices(scene: Scene) -> torch.Tensor:
    V = torch.as_tensor(np.asarray(scene.object.mesh.vertices), dtype=torch.float64)
    P = scene.object_pose
    return torch.einsum("tij,nj->tni", P[:, :3, :3], V) + P[:, None, :3, 3]


def hold_frames(scene: Scene) -> torch.Tensor:
    """Frames where every wrist is rigidly attached to the object (relative pose equal to the middle frame's)."""
    rel = [torch.linalg.inv(scene.object_pose) @ h.wrist_pose for h in scene.hands]
    mid = scene.T // 2
    return torch.stack([(r - r[mid]).abs().amax(dim=(-1, -2)) < 1e-9 for r in rel]).all(0)


# ---------------------------------------------------------------------------------------------------------------
# built-in scenes


def test_builtin_names():
    names = list_builtin_scenes()
    assert len(names) >= 5
    assert set(REQUIRED) <= set(names)
    for n in names:
        assert builtin_scene_description(n)
    with pytest.raises(UnknownNameError, match="box-turn"):
        builtin_scene("no-such-scene")


@pytest.mark.parametrize("name", REQUIRED + TAKING_TURNS + ONTO_THE_FLOOR)
def test_builtin_scene_is_valid(scenes, name):
    s = scenes[name]
    s.validate()
    assert s.name == name and s.description
    assert 45 <= s.T <= (140 if name == "cup-spin" else 120) and s.fps == 30.0
    assert s.object_pose.dtype == torch.float64 and s.object_pose.shape == (s.T, 4, 4)
    check_transforms(s.object_pose, "object_pose")
    for h in s.hands:
        assert h.wrist_pose.shape == (s.T, 4, 4) and h.wrist_pose.dtype == torch.float64
        check_transforms(h.wrist_pose, "wrist_pose")
    assert s.environment.table
    assert s.object.mass > 0 and s.object.watertight
    # objects rest ON the table (box-carry: the floor at the end) at the start and the end, and never go below it
    P = world_vertices(s)
    z = (P[..., 2] - s.environment.ground().support_height(P)).amin(dim=-1)
    assert abs(float(z[0])) < 1e-6 and abs(float(z[-1])) < 1e-6
    assert float(z.min()) > -1e-6


@pytest.mark.parametrize("name", REQUIRED)
def test_builtin_wrists_hold_the_object(scenes, name):
    s = scenes[name]
    hold = hold_frames(s)
    assert int(hold.sum()) >= s.T // 2  # the wrist moves rigidly with the object while held
    assert not bool(hold[0]) and not bool(hold[-1])  # short approach and retreat
    query = trimesh.proximity.ProximityQuery(s.object.mesh)
    palm = torch.tensor(np.append(PALM_CENTRE, 1.0))
    for h in s.hands:
        rel = torch.linalg.inv(s.object_pose) @ h.wrist_pose  # hand in object frame
        pc = (rel @ palm)[:, :3].numpy()
        dist = -query.signed_distance(pc)  # trimesh: positive inside
        assert (dist > 0).all(), "the palm never penetrates the object"
        assert dist[hold.numpy()].max() < 0.04, "palm near the object while holding"
        assert dist.max() < 0.1, "approach and retreat stay short"
        # palm faces the object: the closest surface point lies on the palm side (-z of the hand frame)
        closest, _, _ = query.on_surface(pc)
        to_obj = torch.linalg.inv(rel)[:, :3, :3] @ torch.as_tensor(closest - pc)[..., None]
        assert (to_obj[hold, 2, 0] < 0).all()
        # the middle frame: fingers (hand length) reach the object from the wrist
        wrist_in_obj = rel[s.T // 2, :3, 3].numpy()
        assert -query.signed_distance(wrist_in_obj[None])[0] < h.length


def test_builtin_scene_sides_and_determinism(scenes):
    assert scenes["two-hand-box"].sides == ("right", "left")
    for n in REQUIRED[:4]:
        assert scenes[n].sides == ("right",)
    again = builtin_scene("box-turn")
    assert torch.equal(again.object_pose, scenes["box-turn"].object_pose)
    assert torch.equal(again.hands[0].wrist_pose, scenes["box-turn"].hands[0].wrist_pose)
    assert again.object.content_hash() == scenes["box-turn"].object.content_hash()


def test_mug_mesh_is_watertight_with_handle():
    mesh = make_mug_mesh()
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    lo, hi = mesh.bounds
    assert lo[2] == pytest.approx(0.0) and hi[2] == pytest.approx(0.095)
    assert hi[1] > 0.06  # the handle sticks out toward +y
    assert mesh.contains([[0.0, 0.065, 0.049]])[0]  # a point in the handle
    assert not mesh.contains([[0.0, 0.0, 0.05]])[0]  # the cup is hollow


# ---------------------------------------------------------------------------------------------------------------
# environment contacts


def test_env_contacts_box_at_rest_and_lifted(scenes):
    s = scenes["box-pickup"]
    ec = environment_contacts(s)
    assert ec.points.shape[:2] == ec.mask.shape == ec.sliding_velocity.shape[:2] == ec.support_index.shape
    assert ec.points.shape[0] == s.T
    assert int(ec.count[0]) == 4 and int(ec.count[-1]) == 4
    pts = ec.points[0][ec.mask[0]]
    assert torch.allclose(pts[:, 2], torch.full((4,), s.environment.table_height, dtype=torch.float64))
    corners = sorted(map(tuple, np.round(pts[:, :2].numpy(), 6).tolist()))
    assert corners == [(-0.035, -0.035), (-0.035, 0.035), (0.035, -0.035), (0.035, 0.035)]
    assert torch.equal(ec.sliding_velocity[0], torch.zeros_like(ec.sliding_velocity[0]))
    lifted = world_vertices(s)[..., 2].amin(-1) > s.environment.table_height + 0.01
    assert bool(lifted.any())
    assert (ec.count[lifted] == 0).all()
    assert torch.equal(ec.normal, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
    assert (ec.support_index[~ec.mask] == -1).all()


def test_env_contacts_sliding_turn(scenes):
    s = scenes["box-turn"]
    ec = environment_contacts(s)
    assert (ec.count == 4).all()
    speed = ec.sliding_velocity.norm(dim=-1)
    assert float(speed.max()) > 0.01  # the box slides while it is turned
    assert float(ec.sliding_velocity[..., 2].abs().max()) == 0.0
    # agrees with omega x r (central differences of a smooth rotation)
    k = s.T // 2
    R = s.object_pose[:, :3, :3]
    theta = torch.atan2(R[:, 1, 0], R[:, 0, 0])
    omega = float(theta[k + 1] - theta[k - 1]) * s.fps / 2
    r = ec.points[k, :, :2] - s.object_pose[k, :2, 3]
    expected = omega * torch.stack([-r[:, 1], r[:, 0]], dim=-1)
    assert torch.allclose(ec.sliding_velocity[k, :, :2], expected, atol=2e-3)
    # static at the start (before the turn)
    assert float(speed[0].max()) == 0.0


def test_env_contacts_without_table(scenes):
    s = dataclasses.replace(scenes["box-turn"], environment=Environment(table=False))
    ec = environment_contacts(s)
    assert ec.points.shape == (s.T, 0, 3) and ec.mask.shape == (s.T, 0)


# ---------------------------------------------------------------------------------------------------------------
# export / load round trip


def assert_same_scene(a: Scene, b: Scene):
    assert a.name == b.name and a.description == b.description
    assert a.fps == b.fps and a.friction == b.friction and a.T == b.T
    assert a.environment == b.environment
    assert torch.equal(a.gravity, b.gravity)
    assert torch.equal(a.object_pose, b.object_pose)
    assert (a.external_wrench is None) == (b.external_wrench is None)
    assert a.external_wrench is None or torch.equal(a.external_wrench, b.external_wrench)
    assert a.sides == b.sides
    for ha, hb in zip(a.hands, b.hands):
        assert ha.length == hb.length and torch.equal(ha.wrist_pose, hb.wrist_pose)
    assert a.object.name == b.object.name and a.object.mass == pytest.approx(b.object.mass, rel=1e-12)
    np.testing.assert_allclose(b.object.mesh.vertices, a.object.mesh.vertices, atol=1e-11)
    np.testing.assert_array_equal(b.object.mesh.faces, a.object.mesh.faces)
    np.testing.assert_allclose(b.object.com, a.object.com, atol=1e-9)
    np.testing.assert_allclose(b.object.inertia, a.object.inertia, atol=1e-9)


@pytest.mark.parametrize("name", ["box-turn", "two-hand-box", "mug-pickup"])
def test_export_load_round_trip(scenes, tmp_path, name):
    out = scenes[name].export(tmp_path / "scene")
    assert sorted(p.name for p in out.iterdir()) == ["object.obj", "scene.toml", "trajectories.npz"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")], "temporary directory removed"
    loaded = load_scene(out)
    assert_same_scene(scenes[name], loaded)
    assert_same_scene(scenes[name], load_scene(out / "scene.toml"))
    assert_same_scene(scenes[name], load_scene(str(out)))


def test_load_builtin_by_name():
    s = load_scene("bottle-turn")
    assert s.name == "bottle-turn"


def test_export_refuses_to_overwrite_and_keeps_files(scenes, tmp_path):
    out = scenes["box-turn"].export(tmp_path / "s")
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    with pytest.raises(InputValueError, match="overwrite"):
        scenes["box-pickup"].export(out)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    scenes["box-pickup"].export(out, overwrite=True)
    assert load_scene(out).name == "box-pickup"


def test_export_failure_leaves_existing_files(scenes, tmp_path, monkeypatch):
    out = scenes["box-turn"].export(tmp_path / "s")
    (out / "notes.txt").write_text("mine")
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def boom(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez", boom)
    with pytest.raises(InputValueError, match="disk full"):
        scenes["box-pickup"].export(out, overwrite=True)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s"]


# ---------------------------------------------------------------------------------------------------------------
# editing: frame ranges and resampling


def test_with_frames(scenes):
    s = scenes["box-pickup"]
    sub = s.with_frames(5, 20)
    assert sub.T == 15 and torch.equal(sub.object_pose, s.object_pose[5:20])
    assert torch.equal(sub.hands[0].wrist_pose, s.hands[0].wrist_pose[5:20])
    for bad in [(-1, 5), (5, 5), (10, 5), (0, s.T + 1)]:
        with pytest.raises(InputValueError):
            s.with_frames(*bad)
    with pytest.raises(TorchhandError):
        s.with_frames(0.5, 3)


def test_resample_up_and_down(scenes):
    s = scenes["box-turn"]
    up = s.resample(60.0)
    assert up.fps == 60.0 and up.T == 2 * s.T - 1
    assert up.duration == pytest.approx(s.duration)
    torch.testing.assert_close(up.object_pose[::2], s.object_pose, atol=1e-12, rtol=0)
    torch.testing.assert_close(up.hands[0].wrist_pose[::2], s.hands[0].wrist_pose, atol=1e-12, rtol=0)
    # rotation about z: the midpoint has the mean yaw
    yaw = lambda P: torch.atan2(P[:, 1, 0], P[:, 0, 0])  # noqa: E731
    mid = 0.5 * (yaw(s.object_pose)[:-1] + yaw(s.object_pose)[1:])
    torch.testing.assert_close(yaw(up.object_pose)[1::2], mid, atol=1e-12, rtol=0)
    check_transforms(up.hands[0].wrist_pose, "resampled")
    down = s.resample(15.0)
    assert down.T == (s.T - 1) // 2 + 1
    torch.testing.assert_close(down.object_pose, s.object_pose[::2][: down.T], atol=1e-12, rtol=0)
    with pytest.raises(InputValueError):
        s.resample(0.0)


def test_interpolate_poses_matches_scipy_slerp():
    g = torch.Generator().manual_seed(3)
    T = 6
    q = torch.randn(T, 4, generator=g, dtype=torch.float64)
    q = q / q.norm(dim=-1, keepdim=True)
    R = Rotation.from_quat(q[:, [1, 2, 3, 0]].numpy())  # scipy is xyzw
    poses = torch.zeros(T, 4, 4, dtype=torch.float64)
    poses[:, :3, :3] = torch.as_tensor(R.as_matrix())
    poses[:, :3, 3] = torch.randn(T, 3, generator=g, dtype=torch.float64)
    poses[:, 3, 3] = 1
    times = torch.arange(T, dtype=torch.float64) * 0.5
    new = torch.rand(7, generator=g, dtype=torch.float64) * 2.5
    out = interpolate_poses(poses, times, new)
    ref = Slerp(times.numpy(), R)(new.numpy()).as_matrix()
    np.testing.assert_allclose(out[:, :3, :3].numpy(), ref, atol=1e-10)
    lin = np.stack([np.interp(new.numpy(), times.numpy(), poses[:, i, 3].numpy()) for i in range(3)], -1)
    np.testing.assert_allclose(out[:, :3, 3].numpy(), lin, atol=1e-12)


# ---------------------------------------------------------------------------------------------------------------
# construction checks


def test_scene_constructor_checks(scenes):
    s = scenes["two-hand-box"]
    with pytest.raises(ShapeError, match="wrist_pose"):
        dataclasses.replace(s, hands=(HandTrack("right", s.hands[0].wrist_pose[:-1]),))
    with pytest.raises(InputValueError, match="distinct"):
        dataclasses.replace(s, hands=(s.hands[0], s.hands[0]))
    with pytest.raises(InputValueError, match="1 or 2"):
        dataclasses.replace(s, hands=())
    with pytest.raises(InputValueError, match="fps"):
        dataclasses.replace(s, fps=0.0)
    with pytest.raises(InputValueError, match="friction"):
        dataclasses.replace(s, friction=-0.1)
    with pytest.raises(InputValueError, match="side"):
        HandTrack("middle", s.hands[0].wrist_pose)
    with pytest.raises(ShapeError):
        dataclasses.replace(s, object_pose=s.object_pose[:, :3])
    bad = s.object_pose.clone()
    bad[3, 0, 0] = float("nan")
    with pytest.raises(InputValueError, match="object_pose"):
        dataclasses.replace(s, object_pose=bad).validate()
    assert s.dt == pytest.approx(1 / 30) and s.duration == pytest.approx((s.T - 1) / 30)
    with pytest.raises(UnknownNameError):
        scenes["box-turn"].hand("left")


# ---------------------------------------------------------------------------------------------------------------
# bad input at load


@pytest.fixture
def scene_dir(scenes, tmp_path) -> Path:
    return scenes["two-hand-box"].export(tmp_path / "scene")


def edit_npz(path: Path, key: str, fn) -> None:
    with np.load(path / "trajectories.npz") as data:
        arrays = {k: data[k] for k in data.files}
    arrays[key] = fn(arrays[key])
    np.savez(path / "trajectories.npz", **arrays)


def edit_toml(path: Path, old: str, new: str) -> None:
    text = (path / "scene.toml").read_text()
    assert old in text
    (path / "scene.toml").write_text(text.replace(old, new, 1))


def test_load_nan_trajectory(scene_dir):
    def nan(a):
        a = a.copy()
        a[7, 1, 3] = np.nan
        return a

    edit_npz(scene_dir, "object_pose", nan)
    with pytest.raises(InputValueError, match=r"trajectories\.npz: object_pose.*NaN"):
        load_scene(scene_dir)


def test_load_non_orthonormal_rotation(scene_dir):
    def stretch(a):
        a = a.copy()
        a[4, :3, :3] *= 1.1
        return a

    edit_npz(scene_dir, "wrist_pose_left", stretch)
    with pytest.raises(InputValueError, match=r"wrist_pose_left.*\(4,\).*not rigid"):
        load_scene(scene_dir)


def test_load_wrong_shape(scene_dir):
    edit_npz(scene_dir, "wrist_pose_right", lambda a: a[:, :3, :])
    with pytest.raises(ShapeError, match=r"wrist_pose_right.*\(T, 4, 4\)"):
        load_scene(scene_dir)


def test_load_frame_count_mismatch(scene_dir):
    edit_npz(scene_dir, "wrist_pose_right", lambda a: a[:-2])
    with pytest.raises(ShapeError, match="wrist_pose_right"):
        load_scene(scene_dir)


def test_load_missing_wrist_array(scene_dir):
    with np.load(scene_dir / "trajectories.npz") as data:
        arrays = {k: data[k] for k in data.files if k != "wrist_pose_left"}
    np.savez(scene_dir / "trajectories.npz", **arrays)
    with pytest.raises(FileFormatError, match="wrist_pose_left"):
        load_scene(scene_dir)


def test_load_corrupt_npz(scene_dir):
    (scene_dir / "trajectories.npz").write_bytes(b"not a zip file")
    with pytest.raises(FileFormatError, match="trajectories.npz"):
        load_scene(scene_dir)


def test_load_malformed_toml(scene_dir):
    edit_toml(scene_dir, "fps = 30.0", "fps = = 30")
    with pytest.raises(FileFormatError, match=r"scene\.toml: malformed TOML.*line \d+, column \d+"):
        load_scene(scene_dir)


@pytest.mark.parametrize("old,new,error,fragment", [
    ("fps = 30.0", "fps = -1.0", InputValueError, "scene.fps"),
    ("fps = 30.0", 'fps = "fast"', FileFormatError, "scene.fps"),
    ("fps = 30.0\n", "", FileFormatError, "missing field scene.fps"),
    ("friction = 0.8", "friction = -0.2", InputValueError, "scene.friction"),
    ("mass = 1.0", "mass = 0.0", InputValueError, "object.mass"),
    ("mass = 1.0", "mass = 1.0\ndensity = 3.0", FileFormatError, "object.density"),
    ("format_version = 2", "format_version = 3", FileFormatError, "format_version 3"),
    ("[environment]", "[environment]\ncolour = 1", FileFormatError, "colour"),
    ('side = "left"', 'side = "right"', InputValueError, "distinct"),
    ('side = "left"', 'side = "middle"', InputValueError, "hands[1].side"),
    ("friction = 0.4", "friction = -1.0", InputValueError, "environment.friction"),
    ('mesh = "object.obj"', 'mesh = "missing.obj"', MissingFileError, "missing.obj"),
])
def test_load_bad_fields(scene_dir, old, new, error, fragment):
    edit_toml(scene_dir, old, new)
    with pytest.raises(error) as info:
        load_scene(scene_dir)
    assert fragment in str(info.value)
    if error is not MissingFileError:
        assert "scene.toml" in str(info.value)


def test_load_missing_and_unknown(tmp_path):
    with pytest.raises(UnknownNameError) as info:
        load_scene("box-twist")
    for n in REQUIRED:
        assert n in str(info.value)
    with pytest.raises(MissingFileError):
        load_scene(tmp_path / "nowhere")
    with pytest.raises(MissingFileError, match="scene.toml"):
        load_scene(tmp_path)  # a directory without scene.toml
    with pytest.raises(MissingFileError):
        load_scene("./nowhere/at/all")


def test_gravity_and_description_round_trip(scenes, tmp_path):
    s = dataclasses.replace(scenes["box-turn"], gravity=torch.tensor([0.0, 0.0, -1.62], dtype=torch.float64),
                            description='quotes " and \\ and\nnewline')
    loaded = load_scene(s.export(tmp_path / "moon"))
    assert torch.equal(loaded.gravity, s.gravity) and loaded.description == s.description
    assert math.isclose(loaded.environment.table_height, 0.75)
    assert os.path.isfile(tmp_path / "moon" / "scene.toml")


def test_smoothing_removes_jitter_and_keeps_slow_motion():
    """smooth_poses against SciPy: a slow rotation about a fixed axis and a uniform translation, with 1 mm / 1 deg
    of white jitter added. The filter must bring the poses closer to the clean motion than the jittered input,
    keep a clean uniform motion unchanged away from the clip's ends, and return proper rotations."""
    from torchhand.scene import smooth_poses

    T, fps = 120, 30.0
    t = np.arange(T) / fps
    axis = np.array([0.2, 0.5, 0.8]) / np.linalg.norm([0.2, 0.5, 0.8])
    R_clean = Rotation.from_rotvec((0.6 * t)[:, None] * axis)
    p_clean = np.stack([0.05 * t, -0.02 * t, 0.3 + 0.0 * t], -1)
    rng = np.random.default_rng(0)
    R_noisy = Rotation.from_rotvec(np.deg2rad(1.0) * rng.standard_normal((T, 3)) / math.sqrt(3)) * R_clean
    p_noisy = p_clean + 0.001 * rng.standard_normal((T, 3)) / math.sqrt(3)

    def poses(R, p):
        out = np.tile(np.eye(4), (T, 1, 1))
        out[:, :3, :3] = R.as_matrix()
        out[:, :3, 3] = p
        return torch.tensor(out)

    clean = poses(R_clean, p_clean)
    sm = smooth_poses(poses(R_noisy, p_noisy), 2.0)
    check_transforms(sm, "smoothed")
    inner = slice(6, T - 6)

    def errors(P):
        ang = (Rotation.from_matrix(P[inner, :3, :3].numpy()) * R_clean[inner].inv()).magnitude()
        return np.rad2deg(ang).mean(), 1000 * np.linalg.norm(P[inner, :3, 3].numpy() - p_clean[inner], axis=-1).mean()

    a0, d0 = errors(poses(R_noisy, p_noisy))
    a1, d1 = errors(sm)
    assert a1 < 0.5 * a0 and d1 < 0.5 * d0, (a0, a1, d0, d1)
    kept = smooth_poses(clean, 2.0)
    torch.testing.assert_close(kept[inner], clean[inner], atol=1e-6, rtol=0)
    with pytest.raises(InputValueError, match="sigma"):
        builtin_scene("box-turn").smoothed(-1.0)
    assert builtin_scene("box-turn").smoothed(0.0).object_pose.shape == (builtin_scene("box-turn").T, 4, 4)


def test_version_1_scene_still_loads(scene_dir):
    edit_toml(scene_dir, "format_version = 2", "format_version = 1")
    scene = load_scene(scene_dir)
    assert scene.T > 0 and scene.source is None


def test_mocap_source_round_trip_and_frame_shift(scenes, tmp_path):
    from torchhand.scene import MocapSource

    R = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    src = MocapSource(kind="body", wrists=(("right", "/data/body.bvh", "RightHand"),), fps=120.0, frames=900,
                      first_frame=10.0, units_scale=0.01, up_axis="y", handedness="right",
                      hand_rotation=(("right", R),))
    scene = dataclasses.replace(scenes["box-turn"], source=src)
    back = load_scene(scene.export(tmp_path / "s"))
    assert back.source == src
    np.testing.assert_array_equal(back.source.rotation("right"), R)
    # scene frame k is source frame first_frame + k * fps_src / fps: cutting frames moves the start
    cut = back.with_frames(3, 10)
    assert cut.source.first_frame == pytest.approx(10.0 + 3 * 120.0 / scene.fps)
    assert cut.resample(15.0).source.first_frame == cut.source.first_frame
    edit_toml(tmp_path / "s", 'kind = "body"', 'kind = "arm"')
    with pytest.raises(InputValueError, match="kind"):
        load_scene(tmp_path / "s")


# ---------------------------------------------------------------------------------------------------------------
# external wrench


def _pushed(scene: Scene) -> Scene:
    """``scene`` with a known external wrench: a push ramping along +x and a torque about z, (T, 6)."""
    t = torch.arange(scene.T, dtype=torch.float64)
    ext = torch.zeros(scene.T, 6, dtype=torch.float64)
    ext[:, 0], ext[:, 5] = 0.1 * t, -0.01 * t
    return dataclasses.replace(scene, external_wrench=ext)


def test_external_wrench_round_trip_and_editing(scenes, tmp_path):
    s = _pushed(scenes["box-turn"])
    out = s.export(tmp_path / "pushed")
    with np.load(out / "trajectories.npz") as z:
        np.testing.assert_array_equal(z["external_wrench"], s.external_wrench.numpy())
    assert "external_wrench = true" in (out / "scene.toml").read_text()
    loaded = load_scene(out)
    assert_same_scene(s, loaded)
    # no wrench: nothing written, None read back
    plain = load_scene(scenes["box-turn"].export(tmp_path / "plain"))
    assert plain.external_wrench is None
    assert "external_wrench" not in (tmp_path / "plain" / "scene.toml").read_text()
    # slicing keeps the matching rows; resampling interpolates them linearly; smoothing keeps them
    cut = loaded.with_frames(10, 20)
    assert torch.equal(cut.external_wrench, s.external_wrench[10:20])
    half = s.resample(15.0)
    np.testing.assert_allclose(half.external_wrench[:, 0].numpy(), 0.1 * 2 * np.arange(half.T), atol=1e-12)
    assert torch.equal(s.smoothed(0.05).external_wrench, s.external_wrench)


def test_external_wrench_bad_input(scenes, tmp_path):
    s = scenes["box-turn"]
    with pytest.raises(ShapeError, match=r"external_wrench: expected shape \(T, 6\)"):
        dataclasses.replace(s, external_wrench=torch.zeros(s.T, 3, dtype=torch.float64))
    with pytest.raises(ShapeError, match=f"expected T = {s.T} frames"):
        dataclasses.replace(s, external_wrench=torch.zeros(s.T - 1, 6, dtype=torch.float64))
    with pytest.raises(TorchhandError, match="external_wrench: expected a torch.Tensor"):
        dataclasses.replace(s, external_wrench=np.zeros((s.T, 6)))
    bad = torch.zeros(s.T, 6, dtype=torch.float64)
    bad[4, 2] = float("nan")
    with pytest.raises(InputValueError, match="external_wrench must be finite; frame 4"):
        dataclasses.replace(s, external_wrench=bad).validate()
    # on disk: a NaN, a wrong shape, a flag without the array
    out = _pushed(s).export(tmp_path / "pushed")
    edit_npz(out, "external_wrench", lambda a: np.where(np.arange(len(a))[:, None] == 3, np.nan, a))
    with pytest.raises(InputValueError, match=r"external_wrench: expected finite values, frame 3"):
        load_scene(out)
    edit_npz(out, "external_wrench", lambda a: np.zeros((len(a), 5)))
    with pytest.raises(ShapeError, match=r"external_wrench: expected shape \(T, 6\)"):
        load_scene(out)
    edit_npz(out, "external_wrench", lambda a: np.zeros((len(a) + 1, 6)))
    with pytest.raises(ShapeError, match="expected T ="):
        load_scene(out)
    with np.load(out / "trajectories.npz") as data:
        arrays = {k: data[k] for k in data.files if k != "external_wrench"}
    np.savez(out / "trajectories.npz", **arrays)
    with pytest.raises(FileFormatError, match="missing array.*external_wrench"):
        load_scene(out)


def test_builtin_name_over_a_directory_without_scene_toml(tmp_path, monkeypatch):
    """An output directory named after a built-in scene (``--out box-turn``) does not hide the built-in scene; a
    real scene directory of that name (with its scene.toml) still wins."""
    from torchhand.scene import load_scene

    monkeypatch.chdir(tmp_path)
    (tmp_path / "box-turn").mkdir()
    assert load_scene("box-turn").name == "box-turn" and load_scene("box-turn").T == 66
    with pytest.raises(MissingFileError, match="scene.toml"):
        load_scene("./box-turn")


def test_box_alternate_hands_take_turns():
    """box-alternate (Ye & Liu Fig. 8): while one hand holds the box (rigid with it) the other waits at least 10 cm
    from it, and the box turns only while a hand holds it."""
    s = builtin_scene("box-alternate")
    box = s.object_pose[:, :3, 3]
    right, left = (s.hands[i].wrist_pose[:, :3, 3] for i in range(2))
    held = {"right": range(10, 51), "left": range(61, 102)}
    for side, other in (("right", left), ("left", right)):
        frames = list(held[side])
        assert float((other[frames] - box[frames]).norm(dim=-1).min()) > 0.10
    yaw = torch.atan2(s.object_pose[:, 1, 0], s.object_pose[:, 0, 0])
    still = [t for t in range(s.T) if t not in held["right"] and t not in held["left"]]
    assert float((yaw[1:] - yaw[:-1]).abs()[[t - 1 for t in still if t > 0 and t - 1 in still]].max()) < 1e-12
    assert abs(float(yaw[-1]) - math.radians(80.0)) < 1e-9


def test_cup_spin_turns_under_a_still_hand():
    """cup-spin (finger gaits): the wrist stays still through the hold while the cup turns 120 degrees under it, in
    two pushes of 60 degrees with the cup at rest between them."""
    s = builtin_scene("cup-spin")
    w = s.hands[0].wrist_pose
    assert float((w[10:130] - w[60]).abs().max()) < 1e-12
    yaw = torch.atan2(s.object_pose[:, 1, 0], s.object_pose[:, 0, 0])
    assert abs(float(yaw[-1]) - math.radians(120.0)) < 1e-9 and float(yaw[10]) == 0.0
    rest = yaw[60:73]
    assert abs(float(rest[0]) - math.radians(60.0)) < 1e-9 and float((rest - rest[0]).abs().max()) < 1e-12
    assert s.environment.friction == 0.25
