"""Exact geometry for the final check of a finished motion (:func:`.pipeline.finalize_solution`).

The search works with the object's SDF grid: fast and batched, but its normals are rounded within a voxel or two
of a sharp edge (on a box, 0.6 mm from an edge the grid's normal leans 30 degrees toward the side face), and its
distances are trilinear. What a user sees — and what ``torchhand check`` measures — is the mesh itself. So the
final check of every written motion recomputes, on the CPU with trimesh:

* :func:`mesh_normals`: each contact's normal from the mesh at the closest surface point: the face's normal on a
  face's interior; where the point lies within ``edge_tol`` of other faces (an edge or a corner), the direction of
  their normal cone closest to the grid's normal (any direction of that cone is a normal of the edge);
* :func:`capsule_depth` / :func:`capsule_penetration`: how deep each link's collision capsule reaches into the
  object, from points along its axis (at most ``spacing`` apart) with the grid's signed distance (the grid's error
  is a fraction of a voxel; against trimesh's exact distance the depths agree within 0.05 mm on box-turn). The
  hand's surface samples, 3-4 mm apart, miss a box edge pressing into a phalanx between them (0.5 mm by the
  samples where the capsule is 2.3 mm deep), so the kinematic verdicts and the reconstruction's collision
  constraints use these instead.

Conventions: object frame for mesh queries, metres; normals point INTO the object.
"""

from __future__ import annotations

import numpy as np
import torch
import trimesh
from scipy.optimize import nnls

__all__ = ["mesh_normals", "capsule_axis_points", "capsule_depth", "capsule_penetration"]


def mesh_normals(mesh: trimesh.Trimesh, points: np.ndarray, guess: np.ndarray, edge_tol: float = 2.5e-4) -> np.ndarray:
    """Inward unit normals of ``mesh`` at the points closest to ``points`` (N, 3), object frame.

    guess: (N, 3) unit normals (the grid's), used to pick a direction of an edge's normal cone
    returns: (N, 3) float64
    """
    points = np.asarray(points, dtype=np.float64)
    guess = np.asarray(guess, dtype=np.float64)
    out = np.zeros_like(points)
    finite = np.isfinite(points).all(-1) & np.isfinite(guess).all(-1)
    if not finite.all():    # a non-finite point (a diverged pose) keeps its guess; its frame fails elsewhere
        out[~finite] = np.nan_to_num(guess[~finite])
        if finite.any():
            out[finite] = mesh_normals(mesh, points[finite], guess[finite], edge_tol)
        return out
    if len(points) == 0:
        return out
    closest, _, tri = trimesh.proximity.closest_point(mesh, points)
    inward = -np.asarray(mesh.face_normals, dtype=np.float64)
    out[:] = inward[tri]
    tris = mesh.triangles.view(np.ndarray)
    tree = mesh.triangles_tree
    for i, c in enumerate(closest):
        cand = np.fromiter(tree.intersection(np.concatenate([c - edge_tol, c + edge_tol])), dtype=np.int64)
        if len(cand) <= 1:
            continue
        d = np.linalg.norm(trimesh.triangles.closest_point(tris[cand], np.repeat(c[None], len(cand), 0)) - c,
                           axis=-1)
        normals = inward[cand[d <= edge_tol]]
        if len(normals) <= 1 or np.ptp(normals, axis=0).max() < 1e-9:
            continue
        lam, _ = nnls(normals.T, guess[i])                      # the cone direction closest to the guess
        n = normals.T @ lam
        out[i] = n / np.linalg.norm(n) if np.linalg.norm(n) > 1e-12 else normals.mean(0) / np.linalg.norm(
            normals.mean(0))
    return out


def capsule_axis_points(hand, spacing: float = 1e-3):
    """Points along every link's capsule axis at most ``spacing`` apart: (link (P,) long, local (P, 3),
    radius (P,))."""
    a, b, r = hand.capsule_a, hand.capsule_b, hand.capsule_radius
    n = int(torch.ceil((b - a).norm(dim=-1).max() / spacing).item()) + 1 if hand.num_links else 1
    u = torch.linspace(0, 1, n, dtype=a.dtype, device=a.device)
    local = a[:, None] + u[None, :, None] * (b - a)[:, None]                 # (L, n, 3)
    link = torch.arange(hand.num_links, device=a.device)[:, None].expand(-1, n)
    return link.reshape(-1), local.reshape(-1, 3), r[:, None].expand(-1, n).reshape(-1)


def capsule_penetration(hand, poses: torch.Tensor, sdf, object_pose: torch.Tensor, object_inv: torch.Tensor,
                        axis=None):
    """The deepest axis point of every link's capsule against the object's grid.

    poses (N, L, 4, 4) world; object_pose, object_inv (N, 4, 4); axis: :func:`capsule_axis_points` (cached)
    returns: depth (N, L) metres (radius - signed distance; > 0 inside), local (N, L, 3) the axis point in its
        link's frame, point (N, L, 3) world, normal (N, L, 3) outward unit surface normal there (world), sd (N, L)
    """
    link, local, r = capsule_axis_points(hand) if axis is None else axis
    N, L = poses.shape[:2]
    n = local.shape[0] // max(L, 1)
    P = poses[:, link]                                                       # (N, P, 4, 4)
    world = (P[..., :3, :3] @ local.unsqueeze(-1)).squeeze(-1) + P[..., :3, 3]
    obj = (object_inv[:, None, :3, :3] @ world.unsqueeze(-1)).squeeze(-1) + object_inv[:, None, :3, 3]
    sd, grad, _ = sdf.query_surface(obj)                                     # (N, P), (N, P, 3): exact near it
    depth = (r - sd).view(N, L, n)
    best, idx = depth.max(-1)                                                # (N, L)
    take = lambda x: x.view(N, L, n, -1).gather(2, idx[..., None, None].expand(N, L, 1, x.shape[-1])).squeeze(2)
    g = take(grad)
    g_world = (object_pose[:, None, :3, :3] @ g.unsqueeze(-1)).squeeze(-1)
    normal = g_world / g_world.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    loc = local.view(L, n, 3)[torch.arange(L, device=local.device)[None], idx]
    return best, loc, take(world), normal, take(sd[..., None]).squeeze(-1)


def capsule_depth(hand, poses: torch.Tensor, sdf, object_inv: torch.Tensor, axis=None) -> torch.Tensor:
    """Depth of every link's capsule inside the object, (N, L) metres (<= 0 outside): max over its axis points of
    radius - signed distance. poses (N, L, 4, 4) world; object_inv (N, 4, 4)."""
    link, local, r = capsule_axis_points(hand) if axis is None else axis
    N, L = poses.shape[:2]
    P = poses[:, link]                                                       # (N, P, 4, 4)
    world = (P[..., :3, :3] @ local.unsqueeze(-1)).squeeze(-1) + P[..., :3, 3]
    obj = (object_inv[:, None, :3, :3] @ world.unsqueeze(-1)).squeeze(-1) + object_inv[:, None, :3, 3]
    return (r - sdf.query_surface(obj)[0]).view(N, L, -1).amax(-1)
