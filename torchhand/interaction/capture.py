"""The interaction-capture file ``capture.npz``: motion and contact forces of one capture session.

Format (``format_version`` 1; one ``.npz``, every array NumPy; T frames, D finger joints, S force sensors)

    ========================  ===========  =============================================================
    key                       shape        meaning, units
    ========================  ===========  =============================================================
    ``format_version``        ()           int, 1
    ``q``                     (T, D)       joint angles in ``joint_names`` order, radians (metres for slides)
    ``joint_names``           (D,)         str, must equal the hand's joint names, in order
    ``root_pose``             (T, 4, 4)    world pose of the hand's root frame (column-vector transform), metres
    ``fps``                   ()           frames per second, Hz
    ``force``                 (T, S, 3)    force ON THE HAND at sensor s, world coordinates, newtons
    ``force_point``           (T, S, 3)    where that force acts, in the frame of link ``force_link[s]``, metres
    ``force_link``            (S,)         str, hand link names
    ``hand``                  ()           str, "default" (``default_hand("right")``) or an MJCF path relative
                                           to the capture file's folder (absolute paths are kept as given)
    ``object_pose``           (T, 4, 4)    optional, world pose of the touched object
    ``source``                ()           optional str: "measured", "synthetic" or "inferred"
    ``truth_compliance``      (6 + D,)     optional, the compliance the data was generated with, rad/(N m)
                                           (root linear entries m/N); NaN where not applicable
    ========================  ===========  =============================================================

A sensor that does not touch has zero force (its point is then irrelevant but must be finite).
Conventions: metres, seconds, radians, newtons; 4x4 column-vector transforms ``T_world_link @ p_link``
(:mod:`torchhand.conventions`). The force is the paper's f_i (on the hand), i.e. minus torchhand's
``contact_force`` (hand on object).
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._atomic import atomic_bytes
from .._npz import read_npz
from ..errors import FileFormatError, InputValueError, MissingFileError, ShapeError, UnknownNameError

__all__ = ["FORMAT_VERSION", "SOURCES", "Capture", "load_capture", "save_capture", "capture_hand", "check_against_hand"]

FORMAT_VERSION = 1
SOURCES = ("measured", "synthetic", "inferred")
_REQUIRED = ("q", "joint_names", "root_pose", "fps", "force", "force_point", "force_link", "hand")


@dataclass(frozen=True, eq=False)
class Capture:
    """One capture session (see the module docstring for the file format).

    q:                joint angles, (T, D), radians
    joint_names:      (D,) tuple of str
    root_pose:        world pose of the hand's root frame, (T, 4, 4), metres
    fps:              frame rate, Hz
    force:            force on the hand per sensor, world, (T, S, 3), newtons
    force_point:      point of application in the sensor's link frame, (T, S, 3), metres
    force_link:       (S,) tuple of link names
    hand:             "default" or an MJCF path (relative to the capture file's folder when read from a file)
    object_pose:      optional world pose of the object, (T, 4, 4)
    source:           optional "measured" | "synthetic" | "inferred"
    truth_compliance: optional known compliance, (6 + D,), rad/(N m) (root linear m/N), NaN where not applicable
    path:             the file it was read from (None when built in memory); not written
    """

    q: np.ndarray
    joint_names: tuple
    root_pose: np.ndarray
    fps: float
    force: np.ndarray
    force_point: np.ndarray
    force_link: tuple
    hand: str = "default"
    object_pose: np.ndarray | None = None
    source: str | None = None
    truth_compliance: np.ndarray | None = None
    path: Path | None = field(default=None, compare=False)

    def __post_init__(self):
        _validate(self, "capture")

    @property
    def num_frames(self) -> int:
        return int(self.q.shape[0])

    @property
    def num_joints(self) -> int:
        return int(self.q.shape[1])

    @property
    def num_sensors(self) -> int:
        return int(self.force.shape[1])

    @property
    def time(self) -> np.ndarray:
        """Frame times, (T,), seconds from the first frame."""
        return np.arange(self.num_frames, dtype=np.float64) / self.fps


def _validate(c: Capture, where: str) -> None:
    """Shapes, T agreement, finiteness (with the first bad frame) and value ranges; raises TorchhandErrors."""
    def arr(name, x, ndim):
        x = np.asarray(x)
        if x.ndim != ndim:
            raise ShapeError(f"{where}: {name}: expected {ndim} dimensions, got shape {x.shape}")
        if not np.issubdtype(x.dtype, np.number):
            raise FileFormatError(f"{where}: {name}: expected numbers, got dtype {x.dtype}")
        return x.astype(np.float64)

    q = arr("q", c.q, 2)
    T, D = q.shape
    if T < 2:
        raise ShapeError(f"{where}: q: expected at least 2 frames, got shape {q.shape}")
    names = tuple(str(n) for n in np.asarray(c.joint_names, dtype=object).reshape(-1))
    if len(names) != D:
        raise ShapeError(f"{where}: joint_names: expected ({D},) to match q's {D} columns, got ({len(names)},)")
    root = arr("root_pose", c.root_pose, 3)
    if root.shape != (T, 4, 4):
        raise ShapeError(f"{where}: root_pose: expected shape ({T}, 4, 4) (T from q), got {root.shape}")
    force = arr("force", c.force, 3)
    if force.shape[0] != T or force.shape[2] != 3:
        raise ShapeError(f"{where}: force: expected shape ({T}, S, 3) (T from q), got {force.shape}")
    S = force.shape[1]
    point = arr("force_point", c.force_point, 3)
    if point.shape != (T, S, 3):
        raise ShapeError(f"{where}: force_point: expected shape ({T}, {S}, 3), got {point.shape}")
    links = tuple(str(n) for n in np.asarray(c.force_link, dtype=object).reshape(-1))
    if len(links) != S:
        raise ShapeError(f"{where}: force_link: expected ({S},) to match force's {S} sensors, got ({len(links)},)")
    try:
        fps = float(c.fps)
    except (TypeError, ValueError):
        raise InputValueError(f"{where}: fps: expected a number, got {c.fps!r}") from None
    if not (np.isfinite(fps) and fps > 0):
        raise InputValueError(f"{where}: fps: expected a positive frame rate in Hz, got {fps}")
    obj = None
    if c.object_pose is not None:
        obj = arr("object_pose", c.object_pose, 3)
        if obj.shape != (T, 4, 4):
            raise ShapeError(f"{where}: object_pose: expected shape ({T}, 4, 4) (T from q), got {obj.shape}")
    for name, x in (("q", q), ("root_pose", root), ("force", force), ("force_point", point), ("object_pose", obj)):
        if x is not None:
            _check_finite(where, name, x)
    if c.source is not None and str(c.source) not in SOURCES:
        raise InputValueError(f"{where}: source: expected one of {', '.join(SOURCES)}, got {c.source!r}")
    truth = None
    if c.truth_compliance is not None:
        truth = arr("truth_compliance", c.truth_compliance, 1)
        if truth.shape != (6 + D,):
            raise ShapeError(f"{where}: truth_compliance: expected shape ({6 + D},) (6 + D), got {truth.shape}")
    hand = str(c.hand)
    if not hand:
        raise InputValueError(f"{where}: hand: expected 'default' or an MJCF path, got an empty string")
    for name, value in (("q", q), ("joint_names", names), ("root_pose", root), ("fps", fps), ("force", force),
                        ("force_point", point), ("force_link", links), ("hand", hand), ("object_pose", obj),
                        ("source", None if c.source is None else str(c.source)), ("truth_compliance", truth)):
        object.__setattr__(c, name, value)


def _check_finite(where: str, name: str, x: np.ndarray) -> None:
    bad = ~np.isfinite(x.reshape(x.shape[0], -1)).all(axis=1)
    if bad.any():
        k = int(np.argmax(bad))
        raise InputValueError(f"{where}: {name}: non-finite values (NaN or inf), first at frame {k} "
                              f"(t = {k} / fps); {int(bad.sum())} bad frames")


def load_capture(path) -> Capture:
    """Read and validate ``capture.npz``.

    path: the file
    returns: :class:`Capture` with ``path`` set
    raises: MissingFileError (no file), FileFormatError (not an npz, missing key, newer format), ShapeError (wrong
        shapes, T mismatch), InputValueError (NaN / inf with the first bad frame, fps <= 0, unknown source)
    """
    path = Path(path)
    data = read_npz(path, _REQUIRED, "a capture (docs/interaction_capture.md)")
    version = int(data["format_version"]) if "format_version" in data else FORMAT_VERSION
    if version > FORMAT_VERSION:
        raise FileFormatError(f"{path}: format_version {version} is newer than this reader ({FORMAT_VERSION})")

    def scalar_str(key):
        v = data[key]
        if v.shape != ():
            raise ShapeError(f"{path}: {key}: expected a scalar string, got shape {v.shape}")
        return str(v)

    fps = data["fps"]
    if fps.shape != ():
        raise ShapeError(f"{path}: fps: expected a scalar, got shape {fps.shape}")
    return Capture(
        q=data["q"], joint_names=tuple(data["joint_names"].tolist()) if data["joint_names"].ndim == 1 else
        data["joint_names"], root_pose=data["root_pose"], fps=fps.item(), force=data["force"],
        force_point=data["force_point"],
        force_link=tuple(data["force_link"].tolist()) if data["force_link"].ndim == 1 else data["force_link"],
        hand=scalar_str("hand"), object_pose=data.get("object_pose"),
        source=scalar_str("source") if "source" in data else None,
        truth_compliance=data.get("truth_compliance"), path=path,
    )


def save_capture(capture: Capture, path) -> Path:
    """Write ``capture`` as ``capture.npz`` (atomically: a reader sees the old file or the new one).

    capture: a :class:`Capture` (``hand`` is written as given: make an MJCF path relative to ``path``'s folder)
    path:    the file (parent folders are created)
    returns: the path written
    """
    path = Path(path)
    out = dict(format_version=np.array(FORMAT_VERSION), q=capture.q,
               joint_names=np.array(capture.joint_names, dtype=str),
               root_pose=capture.root_pose, fps=np.array(capture.fps), force=capture.force,
               force_point=capture.force_point, force_link=np.array(capture.force_link, dtype=str),
               hand=np.array(capture.hand))
    if capture.object_pose is not None:
        out["object_pose"] = capture.object_pose
    if capture.source is not None:
        out["source"] = np.array(capture.source)
    if capture.truth_compliance is not None:
        out["truth_compliance"] = capture.truth_compliance
    buf = io.BytesIO()
    np.savez_compressed(buf, **out)
    atomic_bytes(path, buf.getvalue())
    return path


def capture_hand(capture: Capture, override: str | None = None):
    """The HandModel a capture refers to, checked against it (:func:`check_against_hand`).

    capture:  a :class:`Capture`
    override: "default" or an MJCF path (the CLI's ``--hand``), instead of ``capture.hand``
    returns: HandModel (float64, CPU)
    raises: MissingFileError (MJCF not found), InputValueError (joint names differ), UnknownNameError (sensor link)
    """
    from ..hand.default import default_hand
    from ..hand.model import HandModel

    spec = override if override is not None else capture.hand
    if spec == "default":
        hand = default_hand("right")
    else:
        p = Path(spec)
        if override is None and not p.is_absolute() and capture.path is not None:
            p = Path(capture.path).parent / p
        if not p.is_file():
            raise MissingFileError(f"hand: MJCF file not found: {p}")
        hand = HandModel.from_mjcf(p)
    check_against_hand(capture, hand)
    return hand


def check_against_hand(capture: Capture, hand) -> None:
    """Joint names equal to the hand's (same order) and every sensor link known to it.

    raises: InputValueError naming the first difference; UnknownNameError listing the hand's links
    """
    if tuple(capture.joint_names) != tuple(hand.joint_names):
        ours, theirs = list(capture.joint_names), list(hand.joint_names)
        if len(ours) != len(theirs):
            detail = f"{len(ours)} joints in the capture, {len(theirs)} in the hand"
        else:
            k = next(i for i, (a, b) in enumerate(zip(ours, theirs)) if a != b)
            detail = f"column {k} is {ours[k]!r} in the capture, {theirs[k]!r} in the hand"
        raise InputValueError(f"joint_names: the capture's joints differ from hand {hand.name!r} ({detail}); "
                              f"the hand's joints: {', '.join(theirs)}")
    for s, name in enumerate(capture.force_link):
        if name not in hand.link_names:
            raise UnknownNameError(f"force_link[{s}]: unknown link {name!r} in hand {hand.name!r}; known links: "
                                   f"{', '.join(hand.link_names)}")
