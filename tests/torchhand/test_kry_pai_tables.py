"""Kry & Pai (2006) Table 2 and Fig. 14 analogues (torchhand/interaction/perturb.py, plots.py and
scripts/kry_pai_tables.py).

References nobody here wrote: SciPy's ODE solver for the second-order fit, MuJoCo's point Jacobian for G and its
dynamics for the perturbation trial, the paper's Table 2 tolerance (8-11 % between k and kG; design note: 15 %)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from torchhand.errors import InputValueError
from torchhand.interaction.perturb import (FitStatus, PerturbSettings, derivatives, endpoint_compliance,
                                           fit_second_order)

_SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "kry_pai_tables.py"


def _script():
    spec = importlib.util.spec_from_file_location("kry_pai_tables", _SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


# ----------------------------------------------------------------------------------------------------------------
# the second-order fit against scipy.integrate.solve_ivp
# ----------------------------------------------------------------------------------------------------------------
def _msd_signal(m, b, k, f0, rate=10000.0, duration=0.06):
    """z(t) of m z'' + b z' + k z + f0 = f(t), z(0) = z'(0) = 0, with a smooth f (rest force plus two sines)."""
    from scipy.integrate import solve_ivp

    def force(t):
        return f0 + 0.3 * np.sin(90.0 * t) + 0.2 * np.sin(230.0 * t + 0.4) * (1 - np.exp(-t / 0.004))

    sol = solve_ivp(lambda t, y: [y[1], (force(t) - b * y[1] - k * y[0] - f0) / m], (0.0, duration), [0.0, 0.0],
                    method="DOP853", rtol=1e-13, atol=1e-18, dense_output=True)
    t = np.arange(int(round(duration * rate)) + 1) / rate
    return t, sol.sol(t)[0], force(t)


@pytest.mark.parametrize("m, b, k, f0", [(0.017, 2.04, 89.16, 0.677), (0.018, 3.86, 257.04, 1.345)])
def test_fit_recovers_a_mass_spring_damper(m, b, k, f0):
    t, z, f = _msd_signal(m, b, k, f0)
    for given in (None, f0):
        fit = fit_second_order(t, z, f, 0.01, 0.025, f0=given)
        assert fit.status == FitStatus.OK and fit.samples == 251
        np.testing.assert_allclose([fit.m, fit.b, fit.k, fit.f0], [m, b, k, f0], rtol=1e-6)
        assert fit.rms < 1e-7


def test_derivatives_are_fourth_order():
    t = np.arange(200) / 1000.0
    y = np.sin(40 * t)
    d1, d2 = derivatives(y, 1e-3)
    inner = slice(2, -2)
    assert np.abs(d1[inner] - 40 * np.cos(40 * t[inner])).max() < 40 * 1e-5
    assert np.abs(d2[inner] + 1600 * y[inner]).max() < 1600 * 2e-5


def test_fit_reports_what_it_cannot_do():
    t = np.arange(50) / 500.0
    assert fit_second_order(t, np.zeros(50), np.ones(50), 0.0, 0.025).status == FitStatus.SINGULAR
    assert fit_second_order(t, np.sin(t), np.ones(50), 0.0, 0.004).status == FitStatus.TOO_FEW_SAMPLES
    with pytest.raises(InputValueError, match="t, z, f"):
        fit_second_order(t, np.zeros(49), np.ones(50), 0.0, 0.025)
    with pytest.raises(InputValueError, match="task"):
        PerturbSettings(task="typing")
    with pytest.raises(InputValueError, match="link_mass"):
        PerturbSettings(link_mass=(0.01, 0.01, -0.01, 0.01))


# ----------------------------------------------------------------------------------------------------------------
# MuJoCo: the Jacobian behind G, and the perturbation trial
# ----------------------------------------------------------------------------------------------------------------
def test_endpoint_compliance_matches_mujoco_jacobian():
    mujoco = pytest.importorskip("mujoco")
    from torchhand.interaction.mujoco_truth import LINKS, planar_finger_mjcf

    c = np.array([0.3488, 0.9882, 0.6715, 2.0052])
    m = mujoco.MjModel.from_xml_string(planar_finger_mjcf(c))
    d = mujoco.MjData(m)
    rng = np.random.default_rng(3)
    for _ in range(3):
        q = rng.uniform(0.0, 0.8, 4)
        p_local = np.array([rng.uniform(0.0, 0.02), 0.0, rng.uniform(-0.006, 0.006)])
        d.qpos[:] = q
        mujoco.mj_forward(m, d)
        b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, LINKS[3])
        jac = np.zeros((3, m.nv))
        mujoco.mj_jac(m, d, jac, None, d.xpos[b] + d.xmat[b].reshape(3, 3) @ p_local, b)
        np.testing.assert_allclose(endpoint_compliance(q, p_local, c), jac @ np.diag(c) @ jac.T, atol=1e-12)


@pytest.fixture(scope="module")
def trials():
    pytest.importorskip("mujoco")
    from torchhand.interaction.perturb import simulate_perturbation

    return {task: simulate_perturbation(PerturbSettings(task=task)) for task in ("exploring", "scratching")}


@pytest.mark.parametrize("task", ["exploring", "scratching"])
def test_perturbation_stiffness_matches_kG(trials, task):
    """Measured at 500 Hz: k - kG = +8.1 % (exploring), +6.4 % (scratching); the paper: 8-11 %. The fitted mass
    is 42-51 % above the endpoint mass 1 / (e_z^T J M^-1 J^T e_z) at 500 Hz (the design note asked for 30 %; 28-32 %
    at 2 kHz), asserted below 60 %."""
    r = trials[task]
    s = r.settings
    assert r.fit.status == FitStatus.OK and not r.lost_contact
    assert r.fit.samples == int(round(s.fit_window * s.rate)) + 1
    assert abs(r.f_rest / s.force - 1) < 0.02
    assert abs(r.k_error) <= 0.15, (r.fit.k, r.reference.kG)
    assert r.fit.b > 0
    assert abs(r.m_error) < 0.6, (r.fit.m, r.reference.mass)
    assert r.reference.kG_held > r.reference.kG                  # holding the tip sideways stiffens it
    assert 1e-4 < r.z[(r.t >= 0) & (r.t <= s.fit_window)].max() < 0.01   # it moved, by less than a centimetre


@pytest.mark.parametrize("task", ["exploring", "scratching"])
def test_perturbation_fit_with_dense_sampling(task):
    """At 10 kHz the differentiation error is gone: measured k - kG = -13.5 % / -10.3 % and m 24 % / 26 % above
    the endpoint mass, so the design note's 15 % and 30 % hold there."""
    pytest.importorskip("mujoco")
    from torchhand.interaction.perturb import simulate_perturbation

    r = simulate_perturbation(PerturbSettings(task=task, rate=10000.0))
    assert r.fit.status == FitStatus.OK and r.fit.b > 0
    assert abs(r.k_error) <= 0.15 and abs(r.m_error) <= 0.30, (r.k_error, r.m_error)


def test_scratching_is_stiffer_than_exploring(trials):
    """Table 2's order: scratching's k and kG above exploring's (the paper: 257 vs 89 N/m, 286 vs 82 N/m)."""
    e, s = trials["exploring"], trials["scratching"]
    assert s.fit.k > 1.5 * e.fit.k and s.reference.kG > 1.5 * e.reference.kG


# ----------------------------------------------------------------------------------------------------------------
# Fig. 14
# ----------------------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def fig14(tmp_path_factory):
    out = tmp_path_factory.mktemp("fig14")
    return out, _script().fig14(out)


def test_fig14_imminent_adjustment_limits_the_slip_ratio(fig14):
    """Heavy pinch (0.35 kg): the ratio reaches mu in all three cases at the lift (a one-step jump at h = 1/120 s,
    faster than the imminent-slip check can react), so the peaks are equal; the imminent response spends less time
    above 0.9 mu, slips less and holds the box, the unadjusted grasp loses it."""
    _, f = fig14
    none, delayed, imminent = (f["cases"][k] for k in ("none", "delayed", "imminent"))
    for c in (none, delayed, imminent):
        assert c["status"] == "COMPLETED"
    assert imminent["peak_ratio"] <= none["peak_ratio"] + 1e-9
    assert none["peak_ratio_over_mu"] > 0.999                    # slides at the friction limit
    assert imminent["time_above_0.9mu_s"] < 0.5 * none["time_above_0.9mu_s"]
    assert imminent["max_slip_mm"] < 5.0 < 20.0 < none["max_slip_mm"]
    assert imminent["lift_mm"] > 40.0 > 1.0 > none["lift_mm"]
    assert imminent["grip_events"] > 0 and none["grip_events"] == 0
    assert delayed["first_grip_frame"] - delayed["grip_onset_frame"] == 12   # 100 ms at 120 Hz


def test_fig14_png_is_written(fig14):
    import matplotlib.image

    out, f = fig14
    img = matplotlib.image.imread(Path(f["png"]))
    assert img.shape[0] > 300 and img.shape[1] > 900
    rgb = img[..., :3].reshape(-1, 3)
    assert len(np.unique((rgb * 255).astype(np.uint8), axis=0)) > 50      # lines in several colours, not blank
    assert (rgb.min(1) < 0.5).mean() > 0.005


def test_script_rejects_bad_input(tmp_path, capsys):
    mod = _script()
    file = tmp_path / "a_file"
    file.write_text("x")
    assert mod.main(["--out", str(file)]) == 2
    assert mod.main(["--out", str(tmp_path / "o"), "--presses", "0"]) == 2
    assert "--presses" in capsys.readouterr().err
