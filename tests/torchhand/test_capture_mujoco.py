"""Compliance estimation against MuJoCo ground truth (the acceptance of interaction capture).

A planar finger (wrist, MP, PIP, DIP) whose joints are MuJoCo springs of stiffness 1/c (Kry & Pai Table 1,
exploring) presses a plane 80 times; joint angles and contact forces at 500 Hz with 0.2 degree and 0.01 N noise
form the capture (torchhand.interaction.mujoco_truth). Asserted: the simulation is quasi-static
(theta - theta_r = C J^T f with torchhand's J^T f of the recorded forces), every loaded joint's median estimate over
the events is within 10 % of the truth, every rejected estimate carries a reason, the held root comes back
``fixed``, and noise-free data gives the truth within 1 % (the paper's slopes form) and 3.5 % (the joint form).
"""

from __future__ import annotations

import numpy as np
import pytest

from torchhand.hand.model import HandModel
from torchhand.interaction import EstimateSettings, Reason, estimate_capture, joint_torques, load_capture

pytest.importorskip("mujoco")

from torchhand.interaction.mujoco_truth import TruthSettings, equilibrium_residual, write_truth_capture  # noqa: E402


@pytest.fixture(scope="module")
def truth(tmp_path_factory):
    folder = tmp_path_factory.mktemp("truth")
    path, run = write_truth_capture(folder, TruthSettings(task="exploring", presses=80), np.random.default_rng(0))
    hand = HandModel.from_mjcf(folder / run.capture.hand)
    return path, run, hand


def _median_error(result, truth_c):
    med = np.array([np.median(v[np.isfinite(v)]) if np.isfinite(v).any() else np.nan
                    for v in result.estimate.values[:, 6:].T])
    return med / truth_c - 1


def test_simulation_is_quasi_static(truth):
    _, run, hand = truth
    r = equilibrium_residual(run, joint_torques(run.clean, hand))
    assert r.size > 1000
    assert np.median(r) < 0.015 and np.percentile(r, 90) < 0.03


def test_capture_file_round_trips_with_its_hand(truth):
    path, run, _ = truth
    cap = load_capture(path)
    assert cap.source == "synthetic" and cap.fps == 500.0 and cap.hand == "planar_finger.xml"
    np.testing.assert_array_equal(cap.truth_compliance[6:], [0.3488, 0.9882, 0.6715, 2.0052])
    assert np.isnan(cap.truth_compliance[:6]).all()
    np.testing.assert_array_equal(cap.q, run.capture.q)


def test_noisy_estimates_within_ten_percent(truth):
    _, run, hand = truth
    res = estimate_capture(run.capture, hand)
    c = run.capture.truth_compliance[6:]
    err = _median_error(res, c)
    assert np.abs(err).max() < 0.10, err
    assert res.events.count >= 80
    valid = res.estimate.valid[:, 6:]
    assert (valid.sum(axis=0) >= 0.75 * res.events.count).all()
    # rejected estimates are NaN and carry a reason; the root is held still by the capture: fixed
    rejected = ~res.estimate.valid
    assert np.isnan(res.estimate.values[rejected]).all() and np.isfinite(res.estimate.values[~rejected]).all()
    assert (res.estimate.reason[rejected] != Reason.VALID).all()
    assert (res.estimate.reason[:, :6] == Reason.FIXED).all()
    s = res.summary()
    assert all(abs(row["relative_error"]) < 0.10 for row in s["coordinates"][6:])


@pytest.mark.parametrize("method, tol", [("slopes", 0.01), ("joint", 0.035)])
def test_noise_free_estimates(truth, method, tol):
    _, run, hand = truth
    res = estimate_capture(run.clean, hand, EstimateSettings(method=method))
    err = _median_error(res, run.clean.truth_compliance[6:])
    assert np.abs(err).max() < tol, err


def test_cli_synthetic_then_estimate(tmp_path, capsys):
    from torchhand.cli import main as cli_main

    out = tmp_path / "syn"
    assert cli_main(["capture", "synthetic", "--out", str(out), "--presses", "3", "--seed", "3"]) == 0
    cap = load_capture(out / "capture.npz")
    assert cap.hand == "planar_finger.xml" and (out / "planar_finger.xml").is_file() and cap.source == "synthetic"
    assert cli_main(["capture", "synthetic", "--out", str(out)]) == 2  # not empty
    assert "not an empty directory" in capsys.readouterr().err
    assert cli_main(["capture", "estimate", str(out / "capture.npz"), "--out", str(tmp_path / "est"),
                     "--no-plots"]) == 0
    assert "dip" in capsys.readouterr().out
    assert cli_main(["capture", "synthetic", "--out", str(tmp_path / "bad"), "--rate", "-5"]) == 2
