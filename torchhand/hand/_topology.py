"""Fingers by topology: the palm, the fingers, the thumb and the side of a hand's body tree, names not needed.

Taken at q = 0 (MuJoCo's reference pose), in the root link's frame:

* **palm**: walking down from the root along the child with the most hinge joints below it, the first body where
  three or more chains carrying at least two hinges each branch. Bodies above it (an arm, a wrist) are not part of
  any finger.
* **fingers**: one per such chain. Its leaf is the one reached with the most hinges (ties: the farthest from the
  palm); its links are the chain's bodies that have joints, then the last body with geometry after them (a
  fingertip link on a fixed joint), the last four kept; the distal link is the last. A tree without a palm (fewer
  than three chains) falls back to every leaf chain with two hinges below its nearest branching body.
* **flexion joints**: the (up to three most distal) hinges of the chain parallel within 25 degrees to its last
  hinge; flexion is positive when the last one's range lies mostly above zero.
* **tip and nail**: finger direction ``d`` from the nearest ancestor origin that differs from the distal link's
  origin; the tip is the support point of the finger's most distal geometry along ``d``; the nail normal is
  ``d x a`` (``a`` the last flexion axis), signed away from the side the finger flexes to.
* **thumb**: the finger that opposes the others: the largest mean angle between its last flexion axis and the other
  fingers' (axes compared without sign), ties broken by the base farthest from the plane of the other bases. It is
  named ``thumb`` unless its name already reads as one (``th``..., ``thumb``), and another finger whose name reads
  as a thumb is renamed ``finger<k>``, so that :func:`torchhand.hand.mount.thumb_index` finds it.
* **side**: with ``x`` from the other fingers' mean base to their mean tip and ``z`` the back of the hand (against
  the direction their tips move when they flex), a right hand has its thumb's base on ``+y = z × x``.
* **names**: the common prefix of a finger's link names without a side prefix (``rh_ff...`` -> ``ff``) and trailing
  digits; else (empty or shared) the leaf's name.
* **length**: the largest distance at q = 0 from the palm to a tip.

Conventions: metres, radians, column-vector 4x4 transforms (see :mod:`torchhand.conventions`).
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass

import numpy as np

from ._specs import FingerSpec, GeomSpec

__all__ = ["Topology", "find_fingers", "THUMB_NAME_RE"]

_FLEX_PARALLEL_COS = math.cos(math.radians(25.0))
THUMB_NAME_RE = re.compile(r"^(th|thumb)", re.IGNORECASE)
"""A finger name that reads as a thumb (the rule :func:`torchhand.hand.mount.thumb_index` applies)."""


@dataclass(frozen=True)
class Topology:
    """What the tree says: fingers (FingerSpecs), length (metres), palm (link index, -1 without one), thumb (finger
    index, -1 when not found), side ("right" | "left" | "none")."""

    fingers: tuple
    length: float
    palm: int
    thumb: int
    side: str


@dataclass(frozen=True)
class _Finger:
    chain: tuple  # link indices palm child .. leaf
    links: tuple  # finger links, proximal -> distal (at most 4)
    hinges: tuple  # hinge joint indices along the chain
    branch: int  # the link the chain hangs from


def find_fingers(tree) -> Topology:
    """The :class:`Topology` of a :class:`~torchhand.hand._compiled_read.CompiledTree` (module docstring)."""
    X, children = _poses(tree)
    palm = _palm(tree, children)
    raw = _palm_fingers(tree, children, palm) if palm >= 0 else _leaf_fingers(tree, children)
    specs, tips, axes, bases, dirs = [], [], [], [], []
    for f in raw:
        spec, tip_root, axis_root, d_root = _annotate(tree, X, f)
        specs.append(spec)
        tips.append(tip_root)
        axes.append(axis_root)
        bases.append(X[f.chain[0]][:3, 3])
        dirs.append(d_root)
    length = max((float(np.linalg.norm(t - X[f.branch][:3, 3])) for f, t in zip(raw, tips)), default=0.0)
    thumb = _thumb(np.array(axes), np.array(bases)) if len(raw) >= 3 else -1
    side = _side(tree, X, raw, thumb, tips, bases) if thumb >= 0 else "none"
    return Topology(tuple(_names(tree, raw, specs, thumb)), length, palm, thumb, side)


def _poses(tree):
    L = len(tree.links)
    X = [np.eye(4)] * L
    children = [[] for _ in range(L)]
    for l in range(1, L):
        X[l] = X[tree.parent[l]] @ tree.links[l].offset
        children[tree.parent[l]].append(l)
    return X, children


def _hinges_below(tree, children, l: int) -> int:
    n = sum(1 for d in tree.link_joints[l] if tree.joints[d].type == "hinge")
    return n + sum(_hinges_below(tree, children, c) for c in children[l])


def _palm(tree, children) -> int:
    b = 0
    while True:
        counts = {c: _hinges_below(tree, children, c) for c in children[b]}
        if sum(1 for n in counts.values() if n >= 2) >= 3:
            return b
        if not counts or max(counts.values()) == 0:
            return -1
        b = max(counts, key=lambda c: (counts[c], -c))


def _finger_from_chain(tree, chain: list, branch: int) -> _Finger:
    geo = {g.link for g in tree.geoms}
    jointed = [l for l in chain if tree.link_joints[l]]
    after = [l for l in chain if chain.index(l) > chain.index(jointed[-1]) and tree.links[l].name in geo]
    links = (jointed + after[-1:])[-4:]
    hinges = tuple(d for l in chain for d in tree.link_joints[l] if tree.joints[d].type == "hinge")
    return _Finger(tuple(chain), tuple(links), hinges, branch)


def _palm_fingers(tree, children, palm: int) -> list[_Finger]:
    out = []
    for c in children[palm]:
        if _hinges_below(tree, children, c) < 2:
            continue
        best = None
        for chain in _chains(children, c):
            n = sum(1 for l in chain for d in tree.link_joints[l] if tree.joints[d].type == "hinge")
            key = (n, len(chain))
            if best is None or key > best[0]:
                best = (key, chain)
        out.append(_finger_from_chain(tree, best[1], palm))
    return out


def _chains(children, c: int) -> list[list[int]]:
    """Every path from ``c`` to a leaf of its subtree."""
    if not children[c]:
        return [[c]]
    return [[c] + rest for k in children[c] for rest in _chains(children, k)]


def _leaf_fingers(tree, children) -> list[_Finger]:
    out = []
    for leaf in range(1, len(tree.links)):
        if children[leaf]:
            continue
        chain = [leaf]
        while tree.parent[chain[-1]] > 0 and len(children[tree.parent[chain[-1]]]) < 2:
            chain.append(tree.parent[chain[-1]])
        chain.reverse()
        f = _finger_from_chain(tree, chain, tree.parent[chain[0]]) if any(tree.link_joints[l] for l in chain) else None
        if f is not None and len(f.hinges) >= 2:
            out.append(f)
    return out


def _annotate(tree, X, f: _Finger):
    """(FingerSpec with a provisional name, tip (root frame), last flexion axis (root frame), direction (root))."""
    distal = f.links[-1]
    Rl = X[distal][:3, :3]
    jlink = {d: l for l in range(len(tree.links)) for d in tree.link_joints[l]}

    def axis_distal(d):
        return Rl.T @ X[jlink[d]][:3, :3] @ tree.joints[d].axis / np.linalg.norm(tree.joints[d].axis)

    a_last = axis_distal(f.hinges[-1])
    flex = [d for d in f.hinges if abs(axis_distal(d) @ a_last) > _FLEX_PARALLEL_COS][-3:]
    d_vec, anc = np.array([0.0, 0.0, 1.0]), tree.parent[distal]
    while anc >= 0:
        v = X[distal][:3, 3] - X[anc][:3, 3]
        if np.linalg.norm(v) > 1e-6:
            d_vec = Rl.T @ v / np.linalg.norm(v)
            break
        anc = tree.parent[anc]
    tip = _tip(tree, X, f, distal, d_vec)
    lo, hi = tree.joints[flex[-1]].limits
    nail = np.cross(d_vec, axis_distal(flex[-1])) * (1.0 if hi + lo >= 0 else -1.0)
    nail = nail - d_vec * (nail @ d_vec)
    if np.linalg.norm(nail) < 1e-9:  # flexion axis along the finger: any perpendicular
        nail = np.cross(d_vec, [1.0, 0.0, 0.0] if abs(d_vec[0]) < 0.9 else [0.0, 1.0, 0.0])
    spec = FingerSpec("", tuple(tree.links[l].name for l in f.links), nail / np.linalg.norm(nail), tip,
                      tuple(tree.joints[d].name for d in flex))
    axis_root = Rl @ axis_distal(flex[-1]) * (1.0 if hi + lo >= 0 else -1.0)
    return spec, Rl @ tip + X[distal][:3, 3], axis_root, Rl @ d_vec


def _tip(tree, X, f: _Finger, distal: int, d_vec: np.ndarray) -> np.ndarray:
    """Support point along ``d_vec`` of the most distal finger link with geometry, in the distal link's frame."""
    for l in reversed(f.links):
        gs = [g for g in tree.geoms if g.link == tree.links[l].name]
        if gs:
            Tl = np.linalg.inv(X[distal]) @ X[l]
            moved = [GeomSpec(g.link, g.type, g.size, Tl @ g.pose, g.mesh) for g in gs]
            return max((_support(g, d_vec) for g in moved), key=lambda sp: sp[0])[1]
    return np.zeros(3)


def _support(g: GeomSpec, d: np.ndarray) -> tuple[float, np.ndarray]:
    """Support value and point (link frame) of geom ``g`` along unit ``d`` (link frame)."""
    R, t = g.pose[:3, :3], g.pose[:3, 3]
    dl = R.T @ d
    dl = np.where(np.abs(dl) < 1e-9, 0.0, dl)
    s = np.resize(np.asarray(g.size, dtype=np.float64), 3)
    if g.type == "mesh":
        V = g.mesh[0]
        k = np.flatnonzero(V @ dl >= (V @ dl).max() - 1e-12)
        p = V[k].mean(0)
    elif g.type == "sphere":
        p = s[0] * dl
    elif g.type == "capsule":
        p = np.array([0.0, 0.0, s[1] * np.sign(dl[2])]) + s[0] * dl
    elif g.type == "cylinder":
        rad = np.array([dl[0], dl[1], 0.0])
        n = np.linalg.norm(rad)
        p = (s[0] * rad / n if n > 0 else np.zeros(3)) + np.array([0.0, 0.0, s[1] * np.sign(dl[2])])
    else:  # box
        p = s * np.sign(dl)
    pw = R @ p + t
    return float(pw @ d), pw


def _thumb(axes: np.ndarray, bases: np.ndarray) -> int:
    """The finger whose flexion axis differs most from the others' (mean angle, sign ignored); ties (within 5
    degrees) go to the base farthest from the least-squares plane of the other bases."""
    F = len(axes)
    cos = np.clip(np.abs(axes @ axes.T), 0.0, 1.0)
    ang = np.degrees(np.arccos(cos))
    score = np.array([ang[f, [g for g in range(F) if g != f]].mean() for f in range(F)])

    def off_plane(f):
        others = bases[[g for g in range(F) if g != f]]
        c = others.mean(0)
        _, _, vt = np.linalg.svd(others - c)
        return abs(float((bases[f] - c) @ vt[-1])) if len(others) >= 3 else 0.0

    best = float(score.max())
    tied = [f for f in range(F) if score[f] >= best - 5.0]
    return max(tied, key=lambda f: (off_plane(f), score[f]))


def _side(tree, X, raw, thumb: int, tips, bases) -> str:
    longs = [f for f in range(len(raw)) if f != thumb]
    b = np.mean([bases[f] for f in longs], axis=0)
    x = np.mean([tips[f] for f in longs], axis=0) - b
    if np.linalg.norm(x) < 1e-9:
        return "none"
    x = x / np.linalg.norm(x)
    flex = np.zeros(3)  # direction the long fingertips move when they flex
    jlink = {d: l for l in range(len(tree.links)) for d in tree.link_joints[l]}
    for f in longs:
        for d in raw[f].hinges:
            j = tree.joints[d]
            T = X[jlink[d]]
            a, c = T[:3, :3] @ j.axis / np.linalg.norm(j.axis), T[:3, :3] @ j.anchor + T[:3, 3]
            flex += np.cross(a, tips[f] - c) * (1.0 if j.limits[0] + j.limits[1] >= 0 else -1.0)
    z = -(flex - (flex @ x) * x)
    if np.linalg.norm(z) < 1e-9:
        return "none"
    y = np.cross(z / np.linalg.norm(z), x)
    off = float((bases[thumb] - b) @ y)
    return "right" if off > 0 else "left" if off < 0 else "none"


def _names(tree, raw, specs, thumb: int) -> list[FingerSpec]:
    out = []
    for k, (base, s) in enumerate(zip(_base_names(tree, raw), specs)):
        name = base
        if k == thumb and not THUMB_NAME_RE.match(name):
            name = "thumb"
        elif (k != thumb and thumb >= 0 and THUMB_NAME_RE.match(name)) or not name:
            name = f"finger{k}"
        out.append(FingerSpec(name, s.links, s.nail_normal, s.tip, s.flexion_joints))
    return out


def _base_names(tree, raw) -> list[str]:
    """Per finger: the common prefix of its link names (side prefix and trailing digits dropped); where that is
    empty or shared, the leaf names with what all those leaves share at both ends removed ('' when nothing that
    starts with a letter is left)."""
    prefixes = []
    for f in raw:
        p = os.path.commonprefix([tree.links[l].name for l in f.links])
        p = re.sub(r"^(rh|lh|r|l|right|left)_", "", p, flags=re.IGNORECASE)
        prefixes.append(re.sub(r"[\W_\d]+$", "", p))
    bad = [k for k, p in enumerate(prefixes) if not p or prefixes.count(p) > 1]
    leaves = [tree.links[raw[k].chain[-1]].name for k in bad]
    if len(leaves) > 1:
        head = len(os.path.commonprefix(leaves))
        tail = len(os.path.commonprefix([n[::-1] for n in leaves]))
        leaves = [n[head:len(n) - tail] if len(n) > head + tail else n for n in leaves]
    for k, n in zip(bad, leaves):
        prefixes[k] = n if re.match(r"^[A-Za-z]", n) else ""
    return prefixes
