"""``torchhand export``: the hand skeleton as BVH against torchhand's FK, the command's files and errors, and
fingers written back onto captured bodies (Mixamo, CMU/MB-Lab) checked against the solution's own FK.

Blender as the client of these files: tests/torchhand/test_export_blender.py.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from torchhand.scene.bvh import read_bvh
from torchhand.cli import main
from torchhand.export.skeleton import axis_change, hand_motion_clip, hand_skeleton
from torchhand.hand import HandModel
from torchhand.hand.default import default_hand
from torchhand.scene.mocap import convert_transforms
from torchhand.io.result import load_result

from tests.conftest import shared_path
from tests.render.fixture_result import write_fixture_result

from .export_fixtures import BODIES, FIRST, body_result


def _hands():
    yield "default", default_hand("right", 0.19)
    yield "default-left", default_hand("left", 0.17)
    for name in ("shadow_hand", "allegro_hand"):
        yield name, HandModel.from_mjcf(shared_path("hands", name, "right_hand.xml"))


def fingertips_world(model, q, root):
    """Fingertip pad points from torchhand's FK, (T, F, 3), world metres."""
    m = model.to(dtype=torch.float64)
    T = m.forward_kinematics(torch.as_tensor(q), torch.as_tensor(root)).numpy()[:, m.distal_link.numpy()]
    return np.einsum("tfab,fb->tfa", T[..., :3, :3], m.fingertip.numpy()) + T[..., :3, 3]


@pytest.mark.parametrize("units,up", [("cm", "y"), ("m", "z")])
@pytest.mark.parametrize("which", ["default", "default-left", "shadow_hand", "allegro_hand"])
def test_hand_bvh_matches_fk(tmp_path, which, units, up):
    """Written, read back and posed by the BVH reader: every link origin and fingertip where FK puts it."""
    from torchhand.scene.bvh import write_bvh

    model = dict(_hands())[which] if which.startswith("default") else HandModel.from_mjcf(
        shared_path("hands", which, "right_hand.xml"))
    g = torch.Generator().manual_seed(3)
    T = 40
    q = model.random_q(T, g).double().numpy()
    ang = torch.rand(T, 3, generator=g, dtype=torch.float64) * 6 - 3
    from torchhand.geometry.euler import euler_to_matrix

    root = np.tile(np.eye(4), (T, 1, 1))
    root[:, :3, :3] = euler_to_matrix(ang, "ZYX").numpy()
    root[:, :3, 3] = torch.rand(T, 3, generator=g, dtype=torch.float64).numpy()
    skel = hand_skeleton(model)
    clip = hand_motion_clip(model, skel, q, root, 30.0, units=units, up=up)
    back = read_bvh(write_bvh(clip, tmp_path / "h.bvh", precision=8))
    assert [n for n, e in zip(back.names, back.is_end_site) if not e] == sorted(model.link_names,
                                                                                key=back.names.index)
    assert set(back.names) >= set(model.link_names)
    assert back.num_frames == T and back.fps == pytest.approx(30.0)
    s = 100.0 if units == "cm" else 1.0
    G = back.global_transforms().numpy()
    to_world = lambda p: (p / s) @ axis_change(up)       # noqa: E731  file -> torchhand world
    links = model.to(dtype=torch.float64).forward_kinematics(torch.as_tensor(q), torch.as_tensor(root)).numpy()
    got = to_world(G[:, [back.joint_index(n) for n in model.link_names]][:, :, :3, 3])
    np.testing.assert_allclose(got, links[:, :, :3, 3], atol=2e-7)
    tips = [back.joint_index(n) for n in np.array(skel.names)[skel.tip_joint]]
    np.testing.assert_allclose(to_world(G[:, tips][:, :, :3, 3]), fingertips_world(model, q, root), atol=2e-7)


@pytest.fixture(scope="module")
def box_result(tmp_path_factory):
    return write_fixture_result(tmp_path_factory.mktemp("exp") / "box-turn", "box-turn", frames=12, solutions=3,
                                q_ramp=0.5)


def test_export_writes_every_solution(box_result, tmp_path):
    out = tmp_path / "out"
    assert main(["export", str(box_result), "--out", str(out), "--no-progress"]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == ["export.json", "sol_000.bvh", "sol_000.glb", "sol_001.bvh", "sol_001.glb", "sol_002.bvh",
                     "sol_002.glb"]
    rep = json.loads((out / "export.json").read_text())
    assert rep["files"] == [n for n in names if n != "export.json"]
    res = load_result(box_result)
    model = res.hand_models["right"]
    for i in range(3):
        clip = read_bvh(out / f"sol_{i:03d}.bvh")
        sol = res.solution(i)
        assert clip.num_frames == sol.T and clip.fps == pytest.approx(sol.fps)
        G = clip.global_transforms().numpy()
        tips = [clip.joint_index(f"{model.link_names[d]}_end") for d in model.distal_link.tolist()]
        got = (G[:, tips][:, :, :3, 3] / 100.0) @ axis_change("y")
        np.testing.assert_allclose(got, fingertips_world(model, sol.q, sol.root_pose), atol=1e-7)
    # again into the same directory: refused, then replaced with --overwrite; files no longer written are removed
    assert main(["export", str(box_result), "--out", str(out), "--no-progress"]) == 2
    assert main(["export", str(box_result), "--out", str(out), "--solutions", "1", "--format", "bvh",
                 "--overwrite", "--no-progress"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["export.json", "sol_001.bvh"]


def test_export_two_hands(tmp_path):
    res = write_fixture_result(tmp_path / "two", "two-hand-box", frames=4, solutions=1)
    out = tmp_path / "out"
    assert main(["export", str(res), "--out", str(out), "--format", "bvh", "--no-progress"]) == 0
    first = load_result(res).scene.hands[0].side
    second = "left" if first == "right" else "right"
    assert sorted(p.name for p in out.iterdir()) == ["export.json", "sol_000.bvh", f"sol_000_{second}.bvh"]


@pytest.mark.parametrize("args,message", [
    (["--format", "obj"], "unknown format"),
    (["--solutions", "7"], "out of range"),
    (["--onto", "BODY"], "no [source] table"),
])
def test_export_bad_input_writes_nothing(box_result, tmp_path, capsys, args, message):
    out = tmp_path / "out"
    if "BODY" in args:
        args = [shared_path("mocap", *BODIES["mixamo"][0]) if a == "BODY" else a for a in args]
    assert main(["export", str(box_result), "--out", str(out), "--no-progress", *map(str, args)]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not out.exists() or not any(out.iterdir())


def test_export_refuses_a_foreign_directory(box_result, tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep")
    assert main(["export", str(box_result), "--out", str(out), "--no-progress"]) == 2
    assert "holds no earlier export" in capsys.readouterr().err
    assert (out / "notes.txt").read_text() == "keep" and len(list(out.iterdir())) == 1


# ---------------------------------------------------------------------------------------------------------------
# fingers back onto the body


@pytest.fixture(scope="module", params=sorted(BODIES))
def onto(request, tmp_path_factory):
    root = tmp_path_factory.mktemp(f"onto-{request.param}")
    result, body = body_result(root, request.param)
    out = root / "out"
    assert main(["export", str(result), "--out", str(out), "--onto", str(body), "--no-progress"]) == 0
    return request.param, result, body, out


def test_onto_keeps_every_other_channel(onto):
    name, _, body_path, out = onto
    body, done = read_bvh(body_path), read_bvh(out / "body_with_fingers.bvh")
    assert done.names == body.names and done.num_frames == body.num_frames
    from torchhand.splice.rigs import detect_rig

    fingers = set(detect_rig(body).finger_joints("right"))
    cols = [(j, c) for j, chans in enumerate(body.channels) for c in chans]
    finger_rot = np.array([j in fingers and c.endswith("rotation") for j, c in cols])
    changed = (done.motion != body.motion)
    assert not changed[:, ~finger_rot].any(), "a non-finger channel changed"
    assert changed[:, finger_rot].any()
    rows = np.nonzero(changed.any(axis=1))[0]
    assert rows.min() >= FIRST and rows.max() <= body.num_frames - 11      # only inside the scene's frames
    # the blended segment joins the captured frames: no 360-degree or twin-triple jump in the finger channels
    last = body.num_frames - 11
    for a, b in ((FIRST - 1, FIRST), (last, last + 1)):
        jump = np.abs(done.motion[b, finger_rot] - done.motion[a, finger_rot]).max()
        assert jump < 15.0, f"{name}: finger channels jump {jump:.1f} degrees between frames {a} and {b}"


def test_onto_fingertips_agree_with_the_solution(onto):
    """Body fingertips (BVH reader FK, converted to torchhand's world) within 5 mm of the solution's fingertips
    (the result's FK at its own wrist poses), on every frame outside the blends."""
    name, result, body_path, out = onto
    _, wrist, units, up = BODIES[name]
    res = load_result(result)
    sol = res.solution(0)
    model = res.hand_models["right"]
    want = fingertips_world(model, sol.q, sol.root_pose)                  # (T, F, 3)
    done = read_bvh(out / "body_with_fingers.bvh")
    G = convert_transforms(done.global_transforms(), units_scale=units, up_axis=up).numpy()
    from torchhand.splice.rigs import detect_rig

    tips = detect_rig(done).tips["right"]
    keys = ["thumb", "index", "middle", "ring", "pinky"]
    k = int(round(0.2 * done.fps))                                        # the default --blend 0.2 s
    frames = np.arange(k, sol.T - k)
    got = np.stack([G[FIRST + frames, tips[f], :3, 3] for f in keys], axis=1)
    err = np.linalg.norm(got - want[frames], axis=-1)
    assert err.max() < 0.005, f"{name}: fingertips {1000 * err.max():.2f} mm from the solution's"
    rep = json.loads((out / "export.json").read_text())["solutions"][0]["onto"]["sides"]["right"]
    assert rep["fingertip_error_max_m"] < 0.005


def test_onto_refuses_another_body(onto, tmp_path, capsys):
    name, result, _, _ = onto
    other = shared_path("mocap", *BODIES["cmu" if name == "mixamo" else "mixamo"][0])
    assert main(["export", str(result), "--out", str(tmp_path / "o"), "--onto", str(other), "--no-progress"]) == 2
    assert "the scene was imported from" in capsys.readouterr().err


def test_onto_a_resampled_scene(tmp_path):
    """A scene resampled from 30 to 20 fps: source frame 10 + 1.5 k is scene frame k; the solution's angles are
    interpolated to the source frames, and on the frames where both clocks meet the fingertips agree."""
    result, body_path = body_result(tmp_path, "mixamo", fps=20.0)
    out = tmp_path / "out"
    assert main(["export", str(result), "--out", str(out), "--onto", str(body_path), "--no-progress"]) == 0
    res = load_result(result)
    assert res.scene.fps == 20.0 and res.scene.source.first_frame == FIRST
    sol, model = res.solution(0), res.hand_models["right"]
    want = fingertips_world(model, sol.q, sol.root_pose)
    done = read_bvh(out / "body_with_fingers.bvh")
    _, _, units, up = BODIES["mixamo"]
    G = convert_transforms(done.global_transforms(), units_scale=units, up_axis=up).numpy()
    from torchhand.splice.rigs import detect_rig

    tips = detect_rig(done).tips["right"]
    ks = np.arange(6, sol.T - 6, 2)                   # scene frames on whole source frames, outside the blends
    got = np.stack([G[FIRST + (3 * ks) // 2, tips[f], :3, 3] for f in ("thumb", "index", "middle", "ring",
                                                                          "pinky")], axis=1)
    assert np.linalg.norm(got - want[ks], axis=-1).max() < 0.005


def test_export_names_a_splice_output(tmp_path, capsys):
    (tmp_path / "spliced").mkdir()
    (tmp_path / "spliced" / "spliced.bvh").write_text("HIERARCHY\n")
    assert main(["export", str(tmp_path / "spliced"), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    assert "splice output" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
