"""Rig recognition and finger retargeting for splicing (torchhand.splice.rigs, torchhand.splice.retarget).

Real files: every shared BVH rig (mocapbank, Mixamo, CMU/MB-Lab, Leap, ManipNet) by name and, with the names
scrambled, by the hierarchy fallback. Synthetic BVH text written here (clearly small made-up hierarchies) covers
the Character Creator and MB-Lab namings, tip joints, maps and errors.

Retargeting is checked by forward kinematics: rotations are written into the destination's channels with SciPy's
Euler conversion (an independent reference) and the destination's global rotations come from
``BVHClip.global_transforms``. The invariant: the rotation of each carried joint relative to the wrist, in each
rig's hand frame, is the same in source and destination; consequently the angle between corresponding posed
finger segments (relative to the hand frame) equals their angle at rest, i.e. the rigs' rest-pose difference,
in every frame. Unmatched destination joints (CMU metacarpals) bound the deviation by their own rotation angle.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from torchhand.scene.bvh import BVHClip, read_bvh
from torchhand.errors import (FileFormatError, InputTypeError, InputValueError, MissingFileError, ShapeError,
                              TorchhandError, UnknownNameError)
from torchhand.splice import (FINGERS, FOREARM_LENGTH, HAND_LENGTH, detect_rig, finger_matches, hand_frame,
                              insert_fingers, rest_positions, retarget_fingers)

from tests.conftest import shared_path

M = np.diag([-1.0, 1.0, 1.0])


def _clip(*parts: str) -> BVHClip:
    return read_bvh(shared_path("mocap", *parts))


def _mocapbank():
    return _clip("bvh_python_tests", "test_mocapbank.bvh")


def _mixamo():
    return _clip("bvh_python_tests", "test_freebvh.bvh")


def _cmu():
    return _clip("cmu_body_frozen_hands", "01-01_v01.bvh")


def _manipnet(side="right"):
    return _clip("manipnet", "mug1", f"{side}Hand.bvh")


def _named(clip, rig, side):
    """Role -> joint name of one side (arm roles, "index1"-style finger roles, "index_tip"-style tips)."""
    s = rig.summary()
    out = dict(s["arms"].get(side, {}))
    out.update(s["fingers"].get(side, {}))
    out.update({f"{f}_tip": n for f, n in s["tips"].get(side, {}).items()})
    return out


def _scrambled(clip: BVHClip) -> BVHClip:
    return replace(clip, names=tuple(f"j{i}" for i in range(clip.num_joints)), path="scrambled.bvh")


# ---------------------------------------------------------------------------------------------------------------
# synthetic BVH text (made-up hierarchies, not captured data)


def _node(name, offset, children=(), end=None):
    return (name, offset, list(children), end)


def _bvh_text(root, frames: int = 2) -> str:
    lines, count = ["HIERARCHY"], [0]

    def emit(node, depth, is_root):
        name, off, kids, end = node
        pad = "  " * depth
        lines.append(f"{pad}{'ROOT' if is_root else 'JOINT'} {name}")
        lines.append(pad + "{")
        lines.append(f"{pad}  OFFSET {off[0]} {off[1]} {off[2]}")
        if is_root:
            lines.append(f"{pad}  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation")
            count[0] += 6
        else:
            lines.append(f"{pad}  CHANNELS 3 Zrotation Xrotation Yrotation")
            count[0] += 3
        for k in kids:
            emit(k, depth + 1, False)
        if end is not None:
            lines.extend([f"{pad}  End Site", pad + "  {", f"{pad}    OFFSET {end[0]} {end[1]} {end[2]}",
                          pad + "  }"])
        lines.append(pad + "}")

    emit(root, 0, True)
    lines += ["MOTION", f"Frames: {frames}", "Frame Time: 0.0333333"]
    lines += [" ".join(["0"] * count[0])] * frames
    return "\n".join(lines) + "\n"


def _hand(sgn, name_of, metacarpal: bool, tip_joint: bool = False):
    """Five finger chains of a T-pose hand along sgn*x (y up, z forward, thumb forward), centimetres."""
    out = []
    spread = {"thumb": 3.0, "index": 2.5, "middle": 0.5, "ring": -1.5, "pinky": -3.5}
    for f in FINGERS:
        if f == "thumb":
            segs = [(sgn * 2.5, -1.0, 3.0), (sgn * 3.0, -1.0, 2.0), (sgn * 3.0, -1.5, 1.5)]
            ords = [1, 2, 3]
        else:
            segs = ([(sgn * 2.0, 0.0, spread[f] * 0.5)] if metacarpal else []) + \
                [(sgn * (9.0 if not metacarpal else 7.0), -0.3, spread[f] * (1.0 if not metacarpal else 0.5)),
                 (sgn * 4.0, -0.3, 0.0), (sgn * 3.0, -0.3, 0.0)]
            ords = ([0] if metacarpal else []) + [1, 2, 3]
        if tip_joint:
            segs.append((sgn * 2.5, -0.3, 0.0))
            ords.append(4)
        chain = None
        for off, o in reversed(list(zip(segs, ords))):
            end = (sgn * 2.0, -0.2, 0.0) if chain is None and not tip_joint else ((0, 0, 0) if chain is None else None)
            chain = _node(name_of(f, o), off, [chain] if chain else [], end)
        out.append(chain)
    return out


def _body(names, *, metacarpal=False, tip_joint=False, extra_arm=None):
    """A T-pose body (y up, facing +z, cm). ``names(role, side, finger=None, ordinal=None)`` names the joints."""
    arms = []
    for side, sgn in (("right", -1.0), ("left", 1.0)):
        hand = _node(names("wrist", side), (sgn * 26.0, 0.0, 0.0),
                     _hand(sgn, lambda f, o, s=side: names("finger", s, f, o), metacarpal, tip_joint))
        fore_kids = [hand] + ([_node(extra_arm("forearm", side), (0, 0, 0), end=(sgn * 12.0, 0, 0))]
                              if extra_arm else [])
        fore = _node(names("elbow", side), (sgn * 28.0, 0.0, 0.0), fore_kids)
        up_kids = [fore] + ([_node(extra_arm("upperarm", side), (0, 0, 0), end=(sgn * 14.0, 0, 0))]
                            if extra_arm else [])
        upper = _node(names("shoulder", side), (sgn * 12.0, 0.0, 0.0), up_kids)
        arms.append(_node(names("clavicle", side), (sgn * 3.0, 10.0, 0.0), [upper]))
    head = _node(names("neck", None), (0, 14.0, 0), [_node(names("head", None), (0, 10.0, 0), end=(0, 15.0, 0))])
    chest = _node(names("chest", None), (0, 12.0, 0), arms + [head])
    spine = _node(names("spine", None), (0, 10.0, 0), [chest])
    legs = [_node(names("thigh", s), (sgn * 9.0, -5.0, 0), end=(0, -80.0, 0))
            for s, sgn in (("right", -1.0), ("left", 1.0))]
    return _node(names("hips", None), (0, 95.0, 0), [spine] + legs)


def _cc_names(role, side, finger=None, ordinal=None):
    s = {"right": "R", "left": "L", None: ""}[side]
    if role == "finger":
        return f"CC_Base_{s}_{'Mid' if finger == 'middle' else finger.capitalize()}{ordinal}"
    table = {"wrist": "Hand", "elbow": "Forearm", "shoulder": "Upperarm", "clavicle": "Clavicle",
             "thigh": "Thigh"}
    if role in table:
        return f"CC_Base_{s}_{table[role]}"
    return {"hips": "CC_Base_Hip", "spine": "CC_Base_Waist", "chest": "CC_Base_Spine02",
            "neck": "CC_Base_NeckTwist01", "head": "CC_Base_Head"}[role]


def _mblab_names(role, side, finger=None, ordinal=None):
    s = {"right": "R", "left": "L", None: ""}[side]
    if role == "finger":
        return f"{finger}0{ordinal}_{s}"
    table = {"wrist": "hand", "elbow": "lowerarm", "shoulder": "upperarm", "clavicle": "clavicle", "thigh": "thigh"}
    if role in table:
        return f"{table[role]}_{s}"
    return {"hips": "pelvis", "spine": "spine01", "chest": "spine03", "neck": "neck", "head": "head"}[role]


def _mixamo_names(role, side, finger=None, ordinal=None):
    s = {"right": "Right", "left": "Left", None: ""}[side]
    if role == "finger":
        return f"mixamorig1:{s}Hand{finger.capitalize()}{ordinal}"
    table = {"wrist": "Hand", "elbow": "ForeArm", "shoulder": "Arm", "clavicle": "Shoulder", "thigh": "UpLeg"}
    if role in table:
        return f"mixamorig1:{s}{table[role]}"
    return "mixamorig1:" + {"hips": "Hips", "spine": "Spine", "chest": "Spine2", "neck": "Neck", "head": "Head"}[role]


def _write(tmp_path, root, name="synthetic.bvh") -> BVHClip:
    p = tmp_path / name
    p.write_text(_bvh_text(root))
    return read_bvh(p)


# ---------------------------------------------------------------------------------------------------------------
# recognition on the real files

EXPECTED = {
    "mocapbank": {
        "right": {"shoulder": "RightShoulder", "elbow": "RightElbow", "forearm": "RightElbow",
                  "wrist": "RightWrist", "trunk": "Chest2"},
        "left": {"shoulder": "LeftShoulder", "elbow": "LeftElbow", "forearm": "LeftElbow", "wrist": "LeftWrist",
                 "trunk": "Chest2"},
    },
    "mixamo": {
        s: {"shoulder": f"mixamorig:{S}Arm", "elbow": f"mixamorig:{S}ForeArm", "forearm": f"mixamorig:{S}ForeArm",
            "wrist": f"mixamorig:{S}Hand", "trunk": "mixamorig:Spine2",
            **{f"{f}{o}": f"mixamorig:{S}Hand{f.capitalize()}{o}" for f in FINGERS for o in (1, 2, 3)},
            **{f"{f}_tip": f"mixamorig:{S}Hand{f.capitalize()}3_end" for f in FINGERS}}
        for s, S in (("right", "Right"), ("left", "Left"))
    },
    "cmu": {
        s: {"shoulder": f"upperarm_{S}", "elbow": f"lowerarm_{S}", "forearm": f"lowerarm_{S}", "wrist": f"hand_{S}",
            "trunk": "spine03",
            **{f"{f}{o}": f"{f}0{o}_{S}" for f in FINGERS for o in (0, 1, 2, 3) if not (f == "thumb" and o == 0)},
            **{f"{f}_tip": f"{f}03_{S}_end" for f in FINGERS}}
        for s, S in (("right", "R"), ("left", "L"))
    },
    "manipnet": {
        "wrist": "WRIST", "thumb1": "THUMB_CMC_AA", "thumb2": "THUMB_MCP_FE", "thumb3": "THUMB_IP_FE",
        **{f"{f}{o}": f"{f.upper()}_{j}" for f in FINGERS[1:] for o, j in ((1, "MCP"), (2, "PIP_FE"), (3, "DIP_FE"))},
        **{f"{f}_tip": f"{f.upper()}_DIP_FE_end" for f in FINGERS[1:]}, "thumb_tip": "THUMB_IP_FE_end",
    },
    "leap": {
        "forearm": "rForeArm", "wrist": "rHand",
        **{f"{f}{o}": f"r{'Mid' if f == 'middle' else f.capitalize()}{o}" for f in FINGERS for o in (1, 2, 3)},
        **{f"{f}_tip": f"r{'Mid' if f == 'middle' else f.capitalize()}3_end" for f in FINGERS},
    },
}


def test_mocapbank_body_without_fingers():
    clip = _mocapbank()
    rig = detect_rig(clip)
    assert rig.name == "mocapbank"
    for side in ("right", "left"):
        assert _named(clip, rig, side) == EXPECTED["mocapbank"][side]
        assert not rig.has_fingers(side) and rig.finger_joints(side) == []
    assert detect_rig(clip, "mocapbank").arms == rig.arms


@pytest.mark.parametrize("rig_name, loader", [("mixamo", _mixamo), ("cmu", _cmu)])
def test_body_rigs_with_fingers(rig_name, loader):
    clip = loader()
    rig = detect_rig(clip)
    assert rig.name == ("mblab" if rig_name == "cmu" else rig_name)
    for side in ("right", "left"):
        assert _named(clip, rig, side) == EXPECTED[rig_name][side]
        arm = rig.arm(side, require=("shoulder", "elbow", "wrist", "trunk"))
        assert clip.parents[arm.wrist] == arm.elbow and clip.parents[arm.elbow] == arm.shoulder
    assert detect_rig(clip, rig_name).fingers == rig.fingers


def test_cmu_finger_joints_include_metacarpals():
    clip = _cmu()
    rig = detect_rig(clip, "cmu")
    assert rig.name == "cmu"
    names = [clip.names[j] for j in rig.finger_joints("right")]
    assert len(names) == 19 and "index00_R" in names and "thumb01_R" in names
    assert all(n.endswith("_R") for n in names)


@pytest.mark.parametrize("side", ["right", "left"])
def test_manipnet_hands(side):
    clip = _manipnet(side)
    rig = detect_rig(clip)
    assert rig.name == "manipnet" and list(rig.arms) == [side]       # side from the file's name
    assert _named(clip, rig, side) == EXPECTED["manipnet"]
    arm = rig.arms[side]
    assert arm.shoulder is None and arm.elbow is None and arm.trunk is None and arm.forearm is None
    # THUMB_CMC_FE has no role but belongs to the chain
    assert "THUMB_CMC_FE" in [clip.names[j] for j in rig.finger_joints(side)]
    assert "THUMB_CMC_FE" not in [clip.names[j] for j in rig.finger_joints(side, roles_only=True)]
    other = "left" if side == "right" else "right"
    assert list(detect_rig(clip, "manipnet", unsided=other).arms) == [other]


def test_leap_hands():
    paths = sorted(shared_path("mocap", "leap_hand_bvh").glob("*.bvh"))
    assert len(paths) == 11
    for p in paths:
        clip = read_bvh(p)
        rig = detect_rig(clip)
        assert rig.name == "leap", p.name
        assert _named(clip, rig, "right") == EXPECTED["leap"], p.name
        arm = rig.arms["right"]
        assert arm.shoulder is None and arm.elbow is None and arm.trunk is None
        assert "left" not in rig.arms


@pytest.mark.parametrize("loader", [_mixamo, _cmu])
def test_fallback_finds_thumb_to_pinky_when_names_are_scrambled(loader):
    clip = loader()
    named = detect_rig(clip)
    rig = detect_rig(_scrambled(clip))
    assert rig.name == "hierarchy"
    for side in ("right", "left"):          # sides from the hands' chirality
        assert rig.arms[side] == named.arms[side]
        assert rig.fingers[side] == named.fingers[side]
        assert rig.tips[side] == named.tips[side]


def test_fallback_on_hand_rigs():
    for clip in (_manipnet("right"), _clip("leap_hand_bvh", "clenching.bvh")):
        named = detect_rig(clip)
        rig = detect_rig(_scrambled(clip), unsided="right")
        assert rig.fingers == named.fingers and rig.arms == named.arms


# ---------------------------------------------------------------------------------------------------------------
# synthetic namings


@pytest.mark.parametrize("names, rig_name, metacarpal", [(_cc_names, "cc", False), (_mblab_names, "mblab", True)])
def test_synthetic_cc_and_mblab(tmp_path, names, rig_name, metacarpal):
    twist = (lambda part, side: names("shoulder", side).replace("pperarm", "pperarmTwist01")
             if part == "upperarm" else names("elbow", side) + "Twist01") if rig_name == "cc" else \
        (lambda part, side: f"{'upperarm' if part == 'upperarm' else 'lowerarm'}_twist_{side[0].upper()}")
    clip = _write(tmp_path, _body(names, metacarpal=metacarpal, extra_arm=twist))
    for rig in (detect_rig(clip), detect_rig(clip, rig_name)):
        assert rig.name == rig_name
        for side in ("right", "left"):
            got = _named(clip, rig, side)
            assert got["wrist"] == names("wrist", side) and got["elbow"] == names("elbow", side)
            assert got["shoulder"] == names("shoulder", side) and got["trunk"] == names("chest", None)
            for f in FINGERS:
                for o in ((0, 1, 2, 3) if metacarpal and f != "thumb" else (1, 2, 3)):
                    assert got[f"{f}{o}"] == names("finger", side, f, o)
            assert got["index_tip"] == names("finger", side, "index", 3) + "_end"
    scr = detect_rig(_scrambled(clip))
    assert scr.fingers == detect_rig(clip).fingers


def test_synthetic_mixamo_tip_joints(tmp_path):
    clip = _write(tmp_path, _body(_mixamo_names, tip_joint=True))
    rig = detect_rig(clip)
    assert rig.name == "mixamo"
    got = _named(clip, rig, "right")
    assert got["index3"] == "mixamorig1:RightHandIndex3"
    assert got["index_tip"] == "mixamorig1:RightHandIndex4_end"
    assert ("index", 4) not in rig.fingers["right"]
    assert clip.names.index("mixamorig1:RightHandIndex4") in rig.finger_joints("right")
    scr = detect_rig(_scrambled(clip))                  # a four-joint thumb next to tip-joint fingers
    assert scr.fingers == rig.fingers and scr.tips == rig.tips


# ---------------------------------------------------------------------------------------------------------------
# maps


def test_toml_map_overrides_detection(tmp_path):
    clip = _scrambled(_mixamo())
    named = detect_rig(_mixamo())
    j = lambda i: f"j{i}"                                              # noqa: E731
    arm = named.arms["right"]
    fingers = {f"{f}{o}": j(i) for (f, o), i in named.fingers["right"].items()}
    text = "\n".join([
        'name = "scrambled-mixamo"', "auto = false", "[right]",
        f'shoulder = "{j(arm.shoulder)}"', f'elbow = "{j(arm.elbow)}"', f'wrist = "{j(arm.wrist)}"',
        f'trunk = "{j(arm.trunk)}"'] + [f'{k} = "{v}"' for k, v in fingers.items()])
    p = tmp_path / "map.toml"
    p.write_text(text)
    rig = detect_rig(clip, str(p))
    assert rig.name == "scrambled-mixamo" and list(rig.arms) == ["right"]
    assert rig.arms["right"] == named.arms["right"]
    assert rig.fingers["right"] == named.fingers["right"] and rig.tips["right"] == named.tips["right"]
    assert rig.how["right arm"] == "map map.toml"
    # overlay on automatic detection: one role moved, the others detected
    p2 = tmp_path / "one.toml"
    p2.write_text('[left]\nindex3 = "mixamorig:LeftHandIndex2"\nwrist = "mixamorig:LeftForeArm"\n')
    rig2 = detect_rig(_mixamo(), p2)
    left = _named(_mixamo(), rig2, "left")
    assert left["index3"] == "mixamorig:LeftHandIndex2" and left["wrist"] == "mixamorig:LeftForeArm"
    assert left["index1"] == "mixamorig:LeftHandIndex1"
    assert rig2.fingers["right"] == named.fingers["right"]


def test_toml_map_errors(tmp_path):
    clip = _mixamo()
    bad = tmp_path / "bad.toml"
    bad.write_text('[right]\nwirst = "mixamorig:RightHand"\n')
    with pytest.raises(FileFormatError, match="wirst"):
        detect_rig(clip, bad)
    bad.write_text('[right]\nwrist = "mixamorig:RightHnd"\n')
    with pytest.raises(UnknownNameError, match="did you mean mixamorig:RightHand"):
        detect_rig(clip, bad)
    bad.write_text("[right\nwrist = 1\n")
    with pytest.raises(FileFormatError, match="not a valid TOML"):
        detect_rig(clip, bad)
    with pytest.raises(MissingFileError):
        detect_rig(clip, tmp_path / "absent.toml")


# ---------------------------------------------------------------------------------------------------------------
# errors


def test_missing_wrist_lists_candidates(tmp_path):
    root = _node("Root", (0, 90, 0), [
        _node("Spine", (0, 10, 0), [_node("ArmR", (-15, 10, 0), [_node("ElbowR", (-28, 0, 0), [
            _node("HandR", (-26, 0, 0), end=(-10, 0, 0))])])])])
    clip = _write(tmp_path, root)
    with pytest.raises(UnknownNameError) as err:
        detect_rig(clip)
    msg = str(err.value)
    assert "HandR" in msg and "--body-map" in msg and "TOML map" in msg and "\n" not in msg
    with pytest.raises(UnknownNameError, match="right wrist"):
        detect_rig(_mocapbank(), "mixamo", side="right")
    leap = _clip("leap_hand_bvh", "clenching.bvh")
    with pytest.raises(UnknownNameError, match="right shoulder"):
        detect_rig(leap, side="right", require=("shoulder", "elbow", "wrist"))
    with pytest.raises(UnknownNameError, match="left wrist.*rHand"):
        detect_rig(leap).arm("left")
    with pytest.raises(InputValueError, match="rig:"):
        detect_rig(leap, "blender")
    with pytest.raises(InputValueError, match="side"):
        detect_rig(leap, side="middle")
    assert issubclass(UnknownNameError, TorchhandError)


# ---------------------------------------------------------------------------------------------------------------
# retargeting


def _local(clip: BVHClip, frames) -> torch.Tensor:
    return clip.local_transforms(frames)[..., :3, :3]


def _with_rotations(clip: BVHClip, rotations: dict, frames: int) -> BVHClip:
    """The clip's first frame repeated, with the given joints' rotation channels set (SciPy Euler)."""
    motion = np.repeat(np.array(clip.motion[:1]), frames, axis=0)
    for j, R in rotations.items():
        cols = [clip.channel_start[j] + i for i, c in enumerate(clip.channels[j]) if c.endswith("rotation")]
        order = "".join(c[0] for c in clip.channels[j] if c.endswith("rotation"))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")                     # gimbal-lock notices
            motion[:, cols] = Rotation.from_matrix(R.double().numpy()).as_euler(order, degrees=True)
    return replace(clip, motion=motion)


def _hand_relative(clip, rig, side, G, handedness="right"):
    """Rotation of every joint relative to the wrist, in the hand frame: (F, J, 3, 3)."""
    R = G[..., :3, :3] if G.shape[-1] == 4 else G
    if handedness == "left":
        R = M @ R @ M
    H = hand_frame(clip, rig, side, handedness=handedness)
    w = rig.arms[side].wrist
    return H.T @ np.swapaxes(R[:, w:w + 1], -1, -2) @ R @ H


def _angle(Ra, Rb):
    """Geodesic angle between rotation stacks, degrees (from ||Ra - Rb||_F = 2 sqrt(2) sin(angle / 2), accurate
    near zero)."""
    chord = np.linalg.norm(Ra - Rb, axis=(-2, -1)) / (2.0 * np.sqrt(2.0))
    return np.degrees(2.0 * np.arcsin(np.clip(chord, 0.0, 1.0)))


def _segment(clip, rig, side, j, handedness="right"):
    """Rest direction (hand frame) from joint j to its single child; None without one or without length."""
    kids = [k for k in range(clip.num_joints) if clip.parents[k] == j]
    if len(kids) != 1:
        return None
    rest = rest_positions(clip, handedness)
    u = hand_frame(clip, rig, side, handedness=handedness).T @ (rest[kids[0]] - rest[j])
    n = np.linalg.norm(u)
    return u / n if n > 1e-9 else None


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_identity_retarget_manipnet(dtype):
    clip = _manipnet("right")
    rig = detect_rig(clip)
    L = _local(clip, slice(600, 700)).to(dtype)
    out = retarget_fingers(clip, rig, clip, rig, "right", L, src_handedness="left", dst_handedness="left")
    assert sorted(out.rotations) == rig.finger_joints("right")                  # CMC_FE paired with itself
    tol = 1e-12 if dtype == torch.float64 else 2e-6
    for j, R in out.rotations.items():
        assert R.dtype == dtype and R.shape == (100, 3, 3)
        assert float((R - L[:, j]).abs().max()) < tol
    assert all(m.src == m.dst for m in out.matches)
    out_r = retarget_fingers(clip, rig, clip, rig, "right", L)                  # same handedness either way
    assert max(float((out_r.rotations[j] - L[:, j]).abs().max()) for j in out_r.rotations) < tol


@pytest.mark.parametrize("loader", [_mixamo, _cmu])
def test_manipnet_onto_body_keeps_hand_relative_rotations(loader):
    src = _manipnet("right")
    srig = detect_rig(src)
    dst = loader()
    drig = detect_rig(dst)
    frames = np.arange(600, 4000, 97)
    out = retarget_fingers(src, srig, dst, drig, "right", _local(src, frames), src_handedness="left")
    names = {(m.finger, m.ordinal): (m.src, m.dst) for m in out.matches}
    assert names[("thumb", 1)][0] == "THUMB_CMC_FE+THUMB_CMC_AA"
    assert len(out.matches) == 15 and sorted(out.rotations) == sorted(
        j for (f, o), j in drig.fingers["right"].items() if o > 0)        # CMU metacarpals left out
    Qs = _hand_relative(src, srig, "right", src.global_transforms(frames).numpy(), "left")
    posed = _with_rotations(dst, out.rotations, len(frames))
    Qt = _hand_relative(dst, drig, "right", posed.global_transforms().numpy())
    # unmatched destination joints (CMU metacarpals) keep their own values: their angle bounds the deviation
    meta = [drig.fingers["right"][k] for k in drig.fingers["right"] if k[1] == 0]
    slack = max([float(Rotation.from_matrix(_local(dst, [0])[0, j].numpy()).magnitude()) for j in meta] + [0.0])
    for m in out.matches:
        s, d = src.names.index(m.src.split("+")[-1]), dst.names.index(m.dst)
        assert _angle(Qs[:, s], Qt[:, d]).max() < np.degrees(slack) + 1e-6
        us, ut = _segment(src, srig, "right", s, "left"), _segment(dst, drig, "right", d)
        if us is None or ut is None:
            continue
        rest_angle = np.degrees(np.arccos(np.clip(us @ ut, -1, 1)))
        posed_angle = np.degrees(np.arccos(np.clip(np.einsum("fij,j,fik,k->f", Qs[:, s], us, Qt[:, d], ut), -1, 1)))
        assert np.abs(posed_angle - rest_angle).max() < np.degrees(slack) + 1e-6


def test_align_rest_makes_segment_directions_agree():
    src = _manipnet("right")
    srig = detect_rig(src)
    dst = _mixamo()
    drig = detect_rig(dst)
    frames = np.arange(600, 4000, 211)
    out = retarget_fingers(src, srig, dst, drig, "right", _local(src, frames), src_handedness="left",
                           align_rest=True)
    Qs = _hand_relative(src, srig, "right", src.global_transforms(frames).numpy(), "left")
    Qt = _hand_relative(dst, drig, "right", _with_rotations(dst, out.rotations, len(frames)).global_transforms()
                        .numpy())
    checked = 0
    for m in out.matches:
        s, d = src.names.index(m.src.split("+")[-1]), dst.names.index(m.dst)
        us, ut = _segment(src, srig, "right", s, "left"), _segment(dst, drig, "right", d)
        if us is None or ut is None:
            continue
        assert np.degrees(np.arccos(np.clip((Qs[:, s] @ us) @ (Qt[:, d] @ ut).T, -1, 1))).diagonal().max() < 1e-5
        checked += 1
    assert checked == 10                              # two segments per finger with length in both rigs


def test_metacarpals_compose_into_the_proximal_joint():
    src, dst = _cmu(), _mixamo()
    srig, drig = detect_rig(src), detect_rig(dst)
    rng = np.random.default_rng(0)
    F = 5
    L = _local(src, [0] * F).clone()
    for j in srig.finger_joints("right"):                             # random finger poses on the CMU hand
        L[:, j] = torch.from_numpy(Rotation.random(F, random_state=rng).as_matrix())
    out = retarget_fingers(src, srig, dst, drig, "right", L)
    m = {(x.finger, x.ordinal): x for x in out.matches}
    assert m[("index", 1)].src == "index00_R+index01_R" and m[("thumb", 1)].src == "thumb01_R"
    Rg = np.zeros((F, src.num_joints, 3, 3))                          # the posed source's global rotations
    for j, p in enumerate(src.parents):
        Rg[:, j] = L[:, j].numpy() if p < 0 else Rg[:, p] @ L[:, j].numpy()
    Qs = _hand_relative(src, srig, "right", Rg)
    Qt = _hand_relative(dst, drig, "right", _with_rotations(dst, out.rotations, F).global_transforms().numpy())
    for x in out.matches:
        s, d = src.names.index(x.src.split("+")[-1]), dst.names.index(x.dst)
        assert _angle(Qs[:, s], Qt[:, d]).max() < 1e-5


def test_include_wrist_and_bad_inputs():
    leap = _clip("leap_hand_bvh", "clenching.bvh")
    lrig = detect_rig(leap)
    dst, drig = _mixamo(), detect_rig(_mixamo())
    L = _local(leap, slice(0, 10))
    out = retarget_fingers(leap, lrig, dst, drig, "right", L, include_wrist=True)
    wrist = drig.arms["right"].wrist
    assert wrist in out.rotations and out.matches[0] == ("wrist", 0, "rHand", "mixamorig:RightHand")
    A = hand_frame(dst, drig, "right") @ hand_frame(leap, lrig, "right").T
    expect = torch.from_numpy(A) @ L[:, lrig.arms["right"].wrist] @ torch.from_numpy(A.T)
    assert float((out.rotations[wrist] - expect).abs().max()) < 1e-12
    assert finger_matches(lrig, drig, "right") == out.matches[1:]
    mn = _manipnet("right")
    mrig = detect_rig(mn)
    with pytest.raises(InputValueError, match="include_wrist"):
        retarget_fingers(mn, mrig, dst, drig, "right", _local(mn, [0]), include_wrist=True)
    with pytest.raises(ShapeError, match="src_local"):
        retarget_fingers(leap, lrig, dst, drig, "right", L[:, :5])
    with pytest.raises(InputTypeError, match="src_local"):
        retarget_fingers(leap, lrig, dst, drig, "right", L.numpy())
    with pytest.raises(UnknownNameError, match="left wrist"):
        retarget_fingers(leap, lrig, dst, drig, "left", L)
    body = _mocapbank()
    with pytest.raises(InputValueError, match="insert_fingers"):
        retarget_fingers(leap, lrig, body, detect_rig(body), "right", L)


# ---------------------------------------------------------------------------------------------------------------
# insertion


def _assert_depth_first(clip: BVHClip):
    for j, p in enumerate(clip.parents):
        assert p < j
    for j in range(clip.num_joints):                  # every subtree is a contiguous run of indices
        sub = [j]
        for k in range(j + 1, clip.num_joints):
            if clip.parents[k] in sub:
                sub.append(k)
        assert sub == list(range(j, j + len(sub)))


def test_insert_manipnet_fingers_into_mocapbank():
    body = _mocapbank()
    brig = detect_rig(body)
    ins = insert_fingers(body, brig, "right", _manipnet("right"), detect_rig(_manipnet("right")),
                         hand_handedness="left")
    clip, rig = ins.clip, ins.rig
    # new joints under the wrist, End Sites included, rotation channels only
    w = rig.arms["right"].wrist
    assert clip.names[w] == "RightWrist"
    new = [n for n in clip.names if n not in body.names]
    assert len(new) == 16 + 5 and "R_THUMB_CMC_FE" in new and "R_INDEX_DIP_FE_end" in new
    assert clip.names[clip.parents[clip.names.index("R_INDEX_MCP")]] == "RightWrist"
    assert all(all(c.endswith("rotation") for c in clip.channels[clip.names.index(n)]) for n in new)
    _assert_depth_first(clip)
    # old channel values unchanged bit for bit, new ones zero, column_map consistent with channel_start
    assert np.array_equal(clip.motion[:, ins.column_map], body.motion)
    new_cols = np.setdiff1d(np.arange(clip.motion.shape[1]), ins.column_map)
    assert len(new_cols) == 16 * 3 and not clip.motion[:, new_cols].any()
    # every joint stays but the wrist's End Site (the fingers replace that hand bone)
    gone = [n for n in body.names if n not in clip.names]
    assert gone == ["RightWrist_end"]
    kept = [j for j, n in enumerate(body.names) if n not in gone]
    for j in kept:
        n = body.names[j]
        k = clip.names.index(n)
        assert clip.channels[k] == body.channels[j]
        assert list(ins.column_map[body.channel_start[j]:body.channel_start[j] + len(body.channels[j])]) == \
            list(range(clip.channel_start[k], clip.channel_start[k] + len(clip.channels[k])))
    old = [clip.names.index(body.names[j]) for j in kept]
    assert np.array_equal(clip.global_transforms().numpy()[:, old], body.global_transforms().numpy()[:, kept])
    assert rig.arms["left"].wrist == clip.names.index("LeftWrist") and not rig.has_fingers("left")
    # size: wrist to middle tip = 0.19 m x forearm / 0.26 m
    rest = rest_positions(clip)
    forearm = np.linalg.norm(rest[w] - rest[rig.arms["right"].elbow])
    hand = np.linalg.norm(rest[rig.tips["right"]["middle"]] - rest[w])
    assert hand == pytest.approx(HAND_LENGTH / FOREARM_LENGTH * forearm, rel=1e-12)
    # the inserted hand frame is the body's, and the file is recognised again
    assert np.allclose(hand_frame(clip, rig, "right"), hand_frame(body, brig, "right"), atol=1e-12)
    again = detect_rig(clip)
    assert again.fingers == rig.fingers and again.arms == rig.arms and again.name == "mocapbank+manipnet"
    with pytest.raises(InputValueError, match="already has"):
        insert_fingers(clip, rig, "right", _manipnet("right"), detect_rig(_manipnet("right")))


def test_retarget_onto_inserted_fingers_is_exact_relative_to_the_hand():
    body, hand = _mocapbank(), _manipnet("right")
    hrig = detect_rig(hand)
    ins = insert_fingers(body, detect_rig(body), "right", hand, hrig, hand_handedness="left")
    frames = np.arange(600, 4000, 331)
    out = retarget_fingers(hand, hrig, ins.clip, ins.rig, "right", _local(hand, frames), src_handedness="left")
    assert sorted(out.rotations) == ins.rig.finger_joints("right")         # every chain joint, CMC_FE too
    Qs = _hand_relative(hand, hrig, "right", hand.global_transforms(frames).numpy(), "left")
    posed = _with_rotations(ins.clip, out.rotations, len(frames))
    Qt = _hand_relative(ins.clip, ins.rig, "right", posed.global_transforms().numpy())
    for m in out.matches:
        assert _angle(Qs[:, hand.names.index(m.src)], Qt[:, ins.clip.names.index(m.dst)]).max() < 1e-5


def test_insert_leap_hand_scales_units():
    body = _mocapbank()
    leap = _clip("leap_hand_bvh", "clenching.bvh")
    lrig = detect_rig(leap)
    ins = insert_fingers(body, detect_rig(body), "right", leap, lrig)        # mm hand into a cm body
    rest = rest_positions(ins.clip)
    w = ins.rig.arms["right"].wrist
    assert np.linalg.norm(rest[ins.rig.tips["right"]["middle"]] - rest[w]) == pytest.approx(
        HAND_LENGTH / FOREARM_LENGTH * np.linalg.norm(rest[w] - rest[ins.rig.arms["right"].elbow]))
    assert "rIndex1" in ins.clip.names
    with pytest.raises(UnknownNameError, match="left wrist"):
        insert_fingers(ins.clip, ins.rig, "left", leap, lrig)


def test_inserted_clip_writes_and_reads_back(tmp_path):
    from torchhand.scene.bvh import write_bvh

    body, hand = _mocapbank(), _manipnet("left")
    ins = insert_fingers(body, detect_rig(body), "left", hand, detect_rig(hand), hand_handedness="left")
    back = read_bvh(write_bvh(ins.clip, tmp_path / "inserted.bvh"))
    assert back.names == ins.clip.names and back.parents == ins.clip.parents
    assert back.channels == ins.clip.channels and np.array_equal(back.offsets, ins.clip.offsets)
    rig = detect_rig(back)
    assert rig.fingers == ins.rig.fingers and rig.arms == ins.rig.arms


def test_torchhands_own_hand_is_recognised():
    """The links of torchhand's hand model (a result's hand.xml, exported as BVH) name a rig: palm = wrist,
    thumb metacarpal/proximal/distal = CMC/MCP/IP, the other fingers' metacarpal..distal = ordinals 0..3."""
    import torch

    import torchhand
    from torchhand.scene.bvh import BVHClip

    h = torchhand.default_hand("right").to("cpu", torch.float64)
    T = h.forward_kinematics(h.q_rest[None])[0].numpy()
    par = [int(p) for p in h.chain.link_parent]
    offs = np.array([T[j, :3, 3] - (T[p, :3, 3] if p >= 0 else 0) for j, p in enumerate(par)])
    ch = tuple((("Xposition", "Yposition", "Zposition") if p < 0 else ()) + ("Zrotation", "Xrotation", "Yrotation")
               for p in par)
    clip = BVHClip(path="right_hand.bvh", names=tuple(h.link_names), parents=tuple(par), offsets=offs, channels=ch,
                   is_end_site=(False,) * len(par), frame_time=1 / 30,
                   motion=np.zeros((2, sum(len(c) for c in ch))))
    rig = detect_rig(clip)
    assert rig.name == "torchhand" and rig.arms["right"].wrist == h.link_names.index("palm")
    f = rig.fingers["right"]
    assert f[("thumb", 1)] == h.link_names.index("thumb_metacarpal")
    assert f[("pinky", 0)] == h.link_names.index("little_metacarpal")
    assert f[("index", 3)] == h.link_names.index("index_distal")
    assert len(f) == 19
