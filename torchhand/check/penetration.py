"""Penetration figures over every frame: hand in object, hand under the table, hand in hand, finger in finger.

The hand's geometry is the collision capsules of the result's ``hand.xml`` (``HandModel.from_mjcf``:
``capsule_a``, ``capsule_b``, ``capsule_radius`` per link), posed by forward kinematics from the solution's ``q``
and ``root_pose``. A hand written by torchhand has exactly one capsule geom per link, so these ARE the written
geometry, and the hand's surface samples (``sample_points``) lie on their surfaces: the capsule depths are the
exact maxima of what the samples measure at their density. A link with other geometry (box, mesh, several geoms)
has a fitted capsule instead, which :func:`capsule_notes` reports.

Depths are positive inside, metres:

* object: ``radius + sd(p)`` maximised over points ``p`` on the capsule axis at most ``spacing`` (1 mm) apart, with
  ``sd`` trimesh's exact signed distance to the object mesh (positive inside, so an axis point inside counts its
  full depth plus the radius). Axis points farther than the radius outside the object's convex hull cannot touch
  and are skipped (their planes bound the distance from below).
* table: ``height - (lowest point of the capsule)``.
* hand-hand: ``r1 + r2 - d`` over every capsule pair of the two hands, ``d`` the exact segment distance.
* finger-finger: the same over capsule pairs of different fingers of one hand. The first link of a four-link finger
  (its metacarpal) lies inside the palm beside its neighbours by construction and is not paired; links of one
  finger (adjacent or not) are not pairs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..errors import FileFormatError
from ..hand import HandModel
from ..hand.model import GEOM_TYPES
from .geometry import ObjectMesh, axis_points, rigid_inverse, segment_segment_distance

__all__ = ["PosedHand", "pose_hand", "capsule_notes", "object_depth", "table_depth", "hand_hand_depth",
           "finger_pairs", "finger_depth"]

AXIS_SPACING = 1e-3
"""Largest distance between consecutive axis points of a capsule in the object test, metres."""


@dataclass(frozen=True, eq=False)
class PosedHand:
    """One hand's capsules over a solution's frames.

    side: "right" | "left"; model: the hand.xml model
    q: joint angles in ``model.joint_names`` order, (T, D), radians
    link_pose: ``T_world_link``, (T, L, 4, 4); a, b: world capsule axis ends, (T, L, 3), metres
    radius: capsule radii, (L,), metres (0: a link without geometry, never checked)
    """

    side: str
    model: HandModel
    q: np.ndarray
    link_pose: np.ndarray
    a: np.ndarray
    b: np.ndarray
    radius: np.ndarray

    def link(self, index: int) -> str:
        """``"side/link"`` name of a link."""
        return f"{self.side}/{self.model.link_names[index]}"

    def joint(self, index: int) -> str:
        return f"{self.side}/{self.model.joint_names[index]}"


def pose_hand(model: HandModel, side: str, q: np.ndarray, joint_names, root_pose: np.ndarray, path) -> PosedHand:
    """Forward kinematics of one hand of a solution (float64).

    q: (T, D) radians in ``joint_names`` order; root_pose: (T, 4, 4) world; path: the solution file, for errors
    Raises FileFormatError when the solution's joints are not the hand model's.
    """
    names = tuple(str(n) for n in joint_names)
    if set(names) != set(model.joint_names) or len(names) != len(model.joint_names):
        missing = sorted(set(model.joint_names) - set(names))
        extra = sorted(set(names) - set(model.joint_names))
        raise FileFormatError(f"{path}: the {side} hand's joint_names do not match its hand.xml "
                              f"(missing {missing[:5]}, unknown {extra[:5]})")
    order = np.array([names.index(n) for n in model.joint_names], dtype=np.int64)
    qm = np.ascontiguousarray(np.asarray(q, dtype=np.float64)[:, order])
    m = model.to(dtype=torch.float64)
    with torch.no_grad():
        poses = m.forward_kinematics(torch.from_numpy(qm), torch.from_numpy(np.asarray(root_pose, np.float64)))
    poses = poses.numpy()
    ca, cb = m.capsule_a.numpy(), m.capsule_b.numpy()
    R, p = poses[..., :3, :3], poses[..., :3, 3]
    a = np.einsum("tlij,lj->tli", R, ca) + p
    b = np.einsum("tlij,lj->tli", R, cb) + p
    return PosedHand(side=side, model=model, q=qm, link_pose=poses, a=a, b=b,
                     radius=m.capsule_radius.numpy().astype(np.float64))


def capsule_notes(model: HandModel, side: str) -> list[str]:
    """Remarks for links whose geometry is not exactly one capsule (their capsules are fitted enclosures)."""
    link = model.geoms.link.numpy()
    kind = model.geoms.type.numpy()
    odd = [model.link_names[li] for li in range(model.num_links)
           if (link == li).sum() > 1 or ((link == li).sum() == 1 and GEOM_TYPES[int(kind[link == li][0])]
                                         != "capsule")]
    if not odd:
        return []
    return [f"{side} hand: links {', '.join(odd)} have geometry other than one capsule; the checks use capsules "
            f"fitted to it"]


def object_depth(hand: PosedHand, obj: ObjectMesh, object_pose: np.ndarray,
                 spacing: float = AXIS_SPACING) -> np.ndarray:
    """Depth of each capsule in the object, (T, L), metres; NaN where no axis point can touch the object.

    A positive depth is exact up to the axis spacing (at most ``spacing / 2`` short, the signed distance being
    1-Lipschitz); a negative one is the clearance of the axis points that were measured, not of the capsule.
    """
    T, L = hand.a.shape[:2]
    out = np.full((T, L), np.nan)
    links = np.nonzero(hand.radius > 0)[0]
    if len(links) == 0:
        return out
    frac, owner = axis_points(hand.a[0, links], hand.b[0, links], spacing)           # rigid: any frame's lengths
    owner = links[owner]
    pts = hand.a[:, owner] + frac[None, :, None] * (hand.b[:, owner] - hand.a[:, owner])     # (T, P, 3) world
    inv = rigid_inverse(object_pose)
    local = np.einsum("tij,tpj->tpi", inv[:, :3, :3], pts) + inv[:, None, :3, 3]
    r = hand.radius[owner]
    bound = obj.hull_distance_bound(local.reshape(-1, 3)).reshape(T, -1)
    t_idx, p_idx = np.nonzero(bound < r[None, :])
    if len(t_idx) == 0:
        return out
    depth = r[p_idx] + obj.signed_distance(local[t_idx, p_idx])
    flat = np.full(T * L, -np.inf)
    np.maximum.at(flat, t_idx * L + owner[p_idx], depth)
    flat[np.isneginf(flat)] = np.nan
    return flat.reshape(T, L)


def table_depth(hand: PosedHand, height: float) -> np.ndarray:
    """Depth of each capsule under the plane z = height, (T, L), metres (negative: clearance); NaN: no geometry."""
    low = np.minimum(hand.a[..., 2], hand.b[..., 2]) - hand.radius
    return np.where(hand.radius > 0, height - low, np.nan)


def hand_hand_depth(h1: PosedHand, h2: PosedHand) -> np.ndarray:
    """Overlap of every capsule pair of two hands, (T, L1, L2), metres (negative: clearance); NaN: no geometry."""
    d = segment_segment_distance(h1.a[:, :, None], h1.b[:, :, None], h2.a[:, None], h2.b[:, None])
    depth = h1.radius[:, None] + h2.radius[None, :] - d
    valid = (h1.radius[:, None] > 0) & (h2.radius[None, :] > 0)
    return np.where(valid, depth, np.nan)


def finger_pairs(model: HandModel) -> np.ndarray:
    """Capsule pairs of different fingers of one hand, (Q, 2) link indices (see the module docstring)."""
    finger = model.link_finger.numpy()
    links = model.finger_links.numpy()
    radius = model.capsule_radius.numpy()
    palm_level = {int(row[0]) for row in links if (row >= 0).sum() == 4}
    cand = [li for li in range(model.num_links) if finger[li] >= 0 and radius[li] > 0 and li not in palm_level]
    pairs = [(a, b) for i, a in enumerate(cand) for b in cand[i + 1:] if finger[a] != finger[b]]
    return np.array(pairs, dtype=np.int64).reshape(-1, 2)


def finger_depth(hand: PosedHand, pairs: np.ndarray) -> np.ndarray:
    """Overlap of the capsule pairs of one hand, (T, Q), metres (negative: clearance)."""
    i, j = pairs[:, 0], pairs[:, 1]
    d = segment_segment_distance(hand.a[:, i], hand.b[:, i], hand.a[:, j], hand.b[:, j])
    return hand.radius[i] + hand.radius[j] - d
