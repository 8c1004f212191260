"""Skeletons from BVH motion, ready to draw: joint poses in the z-up metre world, bones, fingers, wrists.

:func:`skeleton_from_bvh` reads a BVH file (:func:`torchhand.scene.bvh.read_bvh`) and converts every joint's global
transform with :func:`torchhand.scene.mocap.convert_transforms` (handedness, then units, then up axis) into a
:class:`SkeletonClip`. Conventions (see :mod:`torchhand.conventions`): world z-up, metres, seconds; column-vector 4x4
transforms ``T_world_joint``. End Sites are joints named ``<parent>_end``, drawn like any other joint.

Rig kind
    *Fingers* are the joints whose names contain thumb, index, middle, mid, ring, pinky, pinkie, little or finger
    (any case), with everything below them. *Wrists* are the joints that are not fingers but have a finger child.
    A rig with fingers whose other joints form one unbranched chain (forearm -> hand) is a *hand* rig; every other
    rig is a *body*.

Units (``units="auto"``)
    Measured on the bone lengths of the first frame, in file units: for a body, the longest chain of bones between
    two joints (fingertip to fingertip across the shoulders, or head to toe: about the height of a standing adult,
    1.4-2.1 m); for a hand rig, the longest chain from a wrist down to a fingertip (0.15-0.25 m). Of m, dm, cm and
    mm, the unit that brings the measure closest, on a log scale, to the middle of its range (1.71 m, 0.19 m) is
    chosen. The units are a factor 10 apart, so a measure off by up to 3x still picks the right one.

Up axis (``up="auto"``)
    z when the rest pose (all channels zero) of a body puts a joint named head above the joints named foot, toe or
    ankle along +z rather than along +y; otherwise y (the BVH convention), and always y for a hand rig.

Hand frame (:meth:`SkeletonClip.hand_frames`)
    The rule of :func:`torchhand.scene.mocap.hand_frame_rotation`: x from the wrist toward the middle finger, y toward
    the thumb for a right hand (away from it for a left hand), z = x × y out of the back of the hand. A wrist's
    side comes from its name (right/left, or an r/l prefix as in ``rHand``, ``L_wrist``), else from the words
    right/left in the file's name (``leftHand.bvh``), else it is right.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from torchhand.errors import InputValueError

__all__ = ["UNIT_SCALES", "SkeletonClip", "skeleton_from_bvh", "finger_mask", "wrist_joints", "joint_side",
           "rig_kind", "rig_size", "guess_units", "guess_up"]

UNIT_SCALES = {"m": 1.0, "dm": 0.1, "cm": 0.01, "mm": 0.001}
"""Metres per file unit of each ``units`` choice."""

_SIZE_RANGE = {"body": (1.4, 2.1), "hand": (0.15, 0.25)}
_FINGER_WORDS = ("thumb", "index", "middle", "mid", "ring", "pinky", "pinkie", "little", "finger")


@dataclass(frozen=True, eq=False)
class SkeletonClip:
    """A BVH skeleton in motion, F frames, J joints (End Sites included).

    path: the BVH file, str
    names: joint names, tuple of J str; parents: parent index per joint, tuple of J int, -1 for a root
    transforms: ``T_world_joint`` per frame, (F, J, 4, 4), metres, float64
    fps: frames per second of the file
    is_finger: (J,) bool, the finger joints (module docstring); wrists: the wrist joints, tuple of int
    kind: "body" or "hand"; size: the measure the units rule uses, metres
    units, up, handedness: the conversion applied ("cm", "y", "right", ...); units_auto, up_auto: whether those
        were guessed
    bvh: the :class:`~torchhand.scene.bvh.BVHClip` it came from
    """

    path: str
    names: tuple
    parents: tuple
    transforms: np.ndarray
    fps: float
    is_finger: np.ndarray
    wrists: tuple
    kind: str
    size: float
    units: str
    up: str
    handedness: str
    units_auto: bool
    up_auto: bool
    bvh: object

    @property
    def F(self) -> int:
        return int(self.transforms.shape[0])

    @property
    def positions(self) -> np.ndarray:
        """Joint positions, (F, J, 3), world, metres."""
        return self.transforms[..., :3, 3]

    @property
    def name(self) -> str:
        return Path(self.path).name

    def bones(self) -> np.ndarray:
        """(parent, child) joint index pairs, (B, 2) int: one bone from every joint to each of its children."""
        pairs = [(p, j) for j, p in enumerate(self.parents) if p >= 0]
        return np.asarray(pairs, dtype=np.int64).reshape(-1, 2)

    def subtree(self, j: int) -> np.ndarray:
        """Joint ``j`` and all its descendants, (K,) int, in file order."""
        keep = np.zeros(len(self.names), dtype=bool)
        keep[j] = True
        for i, p in enumerate(self.parents):
            if p >= 0 and keep[p]:
                keep[i] = True
        return np.nonzero(keep)[0]

    def joint_index(self, name: str) -> int:
        """Index of the joint ``name``; :class:`~torchhand.errors.UnknownNameError` listing the joints if none."""
        return self.bvh.joint_index(name)

    def side(self, j: int) -> str:
        """The side of joint ``j``: from its name (:func:`joint_side`), else from the words right / left in the
        file's name (``leftHand.bvh``), else "right"."""
        stem = Path(self.path).stem.lower()
        file_side = "right" if "right" in stem else "left" if "left" in stem else None
        return joint_side(self.names[j]) or file_side or "right"

    def hand_frames(self, wrist: int) -> np.ndarray:
        """``T_world_hand`` of the hand at joint ``wrist``, (F, 4, 4), metres (hand frame: module docstring)."""
        from torchhand.scene.mocap import hand_frame_rotation

        R_fix, _, _ = hand_frame_rotation(self.bvh, wrist, self.side(wrist), handedness=self.handedness,
                                          up_axis=self.up)
        fix = np.eye(4)
        fix[:3, :3] = R_fix
        return self.transforms[:, wrist] @ fix


def finger_mask(names, parents) -> np.ndarray:
    """(J,) bool: joints whose names name a finger, and everything below them."""
    out = np.zeros(len(names), dtype=bool)
    for j, (n, p) in enumerate(zip(names, parents)):
        low = str(n).lower()
        out[j] = any(w in low for w in _FINGER_WORDS) or (p >= 0 and out[p])
    return out


def wrist_joints(names, parents, is_finger) -> tuple:
    """Joints that are not fingers but have a finger child, in file order."""
    return tuple(sorted({p for j, p in enumerate(parents) if p >= 0 and is_finger[j] and not is_finger[p]}))


def joint_side(name: str) -> str | None:
    """"right", "left" or None from a joint's name: the words right / left, or an r / l prefix followed by an
    upper-case letter or a separator (``rHand``, ``RThumb1``, ``L_wrist``); a namespace (``mixamorig:``) is ignored."""
    base = str(name).split(":")[-1]
    low = base.lower()
    if "right" in low:
        return "right"
    if "left" in low:
        return "left"
    m = re.match(r"^([rRlL])(?:[A-Z]|[_.\- ])", base)
    if m:
        return "right" if m.group(1) in "rR" else "left"
    return None


def rig_kind(parents, is_finger) -> str:
    """"hand" when the rig has fingers and its other joints form one unbranched chain, else "body"."""
    if not np.any(is_finger):
        return "body"
    other = [j for j in range(len(parents)) if not is_finger[j]]
    roots = [j for j in other if parents[j] < 0]
    kids = {j: 0 for j in other}
    for j in other:
        if parents[j] >= 0:
            kids[parents[j]] += 1
    return "hand" if len(roots) == 1 and max(kids.values()) <= 1 else "body"


def rig_size(parents, bone_lengths: np.ndarray, kind: str, wrists=()) -> float:
    """The units rule's measure (module docstring), in the units of ``bone_lengths`` ((J,), from each joint to
    its parent, 0 for a root): the longest bone chain between two joints for a body, the longest chain from a
    wrist down to a joint below it for a hand."""
    J = len(parents)
    down = np.zeros(J)  # longest chain from each joint down to a joint below it
    best = 0.0
    for j in range(J - 1, -1, -1):  # parents precede children
        p = parents[j]
        if p >= 0:
            reach = bone_lengths[j] + down[j]
            best = max(best, down[p] + reach)  # the two longest branches below p
            down[p] = max(down[p], reach)
    if kind == "hand" and wrists:
        return float(max(down[w] for w in wrists))
    return float(best)


def guess_units(size: float, kind: str) -> str:
    """The unit (a key of :data:`UNIT_SCALES`) that brings ``size`` (file units) closest on a log scale to the
    middle of the expected range for ``kind`` (module docstring)."""
    lo, hi = _SIZE_RANGE[kind]
    centre = math.sqrt(lo * hi)
    return min(UNIT_SCALES, key=lambda u: abs(math.log(size * UNIT_SCALES[u] / centre)))


def guess_up(names, rest: np.ndarray, kind: str) -> str:
    """"z" or "y" from the rest joint positions ``rest`` (J, 3), file axes (module docstring)."""
    if kind != "body":
        return "y"
    low = [str(n).split(":")[-1].lower() for n in names]
    head = [j for j, n in enumerate(low) if "head" in n and not n.endswith("_end")]
    feet = [j for j, n in enumerate(low) if any(w in n for w in ("foot", "toe", "ankle"))]
    if not head or not feet:
        return "y"
    d = rest[head[0]] - rest[feet].mean(axis=0)
    return "z" if d[2] > abs(d[1]) else "y"


def _choice(value: str, name: str, choices) -> str:
    if value not in choices:
        raise InputValueError(f"{name}: expected one of {', '.join(choices)}, got {value!r}")
    return value


def skeleton_from_bvh(path, *, units: str = "auto", up: str = "auto", handedness: str = "right") -> SkeletonClip:
    """Read the BVH file ``path`` as a :class:`SkeletonClip` in the z-up metre world.

    units: "auto" (module docstring) or a key of :data:`UNIT_SCALES`; up: "auto", "y" or "z";
    handedness: "right", or "left" for left-handed sources (mirrored, see :mod:`torchhand.scene.mocap`).

    Raises:
        MissingFileError, FileFormatError: the file is missing or malformed (from :func:`torchhand.scene.bvh.read_bvh`).
        InputValueError: a bad option, or units to guess for a skeleton without extent.
    """
    from torchhand.scene.bvh import read_bvh
    from torchhand.scene.mocap import convert_transforms

    _choice(units, "--bvh-units", ("auto", *UNIT_SCALES))
    _choice(up, "--bvh-up", ("auto", "y", "z"))
    _choice(handedness, "--bvh-handedness", ("right", "left"))
    clip = read_bvh(path)
    G = clip.global_transforms()  # (F, J, 4, 4), file units and axes
    is_finger = finger_mask(clip.names, clip.parents)
    wrists = wrist_joints(clip.names, clip.parents, is_finger)
    kind = rig_kind(clip.parents, is_finger)
    p0 = G[0, :, :3, 3].numpy()
    lengths = np.array([np.linalg.norm(p0[j] - p0[p]) if p >= 0 else 0.0 for j, p in enumerate(clip.parents)])
    size = rig_size(clip.parents, lengths, kind, wrists)
    if units == "auto":
        if not size > 0:
            raise InputValueError(f"--bvh-units: cannot guess the units of {clip.path}: its first frame has no bone "
                                  f"of non-zero length; give --bvh-units m|dm|cm|mm")
        chosen_units = guess_units(size, kind)
    else:
        chosen_units = units
    chosen_up = guess_up(clip.names, clip.rest_transforms()[:, :3, 3].numpy(), kind) if up == "auto" else up
    world = convert_transforms(G, units_scale=UNIT_SCALES[chosen_units], up_axis=chosen_up, handedness=handedness)
    return SkeletonClip(path=clip.path, names=clip.names, parents=clip.parents, transforms=world.numpy(), fps=clip.fps,
                        is_finger=is_finger, wrists=wrists, kind=kind, size=size * UNIT_SCALES[chosen_units],
                        units=chosen_units, up=chosen_up, handedness=handedness, units_auto=units == "auto",
                        up_auto=up == "auto", bvh=clip)
