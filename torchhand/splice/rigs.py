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
"""

from __future__ import annotations

import difflib
import re
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..scene.bvh import BVHClip
from ..errors import FileFormatError, InputValueError, MissingFileError, UnknownNameError
from .rig_hierarchy import (_TIP, FINGERS, _ancestors, _chain, _chain_roles, _children, _chirality,  # noqa: F401
                            _finger_chains, _hierarchy_fingers, _is_below, _joint_children, _order_chains, _tip,
                            _trunk, _unit, rest_positions)

__all__ = ["FINGERS", "SIDES", "KNOWN_RIGS", "Arm", "Rig", "detect_rig", "rest_positions"]

SIDES = ("right", "left")

KNOWN_RIGS = ("mixamo", "mblab", "cmu", "cc", "mocapbank", "leap", "manipnet", "torchhand")
"""Rig names :func:`detect_rig` accepts besides "auto" and a map path (``cmu`` = ``mblab``)."""

_ARM_ROLES = ("shoulder", "elbow", "forearm", "wrist", "trunk")


@dataclass(frozen=True)
class Arm:
    """The joints of one arm (indices into the clip's joints; None = the rig has none).

    side: "right" or "left"
    shoulder: the upper-arm joint, whose origin is the shoulder joint's centre (body rigs; None for hand rigs)
    elbow: the forearm joint at the elbow's centre (body rigs; None for hand rigs)
    wrist: the hand joint, whose origin is the wrist's centre (always present)
    trunk: a spine/chest joint above the clavicle whose rotation is the trunk's (body rigs; None for hand rigs)
    forearm: the joint whose rotation carries the forearm segment, the wrist's parent: the elbow joint (or a
        forearm twist joint) of body rigs, Leap's ``ForeArm`` root; None when the wrist is a root (ManipNet)
    """

    side: str
    shoulder: int | None
    elbow: int | None
    wrist: int
    trunk: int | None
    forearm: int | None = None


@dataclass(frozen=True)
class Rig:
    """A recognised rig.

    name: the naming recognised ("mixamo", "mblab", ..., "hierarchy", a map's name, or "arms+fingers" when they
        come from two namings)
    arms: side -> :class:`Arm`
    fingers: side -> (finger, ordinal) -> joint index (module docstring for ordinals)
    tips: side -> finger -> the End Site below the finger's last joint, or that joint when it has none
    names, parents, is_end_site: the clip's joint names, parent indices and End Site flags, tuples of J
    how: part ("right arm", "right fingers", ...) -> how it was found ("mixamo names", "hierarchy",
        "map <file>", "inserted from <rig>")
    """

    name: str
    arms: dict[str, Arm]
    fingers: dict[str, dict[tuple[str, int], int]]
    tips: dict[str, dict[str, int]]
    names: tuple[str, ...] = ()
    parents: tuple[int, ...] = ()
    is_end_site: tuple[bool, ...] = ()
    how: dict[str, str] = field(default_factory=dict)

    def has_fingers(self, side: str) -> bool:
        """Whether ``side`` has finger joints."""
        return bool(self.fingers.get(side))

    def finger_joints(self, side: str, *, roles_only: bool = False) -> list[int]:
        """Joints of ``side``'s finger chains, sorted: every joint between the wrist and each finger's tip (End
        Sites excluded), including joints without a role (ManipNet's ``THUMB_CMC_FE``, tip joints); with
        ``roles_only`` only the joints of :attr:`fingers`."""
        roles = set(self.fingers.get(side, {}).values())
        if roles_only or side not in self.arms or not self.parents:
            return sorted(roles)
        wrist, out = self.arms[side].wrist, set(roles)
        for j in list(roles) + list(self.tips.get(side, {}).values()):
            k = j
            while k >= 0 and k != wrist:
                out.add(k)
                k = self.parents[k]
        return sorted(j for j in out if not self.is_end_site[j])

    def arm(self, side: str, require: tuple[str, ...] = ("wrist",)) -> Arm:
        """The arm of ``side``, checked to have the ``require`` roles (from shoulder, elbow, forearm, wrist,
        trunk); UnknownNameError listing candidate joints otherwise."""
        _check_side(side)
        arm = self.arms.get(side)
        for role in ("wrist",) + tuple(r for r in require if r != "wrist"):
            if role not in _ARM_ROLES:
                raise InputValueError(f"require: expected roles from {', '.join(_ARM_ROLES)}, got {role!r}")
            if arm is None or getattr(arm, role) is None:
                raise _missing(self.names, side, role, self.name)
        return arm

    def summary(self) -> dict:
        """Joint names by role, for reports: {"name", "arms": {side: {role: name}}, "fingers": {side: {"index1":
        name}}, "tips": {side: {finger: name}}, "how": {...}}."""
        n = self.names
        nm = (lambda j: n[j] if n else j)
        return {
            "name": self.name,
            "arms": {s: {r: nm(getattr(a, r)) for r in _ARM_ROLES if getattr(a, r) is not None}
                     for s, a in self.arms.items()},
            "fingers": {s: {f"{f}{o}": nm(j) for (f, o), j in sorted(d.items(), key=_role_key)}
                        for s, d in self.fingers.items()},
            "tips": {s: {f: nm(j) for f, j in d.items()} for s, d in self.tips.items()},
            "how": dict(self.how),
        }


def _role_key(item) -> tuple[int, int]:
    (f, o), _ = item
    return FINGERS.index(f), o


# ---------------------------------------------------------------------------------------------------------------
# namings

_S_WORD = r"(?P<s>right|left)"
_S_LETTER = r"(?P<s>r|l)"
_FINGER_WORDS = {"thumb": "thumb", "index": "index", "middle": "middle", "mid": "middle", "ring": "ring",
                 "pinky": "pinky", "little": "pinky"}
_F = r"(?P<f>thumb|index|middle|mid|ring|pinky)"


@dataclass(frozen=True)
class _Naming:
    """Regular expressions (whole name, case-insensitive) of one rig's naming. Groups: ``s`` side, ``f`` finger,
    ``n`` the digits of the name, mapped to an ordinal by ``ordinal``; fixed finger joints in ``named``."""

    name: str
    arm: dict[str, str]
    finger: str | None = None
    ordinal: dict[str, dict[str, int]] = field(default_factory=dict)   # "thumb"/"other" -> digits -> ordinal
    named: dict[str, tuple[str, int]] = field(default_factory=dict)     # regex -> (finger, ordinal)


_ONE_TWO_THREE = {"1": 1, "2": 2, "3": 3, "4": _TIP}
_NAMINGS = (
    _Naming("mixamo", {"shoulder": _S_WORD + "arm", "elbow": _S_WORD + "forearm", "wrist": _S_WORD + "hand"},
            _S_WORD + "hand" + _F + r"(?P<n>[1-4])", {"thumb": _ONE_TWO_THREE, "other": _ONE_TWO_THREE}),
    _Naming("mblab", {"shoulder": "upperarm_" + _S_LETTER, "elbow": "lowerarm_" + _S_LETTER,
                      "wrist": "hand_" + _S_LETTER},
            _F + r"(?P<n>0[0-3])_" + _S_LETTER,
            {"thumb": {"01": 1, "02": 2, "03": 3}, "other": {"00": 0, "01": 1, "02": 2, "03": 3}}),
    _Naming("cc", {"shoulder": "cc_base_" + _S_LETTER + "_upperarm", "elbow": "cc_base_" + _S_LETTER + "_forearm",
                   "wrist": "cc_base_" + _S_LETTER + "_hand"},
            "cc_base_" + _S_LETTER + "_" + _F + r"(?P<n>[0-3])",
            {"thumb": {"1": 1, "2": 2, "3": 3}, "other": {"0": 0, "1": 1, "2": 2, "3": 3}}),
    _Naming("mocapbank", {"shoulder": _S_WORD + "shoulder", "elbow": _S_WORD + "elbow",
                          "wrist": _S_WORD + "wrist"}),
    _Naming("leap", {"forearm": _S_LETTER + "forearm", "wrist": _S_LETTER + "hand"},
            _S_LETTER + _F + r"(?P<n>[1-3])", {"thumb": {"1": 1, "2": 2, "3": 3}, "other": {"1": 1, "2": 2, "3": 3}}),
    _Naming("manipnet", {"wrist": r"(?:(?P<s>right|left|r|l)_)?wrist"},
            named={r"thumb_cmc_aa": ("thumb", 1), r"thumb_mcp_fe": ("thumb", 2), r"thumb_ip_fe": ("thumb", 3),
                   r"(?P<f>index|middle|ring|pinky)_mcp(?:_fe)?": (None, 1),
                   r"(?P<f>index|middle|ring|pinky)_pip(?:_fe)?": (None, 2),
                   r"(?P<f>index|middle|ring|pinky)_dip(?:_fe)?": (None, 3)}),
    # torchhand's own hand (hand.xml of a result, exported as BVH): the palm is the wrist
    _Naming("torchhand", {"wrist": r"(?:(?P<s>right|left|r|l)_)?palm"},
            named={r"thumb_metacarpal": ("thumb", 1), r"thumb_proximal": ("thumb", 2), r"thumb_distal": ("thumb", 3),
                   r"(?P<f>index|middle|ring|little)_metacarpal": (None, 0),
                   r"(?P<f>index|middle|ring|little)_proximal": (None, 1),
                   r"(?P<f>index|middle|ring|little)_middle": (None, 2),
                   r"(?P<f>index|middle|ring|little)_distal": (None, 3)}),
)
_BY_NAME = {n.name: n for n in _NAMINGS}
_BY_NAME["cmu"] = _BY_NAME["mblab"]
_SIDE_PREFIX = r"(?:(?P<s>right|left|r|l)_)?"


def _bare(name: str) -> str:
    """A joint name without namespace (``mixamorig:RightHand`` -> ``righthand``), lower case."""
    return name.rsplit(":", 1)[-1].lower()


def _side_of(token: str | None, unsided: str) -> str:
    if not token:
        return unsided
    return "right" if token.lower() in ("r", "right") else "left"


def _match_arms(clip: BVHClip, naming: _Naming, unsided: str) -> dict[str, dict[str, int]]:
    """side -> role -> joint for one naming (first match in hierarchy order)."""
    out: dict[str, dict[str, int]] = {}
    pats = {r: re.compile(p, re.IGNORECASE) for r, p in naming.arm.items()}
    for j, nm in enumerate(clip.names):
        if clip.is_end_site[j]:
            continue
        b = _bare(nm)
        for role, pat in pats.items():
            m = pat.fullmatch(b)
            if m:
                side = _side_of(m.groupdict().get("s"), unsided)
                out.setdefault(side, {}).setdefault(role, j)
    return out


def _match_fingers(clip: BVHClip, naming: _Naming, unsided: str) -> dict[str, dict[tuple[str, int], int]]:
    """side -> (finger, ordinal) -> joint for one naming (ordinal _TIP marks tip joints)."""
    out: dict[str, dict[tuple[str, int], int]] = {}
    pats = []
    if naming.finger:
        pats.append((re.compile(naming.finger, re.IGNORECASE), None))
    for p, role in naming.named.items():
        pats.append((re.compile(_SIDE_PREFIX + p, re.IGNORECASE), role))
    for j, nm in enumerate(clip.names):
        if clip.is_end_site[j]:
            continue
        b = _bare(nm)
        for pat, role in pats:
            m = pat.fullmatch(b)
            if not m:
                continue
            g = m.groupdict()
            finger = _FINGER_WORDS[g["f"].lower()] if g.get("f") else role[0]
            if role is not None:
                ordinal = role[1]
            else:
                table = naming.ordinal["thumb" if finger == "thumb" else "other"]
                if g["n"] not in table:
                    continue
                ordinal = table[g["n"]]
            out.setdefault(_side_of(g.get("s"), unsided), {}).setdefault((finger, ordinal), j)
            break
    return out


# ---------------------------------------------------------------------------------------------------------------
# detection


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


def _auto(clip: BVHClip, namings, unsided: str, *, fallback: bool = True, name: str | None = None) -> Rig:
    rest = rest_positions(clip)
    how: dict[str, str] = {}
    # arms: the naming with the most roles
    best, arm_naming = {}, None
    for nm in namings:
        found = _match_arms(clip, nm, unsided)
        if sum(len(r) for r in found.values()) > sum(len(r) for r in best.values()) and \
                any("wrist" in r for r in found.values()):
            best, arm_naming = found, nm.name
    arms: dict[str, Arm] = {}
    for s, roles in best.items():
        if "wrist" in roles:
            arms[s] = _make_arm(clip, s, roles)
            how[f"{s} arm"] = f"{arm_naming} names"
    fingers: dict[str, dict[tuple[str, int], int]] = {}
    finger_namings = set()
    if not arms and fallback:
        arms, fingers = _hierarchy_arms(clip, rest, unsided)
        for s in arms:
            how[f"{s} arm"] = how[f"{s} fingers"] = "hierarchy"
        arm_naming = "hierarchy" if arms else None
    for s, arm in arms.items():
        if s in fingers:
            continue
        top, top_naming = {}, None
        for nm in namings:
            found = {k: j for k, j in _match_fingers(clip, nm, unsided).get(s, {}).items()
                     if _is_below(clip.parents, j, arm.wrist)}
            if len([k for k in found if k[1] != _TIP]) > len([k for k in top if k[1] != _TIP]):
                top, top_naming = found, nm.name
        if not top and fallback:
            top = _hierarchy_fingers(clip, rest, arm.wrist) or {}
            top_naming = "hierarchy" if top else None
        if top:
            fingers[s] = top
            finger_namings.add(top_naming)
            how[f"{s} fingers"] = top_naming + ("" if top_naming == "hierarchy" else " names")
    rig_name = name or _combined_name(arm_naming, finger_namings)
    return _finish(clip, rig_name, arms, fingers, how)


def _combined_name(arm_naming: str | None, finger_namings: set) -> str:
    parts = [arm_naming] if arm_naming else []
    parts += sorted(n for n in finger_namings if n and n != arm_naming)
    return "+".join(parts) or "none"


def _make_arm(clip: BVHClip, side: str, roles: dict[str, int]) -> Arm:
    w = roles["wrist"]
    par = clip.parents
    elbow = roles.get("elbow")
    if elbow is not None and not _is_below(par, w, elbow):
        elbow = None
    shoulder = roles.get("shoulder")
    if shoulder is not None and not _is_below(par, elbow if elbow is not None else w, shoulder):
        shoulder = None
    forearm = roles.get("forearm")
    if forearm is None or not _is_below(par, w, forearm):
        forearm = par[w] if par[w] >= 0 else None
    return Arm(side=side, shoulder=shoulder, elbow=elbow, wrist=w, trunk=_trunk(clip, shoulder), forearm=forearm)


def _hierarchy_arms(clip: BVHClip, rest: np.ndarray, unsided: str):
    """Wrists from finger chains, arms from the hierarchy, sides from chirality (module docstring)."""
    found = []
    for j in range(clip.num_joints):
        if clip.is_end_site[j]:
            continue
        f = _hierarchy_fingers(clip, rest, j)
        if f is not None:
            tips = {fi: _tip(clip, max((jj for (ff, _), jj in f.items() if ff == fi), key=lambda q: q))
                    for fi in FINGERS}
            found.append((j, f, _chirality(rest, j, f, tips)))
    # a joint whose only child is a wrist (a forearm) also sees five chains through it: keep the lowest
    found = [c for c in found if not any(_is_below(clip.parents, o[0], c[0]) for o in found)]
    if len(found) == 1 and found[0][2] is None:
        found = [(found[0][0], found[0][1], unsided)]
    if len(found) == 2 and (found[0][2] is None) != (found[1][2] is None):
        known = found[0][2] or found[1][2]
        other = "left" if known == "right" else "right"
        found = [(j, f, s or other) for j, f, s in found]
    sides = [s for _, _, s in found]
    if len(found) > 2 or None in sides or len(set(sides)) != len(sides):
        names = ", ".join(clip.names[j] for j, _, _ in found)
        raise UnknownNameError(f"rig: cannot tell the sides of the hands at {names} in {clip.path} from names or "
                               "shape; give a TOML map (docs/splice_rigs.md) with --body-map/--hand-map")
    arms, fingers = {}, {}
    for w, f, s in found:
        par = clip.parents
        body = any(len(_joint_children(clip, a)) >= 2 for a in _ancestors(par, w))
        forearm = par[w] if par[w] >= 0 else None
        if body and forearm is not None and par[forearm] >= 0:
            shoulder = par[forearm]
            arms[s] = Arm(side=s, shoulder=shoulder, elbow=forearm, wrist=w, trunk=_trunk(clip, shoulder),
                          forearm=forearm)
        else:
            arms[s] = Arm(side=s, shoulder=None, elbow=None, wrist=w, trunk=None, forearm=forearm)
        fingers[s] = f
    return arms, fingers


def _finish(clip: BVHClip, name: str, arms: dict[str, Arm], fingers: dict, how: dict) -> Rig:
    """Drop tip-joint markers from the finger roles and find each finger's tip."""
    roles, tips = {}, {}
    for s, d in fingers.items():
        roles[s] = {k: j for k, j in d.items() if k[1] != _TIP}
        tips[s] = {}
        for f in FINGERS:
            js = [j for (ff, _), j in d.items() if ff == f]
            if js:
                deepest = max(js, key=lambda j: len(_ancestors(clip.parents, j)))
                tips[s][f] = _tip(clip, deepest)
        if not roles[s]:
            del roles[s], tips[s]
    return Rig(name=name, arms=arms, fingers=roles, tips=tips, names=clip.names, parents=clip.parents,
               is_end_site=clip.is_end_site, how=how)


# ---------------------------------------------------------------------------------------------------------------
# map files

_MAP_ROLES = set(_ARM_ROLES) | {f"{f}{o}" for f in FINGERS for o in range(4) if not (f == "thumb" and o == 0)} \
    | {f"{f}_tip" for f in FINGERS}


def _from_map(clip: BVHClip, path: Path, unsided: str) -> Rig:
    if not path.is_file():
        raise MissingFileError(f"rig: map file '{path}' does not exist")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise FileFormatError(f"{path}: not a valid TOML map: {err}") from None
    bad = set(data) - {"name", "auto", "right", "left"}
    if bad:
        raise FileFormatError(f"{path}: unknown top-level key(s) {', '.join(sorted(bad))}; expected name, auto, "
                              "[right], [left]")
    auto = data.get("auto", True)
    if not isinstance(auto, bool):
        raise FileFormatError(f"{path}: 'auto' must be true or false, got {auto!r}")
    base = Rig("map", {}, {}, {})
    if auto:
        try:
            base = _auto(clip, _NAMINGS, unsided)
        except UnknownNameError:
            pass                                   # the map may name what detection could not
    arms = dict(base.arms)
    fingers = {s: {k: j for k, j in d.items()} for s, d in base.fingers.items()}
    tip_override: dict[str, dict[str, int]] = {}
    how = dict(base.how)
    for s in SIDES:
        idx = _map_table(clip, path, s, data.get(s))
        if not idx:
            continue
        given = {r: j for r, j in idx.items() if r in _ARM_ROLES}
        if given:
            old = arms.get(s)
            roles = {r: getattr(old, r) for r in ("shoulder", "elbow", "wrist") if old and getattr(old, r) is not None}
            roles.update({r: j for r, j in given.items() if r in ("shoulder", "elbow", "wrist", "forearm")})
            if "wrist" not in roles:
                raise UnknownNameError(f"{path}: [{s}] gives arm joints but no wrist, and none was recognised in "
                                       f"{clip.path}")
            arm = replace(_make_arm(clip, s, roles), **given)
            if "trunk" not in given and "shoulder" in given:
                arm = replace(arm, trunk=_trunk(clip, arm.shoulder))
            arms[s] = arm
            how[f"{s} arm"] = f"map {path.name}"
        froles = {(r.rstrip("0123"), int(r[-1])): j for r, j in idx.items()
                  if r not in _ARM_ROLES and not r.endswith("_tip")}
        if froles:
            fingers[s] = {**fingers.get(s, {}), **froles} if auto else froles
            how[f"{s} fingers"] = f"map {path.name}"
        tip_override[s] = {r[:-4]: j for r, j in idx.items() if r.endswith("_tip")}
    for s, arm in arms.items():
        if s not in fingers and not auto:
            found = _hierarchy_fingers(clip, rest_positions(clip), arm.wrist)
            if found:
                fingers[s] = found
                how[f"{s} fingers"] = "hierarchy"
    out = _finish(clip, str(data.get("name", path.stem)), arms, fingers, how)
    for s, d in tip_override.items():
        if d:
            out.tips.setdefault(s, {}).update(d)
    return out


def _map_table(clip: BVHClip, path: Path, side: str, table) -> dict[str, int]:
    """role -> joint index of one side's table of a map file."""
    if table is None:
        return {}
    if not isinstance(table, dict):
        raise FileFormatError(f"{path}: [{side}] must be a table of role = \"joint name\"")
    bad = set(table) - _MAP_ROLES
    if bad:
        raise FileFormatError(f"{path}: [{side}] unknown role(s) {', '.join(sorted(bad))}; roles: shoulder, elbow, "
                              "forearm, wrist, trunk, thumb1-3, index0-3, middle0-3, ring0-3, pinky0-3, <finger>_tip")
    idx = {}
    for role, jname in table.items():
        if not isinstance(jname, str):
            raise FileFormatError(f"{path}: [{side}] {role} must be a joint name (a string), got {jname!r}")
        if jname not in clip.names:
            close = difflib.get_close_matches(jname, clip.names, n=5, cutoff=0.5)
            raise UnknownNameError(f"{path}: [{side}] {role} = '{jname}' is not a joint of {clip.path}"
                                   + (f"; did you mean {', '.join(close)}?" if close else ""))
        idx[role] = clip.names.index(jname)
    return idx


# ---------------------------------------------------------------------------------------------------------------
# errors

_ROLE_WORDS = {
    "wrist": ("hand", "wrist", "carpal", "palm"),
    "elbow": ("elbow", "forearm", "lowerarm", "fore"),
    "forearm": ("forearm", "lowerarm", "elbow", "fore"),
    "shoulder": ("shoulder", "upperarm", "arm", "collar", "clavicle"),
    "trunk": ("spine", "chest", "torso", "back"),
}


def _check_side(side: str) -> None:
    if side not in SIDES:
        raise InputValueError(f"side: expected 'right' or 'left', got {side!r}")


def _name_side(name: str) -> str | None:
    """"right", "left" or None from a joint name's side marker (words, ``R_``/``_R``/``.R``, Leap's ``rHand``)."""
    raw = name.rsplit(":", 1)[-1]
    b = raw.lower()
    if "right" in b:
        return "right"
    if "left" in b:
        return "left"
    m = re.match(r"([rl])[_.]", b) or re.search(r"[_.]([rl])(?=[_.]|$)", b) or re.match(r"([rl])(?=[A-Z])", raw)
    if m:
        return "right" if m.group(1).lower() == "r" else "left"
    return None


def _missing(names, side: str, role: str, rig: str) -> UnknownNameError:
    """UnknownNameError for a missing role, listing candidate joints."""
    words = _ROLE_WORDS.get(role, (role,))
    joints = [n for n in names if not n.endswith("_end")]
    cands = [n for n in joints if any(w in _bare(n) for w in words)
             and (side not in SIDES or _name_side(n) in (side, None))]
    if cands:
        listed = ", ".join(cands[:12]) + (f" (+{len(cands) - 12} more)" if len(cands) > 12 else "")
        what = f"candidates: {listed}"
    else:
        listed = ", ".join(joints[:12]) + (f" (+{len(joints) - 12} more)" if len(joints) > 12 else "")
        what = f"joints: {listed}"
    who = f"{side} {role}" if side in SIDES else role
    return UnknownNameError(f"rig: no {who} recognised (rig '{rig}'); {what}; name the rig with "
                            "--body-map/--hand-map or give a TOML map (docs/splice_rigs.md)")
