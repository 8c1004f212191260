"""BVH reader and writer: parsing, per-joint channel orders against SciPy, malformed files, the shared mocap data
(position channels replace the OFFSET, Leap's leading zero row), Euler conversions against SciPy, and read -> write
-> read on every shared file."""

from __future__ import annotations

import math
import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from torchhand.scene.bvh import euler_to_matrix, matrix_to_euler, read_bvh, unwrap_euler, write_bvh
from torchhand.errors import (FileFormatError, InputTypeError, InputValueError, MissingFileError, ShapeError,
                              TorchhandError, UnknownNameError)

from tests.conftest import shared_data_dir as shared_data


MOCAP = shared_data() / "mocap"
ALL_BVH = sorted(MOCAP.glob("**/*.bvh")) if MOCAP.is_dir() else []
EVERY_BVH = sorted(shared_data().glob("**/*.bvh")) if shared_data().is_dir() else []
CMU = MOCAP / "cmu_body_frozen_hands" / "01-01_v01.bvh"
LEAP = sorted((MOCAP / "leap_hand_bvh").glob("*.bvh")) if (MOCAP / "leap_hand_bvh").is_dir() else []
LEAP_GESTURES = [p for p in LEAP if p.name != "air-hand_hand1.bvh"]
ORDERS = ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX")
TOL = {torch.float32: 2e-6, torch.float64: 1e-12}        # matrix entries, per dtype

SMALL = """HIERARCHY
ROOT hips
{
  OFFSET 1.0 2.0 3.0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT arm
  {
    OFFSET 0.0 1.0 0.0
    CHANNELS 3 Yrotation Xrotation Zrotation
    End Site
    {
      OFFSET 0.5 0.0 0.0
    }
  }
  JOINT leg {
    OFFSET 0.0 -1.0 0.0
    CHANNELS 3 Xrotation Yrotation Zrotation
    End Site { OFFSET 0 -0.5 0 }
  }
}
MOTION
Frames: 2
Frame Time: 0.0333333
0.1 0.2 0.3 10 20 30 40 50 60 5 -15 25
-1 -2 -3 -90 45 0 0 0 90 0 0 0
"""


def write(tmp_path: Path, text: str, name: str = "clip.bvh") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_small_structure(tmp_path):
    clip = read_bvh(write(tmp_path, SMALL))
    assert clip.names == ("hips", "arm", "arm_end", "leg", "leg_end")
    assert clip.parents == (-1, 0, 1, 0, 3)
    assert clip.is_end_site == (False, False, True, False, True)
    assert clip.channels[0] == ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
    assert clip.channels[2] == ()
    assert clip.motion.shape == (2, 12) and clip.motion.dtype == np.float64
    assert clip.num_frames == 2 and clip.extra_lines_dropped == 0
    assert clip.frame_time == pytest.approx(0.0333333)
    np.testing.assert_allclose(clip.offsets[2], [0.5, 0.0, 0.0])
    assert clip.joint_index("leg") == 3
    with pytest.raises(UnknownNameError, match="hips"):
        clip.joint_index("nope")


def _reference_global(clip, f):
    """Independent FK with SciPy's intrinsic Euler rotations (uppercase order = intrinsic)."""
    out = []
    col = 0
    for j, chans in enumerate(clip.channels):
        vals = clip.motion[f, col:col + len(chans)]
        col += len(chans)
        pos = np.array(clip.offsets[j], dtype=float)
        rot_axes, rot_vals = "", []
        for ch, v in zip(chans, vals):
            if ch.endswith("position"):
                pos["XYZ".index(ch[0])] = v            # a position channel replaces that axis of the OFFSET
            else:
                rot_axes += ch[0]
                rot_vals.append(v)
        L = np.eye(4)
        if rot_axes:
            L[:3, :3] = Rotation.from_euler(rot_axes, rot_vals, degrees=True).as_matrix()
        L[:3, 3] = pos
        p = clip.parents[j]
        out.append(L if p < 0 else out[p] @ L)
    return np.stack(out)


def test_small_global_transforms_match_scipy(tmp_path):
    clip = read_bvh(write(tmp_path, SMALL))
    G = clip.global_transforms()
    assert G.shape == (2, 5, 4, 4) and G.dtype == torch.float64
    for f in range(2):
        np.testing.assert_allclose(G[f].numpy(), _reference_global(clip, f), atol=1e-12)
    # the root's rotation is Rz Rx Ry in the listed order (not the extrinsic reading)
    R = Rotation.from_euler("ZXY", [10, 20, 30], degrees=True).as_matrix()
    np.testing.assert_allclose(G[0, 0, :3, :3].numpy(), R, atol=1e-12)
    np.testing.assert_allclose(G[0, 0, :3, 3].numpy(), [0.1, 0.2, 0.3], atol=1e-12)   # channels, not OFFSET + them
    # End Site: parent transform applied to its offset
    np.testing.assert_allclose(G[:, 2, :3, 3].numpy(),
                               (G[:, 1] @ torch.tensor([0.5, 0.0, 0.0, 1.0], dtype=torch.float64))[:, :3].numpy())
    # frame selection
    np.testing.assert_allclose(clip.global_transforms(frames=[1])[0].numpy(), G[1].numpy())
    np.testing.assert_allclose(clip.global_transforms(frames=1)[0].numpy(), G[1].numpy())
    rest = clip.rest_transforms()                          # position channels at their OFFSET
    np.testing.assert_allclose(rest[0, :3, 3].numpy(), [1.0, 2.0, 3.0])
    np.testing.assert_allclose(rest[2, :3, 3].numpy(), [1.5, 3.0, 3.0])


def test_position_channels_replace_the_offset_on_any_joint(tmp_path):
    text = SMALL.replace("CHANNELS 3 Yrotation Xrotation Zrotation",
                         "CHANNELS 5 Yposition Zposition Yrotation Xrotation Zrotation")
    text = text.replace("0.1 0.2 0.3 10 20 30 40 50 60", "0.1 0.2 0.3 10 20 30 7 8 40 50 60")
    text = text.replace("-1 -2 -3 -90 45 0 0 0 90", "-1 -2 -3 -90 45 0 7 8 0 0 90")
    clip = read_bvh(write(tmp_path, text))
    local = clip.local_transforms()
    np.testing.assert_allclose(local[:, 1, :3, 3].numpy(), [[0.0, 7.0, 8.0]] * 2)   # x from OFFSET, y z replaced
    np.testing.assert_allclose(clip.rest_transforms()[1, :3, 3].numpy(), [1.0, 3.0, 3.0])


def test_euler_to_matrix_orders():
    g = torch.Generator().manual_seed(0)
    angles = (torch.rand(7, 3, generator=g, dtype=torch.float64) - 0.5) * 6
    for order in ("XYZ", "YXZ", "ZYX", "ZXY"):
        ref = Rotation.from_euler(order, angles.numpy()).as_matrix()
        np.testing.assert_allclose(euler_to_matrix(angles, order).numpy(), ref, atol=1e-12)
    with pytest.raises(TorchhandError):
        euler_to_matrix(angles, "XQZ")


def test_extra_motion_line_is_dropped(tmp_path):
    text = SMALL.rstrip("\n") + "\n0 0 0 0 0 0 0 0 0 0 0 0\n"
    clip = read_bvh(write(tmp_path, text))
    assert clip.num_frames == 2 and clip.extra_lines_dropped == 1 and clip.extra_line_dropped_at == "last"
    np.testing.assert_allclose(clip.motion[0, :3], [0.1, 0.2, 0.3])
    assert read_bvh(write(tmp_path, SMALL)).extra_line_dropped_at is None


def test_leading_zero_line_is_dropped(tmp_path):
    text = SMALL.replace("Frame Time: 0.0333333\n", "Frame Time: 0.0333333\n0 0 0 0.0 -0 0 0 0 0 0 0 0.000\n")
    clip = read_bvh(write(tmp_path, text))
    assert clip.num_frames == 2 and clip.extra_lines_dropped == 1 and clip.extra_line_dropped_at == "first"
    np.testing.assert_allclose(clip.motion[:, 0], [0.1, -1.0])          # the last line is real data, kept
    # a leading zero row when the count is right is a frame like any other
    text = SMALL.replace("Frames: 2\nFrame Time: 0.0333333\n", "Frames: 3\nFrame Time: 0.0333333\n" + "0 " * 12 + "\n")
    clip = read_bvh(write(tmp_path, text))
    assert clip.num_frames == 3 and clip.extra_lines_dropped == 0 and not clip.motion[0].any()


def test_blank_lines_and_crlf(tmp_path):
    text = SMALL.replace("\n", "\r\n") + "\r\n\r\n"
    clip = read_bvh(write(tmp_path, text))
    assert clip.num_frames == 2


MALFORMED = {
    "no hierarchy": (SMALL.replace("HIERARCHY", "HIERARCHI"), 1, "HIERARCHY"),
    "no motion": (SMALL.split("MOTION")[0], None, "MOTION"),
    "channel count": (SMALL.replace("CHANNELS 3 Yrotation Xrotation Zrotation",
                                    "CHANNELS 3 Yrotation Xrotation"), 9, "declares 3 channels"),
    "unknown channel": (SMALL.replace("CHANNELS 3 Xrotation", "CHANNELS 3 Wrotation"), 17, "declares 3"),
    "non-numeric": (SMALL.replace("-1 -2 -3", "-1 abc -3"), 25, "non-numeric"),
    "nan value": (SMALL.replace("-1 -2 -3", "-1 nan -3"), 25, "non-finite"),
    "values per line": (SMALL.replace("5 -15 25", "5 -15"), 24, "11 values"),
    "too few frames": (SMALL.replace("Frames: 2", "Frames: 5"), None, "'Frames: 5'"),
    "too many frames": (SMALL.replace("Frames: 2", "Frames: 0"), None, "Frames"),
    "two extra lines": (SMALL.rstrip("\n") + "\n" + "0 " * 12 + "\n" + "0 " * 12 + "\n", None, "motion lines"),
    "frame time": (SMALL.replace("Frame Time: 0.0333333", "Frame Time: fast"), 23, "Frame Time"),
    "unbalanced braces": (SMALL.replace("MOTION", "}\nMOTION"), None, "ROOT"),
    "missing brace": (SMALL.replace("    End Site\n    {\n      OFFSET 0.5 0.0 0.0\n    }\n", "    End Site\n"),
                      None, "expected"),
    "bad offset": (SMALL.replace("OFFSET 0.0 1.0 0.0", "OFFSET 0.0 one 0.0"), 8, "number"),
}


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_malformed_files_name_file_and_line(tmp_path, case):
    text, line, fragment = MALFORMED[case]
    p = write(tmp_path, text, "bad.bvh")
    with pytest.raises(FileFormatError) as info:
        read_bvh(p)
    msg = str(info.value)
    assert str(p) in msg
    assert fragment in msg
    if line is not None:
        assert f"{p}:{line}:" in msg
    else:
        assert f"{p}:" in msg


def test_missing_file(tmp_path):
    with pytest.raises(MissingFileError, match="nope.bvh"):
        read_bvh(tmp_path / "nope.bvh")


def test_empty_file(tmp_path):
    with pytest.raises(FileFormatError, match="HIERARCHY"):
        read_bvh(write(tmp_path, ""))


# ---------------------------------------------------------------------------------------------------------------
# the shared reference data


@pytest.mark.skipif(not ALL_BVH, reason=f"no BVH files under {MOCAP} (set TORCHHAND_SHARED_DATA)")
@pytest.mark.parametrize("path", ALL_BVH, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_shared_bvh_files(path):
    clip = read_bvh(path)
    frames = np.linspace(0, clip.num_frames - 1, min(clip.num_frames, 40)).astype(int)
    G = clip.global_transforms(frames)
    assert G.shape == (len(frames), clip.num_joints, 4, 4)
    assert torch.isfinite(G).all()
    R = G[..., :3, :3]
    eye = torch.eye(3, dtype=torch.float64)
    assert (R.transpose(-1, -2) @ R - eye).abs().max() < 1e-9
    for k in (0, len(frames) - 1):
        np.testing.assert_allclose(G[k].numpy(), _reference_global(clip, int(frames[k])), atol=1e-9 * max(
            1.0, float(np.abs(clip.motion).max())))
    if path.parent.name == "leap_hand_bvh":
        # the documented quirk: one more motion line than 'Frames:' says (all but the 19-frame file), a leading
        # all-zero row
        gesture = path.name != "air-hand_hand1.bvh"
        assert clip.extra_lines_dropped == int(gesture)
        assert clip.extra_line_dropped_at == ("first" if gesture else None)
    else:
        assert clip.extra_lines_dropped == 0 and clip.extra_line_dropped_at is None
    if path.parent.name == "mug1":
        assert clip.num_frames == 4000 and clip.fps == pytest.approx(120.0, rel=1e-6)
        assert all(c[-3:] == ("Yrotation", "Xrotation", "Zrotation") for c in clip.channels if c)


@pytest.mark.skipif(not CMU.is_file(), reason=f"CMU body absent: {CMU} (set TORCHHAND_SHARED_DATA)")
def test_cmu_body_stands_on_the_floor():
    # metres, z up; every non-root joint with position channels holds its OFFSET there, and 'pelvis' carries the
    # root motion: adding channels to offsets put the pelvis at 2.03 m and the feet never below 0.93 m
    clip = read_bvh(CMU)
    G = clip.global_transforms().numpy()
    assert 0.9 < G[:, clip.joint_index("pelvis"), 2, 3].mean() < 1.2
    feet = [j for j, n in enumerate(clip.names) if n.startswith(("foot_", "toes_"))]
    assert len(feet) == 6
    assert -0.01 <= G[:, feet, 2, 3].min() <= 0.15


@pytest.mark.skipif(not LEAP, reason=f"Leap clips absent under {MOCAP} (set TORCHHAND_SHARED_DATA)")
@pytest.mark.parametrize("path", LEAP, ids=lambda p: p.name)
def test_leap_hand_sits_at_its_offset(path):
    clip = read_bvh(path)
    G = clip.global_transforms()
    h = clip.joint_index("rHand")
    rel = (torch.linalg.inv(G[:, clip.parents[h]]) @ G[:, h])[:, :3, 3]
    np.testing.assert_allclose(rel.numpy(), np.broadcast_to(clip.offsets[h], rel.shape), atol=1e-9)


@pytest.mark.skipif(not LEAP_GESTURES, reason=f"Leap clips absent under {MOCAP} (set TORCHHAND_SHARED_DATA)")
@pytest.mark.parametrize("path", LEAP_GESTURES, ids=lambda p: p.name)
def test_leap_gestures_drop_the_leading_zero_row(path):
    assert len(LEAP_GESTURES) == 10
    clip = read_bvh(path)
    assert clip.extra_line_dropped_at == "first"
    lines = [ln for ln in path.read_text().splitlines() if ln.strip()]
    data = lines[next(i for i, ln in enumerate(lines) if ln.strip().upper() == "MOTION") + 3:]
    assert len(data) == clip.num_frames + 1
    assert not np.asarray(data[0].split(), dtype=float).any()
    np.testing.assert_array_equal(clip.motion[-1], np.asarray(data[-1].split(), dtype=float))   # real data, kept
    assert (clip.motion[:, :3] != 0).any(axis=1).all()                     # no frame at the sensor origin


# ---------------------------------------------------------------------------------------------------------------
# Euler angles


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("order", ORDERS)
def test_matrix_to_euler_against_scipy(order, dtype):
    rot = Rotation.random(500, random_state=3)
    R = torch.from_numpy(rot.as_matrix()).to(dtype)
    angles = matrix_to_euler(R, order)
    assert angles.shape == (500, 3) and angles.dtype == dtype
    torch.testing.assert_close(euler_to_matrix(angles, order), R, atol=TOL[dtype], rtol=0)
    # the same angles as SciPy's intrinsic (upper-case) convention: middle in [-pi/2, pi/2], others in (-pi, pi]
    ref = rot.as_euler(order)
    np.testing.assert_allclose(angles.double().numpy(), ref, atol=1e-5 if dtype == torch.float32 else 1e-10)
    # and SciPy's matrix of our angles is R
    np.testing.assert_allclose(Rotation.from_euler(order, angles.double().numpy()).as_matrix(),
                               R.double().numpy(), atol=1e-5 if dtype == torch.float32 else 1e-12)
    # batch ranks: (...,) leading shapes, and B = 1
    torch.testing.assert_close(matrix_to_euler(R.reshape(5, 100, 3, 3), order), angles.reshape(5, 100, 3))
    torch.testing.assert_close(matrix_to_euler(R[:1], order), angles[:1])
    torch.testing.assert_close(matrix_to_euler(R[0], order), angles[0])


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("order", ORDERS)
def test_matrix_to_euler_at_gimbal_lock(order, dtype):
    g = torch.Generator().manual_seed(1)
    angles = (torch.rand(40, 3, generator=g, dtype=torch.float64) - 0.5) * 2 * math.pi
    angles[:10, 1] = math.pi / 2
    angles[10:20, 1] = -math.pi / 2
    angles[20:30, 1] = math.pi / 2 - 1e-7                     # near the lock
    angles[30:, 1] = -math.pi / 2 + 1e-9
    R = euler_to_matrix(angles, order).to(dtype)
    out = matrix_to_euler(R, order)
    assert torch.isfinite(out).all()
    torch.testing.assert_close(euler_to_matrix(out, order), R, atol=10 * TOL[dtype], rtol=0)
    assert (out[:20, 0] == 0).all()                           # exact lock: the first angle is 0
    # with a reference the first angle follows it at the lock, and the result is the reference itself
    ref = angles.to(dtype)
    near = matrix_to_euler(R, order, reference=ref)
    torch.testing.assert_close(euler_to_matrix(near, order), R, atol=10 * TOL[dtype], rtol=0)
    torch.testing.assert_close(near[:20], ref[:20], atol=1e-5 if dtype == torch.float32 else 1e-12, rtol=0)


@pytest.mark.parametrize("order", ORDERS)
def test_matrix_to_euler_reference_picks_the_nearest_equivalent(order):
    g = torch.Generator().manual_seed(2)
    angles = (torch.rand(200, 3, generator=g, dtype=torch.float64) - 0.5) * 2 * math.pi
    R = euler_to_matrix(angles, order)
    base = matrix_to_euler(R, order)
    a, b, c = base.unbind(-1)
    twin = torch.stack([a + math.pi, math.pi - b, c + math.pi], -1)
    turns = torch.randint(-2, 3, (200, 3), generator=g).double() * 2 * math.pi
    for target in (base + turns, twin + turns):
        ref = target + 0.3 * (torch.rand(200, 3, generator=g, dtype=torch.float64) - 0.5)
        torch.testing.assert_close(matrix_to_euler(R, order, reference=ref), target, atol=1e-9, rtol=0)


def test_unwrap_euler_across_180_degrees():
    t = torch.linspace(0, 1, 400, dtype=torch.float64)
    # the first and third angles sweep through +-180 degrees, the middle one through +90 degrees (where the
    # canonical solution switches to its twin)
    truth = torch.stack([-2.0 + 7.0 * t, 1.25 + 0.6 * torch.sin(7.0 * t), 0.5 - 9.0 * t], -1)
    for order in ORDERS:
        R = euler_to_matrix(truth, order)
        wrapped = matrix_to_euler(R, order)
        assert (wrapped[1:] - wrapped[:-1]).abs().max() > 3.0          # jumps without unwrapping
        out = unwrap_euler(wrapped, order)
        torch.testing.assert_close(euler_to_matrix(out, order), R, atol=1e-12, rtol=0)
        assert (out[1:] - out[:-1]).abs().max() < 0.1                   # continuous
        torch.testing.assert_close(out, truth, atol=1e-9, rtol=0)      # the first frame is the truth's
        torch.testing.assert_close(out[0], wrapped[0])
    # frame by frame with matrix_to_euler's reference gives the same sequence
    R = euler_to_matrix(truth, "ZXY")
    prev, seq = truth[0], []
    for f in range(0, 400, 40):
        prev = matrix_to_euler(R[f], "ZXY", reference=prev)
        seq.append(prev)
    torch.testing.assert_close(torch.stack(seq), truth[::40], atol=1e-9, rtol=0)
    # float32, one frame, and bad input
    out32 = unwrap_euler(matrix_to_euler(R.float(), "ZXY"), "ZXY")
    torch.testing.assert_close(out32, truth.float(), atol=1e-4, rtol=0)
    assert unwrap_euler(truth[:1], "ZXY").shape == (1, 3)
    with pytest.raises(ShapeError, match="angles"):
        unwrap_euler(truth[None], "ZXY")
    with pytest.raises(InputValueError, match="order"):
        unwrap_euler(truth, "ZXZ")


def test_matrix_to_euler_bad_input():
    R = torch.eye(3).expand(4, 3, 3)
    with pytest.raises(InputValueError, match="order"):
        matrix_to_euler(R, "XYX")
    with pytest.raises(InputValueError, match="order"):
        matrix_to_euler(R, "XY")
    with pytest.raises(ShapeError, match="R: "):
        matrix_to_euler(torch.eye(4), "XYZ")
    with pytest.raises(InputTypeError, match="R: "):
        matrix_to_euler(torch.eye(3, dtype=torch.long), "XYZ")
    with pytest.raises(ShapeError, match="reference"):
        matrix_to_euler(R, "XYZ", reference=torch.zeros(3))
    assert isinstance(ShapeError("x"), TorchhandError)


# ---------------------------------------------------------------------------------------------------------------
# writing


def test_write_small_round_trip(tmp_path):
    clip = read_bvh(write(tmp_path, SMALL))
    out = write_bvh(clip, tmp_path / "out.bvh")
    assert out == tmp_path / "out.bvh"
    text = out.read_text()
    assert "End Site" in text and "arm_end" not in text and "Frames: 2\n" in text
    assert "Frame Time: 0.033333300\n" in text                         # at least 8 significant digits
    assert "\n0.100000 0.200000 0.300000 10.000000" in text            # %.6f
    back = read_bvh(out)
    assert (back.names, back.parents, back.channels, back.is_end_site) == (
        clip.names, clip.parents, clip.channels, clip.is_end_site)
    assert back.frame_time == clip.frame_time
    np.testing.assert_array_equal(back.offsets, clip.offsets)
    np.testing.assert_array_equal(back.motion, clip.motion)
    assert [ln for ln in out.read_text().splitlines() if ln.strip()] == [ln for ln in text.splitlines() if ln.strip()]
    write_bvh(clip, tmp_path / "p2.bvh", precision=2)
    assert "\n0.10 0.20 0.30 10.00" in (tmp_path / "p2.bvh").read_text()


def test_write_several_roots_and_joint_order(tmp_path):
    two = SMALL.replace("MOTION", "ROOT prop\n{\n  OFFSET 0 0 0\n  CHANNELS 3 Xposition Yposition Zposition\n}\nMOTION")
    two = two.replace("5 -15 25\n", "5 -15 25 7 8 9\n").replace("90 0 0 0\n", "90 0 0 0 -7 -8 -9\n")
    clip = read_bvh(write(tmp_path, two))
    assert clip.parents[-1] == -1 and clip.names[-1] == "prop"
    back = read_bvh(write_bvh(clip, tmp_path / "out.bvh"))
    assert back.names == clip.names and back.parents == clip.parents
    np.testing.assert_array_equal(back.motion, clip.motion)
    # joints listed in another (valid) order are written depth-first, with their motion columns
    perm = [0, 3, 1, 4, 2, 5]                                           # hips, leg, arm, leg_end, arm_end, prop
    old_to_new = {o: n for n, o in enumerate(perm)}
    cols = [clip.channel_start[j] + i for j in perm for i in range(len(clip.channels[j]))]
    shuffled = replace(clip, names=tuple(clip.names[j] for j in perm),
                       parents=tuple(old_to_new.get(clip.parents[j], -1) for j in perm),
                       offsets=clip.offsets[perm], channels=tuple(clip.channels[j] for j in perm),
                       is_end_site=tuple(clip.is_end_site[j] for j in perm), motion=clip.motion[:, cols])
    back = read_bvh(write_bvh(shuffled, tmp_path / "shuffled.bvh"))
    assert back.names == ("hips", "leg", "leg_end", "arm", "arm_end", "prop")     # children in index order
    G, G_back = clip.global_transforms(), back.global_transforms()
    for j, name in enumerate(clip.names):
        k = back.joint_index(name)
        assert back.channels[k] == clip.channels[j]
        np.testing.assert_array_equal(G_back[:, k].numpy(), G[:, j].numpy())


def test_with_motion(tmp_path):
    clip = read_bvh(write(tmp_path, SMALL.rstrip("\n") + "\n" + "0 " * 12 + "\n"))
    new = clip.with_motion(torch.zeros(5, 12), frame_time=0.01)
    assert new.num_frames == 5 and new.frame_time == 0.01 and new.extra_lines_dropped == 0
    assert new.extra_line_dropped_at is None and new.names == clip.names and new.motion.dtype == np.float64
    assert not new.motion.flags.writeable
    assert clip.with_motion(clip.motion[:1]).frame_time == clip.frame_time
    with pytest.raises(ShapeError, match=r"motion: expected shape \(F, 12\)"):
        clip.with_motion(np.zeros((5, 11)))
    with pytest.raises(ShapeError, match="motion"):
        clip.with_motion(np.zeros((0, 12)))
    with pytest.raises(InputValueError, match="frame 0, column 2"):
        clip.with_motion(np.where(np.eye(2, 12, 2, dtype=bool), np.inf, 0.0))
    with pytest.raises(InputValueError, match="frame_time"):
        clip.with_motion(clip.motion, frame_time=0.0)


def test_write_bad_input_leaves_nothing_behind(tmp_path, monkeypatch):
    clip = read_bvh(write(tmp_path, SMALL))
    target = tmp_path / "keep.bvh"
    target.write_text("old")
    cases = [
        (replace(clip, motion=clip.motion[:, :11]), ShapeError, r"clip\.motion: expected shape \(F, 12\)"),
        (replace(clip, motion=np.where(np.eye(2, 12, 4, dtype=bool), np.nan, clip.motion)), InputValueError,
         "non-finite value at frame 0, column 4"),
        (replace(clip, offsets=np.where(np.eye(5, 3, dtype=bool), np.inf, clip.offsets)), InputValueError,
         "OFFSET"),
        (replace(clip, frame_time=-1.0), InputValueError, "frame_time"),
        (replace(clip, names=("hips", "left arm") + clip.names[2:]), InputValueError, "left arm"),
        (replace(clip, parents=(-1, 2, 1, 0, 3)), InputValueError, "clip.parents"),
        (replace(clip, channels=clip.channels[:2] + (("Xrotation",),) + clip.channels[3:]), InputValueError,
         "End Site"),
    ]
    for bad, err, fragment in cases:
        with pytest.raises(err, match=fragment) as info:
            write_bvh(bad, target)
        assert "\n" not in str(info.value)
    with pytest.raises(InputTypeError, match="clip"):
        write_bvh("clip.bvh", target)
    with pytest.raises(InputValueError, match="precision"):
        write_bvh(clip, target, precision=-1)
    with pytest.raises(MissingFileError, match="nope"):
        write_bvh(clip, tmp_path / "nope" / "out.bvh")
    with pytest.raises(InputValueError, match="folder"):
        write_bvh(clip, tmp_path)
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.bvh", "keep.bvh"]
    # an error while writing leaves the old file and no temporary file
    def broken_fsync(fd):
        raise OSError("disk full")

    with monkeypatch.context() as patch:
        patch.setattr(os, "fsync", broken_fsync)
        with pytest.raises(OSError, match="disk full"):
            write_bvh(clip, target)
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.bvh", "keep.bvh"]
    write_bvh(clip, target)                                             # and a good write replaces it
    assert read_bvh(target).num_frames == 2


@pytest.mark.skipif(not EVERY_BVH, reason=f"no BVH files under {shared_data()} (set TORCHHAND_SHARED_DATA)")
@pytest.mark.parametrize("path", EVERY_BVH, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_round_trip_every_shared_file(tmp_path, path):
    clip = read_bvh(path)
    out = write_bvh(clip, tmp_path / path.name)
    back = read_bvh(out)
    assert back.names == clip.names and back.parents == clip.parents
    assert back.channels == clip.channels and back.is_end_site == clip.is_end_site
    assert back.num_frames == clip.num_frames and back.extra_lines_dropped == 0
    assert back.frame_time == pytest.approx(clip.frame_time, rel=1e-12, abs=0)
    np.testing.assert_allclose(back.offsets, clip.offsets, rtol=0, atol=1e-6)
    np.testing.assert_allclose(back.motion, clip.motion, rtol=0, atol=1e-6)
    np.testing.assert_allclose(back.global_transforms().numpy(), clip.global_transforms().numpy(), rtol=0, atol=1e-6)
    # exactly 'Frames:' motion lines (Leap's leading zero row is not written back)
    lines = [ln for ln in out.read_text().splitlines() if ln.strip()]
    motion_at = lines.index("MOTION")
    assert lines[motion_at + 1] == f"Frames: {clip.num_frames}"
    assert len(lines) - motion_at - 3 == clip.num_frames
