"""Where a hand model sits on a wrist track: the hand frame of a model, and a model re-rooted on it.

A scene's wrist track is the pose of the **hand frame** (docs/scene_format.md): origin at the wrist, ``+x`` along
the fingers, ``+z`` out of the back of the hand (the palm faces ``-z``), ``+y = z × x`` (toward the thumb for a
right hand, away from it for a left hand). The built-in hand is modelled in that frame. A robot hand from MJCF is
not: its root body's axes are whatever its authors chose (the Shadow hand's forearm points along ``+z``). So a
robot hand is *mounted*: its root link's offset is pre-multiplied by ``F⁻¹``, with ``F`` the hand frame in the
model's root coordinates, and then ``forward_kinematics(q, wrist_pose)`` places it on the track like the built-in
hand.

``F`` from the model at ``q = 0`` clamped to the limits, straight fingers (:func:`hand_frame`), unless a sidecar file gives it (:func:`load_sidecar`):

* thumb: the finger whose name contains ``th`` or ``thumb``; the others are the long fingers;
* ``+x``: from the mean base (first link origin) of the long fingers to the mean of their fingertips;
* ``+y``: across the knuckles, from the outermost long finger's base to the one on the thumb's side, made
  orthogonal to ``x``; negated for a left hand;
* origin: at the wrist end of the link the fingers branch from (the palm: Shadow's ``rh_palm``, Allegro's
  ``palm``), with the palm's volar surface :data:`PALM_DEPTH` (1.5 cm) below it, as in the built-in hand: from that
  link's origin, moved along ``x`` to the rearmost point of its geometry and along ``z`` so that its deepest point
  lies ``PALM_DEPTH`` below (surface samples at ``q = 0``).

Joints between the root and the link the fingers branch from (the Shadow hand's wrist ``WRJ1``, ``WRJ2``) are
locked at ``q_rest`` (:func:`lock_palm_joints`): the wrist track gives the palm's pose.

Rest pose: the MJCF's own ``q = 0`` (clamped to the limits), usually the robot's home pose with open fingers.
The search starts its inverse kinematics there and lets free fingers return to it. :func:`relaxed_rest` derives a
human-like alternative, chosen with ``[rest] pose = "relaxed"`` in the sidecar: each fingertip at the built-in
hand's rest fingertip of the matching finger (thumb to thumb, long fingers in order across the knuckles), scaled
by the ratio of the hands' lengths, with the nail facing the same way; joints fitted within their limits. On
``box-turn`` it lets the Shadow thumb, which lies in the palm's plane at ``q = 0`` and reaches no side of the box
from there (IK ends at its joint limits 6-20 mm short), start opposed; on ``cube-turn`` the Allegro hand's curled
fingers then start inside the cube and most found paths cannot be smoothed, so it is not the default.

Sidecar (``<model>.torchhand.toml`` beside the MJCF file, all keys optional)::

    [mount]
    origin = [0.0, 0.0, 0.034]            # hand-frame origin in the root link's parent frame, metres
    x_axis = [0.0, 0.0, 1.0]              # + x (along the fingers), root coordinates
    y_axis = [1.0, 0.0, 0.0]              # + y (made orthogonal to x), root coordinates
    shift = [0.0, -0.014, 0.0]            # then move the hand on the track by this, hand-frame metres

    [rest]
    pose = "relaxed"                      # "zero" (default: q = 0 clamped) or "relaxed" (relaxed_rest)
    rh_THJ4 = 1.0                         # rest angle of a named joint, radians (after the pose)

Conventions: metres, column-vector 4x4 transforms (:mod:`torchhand.conventions`).
"""

from __future__ import annotations

import dataclasses
import functools
import tomllib
from pathlib import Path

import numpy as np
import torch

from ..errors import FileFormatError, InputValueError, MissingFileError

PALM_DEPTH = 0.015
"""Depth of the palm's volar surface below the hand frame's origin, metres (the built-in hand's, about 1.5 cm; the
built-in scenes place the palm surface a few millimetres off the object with it)."""

__all__ = ["PALM_DEPTH", "hand_frame", "mounted", "load_sidecar", "sidecar_path", "sidecar_frame", "thumb_index",
           "track_hand", "relaxed_rest", "with_rest", "mount_transform", "moved_on_track"]


def thumb_index(model) -> int | None:
    """Index of the thumb among ``model.finger_names`` (name containing "th"/"thumb"), or None."""
    for f, name in enumerate(model.finger_names):
        n = name.lower()
        if "thumb" in n or n.startswith("th"):
            return f
    return None


def palm_link(hand) -> int:
    """The link the fingers branch from (the palm): the deepest common ancestor of every finger's first link."""
    parents = hand.chain.link_parent.tolist()
    chains = []
    for f in range(hand.num_fingers):
        a, path = int(hand.finger_links[f, 0]), []
        while a >= 0:
            path.append(a)
            a = parents[a]
        chains.append(path[::-1])
    common = 0
    for k in range(min(len(c) for c in chains)):
        if len({c[k] for c in chains}) != 1:
            break
        common = chains[0][k]
    return common


def hand_frame(model) -> np.ndarray:
    """``F``: the hand frame in the model's root coordinates (the root link's parent frame) at ``q = 0``, (4, 4).

    Raises:
        InputValueError: fewer than two long fingers, or no thumb, so the axes are not defined.
    """
    m = model.to(device="cpu", dtype=torch.float64)
    q0 = m.clamp_to_limits(torch.zeros(1, m.num_joints, dtype=torch.float64))      # straight fingers
    T = m.forward_kinematics(q0).numpy()[0]                                         # (L, 4, 4)
    th = thumb_index(m)
    long_f = [f for f in range(m.num_fingers) if f != th]
    if th is None or len(long_f) < 2:
        raise InputValueError(f"hand {m.name!r}: cannot find its hand frame (fingers {', '.join(m.finger_names)}; "
                              "a thumb and two other fingers are needed); give [mount] in a sidecar file")
    base = np.stack([T[int(m.finger_links[f, 0]), :3, 3] for f in range(m.num_fingers)])
    distal = m.distal_link.numpy()
    tips = np.einsum("fab,fb->fa", T[distal, :3, :3], m.fingertip.numpy()) + T[distal, :3, 3]
    b = base[long_f].mean(0)
    x = _unit(tips[long_f].mean(0) - b)
    y = base[long_f[0]] - base[long_f[-1]]                 # across the knuckles, toward the thumb's side
    if y @ (base[th] - b) < 0:
        y = -y
    y = _unit(y - (y @ x) * x)
    if m.side == "left":
        y = -y
    z = np.cross(x, y)
    common = palm_link(m)  # the branching link
    # origin: on the palm's wrist end, its volar surface PALM_DEPTH below: the palm link's surface samples give
    # the rearmost point along x and the deepest along -z, measured from the palm link's origin
    o = T[common, :3, 3]
    sel = m.sample_link == common
    if bool(sel.any()):
        Ts = T[m.sample_link[sel].numpy()]
        P = np.einsum("sab,sb->sa", Ts[:, :3, :3], m.sample_points[sel].numpy()) + Ts[:, :3, 3]
        origin = o + float(((P - o) @ x).min()) * x + (float(((P - o) @ z).min()) + PALM_DEPTH) * z
    else:
        origin = o.copy()
    F = np.eye(4)
    F[:3, 0], F[:3, 1], F[:3, 2], F[:3, 3] = x, y, z, origin
    return F


def sidecar_path(mjcf_path) -> Path:
    """``<stem>.torchhand.toml`` beside the MJCF file."""
    p = Path(mjcf_path)
    return p.with_name(p.stem + ".torchhand.toml")


def load_sidecar(mjcf_path) -> dict:
    """The sidecar of an MJCF file as a dict ({} when there is none); FileFormatError for unknown keys."""
    p = sidecar_path(mjcf_path)
    if not p.is_file():
        return {}
    try:
        doc = tomllib.loads(p.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, OSError, UnicodeDecodeError) as err:
        raise FileFormatError(f"{p}: cannot read: {err}") from None
    allowed = {"mount": {"origin", "x_axis", "y_axis", "shift"}, "rest": None}
    for key, table in doc.items():
        if key not in allowed or not isinstance(table, dict) or (allowed[key] and set(table) - allowed[key]):
            raise FileFormatError(f"{p}: unknown table or key {key!r}; allowed: [mount] origin, x_axis, y_axis, shift; "
                                  '[rest] pose = "zero"|"relaxed", JOINT = radians')
    for name, value in doc.get("rest", {}).items():
        if name == "pose":
            if value not in ("zero", "relaxed"):
                raise FileFormatError(f'{p}: [rest] pose: expected "zero" or "relaxed", got {value!r}')
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
            raise FileFormatError(f"{p}: [rest] {name}: expected a number of radians, got {value!r}")
    return doc


def sidecar_frame(doc: dict, default: np.ndarray) -> np.ndarray:
    """``F`` with the sidecar's ``[mount]`` entries replacing those of ``default`` (4, 4); ``shift`` (hand-frame
    metres) then moves the hand by that much on the track (the frame's origin by minus that much)."""
    mount = doc.get("mount", {})
    F = default.copy()
    x = _vec(mount["x_axis"], "mount.x_axis") if "x_axis" in mount else F[:3, 0]
    y = _vec(mount["y_axis"], "mount.y_axis") if "y_axis" in mount else F[:3, 1]
    x = _unit(x)
    y = _unit(y - (y @ x) * x)
    F[:3, 0], F[:3, 1], F[:3, 2] = x, y, np.cross(x, y)
    if "origin" in mount:
        F[:3, 3] = _vec(mount["origin"], "mount.origin")
    if "shift" in mount:
        F[:3, 3] = F[:3, 3] - F[:3, :3] @ _vec(mount["shift"], "mount.shift")
    return F


def mounted(model, F: np.ndarray):
    """``model`` re-rooted on its hand frame ``F`` (4, 4): the root link's offset becomes ``F⁻¹ @ offset``."""
    return _premultiplied(model, np.linalg.inv(np.asarray(F, dtype=np.float64)))


def _premultiplied(model, A: np.ndarray):
    """``model`` with its root link's offset pre-multiplied by ``A`` (4, 4)."""
    ch = model.chain
    off = ch.link_offset.clone()
    off[0] = torch.as_tensor(A, dtype=off.dtype, device=off.device) @ off[0]
    return dataclasses.replace(model, chain=ch._replace(link_offset=off))


def track_hand(track):
    """The hand model of a scene's hand track (:class:`torchhand.scene.HandTrack`), float64 on the CPU.

    ``track.model == "default"``: ``default_hand(track.side, track.length)``. Otherwise the hand file (MJCF or
    URDF) at ``track.model``, loaded as a ``track.side`` hand and mounted on its hand frame (module docstring; the
    sidecar file wins where it says something). Then moved by ``track.mount`` when it has one
    (:func:`moved_on_track`). Loaded files are cached per (path, side, modification time).

    Raises:
        MissingFileError: the MJCF file does not exist; InputValueError: a hand of the other side, or no hand frame.
    """
    mount = getattr(track, "mount", None)
    if track.model == "default":
        from .default import default_hand

        return moved_on_track(default_hand(track.side, track.length), mount)
    rest = getattr(track, "rest", None)
    path = Path(track.model)
    if not path.is_file():
        raise MissingFileError(f"hands: hand file '{path}' does not exist")
    side_car = sidecar_path(path)
    stamp = (path.stat().st_mtime_ns, side_car.stat().st_mtime_ns if side_car.is_file() else 0)
    key = (str(path.resolve()), track.side, stamp)
    model = _with_rest_cached(*key, rest) if rest is not None else _mounted_mjcf(*key)
    return moved_on_track(model, mount)


@functools.lru_cache(maxsize=16)
def _with_rest_cached(path: str, side: str, stamp, rest: str):
    """The mounted model with the rest pose ``rest`` ("zero" or "relaxed") instead of its own (a track's ``rest``;
    the named joints of a sidecar's ``[rest]`` still apply)."""
    model = _mounted_mjcf(path, side, stamp)
    named = {k: v for k, v in load_sidecar(path).get("rest", {}).items() if k != "pose"}
    base = dataclasses.replace(model, q_rest=model.clamp_to_limits(torch.zeros(1, model.num_joints,
                                                                                dtype=model.dtype))[0])
    return with_rest(base, {"pose": rest, **named}, path)


def mount_transform(mount) -> np.ndarray:
    """``M`` (4, 4) of a track's ``mount`` (shift metres, rotation vector degrees; hand frame): the model's hand
    frame sits at ``wrist_pose @ M``. The identity for None."""
    M = np.eye(4)
    if mount is None:
        return M
    from scipy.spatial.transform import Rotation

    M[:3, :3] = Rotation.from_rotvec(np.radians(np.asarray(mount[3:], dtype=np.float64))).as_matrix()
    M[:3, 3] = np.asarray(mount[:3], dtype=np.float64)
    return M


def moved_on_track(model, mount):
    """``model`` (mounted on its hand frame) moved by a track's ``mount`` (:func:`mount_transform`): the root
    link's offset pre-multiplied by ``M``. ``model`` itself for None."""
    if mount is None or not any(mount):
        return model
    return _premultiplied(model, mount_transform(mount))


@functools.lru_cache(maxsize=16)
def _mounted_mjcf(path: str, side: str, stamp) -> "object":
    from .mjcf import load_mjcf

    model = load_mjcf(path)
    if model.side not in (side, "none"):
        raise InputValueError(f"hands: {path} is a {model.side} hand (its thumb's side), the scene's track is the "
                              f"{side} hand")
    model = dataclasses.replace(model, side=side)
    doc = load_sidecar(path)
    mount = doc.get("mount", {})
    default = np.eye(4) if {"origin", "x_axis", "y_axis"} <= set(mount) else hand_frame(model)
    hand = lock_palm_joints(mounted(model, sidecar_frame(doc, default)))
    return with_rest(hand, doc.get("rest", {}), path)


def with_rest(model, rest: dict, where: str = "sidecar"):
    """``model`` with the rest pose a sidecar's ``[rest]`` table ``rest`` gives: ``pose`` "zero" (``model.q_rest``,
    the default) or "relaxed" (:func:`relaxed_rest`), then the angles of the joints it names ({joint name: radians})
    replacing those joints' (clamped to their limits). Raises InputValueError for an unknown joint name."""
    named = {k: v for k, v in rest.items() if k != "pose"}
    if not named and rest.get("pose", "zero") == "zero":
        return model
    q = relaxed_rest(model) if rest.get("pose") == "relaxed" else model.q_rest.clone()
    names = list(model.joint_names)
    for name, value in named.items():
        if name not in names:
            raise InputValueError(f"{where}: [rest] names joint {name!r}, which the hand does not have")
        q[names.index(name)] = float(value)
    lim = model.joint_limits
    return dataclasses.replace(model, q_rest=torch.minimum(torch.maximum(q.to(lim.dtype), lim[:, 0]), lim[:, 1]))


def relaxed_rest(model, *, starts: int = 64, iters: int = 200) -> torch.Tensor:
    """A relaxed rest pose of a mounted hand, (D,) radians (module docstring, "Rest pose").

    Per finger f: minimise ``|tip_f(q) - s tip*_g|^2 / (1 cm)^2 + (1 - nail_f(q) . nail*_g)`` over its joints within
    the limits, where g is the built-in hand's matching finger, ``tip*``/``nail*`` its rest fingertip and nail
    direction in the hand frame and ``s`` the ratio of the hands' lengths (farthest long fingertip at ``q = 0``).
    Adam on a sigmoid parametrisation of each joint's range from ``starts`` starts (a fixed generator: the same
    model always gives the same pose), best start per finger. Joints of no finger keep ``model.q_rest``.
    """
    from .default import default_hand

    m = model.to(device="cpu", dtype=torch.float64)
    ref = default_hand(m.side if m.side in ("left", "right") else "right")
    zero = lambda h: h.clamp_to_limits(torch.zeros(1, h.num_joints, dtype=torch.float64))
    tips0, _ = _tips_nails(m, zero(m))
    rtips0, _ = _tips_nails(ref, zero(ref))
    rtips, rnails = _tips_nails(ref, ref.q_rest[None])
    th, rth = thumb_index(m), thumb_index(ref)
    longs = sorted((f for f in range(m.num_fingers) if f != th), key=lambda f: -float(tips0[0, f, 1]))
    rlongs = sorted((f for f in range(ref.num_fingers) if f != rth), key=lambda f: -float(rtips0[0, f, 1]))
    if m.side == "left":                                    # +y points away from the thumb on a left hand
        longs, rlongs = longs[::-1], rlongs[::-1]
    match = {f: rlongs[round(i * (len(rlongs) - 1) / max(len(longs) - 1, 1))] for i, f in enumerate(longs)}
    if th is not None:
        match[th] = rth
    reach = lambda t, fs: float(t[0, fs].norm(dim=-1).max())
    s = reach(tips0, longs) / reach(rtips0, rlongs) if longs else 1.0
    order = sorted(match)
    tgt = torch.stack([rtips[0, match[f]] * s for f in order])              # (F, 3)
    ntg = torch.stack([rnails[0, match[f]] for f in order])
    lo, hi = m.joint_limits[:, 0], m.joint_limits[:, 1]
    span = (hi - lo).clamp_min(1e-9)
    gen = torch.Generator().manual_seed(0)
    u0 = ((zero(m)[0] - lo) / span).clamp(1e-3, 1 - 1e-3)
    z = (torch.logit(u0)[None] + 4.0 * (torch.rand(starts, m.num_joints, generator=gen, dtype=torch.float64) - 0.5))
    z.requires_grad_(True)
    opt = torch.optim.Adam([z], lr=0.05)
    idx = torch.tensor(order)
    for _ in range(iters):
        tp, nl = _tips_nails(m, lo + span * torch.sigmoid(z))
        loss = ((tp[:, idx] - tgt) ** 2).sum(-1) / 1e-4 + (1 - (nl[:, idx] * ntg).sum(-1))
        opt.zero_grad()
        loss.sum().backward()
        opt.step()
    with torch.no_grad():
        q = lo + span * torch.sigmoid(z)
        tp, nl = _tips_nails(m, q)
        cost = ((tp[:, idx] - tgt) ** 2).sum(-1) / 1e-4 + (1 - (nl[:, idx] * ntg).sum(-1))   # (starts, F)
        best = cost.argmin(0)
        out = m.q_rest.clone()
        jf = m.link_finger[m.chain.joint_link]
        free = hi > lo
        for i, f in enumerate(order):
            js = (jf == f) & free
            out[js] = q[best[i], js]
    return out.to(model.joint_limits.dtype)


def _tips_nails(m, q: torch.Tensor):
    """Fingertip pads' centres and nail directions in the hand frame, (B, F, 3) each, for poses q (B, D)."""
    T = m.forward_kinematics(q)
    dl = m.distal_link
    R = T[:, dl, :3, :3]
    return (R @ m.fingertip[None, :, :, None]).squeeze(-1) + T[:, dl, :3, 3], (R @ m.nail_normal[None, :, :, None]).squeeze(-1)


def lock_palm_joints(model):
    """``model`` with the joints between the root and the link the fingers branch from (the Shadow hand's wrist
    ``WRJ1``/``WRJ2``) locked at ``q_rest`` (their limits collapsed to it): a wrist track gives the palm's pose, so
    the palm must not move against it. Joints on a link above one finger only (the Shadow thumb's ``THJ5``, the
    little finger's metacarpal ``LFJ5``) stay free."""
    shared = _shared_links(model)
    palm = torch.tensor([int(l) in shared for l in model.chain.joint_link.tolist()], dtype=torch.bool,
                        device=model.joint_limits.device)
    if not bool(palm.any()):
        return model
    lim = model.joint_limits.clone()
    lim[palm, 0] = model.q_rest[palm]
    lim[palm, 1] = model.q_rest[palm]
    return dataclasses.replace(model, joint_limits=lim)


def _shared_links(model) -> set[int]:
    """Links that are ancestors of (or equal to) every finger's first link: root .. branching link."""
    parents = model.chain.link_parent.tolist()
    shared = None
    for f in range(model.num_fingers):
        a, path = int(model.finger_links[f, 0]), set()
        a = parents[a]
        while a >= 0:
            path.add(a)
            a = parents[a]
        shared = path if shared is None else shared & path
    return shared or set()


def _vec(v, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64) if isinstance(v, list) else None
    if a is None or a.shape != (3,) or not np.isfinite(a).all():
        raise InputValueError(f"{name}: expected 3 numbers, got {v!r}")
    return a


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    if n < 1e-9:
        raise InputValueError("hand frame: degenerate direction (fingers and thumb coincide)")
    return v / n
