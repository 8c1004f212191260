"""Plots of a compliance estimate (matplotlib, Agg backend; files written atomically).

* ``compliance_events.png``: per generalized coordinate (x), every event's estimate: valid as dots, rejected as
  crosses at their raw value (clipped to the axis) labelled by reason, the truth (when known) as a bar, the default
  as a grey tick.
* ``contact_event_<e>.png`` (Fig. 3 analogue): for the loaded coordinates of event e (at most ``max_joints``),
  theta_j and tau_j against time around t_c with the pre and post windows shaded, the fitted polynomials, and
  theta_r = theta - c tau.
* :func:`plot_slip_ratio_comparison` (Fig. 14 analogue): resynthesised rollouts side by side, the ratio
  |f_t| / f_n of every hand link's contact against time with lines at mu and the imminent-slip threshold, the grip
  events marked, and the normal forces below.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from .._atomic import atomic_bytes
from .estimate import REASON_NAMES, Reason

__all__ = ["plot_compliance_events", "plot_contact_event", "write_plots", "plot_slip_ratio_comparison"]


def _figure(*args, **kwargs):
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    return Figure(*args, **kwargs)


def _save(fig, path: Path) -> Path:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    atomic_bytes(path, buf.getvalue())
    return path


def plot_compliance_events(result, path) -> Path:
    """``compliance_events.png`` of a :class:`~torchhand.interaction.pipeline.CaptureEstimate`."""
    est = result.estimate
    E, N = est.raw.shape
    show = [j for j in range(N) if not np.all(np.isin(est.reason[:, j], (Reason.FIXED, Reason.NOT_LOADED)))]
    show = show or list(range(N))
    fig = _figure(figsize=(max(6.0, 0.45 * len(show) + 2), 4.5))
    ax = fig.add_subplot(1, 1, 1)
    finite = est.values[:, show][np.isfinite(est.values[:, show])]
    top = float(np.percentile(finite, 98)) * 1.5 if finite.size else 1.0
    if result.truth is not None and np.isfinite(result.truth[show]).any():
        top = max(top, 1.5 * float(np.nanmax(result.truth[show])))
    top = max(top, 1.2 * float(np.max(result.defaults[show])))
    x = np.arange(len(show))
    for i, j in enumerate(show):
        v = est.valid[:, j]
        jitter = np.linspace(-0.2, 0.2, E) if E > 1 else np.zeros(1)
        ax.plot(i + jitter[v], est.values[v, j], "o", ms=3, color="C0", label="valid" if i == 0 else None)
        bad = ~v & ~np.isin(est.reason[:, j], (Reason.FIXED, Reason.NOT_LOADED))
        raw = np.clip(np.nan_to_num(est.raw[bad, j], nan=0.0), -0.2 * top, top)
        ax.plot(i + jitter[bad], raw, "x", ms=4, color="C3", label="rejected" if i == 0 else None)
        if result.truth is not None and np.isfinite(result.truth[j]):
            ax.plot([i - 0.35, i + 0.35], [result.truth[j]] * 2, "-", color="k", lw=2,
                    label="truth" if i == 0 else None)
        ax.plot([i - 0.3, i + 0.3], [result.defaults[j]] * 2, "-", color="0.6", lw=1,
                label="default" if i == 0 else None)
    counts = {}
    for r in est.reason[:, show].reshape(-1).tolist():
        if r not in (Reason.VALID, Reason.FIXED, Reason.NOT_LOADED):
            counts[REASON_NAMES[r]] = counts.get(REASON_NAMES[r], 0) + 1
    ax.set_title(f"compliance at {E} contact events" + (
        "; rejected: " + ", ".join(f"{k} {n}" for k, n in sorted(counts.items())) if counts else ""), fontsize=9)
    ax.set_xticks(x)
    ax.set_xticklabels([result.names[j] for j in show], rotation=60, ha="right", fontsize=7)
    ax.set_ylabel("compliance, rad/(N m)  (root linear: m/N)")
    ax.set_ylim(-0.2 * top, top)
    ax.axhline(0.0, color="0.8", lw=0.5)
    ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    return _save(fig, Path(path))


def plot_contact_event(result, e: int, path, max_joints: int = 6) -> Path:
    """``contact_event_<e>.png`` (Fig. 3 analogue) for event ``e``."""
    est = result.estimate
    lo, k, hi = (int(v) for v in est.windows[e])
    fps = result.fps
    loaded = [j for j in range(est.raw.shape[1]) if est.reason[e, j] not in (Reason.FIXED, Reason.NOT_LOADED)]
    # the most loaded first
    loaded.sort(key=lambda j: -abs(np.nan_to_num(est.tau_rate[e, j])))
    loaded = loaded[:max_joints] or [0]
    a, b = max(lo - (k - lo), 0), min(hi + (hi - k) // 2, result.theta.shape[0])
    t = (np.arange(a, b) - k) / fps
    fig = _figure(figsize=(3.2 * len(loaded), 5.0))
    cp, cq, ct, cu = est.fits[e] if est.fits else (None,) * 4
    for col, j in enumerate(loaded):
        ax1 = fig.add_subplot(2, len(loaded), col + 1)
        ax2 = fig.add_subplot(2, len(loaded), len(loaded) + col + 1, sharex=ax1)
        for ax in (ax1, ax2):
            ax.axvspan((lo - k) / fps, 0.0, color="C2", alpha=0.12)
            ax.axvspan(0.0, (hi - k) / fps, color="C1", alpha=0.12)
            ax.axvline(0.0, color="k", lw=0.6)
        ax1.plot(t, result.theta[a:b, j], ".", ms=2, color="C0", label="θ")
        ax2.plot(t, result.tau[a:b, j], ".", ms=2, color="C3", label="τ")
        if cp is not None and hi > k and k > lo:
            tp = np.linspace((lo - k) / fps, (hi - k) / fps, 60)
            tq = np.linspace(0.0, (hi - k) / fps, 40)
            poly = lambda c, x: c[0, j] + c[1, j] * x + c[2, j] * x * x  # noqa: E731
            ax1.plot(tp, poly(cp, tp), "-", color="C2", lw=1, label="pre fit (extrapolated)")
            ax1.plot(tq, poly(cq, tq), "-", color="C1", lw=1, label="post fit")
            ax2.plot(tq, poly(cu, tq), "-", color="C1", lw=1)
            c = est.raw[e, j]
            if np.isfinite(c):
                ax1.plot(t, result.theta[a:b, j] - c * result.tau[a:b, j], "-", color="0.5", lw=0.8,
                         label="θ − c τ")
        reason = REASON_NAMES[int(est.reason[e, j])]
        ax1.set_title(f"{result.names[j]}: c = {est.raw[e, j]:.3g} ({reason})", fontsize=8)
        ax2.set_xlabel("t − t_c, s", fontsize=8)
        if col == 0:
            ax1.set_ylabel("angle, rad", fontsize=8)
            ax2.set_ylabel("torque, N m", fontsize=8)
            ax1.legend(fontsize=6)
        for ax in (ax1, ax2):
            ax.tick_params(labelsize=7)
    fig.suptitle(f"contact event {e} at t = {result.events.time[e]:.3f} s (sensor {result.events.sensor[e]})",
                 fontsize=9)
    fig.tight_layout()
    return _save(fig, Path(path))


def write_plots(result, out, *, max_events: int | None = None) -> list[Path]:
    """``compliance_events.png`` and one ``contact_event_<e>.png`` per event (the first ``max_events`` if given)."""
    out = Path(out)
    paths = [plot_compliance_events(result, out / "compliance_events.png")]
    E = result.events.count if max_events is None else min(result.events.count, max_events)
    for e in range(E):
        paths.append(plot_contact_event(result, e, out / f"contact_event_{e}.png"))
    return paths


def _per_link(arrays: dict, values: np.ndarray) -> dict:
    """Per hand link: the (T,) series of ``values`` (T, K) at the columns where that link is in contact (NaN
    where it is not); the columns of a result's contact arrays change owner from frame to frame."""
    link = arrays["contact_link"]
    out = {}
    for lk in sorted(int(v) for v in np.unique(link[link >= 0])):
        hit = link == lk
        out[lk] = np.where(hit.any(1), np.where(hit, values, 0.0).sum(1), np.nan)
    return out


def plot_slip_ratio_comparison(results, path, *, ratio: float = 0.9) -> Path:
    """Fig. 14 analogue: one column per rollout, side by side.

    results: sequence of (title, arrays) with ``arrays`` the npz arrays of a resynthesised rollout
        (:func:`torchhand.interaction.resynth.solution_arrays`: ``slip_ratio`` (T, K), ``contact_link`` (T, K),
        ``contact_force`` and ``contact_normal`` (T, K, 3), ``grip_events`` (G, 2) rows (frame, link),
        ``friction``, ``fps``, ``contact_link_name``)
    path: the PNG to write; ratio: the imminent-slip threshold as a fraction of mu (the paper: 0.9)
    Top row: |f_t| / f_n per hand link (computed where the normal force exceeds the watch threshold, 0 elsewhere),
    mu and ratio x mu as dashed lines, grip events as ticks along the top; bottom row: the normal force per link.
    """
    results = list(results)
    fig = _figure(figsize=(4.2 * len(results), 5.6))
    axes_top, axes_bot = [], []
    for col, (title, a) in enumerate(results):
        ax = fig.add_subplot(2, len(results), col + 1, sharey=axes_top[0] if axes_top else None)
        bx = fig.add_subplot(2, len(results), len(results) + col + 1, sharex=ax,
                             sharey=axes_bot[0] if axes_bot else None)
        axes_top.append(ax)
        axes_bot.append(bx)
        fps, mu = float(a["fps"]), float(a["friction"])
        T = a["slip_ratio"].shape[0]
        t = np.arange(T) / fps
        names = [str(n) for n in a["contact_link_name"]]
        fn = (a["contact_force"] * a["contact_normal"]).sum(-1) * a["contact_mask"]
        rho = _per_link(a, a["slip_ratio"])
        force = _per_link(a, np.abs(fn))
        for i, lk in enumerate(rho):
            ax.plot(t, rho[lk], "-", lw=1.0, color=f"C{i}", label=names[lk])
            bx.plot(t, force[lk], "-", lw=1.0, color=f"C{i}", label=names[lk])
        ax.axhline(mu, color="k", ls="--", lw=0.8, label="µ")
        ax.axhline(ratio * mu, color="C3", ls=":", lw=0.9, label=f"{ratio:g} µ")
        ev = np.asarray(a["grip_events"]).reshape(-1, 2)
        if ev.size:
            frames = np.unique(ev[:, 0])
            ax.plot(frames / fps, np.full(frames.shape, 1.08 * mu), "|", color="C3", ms=6, label="grip event")
        peak = float(np.nanmax(a["slip_ratio"])) if T else 0.0
        ax.set_title(f"{title}\npeak ratio {peak:.3f} ({peak / mu:.2f} µ), {len(ev)} grip events", fontsize=9)
        ax.set_ylim(0.0, 1.2 * mu)
        ax.set_xlim(0.0, max(t[-1], 1.0 / fps) if T else 1.0)
        ax.tick_params(labelsize=7)
        bx.tick_params(labelsize=7)
        bx.set_xlabel("time, s", fontsize=8)
        if col == 0:
            ax.set_ylabel("|f_t| / f_n", fontsize=8)
            bx.set_ylabel("normal force, N", fontsize=8)
            ax.legend(fontsize=6, loc="lower right")
    fig.tight_layout()
    return _save(fig, Path(path))
