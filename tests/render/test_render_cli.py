"""`torchhand render` and `torchhand plot`: outputs, formats, grid, compare, and one-line errors with exit code 2."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from torchhand.cli import main

REPO = Path(__file__).resolve().parents[2]


def _one_line_error(capsys, *needles):
    err = capsys.readouterr().err.strip()
    assert err.startswith("torchhand: error:") and "\n" not in err, err
    for n in needles:
        assert n in err, err
    return err


def test_render_mp4(box_turn_result, tmp_path, capsys):
    out = tmp_path / "clip.mp4"
    assert main(["render", str(box_turn_result), "--out", str(out), "--size", "321x241", "--frames", "0:10",
                 "--no-progress"]) == 0
    assert "10 frames, 320x240" in capsys.readouterr().out  # cropped to even sizes for yuv420p
    frames = iio.imread(out, plugin="pyav") if _has_pyav() else _ffmpeg_frames(out)
    assert frames.shape[0] == 10 and frames.shape[1:3] == (240, 320)
    assert frames.std() > 10
    assert not [p for p in tmp_path.iterdir() if p.name != "clip.mp4"]  # no temporary files left behind


def _has_pyav() -> bool:
    try:
        import av  # noqa: F401
        return True
    except ImportError:
        return False


def _ffmpeg_frames(path: Path) -> np.ndarray:
    import imageio.v2 as iio2

    with iio2.get_reader(str(path), format="FFMPEG") as r:
        return np.stack([f for f in r])


def test_render_grid_gif_and_png_frames(box_turn_result, tmp_path):
    gif = tmp_path / "grid.gif"
    assert main(["render", str(box_turn_result), "--out", str(gif), "--grid", "--size", "96x72", "--no-shadows",
                 "--frames", "0:4", "--no-progress"]) == 0
    frames = iio.imread(gif, index=None)
    from torchhand.render.overlay import grid_shape

    rows, cols = grid_shape(len(list((box_turn_result / "solutions").glob("sol_*.npz"))))
    assert frames.shape[0] == 4 and frames.shape[1:3] == (rows * 72 + 2 * (rows - 1), cols * 96 + 2 * (cols - 1))
    png = tmp_path / "frames"
    assert main(["render", str(box_turn_result), "--out", str(png), "--format", "png", "--size", "96x72",
                 "--frames", "2:5", "--orbit", "--no-shadows", "--no-progress"]) == 0
    files = sorted(png.iterdir())
    assert [f.name for f in files] == ["frame_00000.png", "frame_00001.png", "frame_00002.png"]
    assert iio.imread(files[0]).shape == (72, 96, 3)


def test_render_one_png_image(box_turn_result, tmp_path, capsys):
    """An --out ending in .png is one image of one frame; more frames are refused with exit 2 before drawing."""
    still = tmp_path / "still.png"
    assert main(["render", str(box_turn_result), "--out", str(still), "--size", "96x72", "--frames", "3:4",
                 "--no-shadows", "--no-progress"]) == 0
    assert still.is_file() and iio.imread(still).shape == (72, 96, 3)
    capsys.readouterr()
    many = tmp_path / "many.png"
    assert main(["render", str(box_turn_result), "--out", str(many), "--size", "96x72", "--frames", "0:3",
                 "--no-shadows", "--no-progress"]) == 2
    _one_line_error(capsys, "many.png", "3 frame(s)", "--frames A:A+1")
    assert not many.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["still.png"]


def test_render_compare_with_solution_npz(box_turn_result, tmp_path):
    ref = box_turn_result / "solutions" / "sol_001.npz"
    out = tmp_path / "cmp"
    assert main(["render", str(box_turn_result), "--out", str(out), "--compare", str(ref), "--size", "96x72",
                 "--frames", "0:1", "--no-shadows", "--no-progress"]) == 0
    img = iio.imread(out / "frame_00000.png")
    assert img.shape == (72, 2 * 96 + 2, 3)
    assert np.abs(img[:, :96].astype(int) - img[:, 98:].astype(int)).mean() > 0.5  # two different motions


def test_render_missing_result_dir(tmp_path, capsys):
    assert main(["render", str(tmp_path / "nope"), "--out", str(tmp_path / "x.mp4")]) == 2
    _one_line_error(capsys, "does not exist")


def test_render_corrupt_npz(box_turn_result, tmp_path, capsys):
    bad = tmp_path / "result"
    shutil.copytree(box_turn_result, bad)
    (bad / "solutions" / "sol_000.npz").write_bytes(b"PK\x03\x04 this is not a zip archive")
    assert main(["render", str(bad), "--out", str(tmp_path / "x.gif"), "--no-progress"]) == 2
    _one_line_error(capsys, "sol_000.npz", "not a readable solution npz")
    assert not (tmp_path / "x.gif").exists()


def test_render_npz_missing_key(box_turn_result, tmp_path, capsys):
    bad = tmp_path / "result"
    shutil.copytree(box_turn_result, bad)
    f = bad / "solutions" / "sol_000.npz"
    data = dict(np.load(f))
    del data["root_pose"]
    np.savez(f, **data)
    assert main(["render", str(bad), "--out", str(tmp_path / "x.gif")]) == 2
    _one_line_error(capsys, "root_pose")


def test_render_missing_ffmpeg(box_turn_result, tmp_path, capsys, monkeypatch):
    import imageio_ffmpeg

    def no_ffmpeg():
        raise RuntimeError("No ffmpeg exe could be found")

    monkeypatch.setattr(imageio_ffmpeg, "get_ffmpeg_exe", no_ffmpeg)
    out = tmp_path / "clip.mp4"
    assert main(["render", str(box_turn_result), "--out", str(out)]) == 2
    _one_line_error(capsys, "ffmpeg", "pip install imageio-ffmpeg")
    assert not out.exists()


def test_bad_arguments(box_turn_result, tmp_path, capsys):
    for args, needle in ((["--size", "640by480"], "--size"), (["--frames", "5:2"], "--frames"),
                         (["--solutions", "7"], "--solutions"), (["--fps", "-3"], "--fps")):
        assert main(["render", str(box_turn_result), "--out", str(tmp_path / "x.gif"), *args]) == 2
        _one_line_error(capsys, needle)


def test_plot_writes_pngs(box_turn_result, two_hand_result, tmp_path, capsys):
    out = tmp_path / "plots"
    assert main(["plot", str(box_turn_result), "--out", str(out)]) == 0
    capsys.readouterr()
    names = {"contact_timeline.png", "forces.png", "joints.png"}
    assert {p.name for p in out.iterdir()} == names
    for name in names:
        img = iio.imread(out / name)
        assert img.ndim == 3 and img.shape[0] > 200 and img.shape[1] > 400
        assert img[..., :3].std() > 10 and len(np.unique(img[..., :3].reshape(-1, 3), axis=0)) > 20
    out2 = tmp_path / "plots2"
    assert main(["plot", str(two_hand_result), "--out", str(out2)]) == 0
    assert {p.name for p in out2.iterdir()} == {"contact_timeline.png", "forces.png", "joints_right.png",
                                                "joints_left.png"}


def test_plot_missing_dir(tmp_path, capsys):
    assert main(["plot", str(tmp_path / "nope"), "--out", str(tmp_path / "p")]) == 2
    _one_line_error(capsys, "does not exist")


def test_imports_stay_light_and_leave_the_platform_alone():
    code = ("import os, sys, json; os.environ.pop('PYOPENGL_PLATFORM', None)\n"
            "import torchhand, torchhand.render, torchhand.render.jobs, torchhand.cli\n"
            "torchhand.cli.build_parser()\n"
            "print(json.dumps([sorted(m for m in sys.modules if m.split('.')[0] in ('pyrender', 'OpenGL', "
            "'matplotlib')), os.environ.get('PYOPENGL_PLATFORM')]))")
    env = {k: v for k, v in os.environ.items() if k != "PYOPENGL_PLATFORM"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, env=env,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    mods, platform = json.loads(out.stdout.strip().splitlines()[-1])
    assert mods == [] and platform is None
