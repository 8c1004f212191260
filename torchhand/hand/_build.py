"""The stages of :func:`torchhand.hand.model.build_hand_model` that turn plain specs into index tables: the tree
(parents, depths, which joints move which link), the kinematic :class:`~torchhand.kernels.kinematics.Chain`, joint
limits and rest pose, and the finger tables with the finger-finger collision pairs.

Inputs are the specs of :mod:`torchhand.hand._specs` (float64 NumPy); tensors come out on the CPU. Conventions:
metres, radians, column-vector 4x4 transforms (see :mod:`torchhand.conventions`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from torchhand.kernels.kinematics import JOINT_HINGE, JOINT_SLIDE, Chain

from ..errors import InputValueError, UnknownNameError
from ._specs import FingerSpec, JointSpec, LinkSpec

__all__ = ["TreeTables", "FingerTables", "as_tensor", "tree_tables", "kinematic_chain", "limits_and_rest",
           "finger_tables", "unit"]


def as_tensor(a, dtype: torch.dtype) -> torch.Tensor:
    """``a`` (array-like) as a CPU tensor of ``dtype``."""
    return torch.as_tensor(np.asarray(a), dtype=dtype)


@dataclass(frozen=True)
class TreeTables:
    """The kinematic tree of L links and D joints as index arrays (int64 unless stated).

    link_names (L,), joint_names (D,); lidx: link name -> index; parent (L,), -1 for the root; depth (L,), 0 at the
    root; joint_link (D,): the link each joint moves; per_link: per link, its joint indices in the order given;
    link_joints (L, J): the same padded with D; support (L, D) bool: joint d moves link l
    """

    link_names: tuple
    joint_names: tuple
    lidx: dict
    parent: np.ndarray
    depth: np.ndarray
    joint_link: np.ndarray
    per_link: list
    link_joints: np.ndarray
    support: np.ndarray


@dataclass(frozen=True)
class FingerTables:
    """Per-finger index tables (F fingers, L links, D joints; -1 where none).

    finger_links (F, 4): the finger's links, proximal first; link_finger (L,): the finger a link belongs to (its base
    links between the palm and the finger included); flexion (F, 3): the flexion joints of Eq. 11; pairs: (a, b)
    link pairs of different fingers checked for interpenetration, a < b
    """

    finger_links: np.ndarray
    link_finger: np.ndarray
    flexion: np.ndarray
    pairs: list


def tree_tables(name: str, links: list[LinkSpec], joints: list[JointSpec]) -> TreeTables:
    """Index tables of the tree; raises InputValueError (duplicate names, a parent not listed before its child, a
    second root) or UnknownNameError (a joint on an unknown link)."""
    link_names = tuple(l.name for l in links)
    if len(set(link_names)) != len(link_names):
        raise InputValueError(f"hand {name!r}: duplicate link names")
    joint_names = tuple(j.name for j in joints)
    if len(set(joint_names)) != len(joint_names):
        raise InputValueError(f"hand {name!r}: duplicate joint names")
    lidx = {n: i for i, n in enumerate(link_names)}
    L, D = len(links), len(joints)
    parent = np.full(L, -1, dtype=np.int64)
    for i, l in enumerate(links):
        if l.parent is None:
            if i != 0:
                raise InputValueError(f"hand {name!r}: only the first link may be the root, {l.name!r} has no parent")
            continue
        if l.parent not in lidx or lidx[l.parent] >= i:
            raise InputValueError(f"hand {name!r}: link {l.name!r} has parent {l.parent!r} that is not listed before it")
        parent[i] = lidx[l.parent]
    depth = np.zeros(L, dtype=np.int64)
    for i in range(1, L):
        depth[i] = depth[parent[i]] + 1

    joint_link = np.array([lidx[j.link] if j.link in lidx else -1 for j in joints], dtype=np.int64)
    if D and (joint_link < 0).any():
        bad = joints[int(np.argmin(joint_link))]
        raise UnknownNameError(f"joint {bad.name!r} refers to unknown link {bad.link!r}")
    per_link = [[d for d in range(D) if joint_link[d] == l] for l in range(L)]
    J = max([len(p) for p in per_link] + [1])
    link_joints = np.full((L, J), D, dtype=np.int64)
    for l, p in enumerate(per_link):
        link_joints[l, : len(p)] = p
    support = np.zeros((L, D), dtype=bool)
    for l in range(L):
        a = l
        while a >= 0:
            for d in per_link[a]:
                support[l, d] = True
            a = parent[a]
    return TreeTables(link_names, joint_names, lidx, parent, depth, joint_link, per_link, link_joints, support)


def kinematic_chain(tree: TreeTables, links: list[LinkSpec], joints: list[JointSpec], dtype: torch.dtype) -> Chain:
    """The kernels' :class:`Chain` of the tree (floating fields of ``dtype``); raises InputValueError for a zero or
    non-finite joint axis."""
    L, D = len(links), len(joints)
    per_link = tree.per_link
    J = tree.link_joints.shape[1]
    axes = np.array([unit(j.axis, f"joint {j.name} axis") for j in joints]).reshape(D, 3)
    jtype = np.array([JOINT_HINGE if j.type == "hinge" else JOINT_SLIDE for j in joints], dtype=np.int64)
    return Chain(
        link_parent=as_tensor(tree.parent, torch.long),
        link_offset=as_tensor(np.stack([l.offset for l in links]), dtype),
        link_joints=as_tensor(tree.link_joints, torch.long),
        joint_link=as_tensor(tree.joint_link, torch.long),
        joint_type=as_tensor(jtype, torch.long),
        joint_axis=as_tensor(axes, dtype),
        joint_anchor=as_tensor(np.array([j.anchor for j in joints]).reshape(D, 3), dtype),
        support=as_tensor(tree.support, torch.bool),
        levels=tuple(as_tensor(np.nonzero(tree.depth == k)[0], torch.long) for k in range(int(tree.depth.max()) + 1)),
        slot_links=tuple(as_tensor([l for l in range(L) if len(per_link[l]) > k], torch.long) for k in range(J)
                         if any(len(p) > k for p in per_link)),
        slot_joints=tuple(as_tensor([per_link[l][k] for l in range(L) if len(per_link[l]) > k], torch.long)
                          for k in range(J) if any(len(p) > k for p in per_link)),
        support_joints=as_tensor(_padded([np.nonzero(tree.support[l])[0] for l in range(L)]), torch.long),
    )


def limits_and_rest(name: str, joints: list[JointSpec], q_rest) -> tuple[np.ndarray, np.ndarray]:
    """Joint limits (D, 2) and the rest pose (D,): ``q_rest``, or zero clamped into the limits when None."""
    D = len(joints)
    limits = np.array([j.limits for j in joints], dtype=np.float64).reshape(D, 2)
    if (limits[:, 0] > limits[:, 1]).any():
        raise InputValueError(f"hand {name!r}: a joint's lower limit exceeds its upper limit")
    if q_rest is None:
        q_rest = np.clip(np.zeros(D), limits[:, 0], limits[:, 1])
    return limits, q_rest


def finger_tables(fingers: list[FingerSpec], tree: TreeTables, capsule_radius: np.ndarray) -> FingerTables:
    """Finger tables; raises InputValueError (a finger without 1 to 4 links) or UnknownNameError (a finger naming
    an unknown link or joint)."""
    finger_links, link_finger, flex = _finger_indices(fingers, tree)
    bases = _finger_bases(finger_links, link_finger, tree.parent)
    pairs = _finger_pairs(finger_links, link_finger, bases, capsule_radius)
    return FingerTables(finger_links, link_finger, flex, pairs)


def _finger_indices(fingers: list[FingerSpec], tree: TreeTables):
    """(finger_links (F, 4), link_finger (L,), flexion (F, 3)) from the finger specs, -1 where none."""
    F, L = len(fingers), len(tree.link_names)
    lidx = tree.lidx
    finger_links = np.full((F, 4), -1, dtype=np.int64)
    link_finger = np.full(L, -1, dtype=np.int64)
    flex = np.full((F, 3), -1, dtype=np.int64)
    jidx = {n: i for i, n in enumerate(tree.joint_names)}
    for f, spec in enumerate(fingers):
        if not 1 <= len(spec.links) <= 4:
            raise InputValueError(f"finger {spec.name!r}: expected 1 to 4 links, got {len(spec.links)}")
        for k, ln in enumerate(spec.links):
            if ln not in lidx:
                raise UnknownNameError(f"finger {spec.name!r} refers to unknown link {ln!r}")
            finger_links[f, k] = lidx[ln]
            link_finger[lidx[ln]] = f
        for k, jn in enumerate(spec.flexion_joints[:3]):
            if jn not in jidx:
                raise UnknownNameError(f"finger {spec.name!r} refers to unknown joint {jn!r}")
            flex[f, k] = jidx[jn]
    return finger_links, link_finger, flex


def _finger_bases(finger_links: np.ndarray, link_finger: np.ndarray, parent: np.ndarray) -> set:
    """Links between the palm and a finger's first link (a robot finger's base: Allegro's ff_base, Shadow's thbase
    and lfmetacarpal) are that finger's: their joints move it. Not in finger_links, not in finger-finger pairs.
    Marks them in ``link_finger`` (in place) and returns them."""
    F = len(finger_links)
    bases = set()
    first = {f: int(finger_links[f, 0]) for f in range(F)}
    ancestors = {f: set() for f in range(F)}
    for f, l0 in first.items():
        a = int(parent[l0])
        while a >= 0:
            ancestors[f].add(a)
            a = int(parent[a])
    for f in range(F):
        for a in ancestors[f]:
            if link_finger[a] < 0 and not any(a in ancestors[g] for g in range(F) if g != f):
                link_finger[a] = f
                bases.add(a)
    return bases


def _finger_pairs(finger_links: np.ndarray, link_finger: np.ndarray, bases: set, capsule_radius: np.ndarray) -> list:
    """Finger-finger pairs (a, b), a < b: links of different fingers with capsules, excluding finger bases and the
    first (palm-level) link of a 4-link finger, which lies inside the palm next to its neighbours by construction."""
    L = len(link_finger)
    pairs = []
    for a in range(L):
        for b in range(a + 1, L):
            if a in bases or b in bases:
                continue
            fa, fb = link_finger[a], link_finger[b]
            if fa >= 0 and fb >= 0 and fa != fb and capsule_radius[a] > 0 and capsule_radius[b] > 0:
                if _palm_level(a, fa, finger_links) or _palm_level(b, fb, finger_links):
                    continue
                pairs.append((a, b))
    return pairs


def _padded(rows: list[np.ndarray]) -> np.ndarray:
    """Stack index rows of different lengths into (len(rows), max(1, longest)), padded with -1."""
    width = max([len(r) for r in rows] + [1])
    out = np.full((len(rows), width), -1, dtype=np.int64)
    for i, r in enumerate(rows):
        out[i, : len(r)] = r
    return out


def _palm_level(link: int, finger: int, finger_links: np.ndarray) -> bool:
    row = finger_links[finger]
    return int((row >= 0).sum()) == 4 and row[0] == link


def unit(v, what: str) -> np.ndarray:
    """``v`` (3,) normalised; raises InputValueError for a zero or non-finite vector, naming ``what``."""
    v = np.asarray(v, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(v))
    if not math.isfinite(n) or n < 1e-12:
        raise InputValueError(f"{what}: expected a non-zero finite vector, got {v.tolist()}")
    return v / n
