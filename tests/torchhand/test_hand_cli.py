"""`torchhand hand show` and `torchhand hand render`: how a hand file was read (palm, thumb, side, root joints,
mount, couplings, fingers) and its picture."""

from __future__ import annotations

import re

import numpy as np
import pytest

from tests.conftest import shared_path
from torchhand.cli import main

# file under hands/ -> (palm link, thumb finger, side, root joints)
HAND_FILES = {
    "shadow_hand/right_hand.xml": ("rh_palm", "th", "right", ["rh_WRJ2", "rh_WRJ1"]),
    "shadow_hand/left_hand.xml": ("lh_palm", "th", "left", ["lh_WRJ2", "lh_WRJ1"]),
    "allegro_hand/right_hand.xml": ("palm", "th", "right", []),
    "allegro_hand/left_hand.xml": ("palm", "th", "left", []),
    "urdf/leap_hand/leap_hand_right.urdf": ("palm_lower", "thumb", "right", []),
    "urdf/allegro_hand/allegro_hand_right.urdf": ("base_link", "thumb", "right", []),
}

# A slide joint below the palm (a lift), three fingers and a thumb of two hinges each.
SLIDE_MJCF = """<mujoco model="slider"><compiler angle="radian"/><worldbody><body name="base">
<geom type="box" size="0.02 0.02 0.02"/>
<body name="carriage" pos="0 0 0.03"><joint name="lift" type="slide" axis="0 0 1" range="-0.02 0.05"/>
<geom type="box" size="0.04 0.01 0.01"/>
<body name="palm" pos="0 0 0.02"><geom type="box" size="0.04 0.01 0.03"/>
{fingers}
</body></body></body></worldbody></mujoco>"""
FINGER = ('<body name="{n}1" pos="{x} 0 0.04"><joint name="{n}1" axis="1 0 0" range="0 1.5"/>'
          '<geom type="capsule" fromto="0 0 0 0 0 0.03" size="0.008"/><body name="{n}2" pos="0 0 0.03">'
          '<joint name="{n}2" axis="1 0 0" range="0 1.5"/><geom type="capsule" fromto="0 0 0 0 0 0.025" '
          'size="0.007"/></body></body>')
THUMB = ('<body name="t1" pos="0.045 -0.02 0"><joint name="t1" axis="0 0 1" range="0 1.5"/><geom type="capsule" '
         'fromto="0 0 0 0.03 -0.01 0.01" size="0.008"/><body name="t2" pos="0.03 -0.01 0.01"><joint name="t2" '
         'axis="0 0 1" range="0 1.5"/><geom type="capsule" fromto="0 0 0 0.025 0 0.01" size="0.007"/></body></body>')


def _show(capsys, *argv) -> str:
    assert main(["hand", "show", *argv]) == 0
    return capsys.readouterr().out


def _field(out: str, key: str) -> str:
    m = re.search(rf"^{key}: (.*)$", out, re.MULTILINE)
    assert m, f"no {key!r} line in:\n{out}"
    return m.group(1)


def _root_joints(out: str) -> list[tuple[str, str]]:
    """(name, rest of the line) of each joint listed under "root joints"."""
    lines = out.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("root joints"))
    rows = []
    for line in lines[start + 1:]:
        if not line.startswith("  "):
            break
        rows.append((line.split()[1], line))
    return rows


def test_show_default_hand(capsys):
    out = _show(capsys)
    assert _field(out, "palm").startswith("palm (link 0")
    assert _field(out, "thumb").startswith("'thumb'")
    assert _field(out, "side").startswith("right (built-in")
    assert _root_joints(out) == [] and out.count("root joints") == 1 and "none" in out.split("root joints")[1]
    assert "couplings: none" in out
    assert re.search(r"^mount \(hand frame.*\n  origin \(.*\) mm +x \(.*\) +y \(.*\)$", out, re.MULTILINE)
    assert "flexion index_mcp_flex, index_pip, index_dip; tip (" in out
    assert "total mass 0.4200 kg" in out                               # what it printed before stays


@pytest.mark.parametrize("name", sorted(HAND_FILES))
def test_show_hand_files(capsys, name):
    path = shared_path("hands", *name.split("/"))
    palm, thumb, side, root = HAND_FILES[name]
    out = _show(capsys, str(path))
    assert _field(out, "palm").startswith(f"{palm} (")
    assert _field(out, "thumb").startswith(f"{thumb!r} (")
    assert _field(out, "side") == f"{side} (from the thumb's position)"
    assert [n for n, _ in _root_joints(out)] == root
    assert all("hinge" in line and line.endswith("deg") for _, line in _root_joints(out))
    assert re.search(r"^mount \(hand frame.*\n  origin \(.*\) mm +x \(.*\) +y \(.*\)$", out, re.MULTILINE)
    assert out.count("; tip (") == len(re.findall(r"^  \S.* > ", out, re.MULTILINE))   # every finger has a tip
    if name.startswith("shadow"):
        assert "tendon" in out and f"{'rh' if side == 'right' else 'lh'}_FFJ0" in out
    else:
        assert "couplings: none" in out


def test_show_mjcf_option_is_an_alias(capsys):
    path = shared_path("hands", "allegro_hand", "left_hand.xml")
    assert _field(_show(capsys, "--mjcf", str(path)), "side") == "left (from the thumb's position)"


def test_show_slide_joint_in_metres(capsys, tmp_path):
    fingers = "".join(FINGER.format(n=n, x=x) for n, x in (("fa", -0.03), ("fb", 0.0), ("fc", 0.03))) + THUMB
    path = tmp_path / "slider.xml"
    path.write_text(SLIDE_MJCF.format(fingers=fingers))
    out = _show(capsys, str(path))
    assert [n for n, _ in _root_joints(out)] == ["lift"]
    lift = [line for line in out.splitlines() if " lift " in line]
    assert len(lift) == 2 and all(line.endswith("[-0.0200,  0.0500] m") for line in lift), lift
    assert "[    0.0,    85.9] deg" in out                                # hinges stay in degrees


def _pixels_varied(png) -> float:
    import matplotlib.image

    img = matplotlib.image.imread(str(png))
    assert img.ndim == 3 and img.shape[0] >= 300 and img.shape[1] >= 600, img.shape
    rgb = img[..., :3]
    background = rgb[2, 2]
    return float(np.mean(np.abs(rgb - background).max(axis=-1) > 0.05))


@pytest.mark.parametrize("source", ["default", "leap"])
def test_render_writes_a_png(capsys, tmp_path, source):
    argv = [] if source == "default" else [str(shared_path("hands", "urdf", "leap_hand", "leap_hand_right.urdf"))]
    out = tmp_path / "hand.png"
    assert main(["hand", "render", *argv, "--out", str(out)]) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert _pixels_varied(out) > 0.01
    assert [p.name for p in tmp_path.iterdir()] == ["hand.png"]          # no temporary file left behind


def test_render_q_zero(capsys, tmp_path):
    out = tmp_path / "zero.png"
    assert main(["hand", "render", "--q", "zero", "--side", "left", "--out", str(out)]) == 0
    assert "q = zero" in capsys.readouterr().out and _pixels_varied(out) > 0.01


@pytest.mark.parametrize("action", ["show", "render"])
def test_missing_file_is_one_line_exit_2(capsys, tmp_path, action):
    argv = ["hand", action, str(tmp_path / "missing.xml")] + (["--out", str(tmp_path / "h.png")]
                                                              if action == "render" else [])
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("torchhand: error:") and "missing.xml" in err[0], err


def test_render_bad_output_folder_is_exit_2(capsys, tmp_path):
    assert main(["hand", "render", "--out", str(tmp_path / "nowhere" / "h.png")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--out" in err[0] and "nowhere" in err[0], err


def test_no_hand_frame_is_reported_and_drawn_along_root_axes(capsys, tmp_path, monkeypatch):
    import torchhand.hand.mount as mount
    from torchhand.errors import InputValueError

    def no_frame(model):
        raise InputValueError(f"hand {model.name!r}: cannot find its hand frame")

    monkeypatch.setattr(mount, "hand_frame", no_frame)
    assert _field(_show(capsys), "mount") == "no hand frame: hand 'default_right': cannot find its hand frame"
    out = tmp_path / "hand.png"
    assert main(["hand", "render", "--out", str(out)]) == 0 and _pixels_varied(out) > 0.01
