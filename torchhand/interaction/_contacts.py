"""Contact slots of the quasi-static step (Kry & Pai 2006 §7.1, Stage 9 step 1 of docs' design note).

Slots are fixed per (link, counterpart): with L hand links, slots 0 .. L-1 pair each link with the object (when
there is one) and the next L slots pair each link with the fixed plane (when there is one); N = L or 2 L, plus the
object-plane slots below. A slot holds the link's deepest point against its counterpart and is active (``mask``)
when that point is closer than ``margin`` (5 mm by default, so that a link cannot pass through a surface in one
step unnoticed). Because a slot keeps its identity from step to step, the force f_i^k carries over to the new
contact point of the same slot (the paper's contact update).

- object: the deepest of the link's surface samples (``HandModel.sample_points``) in the object's signed distance
  grid; the normal is the grid's gradient there.
- plane: exact. ``geometry="samples"`` takes the deepest surface sample; ``geometry="capsules"`` takes the exact
  lowest point of the link's fitted capsule (``capsule_a``, ``capsule_b``, ``capsule_radius``; the middle of the
  segment when it lies parallel to the plane), which is the true contact point for capsule-shaped links.

Normals are stored as the paper's d_i0: the unit outward normal of the object or plane, the direction of the force
the counterpart exerts on the hand (torchhand's contact normal, into the object, is -d0).

Object-plane slots (an extension of the paper, whose environments were fixed or held): with an object, a plane and
the object's support points (:func:`support_points`: its convex hull vertices, clustered, object frame) P more
slots follow, one per support point, ``body = BODY_OBJECT_ENV`` and ``link = -1``. For them the "first body" is the
object: ``points`` is the support point in the world, ``d0`` the plane normal (the direction of the force of the
plane on the object), ``separation`` its height above the plane, and the rows of ``J`` are 0 (the hand does not
move them: a rigid environment, G block 0).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import torch

from ..collision import hand_object_penetration, rigid_inverse
from ..errors import InputValueError
from ..hand.dynamics import point_jacobian

__all__ = ["TablePlane", "Contacts", "find_contacts", "support_points", "BODY_OBJECT", "BODY_ENV", "BODY_OBJECT_ENV"]

BODY_OBJECT = 0
BODY_ENV = 1
BODY_OBJECT_ENV = 2


@dataclass(frozen=True)
class TablePlane:
    """A fixed plane {x : normal . x = offset} (an infinitely heavy environment: U_phi = u_phi = 0).

    normal: unit outward normal, 3 floats (default +z); offset: metres; mu: friction coefficient with the hand
    """

    normal: tuple = (0.0, 0.0, 1.0)
    offset: float = 0.0
    mu: float = 1.0

    def __post_init__(self):
        n = tuple(float(x) for x in self.normal)
        norm = sum(x * x for x in n) ** 0.5
        if len(n) != 3 or not norm > 0:
            raise InputValueError(f"normal: expected a non-zero 3-vector, got {self.normal!r}")
        object.__setattr__(self, "normal", tuple(x / norm for x in n))
        if not self.mu >= 0:
            raise InputValueError(f"mu: expected >= 0, got {self.mu}")


class Contacts(NamedTuple):
    """Contact slots at one configuration (N slots, module docstring).

    link:       hand link of each slot, (N,), long; -1 for object-plane slots
    body:       counterpart of each slot, (N,), long: BODY_OBJECT (0), BODY_ENV (1) (hand on the plane) or
                BODY_OBJECT_ENV (2) (the object on the plane)
    local:      contact point in its link's frame, (B, N, 3), metres
    points:     contact point r_i, (B, N, 3), world, metres
    d0:         outward unit normal of the counterpart (paper's d_i0), (B, N, 3), world
    separation: s_i0, signed distance along d0, (B, N), metres, negative when penetrating
    mask:       active slots (separation < margin and the link has geometry), (B, N), bool
    J:          stacked contact Jacobians J_i (Eq. 4) over the 6 + D generalized coordinates (root angular,
                root linear, joints), (B, 3N, 6 + D), metres per radian / dimensionless; 0 rows for inactive slots
    """

    link: torch.Tensor
    body: torch.Tensor
    local: torch.Tensor
    points: torch.Tensor
    d0: torch.Tensor
    separation: torch.Tensor
    mask: torch.Tensor
    J: torch.Tensor


def _transform(T: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    return (T[..., :3, :3] @ p[..., None]).squeeze(-1) + T[..., :3, 3]


def _plane_samples(hand, link_poses: torch.Tensor, n: torch.Tensor, offset: float):
    B, L = link_poses.shape[:2]
    S = hand.sample_points.shape[0]
    sl = hand.sample_link
    pts = _transform(link_poses[:, sl], hand.sample_points.to(link_poses).expand(B, S, 3))      # (B, S, 3)
    sd = pts @ n - offset
    inf = sd.new_full((B, L), float("inf"))
    best = inf.scatter_reduce(1, sl.expand(B, S), sd, reduce="amin", include_self=True)
    is_min = sd == best.gather(1, sl.expand(B, S))
    cand = torch.where(is_min, torch.arange(S, device=sd.device).expand(B, S), S)
    first = torch.full((B, L), S, dtype=torch.long, device=sd.device)
    first = first.scatter_reduce(1, sl.expand(B, S), cand, reduce="amin", include_self=True)
    has = first < S
    local = hand.sample_points.to(link_poses)[first.clamp_max(S - 1)]
    return local, has


def _plane_capsules(hand, link_poses: torch.Tensor, n: torch.Tensor):
    a = _transform(link_poses, hand.capsule_a.to(link_poses))                                  # (B, L, 3)
    b = _transform(link_poses, hand.capsule_b.to(link_poses))
    rad = hand.capsule_radius.to(link_poses)
    da, db = a @ n, b @ n
    tol = 1e-9
    t = torch.where(da < db - tol, 0.0, torch.where(db < da - tol, 1.0, 0.5))
    lowest = a + t[..., None] * (b - a) - rad[None, :, None] * n
    local = _transform(rigid_inverse(link_poses), lowest)
    return local, (rad > 0).expand(a.shape[:2])


def find_contacts(hand, q: torch.Tensor, root: torch.Tensor, *, sdf=None, object_pose: torch.Tensor | None = None,
                  plane: TablePlane | None = None, margin: float = 0.005, geometry: str = "samples",
                  object_points: torch.Tensor | None = None) -> Contacts:
    """Contact slots of the hand against an object and/or a fixed plane (module docstring).

    hand: HandModel; q: finger joints, (B, D), radians; root: root pose, (B, 4, 4)
    sdf: the object's :class:`~torchhand.sdf.SDFGrid` (object frame) or None; object_pose: T_world_object, (B, 4, 4)
    plane: :class:`TablePlane` or None; margin: activation distance, metres; geometry: "samples" | "capsules"
        (how plane contacts are found)
    object_points: the object's support points, (P, 3), object frame, metres (:func:`support_points`), or None;
        with an object and a plane they add P object-plane slots (module docstring)
    returns: :class:`Contacts` with N = L per counterpart given (+ P object-plane slots)
    """
    if sdf is None and plane is None:
        raise InputValueError("find_contacts: give an object (sdf) or a plane, got neither")
    if geometry not in ("samples", "capsules"):
        raise InputValueError(f"geometry: expected 'samples' or 'capsules', got {geometry!r}")
    B, L = q.shape[0], hand.num_links
    link_poses = hand.forward_kinematics(q, root)
    arangeL = torch.arange(L, device=q.device)
    parts = []
    if sdf is not None:
        pen = hand_object_penetration(hand, link_poses, sdf, object_pose)
        has = pen.deepest_index >= 0
        local = hand.sample_points.to(q)[pen.deepest_index.clamp_min(0)]
        parts.append((BODY_OBJECT, local, pen.deepest_point, pen.deepest_normal,
                      torch.where(has, pen.deepest_value, torch.inf), has))
    if plane is not None:
        n = torch.tensor(plane.normal, dtype=q.dtype, device=q.device)
        if geometry == "samples":
            local, has = _plane_samples(hand, link_poses, n, plane.offset)
        else:
            local, has = _plane_capsules(hand, link_poses, n)
        pts = _transform(link_poses, local)
        sep = torch.where(has, pts @ n - plane.offset, torch.inf)
        parts.append((BODY_ENV, local, pts, n.expand(B, L, 3), sep, has))
    body = torch.cat([torch.full((L,), k, dtype=torch.long, device=q.device) for k, *_ in parts])
    link = arangeL.repeat(len(parts))
    local = torch.cat([p[1] for p in parts], 1)
    points = torch.cat([p[2] for p in parts], 1)
    d0 = torch.cat([p[3] for p in parts], 1)
    sep = torch.cat([p[4] for p in parts], 1)
    mask = torch.cat([p[5] for p in parts], 1) & (sep < margin)
    N = link.shape[0]
    J = point_jacobian(hand, q, link, local, root).reshape(B, 3 * N, -1)
    J = J * mask.repeat_interleave(3, dim=1)[..., None].to(J.dtype)
    if object_points is not None and sdf is not None and plane is not None:
        if not (isinstance(object_points, torch.Tensor) and object_points.dim() == 2 and object_points.shape[1] == 3):
            raise InputValueError(f"object_points: expected a (P, 3) tensor, got "
                                  f"{tuple(getattr(object_points, 'shape', ())) or type(object_points).__name__}")
        P = object_points.shape[0]
        n = torch.tensor(plane.normal, dtype=q.dtype, device=q.device)
        loc = object_points.to(q).expand(B, P, 3)
        pts = _transform(object_pose[:, None], loc)
        s_env = pts @ n - plane.offset
        m_env = s_env < margin
        body = torch.cat([body, torch.full((P,), BODY_OBJECT_ENV, dtype=torch.long, device=q.device)])
        link = torch.cat([link, torch.full((P,), -1, dtype=torch.long, device=q.device)])
        local = torch.cat([local, loc], 1)
        points = torch.cat([points, pts], 1)
        d0 = torch.cat([d0, n.expand(B, P, 3)], 1)
        sep = torch.cat([sep, s_env], 1)
        mask = torch.cat([mask, m_env], 1)
        J = torch.cat([J, J.new_zeros(B, 3 * P, J.shape[2])], 1)
    sep = torch.where(mask, sep, torch.zeros_like(sep))
    return Contacts(link, body, local, points, d0, sep, mask, J)


def support_points(vertices, max_points: int = 16, merge: float = 0.002) -> torch.Tensor:
    """The points an object can rest on: its convex hull vertices, merged within ``merge`` and thinned to at most
    ``max_points`` by farthest-point selection (deterministic: the first point is the lowest-index hull vertex).

    vertices: mesh vertices, (V, 3), object frame, metres (array-like); max_points: >= 3; merge: metres
    returns: (P, 3) float64, object frame, metres
    """
    import numpy as np

    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] < 1:
        raise InputValueError(f"vertices: expected a (V, 3) array, got shape {v.shape}")
    if int(max_points) < 3:
        raise InputValueError(f"max_points: expected >= 3, got {max_points}")
    from scipy.spatial import ConvexHull, QhullError

    try:
        v = v[np.sort(ConvexHull(v).vertices)]
    except (QhullError, ValueError):          # flat or too few points: keep every vertex
        pass
    kept: list = []
    for p in v:                  # greedy clustering of nearby hull vertices (rounded corners)
        if not kept or np.min(np.linalg.norm(np.asarray(kept) - p, axis=1)) > merge:
            kept.append(p)
    pts = np.asarray(kept)
    if len(pts) > max_points:
        chosen = [0]
        dist = np.linalg.norm(pts - pts[0], axis=1)
        for _ in range(int(max_points) - 1):
            i = int(np.argmax(dist))
            chosen.append(i)
            dist = np.minimum(dist, np.linalg.norm(pts - pts[i], axis=1))
        pts = pts[np.sort(chosen)]
    return torch.from_numpy(pts)
