"""The record of a recognised rig (:class:`Arm`, :class:`Rig`; roles and ordinals in
:mod:`torchhand.splice.rigs`), and what recognition, maps and retargeting share about roles: the sides, the arm
roles, a joint name's side marker, and the error that lists candidate joints for a missing role."""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from ..errors import InputValueError, UnknownNameError
from .rig_hierarchy import FINGERS

SIDES = ("right", "left")

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


def _bare(name: str) -> str:
    """A joint name without namespace (``mixamorig:RightHand`` -> ``righthand``), lower case."""
    return name.rsplit(":", 1)[-1].lower()


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
