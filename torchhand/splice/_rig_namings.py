"""The rig namings :func:`torchhand.splice.rigs.detect_rig` knows (table in ``docs/splice_rigs.md``): whole-name
regular expressions per naming (:class:`_Naming`, :data:`_NAMINGS`), and the matchers that find one naming's arm
roles and finger joints in a clip."""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from ..scene.bvh import BVHClip
from ._rig_record import _bare
from .rig_hierarchy import _TIP


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
