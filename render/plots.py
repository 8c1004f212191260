"""Plots of a result directory with matplotlib (Agg backend), written as PNG files.

* :func:`plot_contact_timeline`: per finger, free / static / sliding over time;
* :func:`plot_forces`: per finger, normal and tangential force magnitudes and the friction-cone limit mu f_n;
* :func:`plot_joints`: the flexion joints of each finger (Ye & Liu 2012, Figure 11), several solutions overlaid.

Units on the axes: seconds, newtons, degrees. Every file is written to a temporary name and moved into place.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from torchhand.errors import InputValueError

from .backend import RenderBackendError
from .video import publish
from .contact_analysis import FREE, SLIDING, STATE_NAMES, STATIC, FingerContacts

__all__ = ["plot_contact_timeline", "plot_forces", "plot_joints"]

_STATE_COLORS = {FREE: "#e9e9ec", STATIC: "#2a9d8f", SLIDING: "#f4a261"}


def _pyplot():
    try:
        import matplotlib
    except ImportError:
        raise RenderBackendError("plots need matplotlib: pip install 'matplotlib>=3.7'") from None
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".png", dir=path.parent)
    os.close(fd)
    try:
        fig.savefig(tmp, dpi=120)
        publish(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
        import matplotlib.pyplot as plt

        plt.close(fig)
    return path


def plot_contact_timeline(fc: FingerContacts, path, title: str = "") -> Path:
    """Rows = fingers, time along x, colour = free / static / sliding."""
    plt = _pyplot()
    from matplotlib.patches import Patch

    T, N = fc.state.shape
    fig, ax = plt.subplots(figsize=(8, 0.45 * N + 1.4))
    dt = 1.0 / fc.fps
    for j in range(N):
        for state in (STATIC, SLIDING, FREE):
            on = fc.state[:, j] == state
            if not on.any():
                continue
            starts = np.flatnonzero(on & ~np.r_[False, on[:-1]])
            ends = np.flatnonzero(on & ~np.r_[on[1:], False])
            ax.broken_barh([(s * dt, (e - s + 1) * dt) for s, e in zip(starts, ends)], (N - 1 - j + 0.1, 0.8),
                           facecolors=_STATE_COLORS[state])
    ax.set_yticks(np.arange(N) + 0.5)
    ax.set_yticklabels(list(fc.labels)[::-1])
    ax.set_xlim(0, T * dt)
    ax.set_ylim(0, N)
    ax.set_xlabel("time (s)")
    ax.set_title(title or "contact state per finger")
    ax.legend(handles=[Patch(color=_STATE_COLORS[s], label=STATE_NAMES[s]) for s in (STATIC, SLIDING, FREE)],
              loc="upper center", bbox_to_anchor=(0.5, -0.3 if N < 6 else -0.12), ncol=3, frameon=False)
    fig.tight_layout()
    return _save(fig, path)


def plot_forces(fc: FingerContacts, path, title: str = "") -> Path:
    """Per finger: normal force, tangential force and the cone limit mu f_n over time (newtons)."""
    plt = _pyplot()
    T, N = fc.normal.shape
    t = np.arange(T) / fc.fps
    fig, axes = plt.subplots(N, 1, figsize=(8, 1.3 * N + 1.0), sharex=True, squeeze=False)
    top = max(float(np.nanmax(np.r_[fc.normal.ravel(), fc.tangential.ravel(), [0.0]])) * 1.1, 1e-3)
    for j, ax in enumerate(axes[:, 0]):
        free = fc.state[:, j] == FREE
        fn = np.where(free, np.nan, fc.normal[:, j])
        ft = np.where(free, np.nan, fc.tangential[:, j])
        ax.plot(t, fn, color="#1d3557", lw=1.6, label="normal $f_n$")
        ax.plot(t, ft, color="#e63946", lw=1.6, label="tangential $|f_t|$")
        ax.plot(t, fc.friction * fn, color="#e63946", lw=1.0, ls="--", label=f"cone limit $\\mu f_n$ "
                                                                             f"($\\mu$ = {fc.friction:g})")
        ax.set_ylim(0, top)
        ax.set_ylabel(f"{fc.labels[j]}\n(N)", fontsize=8)
        ax.grid(alpha=0.3)
    axes[0, 0].set_title(title or "contact forces per finger")
    axes[0, 0].legend(loc="upper right", fontsize=7, ncol=3)
    axes[-1, 0].set_xlabel("time (s)")
    fig.tight_layout()
    return _save(fig, path)


def plot_joints(series: list[tuple[str, np.ndarray, tuple]], hand, fps: float, path, title: str = "") -> Path:
    """The flexion joints of each finger, one panel per finger, one colour per solution, one line style per joint.

    series: (label, q (T, D) radians, joint_names (D,)) per solution
    hand: the :class:`~torchhand.hand.HandModel` whose ``flexion_joints`` choose the joints
    """
    plt = _pyplot()
    if not series:
        raise InputValueError("plot_joints: no solutions to plot")
    F = hand.num_fingers
    fig, axes = plt.subplots(1, F, figsize=(3.0 * F, 3.2), sharey=True, squeeze=False)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    styles = ("-", "--", ":")
    flex = hand.flexion_joints.tolist()
    for f in range(F):
        ax = axes[0, f]
        for i, (label, q, names) in enumerate(series):
            index = {n: c for c, n in enumerate(names)}
            t = np.arange(q.shape[0]) / fps
            for s, jid in enumerate(flex[f]):
                if jid < 0 or hand.joint_names[jid] not in index:
                    continue
                ax.plot(t, np.degrees(q[:, index[hand.joint_names[jid]]]), color=colors[i % len(colors)],
                        ls=styles[s % 3], lw=1.3, label=label if s == 0 else None)
        ax.set_title(str(hand.finger_names[f]))
        ax.set_xlabel("time (s)")
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("flexion (degrees)")
    fig.text(0.5, 0.01, "line style: solid = proximal, dashed = middle, dotted = distal flexion joint", ha="center",
             fontsize=8)
    axes[0, -1].legend(fontsize=7, loc="best")
    if title:
        fig.suptitle(title)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    return _save(fig, path)
