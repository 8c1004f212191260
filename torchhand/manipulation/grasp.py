"""The grasp a manipulation starts from (Liu 2009, Sec. 3): a hand, its joint angles and its wrist pose on the object.

A grasp is stored as ``grasp.npz`` (NumPy, ``allow_pickle=False``; docs/manipulation.md):

======================  ========  =========  ===================================================================
key                     shape     dtype      meaning
======================  ========  =========  ===================================================================
``hand``                ()        str        ``"default"`` (the built-in hand) or the path of an MJCF hand
``side``                ()        str        ``"right"`` or ``"left"``
``length``              ()        float64    hand length, metres (scales the built-in hand; optional, 0.19)
``joint_names``         (D,)      str        the hand's joints, in its order
``q``                   (D,)      float64    joint angles, radians (metres for slide joints)
``wrist_in_object``     (4, 4)    float64    the hand (wrist) frame in the object frame, ``T_object_hand``, metres
``frame``               ()        int64      the frame of the object motion the grasp belongs to
``contact_links``       (C,)      str        optional: links in contact
``contact_hand``        (C, 3)    float64    optional: contact points in their link's frame, metres
``contact_object``      (C, 3)    float64    optional: the matching points on the object surface, object frame
``snap_distance``       (C,)      float64    optional: signed distance of each contact before snapping, metres
======================  ========  =========  ===================================================================

Conventions (:mod:`torchhand.conventions`): metres, radians, column-vector 4x4 transforms; the hand frame is the wrist
frame of docs/scene_format.md. The world wrist pose at frame t is ``object_pose[t] @ wrist_in_object``.

:func:`load_grasp` validates everything (missing keys, shapes, dtypes, a rigid ``wrist_in_object``, and, with the
hand, joint names and joint limits); :func:`save_grasp` writes atomically.
"""

from __future__ import annotations

import dataclasses
import io
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from .._atomic import atomic_bytes
from .._npz import read_npz
from ..scene.builtin.liu import LIU_SCENES, SHADOW_HAND, grasp_paths, shadow_hand_path
from ..errors import FileFormatError, InputValueError, ShapeError, UnknownNameError

__all__ = ["Grasp", "load_grasp", "save_grasp", "grasp_hand", "check_grasp_hand", "load_packaged_grasp", "LIMIT_TOL"]

LIMIT_TOL = 1e-6
"""Joint angles may exceed the hand's limits by this much (radians) before a grasp is refused."""

_REQUIRED = ("hand", "side", "joint_names", "q", "wrist_in_object", "frame")
_CONTACT_KEYS = ("contact_links", "contact_hand", "contact_object")


@dataclass(frozen=True, eq=False)
class Grasp:
    """A grasping pose on an object (NumPy, float64).

    hand: "default" or the path of an MJCF hand file
    side: "right" | "left"
    joint_names: (D,) str, the hand's joint order
    q: joint angles, (D,), radians
    wrist_in_object: ``T_object_hand``, (4, 4), metres
    frame: frame index of the object motion the grasp was taken at
    length: hand length, metres (the built-in hand's scale)
    contact_links: (C,) str link names in contact, or () when not snapped yet
    contact_hand: contact points in their link's frame, (C, 3), metres
    contact_object: the matching object-surface points, (C, 3), object frame, metres
    snap_distance: signed distance of each contact link to the object before snapping, (C,), metres (negative =
        penetrating); zeros when unknown
    """

    hand: str
    side: str
    joint_names: tuple
    q: np.ndarray
    wrist_in_object: np.ndarray
    frame: int = 0
    length: float = 0.19
    contact_links: tuple = ()
    contact_hand: np.ndarray | None = None
    contact_object: np.ndarray | None = None
    snap_distance: np.ndarray | None = None

    def __post_init__(self):
        _validate(self, "Grasp")

    @property
    def num_contacts(self) -> int:
        return len(self.contact_links)

    @property
    def has_contacts(self) -> bool:
        return len(self.contact_links) > 0


def _fail(where: str, key: str, expected: str, got) -> ShapeError:
    return ShapeError(f"{where}: {key}: expected {expected}, got {got}")


def _validate(g: Grasp, where: str) -> None:
    if not isinstance(g.hand, str) or not g.hand:
        raise InputValueError(f"{where}: hand: expected 'default' or an MJCF path, got {g.hand!r}")
    if g.side not in ("right", "left"):
        raise InputValueError(f"{where}: side: expected 'right' or 'left', got {g.side!r}")
    names = tuple(str(n) for n in g.joint_names)
    object.__setattr__(g, "joint_names", names)
    q = np.asarray(g.q, dtype=np.float64)
    if q.shape != (len(names),):
        raise _fail(where, "q", f"shape ({len(names)},) (one value per joint name)", tuple(q.shape))
    if not np.isfinite(q).all():
        raise InputValueError(f"{where}: q: contains NaN or inf")
    object.__setattr__(g, "q", q)
    T = np.asarray(g.wrist_in_object, dtype=np.float64)
    if T.shape != (4, 4):
        raise _fail(where, "wrist_in_object", "shape (4, 4)", tuple(T.shape))
    R = T[:3, :3]
    if (not np.isfinite(T).all() or np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or abs(np.linalg.det(R) - 1) > 1e-6
            or np.abs(T[3] - [0, 0, 0, 1]).max() > 1e-9):
        raise InputValueError(f"{where}: wrist_in_object: expected a rigid transform (orthonormal rotation, "
                              f"last row 0 0 0 1), got {np.array2string(T, precision=4)}")
    object.__setattr__(g, "wrist_in_object", T)
    if isinstance(g.frame, bool) or not isinstance(g.frame, (int, np.integer)) or g.frame < 0:
        raise InputValueError(f"{where}: frame: expected a non-negative integer, got {g.frame!r}")
    object.__setattr__(g, "frame", int(g.frame))
    if not (isinstance(g.length, (int, float, np.floating)) and np.isfinite(g.length) and g.length > 0):
        raise InputValueError(f"{where}: length: expected a positive number of metres, got {g.length!r}")
    object.__setattr__(g, "length", float(g.length))
    links = tuple(str(n) for n in g.contact_links)
    C = len(links)
    object.__setattr__(g, "contact_links", links)
    for key in ("contact_hand", "contact_object"):
        v = getattr(g, key)
        v = np.zeros((C, 3)) if v is None and C == 0 else np.asarray(v, dtype=np.float64) if v is not None else v
        if v is None or v.shape != (C, 3):
            raise _fail(where, key, f"shape ({C}, 3) (one row per contact link)",
                        None if v is None else tuple(v.shape))
        if not np.isfinite(v).all():
            raise InputValueError(f"{where}: {key}: contains NaN or inf")
        object.__setattr__(g, key, v)
    sd = np.zeros(C) if g.snap_distance is None else np.asarray(g.snap_distance, dtype=np.float64)
    if sd.shape != (C,):
        raise _fail(where, "snap_distance", f"shape ({C},)", tuple(sd.shape))
    object.__setattr__(g, "snap_distance", sd)


# ---------------------------------------------------------------------------------------------------------- I/O
def save_grasp(grasp: Grasp, path, *, overwrite: bool = False) -> Path:
    """Write ``grasp`` to ``path`` (``.npz``) atomically; refuses an existing file unless ``overwrite``."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise InputValueError(f"{path} exists; pass --overwrite (overwrite=True) to replace it")
    data = {
        "format_version": np.array(1, dtype=np.int64),
        "hand": np.array(grasp.hand), "side": np.array(grasp.side), "length": np.array(grasp.length),
        "joint_names": np.array(grasp.joint_names, dtype=str), "q": grasp.q,
        "wrist_in_object": grasp.wrist_in_object, "frame": np.array(grasp.frame, dtype=np.int64),
    }
    if grasp.has_contacts:
        data.update(contact_links=np.array(grasp.contact_links, dtype=str), contact_hand=grasp.contact_hand,
                    contact_object=grasp.contact_object, snap_distance=grasp.snap_distance)
    buf = io.BytesIO()
    np.savez(buf, **data)
    atomic_bytes(path, buf.getvalue())
    return path


def load_grasp(path, hand=None) -> Grasp:
    """Read and validate a ``grasp.npz``; with ``hand`` (a :class:`~torchhand.hand.HandModel`) also check the joint
    names and limits (:func:`check_grasp_hand`).

    Raises:
        MissingFileError: no such file; FileFormatError: not an npz, a missing key or a wrong dtype;
        ShapeError: a wrong shape; InputValueError: a bad value; UnknownNameError / InputValueError from
        :func:`check_grasp_hand`.
    """
    path = Path(path)
    data = read_npz(path, _REQUIRED, "a grasp.npz (docs/manipulation.md)")
    has = [k in data for k in _CONTACT_KEYS]
    if any(has) and not all(has):
        raise FileFormatError(f"{path}: contacts need all of {', '.join(_CONTACT_KEYS)}; missing "
                              f"{', '.join(k for k, h in zip(_CONTACT_KEYS, has) if not h)}")

    def text(key):
        v = data[key]
        if v.dtype.kind != "U" or v.shape != ():
            raise FileFormatError(f"{path}: {key}: expected a string, got dtype {v.dtype} shape {v.shape}")
        return str(v)

    def names(key):
        v = data[key]
        if v.dtype.kind != "U" or v.ndim != 1:
            raise FileFormatError(f"{path}: {key}: expected a 1-d array of strings, got dtype {v.dtype} "
                                  f"shape {v.shape}")
        return tuple(str(n) for n in v)

    def floats(key):
        v = data[key]
        if v.dtype.kind not in "fi":
            raise FileFormatError(f"{path}: {key}: expected numbers, got dtype {v.dtype}")
        return v.astype(np.float64)

    frame = data["frame"]
    if frame.shape != () or frame.dtype.kind not in "iu":
        raise FileFormatError(f"{path}: frame: expected an integer, got dtype {frame.dtype} shape {frame.shape}")
    kw = {}
    if all(has):
        kw = dict(contact_links=names("contact_links"), contact_hand=floats("contact_hand"),
                  contact_object=floats("contact_object"),
                  snap_distance=floats("snap_distance") if "snap_distance" in data else None)
    length = floats("length") if "length" in data else np.array(0.19)
    if length.shape != ():
        raise _fail(str(path), "length", "a scalar", tuple(length.shape))
    grasp = _construct(str(path), hand=text("hand"), side=text("side"), joint_names=names("joint_names"),
                       q=floats("q"), wrist_in_object=floats("wrist_in_object"), frame=int(frame),
                       length=float(length), **kw)
    if hand is not None:
        check_grasp_hand(grasp, hand, where=str(path))
    return grasp


def _construct(where: str, **kw) -> Grasp:
    try:
        return Grasp(**kw)
    except (ShapeError, InputValueError) as err:
        raise type(err)(str(err).replace("Grasp:", f"{where}:", 1)) from None


# ---------------------------------------------------------------------------------------------------- the hand
def grasp_hand(grasp: Grasp):
    """The hand model of ``grasp`` (float64, CPU): the built-in hand at ``grasp.length``, or the MJCF hand mounted on
    its hand frame exactly as a scene's hand track mounts it (:func:`torchhand.hand.mount.track_hand`)."""
    from ..hand.mount import track_hand

    return track_hand(SimpleNamespace(model=grasp.hand, side=grasp.side, length=grasp.length))


def check_grasp_hand(grasp: Grasp, hand, *, where: str = "grasp") -> None:
    """Check that ``grasp`` fits ``hand``: the same joint names in the same order, ``q`` within the joint limits
    (up to :data:`LIMIT_TOL`), and contact links the hand has.

    Raises:
        UnknownNameError: joint or contact-link names differ (the differences are named);
        InputValueError: joints outside their limits (named, with value and range).
    """
    names = tuple(hand.joint_names)
    if grasp.joint_names != names:
        extra = [n for n in grasp.joint_names if n not in names]
        lacking = [n for n in names if n not in grasp.joint_names]
        detail = (f"not in the hand: {', '.join(extra) or '-'}; missing: {', '.join(lacking) or '-'}"
                  if extra or lacking else "same names in a different order")
        raise UnknownNameError(f"{where}: joint_names do not match the hand {hand.name!r} ({detail})")
    lim = hand.joint_limits.detach().cpu().double().numpy()
    q = grasp.q
    bad = np.nonzero((q < lim[:, 0] - LIMIT_TOL) | (q > lim[:, 1] + LIMIT_TOL))[0]
    if bad.size:
        rows = ", ".join(f"{names[d]} = {q[d]:.6f} not in [{lim[d, 0]:.6f}, {lim[d, 1]:.6f}]" for d in bad)
        raise InputValueError(f"{where}: q outside the joint limits by more than {LIMIT_TOL:g} rad: {rows}")
    unknown = [n for n in grasp.contact_links if n not in hand.link_names]
    if unknown:
        raise UnknownNameError(f"{where}: contact_links {', '.join(unknown)} are not links of the hand "
                               f"{hand.name!r}")


def load_packaged_grasp(scene_name: str, hand=None):
    """The packaged grasp of a built-in scene, ready to use: :func:`~torchhand.manipulation.load_grasp` of
    :func:`torchhand.scene.builtin.liu.grasp_path`, with a hand named relative to the shared reference data (``liu-shadow-lift``'s
    :data:`SHADOW_HAND`) resolved to its file. With ``hand`` (one-hand scenes), also checked against it. A
    two-hand scene gives a tuple of grasps in its hand order (:func:`torchhand.scene.builtin.liu.grasp_paths`).

    Raises:
        UnknownNameError: the scene has no packaged grasp; MissingFileError: its hand is not in the shared data;
        the errors of ``load_grasp``.
    """
    paths = grasp_paths(scene_name)
    if not paths:
        raise UnknownNameError(f"scene: no packaged grasp for {scene_name!r}; packaged: {', '.join(LIU_SCENES)}")
    grasps = []
    for path in paths:
        grasp = load_grasp(path)
        if grasp.hand == SHADOW_HAND:
            grasp = dataclasses.replace(grasp, hand=str(shadow_hand_path()))
        if hand is not None and len(paths) == 1:
            check_grasp_hand(grasp, hand, where=str(path))
        grasps.append(grasp)
    return grasps[0] if len(grasps) == 1 else tuple(grasps)
