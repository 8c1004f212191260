"""Contact slots of the quasi-static step (Kry & Pai 2006 §7.1, Stage 9 step 1 of docs' design note).

Slots are fixed per (link, counterpart): with L hand links, slots 0 .. L-1 pair each link with the object (when
there is one) and the next L slots pair each link with the fixed plane (when there is one); N = L or 2 L, plus the
object-plane slots below. A slot holds the link's deepest point against its counterpart and is active (``mask``)
when that point is closer than ``margin`` (5 mm by default, so that a link cannot pass through a surface in one
step unnoticed). Because a slot keeps its identity from step to step, the force f_i^k carries over to the new
contact point of the same slot (the paper's contact update).

- object, ``geometry="samples"`` or no exact mesh: the deepest of the link's surface samples
  (``HandModel.sample_points``) in the object's signed distance grid; the normal is the grid's gradient there
  (trilinear, so blended over a voxel near an edge or a corner, and the point is only as deep as the nearest sample).
- object, ``geometry="capsules"`` with the exact mesh (``object_mesh``, a
  :class:`~torchhand.check.geometry.ObjectMesh`): the link's capsule against the mesh, the same geometry as
  ``torchhand check``. Points on the capsule axis at most :data:`AXIS_SPACING` (1 mm) apart whose hull bound allows
  contact within ``margin`` get trimesh's exact closest surface point c and signed distance; the axis point p with
  the smallest ``separation = distance(p) - radius`` is the link's contact. Its normal d0 is the closest-point
  direction (p - c) / |p - c| (reversed when p is inside): the exact gradient of the distance to the mesh, which is
  the face normal on a face and turns continuously around a convex edge or corner through the normals of the
  faces that meet there (the face normal of c's triangle when p lies on the surface). d0 must lie in the mesh's
  normal cone at c, the cone of the normals of the faces within 0.5 mm of c that ``torchhand check`` measures
  friction against: at a convex edge or corner it does; at a vertex where a scanned mesh is not convex it can lie
  just outside (0.4 degrees measured on the bunny, enough for a force on its pyramid's edge to leave the cone), and
  is projected onto that cone. The slot's point is the capsule surface point p - radius d0 (on the link's capsule,
  which is what the Jacobian moves) and the written object contact point, ``points - separation d0``, is c itself
  (within distance(p) times the projection's angle where d0 was projected).
- plane: exact. ``geometry="samples"`` takes the deepest surface sample; ``geometry="capsules"`` takes the exact
  lowest point of the link's fitted capsule (``capsule_a``, ``capsule_b``, ``capsule_radius``; the middle of the
  segment when it lies parallel to the plane), which is the true contact point for capsule-shaped links.

Finger-finger slots (an extension: the paper's step has none, and its fingers pass through each other; design note
§3): with ``self_pairs`` (Q, 2) link pairs (:func:`self_pairs`: the capsule pairs of different fingers that
``torchhand check`` measures), Q more slots follow the object and plane slots, ``body = BODY_SELF``, ``link`` the
pair's first link a. Both bodies are compliant: the closest points p_a, p_b of the two capsule axes give
d0 = (p_a - p_b) / |p_a - p_b| (the direction of the force link b exerts on link a), separation
|p_a - p_b| - r_a - r_b, the slot point p_a - r_a d0 on a's capsule, and the Jacobian row J_a(p_a - r_a d0) -
J_b(p_b + r_b d0): the relative motion of the two surface points, so that G = J C J^T holds the compliance of both
fingers (and nothing of the root, which moves both). They enter the LCP like hand-plane rows (U_phi = u_phi = 0).

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

import weakref
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch

from ..hand.collision import hand_object_penetration, rigid_inverse
from ..errors import InputValueError
from ..hand.dynamics import kinematic_frames, point_jacobian_at

__all__ = ["TablePlane", "Contacts", "find_contacts", "support_points", "self_pairs", "BODY_OBJECT", "BODY_ENV",
           "BODY_OBJECT_ENV", "BODY_SELF"]

BODY_OBJECT = 0
BODY_ENV = 1
BODY_OBJECT_ENV = 2
BODY_SELF = 3


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


AXIS_SPACING = 1e-3
"""Largest distance between consecutive capsule-axis points in the exact object test, metres (the checker's)."""


def _into_normal_cone(mesh, closest, tri, n):
    """Outward normals n (K, 3) moved into the normal cone of the mesh at their closest points: the cone of the
    normals of every face within ``torchhand.check.contacts.EDGE_TOL`` (the cone ``torchhand check`` measures
    friction against). On a face, and at a convex edge or corner, the closest-point direction already lies in it;
    at a vertex where the surface is not convex (a saddle of a scanned mesh) it can lie just outside, and is
    replaced by its projection onto the cone (non-negative least squares over the generators, renormalised)."""
    import numpy as np
    from scipy.optimize import nnls

    from ..check.contacts import EDGE_TOL

    out = n.copy()
    for i, gens in enumerate(mesh.normal_cone(closest, tri, EDGE_TOL)):
        if len(gens) < 2:
            continue
        G = -gens                                   # outward generators, (m, 3)
        lam, _ = nnls(G.T, n[i])
        x = G.T @ lam
        if np.linalg.norm(x) > 1e-12 and np.linalg.norm(x / np.linalg.norm(x) - n[i]) > 1e-12:
            out[i] = x / np.linalg.norm(x)
    return out


def _capsule_axes(hand, spacing: float):
    """The hand's capsules as float64 arrays (a, b (L, 3), radius (L,)), the links with a capsule, and the points
    on their axes at most ``spacing`` apart: fraction along the axis (P,) and link (P,)."""
    from ..check.geometry import axis_points

    ca = hand.capsule_a.detach().cpu().double().numpy()
    cb = hand.capsule_b.detach().cpu().double().numpy()
    rad = hand.capsule_radius.detach().cpu().double().numpy()
    links = np.nonzero(rad > 0)[0]
    frac, owner = axis_points(ca[links], cb[links], spacing)
    return ca, cb, rad, links, frac, links[owner]


def _object_capsules(hand, link_poses: torch.Tensor, object_pose: torch.Tensor, mesh, margin: float,
                     spacing: float = AXIS_SPACING):
    """Each link's capsule against the exact mesh (module docstring): local (B, L, 3) link frame, hand point
    (B, L, 3) world, d0 (B, L, 3) world, separation (B, L) (inf where no axis point can come within ``margin``),
    has (B, L) bool."""
    like = link_poses
    B, L = link_poses.shape[:2]
    lp = link_poses.detach().cpu().double().numpy()
    E = object_pose.detach().cpu().double().numpy()
    ca, cb, rad, links, frac, owner = _per_hand(hand, f"axis {spacing!r}", lambda: _capsule_axes(hand, spacing))
    sep = np.full((B, L), np.inf)
    hand_pt = np.zeros((B, L, 3))
    d0 = np.zeros((B, L, 3))
    d0[..., 2] = 1.0
    if len(links):
        R, t = lp[:, :, :3, :3], lp[:, :, :3, 3]
        aw = np.einsum("blij,lj->bli", R, ca) + t
        bw = np.einsum("blij,lj->bli", R, cb) + t
        pw = aw[:, owner] + frac[None, :, None] * (bw[:, owner] - aw[:, owner])            # (B, P, 3) world
        Ri, ti = E[:, :3, :3].transpose(0, 2, 1), -np.einsum("bji,bj->bi", E[:, :3, :3], E[:, :3, 3])
        po = np.einsum("bij,bpj->bpi", Ri, pw) + ti[:, None]                                 # object frame
        r = rad[owner]
        bound = mesh.hull_distance_bound(po.reshape(-1, 3)).reshape(B, -1)
        bi, pi = np.nonzero(bound < r[None, :] + margin)
        if len(bi):
            sd, c_all, _, tri_all = mesh.signed_closest(po[bi, pi])                        # positive inside
            s_all = -sd - r[pi]
            flat = np.full(B * L, np.inf)
            key = bi * L + owner[pi]
            np.minimum.at(flat, key, s_all)
            best = np.full(B * L, -1, dtype=np.int64)
            hit = s_all <= flat[key]
            best[key[hit]] = np.nonzero(hit)[0]
            sel = np.nonzero(best >= 0)[0]
            j = best[sel]
            p = po[bi[j], pi[j]]
            c, tri = c_all[j], tri_all[j]
            inside = sd[j] > 0
            face_n = np.asarray(mesh.mesh.face_normals, dtype=np.float64)[tri]
            v = np.where(inside[:, None], c - p, p - c)
            nv = np.linalg.norm(v, axis=-1, keepdims=True)
            n_obj = np.where(nv > 1e-9, v / np.maximum(nv, 1e-300), face_n)
            n_obj = _into_normal_cone(mesh, c, tri, n_obj)
            b_sel, l_sel = sel // L, sel % L
            n_w = np.einsum("bij,bj->bi", E[b_sel, :3, :3], n_obj)
            p_w = pw[b_sel, pi[j]]
            hand_pt[b_sel, l_sel] = p_w - rad[l_sel, None] * n_w
            d0[b_sel, l_sel] = n_w
            sep[b_sel, l_sel] = s_all[j]
    has = np.isfinite(sep)
    inv = np.linalg.inv(lp)
    local = np.einsum("blij,blj->bli", inv[..., :3, :3], hand_pt) + inv[..., :3, 3]
    tt = lambda x: torch.from_numpy(x).to(like)  # noqa: E731
    return tt(local), tt(hand_pt), tt(d0), tt(sep), torch.from_numpy(has).to(like.device)


_PER_HAND: dict = {}


def _per_hand(hand, key: str, make):
    """``make()``, computed once per hand object (a step recomputes nothing that depends on the hand alone)."""
    k = (id(hand), key)
    hit = _PER_HAND.get(k)
    if hit is not None and hit[0]() is hand:
        return hit[1]
    for dead in [k2 for k2, (ref, _) in _PER_HAND.items() if ref() is None]:
        del _PER_HAND[dead]
    value = make()
    _PER_HAND[k] = (weakref.ref(hand), value)
    return value


def self_pairs(hand) -> torch.Tensor:
    """The capsule pairs of different fingers that ``torchhand check`` measures for finger-finger penetration
    (:func:`torchhand.check.penetration.finger_pairs`: links with a capsule, a four-link finger's first link left
    out), (Q, 2) long."""
    from ..check.penetration import finger_pairs

    def make():
        cpu = hand if hand.joint_limits.device.type == "cpu" else hand.to("cpu")
        return torch.from_numpy(finger_pairs(cpu)).to(torch.long)

    return _per_hand(hand, "self_pairs", make).clone()


def _jacobian_where(hand, fr, root: torch.Tensor, link: torch.Tensor, local: torch.Tensor,
                    active: torch.Tensor) -> torch.Tensor:
    """Jacobians (B, N, 3, 6 + D) of the slot points ``local`` (B, N, 3) on links ``link`` (N,), computed only for
    the slots active in some rollout (``active`` (B, N)) and 0 on the others."""
    B, N = active.shape
    cols = active.any(0).nonzero().flatten()
    J = local.new_zeros(B, N, 3, 6 + hand.num_joints)
    if cols.numel():
        J[:, cols] = point_jacobian_at(hand, fr, root, link[cols], local[:, cols])
    return J


def _object_capsules_of(hand, link_poses: torch.Tensor, object_pose: torch.Tensor, mesh, margin: float):
    """:func:`_object_capsules` for one mesh or a sequence of B meshes (one per rollout): the rollouts that share a
    mesh are run together, and each rollout's answer is what it would be alone."""
    if not isinstance(mesh, (tuple, list)):
        return _object_capsules(hand, link_poses, object_pose, mesh, margin)
    B = link_poses.shape[0]
    if len(mesh) != B:
        raise InputValueError(f"object_mesh: {len(mesh)} meshes for {B} rollouts")
    groups: dict = {}
    for b, m in enumerate(mesh):
        groups.setdefault(id(m), (m, []))[1].append(b)
    if len(groups) == 1:
        return _object_capsules(hand, link_poses, object_pose, mesh[0], margin)
    out = None
    for m, rows in groups.values():
        idx = torch.tensor(rows, device=link_poses.device)
        part = _object_capsules(hand, link_poses[idx], object_pose[idx], m, margin)
        if out is None:
            out = [x.new_zeros((B,) + tuple(x.shape[1:])) for x in part]
        for o, x in zip(out, part):
            o[idx] = x
    return tuple(out)


def _self_slots(hand, root, fr, pairs: torch.Tensor, margin: float):
    """Finger-finger slots (module docstring): local_a (B, Q, 3), point (B, Q, 3), d0 (B, Q, 3), separation
    (B, Q), active (B, Q) (separation < ``margin``), J (B, 3Q, 6 + D), 0 on inactive pairs."""
    from torchhand.kernels.penetration import capsule_interpenetration

    link_poses = fr.poses
    B, Q = link_poses.shape[0], pairs.shape[0]
    rad = hand.capsule_radius.to(link_poses)
    res = capsule_interpenetration(link_poses, hand.capsule_a.to(link_poses), hand.capsule_b.to(link_poses), rad,
                                   pairs.to(link_poses.device))
    ia, ib = pairs[:, 0].to(root.device), pairs[:, 1].to(root.device)
    v = res.point_i - res.point_j
    dist = v.norm(dim=-1, keepdim=True)
    # coincident axes (never in practice): push along +z rather than divide by zero
    z = torch.zeros_like(v)
    z[..., 2] = 1.0
    n = torch.where(dist > 1e-12, v / dist.clamp_min(1e-300), z)
    pa = res.point_i - rad[ia][None, :, None] * n
    pb = res.point_j + rad[ib][None, :, None] * n
    sep = dist[..., 0] - rad[ia] - rad[ib]
    active = sep < margin
    inv = rigid_inverse(link_poses)
    la = _transform(inv[:, ia], pa)
    lb = _transform(inv[:, ib], pb)
    J = _jacobian_where(hand, fr, root, torch.cat([ia, ib]), torch.cat([la, lb], 1), active.repeat(1, 2))
    J = J.reshape(B, 2, Q, 3, -1)
    J = (J[:, 0] - J[:, 1]) * active[..., None, None].to(J.dtype)
    return la, pa, n, sep, active, J.reshape(B, 3 * Q, -1)


def find_contacts(hand, q: torch.Tensor, root: torch.Tensor, *, sdf=None, object_pose: torch.Tensor | None = None,
                  plane: TablePlane | None = None, margin: float = 0.005, geometry: str = "samples",
                  object_points: torch.Tensor | None = None, object_mesh=None,
                  self_pairs: torch.Tensor | None = None, object_points_mask: torch.Tensor | None = None) -> Contacts:
    """Contact slots of the hand against an object and/or a fixed plane (module docstring).

    hand: HandModel; q: finger joints, (B, D), radians; root: root pose, (B, 4, 4)
    sdf: the object's :class:`~torchhand.geometry.sdf.SDFGrid` (object frame) or None; object_pose: T_world_object, (B, 4, 4)
    plane: :class:`TablePlane` or None; margin: activation distance, metres; geometry: "samples" | "capsules"
        (how plane contacts are found)
    object_points: the object's support points, (P, 3) or per rollout (B, P, 3), object frame, metres
        (:func:`support_points`), or None; with an object and a plane they add P object-plane slots (module
        docstring); object_points_mask: (B, P) bool, the real points where rollouts have fewer (the others never
        become active), or None (all)
    object_mesh: the object's exact mesh, :class:`~torchhand.check.geometry.ObjectMesh` (object frame), a sequence
        of B of them (one object per rollout), or None; with ``geometry="capsules"`` the object slots come from it
        (module docstring), and ``sdf`` may be None
    self_pairs: finger-finger capsule pairs, (Q, 2) long (:func:`self_pairs`), or None (no finger-finger slots)
    returns: :class:`Contacts` with N = L per counterpart given (+ P object-plane slots, + Q finger-finger slots)
    """
    exact = object_mesh is not None and geometry == "capsules"
    has_obj = sdf is not None or exact
    if object_mesh is not None and sdf is None and not exact:
        raise InputValueError("find_contacts: an object given by its exact mesh alone needs geometry='capsules' "
                              "(surface samples are looked up in a signed distance grid)")
    if not has_obj and plane is None:
        raise InputValueError("find_contacts: give an object (sdf or object_mesh) or a plane, got neither")
    if geometry not in ("samples", "capsules"):
        raise InputValueError(f"geometry: expected 'samples' or 'capsules', got {geometry!r}")
    B, L = q.shape[0], hand.num_links
    fr = kinematic_frames(hand, q, root)       # one kinematics pass for the poses and every Jacobian below
    link_poses = fr.poses
    arangeL = torch.arange(L, device=q.device)
    parts = []
    if exact:
        local, pts, nrm, sep, has = _object_capsules_of(hand, link_poses, object_pose, object_mesh, margin)
        parts.append((BODY_OBJECT, local, pts, nrm, sep, has))
    elif sdf is not None:
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
    J = _jacobian_where(hand, fr, root, link, local, mask).reshape(B, 3 * N, -1)
    J = J * mask.repeat_interleave(3, dim=1)[..., None].to(J.dtype)
    if object_points is not None and has_obj and plane is not None:
        loc, real = _support_args(object_points, object_points_mask, B, q)
        P = loc.shape[1]
        n = torch.tensor(plane.normal, dtype=q.dtype, device=q.device)
        pts = _transform(object_pose[:, None], loc)
        s_env = pts @ n - plane.offset
        m_env = (s_env < margin) & real
        body = torch.cat([body, torch.full((P,), BODY_OBJECT_ENV, dtype=torch.long, device=q.device)])
        link = torch.cat([link, torch.full((P,), -1, dtype=torch.long, device=q.device)])
        local = torch.cat([local, loc], 1)
        points = torch.cat([points, pts], 1)
        d0 = torch.cat([d0, n.expand(B, P, 3)], 1)
        sep = torch.cat([sep, s_env], 1)
        mask = torch.cat([mask, m_env], 1)
        J = torch.cat([J, J.new_zeros(B, 3 * P, J.shape[2])], 1)
    if self_pairs is not None and self_pairs.shape[0] > 0:
        Q = self_pairs.shape[0]
        la, pa, n, s_self, m_self, J_self = _self_slots(hand, root, fr, self_pairs, margin)
        body = torch.cat([body, torch.full((Q,), BODY_SELF, dtype=torch.long, device=q.device)])
        link = torch.cat([link, self_pairs[:, 0].to(q.device)])
        local = torch.cat([local, la], 1)
        points = torch.cat([points, pa], 1)
        d0 = torch.cat([d0, n], 1)
        sep = torch.cat([sep, s_self], 1)
        mask = torch.cat([mask, m_self], 1)
        J = torch.cat([J, J_self], 1)
    sep = torch.where(mask, sep, torch.zeros_like(sep))
    return Contacts(link, body, local, points, d0, sep, mask, J)


def _support_args(points, mask, B: int, like: torch.Tensor):
    """Support points (P, 3) or (B, P, 3) and their mask (B, P) or None -> (B, P, 3), (B, P) bool."""
    ok = isinstance(points, torch.Tensor) and points.shape[-1:] == (3,) and (
        points.dim() == 2 or (points.dim() == 3 and points.shape[0] == B))
    if not ok:
        raise InputValueError(f"object_points: expected a (P, 3) or ({B}, P, 3) tensor, got "
                              f"{tuple(getattr(points, 'shape', ())) or type(points).__name__}")
    loc = points.to(like).expand(B, *points.shape[-2:])
    if mask is None:
        return loc, torch.ones(loc.shape[:2], dtype=torch.bool, device=like.device)
    if not (isinstance(mask, torch.Tensor) and mask.dtype == torch.bool and tuple(mask.shape) == tuple(loc.shape[:2])):
        raise InputValueError(f"object_points_mask: expected a bool tensor of shape {tuple(loc.shape[:2])}")
    return loc, mask.to(like.device)


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
