"""Grasp input for manipulation (Liu 2009): grasp.npz round trip, bad inputs, the makers and the snap step."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

from torchhand.cli import main as cli
from torchhand.errors import FileFormatError, InputValueError, MissingFileError, ShapeError, UnknownNameError
from torchhand.manipulation import (Grasp, grasp_from_qpos, grasp_from_result, grasp_hand, load_grasp, save_grasp, snap_grasp)
from torchhand.manipulation.snap import hand_surface_in_object, signed_distance

# box-turn's first 8 frames with a small search: a real result in a few seconds (as test_synthesis_output.py), for
# the tests of `grasp from-result` and `from-qpos` themselves
SYNTH = ["synthesize", "box-turn", "--frames", "0:8", "--trees", "4", "--candidates", "8", "--max-nodes", "2000",
         "--solutions", "1", "--seed", "0", "--no-progress", "--threads", "1"]
FRAME = 6          # thumb, index and little finger on the box's sides

TEST_GRASP = Path(__file__).resolve().parents[1] / "data" / "box_turn_grasp.npz"
"""The manipulation tests' grasp: such a search's solution 0 at FRAME, snapped (six contact links), stored once by
``python scripts/make_liu_grasps.py --test-grasp``. A fixed input: the search itself moves with the last bits of the
arithmetic (its grasps differed by about 2e-8 m between CPUs), and so did the planner's verdicts built on it."""

_CACHE: dict = {}


def small_result(tmp_path_factory) -> Path:
    """A `torchhand synthesize box-turn` result (run once per session; test_inferred.py shares it)."""
    if "dir" not in _CACHE:
        out = tmp_path_factory.mktemp("manip") / "bt"
        assert cli(SYNTH + ["--out", str(out)]) == 0
        _CACHE["dir"] = out
    return _CACHE["dir"]


def box_turn_grasp():
    """(the stored snapped grasp TEST_GRASP at FRAME, the built-in box-turn scene it belongs to)."""
    from torchhand.scene import load_scene

    if "grasp" not in _CACHE:
        _CACHE["grasp"] = (load_grasp(TEST_GRASP), load_scene("box-turn"))
    return _CACHE["grasp"]


@pytest.fixture(scope="module")
def grasp_scene():
    return box_turn_grasp()


def _raw(path: Path) -> dict:
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def test_round_trip(grasp_scene, tmp_path):
    g, _ = grasp_scene
    f = save_grasp(g, tmp_path / "g.npz")
    back = load_grasp(f, grasp_hand(g))
    assert back.hand == g.hand and back.side == g.side and back.frame == FRAME and back.length == g.length
    assert back.joint_names == g.joint_names and back.contact_links == g.contact_links
    for key in ("q", "wrist_in_object", "contact_hand", "contact_object", "snap_distance"):
        np.testing.assert_array_equal(getattr(back, key), getattr(g, key))
    with pytest.raises(InputValueError, match="exists"):
        save_grasp(g, f)
    save_grasp(g, f, overwrite=True)


def test_from_result_matches_the_solution(tmp_path_factory, grasp_scene):
    root = small_result(tmp_path_factory)
    g, scene = grasp_from_result(root, solution=0, frame=FRAME)
    with np.load(root / "solutions" / "sol_000.npz") as z:
        q, root_pose, obj = z["q"][FRAME], z["root_pose"][FRAME], z["object_pose"][FRAME]
    np.testing.assert_allclose(g.q, q, atol=0)
    np.testing.assert_allclose(obj @ g.wrist_in_object, root_pose, atol=1e-12)
    snapped, _ = grasp_scene
    assert snapped.num_contacts >= 3
    fingers = {n.split("_")[0] for n in snapped.contact_links}
    assert {"thumb", "index", "little"} <= fingers
    # every contact lies on the object surface (trimesh, exact) within the IK's residual
    hand = grasp_hand(snapped)
    T = hand.forward_kinematics(torch.as_tensor(snapped.q)[None], torch.as_tensor(snapped.wrist_in_object)[None])[0]
    for name, h, p in zip(snapped.contact_links, snapped.contact_hand, snapped.contact_object):
        L = T[hand.link_index(name)].numpy()
        assert np.linalg.norm(L[:3, :3] @ h + L[:3, 3] - p) < 1.2e-3        # the node test's contact distance
        assert abs(signed_distance(scene.object.mesh, p[None])[0][0]) < 1e-9


def test_cli_from_result_and_overwrite(tmp_path_factory, tmp_path, capsys):
    root = small_result(tmp_path_factory)
    out = tmp_path / "g.npz"
    args = ["grasp", "from-result", str(root), "--solution", "0", "--frame", str(FRAME), "--out", str(out)]
    assert cli(args) == 0
    assert "snap: contact thumb_distal" in capsys.readouterr().out
    g = load_grasp(out)
    assert g.num_contacts >= 3 and g.frame == FRAME
    before = out.read_bytes()
    assert cli(args) == 2
    assert "exists; pass --overwrite" in capsys.readouterr().err
    assert out.read_bytes() == before
    assert cli(args + ["--overwrite"]) == 0
    assert cli(["grasp", "from-result", str(root), "--frame", "99", "--out", str(tmp_path / "x.npz")]) == 2
    assert "--frame" in capsys.readouterr().err


def test_from_qpos_reproduces_the_hand_surface(tmp_path_factory, tmp_path):
    """The result's hand.xml (free root joint, then the joints) at qpos = (root position, root quaternion wxyz, q)
    puts the hand surface where the result's grasp puts it."""
    from scipy.spatial.transform import Rotation

    root = small_result(tmp_path_factory)
    g, scene = grasp_from_result(root, solution=0, frame=FRAME)
    with np.load(root / "solutions" / "sol_000.npz") as z:
        q, root_pose = z["q"][FRAME], z["root_pose"][FRAME]
    xyzw = Rotation.from_matrix(root_pose[:3, :3]).as_quat()
    qpos = np.concatenate([root_pose[:3, 3], [xyzw[3], *xyzw[:3]], q])
    np.save(tmp_path / "qpos.npy", qpos)
    out = tmp_path / "g.npz"
    assert cli(["grasp", "from-qpos", str(root / "hand.xml"), "--qpos", str(tmp_path / "qpos.npy"), "--scene",
                str(root / "scene"), "--frame", str(FRAME), "--out", str(out)]) == 0
    gq = grasp_from_qpos(root / "hand.xml", qpos, scene, frame=FRAME)
    a = hand_surface_in_object(grasp_hand(g), g.q, g.wrist_in_object)
    b = hand_surface_in_object(grasp_hand(gq), gq.q, gq.wrist_in_object)
    assert a.shape == b.shape
    assert np.abs(a - b).max() < 1e-6
    assert load_grasp(out).num_contacts >= 3
    with pytest.raises(ShapeError, match="qpos"):
        grasp_from_qpos(root / "hand.xml", qpos[:-1], scene, frame=FRAME)


# ---------------------------------------------------------------------------------------------------- bad inputs
def test_bad_files(grasp_scene, tmp_path):
    g, _ = grasp_scene
    hand = grasp_hand(g)
    with pytest.raises(MissingFileError):
        load_grasp(tmp_path / "none.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(FileFormatError):
        load_grasp(tmp_path / "junk.npz")
    good = _raw(save_grasp(g, tmp_path / "g.npz"))

    def write(**change):
        d = {k: v for k, v in good.items() if k not in change or change[k] is not None}
        d.update({k: v for k, v in change.items() if v is not None})
        p = tmp_path / "bad.npz"
        np.savez(p, **d)
        return p

    with pytest.raises(FileFormatError, match="missing key.*wrist_in_object"):
        load_grasp(write(wrist_in_object=None))
    with pytest.raises(FileFormatError, match="contact_object"):
        load_grasp(write(contact_object=None))
    with pytest.raises(ShapeError, match="q: expected shape \\(30,\\)"):
        load_grasp(write(q=good["q"][:-1]))
    with pytest.raises(ShapeError, match="wrist_in_object"):
        load_grasp(write(wrist_in_object=np.eye(3)))
    bent = good["wrist_in_object"].copy()
    bent[0, 0] += 0.1
    with pytest.raises(InputValueError, match="rigid"):
        load_grasp(write(wrist_in_object=bent))
    with pytest.raises(ShapeError, match="contact_hand"):
        load_grasp(write(contact_hand=good["contact_hand"][:-1]))
    names = good["joint_names"].copy()
    names[3] = "wrist_spin"
    with pytest.raises(UnknownNameError, match="wrist_spin"):
        load_grasp(write(joint_names=names), hand)
    q = good["q"].copy()
    j = 5
    q[j] = float(hand.joint_limits[j, 1]) + 1e-3
    with pytest.raises(InputValueError, match=hand.joint_names[j]):
        load_grasp(write(q=q), hand)
    q[j] = float(hand.joint_limits[j, 1]) + 5e-7                   # within the 1e-6 tolerance
    load_grasp(write(q=q), hand)


def test_cli_bad_input_exits_2(tmp_path, capsys):
    assert cli(["grasp", "from-result", str(tmp_path / "nothing"), "--frame", "0", "--out",
                str(tmp_path / "g.npz")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert cli(["grasp", "from-qpos", str(tmp_path / "hand.xml"), "--qpos", str(tmp_path / "q.npy"), "--scene",
                "box-turn", "--frame", "0", "--out", str(tmp_path / "g.npz")]) == 2


# ---------------------------------------------------------------------------------------------------------- snap
def _thumb_moved(g: Grasp, hand, mesh, gap: float) -> Grasp:
    """``g`` with the thumb's joints moved so that its contact point leaves the surface by about ``gap`` metres."""
    i = g.contact_links.index("thumb_distal")
    link = hand.link_index("thumb_distal")
    thumb = [d for d, n in enumerate(hand.joint_names) if n.startswith("thumb")]
    _, _, n_out = signed_distance(mesh, g.contact_object[i:i + 1])
    q = g.q.copy()
    lim = hand.joint_limits.numpy()
    root = torch.as_tensor(g.wrist_in_object)[None]
    for _ in range(4):
        T = hand.forward_kinematics(torch.as_tensor(q)[None], root)[0, link].numpy()
        x = T[:3, :3] @ g.contact_hand[i] + T[:3, 3]
        target = g.contact_object[i] + gap * n_out[0]
        J = hand.point_jacobian(torch.as_tensor(q)[None], torch.tensor([link]),
                                torch.as_tensor(g.contact_hand[i:i + 1]), root)[0, 0].numpy()[:, thumb]
        q[thumb] += np.linalg.lstsq(J, target - x, rcond=None)[0]
        q = np.clip(q, lim[:, 0], lim[:, 1])
    return dataclasses.replace(g, q=q, contact_links=(), contact_hand=None, contact_object=None, snap_distance=None)


def test_snap_closes_a_3mm_gap_and_refuses_8mm(grasp_scene):
    g, scene = grasp_scene
    hand, mesh = grasp_hand(g), scene.object.mesh
    s3, rep3 = snap_grasp(_thumb_moved(g, hand, mesh, 0.003), hand, mesh)
    k = rep3.links.index("thumb_distal")
    assert 0.0025 < rep3.before[k] < 0.0035
    assert abs(rep3.after[k]) < 3e-4
    assert rep3.max_joint_move > 0.01
    s8, rep8 = snap_grasp(_thumb_moved(g, hand, mesh, 0.008), hand, mesh)
    assert "thumb_distal" not in rep8.links
    gaps = dict(rep8.unsnapped)
    assert 0.0075 < gaps["thumb_distal"] < 0.0085
    assert any("thumb_distal is 8." in line for line in rep8.lines())


def test_snap_errors(grasp_scene):
    g, scene = grasp_scene
    hand, mesh = grasp_hand(g), scene.object.mesh
    bare = dataclasses.replace(g, contact_links=(), contact_hand=None, contact_object=None, snap_distance=None)
    away = bare.wrist_in_object.copy()
    away[:3, 3] += (0.0, 0.0, 0.2)
    with pytest.raises(InputValueError, match=r"touches nothing: nearest link \w+ is \d+\.\d mm from the object"):
        snap_grasp(dataclasses.replace(bare, wrist_in_object=away), hand, mesh)
    i = g.contact_links.index("thumb_distal")
    _, _, n_out = signed_distance(mesh, g.contact_object[i:i + 1])
    into = bare.wrist_in_object.copy()
    into[:3, 3] -= 0.008 * n_out[0]
    with pytest.raises(InputValueError, match=r"penetrates the object beyond the snap tolerance 5.0 mm: "
                                              r".*thumb_distal by [78]\.\d mm"):
        snap_grasp(dataclasses.replace(bare, wrist_in_object=into), hand, mesh)
    with pytest.raises(InputValueError, match="snap tolerance"):
        snap_grasp(bare, hand, mesh, tol=0.0)
