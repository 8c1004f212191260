"""Contact figures over every frame: where the contact points are, and whether the forces lie in their cones.

* contact-object gap: the exact distance of each hand contact point to the object's surface (trimesh's closest
  point), metres.
* contact-hand gap: ``|d - r|``, the distance of the point to the axis of its link's capsule (the link named by
  ``contact_link`` / ``contact_link_name``) minus the radius, metres.
* cone violation: ``max(|f_t| - mu f_n, -f_n)`` with the SCENE's friction (``scene.friction``, the solution's own
  ``friction`` and ``contact_normal`` are not used) about the mesh's inward normal at the closest surface point.
  Where that point lies within :data:`EDGE_TOL` of a triangle's edge or vertex (a box's edge, a corner), every
  face within that distance takes part, and any convex combination of their normals counts: the violation is its
  minimum over that normal cone. It is attained at the direction of the cone closest to the force (the Euclidean
  projection of the force onto the cone, by non-negative least squares), since the violation only grows with the
  angle between force and normal up to 90 deg + atan(mu); a force at more than 90 deg from every normal of the
  cone (pulling) is measured at the cone's generators, which can only overstate it. Table forces use the table's
  friction (``scene.environment.friction``) about +z. Both are divided by the frame's largest force, hand and
  table together (at least 1e-6 of the object's weight, so that a frame without forces cannot divide by zero).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import nnls

from ..errors import FileFormatError
from .geometry import ObjectMesh, point_segment_distance, rigid_inverse
from .penetration import PosedHand

__all__ = ["EDGE_TOL", "contact_slots", "contact_gaps", "cone_violations", "violation"]

EDGE_TOL = 5e-4
"""A contact's closest surface point within this distance of other faces takes their normals too, metres."""


def violation(f: np.ndarray, n: np.ndarray, mu: float) -> np.ndarray:
    """``max(|f_t| - mu f_n, -f_n)`` of forces f about unit normals n, (..., 3) -> (...,), newtons."""
    fn = np.einsum("...i,...i->...", f, n)
    ft = np.linalg.norm(f - fn[..., None] * n, axis=-1)
    return np.maximum(ft - mu * fn, -fn)


def cone_violation(f: np.ndarray, normals: np.ndarray, mu: float) -> float:
    """The smallest :func:`violation` of one force f (3,) over the cone of unit ``normals`` (m, 3), newtons."""
    if len(normals) == 1:
        return float(violation(f, normals[0], mu))
    cands = [normals]
    lam, _ = nnls(normals.T, f)
    x = normals.T @ lam
    if np.linalg.norm(x) > 1e-12 * max(np.linalg.norm(f), 1e-300):
        cands.append((x / np.linalg.norm(x))[None])
    return float(violation(f[None], np.concatenate(cands), mu).min())


def contact_slots(hands: dict[str, PosedHand], names: tuple, link: np.ndarray, mask: np.ndarray, path) -> tuple:
    """Hand and link of every active contact.

    hands: side -> PosedHand, in the scene's hand order; names: ``contact_link_name``; link, mask: (T, K)
    returns: frame (N,), slot (N,), side per contact (list of str), link index per contact (N,) long
    Raises FileFormatError for an active slot whose link index or name does not resolve to a hand.xml link.
    """
    first = next(iter(hands))
    resolved = []
    for n in names:
        side, lname = n.split("/", 1) if "/" in n and n.split("/", 1)[0] in hands else (first, n)
        if lname not in hands[side].model.link_names:
            resolved.append(None)
        else:
            resolved.append((side, hands[side].model.link_names.index(lname)))
    t_idx, k_idx = np.nonzero(mask)
    li = link[t_idx, k_idx]
    bad = (li < 0) | (li >= len(names))
    if bad.any():
        i = int(np.argmax(bad))
        raise FileFormatError(f"{path}: contact_link[{t_idx[i]}, {k_idx[i]}] = {li[i]} is not an index into "
                              f"contact_link_name ({len(names)} names) for an active contact")
    sides, links = [], np.zeros(len(li), dtype=np.int64)
    for j, v in enumerate(li):
        r = resolved[int(v)]
        if r is None:
            raise FileFormatError(f"{path}: contact_link_name {names[int(v)]!r} is not a link of the hand.xml "
                                  f"hands ({', '.join(hands)})")
        sides.append(r[0])
        links[j] = r[1]
    return t_idx, k_idx, sides, links


def contact_gaps(hands: dict[str, PosedHand], slots: tuple, points: np.ndarray, obj: ObjectMesh,
                 object_pose: np.ndarray):
    """Object and hand gaps of every contact, and its closest surface point.

    points: contact_point, (T, K, 3) world
    returns: object gap (T, K), hand gap (T, K) (NaN in inactive slots), metres; closest surface points (N, 3)
        object frame, and their triangles (N,)
    """
    t_idx, k_idx, sides, links = slots
    T, K = points.shape[:2]
    gap_obj, gap_hand = np.full((T, K), np.nan), np.full((T, K), np.nan)
    if len(t_idx) == 0:
        return gap_obj, gap_hand, np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    p = points[t_idx, k_idx]
    inv = rigid_inverse(object_pose[t_idx])
    local = np.einsum("nij,nj->ni", inv[:, :3, :3], p) + inv[:, :3, 3]
    closest, dist, tri = obj.closest(local)
    gap_obj[t_idx, k_idx] = dist
    for side, hand in hands.items():
        sel = np.array([s == side for s in sides], dtype=bool)
        if not sel.any():
            continue
        t, li = t_idx[sel], links[sel]
        d = point_segment_distance(p[sel], hand.a[t, li], hand.b[t, li])
        gap_hand[t_idx[sel], k_idx[sel]] = np.abs(d - hand.radius[li])
    return gap_obj, gap_hand, closest, tri


def cone_violations(slots: tuple, forces: np.ndarray, closest: np.ndarray, tri: np.ndarray, obj: ObjectMesh,
                    object_pose: np.ndarray, mu: float, env_mask: np.ndarray, env_forces: np.ndarray,
                    env_mu: float, floor: float):
    """Relative cone violations of hand and table forces.

    forces: contact_force (T, K, 3); env_mask (T, E), env_forces (T, E, 3), newtons; floor: smallest force scale
    returns: hand (T, K), table (T, E), NaN in inactive slots
    """
    t_idx, k_idx = slots[0], slots[1]
    T, K = forces.shape[:2]
    hand_scale = np.where(_active(forces, t_idx, k_idx), np.linalg.norm(forces, axis=-1), 0.0)
    env_norm = np.where(env_mask, np.linalg.norm(env_forces, axis=-1), 0.0)
    scale = np.maximum(np.maximum(hand_scale.max(axis=1, initial=0.0), env_norm.max(axis=1, initial=0.0)), floor)
    hand = np.full((T, K), np.nan)
    if len(t_idx):
        cones = obj.normal_cone(closest, tri, EDGE_TOL)
        R = object_pose[t_idx, :3, :3]
        for j, normals in enumerate(cones):
            n_world = normals @ R[j].T
            hand[t_idx[j], k_idx[j]] = cone_violation(forces[t_idx[j], k_idx[j]], n_world, mu)
        hand /= scale[:, None]
    up = np.array([0.0, 0.0, 1.0])
    table = np.where(env_mask, violation(env_forces, up, env_mu) / scale[:, None], np.nan)
    return hand, table


def _active(forces: np.ndarray, t_idx: np.ndarray, k_idx: np.ndarray) -> np.ndarray:
    m = np.zeros(forces.shape[:2], dtype=bool)
    m[t_idx, k_idx] = True
    return m
