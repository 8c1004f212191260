"""Per-finger contact states from the stored sliding, "unsmoothed" labels and titles, camera projection and the
choice of the OpenGL platform. (Reading result files: tests/torchhand/test_result.py.)"""

from __future__ import annotations

import shutil

import numpy as np
import pytest

import torchhand
from torchhand.render import backend
from torchhand.render.camera import frame_points, look_at
from torchhand.render.contact_analysis import FREE, SLIDING, STATIC, finger_contacts
from torchhand.io.result import load_result

from .fixture_result import write_fixture_result


def test_two_hand_solution(two_hand_result):
    s = load_result(two_hand_result).solution(0)
    assert [h.side for h in s.hands] == ["right", "left"]
    side, link = s.contact_side_link()
    assert set(side[s.contact_mask].tolist()) == {0, 1}
    assert all(n.startswith(("right/", "left/")) for n in s.contact_link_name)


def test_finger_states_follow_the_stored_sliding(tmp_path):
    r = load_result(write_fixture_result(tmp_path / "box-turn", "box-turn", frames=10, solutions=1))
    fc = finger_contacts(r.solution(0), r.hand_models)
    assert fc.labels == ("thumb", "index", "middle", "ring", "little")
    st = fc.state
    assert (st[:, 0] == STATIC).all() and (st[:, 2] == STATIC).all()
    assert (st[:4, 1] == STATIC).all() and (st[4:, 1] == SLIDING).all()  # contact_sliding is set from frame 4
    assert (st[:5, 3] == FREE).all() and (st[5:, 3] != FREE).all()
    assert (st[:, 4] == FREE).all()
    on = st != FREE
    assert np.allclose(fc.normal[on], 3.0) and np.allclose(fc.tangential[on], 0.9, atol=0.05)
    assert fc.friction == pytest.approx(r.scene.friction)


def test_finger_states_of_a_real_result(box_turn_result):
    r = load_result(box_turn_result)
    hand = r.hand_models["right"]
    for s in r.solutions:
        fc = finger_contacts(s, r.hand_models)
        finger = np.where(s.contact_mask, np.asarray(hand.link_finger)[np.maximum(s.contact_link, 0)], -1)
        n = s.contact_normal / np.maximum(np.linalg.norm(s.contact_normal, axis=-1, keepdims=True), 1e-12)
        for f in range(hand.num_fingers):
            m = finger == f
            want = np.where(m.any(1), np.where((m & s.contact_sliding).any(1), SLIDING, STATIC), FREE)
            assert np.array_equal(fc.state[:, f], want), f
            assert np.allclose(fc.normal[:, f], ((s.contact_force * n).sum(-1) * m).sum(1))
        assert (fc.state != FREE).any()


def _unsmoothed_copy(result_dir, tmp_path, index=1):
    root = tmp_path / "result"
    shutil.copytree(result_dir, root)
    f = root / "solutions" / f"sol_{index:03d}.npz"
    with np.load(f) as z:
        data = {k: z[k] for k in z.files}
    np.savez(f, **{**data, "reconstructed": np.array(False)})
    return root


def test_unsmoothed_in_labels_and_titles(box_turn_result, tmp_path, monkeypatch):
    from torchhand.render import jobs, plots

    root = _unsmoothed_copy(box_turn_result, tmp_path)
    clips = jobs.result_clips(root, "all")
    assert "unsmoothed" not in clips[0].labels[0] and clips[1].labels[0].endswith(", unsmoothed")
    ref = jobs.result_clips(box_turn_result, "0", compare=root / "solutions" / "sol_001.npz")
    assert ref[0].labels[0] == "reference: sol_001.npz, unsmoothed" and "unsmoothed" not in ref[1].labels[0]
    titles = []
    for name in ("plot_contact_timeline", "plot_forces"):
        monkeypatch.setattr(plots, name, lambda fc, path, title="": titles.append(title) or path)
    monkeypatch.setattr(plots, "plot_joints", lambda series, hand, fps, path, title="":
                        titles.append((title, [s[0] for s in series])) or path)
    jobs.plot_result(root, tmp_path / "p1", solution=0)
    jobs.plot_result(root, tmp_path / "p2", solution=1)
    assert not any("unsmoothed" in t for t in titles[:2]) and all("unsmoothed" in t for t in titles[3:5])
    joints_title, legend = titles[2]
    assert joints_title.endswith("(unsmoothed: solution 1)") and "unsmoothed" in legend[1]
    assert "unsmoothed" not in legend[0]


def test_camera_projection_matches_look_at():
    pts = np.random.default_rng(0).uniform(-0.1, 0.1, (50, 3))
    cam = frame_points(pts, 320, 240, 3, orbit_deg_per_frame=10.0)
    for f in range(3):
        uv, depth = cam.project(pts, f)
        assert (depth > 0).all()
        assert (uv[:, 0] >= 0).all() and (uv[:, 0] < 320).all() and (uv[:, 1] >= 0).all() and (uv[:, 1] < 240).all()
    uv, _ = cam.project(cam.target[None], 1)
    assert np.allclose(uv, [[160, 120]], atol=1e-6)  # the target is at the image centre
    T = look_at(np.array([1.0, 0.0, 0.0]), np.zeros(3))
    assert np.allclose(T[:3, :3].T @ T[:3, :3], np.eye(3)) and np.allclose(T[:3, 2], [1.0, 0.0, 0.0])


def test_platform_respects_the_user(monkeypatch):
    monkeypatch.setenv("PYOPENGL_PLATFORM", "osmesa")
    monkeypatch.setattr(backend, "_egl_works", lambda: pytest.fail("probed EGL although the user chose"))
    assert backend.select_platform() == "osmesa"


def test_platform_prefers_egl_then_osmesa_then_fails(monkeypatch):
    monkeypatch.delenv("PYOPENGL_PLATFORM", raising=False)
    monkeypatch.delitem(__import__("sys").modules, "OpenGL", raising=False)  # as if PyOpenGL were not imported
    monkeypatch.setattr(backend, "_egl_works", lambda: True)
    assert backend.select_platform() == "egl"
    monkeypatch.delenv("PYOPENGL_PLATFORM")
    monkeypatch.setattr(backend, "_egl_works", lambda: False)
    monkeypatch.setattr(backend.ctypes.util, "find_library", lambda name: "libOSMesa.so.8" if name == "OSMesa"
                        else None)
    assert backend.select_platform() == "osmesa"
    monkeypatch.delenv("PYOPENGL_PLATFORM")
    monkeypatch.setattr(backend.ctypes.util, "find_library", lambda name: None)
    with pytest.raises(backend.RenderBackendError, match="apt-get install libegl1"):
        backend.select_platform()


def test_missing_egl_is_one_line_exit_2(box_turn_result, tmp_path, monkeypatch, capsys):
    from torchhand.cli import main

    monkeypatch.setattr(backend, "offscreen_renderer", _raise_no_gl)
    monkeypatch.setattr("torchhand.render.renderer.offscreen_renderer", _raise_no_gl)
    assert main(["render", str(box_turn_result), "--out", str(tmp_path / "x.gif"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "EGL or OSMesa" in err and "apt-get install" in err
    assert not (tmp_path / "x.gif").exists()


def _raise_no_gl(width, height):
    raise backend.RenderBackendError(f"offscreen rendering needs EGL or OSMesa: {backend.INSTALL_HINT}")


def test_default_hand_meshes_are_closed():
    from torchhand.render.geometry import hand_link_meshes

    hand = torchhand.default_hand()
    meshes = hand_link_meshes(hand)
    assert {li for li, _ in meshes} == set(range(hand.num_links))
    for _, m in meshes:
        assert m.is_watertight and len(m.faces) > 100


def test_text_without_pillow_uses_the_bitmap_font(monkeypatch):
    from torchhand.render import overlay

    monkeypatch.setattr(overlay, "_pil_font", lambda size: None)
    img = np.full((120, 160, 3), 230, np.uint8)
    out = overlay.draw_text_block(img, ["solution 0: static", "1 cm = 2.5 N"], "tl", [None, (225, 20, 15)])
    box = out[:40, :120].astype(int)
    assert (box.sum(-1) < 200).sum() > 50  # dark glyph pixels
    assert ((box[..., 0] > 200) & (box[..., 1] < 50)).any()  # the red swatch
    assert np.array_equal(out[60:], img[60:])  # nothing drawn outside the box
