"""Snapping a grasp onto its object: which links touch, and closing the small gaps (Liu 2009, Sec. 3 preprocessing).

Liu 2009 "preprocess[es] the input grasping pose to detect initial contacts with the object" without saying how.
Rule used here (docs/manipulation.md):

1. Distances: every surface sample of the hand (``HandModel.sample_points``) is placed in the object frame at the
   grasp pose (``wrist_in_object @ FK(q)``) and its signed distance to the object mesh is measured exactly with
   trimesh (closest surface point, sign from ``mesh.contains``; negative inside). A link's distance is that of its
   closest sample.
2. Contacts: the links whose distance lies within the snap tolerance ``tol`` (default 5 mm) on either side. A link
   deeper than ``tol`` inside the object is an error naming the link and the depth; when no link is within ``tol``
   the grasp "touches nothing" (an error naming the nearest link and its distance).
3. Closing: the gaps and penetrations of the contact links are closed by a **small IK move of the fingers**: damped
   least squares on the finger joints (the wrist stays where the grasp puts it) moving each contact link's closest
   sample onto its closest surface point, all contacts at once, each joint kept within its limits and within
   ``max_move`` (0.15 rad) of the grasp's angle by clamping (the move stays small), until every residual is below
   ``close_tol`` (0.2 mm), the largest residual stops improving (three steps) or ``max_iters`` steps pass; the
   pose with the smallest largest residual is kept. What the IK cannot close (a joint at its limit or at
   ``max_move``, or links of one finger that cannot all lie on the surface) stays as a reported residual; the
   contact's object point is then the projection of its hand point onto the surface (the contact point is moved
   onto the surface).
4. Links farther than ``tol`` but within ``3 tol`` are reported as unsnapped gaps; they are not contacts.

Each contact is the link's closest sample (``contact_hand``, link frame) and its closest surface point
(``contact_object``, object frame). Conventions: metres, radians, SDF negative inside.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import torch

from ..errors import InputValueError
from .grasp import Grasp, check_grasp_hand

__all__ = ["SnapReport", "snap_grasp", "hand_surface_in_object", "signed_distance"]

SNAP_TOL = 0.005
"""Default snap tolerance, metres."""


@dataclass(frozen=True)
class SnapReport:
    """What :func:`snap_grasp` did.

    links: (C,) contact link names
    before: signed distance of each contact link before snapping, (C,), metres (negative = penetrating)
    after: the same after snapping, (C,), metres (the residual the IK left)
    unsnapped: ((link, distance in metres), ...) links within 3 tol but beyond tol: gaps not closed
    max_joint_move: largest joint change of the IK, radians
    iterations: IK steps taken
    tol: the snap tolerance, metres
    """

    links: tuple
    before: np.ndarray
    after: np.ndarray
    unsnapped: tuple
    max_joint_move: float
    iterations: int
    tol: float

    def lines(self) -> list[str]:
        """One human-readable line per contact and per unsnapped gap (distances in mm)."""
        out = [f"contact {n}: {1e3 * b:+.2f} mm -> {1e3 * a:+.2f} mm" for n, b, a in
               zip(self.links, self.before, self.after)]
        out += [f"gap not closed: {n} is {1e3 * d:.2f} mm from the object (snap tolerance {1e3 * self.tol:.1f} mm)"
                for n, d in self.unsnapped]
        out.append(f"IK: {self.iterations} step(s), largest joint move {self.max_joint_move:.4f} rad")
        return out

    def as_dict(self) -> dict:
        """JSON-ready summary (distances in metres)."""
        return {"links": list(self.links), "before_m": [float(x) for x in self.before],
                "after_m": [float(x) for x in self.after],
                "unsnapped": [{"link": n, "distance_m": float(d)} for n, d in self.unsnapped],
                "max_joint_move_rad": self.max_joint_move, "iterations": self.iterations, "tol_m": self.tol}


def signed_distance(mesh, points: np.ndarray, cutoff: float | None = None,
                    chunk: int = 2048) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact signed distance of points (N, 3) to a trimesh (same frame), negative inside.

    cutoff: None (every point exact), or a distance in metres beyond which a point needs no exact answer: a point
        whose nearest mesh vertex is farther than ``cutoff`` plus the mesh's longest edge is certainly farther than
        ``cutoff`` from the surface; it gets its nearest vertex (distance, point, vertex normal) instead, a value
        above ``cutoff``. (The exact closest-point search of a point far from a scanned mesh considers most of its
        faces: all 14,515 Shadow hand samples near a 16,384-face scan at once asked for 3.5 GB.)
    chunk: points per exact closest-point call (memory bound)

    Returns (sd (N,), closest surface points (N, 3), outward face normal at each closest point (N, 3)).
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = len(points)
    dist, closest, normals = np.empty(n), np.empty((n, 3)), np.empty((n, 3))
    exact = np.ones(n, dtype=bool)
    if cutoff is not None and n:
        dv, iv = mesh.kdtree.query(points)
        edge = float(np.asarray(mesh.edges_unique_length).max(initial=0.0))
        exact = dv <= cutoff + edge
        far = ~exact
        dist[far], closest[far] = dv[far], np.asarray(mesh.vertices)[iv[far]]
        normals[far] = np.asarray(mesh.vertex_normals)[iv[far]]
    idx = np.flatnonzero(exact)
    for s in range(0, len(idx), chunk):
        sel = idx[s:s + chunk]
        c, d, tri = mesh.nearest.on_surface(points[sel])
        closest[sel], dist[sel], normals[sel] = c, d, np.asarray(mesh.face_normals)[tri]
    inside = mesh.contains(points) if n else np.zeros(0, dtype=bool)
    return np.where(inside, -dist, dist), closest, normals


def hand_surface_in_object(hand, q: np.ndarray, wrist_in_object: np.ndarray) -> np.ndarray:
    """The hand's surface samples in the object frame at a pose, (S, 3), metres (rows of ``hand.sample_points``)."""
    T = _link_poses(hand, q, wrist_in_object)
    pts = hand.sample_points.detach().cpu().double().numpy()
    link = hand.sample_link.cpu().numpy()
    return np.einsum("sij,sj->si", T[link, :3, :3], pts) + T[link, :3, 3]


def _link_poses(hand, q, wrist_in_object) -> np.ndarray:
    qt = torch.as_tensor(np.asarray(q, dtype=np.float64))[None].to(hand.dtype)
    root = torch.as_tensor(np.asarray(wrist_in_object, dtype=np.float64))[None].to(hand.dtype)
    return hand.forward_kinematics(qt, root)[0].detach().cpu().double().numpy()


def _link_min(sd: np.ndarray, link: np.ndarray, L: int) -> tuple[np.ndarray, np.ndarray]:
    """Per link: the smallest signed distance of its samples and that sample's index (inf / -1 without samples)."""
    best = np.full(L, np.inf)
    idx = np.full(L, -1, dtype=np.int64)
    order = np.lexsort((sd, link))                    # by link, then distance
    first = np.unique(link[order], return_index=True)
    for l, k in zip(*first):
        best[l], idx[l] = sd[order[k]], order[k]
    return best, idx


def snap_grasp(grasp: Grasp, hand, mesh, *, tol: float = SNAP_TOL, close_tol: float = 2e-4, max_iters: int = 30,
               damping: float = 1e-3, max_step: float = 0.05,
               max_move: float = 0.15) -> tuple[Grasp, SnapReport]:
    """Find the grasp's contacts and close their gaps (module docstring).

    Args:
        grasp: the grasp (its own contacts, if any, are replaced)
        hand: its :class:`~torchhand.hand.HandModel` (see :func:`~torchhand.manipulation.grasp.grasp_hand`)
        mesh: the object's trimesh, object frame, metres
        tol: snap tolerance, metres (> 0)
        close_tol: residual below which a contact counts as closed, metres
        max_iters: IK steps
        damping: damped-least-squares damping, metres
        max_step: largest joint change per IK step, radians
        max_move: largest total change of any joint, radians (keeps the move small)

    Returns:
        (the snapped grasp with ``q`` moved and the contacts filled in, :class:`SnapReport`)

    Raises:
        InputValueError: a link penetrates deeper than ``tol`` (before or after snapping), or no link is within
            ``tol`` ("touches nothing", naming the nearest link and its distance); the checks of
            :func:`~torchhand.manipulation.grasp.check_grasp_hand`.
    """
    if not (isinstance(tol, (int, float)) and np.isfinite(tol) and tol > 0):
        raise InputValueError(f"snap tolerance: expected a positive number of metres, got {tol!r}")
    check_grasp_hand(grasp, hand)
    hand = hand.to("cpu", torch.float64)
    names = hand.link_names
    L = hand.num_links
    link_of = hand.sample_link.numpy()
    local = hand.sample_points.numpy()
    who = f"grasp ({grasp.side})"

    sd, _, _ = signed_distance(mesh, hand_surface_in_object(hand, grasp.q, grasp.wrist_in_object), cutoff=4 * tol)
    best, _ = _link_min(sd, link_of, L)
    _check_depth(best, names, tol, who, "")
    contact = np.nonzero(np.abs(best) <= tol)[0]
    if contact.size == 0:
        near = int(np.argmin(np.abs(best)))
        raise InputValueError(f"{who} touches nothing: nearest link {names[near]} is {1e3 * best[near]:.1f} mm from "
                              f"the object (snap tolerance {1e3 * tol:.1f} mm)")
    before = best[contact]
    unsnapped = tuple((names[l], float(best[l])) for l in np.nonzero((best > tol) & (best <= 3 * tol))[0])

    # IK: damped least squares on the finger joints, the wrist fixed (only the contact links' samples are measured).
    lim = hand.joint_limits.numpy()
    q = grasp.q.copy()
    lo = np.maximum(lim[:, 0], np.minimum(q, q - max_move))
    hi = np.minimum(lim[:, 1], np.maximum(q, q + max_move))
    root = torch.as_tensor(grasp.wrist_in_object)[None]
    sub = np.nonzero(np.isin(link_of, contact))[0]
    best_err, best_q, steps = np.inf, q, 0
    for _ in range(max_iters):
        X = hand_surface_in_object(hand, q, grasp.wrist_in_object)[sub]
        sd, closest, _ = signed_distance(mesh, X)
        b, i = _link_min(sd, link_of[sub], L)
        err = float(np.abs(b[contact]).max())
        if err < best_err - 1e-6:
            best_err, best_q, stall = err, q, 0
        else:
            stall += 1
        if err <= close_tol or stall >= 3:
            break
        s = i[contact]
        J = hand.point_jacobian(torch.as_tensor(q)[None], torch.as_tensor(link_of[sub][s]),
                                torch.as_tensor(local[sub][s]), root)[0].numpy()       # (P, 3, D)
        e = (closest[s] - X[s]).reshape(-1)
        Jf = J.reshape(-1, J.shape[-1])
        dq = Jf.T @ np.linalg.solve(Jf @ Jf.T + damping ** 2 * np.eye(Jf.shape[0]), e)
        dq *= min(1.0, max_step / max(float(np.abs(dq).max()), 1e-300))
        q = np.clip(q + dq, lo, hi)
        steps += 1
    q = best_q

    sd, closest, _ = signed_distance(mesh, hand_surface_in_object(hand, q, grasp.wrist_in_object), cutoff=4 * tol)
    best, idx = _link_min(sd, link_of, L)
    _check_depth(best, names, tol, who, " after snapping")
    s = idx[contact]
    snapped = dataclasses.replace(
        grasp, q=q, contact_links=tuple(names[l] for l in contact), contact_hand=local[s].copy(),
        contact_object=closest[s].copy(), snap_distance=before.copy())
    report = SnapReport(links=snapped.contact_links, before=before.copy(), after=best[contact].copy(),
                        unsnapped=unsnapped, max_joint_move=float(np.abs(q - grasp.q).max(initial=0.0)),
                        iterations=steps, tol=float(tol))
    return snapped, report


def _check_depth(best: np.ndarray, names, tol: float, who: str, when: str) -> None:
    deep = np.nonzero(best < -tol)[0]
    if deep.size:
        rows = ", ".join(f"{names[l]} by {-1e3 * best[l]:.1f} mm" for l in deep[np.argsort(best[deep])])
        raise InputValueError(f"{who} penetrates the object{when} beyond the snap tolerance {1e3 * tol:.1f} mm: "
                              f"{rows}")
