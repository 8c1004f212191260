"""Splicing end to end: alignment against known time warps on real body capture, fingers carried through the
spliced BVH, the command line and its errors (Majkowska et al. 2006; docs/splice.md)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from tests.conftest import shared_path
from torchhand.scene.bvh import read_bvh, write_bvh
from torchhand.cli import main
from torchhand.kernels.dtw import dtw, pairwise_cost
from torchhand.splice import SpliceSettings, align, detect_rig, prepare_out, splice, virtual_markers, write_splice
from torchhand.splice.align import band_width, path_median
from torchhand.splice.retime import local_rotations, retime_motion
from torchhand.splice.splice import arm_joints, clip_axes
from torchhand.splice.synthetic import make_hand_session, with_fingers


def _body(name: str):
    path = {"mocapbank": ("mocap", "bvh_python_tests", "test_mocapbank.bvh"),
            "cmu": ("mocap", "cmu_body_frozen_hands", "01-01_v01.bvh"),
            "mixamo": ("mocap", "bvh_python_tests", "test_freebvh.bvh")}[name]
    clip = read_bvh(shared_path(*path))
    rig = detect_rig(clip)
    units, up = clip_axes(clip, rig, "right")
    return clip, rig, units, up


def _session(name: str, level: str, seed: int):
    body, rig, units, up = _body(name)
    arms = [rig.arms[s] for s in ("right", "left")]
    hs = make_hand_session(body, level, torch.Generator().manual_seed(seed), shoulders=[a.shoulder for a in arms],
                           elbows=[a.elbow for a in arms], wrists=[a.wrist for a in arms], up_axis=up,
                           units_scale=units)
    aj = arm_joints(body, rig, "right")
    mb = virtual_markers(body, aj, units_scale=units, up_axis=up)
    mh = virtual_markers(hs.clip, aj, units_scale=units, up_axis=up)
    return body, hs, mb, mh


def _errors(est_s: np.ndarray, truth_s: np.ndarray, mb) -> tuple[float, float, float]:
    e = np.abs(est_s - truth_s) * 1000
    sp = (mb.markers[1:, 0] - mb.markers[:-1, 0]).norm(dim=-1).numpy()
    sp = np.concatenate([sp[:1], sp])
    moving = sp > 0.25 * np.percentile(sp, 95)
    return float(np.median(e)), float(np.percentile(e, 95)), float(np.percentile(e[moving], 95))


def _align(mb, mh, hand_only=False, **settings):
    return align(mb.markers[None], mh.markers[None], body_fps=mb.fps, hand_fps=mh.fps,
                 body_shoulder=mb.shoulder[None], body_trunk=mb.trunk[None],
                 hand_shoulder=None if hand_only else mh.shoulder[None],
                 hand_trunk=None if hand_only else mh.trunk[None], settings=SpliceSettings(**settings))


@pytest.mark.parametrize("name, seed", [("mocapbank", 0), ("cmu", 1)])
def test_known_warp_with_a_still_trunk_is_recovered(name, seed):
    """L4: warp 0.6-1.4x, 60 Hz, noise, 55-90 % amplitude, 30 deg turn, trunk frozen. Targets of the issue."""
    body, hs, mb, mh = _session(name, "L4", seed)
    al = _align(mb, mh)
    assert int(al.status[0]) == 0
    med, p95, mov = _errors(al.hand_time[0].numpy(), hs.truth, mb)
    assert med <= 33 and p95 <= 200 and mov <= 100, (med, p95, mov)
    # better than uniform time scaling and than one DTW on Euclidean marker distances
    n, m = mb.num_frames, mh.num_frames
    uniform = np.arange(n) * (m - 1) / (n - 1) / mh.fps
    assert med < _errors(uniform, hs.truth, mb)[0] / 10
    feats = [(x.markers - x.shoulder.unsqueeze(1)) for x in (mb, mh)]
    feats = [(f - f.mean(0)).reshape(f.shape[0], -1)[None] for f in feats]
    res = dtw(pairwise_cost(*feats), band=band_width(0.30, n, m)[0])
    plain = path_median(res.path, n)[0].numpy() / mh.fps
    assert med < _errors(plain, hs.truth, mb)[0] / 5


def test_hand_only_capture_finds_its_rotation():
    """The session seen as a hand capture: no shoulder, no trunk; one rotation is fitted."""
    body, hs, mb, mh = _session("mocapbank", "L4", 0)
    al = _align(mb, mh, hand_only=True)
    med, p95, _ = _errors(al.hand_time[0].numpy(), hs.truth, mb)
    assert med <= 33 and p95 <= 200, (med, p95)


def test_paper_mode_and_pass_two_on_a_pure_warp():
    """L0: the paper's own cost (Eq. 7 per cell) meets the design note's targets; pass 2 lowers the pass-1 p95 and
    never raises its median by more than 10 %."""
    body, hs, mb, mh = _session("mocapbank", "L0", 0)
    med, p95, _ = _errors(_align(mb, mh, features="paper").hand_time[0].numpy(), hs.truth, mb)
    assert med <= 10 and p95 <= 50, (med, p95)
    one = _errors(_align(mb, mh, passes=1).hand_time[0].numpy(), hs.truth, mb)
    al2 = _align(mb, mh, passes=2)
    two = _errors(al2.hand_time[0].numpy(), hs.truth, mb)
    assert bool(al2.pass2_used[0])
    assert two[0] <= 1.1 * one[0] and two[1] <= one[1], (one, two)


def test_pass_two_is_skipped_without_wrist_signal():
    """The CMU body's hands are frozen: pass 2 would align noise, so it is skipped and says why."""
    body, hs, mb, mh = _session("cmu", "L0", 0)
    al = _align(mb, mh)
    assert not bool(al.pass2_used[0]) and "no wrist signal" in al.pass2_note[0]


def test_matching_points_are_honoured_and_move_the_map():
    body, hs, mb, mh = _session("mocapbank", "L2", 0)
    n = mb.num_frames
    x = 200
    true_y = int(round(hs.truth[x] * mh.fps))
    for shift_s, tol in ((0.0, 0), (0.5, 0), (0.5, 3)):
        y = true_y + int(round(shift_s * mh.fps))
        al = align(mb.markers[None], mh.markers[None], body_fps=mb.fps, hand_fps=mh.fps,
                   body_shoulder=mb.shoulder[None], body_trunk=mb.trunk[None], hand_shoulder=mh.shoulder[None],
                   hand_trunk=mh.trunk[None], anchors=[[(x, y)]], settings=SpliceSettings(tolerance=tol))
        p = al.path1[0]
        cols = p[p[:, 0] == x][:, 1]
        assert (cols - y).abs().min() <= tol
        assert abs(float(al.hand_frame[0, x]) - y) <= tol + 1.5     # smoothing may move it by a frame
    assert n > x


def test_batched_pairs_equal_one_at_a_time():
    body, hs, mb, mh = _session("mocapbank", "L1", 2)
    T = 200
    starts = [0, 60, 150]
    P = torch.stack([mb.markers[s:s + T] for s in starts])
    Q = torch.stack([mh.markers[2 * s:2 * s + 2 * T] for s in starts])
    S = torch.stack([mb.shoulder[s:s + T] for s in starts])
    st = SpliceSettings(passes=1)
    batch = align(P, Q, body_fps=30.0, hand_fps=60.0, body_shoulder=S, settings=st)
    for b in range(3):
        one = align(P[b:b + 1], Q[b:b + 1], body_fps=30.0, hand_fps=60.0, body_shoulder=S[b:b + 1], settings=st)
        assert torch.allclose(one.hand_frame[0], batch.hand_frame[b], atol=1e-9)


def test_real_fingers_through_the_spliced_file():
    """GT-2: ManipNet's fingers on the synthetic clock, spliced onto the finger-less mocapbank body, written and
    read back: within 2 deg mean and 10 deg at the 95th percentile per joint, far better than uniform scaling."""
    body, rig, units, up = _body("mocapbank")
    manip = read_bvh(shared_path("mocap", "manipnet", "mug1", "rightHand.bvh"))
    mrig = detect_rig(manip)
    arms = [rig.arms[s] for s in ("right", "left")]
    hs = make_hand_session(body, "L4", torch.Generator().manual_seed(0), shoulders=[a.shoulder for a in arms],
                           elbows=[a.elbow for a in arms], wrists=[a.wrist for a in arms], up_axis=up,
                           units_scale=units)
    n, m = body.num_frames, hs.clip.num_frames
    hand, _ = with_fingers(hs.clip, rig, "right", manip, mrig,
                           600 + hs.warp.inverse(np.arange(m) / hs.clip.fps) * manip.fps, finger_handedness="left",
                           up_axis=up)
    truth, trig = with_fingers(body, rig, "right", manip, mrig, 600 + np.arange(n) / body.fps * manip.fps,
                               finger_handedness="left", up_axis=up)
    res = splice(body, hand)
    assert res.report["fingers_inserted"] and len(res.report["joints_carried"]) >= 15
    import tempfile
    with tempfile.TemporaryDirectory() as d:
        write_splice(res, prepare_out(f"{d}/out"))
        back = read_bvh(f"{d}/out/spliced.bvh")
    assert back.num_frames == n and back.frame_time == body.frame_time
    names = [truth.names[j] for j in trig.finger_joints("right")]
    Rt = local_rotations(truth)[:, trig.finger_joints("right")]
    Rb = local_rotations(back)[:, [back.names.index(x) for x in names]]

    def geo(Ra, Rb_):
        c = (((Ra.transpose(-1, -2) @ Rb_).diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1, 1)
        return torch.rad2deg(torch.acos(c)).numpy()

    e = geo(Rb, Rt)
    assert e.mean() <= 2.0 and np.percentile(e, 95) <= 10.0, (e.mean(), np.percentile(e, 95))
    uni = local_rotations(hand, retime_motion(hand, np.arange(n) * (m - 1) / (n - 1)))
    eu = geo(uni[:, [hand.names.index(x) for x in names]], Rt)
    assert e.mean() < eu.mean() / 3
    # the body's own channels are untouched (columns of the original joints, after the inserted ones moved them)
    for j, name in enumerate(body.names):
        w = len(body.channels[j])
        if w == 0:
            continue                          # End Sites (the wrist's is replaced by the fingers)
        k = back.names.index(name)
        a, b = body.channel_start[j], back.channel_start[k]
        assert np.abs(back.motion[:, b:b + w] - body.motion[:, a:a + w]).max() <= 1e-6, name


# ---------------------------------------------------------------------------------------------------------------
# the command line


def _trimmed(tmp_path, rel, frames, name):
    clip = read_bvh(shared_path(*rel))
    out = tmp_path / name
    write_bvh(clip.with_motion(clip.motion[frames]), out)
    return out


def test_cli_splices_real_files_and_keeps_the_body(tmp_path, capsys):
    """Mixamo body (fingers present) + 2.5 s of a ManipNet hand: files, shapes, and only finger channels changed;
    with a Leap hand, --wrist hand changes the wrist too and nothing else (ManipNet has no forearm: refused)."""
    body_p = shared_path("mocap", "bvh_python_tests", "test_freebvh.bvh")
    hand_p = _trimmed(tmp_path, ("mocap", "manipnet", "mug1", "rightHand.bvh"), slice(600, 900), "hand.bvh")
    out = tmp_path / "out"
    rc = main(["splice", "--body", str(body_p), "--hand", str(hand_p), "--hand-handedness", "left",
               "--out", str(out), "--plots", "--no-progress"])
    assert rc == 0
    assert "wrote" in capsys.readouterr().out
    for f in ("spliced.bvh", "warp.npz", "report.json", "plots/costs.png", "plots/warp.png"):
        assert (out / f).is_file(), f
    body = read_bvh(body_p)
    back = read_bvh(out / "spliced.bvh")
    assert back.names == body.names and back.channels == body.channels and back.num_frames == body.num_frames
    assert back.frame_time == body.frame_time
    rig = detect_rig(body)
    finger_cols = set()
    for j in rig.finger_joints("right"):
        finger_cols.update(range(body.channel_start[j], body.channel_start[j] + len(body.channels[j])))
    other = [c for c in range(body.motion.shape[1]) if c not in finger_cols]
    assert np.abs(back.motion[:, other] - body.motion[:, other]).max() <= 1e-6
    assert np.abs(back.motion[:, sorted(finger_cols)] - body.motion[:, sorted(finger_cols)]).max() > 1.0
    w = np.load(out / "warp.npz")
    n = body.num_frames
    assert w["body_frame"].shape == (n,) and w["hand_time"].shape == (n,)
    assert np.all(np.diff(w["hand_time"]) >= -1e-12) and w["hand_time"].max() <= 299
    assert np.allclose(w["hand_seconds"], w["hand_time"] / 120.0)
    assert w["path1"].shape[1] == 2 and w["cost1"].shape == (n, 300)
    rep = json.loads((out / "report.json").read_text())
    assert rep["body_rig"] == "mixamo" and rep["hand_rig"] == "manipnet" and rep["wrist"] == "body"

    # the wrist relative to the forearm needs a hand rig with a forearm joint: Leap's
    leap = shared_path("mocap", "leap_hand_bvh", "hello-world.bvh")
    out2 = tmp_path / "out2"
    assert main(["splice", "--body", str(body_p), "--hand", str(leap), "--out", str(out2), "--wrist", "hand",
                 "--no-progress"]) == 0
    back2 = read_bvh(out2 / "spliced.bvh")
    wj = rig.arms["right"].wrist
    wcols = set(range(body.channel_start[wj], body.channel_start[wj] + len(body.channels[wj])))
    other2 = [c for c in other if c not in wcols]
    assert np.abs(back2.motion[:, other2] - body.motion[:, other2]).max() <= 1e-6
    assert np.abs(back2.motion[:, sorted(wcols)] - body.motion[:, sorted(wcols)]).max() > 1.0


def _one_line_exit_2(capsys, argv, needle):
    rc = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2, err
    assert len([ln for ln in err if ln.startswith("torchhand: error:")]) == 1
    assert needle in err[-1], err[-1]


def test_cli_bad_input(tmp_path, capsys):
    body = str(shared_path("mocap", "bvh_python_tests", "test_mocapbank.bvh"))
    leap = str(shared_path("mocap", "leap_hand_bvh", "hello-world.bvh"))
    still = str(shared_path("mocap", "leap_hand_bvh", "air-hand_hand1.bvh"))
    out = str(tmp_path / "o")
    args = ["--no-progress", "--out", out]
    _one_line_exit_2(capsys, ["splice", "--body", body, "--hand", still, *args], "no motion")
    _one_line_exit_2(capsys, ["splice", "--body", body, "--hand", body, *args], "no right-hand finger joints")
    _one_line_exit_2(capsys, ["splice", "--body", body, "--hand", leap, "--match", "100:20,50:40", *args],
                     "must increase")
    _one_line_exit_2(capsys, ["splice", "--body", body, "--hand", leap, "--match", "100:9999", *args],
                     "outside the clips")
    _one_line_exit_2(capsys, ["splice", "--body", body, "--hand", leap, "--match", "1.5x:2", *args],
                     "not a frame number")
    _one_line_exit_2(capsys, ["splice", "--body", body, "--hand", leap, "--body-map", "nonesuch", *args],
                     "nonesuch")
    slow = tmp_path / "slow.bvh"
    clip = read_bvh(leap)
    write_bvh(clip.with_motion(clip.motion, frame_time=2.0), slow)
    _one_line_exit_2(capsys, ["splice", "--body", body, "--hand", str(slow), *args], "frame rate")
    manip = _trimmed(tmp_path, ("mocap", "manipnet", "mug1", "rightHand.bvh"), slice(600, 900), "manip.bvh")
    _one_line_exit_2(capsys, ["splice", "--body", body, "--hand", str(manip), "--hand-handedness", "left",
                              "--wrist", "hand", *args], "no forearm joint")
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "notes.txt").write_text("keep me")
    _one_line_exit_2(capsys, ["splice", "--body", body, "--hand", leap, "--no-progress", "--out",
                              str(tmp_path / "busy")], "not a splice result")
    assert (tmp_path / "busy" / "notes.txt").read_text() == "keep me"


def test_cli_refuses_to_replace_without_overwrite(tmp_path, capsys):
    body = str(shared_path("mocap", "bvh_python_tests", "test_mocapbank.bvh"))
    leap = str(shared_path("mocap", "leap_hand_bvh", "hello-world.bvh"))
    out = tmp_path / "o"
    assert main(["splice", "--body", body, "--hand", leap, "--out", str(out), "--no-progress"]) == 0
    before = (out / "spliced.bvh").read_bytes()
    _one_line_exit_2(capsys, ["splice", "--body", body, "--hand", leap, "--out", str(out), "--no-progress",
                              "--band1", "0.4"], "--overwrite")
    assert (out / "spliced.bvh").read_bytes() == before
    assert main(["splice", "--body", body, "--hand", leap, "--out", str(out), "--no-progress", "--overwrite",
                 "--band1", "0.4"]) == 0
    assert json.loads((out / "report.json").read_text())["band1"] == 0.4
