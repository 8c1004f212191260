"""Which joint is which: arms and fingers of a BVH rig, recognised from joint names or the hierarchy.

Roles
    Per side ("right", "left"): an :class:`Arm` (shoulder, elbow, forearm, wrist, trunk joints) and finger joints
    keyed by ``(finger, ordinal)``, ``finger`` in :data:`FINGERS`. Ordinals: 0 = metacarpal (rigs that have one:
    MB-Lab/CMU ``index00``), 1 = proximal phalanx (its joint is the knuckle, MCP), 2 = middle phalanx (PIP),
    3 = distal phalanx (DIP). The thumb has no 0; its ordinals follow the anatomical joint: 1 = CMC (moves the
    first metacarpal), 2 = MCP, 3 = IP. Three-joint thumbs (Mixamo, MB-Lab/CMU, Character Creator, Leap) are
    1, 2, 3 in chain order: their first thumb joint sits near the wrist, at the CMC. ManipNet's thumb has two CMC
    joints 2.8 mm apart (``THUMB_CMC_FE`` then ``THUMB_CMC_AA``): ``THUMB_CMC_AA`` is thumb 1 and ``THUMB_CMC_FE``
    a chain joint without a role (retargeting composes it into thumb 1, :mod:`torchhand.splice.retarget`).
    Chain joints without a role (that one, tip joints such as Mixamo's ``Index4``) are in
    :meth:`Rig.finger_joints` but not in :attr:`Rig.fingers`.

Known namings (whole names, case-insensitive, after a namespace such as ``mixamorig:``; table in
``docs/splice_rigs.md``): mixamo, mblab (alias cmu: the CMU library on MB-Lab's skeleton; "auto" reports
mblab), cc (Character Creator ``CC_Base_*``), mocapbank (no fingers), leap (forearm root, no shoulder or
elbow), manipnet (wrist root, no forearm). Side markers: Right/Left words, ``_R``/``_L`` suffixes, ``_R_``/``_L_``
infixes, r/l prefixes (``rHand``), ``R_``/``L_`` prefixes on ManipNet names. A hand whose names carry no side
(ManipNet) is on side ``unsided`` (argument), else the word right/left in the file's name (``leftHand.bvh``),
else "right".

Automatic detection ("auto")
    Arms and fingers are recognised separately, each by the naming that finds the most roles (ties: the order
    above), so a body whose fingers came from another rig (inserted ManipNet fingers) is recognised too. Finger
    joints must lie below their side's wrist. Trunk: the first joint above the shoulder's parent with two or more
    child joints (the chest joint the clavicle hangs from; the shoulder's parent when there is no clavicle).
    Forearm: the wrist's parent (Leap: ``rForeArm``; None when the wrist is a root).

Hierarchy fallback (names say nothing)
    * Fingers of a wrist: the chains below it (directly, or through one palm joint) that are unbranched and 2-5
      joints long (End Sites not counted); exactly five, or the side has no fingers. Order: the thumb is the chain
      whose joints lie nearest the wrist along the hand axis (wrist -> mean of the five chain ends); the other
      four are ordered along the thumb-ward axis (the thumb chain's first joint minus the mean of the four
      chains' joints, made orthogonal to the hand axis), nearest the thumb first: index, middle, ring, pinky.
      Ordinals: four finger joints whose first lies nearer the wrist than half the wrist-to-second-joint distance
      are 0-3 (metacarpal), otherwise 1, 2, 3 and a tip joint; three are 1-3; two 1-2; more than four: the last
      four are 0-3. Thumb: a four-joint thumb ends in a tip joint when the other fingers do, otherwise its first
      joint has no role (two CMC joints, ManipNet); the last three joints are 1, 2, 3.
    * Wrists: joints with five such chains (the lowest when a forearm sees them through its only child). A body
      when an ancestor of the wrist has two or more child joints: elbow = forearm = the wrist's parent, shoulder =
      its parent; otherwise a hand rig: forearm = the wrist's parent. Side: the hand's chirality in the file's
      coordinates (fingertips and thumb lie on the palm side, -(x × t) for a right hand, x the hand axis, t the
      pinky -> index knuckle direction) when the evidence exceeds 3 % of the hand length; else the file's name;
      else "right" for a single hand. A left-handed file looks mirrored: give such a rig's sides in a map.

Map files (TOML, a path ending in ``.toml``; ``docs/splice_rigs.md``)
    ``[right]``/``[left]`` tables of role = "joint name" (``shoulder``, ``elbow``, ``forearm``, ``wrist``,
    ``trunk``, ``thumb1``-``thumb3``, ``index0``-``index3`` ... ``pinky3``, ``thumb_tip`` ... ``pinky_tip``);
    top-level ``name`` and ``auto`` (default true: roles the map does not give are detected automatically).

Errors
    :class:`~torchhand.errors.UnknownNameError` when no wrist is recognised (or a requested side lacks a required
    role), listing candidate joints and suggesting ``--body-map``/``--hand-map`` or a map. A rig without fingers
    is not an error. Rest geometry comes from the OFFSETs alone (every channel zero, position channels ignored).

Modules
    ``_rig_record`` :class:`Arm`, :class:`Rig`, sides and roles, the missing-role error; ``_rig_namings`` the
    naming table and its matchers; ``rig_hierarchy`` rest positions and the hierarchy fallback; ``_rig_auto``
    automatic detection; ``_rig_map`` map files; this module :func:`detect_rig`, which picks among them.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import InputValueError
from ..scene.bvh import BVHClip
from ._rig_auto import _auto
from ._rig_map import _from_map
from ._rig_namings import _BY_NAME, _NAMINGS
from ._rig_record import SIDES, Arm, Rig, _check_side, _missing
from .rig_hierarchy import FINGERS, rest_positions

__all__ = ["FINGERS", "SIDES", "KNOWN_RIGS", "Arm", "Rig", "detect_rig", "rest_positions"]

KNOWN_RIGS = ("mixamo", "mblab", "cmu", "cc", "mocapbank", "leap", "manipnet", "torchhand")
"""Rig names :func:`detect_rig` accepts besides "auto" and a map path (``cmu`` = ``mblab``)."""


def detect_rig(clip: BVHClip, rig: str = "auto", *, side: str | None = None, require: tuple[str, ...] = ("wrist",),
               unsided: str | None = None) -> Rig:
    """Recognise the arms and fingers of ``clip`` (module docstring).

    Args:
        clip: the BVH
        rig: "auto", a name from :data:`KNOWN_RIGS`, or the path of a TOML map (``.toml``)
        side: when given, that side must have the ``require`` roles (UnknownNameError otherwise)
        require: arm roles ``side`` must have, from shoulder, elbow, forearm, wrist, trunk
        unsided: the side of a hand whose joint names carry none (ManipNet); default: the word right/left in the
            file's name, else "right"

    Returns:
        :class:`Rig`

    Raises:
        UnknownNameError: no wrist recognised, or ``side`` lacks a required role (the message lists candidates)
        InputValueError: an unknown ``rig`` or ``side``
        MissingFileError, FileFormatError: an unreadable or malformed map
    """
    if not isinstance(rig, str):
        rig = str(rig)
    if side is not None:
        _check_side(side)
    if unsided is not None:
        _check_side(unsided)
    unsided = unsided or _file_side(clip.path) or "right"
    key = rig.lower()
    if key == "auto":
        out = _auto(clip, _NAMINGS, unsided)
    elif key in _BY_NAME:
        out = _auto(clip, (_BY_NAME[key],), unsided, fallback=False, name=key)
    elif key.endswith(".toml") or Path(rig).is_file():
        out = _from_map(clip, Path(rig), unsided)
    else:
        raise InputValueError(f"rig: expected 'auto', one of {', '.join(KNOWN_RIGS)} or a .toml map, got {rig!r}")
    if not out.arms:
        raise _missing(clip.names, side or "any", "wrist", rig)
    if side is not None:
        out.arm(side, require)
    return out


def _file_side(path: str) -> str | None:
    stem = Path(path).stem.lower()
    if "right" in stem and "left" not in stem:
        return "right"
    if "left" in stem and "right" not in stem:
        return "left"
    return None
