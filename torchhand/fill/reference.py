"""The captured fingers as a reference: where a capture has finger joints, compare the synthesized fingers with them.

A hand BVH (ManipNet's ``rightHand.bvh``) carries the fingers the capture saw. torchhand never uses them to
synthesize; they are only the reference a filled motion is compared with.

* **Captured fingertips** (:func:`captured_fingertips`): below the wrist joint of the scene's source
  (``scene.source``, :class:`~torchhand.scene.MocapSource`), the first chain whose joint names contain ``thumb``,
  ``index``, ``middle``/``mid``, ``ring`` and ``pinky``/``pinkie``/``little`` (breadth first), and in each chain its
  deepest joint (the ``End Site``: the end of the finger). Its positions are converted into the scene's world
  exactly as the wrist is (:func:`torchhand.scene.mocap.convert_transforms`: mirror, units, up axis). Scene frame
  ``k`` is source frame ``s = first_frame + k * source.fps / scene.fps``; positions are interpolated linearly
  between the two source frames around ``s`` (the scene's own wrist track is resampled the same way, so the wrist
  joint read this way lands on the scene's wrist: the tests check it).
* **Synthesized fingertips** (:func:`solution_fingertips`): the hand model's fingertip pad points
  (``HandModel.fingertip`` on each ``distal_link``) after forward kinematics of a solution's joint angles on its
  wrist poses. A pad point lies a few millimetres back and palmar of the end of the finger, so a perfect match
  reads a few millimetres, not zero.
* **Contact** (:func:`compare_fingers`): a fingertip is in contact where its distance to the object's mesh (exact,
  trimesh, in the object frame) is at most ``contact_distance`` or it is inside a watertight mesh. The captured
  fingers are always judged this way; the synthesized ones too unless the caller gives their contacts.
* **Agreement** (:meth:`FingerComparison.summary`): over the compared frames, the median and 90th percentile of the
  fingertip distance (mm, all fingers together and per finger), the fraction of frames where the set of fingers in
  contact is the same, and per finger the fraction of frames where its contact state is the same.

Conventions: world z-up, metres, seconds; finger order :data:`FINGERS` (thumb, index, middle, ring, little).
"""

from __future__ import annotations

import functools
import io
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .._atomic import atomic_bytes
from ..errors import InputValueError, ShapeError
from .phases import _track

__all__ = ["FINGERS", "CONTACT_DISTANCE", "captured_fingertips", "solution_fingertips", "FingerComparison",
           "compare_fingers", "plot_comparison", "reference_report"]

FINGERS = ("thumb", "index", "middle", "ring", "little")
"""The finger order of every (T, F, 3) array here, F = 5."""

CONTACT_DISTANCE = 0.02
"""Metres: a fingertip within this distance of the object's surface is in contact. The captured finger ends of
ManipNet's mug1 sit about 10 mm off the mug while it is held (median over the contact phases; the End Site lies on
the finger's axis, a finger's radius from its skin): 20 mm calls 73-90 % of the held frames of the four fingers
in contact (the little finger's 47 %), 10 mm only 17-43 %, and no frame of the free phases at either."""

_FINGER_KEYS = (("thumb",), ("index",), ("middle", "mid"), ("ring",), ("pinky", "pinkie", "little"))


# ---------------------------------------------------------------------------------------------------------------
# captured fingers


@functools.lru_cache(maxsize=4)
def _read_clip(path: str, stamp: int):
    """The BVH at ``path`` (cached per modification time ``stamp``)."""
    from ..scene.bvh import read_bvh

    return read_bvh(path)


def _tip_joints(clip, wrist: int) -> list[int] | None:
    """Per finger of :data:`FINGERS`, the deepest joint of its chain below ``wrist``; None when one is missing."""
    below, queue = [], list(clip.children(wrist))
    while queue:                                                     # breadth first
        j = queue.pop(0)
        below.append(j)
        queue.extend(clip.children(j))
    tips = []
    for keys in _FINGER_KEYS:
        base = next((j for j in below if not clip.is_end_site[j] and any(k in clip.names[j].lower() for k in keys)),
                    None)
        if base is None:
            return None
        while clip.children(base):
            base = clip.children(base)[0]
        tips.append(base)
    return tips


def _source_joints(scene, side: str, joints) -> np.ndarray:
    """World positions of source joints over the scene's frames, (T, J, 3) metres: ``joints`` is a callable
    ``(clip, wrist_index) -> list of joint indices or None``; returns an empty (T, 0, 3) array when it gives None."""
    from ..scene.mocap import convert_transforms

    src = scene.source
    path, joint = src.wrist(side)
    clip = _read_clip(path, os.stat(path).st_mtime_ns)
    idx = joints(clip, clip.joint_index(joint))
    if idx is None:
        return np.zeros((scene.T, 0, 3))
    s = src.first_frame + np.arange(scene.T) * (src.fps / scene.fps)
    s = np.clip(s, 0.0, clip.num_frames - 1)
    lo = np.floor(s).astype(np.int64)
    hi = np.minimum(lo + 1, clip.num_frames - 1)
    need = np.unique(np.concatenate([lo, hi]))
    G = convert_transforms(clip.global_transforms(need)[:, idx], units_scale=src.units_scale, up_axis=src.up_axis,
                           handedness=src.handedness)[..., :3, 3].numpy()               # (N, J, 3)
    a, b = G[np.searchsorted(need, lo)], G[np.searchsorted(need, hi)]
    w = (s - lo)[:, None, None]
    return (1.0 - w) * a + w * b


def captured_fingertips(scene, side: str) -> np.ndarray | None:
    """The captured fingertips of hand ``side``, (T, 5, 3), world, metres, float64, in :data:`FINGERS` order
    (module docstring); None when the scene has no ``source`` or its BVH has no wrist for ``side`` or no five
    finger chains.

    Raises:
        InputValueError: the scene has no ``side`` hand.
        MissingFileError, FileFormatError: the source BVH cannot be read.
    """
    _track(scene, side)
    src = scene.source
    if src is None or side not in (w[0] for w in src.wrists):
        return None
    tips = _source_joints(scene, side, _tip_joints)
    return tips if tips.shape[1] == len(FINGERS) else None


def solution_fingertips(hand_model, q, root_pose) -> np.ndarray:
    """The hand model's fingertip pad points, (T, F, 3), world, metres, float64, in ``hand_model.finger_names``
    order (the built-in hand's is :data:`FINGERS`).

    Args:
        hand_model: :class:`~torchhand.hand.model.HandModel`
        q: joint angles, (T, D), radians (array or tensor)
        root_pose: wrist poses ``T_world_hand``, (T, 4, 4), world, metres (array or tensor)
    """
    model = hand_model.to("cpu", torch.float64)
    q, root = (x.detach().cpu().double() if isinstance(x, torch.Tensor) else torch.tensor(np.asarray(x, np.float64))
               for x in (q, root_pose))
    if q.dim() != 2 or q.shape[1] != model.num_joints:
        raise ShapeError(f"q: expected (T, {model.num_joints}) joint angles, got {tuple(q.shape)}")
    if tuple(root.shape) != (q.shape[0], 4, 4):
        raise ShapeError(f"root_pose: expected ({q.shape[0]}, 4, 4) wrist poses, got {tuple(root.shape)}")
    links = model.forward_kinematics(q, root)[:, model.distal_link]                      # (T, F, 4, 4)
    tips = links[..., :3, :3] @ model.fingertip[None, :, :, None] + links[..., :3, 3:]
    return tips[..., 0].numpy()


# ---------------------------------------------------------------------------------------------------------------
# comparison


@dataclass(frozen=True)
class FingerComparison:
    """Synthesized against captured fingers (module docstring), T frames, F = 5 fingers in :data:`FINGERS` order.

    Fields
        tip_distance: synthesized to captured fingertip, (T, F), metres (NaN where either is not finite)
        captured_contact: the captured fingertip touches the object, (T, F) bool
        synthesized_contact: the synthesized fingertip touches it (given, or by the same distance rule), (T, F) bool
        frames: the frames compared, (T,) bool (finite fingertips, and within the caller's selection)
    """

    tip_distance: np.ndarray
    captured_contact: np.ndarray
    synthesized_contact: np.ndarray
    frames: np.ndarray

    def summary(self) -> dict:
        """For ``stats.json``: ``frames`` (compared), ``tip_distance_mm`` (``median``, ``p90``, ``per_finger``
        medians), ``contact_agreement`` (fraction of compared frames whose sets of fingers in contact are equal),
        ``contact_agreement_per_finger``, and the fractions of finger-frames in contact, ``captured_contact`` and
        ``synthesized_contact``. Figures are None when no frame is compared."""
        f = self.frames
        n = int(f.sum())
        if n == 0:
            return {"frames": 0, "tip_distance_mm": {"median": None, "p90": None,
                                                      "per_finger": {k: None for k in FINGERS}},
                    "contact_agreement": None, "contact_agreement_per_finger": {k: None for k in FINGERS},
                    "captured_contact": None, "synthesized_contact": None}
        d = 1e3 * self.tip_distance[f]
        same = self.captured_contact[f] == self.synthesized_contact[f]                    # (n, F)
        return {
            "frames": n,
            "tip_distance_mm": {"median": round(float(np.nanmedian(d)), 2),
                                "p90": round(float(np.nanpercentile(d, 90)), 2),
                                "per_finger": {k: round(float(np.nanmedian(d[:, i])), 2)
                                               for i, k in enumerate(FINGERS)}},
            "contact_agreement": round(float(same.all(1).mean()), 4),
            "contact_agreement_per_finger": {k: round(float(same[:, i].mean()), 4) for i, k in enumerate(FINGERS)},
            "captured_contact": round(float(self.captured_contact[f].mean()), 4),
            "synthesized_contact": round(float(self.synthesized_contact[f].mean()), 4),
        }


def _mesh_contact(points: np.ndarray, scene, contact_distance: float) -> np.ndarray:
    """(T, F) bool: world points (T, F, 3) within ``contact_distance`` of the object's mesh or inside it
    (watertight meshes); non-finite points are not in contact. Only points within ``contact_distance`` of the
    mesh's bounding box are queried exactly (the others cannot be in contact)."""
    import trimesh

    T, F, _ = points.shape
    O = scene.object_pose.detach().cpu().double().numpy()
    local = np.einsum("tji,tpj->tpi", O[:, :3, :3], points - O[:, None, :3, 3]).reshape(-1, 3)
    mesh = scene.object.mesh
    lo, hi = mesh.bounds
    with np.errstate(invalid="ignore"):
        box = np.linalg.norm(np.maximum(np.maximum(lo - local, local - hi), 0.0), axis=1)
    near = np.nonzero(np.isfinite(box) & (box <= contact_distance))[0]
    out = np.zeros(T * F, dtype=bool)
    if len(near):
        _, d, _ = trimesh.proximity.closest_point(mesh, local[near])
        hit = d <= contact_distance
        if mesh.is_watertight and not hit.all():
            hit[~hit] = mesh.contains(local[near][~hit])
        out[near] = hit
    return out.reshape(T, F)


def compare_fingers(fingertips: np.ndarray, contact: np.ndarray | None, scene, side: str, *,
                    contact_distance: float = CONTACT_DISTANCE, frames: np.ndarray | None = None
                    ) -> FingerComparison:
    """Compare synthesized fingertips of hand ``side`` with the captured ones (module docstring).

    Args:
        fingertips: synthesized fingertips, (T, 5, 3), world, metres, :data:`FINGERS` order
            (:func:`solution_fingertips` of the built-in hand)
        contact: the synthesized per-finger contacts, (T, 5) bool; None: by distance to the mesh, as the captured
        scene: the scene (with ``source``) the fingertips belong to
        side: "right" or "left"
        contact_distance: metres, the contact rule's distance (default :data:`CONTACT_DISTANCE`)
        frames: optional (T,) bool, the frames to compare (e.g. the solved ones); default every frame

    Raises:
        InputValueError: no ``side`` hand, a scene without captured fingers, a bad ``contact_distance``.
        ShapeError: arrays of the wrong shape.
    """
    if not (isinstance(contact_distance, (int, float)) and np.isfinite(contact_distance) and contact_distance >= 0):
        raise InputValueError(f"contact_distance: expected a finite number >= 0 (metres), got {contact_distance!r}")
    captured = captured_fingertips(scene, side)
    if captured is None:
        raise InputValueError(f"scene: '{scene.name}' has no captured fingers for the {side} hand (no mocap source "
                              "or no five finger chains in its BVH)")
    T, F = scene.T, len(FINGERS)
    tips = np.asarray(fingertips, dtype=np.float64)
    if tips.shape != (T, F, 3):
        raise ShapeError(f"fingertips: expected ({T}, {F}, 3) (frames, fingers {', '.join(FINGERS)}, xyz), got "
                         f"{tips.shape}")
    if contact is not None and np.shape(contact) != (T, F):
        raise ShapeError(f"contact: expected ({T}, {F}) bool or None, got {np.shape(contact)}")
    if frames is not None and np.shape(frames) != (T,):
        raise ShapeError(f"frames: expected ({T},) bool or None, got {np.shape(frames)}")
    finite = np.isfinite(tips).all((1, 2)) & np.isfinite(captured).all((1, 2))
    compared = finite if frames is None else finite & np.asarray(frames, dtype=bool)
    dist = np.linalg.norm(tips - captured, axis=-1)
    cap_contact = _mesh_contact(captured, scene, contact_distance)
    syn_contact = (_mesh_contact(tips, scene, contact_distance) if contact is None
                   else np.asarray(contact, dtype=bool).copy())
    return FingerComparison(tip_distance=dist, captured_contact=cap_contact, synthesized_contact=syn_contact,
                            frames=compared)


def plot_comparison(cmp: FingerComparison, path, *, fps: float, title: str = "") -> Path:
    """A PNG at ``path`` (written atomically): above, each finger's tip distance (mm) over time (compared frames);
    below, a contact timeline per finger, captured (thin, upper) and synthesized (thick, lower) bars."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    T, F = cmp.tip_distance.shape
    t = np.arange(T) / float(fps)
    fig = Figure(figsize=(10, 6))
    ax, bx = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 2]})
    d = np.where(cmp.frames[:, None], 1e3 * cmp.tip_distance, np.nan)
    for i, name in enumerate(FINGERS[:F]):
        ax.plot(t, d[:, i], lw=1, color=f"C{i}", label=name)
    ax.set_ylabel("tip distance, synthesized to captured (mm)")
    ax.legend(loc="upper right", fontsize=8, ncol=F)
    ax.grid(alpha=0.3)
    for i, name in enumerate(FINGERS[:F]):
        for row, mask, h in ((i + 0.22, cmp.captured_contact[:, i], 0.18), (i - 0.2, cmp.synthesized_contact[:, i],
                                                                                 0.34)):
            m = mask & cmp.frames
            edges = np.diff(np.concatenate([[0], m.astype(np.int8), [0]]))
            runs = [(a / fps, (b - a) / fps) for a, b in zip(np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0])]
            bx.broken_barh(runs, (row - h / 2, h), color=f"C{i}", alpha=0.45 if h < 0.3 else 0.9)
    bx.set_yticks(range(F), [f"{n}\ncapt. / synth." for n in FINGERS[:F]], fontsize=7)
    bx.set_ylim(-0.7, F - 0.3)
    bx.set_xlabel("time (s)")
    bx.set_title("contact: captured (upper, light) and synthesized (lower, dark)", fontsize=9)
    if title:
        fig.suptitle(title)
    return save_png(fig, path)


def save_png(fig, path, dpi: int = 90) -> Path:
    """A matplotlib figure laid out and written as a PNG at ``path``, atomically. Returns the path."""
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    path = Path(path)
    atomic_bytes(path, buf.getvalue())
    return path


def reference_report(scene, hands, motions, out_dir, *, frames=None, plot: bool = True) -> dict:
    """The captured-finger comparison of written motions, for ``stats.json`` (``reference``), with a plot per motion
    and hand (``fingers_<side>_sol_XXX.png`` in ``out_dir``).

    Args:
        scene: the scene the motions belong to (with ``source``); hands: the hand models in the scene's hand order;
        motions: per motion, (q (T, H, D) radians, root poses (H, T, 4, 4)); frames: None or per motion a (T,) bool
        of the frames to compare (e.g. those a fill solved); plot: write the PNGs.
    Returns:
        {side: [summary per motion (:meth:`FingerComparison.summary`)]}, only for hands whose capture has fingers
        and whose model has the five fingers of :data:`FINGERS` (robot hands are not compared); {} otherwise.
    """
    out = {}
    for h, track in enumerate(scene.hands):
        model = hands[h]
        if tuple(getattr(model, "finger_names", ())) != FINGERS or captured_fingertips(scene, track.side) is None:
            continue
        rows = []
        for v, (q, roots) in enumerate(motions):
            tips = solution_fingertips(model, q[:, h], roots[h])
            sel = None if frames is None else frames[v]
            cmp = compare_fingers(tips, None, scene, track.side, frames=sel)
            rows.append(cmp.summary())
            if plot:
                plot_comparison(cmp, Path(out_dir) / f"fingers_{track.side}_sol_{v:03d}.png", fps=scene.fps,
                                title=f"{scene.name}, {track.side} hand, sol_{v:03d}: synthesized vs captured")
        out[track.side] = rows
    return out

