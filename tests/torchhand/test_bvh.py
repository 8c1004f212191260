"""BVH reader: parsing, per-joint channel orders against SciPy, malformed files, and the shared mocap data."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from torchhand.bvh import euler_to_matrix, read_bvh
from torchhand.errors import FileFormatError, MissingFileError, TorchhandError, UnknownNameError

from tests.conftest import shared_data_dir as shared_data


MOCAP = shared_data() / "mocap"
ALL_BVH = sorted(MOCAP.glob("**/*.bvh")) if MOCAP.is_dir() else []

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
                pos["XYZ".index(ch[0])] += v
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
    np.testing.assert_allclose(G[0, 0, :3, 3].numpy(), [1.1, 2.2, 3.3], atol=1e-12)
    # End Site: parent transform applied to its offset
    np.testing.assert_allclose(G[:, 2, :3, 3].numpy(),
                               (G[:, 1] @ torch.tensor([0.5, 0.0, 0.0, 1.0], dtype=torch.float64))[:, :3].numpy())
    # frame selection
    np.testing.assert_allclose(clip.global_transforms(frames=[1])[0].numpy(), G[1].numpy())
    np.testing.assert_allclose(clip.global_transforms(frames=1)[0].numpy(), G[1].numpy())
    rest = clip.rest_transforms()
    np.testing.assert_allclose(rest[2, :3, 3].numpy(), [1.5, 3.0, 3.0])


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
    assert clip.num_frames == 2 and clip.extra_lines_dropped == 1


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
        # the documented quirk: one more motion line than 'Frames:' says (all but the 19-frame file)
        assert clip.extra_lines_dropped == (0 if path.name == "air-hand_hand1.bvh" else 1)
    else:
        assert clip.extra_lines_dropped == 0
    if path.parent.name == "mug1":
        assert clip.num_frames == 4000 and clip.fps == pytest.approx(120.0, rel=1e-6)
        assert all(c[-3:] == ("Yrotation", "Xrotation", "Zrotation") for c in clip.channels if c)
