"""``torchhand view``: the per-frame geometry against forward kinematics, the scene's nodes, the timeline, bad input,
and the viewer in a real browser (the system's Chromium driven by Playwright).

The result is the render tests' hand-written fixture (tests/render/fixture_result.py: box-turn cut to 8 frames,
two solutions whose fingers close over the clip); no synthesis runs.
"""

from __future__ import annotations

import io
import shutil
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("viser")

import torchhand  # noqa: E402
from torchhand.check import check_result  # noqa: E402
from torchhand.errors import InputValueError, MissingFileError, TorchhandError  # noqa: E402
from torchhand.view import PortInUseError, load_view, serve  # noqa: E402
from torchhand.view.scene import matrix_to_wxyz  # noqa: E402
from torchhand.view.verdict import frame_verdicts  # noqa: E402

FRAMES = 8


@pytest.fixture(scope="module")
def result_dir(tmp_path_factory) -> Path:
    from tests.render.fixture_result import write_fixture_result

    return write_fixture_result(tmp_path_factory.mktemp("view") / "r", "box-turn", frames=FRAMES, solutions=2,
                                q_ramp=0.6)


@pytest.fixture(scope="module")
def viewer(result_dir):
    handle = serve(result_dir, host="127.0.0.1", port=0, block=False)
    yield handle
    handle.stop()


# --- without a browser ---------------------------------------------------------------------------------------------

def test_link_poses_are_the_hand_models_forward_kinematics(result_dir):
    data = load_view(result_dir)
    result = torchhand.load_result(result_dir)
    hand = result.hand_models["right"].to(dtype=torch.float64)
    assert data.frames == FRAMES and data.fps == pytest.approx(result.scene.fps)
    for i, frames in enumerate(data.solutions):
        sol = result.solution(i)
        names = list(sol.hands[0].joint_names)
        order = [names.index(n) for n in hand.joint_names]
        q = torch.from_numpy(np.ascontiguousarray(sol.q[:, order]))
        want = hand.forward_kinematics(q, torch.from_numpy(sol.root_pose)).numpy()     # (T, L, 4, 4)
        got = frames.hands[0].link_pose
        assert got.shape == want.shape == (FRAMES, hand.num_links, 4, 4)
        np.testing.assert_allclose(got, want, atol=1e-12)
        np.testing.assert_array_equal(frames.object_pose, sol.object_pose)
        np.testing.assert_array_equal(frames.contacts.mask, sol.contact_mask)


def test_scene_has_object_table_hands_contacts_and_forces(viewer):
    names = set(viewer.nodes.names)
    assert {"/object", "/table", "/sol_000", "/sol_001"} <= names
    link_names = viewer.data.hand_meshes["right"].link_names
    for sol in ("sol_000", "sol_001"):
        assert {f"/{sol}/contacts", f"/{sol}/forces", f"/{sol}/table_contacts", f"/{sol}/table_forces"} <= names
        assert {f"/{sol}/right/{n}" for n in ("index_distal", "thumb_distal", "little_distal")} <= names
        assert len([n for n in names if n.startswith(f"/{sol}/right/")]) == len(viewer.data.hand_meshes["right"].link)
    assert len(link_names) == viewer.data.hand_meshes["right"].link.max() + 1
    for name in ("/object", "/sol_000/right/index_distal", "/sol_000/contacts", "/sol_000/forces"):
        assert viewer.server.scene.get_handle_by_name(name) is not None, name


def test_setting_the_frame_moves_the_hands_to_that_frames_pose(viewer):
    viewer.set_solution(None)
    for t in (0, FRAMES - 1, 3):
        viewer.set_frame(t)
        assert viewer.frame == t
        for sol in viewer.data.solutions:
            pose = sol.hands[0].link_pose[t, viewer.data.hand_meshes["right"].link]
            np.testing.assert_allclose(viewer.link_positions(sol.index, "right"), pose[:, :3, 3], atol=1e-6)
            node = viewer.nodes.links[(sol.index, "right")][-1][1]
            q = matrix_to_wxyz(pose[-1, :3, :3])
            assert min(np.abs(node.wxyz - q).max(), np.abs(node.wxyz + q).max()) < 1e-6
    viewer.set_frame(0)
    p0 = viewer.link_positions(0, "right")
    viewer.set_frame(FRAMES - 1)
    assert np.abs(viewer.link_positions(0, "right") - p0).max() > 0.01     # the fingers close by 0.6 rad
    assert f"frame {FRAMES - 1} / {FRAMES - 1}" in viewer.timeline.verdict.content


def test_solution_choice_hides_the_other_solutions(viewer):
    viewer.set_solution(1)
    assert viewer.timeline.shown() == [1]
    assert not viewer.nodes.groups[0].visible and viewer.nodes.groups[1].visible
    assert "sol_001" in viewer.timeline.verdict.content and "sol_000" not in viewer.timeline.verdict.content
    viewer.set_solution(None)
    assert viewer.nodes.groups[0].visible and viewer.nodes.groups[1].visible
    with pytest.raises(InputValueError, match="solution 5"):
        viewer.set_solution(5)
    with pytest.raises(InputValueError, match="frame"):
        viewer.set_frame(FRAMES)


def test_play_advances_the_frame(viewer):
    viewer.set_frame(0)
    viewer.timeline.fps.value = 60.0
    viewer.timeline.toggle()
    try:
        deadline = time.time() + 5.0
        while viewer.frame == 0 and time.time() < deadline:
            time.sleep(0.02)
    finally:
        viewer.timeline.toggle()
    assert viewer.frame != 0 and viewer.timeline.play.label == "play"


def test_frame_verdicts_agree_with_the_checker(result_dir):
    report = check_result(result_dir)
    verdicts = frame_verdicts(result_dir)
    assert len(verdicts) == len(report.solutions)
    for v, s in zip(verdicts, report.solutions):
        assert v.passed == s.passed and v.frame_ok.shape == (FRAMES,)
        for name, fig in s.figures.items():
            if fig.frame is None or name not in v.values:
                continue
            # the worst frame of every figure carries the checker's worst value (floored at 0 like the checker's)
            assert max(float(v.values[name][fig.frame]), 0.0) == pytest.approx(fig.value, rel=1e-9, abs=1e-12), name
            assert np.nanmax(v.values[name]) <= fig.value + 1e-12, name
            if not fig.ok:
                assert not v.frame_ok[fig.frame] and name in v.frame_failing[fig.frame], name
    assert "FAIL" in verdicts[0].describe(FRAMES - 1)


def test_bad_input_raises_one_line_torchhand_errors(result_dir, tmp_path):
    with pytest.raises(MissingFileError, match="does not exist"):
        serve(tmp_path / "nothing", port=0, block=False)
    (tmp_path / "empty").mkdir()
    with pytest.raises(MissingFileError, match="scene"):
        serve(tmp_path / "empty", port=0, block=False)
    with pytest.raises(InputValueError, match="solution"):
        serve(result_dir, port=0, solution="7", block=False, check=False)
    with pytest.raises(InputValueError, match="solution"):
        serve(result_dir, port=0, solution="first", block=False, check=False)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        port = s.getsockname()[1]
        with pytest.raises(PortInUseError, match=f"port {port}.*in use") as err:
            serve(result_dir, host="127.0.0.1", port=port, block=False, check=False)
    assert isinstance(err.value, TorchhandError) and "\n" not in str(err.value)


def test_cli_bad_input_exits_2_with_one_line(tmp_path, capsys):
    from torchhand.cli import main

    assert main(["view", str(tmp_path / "nothing")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("torchhand: error:") and "does not exist" in err[0]


def test_cli_prints_the_url_and_serves_until_interrupted(result_dir, monkeypatch, capsys):
    """The command prints http://HOST:PORT and the page answers there; the wait for Ctrl-C is replaced by a fetch of
    the page and a stop, after which the command returns 0 (Ctrl-C itself: ViewerHandle.wait catches it)."""
    import urllib.request

    from torchhand.cli import main
    from torchhand.view.server import ViewerHandle

    seen = {}

    def fake_wait(handle):       # stands in for the wait on Ctrl-C: fetch the page, then stop as Ctrl-C does
        seen["page"] = urllib.request.urlopen(handle.url, timeout=10).read()
        handle.stop()

    monkeypatch.setattr(ViewerHandle, "wait", fake_wait)
    assert main(["view", str(result_dir), "--port", "0", "--no-check", "--solution", "1"]) == 0
    out = capsys.readouterr().out
    urls = [w for w in out.split() if w.startswith("http://127.0.0.1:")]
    assert urls and b"<html" in seen["page"].lower()


# --- in a real browser --------------------------------------------------------------------------------------------

def _chromium() -> str | None:
    for path in (shutil.which("chromium"), "/usr/bin/chromium", shutil.which("chromium-browser")):
        if path and Path(path).exists():
            return path
    return None


CHROMIUM_ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]
"""Software WebGL (SwiftShader through ANGLE) in a headless Chromium without a GPU."""


def _image(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(np.float64)


def _wait_text(page, text: str, timeout_ms: int = 20000) -> None:
    page.wait_for_function("t => document.body.innerText.includes(t)", arg=text, polling=100, timeout=timeout_ms)


def _canvas_shot(page, settle: float = 0.6) -> np.ndarray:
    time.sleep(settle)
    return _image(page.locator("canvas").first.screenshot())


def test_in_a_real_browser(result_dir):
    """Chromium opens the page, the panel shows every control and both solutions' verdicts, pressing End on the
    frame slider moves the server to the last frame and the hands there, and the canvas shows a scene that is
    not blank and changes between frames."""
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (test extra)")
    exe = _chromium()
    if exe is None:
        pytest.skip("no system Chromium (apt-get install chromium); Playwright's own download is not used")
    handle = serve(result_dir, host="127.0.0.1", port=0, block=False)
    serving = threading.Thread(target=handle.wait, daemon=True)      # serves in the background as the command does
    serving.start()
    try:
        with sync_api.sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=exe, args=CHROMIUM_ARGS)
            try:
                _browse(browser, handle)
            finally:
                browser.close()
    finally:
        handle.stop()
        serving.join(timeout=10)


def _browse(browser, handle) -> None:
    page = browser.new_page(viewport={"width": 1000, "height": 700})
    page.goto(handle.url)
    last = FRAMES - 1
    _wait_text(page, f"frame 0 / {last}")                        # the panel arrived over the websocket
    deadline = time.time() + 10
    while handle.clients() < 1 and time.time() < deadline:
        time.sleep(0.05)
    assert handle.clients() == 1
    text = page.evaluate("document.body.innerText")
    for label in ("solution", "contacts", "forces", "frame", "play", "fps", "sol_000: FAIL", "sol_001: FAIL"):
        assert label in text, label
    assert page.locator(".torchhand-strip > div").count() == 2       # one pass/fail row per solution
    page.evaluate("document.querySelectorAll('.mantine-Notification-closeButton').forEach(b => b.click())")
    first = _wait_drawn(page)
    p0 = handle.link_positions(0, "right")
    slider = page.get_by_role("slider").first
    slider.focus()
    page.keyboard.press("End")                                      # through the page: the slider's own keys
    _wait_text(page, f"frame {last} / {last}")
    assert handle.frame == last
    assert np.abs(handle.link_positions(0, "right") - p0).max() > 0.01
    second = _canvas_shot(page)
    assert np.abs(second - first).mean() > 0.5, "the canvas did not change between frame 0 and the last"
    _assert_not_blank(second)


def _wait_drawn(page, timeout: float = 20.0) -> np.ndarray:
    """The canvas once it shows the scene (its pixels vary), polled."""
    deadline = time.time() + timeout
    while True:
        shot = _canvas_shot(page, 0.3)
        if shot.std() > 10 or time.time() > deadline:
            _assert_not_blank(shot)
            return shot


def _assert_not_blank(img: np.ndarray) -> None:
    assert img.std() > 10, f"the canvas is nearly uniform (pixel std {img.std():.1f})"
    colours = len(np.unique(img.reshape(-1, 3).astype(np.uint8), axis=0))
    assert colours > 50, f"only {colours} colours on the canvas"


def test_wait_serves_until_stopped_and_frees_the_port(result_dir):
    """handle.wait() (what the command runs) serves in its thread until handle.stop(); the port is free after."""
    handle = serve(result_dir, host="127.0.0.1", port=0, check=False, block=False)
    thread = threading.Thread(target=handle.wait, daemon=True)
    thread.start()
    time.sleep(0.2)
    assert thread.is_alive()
    handle.stop()
    thread.join(timeout=10)
    assert not thread.is_alive()
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.1", handle.port))
