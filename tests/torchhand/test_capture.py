"""Interaction capture (torchhand/interaction): the capture format and its errors, contact events, the compliance
estimator on analytic signals (exact noise-free), reason codes, the reference trajectory, J^T f against the
Jacobian, Table 1 defaults, and the ``torchhand capture`` command (outputs, exit codes, refused directories)."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import torch

from torchhand.cli import main as cli_main
from torchhand.errors import FileFormatError, InputValueError, MissingFileError, ShapeError, UnknownNameError
from torchhand.hand.default import default_hand
from torchhand.hand.model import HandModel
from torchhand.interaction import (REASON_NAMES, Capture, EstimateSettings, NoContactError, Reason,
                                   capture_hand, default_compliance, detect_contact_events, estimate_capture,
                                   estimate_compliance, generalized_coordinates, joint_torques, load_capture,
                                   reference_trajectory, save_capture)
from torchhand.interaction.mujoco_truth import planar_finger_mjcf

FPS = 500.0


# ----------------------------------------------------------------------------------------------------------------
# builders
# ----------------------------------------------------------------------------------------------------------------
def _finger(tmp_path) -> HandModel:
    path = tmp_path / "finger.xml"
    path.write_text(planar_finger_mjcf([0.35, 0.99, 0.67, 2.0]))
    return HandModel.from_mjcf(path)


def _finger_capture(tmp_path, *, T: int = 1000, force_scale: float = 1.0, fps: float = FPS, taps=(0.5, 1.3)):
    """A planar-finger capture (hand file next to it): smooth joint motion, fingertip force ramps at ``taps``."""
    (tmp_path / "finger.xml").write_text(planar_finger_mjcf([0.35, 0.99, 0.67, 2.0]))
    t = np.arange(T) / fps
    q = np.stack([0.1 + 0.2 * t, 0.3 + 0.3 * t, 0.4 + 0.1 * np.sin(t), 0.3 + 0.05 * t * t], axis=1)
    force = np.zeros((T, 4, 3))
    for t0 in taps:
        on = (t >= t0) & (t < t0 + 0.3)
        force[on, 3, 2] = force_scale * 10.0 * (t[on] - t0)
        force[on, 3, 0] = -force_scale * 2.0 * (t[on] - t0)
    point = np.zeros((T, 4, 3))
    point[:, 3] = (0.012, 0.0, -0.006)
    root = np.tile(np.eye(4), (T, 1, 1))
    root[:, 2, 3] = 0.08
    return Capture(q=q, joint_names=("wrist", "mp", "pip", "dip"), root_pose=root, fps=fps, force=force,
                   force_point=point, force_link=("palm", "proximal", "middle", "distal"), hand="finger.xml",
                   source="synthetic", truth_compliance=np.r_[np.full(6, np.nan), 0.35, 0.99, 0.67, 2.0])


def _analytic(C, *, T=400, k_c=200, pre_rate=None, fps=FPS, seed=None, noise=0.0):
    """theta = theta_r + C tau with theta_r quadratic and tau = 0 before k_c, quadratic after (plus an optional
    pre-existing load ramp ``pre_rate``): (theta (T, N), tau (T, N), events)."""
    C = np.asarray(C, dtype=np.float64)
    N = C.size
    t = (np.arange(T) - k_c) / fps
    j = np.arange(N)
    theta_r = 0.2 + (0.5 + 0.1 * j) * t[:, None] + (1.0 - 0.3 * j) * t[:, None] ** 2
    post = np.where(t[:, None] >= 0, (0.5 + 0.2 * j) * t[:, None] + (0.8 - 0.1 * j) * t[:, None] ** 2, 0.0)
    tau = post + (0.0 if pre_rate is None else pre_rate * (t[:, None] + 1.0))
    theta = theta_r + C * tau
    if noise:
        theta = theta + np.random.default_rng(seed).normal(0, noise, theta.shape)
    force = np.zeros((T, 1, 3))
    force[k_c:, 0, 2] = 1.0 + t[k_c:]
    events = detect_contact_events(force, fps)
    return theta, tau, events


# ----------------------------------------------------------------------------------------------------------------
# format
# ----------------------------------------------------------------------------------------------------------------
def test_capture_round_trip(tmp_path):
    cap = _finger_capture(tmp_path)
    obj = np.tile(np.eye(4), (cap.num_frames, 1, 1))
    cap = dataclasses.replace(cap, object_pose=obj)
    path = save_capture(cap, tmp_path / "capture.npz")
    back = load_capture(path)
    for name in ("q", "root_pose", "force", "force_point", "object_pose"):
        np.testing.assert_array_equal(getattr(back, name), getattr(cap, name))
    np.testing.assert_array_equal(back.truth_compliance, cap.truth_compliance)
    assert back.joint_names == cap.joint_names and back.force_link == cap.force_link
    assert (back.fps, back.hand, back.source) == (FPS, "finger.xml", "synthetic")
    with np.load(path) as z:
        assert int(z["format_version"]) == 1
    hand = capture_hand(back)  # the MJCF path is relative to the capture file
    assert hand.joint_names == cap.joint_names


def test_capture_without_optional_fields(tmp_path):
    cap = dataclasses.replace(_finger_capture(tmp_path), source=None, truth_compliance=None)
    back = load_capture(save_capture(cap, tmp_path / "c.npz"))
    assert back.source is None and back.truth_compliance is None and back.object_pose is None


def _write_raw(path, **changes):
    cap = _finger_capture(path.parent)
    data = dict(format_version=np.array(1), q=cap.q, joint_names=np.array(cap.joint_names), root_pose=cap.root_pose,
                fps=np.array(cap.fps), force=cap.force, force_point=cap.force_point,
                force_link=np.array(cap.force_link), hand=np.array(cap.hand))
    for k, v in changes.items():
        if v is None:
            data.pop(k)
        else:
            data[k] = v
    np.savez(path, **data)
    return path


@pytest.mark.parametrize("key", ["q", "fps", "force", "force_link", "hand"])
def test_missing_key_is_named(tmp_path, key):
    with pytest.raises(FileFormatError, match=key):
        load_capture(_write_raw(tmp_path / "c.npz", **{key: None}))


def test_bad_shapes_and_t_mismatch(tmp_path):
    cap = _finger_capture(tmp_path)
    with pytest.raises(ShapeError, match="root_pose"):
        load_capture(_write_raw(tmp_path / "a.npz", root_pose=cap.root_pose[:-1]))
    with pytest.raises(ShapeError, match="force_point"):
        load_capture(_write_raw(tmp_path / "b.npz", force_point=cap.force_point[:, :2]))
    with pytest.raises(ShapeError, match="force"):
        load_capture(_write_raw(tmp_path / "c.npz", force=cap.force[:10]))
    with pytest.raises(ShapeError, match="joint_names"):
        load_capture(_write_raw(tmp_path / "d.npz", joint_names=np.array(["a", "b"])))
    with pytest.raises(ShapeError, match="force_link"):
        load_capture(_write_raw(tmp_path / "e.npz", force_link=np.array(["distal"])))
    with pytest.raises(ShapeError, match="truth_compliance"):
        load_capture(_write_raw(tmp_path / "f.npz", truth_compliance=np.ones(4)))


def test_nan_names_first_bad_frame(tmp_path):
    cap = _finger_capture(tmp_path)
    f = cap.force.copy()
    f[137, 2, 1] = np.nan
    f[400, 0, 0] = np.inf
    with pytest.raises(InputValueError, match="force: .*first at frame 137"):
        load_capture(_write_raw(tmp_path / "c.npz", force=f))


def test_not_an_npz_missing_file_newer_version(tmp_path):
    (tmp_path / "bad.npz").write_text("hello")
    with pytest.raises(FileFormatError, match="bad.npz"):
        load_capture(tmp_path / "bad.npz")
    with pytest.raises(MissingFileError):
        load_capture(tmp_path / "none.npz")
    with pytest.raises(FileFormatError, match="format_version"):
        load_capture(_write_raw(tmp_path / "v.npz", format_version=np.array(99)))
    with pytest.raises(InputValueError, match="fps"):
        load_capture(_write_raw(tmp_path / "z.npz", fps=np.array(0.0)))
    with pytest.raises(InputValueError, match="source"):
        load_capture(_write_raw(tmp_path / "s.npz", source=np.array("guessed")))


def test_unknown_link_lists_links_and_joint_names_must_match(tmp_path):
    cap = _finger_capture(tmp_path)
    bad = dataclasses.replace(cap, force_link=("palm", "proximal", "middle", "fingernail"))
    with pytest.raises(UnknownNameError, match="fingernail.*known links: forearm, palm, proximal, middle, distal"):
        capture_hand(dataclasses.replace(bad, path=tmp_path / "c.npz"))
    swapped = dataclasses.replace(cap, joint_names=("wrist", "mp", "dip", "pip"), path=tmp_path / "c.npz")
    with pytest.raises(InputValueError, match="column 2 is 'dip'"):
        capture_hand(swapped)
    with pytest.raises(InputValueError, match="differ"):
        capture_hand(dataclasses.replace(cap, path=tmp_path / "c.npz"), "default")
    with pytest.raises(MissingFileError):
        capture_hand(dataclasses.replace(cap, hand="nowhere.xml", path=tmp_path / "c.npz"))


# ----------------------------------------------------------------------------------------------------------------
# torques and coordinates
# ----------------------------------------------------------------------------------------------------------------
def _bench_capture(seconds=2.0):
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("bench_capture", Path(__file__).parents[2] / "scripts" /
                                                  "bench_capture.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.build_capture(seconds=seconds)


def test_joint_torques_match_point_jacobian():
    cap, hand = _bench_capture(1.0)
    tau = joint_torques(cap, hand, chunk=97)
    links = torch.tensor([hand.link_index(n) for n in cap.force_link])
    k = np.array([0, 250, 499])
    J = hand.point_jacobian(torch.from_numpy(cap.q[k]), links, torch.from_numpy(cap.force_point[k]),
                            torch.from_numpy(cap.root_pose[k]), wrt_root=True)  # (3, S, 3, 36)
    ref = torch.einsum("bsin,bsi->bn", J, torch.from_numpy(cap.force[k])).numpy()
    np.testing.assert_allclose(tau[k], ref, rtol=1e-12, atol=1e-12)
    assert tau.shape == (cap.num_frames, 36)


def test_generalized_coordinates_root_relative_to_first_frame():
    cap, _ = _bench_capture(1.0)
    th = generalized_coordinates(cap)
    np.testing.assert_allclose(th[0, :6], 0.0, atol=1e-15)
    np.testing.assert_array_equal(th[:, 6:], cap.q)
    np.testing.assert_allclose(th[:, 3:6], cap.root_pose[:, :3, 3] - cap.root_pose[0, :3, 3])
    # the rotation-vector rate is the world angular velocity near the first frame
    R = cap.root_pose[:, :3, :3]
    W = (R[1] - R[0]) @ R[0].T * FPS
    np.testing.assert_allclose(th[1, :3] * FPS, [W[2, 1], W[0, 2], W[1, 0]], rtol=2e-2, atol=1e-6)


def test_table1_defaults_for_the_default_hand():
    hand = default_hand("right")
    c, src = default_compliance(hand, "table1-exploring")
    name = dict(zip(("root_rx", "root_ry", "root_rz", "root_x", "root_y", "root_z") + hand.joint_names, c))
    assert name["root_rx"] == 0.3488 and name["root_x"] == 1e-4
    assert (name["index_mcp_flex"], name["index_pip"], name["index_dip"]) == (0.9882, 0.6715, 2.0052)
    assert (name["thumb_cmc_flex"], name["thumb_mcp_flex"], name["thumb_ip"]) == (0.9882, 0.6715, 2.0052)
    assert name["index_mcp_abd"] == pytest.approx(0.4941) and name["index_cmc_flex"] == pytest.approx(0.09882)
    assert src[6 + hand.joint_index("index_cmc_roll")].startswith("assumed")
    with pytest.raises(InputValueError, match="default-compliance"):
        default_compliance(hand, "table2")


# ----------------------------------------------------------------------------------------------------------------
# events
# ----------------------------------------------------------------------------------------------------------------
def test_event_detection_gap_threshold_and_onset():
    T = 1000
    f = np.zeros((T, 2, 3))
    f[100:300, 0, 2] = np.linspace(0.001, 2.0, 200)  # event at 100 (first loaded frame)
    f[310:400, 0, 2] = 1.0  # back within 20 ms < gap: not an event
    f[500:600, 0, 2] = 0.04  # below the 0.05 N threshold: not an event
    f[700:800, 1, 2] = 1.0  # sensor 1
    f[5:50, 1, 2] = 1.0  # within the first 50 ms: no quiet time before it
    ev = detect_contact_events(f, FPS)
    assert ev.frame.tolist() == [100, 700] and ev.sensor.tolist() == [0, 1]
    assert ev.end_frame.tolist() == [300, 800]
    np.testing.assert_allclose(ev.time, [0.2, 1.4])
    assert ev.threshold == 0.05 and ev.max_force == pytest.approx(2.0)
    # a 10 ms gap (5 frames) finds the re-touch and the touch at frame 5
    assert detect_contact_events(f, FPS, gap=0.01).frame.tolist() == [5, 100, 310, 700]


def test_event_merging_on_one_finger_and_noise_threshold():
    T = 600
    f = np.zeros((T, 3, 3))
    f[200:, 0, 2] = 1.0
    f[205:, 1, 2] = 1.0  # same finger, 10 ms later: merged
    f[210:, 2, 2] = 1.0  # other finger: its own event
    ev = detect_contact_events(f, FPS, finger=np.array([0, 0, 1]))
    assert ev.frame.tolist() == [200, 210] and ev.sensors == ((0, 1), (2,))
    assert detect_contact_events(f, FPS, finger=np.array([0, 0, 1]), merge=False).count == 3
    noisy = f + np.random.default_rng(0).normal(0, 0.05, f.shape)
    ev = detect_contact_events(noisy, FPS, finger=np.array([0, 0, 1]))
    assert ev.noise == pytest.approx(0.05, rel=0.1)
    assert ev.threshold == pytest.approx(3 * math.sqrt(3) * ev.noise)
    assert ev.frame.tolist() == [200, 210]


def test_event_detection_bad_input():
    with pytest.raises(ShapeError):
        detect_contact_events(np.zeros((10, 3)), FPS)
    with pytest.raises(InputValueError, match="force_threshold"):
        detect_contact_events(np.zeros((10, 1, 3)), FPS, force_threshold=0.0)


# ----------------------------------------------------------------------------------------------------------------
# estimator
# ----------------------------------------------------------------------------------------------------------------
C4 = [0.3488, 0.9882, 0.6715, 2.0052]


@pytest.mark.parametrize("method", ["joint", "slopes"])
@pytest.mark.parametrize("degree", [None, 2])
def test_estimator_exact_on_analytic_signal(method, degree):
    theta, tau, events = _analytic(C4)
    assert events.frame.tolist() == [200]
    est = estimate_compliance(theta, tau, events, FPS, EstimateSettings(method=method, degree=degree))
    assert (est.reason == Reason.VALID).all()
    np.testing.assert_allclose(est.values[0], C4, rtol=1e-6)
    # slopes of the fits at t_c are the analytic ones
    j = np.arange(4)
    np.testing.assert_allclose(est.slope_pre[0], 0.5 + 0.1 * j, rtol=1e-6)
    np.testing.assert_allclose(est.tau_rate[0], 0.5 + 0.2 * j, rtol=1e-6)
    np.testing.assert_allclose(est.slope_post[0], 0.5 + 0.1 * j + np.array(C4) * (0.5 + 0.2 * j), rtol=1e-6)


def test_estimator_exact_with_a_load_before_contact():
    theta, tau, events = _analytic(C4, pre_rate=0.3)
    for method in ("joint", "slopes"):
        est = estimate_compliance(theta, tau, events, FPS, EstimateSettings(method=method))
        np.testing.assert_allclose(est.values[0], C4, rtol=1e-6)


def test_estimator_degree_one_is_biased_by_curvature_and_noise_is_tolerated():
    theta, tau, events = _analytic(C4)
    est = estimate_compliance(theta, tau, events, FPS, EstimateSettings(degree=1, method="slopes", poor_fit=1e9))
    assert np.abs(est.raw[0] / C4 - 1).max() > 1e-3
    vals = []
    for seed in range(20):
        th, ta, ev = _analytic(C4, seed=seed, noise=math.radians(0.05))
        vals.append(estimate_compliance(th, ta, ev, FPS, EstimateSettings(degree=2)).raw[0])
    np.testing.assert_allclose(np.median(vals, axis=0), C4, rtol=0.1)


def test_reason_codes():
    N = 7
    C = np.array([1.0, 1.0, 1.0, -0.5, 1.0, 1.0, 1.0])
    theta, tau, events = _analytic(C, T=400)
    tau[:, 1] = 0.0  # joint 1 off the load path
    theta[:, 1] = 0.1 + 0.2 * np.arange(400) / FPS
    theta[:, 2] = 0.4  # fixed (e.g. the root held by the capture)
    rng = np.random.default_rng(0)
    tau[:, 4] = np.where(np.arange(400) >= 200, 1e-6 * rng.normal(size=400), 0.0)  # rate within its noise
    theta[:, 4] = 0.2 + rng.normal(0, 1e-3, 400)
    theta[220:, 5] += 0.05 * np.sin(np.arange(180) / 3.0)  # not a polynomial: poor fit
    est = estimate_compliance(theta, tau, events, FPS)
    r = est.reason[0]
    assert r[0] == Reason.VALID and r[6] == Reason.VALID
    assert r[1] == Reason.NOT_LOADED and r[2] == Reason.FIXED and r[3] == Reason.NEGATIVE
    assert r[4] == Reason.SMALL_TORQUE_RATE and r[5] == Reason.POOR_FIT
    assert np.isnan(est.values[0, 1:6]).all() and np.isfinite(est.values[0, [0, 6]]).all()
    assert REASON_NAMES[Reason.SMALL_TORQUE_RATE] == "small_torque_rate" and Reason.NEGATIVE.message
    # an event near the end: too few post-contact frames
    theta, tau, events = _analytic(np.ones(N), T=205)
    est = estimate_compliance(theta, tau, events, FPS)
    assert (est.reason[0] == Reason.SHORT_WINDOW).all() and np.isnan(est.values).all()


def test_settings_bad_values():
    with pytest.raises(InputValueError, match="window_post"):
        EstimateSettings(window_post=0.0)
    with pytest.raises(InputValueError, match="degree"):
        EstimateSettings(degree=3)
    with pytest.raises(InputValueError, match="method"):
        EstimateSettings(method="magic")


def test_reference_trajectory_latest_valid_and_defaults():
    theta, tau, _ = _analytic([1.0, 1.0, 1.0], T=300)
    from torchhand.interaction import ComplianceEstimate

    values = np.array([[0.5, np.nan, 2.0], [0.7, np.nan, np.nan]])
    reason = np.where(np.isnan(values), int(Reason.NEGATIVE), int(Reason.VALID))
    est = ComplianceEstimate(values=values, raw=values, stderr=values, reason=reason, slope_pre=values,
                             slope_post=values, tau_rate=values, windows=np.zeros((2, 3), int), fits=())
    tr = reference_trajectory(theta, tau, est, np.array([100, 200]), np.array([9.0, 8.0, 7.0]))
    assert tr.is_default.tolist() == [False, True, False]
    np.testing.assert_array_equal(tr.compliance[[0, 99, 100, 199, 200, 299], 0], [0.5, 0.5, 0.5, 0.5, 0.7, 0.7])
    np.testing.assert_array_equal(tr.compliance[:, 1], 8.0)
    np.testing.assert_array_equal(tr.compliance[:, 2], 2.0)
    np.testing.assert_allclose(tr.theta_r, theta - tr.compliance * tau)
    med = reference_trajectory(theta, tau, est, np.array([100, 200]), np.array([9.0, 8.0, 7.0]), mode="median")
    np.testing.assert_allclose(med.compliance[:, 0], 0.6)


def test_estimate_capture_low_rate_and_no_contact(tmp_path):
    cap = _finger_capture(tmp_path, fps=120.0, T=300)
    hand = _finger(tmp_path)
    with pytest.raises(InputValueError, match="--allow-low-rate"):
        estimate_capture(cap, hand)
    estimate_capture(cap, hand, allow_low_rate=True)
    quiet = _finger_capture(tmp_path, force_scale=0.001)
    with pytest.raises(NoContactError, match="largest force is 0.0030"):
        estimate_capture(quiet, hand)


# ----------------------------------------------------------------------------------------------------------------
# command line
# ----------------------------------------------------------------------------------------------------------------
def test_cli_estimate_writes_outputs_and_reuses_its_own_dir(tmp_path, capsys):
    path = save_capture(_finger_capture(tmp_path), tmp_path / "capture.npz")
    out = tmp_path / "est"
    args = ["capture", "estimate", str(path), "--out", str(out), "--max-event-plots", "1"]
    assert cli_main(args) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == ["compliance_events.png", "contact_event_0.png", "interaction.npz", "summary.json"]
    with np.load(out / "interaction.npz") as z:
        T = 1000
        assert z["C"].shape == (T, 10) and z["theta_r"].shape == (T, 4) and z["tau"].shape == (T, 10)
        assert z["estimates"].shape == (2, 10) and z["reasons"].shape == (2, 10)
        assert tuple(z["reason_names"]) == REASON_NAMES and tuple(z["joint_names"]) == ("wrist", "mp", "pip", "dip")
        np.testing.assert_allclose(z["event_time"], [0.5, 1.3], atol=1 / FPS)
        assert (z["reasons"][:, :6] == Reason.FIXED).all()  # the capture holds the root still
    summary = json.loads((out / "summary.json").read_text())
    assert summary["events"] == 2 and summary["coordinates"][6]["name"] == "wrist"
    assert "wrist" in capsys.readouterr().out
    assert cli_main(args) == 2  # an earlier estimate is kept unless --overwrite
    assert "--overwrite" in capsys.readouterr().err and (out / "contact_event_0.png").exists()
    assert cli_main(args + ["--overwrite", "--no-plots"]) == 0  # replaced; the old plots are gone
    assert sorted(p.name for p in out.iterdir()) == ["interaction.npz", "summary.json"]


def test_cli_exit_codes(tmp_path, capsys):
    path = save_capture(_finger_capture(tmp_path), tmp_path / "capture.npz")
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    assert cli_main(["capture", "estimate", str(path), "--out", str(foreign)]) == 2
    err = capsys.readouterr().err
    assert "notes.txt" in err and len(err.strip().splitlines()) == 1
    assert (foreign / "notes.txt").read_text() == "mine" and len(list(foreign.iterdir())) == 1
    assert cli_main(["capture", "estimate", str(tmp_path / "none.npz"), "--out", str(tmp_path / "o1")]) == 2
    low = save_capture(_finger_capture(tmp_path, fps=120.0, T=300), tmp_path / "low.npz")
    assert cli_main(["capture", "estimate", str(low), "--out", str(tmp_path / "o2"), "--no-plots"]) == 2
    assert "--allow-low-rate" in capsys.readouterr().err
    quiet = save_capture(_finger_capture(tmp_path, force_scale=0.001), tmp_path / "quiet.npz")
    assert cli_main(["capture", "estimate", str(quiet), "--out", str(tmp_path / "o3")]) == 1
    assert "largest force is" in capsys.readouterr().err
    assert cli_main(["capture", "estimate", str(path), "--out", str(tmp_path / "o4"), "--hand", "default"]) == 2
    assert cli_main(["capture", "estimate", str(path), "--out", str(tmp_path / "o5"), "--window-pre", "0"]) == 2
