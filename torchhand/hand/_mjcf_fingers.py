"""MJCF import heuristics: which bodies form fingers, their frames and tips, and the hand's side.

Used by :func:`torchhand.hand.mjcf.load_mjcf` when a file carries no torchhand ``<custom>`` annotations; the rules
are listed in the docstring of :mod:`torchhand.hand.mjcf`. All directions are taken at q = 0 in the distal link's
frame. Conventions: metres, radians, column-vector 4x4 transforms (see :mod:`torchhand.conventions`).
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ._specs import FingerSpec, GeomSpec

if TYPE_CHECKING:
    from ._mjcf_bodies import _Tree

_FLEX_PARALLEL_COS = math.cos(math.radians(25.0))


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


def _detect_fingers(tree: _Tree) -> tuple[list[FingerSpec], float]:
    L = len(tree.links)
    X = [np.eye(4)] * L  # link poses at q = 0 relative to the root
    children = [[] for _ in range(L)]
    for l in range(1, L):
        X[l] = X[tree.parent[l]] @ tree.links[l].offset
        children[tree.parent[l]].append(l)
    jlink = {d: l for l in range(L) for d in tree.link_joints[l]}
    fingers, length, used = [], 0.0, set()
    for leaf in range(1, L):
        if children[leaf]:
            continue
        chain = [leaf]
        while tree.parent[chain[-1]] > 0 and len(children[tree.parent[chain[-1]]]) < 2:
            chain.append(tree.parent[chain[-1]])
        chain.reverse()
        branch = tree.parent[chain[0]]
        hinges = [d for l in chain for d in tree.link_joints[l] if tree.joints[d].type == "hinge"]
        if len(hinges) < 2:
            continue
        links = [l for l in chain if tree.link_joints[l]] + ([] if tree.link_joints[leaf] else [leaf])
        links = links[-4:]
        Rl = X[leaf][:3, :3]

        def axis_leaf(d):
            return Rl.T @ X[jlink[d]][:3, :3] @ tree.joints[d].axis / np.linalg.norm(tree.joints[d].axis)

        a_last = axis_leaf(hinges[-1])
        flex = [d for d in hinges if abs(axis_leaf(d) @ a_last) > _FLEX_PARALLEL_COS][-3:]
        # Finger direction: from the nearest ancestor origin that differs from the leaf's.
        d_vec, anc = np.array([0.0, 0.0, 1.0]), tree.parent[leaf]
        while anc >= 0:
            v = X[leaf][:3, 3] - X[anc][:3, 3]
            if np.linalg.norm(v) > 1e-6:
                d_vec = Rl.T @ v / np.linalg.norm(v)
                break
            anc = tree.parent[anc]
        # Tip: support point of the distal geometry (or of the nearest finger link with geometry).
        tip = np.zeros(3)
        for l in reversed(links):
            gs = [g for g in tree.geoms if g.link == tree.links[l].name]
            if gs:
                Tl = np.linalg.inv(X[leaf]) @ X[l]
                moved = [GeomSpec(g.link, g.type, g.size, Tl @ g.pose, g.mesh) for g in gs]
                tip = max((_support(g, d_vec) for g in moved), key=lambda sp: sp[0])[1]
                break
        lo, hi = tree.joints[flex[-1]].limits
        nail = np.cross(d_vec, axis_leaf(flex[-1])) * (1.0 if hi + lo >= 0 else -1.0)
        nail = nail - d_vec * (nail @ d_vec)
        if np.linalg.norm(nail) < 1e-9:  # flexion axis along the finger: any perpendicular
            nail = np.cross(d_vec, [1.0, 0.0, 0.0] if abs(d_vec[0]) < 0.9 else [0.0, 1.0, 0.0])
        names = [tree.links[l].name for l in links]
        prefix = os.path.commonprefix(names)
        fname = re.sub(r"^(rh|lh|right|left)_", "", prefix).strip("_")
        if not fname or fname in used:
            fname = tree.links[leaf].name
        used.add(fname)
        fingers.append(FingerSpec(fname, tuple(names), nail / np.linalg.norm(nail), tip,
                                  tuple(tree.joints[d].name for d in flex)))
        tip_root = X[leaf][:3, :3] @ tip + X[leaf][:3, 3]
        length = max(length, float(np.linalg.norm(tip_root - X[branch][:3, 3])))
    return fingers, length


def _detect_side(path: Path, model: str, links: list) -> str:
    for text in (path.stem, model):
        m = re.search(r"(?:^|[^a-z])(right|left)(?:[^a-z]|$)", text.lower())
        if m:
            return m.group(1)
    prefixes = {l.name[:3].lower() for l in links}
    if "rh_" in prefixes and "lh_" not in prefixes:
        return "right"
    if "lh_" in prefixes and "rh_" not in prefixes:
        return "left"
    return "none"
