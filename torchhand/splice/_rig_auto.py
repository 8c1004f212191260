"""Automatic rig recognition (``rig="auto"`` or a naming's name): arms and fingers each by the naming that finds
the most roles, the hierarchy fallback where names say nothing, and the finished :class:`Rig` with each finger's
tip (rules in :mod:`torchhand.splice.rigs`)."""

from __future__ import annotations

import numpy as np

from ..errors import UnknownNameError
from ..scene.bvh import BVHClip
from ._rig_namings import _match_arms, _match_fingers
from ._rig_record import Arm, Rig
from .rig_hierarchy import (_TIP, FINGERS, _ancestors, _chirality, _hierarchy_fingers, _is_below, _joint_children,
                            _tip, _trunk, rest_positions)


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
