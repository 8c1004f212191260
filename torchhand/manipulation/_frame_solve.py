"""The iterations of one frame's synthesis (:func:`.synth.synthesize_frame`): damped Gauss-Newton on the l1 merit
with second-order corrections until the merit is stationary, then polishing steps (docs/manipulation.md, "Converged
frames"). Budgets are iterations, never time.

x = (q (D,), root (4, 4), s (H,)); a step dx = (root twist (3), root translation (3), joints (D), s (H)); ``step(L,
lm, project=False)`` returns the QP step at the linearisation L with damping lm (or the least-norm step onto the
constraints); ``base`` (nv,) the step scales.
"""

from __future__ import annotations

import numpy as np

from ._frame_geometry import exp_rot
from ._frame_linearise import linearise

__all__ = ["VIOL_TOL", "LM_MAX", "POLISH_STEPS", "POLISH_TOL", "POLISH_RATE", "POLISH_MAX"]

VIOL_TOL = 1e-9
"""A frame's constraints hold when their largest violation is at most this (metres; radians for angles)."""

LM_MAX = 1e3
"""Damping beyond which no shorter step is tried: the merit is stationary at the current point."""

POLISH_STEPS = 40
"""Work budget of the polishing steps after the merit is stationary, Gauss-Newton iterations."""

POLISH_TOL = 1e-9
"""Polishing stops when a step moves every variable by at most this fraction of its step scale."""

POLISH_RATE = 0.95
"""Each polishing step must be shorter than this fraction of the one before (a contraction)."""

POLISH_MAX = 0.1
"""The first polishing step may be at most this fraction of the step scale."""


def _apply_step(x, dx, N):
    """x = (q, root, s) moved by the step dx = (root twist, q, s) (N = 6 + D); s kept in [0, 1]."""
    q, root, s = x
    root = root.copy()
    root[:3, :3] = exp_rot(dx[:3]) @ root[:3, :3]
    root[:3, 3] = root[:3, 3] + dx[3:6]
    return q + dx[6:N], root, np.clip(s + dx[N:], 0.0, 1.0)


def _trial(setup, x, dx, L, step, N):
    """The point x + dx and its linearisation, with a second-order correction when the step raised the merit by
    breaking the (curved) constraints it was linearised on: one least-norm step back onto them from x + dx, kept
    when it lowers the merit (the Maratos effect: without it a Gauss-Newton step that improves the objective is
    rejected for the second-order violation it brings, and the iterates creep)."""
    xn = _apply_step(x, dx, N)
    Ln = linearise(setup, *xn)
    if Ln.merit > L.merit and Ln.viol > L.viol:
        xc = _apply_step(xn, step(Ln, 0.0, project=True), N)
        Lc = linearise(setup, *xc)
        if Lc.merit < Ln.merit:
            return xc, Lc
    return xn, Ln


def _iterate(setup, x, L, max_iters: int, step, base, N):
    """Damped Gauss-Newton on the l1 merit until it is stationary (module docstring, "Convergence").

    Returns (x, its linearisation, iterations, converged). A step is accepted when it does not raise the merit
    (beyond rounding); after an accepted step the damping falls by 3, after a rejected one it rises by 10.
    The merit is stationary when an accepted step changed it by at most ``merit_tol`` of it, or moved no variable
    by more than ``step_tol`` of its step scale, or no step lowers it however short (the damping reached
    ``LM_MAX``); then :func:`_polish` decides convergence. Not stationary within ``max_iters``: not converged. The
    caller also requires the constraints to hold within ``VIOL_TOL``."""
    st = setup.st
    lm, it = 1e-5, 0
    while it < max_iters:
        it += 1
        dx = step(L, lm)
        xn, Ln = _trial(setup, x, dx, L, step, N)
        if Ln.merit > L.merit * (1 + 1e-12) + 1e-15:
            lm *= 10.0                                     # backtrack: more damping, a shorter step
            if lm > LM_MAX:                                # no descent at any step length: stationary
                return _polish(setup, x, L, it, max_iters + POLISH_STEPS, step, base, N)
            continue
        change = L.merit - Ln.merit
        x, L = xn, Ln
        lm = max(lm / 3.0, 1e-9)
        if change <= st.merit_tol * (1.0 + L.merit) or np.abs(dx / base).max() <= st.step_tol:
            return _polish(setup, x, L, it, max_iters + POLISH_STEPS, step, base, N)
    return x, L, it, False


def _polish(setup, x, L, it: int, budget: int, step, base, N):
    """Undamped Gauss-Newton steps from a point where the merit is stationary, accepted without comparing merits
    (at this point merit differences are rounding: they cannot place the iterate closer than about
    sqrt(rounding / curvature), milliradians along weakly determined directions), as long as each step is shorter
    than ``POLISH_RATE`` times the one before, until a step is at most ``POLISH_TOL`` of the step scale. When the
    steps stop contracting or the budget runs out, the last point is kept if its merit is within ``merit_tol`` of
    the stationary point's and its constraints hold as well; otherwise the stationary point is.

    Returns (x, its linearisation, iterations, True): the merit is stationary either way."""
    x0, L0, tol = x, L, setup.st.merit_tol
    size_before = POLISH_MAX
    while it < budget:
        dx = step(L, 1e-9)
        size = float(np.abs(dx / base).max())
        if size > POLISH_RATE * size_before:
            break
        it += 1
        x = _apply_step(x, dx, N)
        L = linearise(setup, *x)
        if size <= POLISH_TOL:
            break
        size_before = size
    if L.merit <= L0.merit * (1 + tol) + 1e-15 and L.viol <= max(L0.viol, VIOL_TOL):
        return x, L, it, True
    return x0, L0, it, True
