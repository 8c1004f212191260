"""Plots of a splice result directory (``torchhand splice --plots``): the cost matrices with the band and both
DTW paths, and the time map (hand time against body time, the uniform line, the local speed ratio)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .plots import _pyplot, _save

__all__ = ["plot_splice"]


def plot_splice(result_dir, out_dir=None) -> list[Path]:
    """Write ``plots/costs.png`` and ``plots/warp.png`` for a splice result directory; returns the paths."""
    d = Path(result_dir)
    w = np.load(d / "warp.npz")
    rep = json.loads((d / "report.json").read_text())
    out = Path(out_dir) if out_dir is not None else d / "plots"
    out.mkdir(parents=True, exist_ok=True)
    plt = _pyplot()
    fb, fh = rep["body_fps"], rep["hand_fps"]
    n, m = w["cost1"].shape
    paths = []

    panels = 2 if w["cost2"].size else 1
    fig, axes = plt.subplots(1, panels, figsize=(6.5 * panels, 5.5), squeeze=False)
    ax = axes[0, 0]
    ax.imshow(w["cost1"].T, origin="lower", aspect="auto", cmap="viridis", extent=(0, n / fb, 0, m / fh))
    i = np.arange(n)
    r = rep["band1_hand_frames"]
    centre = i * (m - 1) / max(n - 1, 1)
    ax.fill_between(i / fb, (centre - r) / fh, (centre + r) / fh, color="white", alpha=0.12, label="band")
    p1 = w["path1"]
    ax.plot(p1[:, 0] / fb, p1[:, 1] / fh, color="red", lw=1.2, label="pass 1 path")
    ax.plot(i / fb, w["hand_time"] / fh, color="white", lw=1.0, ls="--", label="final time map")
    for b, h in rep["matches"]:
        ax.plot([b / fb], [h / fh], marker="s", mfc="none", mec="orange", ms=9)
    ax.set(xlabel="body time (s)", ylabel="hand time (s)", title="pass 1: Eq. 6 sign cost", ylim=(0, m / fh))
    ax.legend(loc="upper left", fontsize=8)
    if panels == 2:
        ax = axes[0, 1]
        ax.imshow(w["cost2"].T, origin="lower", aspect="auto", cmap="magma", extent=(0, n / fb, 0, n / fb))
        p2 = w["path2"]
        ax.plot(p2[:, 0] / fb, p2[:, 1] / fb, color="cyan", lw=1.2, label="pass 2 path")
        ax.set(xlabel="body time (s)", ylabel="pass-1-aligned time (s)", title="pass 2: Eq. 9 palm angle")
        ax.legend(loc="upper left", fontsize=8)
    fig.suptitle(f"{Path(rep['body']).name}  +  {Path(rep['hand']).name}", fontsize=10)
    paths.append(_save(fig, out / "costs.png"))

    fig, (a1, a2) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    t = i / fb
    a1.plot(t, w["hand_time"] / fh, label="hand time shown")
    a1.plot(t, t * ((m - 1) / fh) / max((n - 1) / fb, 1e-9), ls=":", color="gray", label="uniform scaling")
    if rep["matches"]:
        bm = np.array(rep["matches"])
        a1.plot(bm[:, 0] / fb, bm[:, 1] / fh, "s", mfc="none", mec="orange", label="matching points")
    a1.set(ylabel="hand time (s)", title="time map")
    a1.legend(fontsize=8)
    speed = np.gradient(w["hand_time"] / fh, 1.0 / fb) if n > 1 else np.ones(1)
    a2.plot(t, speed, color="purple")
    a2.axhline(1.0, color="gray", ls=":")
    a2.fill_between(t, 0, 1, where=speed < 0.05, color="orange", alpha=0.2, transform=a2.get_xaxis_transform(),
                    label="hand held (speed < 0.05)")
    a2.set(xlabel="body time (s)", ylabel="local speed (hand s / body s)")
    a2.legend(fontsize=8)
    paths.append(_save(fig, out / "warp.png"))
    return paths
