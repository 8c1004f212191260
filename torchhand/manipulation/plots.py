"""Plots of a manipulation result directory (``torchhand manipulate``; matplotlib, Agg backend; files written
atomically).

* ``torque_deviation.png``: per frame, the torque deviation ``|u - u_bar|^2`` of Liu's objective (Eq. 8), split into
  the six wrist rows (torque about the root origin, N m, and force, N: the wrench the wrist carries), the finger
  joints (N m) and each finger's joints; with a second result (``compare``, e.g. the ``--no-objective`` ablation)
  overlaid dashed. The legend gives each run's sums over the frames. Two hands: both hands' deviations add up.
* ``forces.png``: per hand contact (slot in order of creation), the magnitude of the stored (re-projected) contact
  force |f| and of the planned force |F_k| (Sec. 4), newtons; added contacts (Sec. 4.3) are titled so and their
  first active frame is marked.
* ``contact_timeline.png``: contacts x frames, each cell inactive, active (static), sliding, or, for an added contact
  (Sec. 4.3), added static or added sliding.

Read from ``solutions/sol_000.npz`` (``torque``, ``torque_rest``, ``contact_*``, ``planned_force``; the contact's slot
from ``contact_slot`` and its link from ``contact_slot_link``, or the column when an older result lacks them) and
``hand.xml`` (which finger each joint moves:
the finger of the link the joint moves; joints of no finger are grouped as "palm").
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._atomic import atomic_bytes
from ..errors import FileFormatError, InputValueError, MissingFileError

__all__ = ["STATES", "ManipulationTrace", "is_manipulation_result", "load_trace", "plot_contact_timeline",
           "plot_forces", "plot_torque_deviation", "torque_deviation", "write_plots"]

INACTIVE, ACTIVE, SLIDING, ADDED, ADDED_SLIDING = 0, 1, 2, 3, 4
STATES = (INACTIVE, ACTIVE, SLIDING, ADDED, ADDED_SLIDING)
_STATE_NAMES = {INACTIVE: "inactive", ACTIVE: "active (static)", SLIDING: "sliding", ADDED: "added, static",
                ADDED_SLIDING: "added, sliding"}
_STATE_COLORS = {INACTIVE: "#eeeeee", ACTIVE: "#2a9d8f", SLIDING: "#f4a261", ADDED: "#6a4c93",
                 ADDED_SLIDING: "#c77dff"}


@dataclass(frozen=True, eq=False)
class ManipulationTrace:
    """What the plots read from one manipulation result (T frames, D joints, K contact slots; NumPy float64).

    label: the result's name and objective, for legends; objective: "torque" (Liu's) or "pose" (the ablation)
    fps: frames per second; complete: stats.json's ``complete`` (False: the grasp became unsuitable, frames cut)
    torque: u, (T, 6 + D); torque_rest: u_bar, (6 + D,): (torque about the root origin N m, force N, joints N m)
    joint_finger: finger name of each joint, (D,) str; finger_names: fingers in the hand's order (+ "palm")
    slot_link: link name of each slot, (K,) str ("" when an older result does not name a never-active slot)
    force, planned: stored and planned force of each slot, (T, K, 3), newtons (0 where inactive)
    mask, sliding, added: (T, K) bool, per slot
    more_hands: with two hands, the second hand's (torque, torque_rest, joint_finger); ``torque`` above is the right
        hand's, and the deviations add both hands
    """

    label: str
    objective: str
    fps: float
    complete: bool
    torque: np.ndarray
    torque_rest: np.ndarray
    joint_finger: np.ndarray
    finger_names: tuple
    slot_link: np.ndarray
    force: np.ndarray
    planned: np.ndarray
    mask: np.ndarray
    sliding: np.ndarray
    added: np.ndarray
    more_hands: tuple = ()

    @property
    def T(self) -> int:
        return int(self.torque.shape[0])

    def states(self) -> np.ndarray:
        """(T, K) int: INACTIVE, ACTIVE, SLIDING, ADDED or ADDED_SLIDING per frame and slot."""
        s = np.where(self.mask, np.where(self.sliding, SLIDING, ACTIVE), INACTIVE)
        return np.where(self.mask & self.added, s + (ADDED - ACTIVE), s)


def _stats(path: Path) -> dict:
    f = path / "stats.json"
    if not f.is_file():
        return {}
    try:
        stats = json.loads(f.read_text())
    except (OSError, ValueError) as err:
        raise FileFormatError(f"{f}: cannot read: {err}") from None
    return stats if isinstance(stats, dict) else {}


def is_manipulation_result(path) -> bool:
    """Whether ``path`` is a ``torchhand manipulate`` result directory (stats.json ``method: "liu2009"``)."""
    p = Path(path)
    return p.is_dir() and _stats(p).get("method") == "liu2009"


def load_trace(path) -> ManipulationTrace:
    """Read the plotted arrays of the manipulation result directory ``path`` (solution 0).

    Raises:
        MissingFileError: no such directory or no solutions/sol_000.npz;
        InputValueError: not a manipulation result (stats.json's method is not "liu2009");
        FileFormatError: a key of the manipulation result is missing.
    """
    from ..io.result import load_result

    root = Path(path)
    if not root.is_dir():
        raise MissingFileError(f"{root}: no such result directory")
    stats = _stats(root)
    if stats.get("method") != "liu2009":
        raise InputValueError(f"{root}: not a manipulation result (stats.json method is "
                              f"{stats.get('method')!r}, expected 'liu2009' from torchhand manipulate)")
    sol = root / "solutions" / "sol_000.npz"
    if not sol.is_file():
        raise MissingFileError(f"{sol}: the manipulation result has no solution file")
    result = load_result(root)
    hand = next(iter(result.hand_models.values()))
    with np.load(sol, allow_pickle=False) as z:
        need = ("torque", "torque_rest", "joint_names", "contact_mask", "contact_link", "contact_link_name",
                "contact_force", "planned_force", "contact_sliding", "contact_added")
        missing = [k for k in need if k not in z.files]
        if missing:
            raise FileFormatError(f"{sol}: missing key(s) {', '.join(missing)} of a manipulation result")
        a = {k: z[k] for k in need}
        extra = {k: z[k] for k in z.files if k.endswith(("_right", "_left")) and k.startswith(("torque", "joint_"))}
        slot = z["contact_slot"] if "contact_slot" in z.files else None
        slot_link = z["contact_slot_link"] if "contact_slot_link" in z.files else None
        fps = float(z["fps"]) if "fps" in z.files else float(result.scene.fps)
    mask = a["contact_mask"].astype(bool)
    T, C = mask.shape
    if slot is None:                                  # older results: the column is the slot
        slot = np.where(mask, np.arange(C)[None], -1)
    K = int(slot.max()) + 1 if slot.size and slot.max() >= 0 else 0
    force, planned = np.zeros((T, K, 3)), np.zeros((T, K, 3))
    m, sl, ad = (np.zeros((T, K), bool) for _ in range(3))
    link = np.array([""] * K, dtype=object)
    names = [str(n) for n in a["contact_link_name"]]
    for t, c in zip(*np.nonzero(slot >= 0)):
        k = slot[t, c]
        force[t, k], planned[t, k] = a["contact_force"][t, c], a["planned_force"][t, c]
        m[t, k], sl[t, k], ad[t, k] = mask[t, c], a["contact_sliding"][t, c], a["contact_added"][t, c]
        link[k] = names[int(a["contact_link"][t, c])]
    if slot_link is not None and len(slot_link) >= K:        # slots that were never active have a name too
        K = len(slot_link)
        force, planned, m, sl, ad = (np.concatenate([x, np.zeros((T, K - x.shape[1]) + x.shape[2:], x.dtype)], 1)
                                     for x in (force, planned, m, sl, ad))
        link = np.array([names[int(i)] for i in slot_link], dtype=object)
    fingers = tuple(str(f) for f in hand.finger_names)
    joint_finger = _joint_fingers(hand, a["joint_names"])
    more = []
    if "torque_left" in extra and "torque_right" in extra:   # two hands: torque/joint_names are the right hand's
        left = _joint_fingers(result.hand_models["left"], extra["joint_names_left"])
        more.append((extra["torque_left"], extra["torque_rest_left"], left))
    joint_finger_all = np.concatenate([joint_finger] + [m[2] for m in more])
    finger_names = fingers + (("palm",) if "palm" in set(joint_finger_all) else ())
    objective = str(stats.get("settings", {}).get("synth", {}).get("objective", "torque"))
    what = "|u - u_bar|^2 objective" if objective == "torque" else "ablation: |q - q_prev|^2 objective"
    return ManipulationTrace(label=f"{root.name} ({what})", objective=objective, fps=fps,
                             complete=bool(stats.get("complete", True)), torque=a["torque"].astype(np.float64),
                             torque_rest=a["torque_rest"].astype(np.float64), joint_finger=joint_finger,
                             finger_names=finger_names, slot_link=link, force=force, planned=planned, mask=m,
                             sliding=sl, added=ad, more_hands=tuple(more))


def _joint_fingers(hand, joint_names) -> np.ndarray:
    """The finger name (or "palm") of each joint in ``joint_names``, (D,) str."""
    joint_link = hand.chain.joint_link.cpu().numpy()
    link_finger = hand.link_finger.cpu().numpy()
    fingers = tuple(str(f) for f in hand.finger_names)
    by_name = {str(n): (fingers[link_finger[joint_link[j]]] if link_finger[joint_link[j]] >= 0 else "palm")
               for j, n in enumerate(hand.joint_names)}
    return np.array([by_name.get(str(n), "palm") for n in joint_names])


def torque_deviation(trace: ManipulationTrace) -> dict:
    """Per-frame squared torque deviation |u - u_bar|^2, (T,) each: ``"wrist"`` (the six root rows; N m and N
    mixed, as in the objective), ``"joints"`` (all finger joints, (N m)^2) and one key per finger name."""
    hands = ((trace.torque, trace.torque_rest, trace.joint_finger),) + tuple(trace.more_hands)
    out = {"wrist": 0.0, "joints": 0.0, **{f: 0.0 for f in trace.finger_names}}
    for torque, rest, joint_finger in hands:                 # two hands: both hands' deviations add up
        d2 = (torque - rest[None]) ** 2
        out["wrist"] = out["wrist"] + d2[:, :6].sum(1)
        out["joints"] = out["joints"] + d2[:, 6:].sum(1)
        for f in trace.finger_names:
            out[f] = out[f] + d2[:, 6:][:, joint_finger == f].sum(1)
    return out


# ------------------------------------------------------------------------------------------------ drawing
def _figure(**kwargs):
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    return Figure(**kwargs)


def _save(fig, path) -> Path:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    atomic_bytes(Path(path), buf.getvalue())
    return Path(path)


def _cut(trace: ManipulationTrace) -> str:
    return "" if trace.complete else " [stopped early: grasp unsuitable]"


def plot_torque_deviation(trace: ManipulationTrace, path, compare: ManipulationTrace | None = None) -> Path:
    """``torque_deviation.png``: three panels over the frames (wrist rows, finger joints, per finger), ``trace``
    solid and ``compare`` dashed in the same colours."""
    runs = [(trace, "-")] + ([(compare, "--")] if compare is not None else [])
    fig = _figure(figsize=(9, 8.5))
    axes = fig.subplots(3, 1, sharex=True)
    colors = ["#1d3557", "#e63946", "#2a9d8f", "#f4a261", "#6a4c93", "#8d99ae", "#588157"]
    for tr, ls in runs:
        dev = torque_deviation(tr)
        x = np.arange(tr.T)
        tag = tr.label + _cut(tr)
        axes[0].plot(x, dev["wrist"], ls=ls, color="#1d3557", lw=1.5,
                     label=f"{tag}: sum {dev['wrist'].sum():.4g}")
        axes[1].plot(x, dev["joints"], ls=ls, color="#e63946", lw=1.5,
                     label=f"{tag}: sum {dev['joints'].sum():.4g}")
        for i, f in enumerate(tr.finger_names):
            axes[2].plot(x, dev[f], ls=ls, color=colors[i % len(colors)], lw=1.3,
                         label=f"{f}" + (f" ({'solid' if ls == '-' else 'dashed'})" if compare is not None else "")
                         + f": sum {dev[f].sum():.3g}")
    axes[0].set_ylabel("wrist rows\n(N m)^2 + N^2")
    axes[0].set_title("torque deviation |u - u_bar|^2 per frame" + ("" if compare is None else
                                                                      ": solid = first, dashed = compared run"))
    axes[1].set_ylabel("finger joints\n(N m)^2")
    axes[2].set_ylabel("per finger\n(N m)^2")
    axes[2].set_xlabel("frame")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.set_ylim(bottom=0)
    axes[0].legend(fontsize=7, loc="upper left")
    axes[1].legend(fontsize=7, loc="upper left")
    axes[2].legend(fontsize=6, loc="upper left", ncol=2 if compare is not None else 1)
    fig.tight_layout()
    return _save(fig, path)


def plot_forces(trace: ManipulationTrace, path) -> Path:
    """``forces.png``: one panel per hand contact slot, |f| (stored) solid and |F_k| (planned) dashed, newtons;
    added contacts titled so, their first active frame marked by a vertical line."""
    K = trace.force.shape[1]
    cols = 3 if K > 4 else max(K, 1)
    rows = max(1, -(-K // cols))
    fig = _figure(figsize=(3.6 * cols, 1.9 * rows + 0.9))
    axes = np.atleast_1d(fig.subplots(rows, cols, sharex=True, squeeze=False)).reshape(-1)
    x = np.arange(trace.T)
    fmag = np.where(trace.mask, np.linalg.norm(trace.force, axis=-1), np.nan)
    pmag = np.where(trace.mask, np.linalg.norm(trace.planned, axis=-1), np.nan)
    top = max(float(np.nanmax(np.r_[fmag.ravel(), pmag.ravel(), [0.0]])) * 1.1, 1e-3)
    for k in range(K):
        ax = axes[k]
        ax.plot(x, fmag[:, k], color="#1d3557", lw=1.5, label="|f| stored (re-projected)")
        ax.plot(x, pmag[:, k], color="#e63946", lw=1.1, ls="--", label="|F| planned")
        slide = trace.mask[:, k] & trace.sliding[:, k]
        if slide.any():
            ax.plot(x[slide], fmag[slide, k], "o", ms=2.5, color="#f4a261", label="sliding")
        title = f"{k}: {trace.slot_link[k]}" + ("" if trace.mask[:, k].any() else " (never active)")
        if trace.added[:, k].any():
            first = int(np.flatnonzero(trace.added[:, k])[0])
            ax.axvline(first, color="#6a4c93", lw=1.2, ls=":")
            title += f" (added, frame {first})"
        ax.set_title(title, fontsize=8)
        ax.set_ylim(0, top)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
    for ax in axes[K:]:
        ax.set_visible(False)
    if K:
        axes[0].legend(fontsize=6, loc="upper left")
    fig.suptitle(f"hand contact forces (N) per contact: {trace.label}{_cut(trace)}", fontsize=9)
    fig.supxlabel("frame", fontsize=8)
    fig.tight_layout()
    return _save(fig, path)


def plot_contact_timeline(trace: ManipulationTrace, path) -> Path:
    """``contact_timeline.png``: rows = hand contact slots, columns = frames, colour = the contact's state
    (:meth:`ManipulationTrace.states`)."""
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    states = trace.states()
    K = states.shape[1]
    fig = _figure(figsize=(9, 0.32 * K + 1.8))
    ax = fig.subplots(1, 1)
    cmap = ListedColormap([_STATE_COLORS[s] for s in STATES])
    ax.imshow(states.T if K else np.zeros((1, trace.T)), aspect="auto", interpolation="nearest", cmap=cmap,
              vmin=-0.5, vmax=len(STATES) - 0.5, extent=(-0.5, trace.T - 0.5, max(K, 1) - 0.5, -0.5))
    ax.set_yticks(np.arange(K))
    ax.set_yticklabels([f"{k}: {trace.slot_link[k]}" for k in range(K)], fontsize=7)
    ax.set_xlabel("frame")
    ax.set_title(f"contact states: {trace.label}{_cut(trace)}", fontsize=9)
    ax.legend(handles=[Patch(color=_STATE_COLORS[s], label=_STATE_NAMES[s]) for s in STATES],
              loc="upper center", bbox_to_anchor=(0.5, -0.18 if K > 6 else -0.35), ncol=5, frameon=False,
              fontsize=7)
    fig.tight_layout()
    return _save(fig, path)


def write_plots(result, out_dir, *, compare=None) -> list[Path]:
    """Write torque_deviation.png, forces.png and contact_timeline.png of the manipulation result directory
    ``result`` into ``out_dir`` (created); ``compare``: a second manipulation result overlaid on the torque
    deviation (e.g. the ``--no-objective`` ablation), or None. Returns the paths written."""
    trace = load_trace(result)
    other = load_trace(compare) if compare is not None else None
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputValueError(f"--out {out}: expected a directory, got a file")
    out.mkdir(parents=True, exist_ok=True)
    return [plot_torque_deviation(trace, out / "torque_deviation.png", other),
            plot_forces(trace, out / "forces.png"),
            plot_contact_timeline(trace, out / "contact_timeline.png")]
