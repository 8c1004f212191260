"""Joint compliance at contact events and the reference trajectory (Kry & Pai 2006, §3.3–3.4, Fig. 3, Eq. 1).

Per event e (contact time t_c, first loaded frame) and generalized coordinate j:

* pre window: frames in ``[t_c - window_pre, t_c)`` (not before the previous event's frame);
  post window: frames in ``[t_c, t_c + window_post)`` (not past the end of the contact or the next event);
* polynomials in ``t - t_c`` are fitted by least squares to theta_j on both windows and to tau_j on both windows,
  all four of one degree per event and coordinate: with ``degree=None`` degree 2 when an F-test on the pre-contact
  angle fit says the quadratic term reduces its residual significantly (F > F_0.99(1, n - 3): theta_r is curved),
  else 1; ``degree=1`` / ``2`` forces it. One degree for the angle and torque fits makes the estimate exact
  whenever theta_r is such a polynomial over both windows and theta = theta_r + C tau, whatever the shape of tau
  (least squares is linear: fit(theta) = theta_r + C fit(tau)).

Two ways to form c from the same windows and degree (``EstimateSettings.method``):

* ``"slopes"``, the paper's: ``c_ej = (dθ_post/dt - dθ_pre/dt) / (dτ_post/dt - dτ_pre/dt)`` at t_c, from the four
  separate fits above;
* ``"joint"`` (the default; a deviation from the paper): one least-squares fit over both windows of
  ``theta_j(t) = p(t) + c tau_j(t)``, p of the chosen degree: the same model (theta_r a low-degree polynomial
  through t_c, theta = theta_r + C tau), but theta_r's slope and curvature are shared by the two windows instead
  of being fitted twice, which roughly halves the scatter under 0.2 degree angle noise on the MuJoCo captures
  (scripts/capture_mujoco_truth.py). With ``degree=None`` its degree comes from an F-test of the quadratic term
  on this joint fit (both windows: far more power to see theta_r's curvature than the pre window alone).
  Noise-free, the slopes form is the more local one (closer to t_c, less affected by the finger's small dynamic
  lag after impact).

Deviation from the paper (both forms): the paper takes tau = 0 before contact, so its denominator is dτ_post/dt
alone; here the pre-contact torque slope is subtracted too, which is the same when nothing else loads the hand
before t_c and stays correct when another contact is already loading it (theta = theta_r + C tau holds
throughout).

Rejections (:class:`Reason`, checked in this order; the estimate is then NaN): ``fixed`` (the coordinate does not
move in the windows, e.g. a root that the capture holds still), ``not_loaded`` (tau_j is zero in the post window:
the joint is off the load path), ``short_window`` (fewer than ``min_samples`` frames in a window), ``poor_fit``
(the residual RMS of the pre-contact angle fit, or of the post-contact angle fit minus c times the torque fit's,
above ``poor_fit`` x the coordinate's noise level plus 1 % of its range in the windows; with ``method="joint"``
the residual of the joint fit),
``small_torque_rate`` (|dτ/dt| change below ``kappa`` x its standard error), ``negative`` (§4.3, Fig. 8),
``uncertain`` (standard error above ``max_relative_se`` x |c|).

Noise levels: per coordinate, 1.4826 MAD of second differences / sqrt(6) over the whole capture.

The reference trajectory (Eq. 1): ``C(t)`` is piecewise constant per coordinate, the latest valid estimate at or
before t (the first valid estimate before it, where tau is zero anyway; ``mode="median"``: the median of the valid
estimates throughout); coordinates without any valid estimate use the defaults and are flagged.
``theta_r(t) = theta(t) - C(t) tau(t)``.

Units: theta radians (root linear metres), tau N m (root linear N), compliance rad/(N m) (root linear m/N).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from ..errors import InputValueError, ShapeError
from .events import ContactEvents

__all__ = ["Reason", "EstimateSettings", "ComplianceEstimate", "InteractionTrajectory", "fit_slope",
           "estimate_compliance", "reference_trajectory", "signal_noise"]


class Reason(IntEnum):
    """Why an estimate was kept or rejected (one per event and coordinate)."""

    VALID = 0
    FIXED = 1
    NOT_LOADED = 2
    SHORT_WINDOW = 3
    POOR_FIT = 4
    SMALL_TORQUE_RATE = 5
    NEGATIVE = 6
    UNCERTAIN = 7

    @property
    def message(self) -> str:
        return _MESSAGES[self]


_MESSAGES = {
    Reason.VALID: "valid",
    Reason.FIXED: "the coordinate does not move around the event (held by the capture or locked)",
    Reason.NOT_LOADED: "no torque in the post-contact window: the joint is off the load path",
    Reason.SHORT_WINDOW: "too few frames before or after contact; raise the frame rate or space the contacts",
    Reason.POOR_FIT: "the polynomial does not fit the window; check the data or force --degree 2",
    Reason.SMALL_TORQUE_RATE: "the torque rate is within its noise (straight finger, joint barely loaded)",
    Reason.NEGATIVE: "negative compliance: extrapolation failed (paper §4.3, Fig. 8)",
    Reason.UNCERTAIN: "the estimate's standard error exceeds max_relative_se times its value",
}

REASON_NAMES = tuple(r.name.lower() for r in Reason)


@dataclass(frozen=True)
class EstimateSettings:
    """Settings of the estimator (design note ambiguity 6 for the defaults).

    window_pre:      pre-contact window, seconds (0.05)
    window_post:     post-contact window, seconds (0.1: the reflex-free time)
    degree:          None (1 or 2 by an F-test), 1 or 2
    force_threshold: lower bound of the contact threshold f_on, newtons (0.05)
    gap:             quiet time before an event and merge window, seconds (0.05)
    merge:           merge events of sensors on one finger within ``gap``
    min_samples:     fewest frames in a window (10)
    kappa:           torque-rate change over its standard error below which an estimate is rejected (3)
    poor_fit:        residual RMS over noise above which a fit is poor (4)
    max_relative_se: standard error over |c| above which an estimate is rejected (1)
    mode:            "latest" or "median": how C(t) is built from the valid estimates
    method:          "joint" (one polynomial theta_r across both windows plus c tau) or "slopes" (the paper's
                     change of slope); see the module docstring
    jacobian_smoothing: seconds of Savitzky-Golay smoothing of the joint angles at which J is evaluated for
                     tau = J^T f (0: raw angles; :mod:`torchhand.interaction.pipeline`)
    """

    window_pre: float = 0.05
    window_post: float = 0.1
    degree: int | None = None
    force_threshold: float = 0.05
    gap: float = 0.05
    merge: bool = True
    min_samples: int = 10
    kappa: float = 3.0
    poor_fit: float = 4.0
    max_relative_se: float = 1.0
    mode: str = "latest"
    method: str = "joint"
    jacobian_smoothing: float = 0.04

    def __post_init__(self):
        for name in ("window_pre", "window_post", "force_threshold", "gap", "kappa", "poor_fit", "max_relative_se"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise InputValueError(f"{name}: expected a positive number, got {v!r}")
        if self.degree not in (None, 1, 2):
            raise InputValueError(f"degree: expected 1, 2 or None (automatic), got {self.degree!r}")
        if not (isinstance(self.min_samples, int) and self.min_samples >= 4):
            raise InputValueError(f"min_samples: expected an integer >= 4, got {self.min_samples!r}")
        if not (isinstance(self.jacobian_smoothing, (int, float)) and self.jacobian_smoothing >= 0):
            raise InputValueError(f"jacobian_smoothing: expected >= 0 seconds, got {self.jacobian_smoothing!r}")
        if self.method not in ("joint", "slopes"):
            raise InputValueError(f"method: expected 'joint' or 'slopes', got {self.method!r}")
        if self.mode not in ("latest", "median"):
            raise InputValueError(f"mode: expected 'latest' or 'median', got {self.mode!r}")


@dataclass(frozen=True)
class ComplianceEstimate:
    """Per event e and generalized coordinate j (E events, N = 6 + D coordinates).

    values:    compliance, (E, N), rad/(N m) (root linear m/N); NaN where rejected
    raw:       the ratio before rejection, (E, N) (NaN where it could not be formed)
    stderr:    its standard error, (E, N)
    reason:    :class:`Reason` codes, (E, N), int
    slope_pre, slope_post: dθ/dt of the fits at t_c, (E, N), rad/s; tau_rate: dτ_post/dt - dτ_pre/dt, (E, N), N m/s
    windows:   (E, 3) int frames (pre start, t_c, post end exclusive)
    fits:      per event, the polynomial coefficients (theta_pre, theta_post, tau_pre, tau_post), each (3, N) in
               powers of (t - t_c) seconds, lowest first (a zero quadratic term for degree 1)
    """

    values: np.ndarray
    raw: np.ndarray
    stderr: np.ndarray
    reason: np.ndarray
    slope_pre: np.ndarray
    slope_post: np.ndarray
    tau_rate: np.ndarray
    windows: np.ndarray
    fits: tuple = field(repr=False)

    @property
    def valid(self) -> np.ndarray:
        """(E, N) bool."""
        return self.reason == int(Reason.VALID)


@dataclass(frozen=True)
class InteractionTrajectory:
    """The interaction trajectory (C, theta_r), N = 6 + D generalized coordinates.

    compliance:  C(t), (T, N), rad/(N m) (root linear m/N)
    theta_r:     reference, (T, N), radians (root linear metres)
    is_default:  coordinates without a valid estimate, which use the defaults, (N,) bool
    """

    compliance: np.ndarray
    theta_r: np.ndarray
    is_default: np.ndarray


def signal_noise(x: np.ndarray) -> np.ndarray:
    """White-noise level of each column of a smooth signal, (T, N) -> (N,): 1.4826 MAD(second differences)/sqrt(6)."""
    if x.shape[0] < 3:
        return np.zeros(x.shape[1])
    d2 = x[2:] - 2 * x[1:-1] + x[:-2]
    return 1.4826 * np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0) / np.sqrt(6.0)


_F99 = {}


def _f_crit(dof: int) -> float:
    if dof not in _F99:
        from scipy.stats import f as fdist

        _F99[dof] = float(fdist.ppf(0.99, 1, dof))
    return _F99[dof]


def fit_slope(t: np.ndarray, y: np.ndarray, degree):
    """Least-squares polynomials of each column of ``y`` in ``t``, and their slopes at t = 0.

    t:      sample times relative to the evaluation point, (n,), seconds
    y:      samples, (n, N)
    degree: 1, 2, a per-column (N,) int array of 1 / 2, or None (per column: 2 when an F-test at 99 % says the
            quadratic term reduces the residual significantly)
    returns: (coef (3, N) lowest power first (zero quadratic term for degree 1), slope (N,), slope standard error
        (N,), residuals (n, N), chosen degree (N,) int)
    """
    n, N = y.shape
    scale = max(float(np.abs(t).max()), 1e-12)
    s = t / scale
    out = {}
    for deg in (1, 2):
        X = np.vander(s, deg + 1, increasing=True)  # (n, deg + 1)
        XtX_inv = np.linalg.inv(X.T @ X)
        coef = XtX_inv @ (X.T @ y)  # (deg + 1, N)
        res = y - X @ coef
        rss = (res ** 2).sum(axis=0)
        dof = max(n - deg - 1, 1)
        se = np.sqrt(np.maximum(rss / dof, 0.0) * XtX_inv[1, 1]) / scale
        out[deg] = (coef, rss, se, dof, res)
    c1, rss1, se1, _, res1 = out[1]
    c2, rss2, se2, dof2, res2 = out[2]
    if degree is None:
        F = (rss1 - rss2) * dof2 / np.maximum(rss2, 1e-300)
        use2 = (F > _f_crit(dof2)) & (rss1 > 1e-24 * np.maximum((y ** 2).sum(axis=0), 1e-300))
    else:
        use2 = np.broadcast_to(np.asarray(degree) == 2, (N,))
    coef = np.zeros((3, N))
    coef[:2] = np.where(use2, c2[:2], c1)
    coef[2] = np.where(use2, c2[2], 0.0)
    coef = coef / np.array([1.0, scale, scale * scale])[:, None]
    return coef, coef[1], np.where(use2, se2, se1), np.where(use2, res2, res1), np.where(use2, 2, 1)


def estimate_compliance(theta: np.ndarray, tau: np.ndarray, events: ContactEvents, fps: float,
                        settings: EstimateSettings = EstimateSettings()) -> ComplianceEstimate:
    """Compliance of every generalized coordinate at every contact event (module docstring).

    theta:    generalized coordinates, (T, N), radians (root linear metres)
    tau:      generalized forces J^T f, (T, N), N m (root linear N)
    events:   :class:`~torchhand.interaction.events.ContactEvents`
    fps:      frame rate, Hz
    returns: :class:`ComplianceEstimate`
    """
    theta = np.asarray(theta, dtype=np.float64)
    tau = np.asarray(tau, dtype=np.float64)
    if theta.ndim != 2 or tau.shape != theta.shape:
        raise ShapeError(f"theta, tau: expected equal shapes (T, N), got {theta.shape} and {tau.shape}")
    T, N = theta.shape
    E = events.count
    n_pre = max(1, int(round(settings.window_pre * fps)))
    n_post = max(1, int(round(settings.window_post * fps)))
    noise_th = signal_noise(theta)
    shape = (E, N)
    raw, se_c = np.full(shape, np.nan), np.full(shape, np.nan)
    reason = np.zeros(shape, dtype=np.int64)
    sp, spo, rate = np.full(shape, np.nan), np.full(shape, np.nan), np.full(shape, np.nan)
    windows = np.zeros((E, 3), dtype=np.int64)
    fits = []
    for e in range(E):
        k = int(events.frame[e])
        lo = max(k - n_pre, int(events.frame[e - 1]) if e else 0)
        hi = min(k + n_post, int(events.end_frame[e]), int(events.frame[e + 1]) if e + 1 < E else T)
        windows[e] = (lo, k, hi)
        zero = np.zeros((3, N))
        if k - lo < settings.min_samples or hi - k < settings.min_samples:
            reason[e] = Reason.SHORT_WINDOW
            fits.append((zero, zero, zero, zero))
            _fixed_or_unloaded(reason[e], theta[lo:hi], tau[k:hi])
            continue
        t_pre = (np.arange(lo, k) - k) / fps
        t_post = (np.arange(k, hi) - k) / fps
        # one degree per coordinate for all four fits: the pre-contact angle fit decides (curvature of theta_r)
        cp, s_pre, e_pre, r_pre, deg = fit_slope(t_pre, theta[lo:k], settings.degree)
        cq, s_post, e_post, r_post, _ = fit_slope(t_post, theta[k:hi], deg)
        ct, u_pre, eu_pre, ru_pre, _ = fit_slope(t_pre, tau[lo:k], deg)
        cu, u_post, eu_post, ru_post, _ = fit_slope(t_post, tau[k:hi], deg)
        fits.append((cp, cq, ct, cu))
        dtau = u_post - u_pre
        se_tau = np.sqrt(eu_pre ** 2 + eu_post ** 2)
        tol = settings.poor_fit * noise_th + 1e-2 * np.ptp(theta[lo:hi], axis=0)
        rms = lambda r: np.sqrt((r ** 2).mean(axis=0))  # noqa: E731
        if settings.method == "slopes":
            with np.errstate(divide="ignore", invalid="ignore"):
                c = (s_post - s_pre) / dtau
                se = np.sqrt(e_pre ** 2 + e_post ** 2 + (c * se_tau) ** 2) / np.abs(dtau)
            # poor fit: theta_r not polynomial before contact, or theta - c tau not polynomial after it
            poor = (rms(r_pre) > tol) | (rms(r_post - np.nan_to_num(c) * ru_post) > tol)
        else:
            frames = np.arange(lo, hi) - k
            if settings.degree is None:  # the quadratic term's F-test on the joint fit (both windows)
                _, _, res1 = _joint_fit(frames, theta[lo:hi], tau[lo:hi], np.ones(N, dtype=np.int64))
                _, _, res2 = _joint_fit(frames, theta[lo:hi], tau[lo:hi], np.full(N, 2, dtype=np.int64))
                rss1, rss2 = (res1 ** 2).sum(axis=0), (res2 ** 2).sum(axis=0)
                dof = max(hi - lo - 4, 1)
                F = (rss1 - rss2) * dof / np.maximum(rss2, 1e-300)
                deg = np.where((F > _f_crit(dof)) & (rss1 > 1e-24 * (theta[lo:hi] ** 2).sum(axis=0)), 2, 1)
            c, se, resid = _joint_fit(frames, theta[lo:hi], tau[lo:hi], deg)
            poor = rms(resid) > tol
        raw[e], se_c[e], sp[e], spo[e], rate[e] = c, se, s_pre, s_post, dtau
        r = reason[e]
        r[:] = Reason.VALID
        r[poor] = Reason.POOR_FIT
        r[(r == 0) & ~(np.abs(dtau) > settings.kappa * se_tau)] = Reason.SMALL_TORQUE_RATE
        r[(r == 0) & ~(c > 0)] = Reason.NEGATIVE
        r[(r == 0) & ~(se <= settings.max_relative_se * np.abs(c))] = Reason.UNCERTAIN
        _fixed_or_unloaded(r, theta[lo:hi], tau[k:hi])
    values = np.where(reason == Reason.VALID, raw, np.nan)
    return ComplianceEstimate(values=values, raw=raw, stderr=se_c, reason=reason, slope_pre=sp, slope_post=spo,
                              tau_rate=rate, windows=windows, fits=tuple(fits))


def _joint_fit(frames: np.ndarray, theta: np.ndarray, tau: np.ndarray, degree: np.ndarray):
    """Per column: least squares of theta = p(t) + c tau with p of the given degree, over both windows.

    frames: (n,) frame offsets from t_c; theta, tau: (n, N); degree: (N,) 1 or 2
    returns: (c (N,), its standard error (N,), residuals (n, N)); NaN where the system is singular
    """
    n, N = theta.shape
    s = frames / max(float(np.abs(frames).max()), 1.0)
    X = np.zeros((N, n, 4))
    X[:, :, 0], X[:, :, 1] = 1.0, s
    X[:, :, 2] = np.where(degree[:, None] == 2, s * s, 0.0)
    scale = np.abs(tau).max(axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    X[:, :, 3] = (tau / scale).T
    A = X.transpose(0, 2, 1) @ X  # (N, 4, 4)
    A[:, 2, 2] += (degree == 1)  # the unused quadratic column: keep the system regular
    b = X.transpose(0, 2, 1) @ theta.T[:, :, None]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        try:
            Ainv = np.linalg.inv(A)
        except np.linalg.LinAlgError:
            Ainv = np.linalg.pinv(A)
        coef = (Ainv @ b)[:, :, 0]  # (N, 4)
        resid = theta - np.einsum("nij,nj->in", X, coef)
        dof = np.maximum(n - 3 - (degree == 2), 1)
        var = (resid ** 2).sum(axis=0) / dof
        c = coef[:, 3] / scale
        se = np.sqrt(np.maximum(var * Ainv[:, 3, 3], 0.0)) / scale
    return c, se, resid


def _fixed_or_unloaded(r: np.ndarray, theta_win: np.ndarray, tau_post: np.ndarray) -> None:
    """Mark, in place, coordinates that do not move in the windows (fixed) or carry no post-contact torque."""
    if theta_win.shape[0]:
        r[np.ptp(theta_win, axis=0) <= 1e-12] = Reason.FIXED
    if tau_post.shape[0]:
        peak = np.abs(tau_post).max(axis=0)
        unloaded = peak <= 1e-9 * max(float(peak.max()), 1e-300)
        r[unloaded & (r != Reason.FIXED)] = Reason.NOT_LOADED


def reference_trajectory(theta: np.ndarray, tau: np.ndarray, estimate: ComplianceEstimate, event_frame: np.ndarray,
                         defaults: np.ndarray, mode: str = "latest") -> InteractionTrajectory:
    """C(t) from the valid estimates and theta_r = theta - C tau (module docstring).

    theta, tau:  (T, N); event_frame: (E,) int; defaults: (N,) compliance used where no estimate is valid
    mode:        "latest" (piecewise constant) or "median"
    returns: :class:`InteractionTrajectory`
    """
    T, N = theta.shape
    defaults = np.asarray(defaults, dtype=np.float64)
    if defaults.shape != (N,):
        raise ShapeError(f"defaults: expected shape ({N},), got {defaults.shape}")
    valid = estimate.valid
    is_default = ~valid.any(axis=0)
    C = np.broadcast_to(defaults, (T, N)).copy()
    for j in np.nonzero(~is_default)[0]:
        ev = np.nonzero(valid[:, j])[0]
        vals = estimate.values[ev, j]
        if mode == "median":
            C[:, j] = np.median(vals)
            continue
        # index of the latest valid event at or before each frame; the first one before it
        idx = np.searchsorted(event_frame[ev], np.arange(T), side="right") - 1
        C[:, j] = vals[np.maximum(idx, 0)]
    return InteractionTrajectory(compliance=C, theta_r=theta - C * tau, is_default=is_default)
