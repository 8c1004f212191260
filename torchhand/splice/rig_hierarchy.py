"""Geometry and hierarchy helpers of rig recognition (:mod:`torchhand.splice.rigs`): rest positions, chains below a
wrist, the fallback that orders five finger chains thumb..pinky by their geometry, and a hand's chirality."""

from __future__ import annotations

import numpy as np

from ..scene.bvh import BVHClip

FINGERS = ("thumb", "index", "middle", "ring", "pinky")
"""Finger names, thumb to pinky."""
_TIP = 9          # ordinal marking a tip joint in the naming tables (a chain joint without a role)



def rest_positions(clip: BVHClip, handedness: str = "right") -> np.ndarray:
    """Joint positions with every channel zero, from the OFFSETs alone (position channels ignored), (J, 3), file
    units; a left-handed file is mirrored (x negated)."""
    pos = np.zeros((clip.num_joints, 3))
    for j, p in enumerate(clip.parents):
        pos[j] = clip.offsets[j] + (pos[p] if p >= 0 else 0.0)
    if handedness == "left":
        pos = pos * np.array([-1.0, 1.0, 1.0])
    return pos


def _children(parents, j: int) -> list[int]:
    return [i for i, p in enumerate(parents) if p == j]


def _joint_children(clip: BVHClip, j: int) -> list[int]:
    return [i for i in _children(clip.parents, j) if not clip.is_end_site[i]]


def _ancestors(parents, j: int) -> list[int]:
    out, k = [], parents[j]
    while k >= 0:
        out.append(k)
        k = parents[k]
    return out


def _is_below(parents, j: int, ancestor: int) -> bool:
    return ancestor in _ancestors(parents, j)


def _tip(clip: BVHClip, j: int) -> int:
    """Follow an unbranched chain down from ``j``; its End Site, or its last joint."""
    while True:
        kids = _joint_children(clip, j)
        if len(kids) != 1:
            break
        j = kids[0]
    ends = [i for i in _children(clip.parents, j) if clip.is_end_site[i]]
    return ends[0] if ends and not _joint_children(clip, j) else j


def _trunk(clip: BVHClip, shoulder: int | None) -> int | None:
    """The first joint above the shoulder's parent with two or more child joints (module docstring)."""
    if shoulder is None or clip.parents[shoulder] < 0:
        return None
    k = clip.parents[shoulder]
    while len(_joint_children(clip, k)) < 2 and clip.parents[k] >= 0:
        k = clip.parents[k]
    return k


def _chain(clip: BVHClip, start: int) -> list[int] | None:
    """The unbranched joint chain from ``start`` (End Sites excluded), or None if it branches."""
    out = [start]
    while True:
        kids = _joint_children(clip, out[-1])
        if not kids:
            return out
        if len(kids) > 1:
            return None
        out.append(kids[0])


def _finger_chains(clip: BVHClip, wrist: int) -> list[list[int]] | None:
    """Five unbranched chains of 2-5 joints below ``wrist`` (directly or through one palm joint), or None."""
    for base in [wrist] + _joint_children(clip, wrist)[:1]:
        if base != wrist and len(_joint_children(clip, wrist)) != 1:
            break
        chains = [c for c in (_chain(clip, k) for k in _joint_children(clip, base)) if c and 2 <= len(c) <= 5]
        if len(chains) == 5:
            return chains
    return None


def _order_chains(rest: np.ndarray, wrist: int, chains: list[list[int]]) -> list[list[int]]:
    """Thumb .. pinky (module docstring: hierarchy fallback)."""
    w = rest[wrist]
    ends = np.stack([rest[c[-1]] for c in chains])
    means = np.stack([rest[c].mean(0) for c in chains])
    x = _unit(ends.mean(0) - w)
    thumb = int(np.argmin((means - w) @ x))
    others = [i for i in range(5) if i != thumb]
    t = rest[chains[thumb][0]] - means[others].mean(0)
    t = t - x * float(x @ t)
    others.sort(key=lambda i: -float(means[i] @ t))
    return [chains[thumb]] + [chains[i] for i in others]


def _chain_roles(rest: np.ndarray, wrist: int, chain: list[int], thumb: bool, tip_joints: bool = False
                 ) -> dict[int, int]:
    """Ordinal per chain joint (ordinal _TIP: tip joint; joints left out: unassigned). ``tip_joints``: whether the
    other fingers end in tip joints (decides a four-joint thumb)."""
    n = len(chain)
    if thumb:
        if n == 4 and tip_joints:
            return {chain[0]: 1, chain[1]: 2, chain[2]: 3, chain[3]: _TIP}
        return {j: o for j, o in zip(chain[-3:], range(4 - min(n, 3), 4))}
    d = lambda a, b: float(np.linalg.norm(rest[a] - rest[b]))     # noqa: E731
    if n == 4 and d(wrist, chain[0]) < 0.5 * d(wrist, chain[1]):
        return {chain[0]: 0, chain[1]: 1, chain[2]: 2, chain[3]: 3}
    if n == 4:
        return {chain[0]: 1, chain[1]: 2, chain[2]: 3, chain[3]: _TIP}
    if n <= 3:
        return {j: o for j, o in zip(chain, range(1, 4))}
    return {j: o for j, o in zip(chain[-4:], range(0, 4))}


def _hierarchy_fingers(clip: BVHClip, rest: np.ndarray, wrist: int) -> dict[tuple[str, int], int] | None:
    chains = _finger_chains(clip, wrist)
    if chains is None:
        return None
    ordered = _order_chains(rest, wrist, chains)
    out = {}
    for finger, chain in zip(FINGERS[1:], ordered[1:]):
        for j, o in _chain_roles(rest, wrist, chain, False).items():
            out[(finger, o)] = j
    tip_joints = any(o == _TIP for _, o in out)
    for j, o in _chain_roles(rest, wrist, ordered[0], True, tip_joints).items():
        out[("thumb", o)] = j
    return out


def _chirality(rest: np.ndarray, wrist: int, fingers: dict[tuple[str, int], int], tips: dict[str, int]
               ) -> str | None:
    """"right"/"left" from the hand's shape in the file's coordinates, or None when undecided."""
    knuckle = {f: fingers.get((f, 1), fingers.get((f, 2))) for f in FINGERS}
    if any(knuckle[f] is None for f in ("index", "middle", "pinky")):
        return None
    w = rest[wrist]
    x = _unit(rest[knuckle["middle"]] - w)
    t = rest[knuckle["index"]] - rest[knuckle["pinky"]]
    n = np.cross(x, t - x * float(x @ t))
    if np.linalg.norm(n) < 1e-12:
        return None
    n = _unit(n)
    pts = [rest[j] - w for j in tips.values()]
    pts += [rest[j] - w for (f, _), j in fingers.items() if f == "thumb"]
    evidence = float(np.mean([p @ n for p in pts]))
    length = max(float(np.linalg.norm(p)) for p in pts)
    if abs(evidence) < 0.03 * length:
        return None
    return "right" if evidence < 0 else "left"


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v / n if n > 0 else v
