"""Object swap (torchhand.scene.swap, `torchhand synthesize --object`): the same motion drives another mesh, placed
where the old object rested; the palm's clearance along a fixed wrist track."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from tests.conftest import shared_path
from torchhand.errors import InputValueError
from torchhand.geometry.objects import RigidObject
from torchhand.scene import environment_contacts, load_scene
from torchhand.scene.swap import swap_object

ROOT = Path(__file__).resolve().parents[2]


def _world(scene, frame: int, points: np.ndarray) -> np.ndarray:
    P = scene.object_pose[frame].double().numpy()
    return points @ P[:3, :3].T + P[:3, 3]


def _tall_cylinder_y() -> RigidObject:
    """A cylinder of radius 2 cm and height 8 cm along the mesh's y axis, its base at y = 1 cm."""
    m = trimesh.creation.cylinder(radius=0.02, height=0.08, sections=48)
    m.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))
    m.apply_translation([0.01, 0.05, -0.02])
    return RigidObject.from_trimesh(m, mass=0.1, name="cyl")


def test_the_swap_keeps_every_track_and_rests_where_the_box_rested():
    box = load_scene("box-turn")
    sw, info = swap_object(box, _tall_cylinder_y(), up="y")
    assert info.align == "rest" and info.frame == 0 and info.mass == pytest.approx(box.object.mass)
    assert torch.equal(sw.object_pose, box.object_pose)
    assert all(torch.equal(a.wrist_pose, b.wrist_pose) for a, b in zip(sw.hands, box.hands))
    old = _world(box, 0, np.asarray(box.object.mesh.vertices))
    new = _world(sw, 0, np.asarray(sw.object.mesh.vertices))
    assert new[:, 2].min() == pytest.approx(old[:, 2].min(), abs=1e-9)          # on the table where the box was
    c_old = _world(box, 0, np.asarray(box.object.com)[None])[0]
    c_new = _world(sw, 0, np.asarray(sw.object.com)[None])[0]
    assert np.allclose(c_new[:2], c_old[:2], atol=1e-9)                          # straight above the box's
    assert np.ptp(new[:, 2]) == pytest.approx(0.08, abs=1e-6)                    # its y axis now points up
    assert environment_contacts(sw).mask[0].sum() >= 3                            # and the table holds it


def test_other_placements_and_a_given_mass():
    box = load_scene("box-turn")
    cyl = _tall_cylinder_y()
    sw, info = swap_object(box, cyl, align="com", up="y", mass=0.4)
    assert info.align == "com" and sw.object.mass == pytest.approx(0.4)
    assert np.allclose(sw.object.com, box.object.com, atol=1e-9)
    same, info = swap_object(box, cyl, align="frame")
    assert np.allclose(np.asarray(same.object.mesh.vertices), np.asarray(cyl.mesh.vertices), atol=1e-12)
    assert np.allclose(info.transform, np.eye(4))


def test_a_scene_without_a_table_places_by_the_centre_of_mass():
    import dataclasses

    box = load_scene("box-turn")
    bare = dataclasses.replace(box, environment=dataclasses.replace(box.environment, table=False))
    _, info = swap_object(bare, _tall_cylinder_y(), up="y")
    assert info.align == "com"


@pytest.mark.parametrize("kwargs, message", [
    ({"align": "top"}, "align: expected one of rest, com, frame, got 'top'"),
    ({"up": "w"}, "up: expected one of z, y, x, -z, -y, -x, got 'w'"),
    ({"scale": 0.0}, "scale: expected a finite positive number, got 0.0"),
    ({"mass": -1.0}, "mass: expected a finite positive number of kilograms, got -1.0"),
])
def test_bad_arguments_are_one_line(kwargs, message):
    with pytest.raises(InputValueError) as err:
        swap_object(load_scene("box-turn"), _tall_cylinder_y(), **kwargs)
    assert str(err.value) == message


def test_the_palm_clearance_names_a_too_large_object():
    from torchhand.synthesis.clearance import describe_palm, palm_clearance
    from torchhand.synthesis.problem import build_problem

    box = load_scene("box-turn")
    p = build_problem(box, torch.Generator().manual_seed(0))
    assert float(palm_clearance(p).min()) > 0.003 and describe_palm(p) is None
    big = RigidObject.from_trimesh(trimesh.creation.box((0.09, 0.07, 0.12)), mass=0.25)     # twice as tall
    p = build_problem(swap_object(box, big)[0], torch.Generator().manual_seed(0))
    line = describe_palm(p)
    assert line is not None and line.startswith("the right palm goes up to ") and "on its fixed wrist track" in line


def test_the_bunny_stands_on_the_table(shared_data):
    bunny = shared_path("meshes", "trimesh", "bunny.ply")
    sw, info = swap_object(load_scene("box-turn"), bunny, up="y", scale=0.45)
    assert info.align == "rest" and sw.object.name == "bunny"
    assert np.ptp(_world(sw, 0, np.asarray(sw.object.mesh.vertices))[:, 2]) == pytest.approx(0.45 * 0.1527, abs=2e-3)
    assert environment_contacts(sw).mask[0].sum() >= 3


def _torchhand(args):
    return subprocess.run([sys.executable, "-m", "torchhand.cli", *args], capture_output=True, text=True, cwd=ROOT,
                          env={**os.environ}, timeout=1800)


def test_cli_object_options_need_an_object(tmp_path):
    run = _torchhand(["synthesize", "box-turn", "--out", str(tmp_path / "o"), "--object-scale", "2"])
    assert run.returncode == 2 and run.stderr.strip() == "torchhand: error: --object-scale: needs --object MESH"
    assert not (tmp_path / "o").exists()


def test_cli_synthesizes_with_a_swapped_object(tmp_path):
    mesh = tmp_path / "cyl.stl"
    _tall_cylinder_y().mesh.export(mesh)
    out = tmp_path / "out"
    run = _torchhand(["synthesize", "box-turn", "--object", str(mesh), "--object-up", "y", "--object-scale", "0.7",
                      "--frames", "0:8", "--solutions", "1", "--max-nodes", "3000", "--out", str(out),
                      "--no-progress"])
    assert run.returncode in (0, 1), run.stderr[-2000:]
    assert "swapped for" in run.stderr and "placed by 'rest' at frame 0" in run.stderr
    stats = json.loads((out / "stats.json").read_text())
    assert stats["object_swap"]["align"] == "rest" and stats["object_swap"]["replaced"] == "box"
    written = load_scene(out / "scene")
    box = load_scene("box-turn").with_frames(0, 8)
    assert torch.allclose(written.object_pose, box.object_pose, atol=1e-12)
    assert np.ptp(np.asarray(written.object.mesh.vertices)[:, 2]) == pytest.approx(0.7 * 0.08, abs=1e-6)


def test_cli_names_a_palm_inside_the_swapped_object(tmp_path):
    mesh = tmp_path / "tall.stl"
    trimesh.creation.box((0.09, 0.07, 0.12)).export(mesh)
    run = _torchhand(["synthesize", "box-turn", "--object", str(mesh), "--frames", "0:12", "--solutions", "1",
                      "--max-nodes", "300", "--out", str(tmp_path / "out"), "--no-progress"])
    assert run.returncode == 1, run.stderr[-2000:]
    assert "no feasible motion found within 300 node tests" in run.stderr
    assert "the right palm goes up to " in run.stderr and "no finger motion can avoid that" in run.stderr


def test_an_offset_in_the_wrist_frame_moves_the_object_relative_to_the_wrist():
    from torchhand.hand.collision import rigid_inverse
    from torchhand.scene.swap import offset_object

    box = load_scene("box-turn")
    o = torch.tensor([0.0, 0.0, 0.02], dtype=torch.float64)
    moved = offset_object(box, o.tolist())
    W = box.hands[0].wrist_pose.double()
    rel_old = rigid_inverse(W) @ box.object_pose.double()
    rel_new = rigid_inverse(W) @ moved.object_pose.double()
    assert torch.allclose(rel_new[:, :3, 3] - rel_old[:, :3, 3], o.expand(box.T, 3), atol=1e-12)
    assert torch.allclose(rel_new[:, :3, :3], rel_old[:, :3, :3], atol=1e-12)
    assert torch.equal(moved.hands[0].wrist_pose, box.hands[0].wrist_pose)


def test_an_offset_into_the_table_is_refused():
    from torchhand.scene.swap import offset_object

    box = load_scene("box-turn")
    down = (box.hands[0].wrist_pose[0, :3, :3].double().T @ torch.tensor([0.0, 0.0, -0.01], dtype=torch.float64))
    with pytest.raises(InputValueError, match=r"^offset: the object would go 10\.0 mm into the table at"):
        offset_object(box, down.tolist())
    with pytest.raises(InputValueError, match=r"^offset: expected three finite numbers"):
        offset_object(box, [0.0, 1.0])
    run = _torchhand(["synthesize", "box-turn", "--out", "/tmp/never-written", "--object-offset", "0,0"])
    assert run.returncode == 2 and run.stderr.strip() == ("torchhand: error: --object-offset: expected X,Y,Z in "
                                                          "metres, got '0,0'")


def test_a_yaw_turns_the_mesh_about_the_vertical():
    box = load_scene("box-turn")
    long_x = RigidObject.from_trimesh(trimesh.creation.box((0.08, 0.02, 0.03)), mass=0.1)
    a, _ = swap_object(box, long_x)
    b, _ = swap_object(box, long_x, yaw=90.0)
    ext = lambda s: np.ptp(_world(s, 0, np.asarray(s.object.mesh.vertices)), axis=0)   # noqa: E731
    assert np.allclose(ext(a)[[1, 0, 2]], ext(b), atol=1e-9)          # x and y extents exchanged, height kept
    with pytest.raises(InputValueError, match="^yaw: expected a finite number of degrees"):
        swap_object(box, long_x, yaw=float("nan"))


def test_the_palm_is_the_palm_link_and_the_metacarpals():
    from torchhand.hand import default_hand
    from torchhand.synthesis.clearance import palm_links

    hand = default_hand()
    names = [hand.link_names[i] for i in palm_links(hand).tolist()]
    assert names == ["palm", "index_metacarpal", "middle_metacarpal", "ring_metacarpal", "little_metacarpal"]


def test_cli_a_bad_object_file_is_one_line(tmp_path):
    run = _torchhand(["synthesize", "box-turn", "--object", str(tmp_path / "none.ply"), "--out", str(tmp_path / "o")])
    assert run.returncode == 2 and run.stderr.strip() == (f"torchhand: error: --object {tmp_path / 'none.ply'}: mesh "
                                                          f"file '{tmp_path / 'none.ply'}' does not exist")
    assert not (tmp_path / "o").exists()


def test_the_handle_pair_differs_only_in_the_handle_s_distance_to_the_palm():
    """handle-lift and handle-lift-palm (Ye & Liu Fig. 7): the same wrist track, the handle 1.5 cm nearer the palm
    in the wrist frame, the palm 15.5 mm clear of it in the first and 0.5 mm in the second."""
    from torchhand.hand.collision import rigid_inverse
    from torchhand.scene.builtin.ye_liu import HANDLE_PALM_OFFSET
    from torchhand.synthesis.clearance import palm_clearance
    from torchhand.synthesis.problem import build_problem

    far, near = load_scene("handle-lift"), load_scene("handle-lift-palm")
    assert torch.equal(far.hands[0].wrist_pose, near.hands[0].wrist_pose)
    W = far.hands[0].wrist_pose.double()
    shift = (rigid_inverse(W) @ near.object_pose.double() - rigid_inverse(W) @ far.object_pose.double())[:, :3, 3]
    assert torch.allclose(shift, torch.tensor(HANDLE_PALM_OFFSET, dtype=torch.float64).expand(far.T, 3), atol=1e-12)
    gaps = [float(palm_clearance(build_problem(s, torch.Generator().manual_seed(0))).min()) for s in (far, near)]
    assert abs(gaps[0] - 0.0155) < 5e-4 and 0.0 < gaps[1] < 0.0012      # near: within contact distance
