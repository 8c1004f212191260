"""Reading result files, per-finger contact states, camera projection and the choice of the OpenGL platform."""

from __future__ import annotations

import numpy as np
import pytest

import torchhand
from torchhand.errors import FileFormatError, MissingFileError, ShapeError, TorchhandError
from torchhand.render import backend
from torchhand.render.camera import frame_points, look_at
from torchhand.render.contact_analysis import FREE, SLIDING, STATIC, finger_contacts
from torchhand.render.results import load_result_dir, load_solution, parse_solution_spec


def test_load_result_dir(box_turn_result):
    r = load_result_dir(box_turn_result)
    assert r.scene.T == 10 and len(r.solution_files) == 2 and r.stats["solutions"] == 2
    s = r.solution(1)
    assert s.T == 10 and s.hands[0].q.shape == (10, 30) and s.strategy == "sliding"
    assert s.contact_point.shape == (10, 5, 3) and s.contact_mask.dtype == bool
    assert s.friction == pytest.approx(r.scene.friction)


def test_two_hand_solution(two_hand_result):
    s = load_result_dir(two_hand_result).solution(0)
    assert [h.side for h in s.hands] == ["right", "left"]
    side, link = s.contact_side_link()
    assert set(side[s.contact_mask].tolist()) == {0, 1}
    assert all(n.startswith(("right/", "left/")) for n in s.contact_link_name)


def test_solution_errors(box_turn_result, tmp_path):
    with pytest.raises(MissingFileError):
        load_solution(tmp_path / "none.npz")
    data = dict(np.load(box_turn_result / "solutions" / "sol_000.npz"))
    data["root_pose"] = data["root_pose"][:, :3]
    np.savez(tmp_path / "bad.npz", **data)
    with pytest.raises(ShapeError, match="root_pose: expected shape"):
        load_solution(tmp_path / "bad.npz")
    data = dict(np.load(box_turn_result / "solutions" / "sol_000.npz"))
    data["q"][3, 2] = np.nan
    np.savez(tmp_path / "nan.npz", **data)
    with pytest.raises(FileFormatError, match="NaN"):
        load_solution(tmp_path / "nan.npz")
    assert parse_solution_spec("all", 3) == [0, 1, 2] and parse_solution_spec("0,2", 3) == [0, 2]
    assert parse_solution_spec("1:", 3) == [1, 2]
    with pytest.raises(TorchhandError):
        parse_solution_spec("3", 3)


def test_finger_states_follow_the_fabricated_pattern(box_turn_result):
    r = load_result_dir(box_turn_result)
    fc = finger_contacts(r.solution(0), r.hand_models, slide_speed=0.01)
    assert fc.labels == ("thumb", "index", "middle", "ring", "little")
    st = fc.state
    assert (st[:, 0] == STATIC).all() and (st[:, 2] == STATIC).all()
    assert (st[:3, 1] == STATIC).all() and (st[4:, 1] == SLIDING).all()  # 2 mm/frame at 30 fps = 6 cm/s
    assert (st[:5, 3] == FREE).all() and (st[5:, 3] != FREE).all()
    assert (st[:, 4] == FREE).all()
    on = st != FREE
    assert np.allclose(fc.normal[on], 3.0) and np.allclose(fc.tangential[on], 0.9, atol=0.05)
    assert fc.friction == pytest.approx(r.scene.friction)


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
