"""Rig map files (TOML, ``docs/splice_rigs.md``): ``[right]``/``[left]`` tables of role = "joint name" over the
automatic recognition (``auto = true``, the default) or instead of it."""

from __future__ import annotations

import difflib
import tomllib
from dataclasses import replace
from pathlib import Path

from ..errors import FileFormatError, MissingFileError, UnknownNameError
from ..scene.bvh import BVHClip
from ._rig_auto import _auto, _finish, _make_arm
from ._rig_namings import _NAMINGS
from ._rig_record import _ARM_ROLES, SIDES, Arm, Rig
from .rig_hierarchy import FINGERS, _hierarchy_fingers, _trunk, rest_positions


_MAP_ROLES = set(_ARM_ROLES) | {f"{f}{o}" for f in FINGERS for o in range(4) if not (f == "thumb" and o == 0)} \
    | {f"{f}_tip" for f in FINGERS}


def _from_map(clip: BVHClip, path: Path, unsided: str) -> Rig:
    """The rig a map file gives: its roles over what recognition finds (``auto``), or its roles alone."""
    data = _read_map(path)
    auto = data.get("auto", True)
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
            arms[s] = _map_arm(clip, path, s, arms.get(s), given)
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


def _read_map(path: Path) -> dict:
    """The map's TOML document, its top-level keys checked."""
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
    return data


def _map_arm(clip: BVHClip, path: Path, side: str, old: Arm | None, given: dict[str, int]) -> Arm:
    """``side``'s arm from the map's arm roles ``given`` over the recognised arm ``old`` (None: none)."""
    roles = {r: getattr(old, r) for r in ("shoulder", "elbow", "wrist") if old and getattr(old, r) is not None}
    roles.update({r: j for r, j in given.items() if r in ("shoulder", "elbow", "wrist", "forearm")})
    if "wrist" not in roles:
        raise UnknownNameError(f"{path}: [{side}] gives arm joints but no wrist, and none was recognised in "
                               f"{clip.path}")
    arm = replace(_make_arm(clip, side, roles), **given)
    if "trunk" not in given and "shoulder" in given:
        arm = replace(arm, trunk=_trunk(clip, arm.shoulder))
    return arm


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
