"""The second-order fit of a perturbation trial (Kry & Pai 2006 §4.2): f = m z'' + b z' + k z + f0 by least
squares, with z's derivatives by five-point central differences (:func:`derivatives`).

Used by :mod:`torchhand.interaction.perturb`. SI units: m kg, b N s/m, k N/m, f0 N.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from ..errors import InputValueError

__all__ = ["FitStatus", "SecondOrderFit", "derivatives", "fit_second_order"]


class FitStatus(IntEnum):
    """Outcome of :func:`fit_second_order`."""

    OK = 0
    TOO_FEW_SAMPLES = 1
    SINGULAR = 2

    @property
    def message(self) -> str:
        return {0: "fitted",
                1: "fewer than 5 samples in the window: lengthen the window or raise the rate",
                2: "the regressors (z'', z', z, 1) are rank deficient on the window: the signal does not excite "
                   "the system"}[int(self)]


@dataclass(frozen=True)
class SecondOrderFit:
    """Least-squares fit of f = m z'' + b z' + k z + f0 (SI units; NaN only with a non-OK status).

    m kg, b N s/m, k N/m, f0 N; rms: residual root mean square, N; samples: samples in the window;
    condition: condition number of the (column-scaled) regressor matrix; status: :class:`FitStatus`
    """

    m: float
    b: float
    k: float
    f0: float
    rms: float
    samples: int
    condition: float
    status: FitStatus


def derivatives(y: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """First and second derivatives of uniformly sampled y (S,) (S >= 5): five-point central differences
    (fourth order) inside, second-order one-sided differences (``np.gradient``) at the two first and last samples.

    returns: (y', y''), each (S,)
    """
    y = np.asarray(y, dtype=np.float64)
    if y.ndim != 1 or y.shape[0] < 5:
        raise InputValueError(f"y: expected a 1-D signal of >= 5 samples, got shape {y.shape}")
    d1 = np.gradient(y, dt, edge_order=2)
    d2 = np.gradient(d1, dt, edge_order=2)
    d1[2:-2] = (-y[4:] + 8 * y[3:-1] - 8 * y[1:-3] + y[:-4]) / (12 * dt)
    d2[2:-2] = (-y[4:] + 16 * y[3:-1] - 30 * y[2:-2] + 16 * y[1:-3] - y[:-4]) / (12 * dt * dt)
    return d1, d2


def fit_second_order(t: np.ndarray, z: np.ndarray, f: np.ndarray, start: float, window: float,
                     f0: float | None = None) -> SecondOrderFit:
    """Fit f = m z'' + b z' + k z + f0 by least squares on the samples with start <= t <= start + window.

    f0: the rest force, newtons, when it is measured (the paper's definition, §4.2: "the rest force at the time of
    perturbation"); None fits it as a fourth unknown

    t: uniform sample times, (S,), s; z: position, (S,), m; f: force, (S,), N; the derivatives of z are taken on the
    whole signal (:func:`derivatives`), so samples before ``start`` enter the first window samples' stencils, as
    numerical differentiation of a measured signal does
    returns: :class:`SecondOrderFit` (status TOO_FEW_SAMPLES or SINGULAR with NaN values when it cannot fit)
    """
    t, z, f = (np.asarray(a, dtype=np.float64) for a in (t, z, f))
    if not (t.ndim == 1 and z.shape == t.shape and f.shape == t.shape):
        raise InputValueError(f"t, z, f: expected three 1-D arrays of one length, got {t.shape}, {z.shape}, {f.shape}")
    if t.shape[0] < 5:
        return SecondOrderFit(*(math.nan,) * 5, int(t.shape[0]), math.inf, FitStatus.TOO_FEW_SAMPLES)
    dt = float(t[1] - t[0])
    if not (dt > 0 and np.allclose(np.diff(t), dt, rtol=1e-6, atol=0)):
        raise InputValueError("t: expected uniformly increasing sample times")
    zd, zdd = derivatives(z, dt)
    sel = (t >= start - 1e-9 * dt) & (t <= start + window + 1e-9 * dt)
    n = int(sel.sum())
    if n < 5:
        return SecondOrderFit(*(math.nan,) * 5, n, math.inf, FitStatus.TOO_FEW_SAMPLES)
    cols = [zdd[sel], zd[sel], z[sel]] + ([np.ones(n)] if f0 is None else [])
    A = np.stack(cols, axis=1)
    rhs = f[sel] - (0.0 if f0 is None else float(f0))
    scale = np.linalg.norm(A, axis=0)
    if not (scale > 0).all():
        return SecondOrderFit(*(math.nan,) * 5, n, math.inf, FitStatus.SINGULAR)
    As = A / scale
    cond = float(np.linalg.cond(As))
    if not cond < 1e12:
        return SecondOrderFit(*(math.nan,) * 5, n, cond, FitStatus.SINGULAR)
    x, *_ = np.linalg.lstsq(As, rhs, rcond=None)
    x = x / scale
    rms = float(np.sqrt(np.mean((A @ x - rhs) ** 2)))
    f0_out = float(x[3]) if f0 is None else float(f0)
    return SecondOrderFit(float(x[0]), float(x[1]), float(x[2]), f0_out, rms, n, cond, FitStatus.OK)
