"""Triangle meshes for drawing: a smooth hand per link, the table, contact dots and force arrows.

All meshes are ``trimesh.Trimesh`` in metres. Hand meshes are in their link's frame, so a frame is drawn by posing
each one with ``T_world_link`` from :meth:`~torchhand.hand.HandModel.forward_kinematics`. Conventions (see
:mod:`torchhand.conventions`): column-vector 4x4 transforms, the palm faces -z of the hand frame.
"""

from __future__ import annotations

import numpy as np
import torch
import trimesh

__all__ = ["capsule_between", "hand_link_meshes", "palm_hull", "arrow_parts", "dot_mesh", "table_mesh",
           "arrow_transforms"]


def capsule_between(a: np.ndarray, b: np.ndarray, radius: float, sections: int = 32) -> trimesh.Trimesh:
    """A capsule of ``radius`` around the segment a -> b ((3,), metres), ``sections`` around its axis."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    d = b - a
    h = float(np.linalg.norm(d))
    m = trimesh.creation.capsule(height=max(h, 1e-9), radius=float(radius), count=[sections, sections // 2 + 2])
    # trimesh's capsule runs along z from 0 to height (older versions: centred); re-centre it either way.
    zmin, zmax = m.bounds[0, 2] + radius, m.bounds[1, 2] - radius
    m.apply_translation([0.0, 0.0, -0.5 * (zmin + zmax)])
    z = d / h if h > 1e-9 else np.array([0.0, 0.0, 1.0])
    T = np.eye(4)
    T[:3, :3] = _frame_with_z(z)
    T[:3, 3] = 0.5 * (a + b)
    m.apply_transform(T)
    return m


def _frame_with_z(z: np.ndarray) -> np.ndarray:
    """A rotation whose third column is the unit vector ``z``."""
    z = z / np.linalg.norm(z)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def palm_hull(hand, sections: int = 24) -> trimesh.Trimesh | None:
    """A rounded palm in the root link's frame: the convex hull of the root link's capsule and the capsules of the
    palm-level links (metacarpals of all fingers but the thumb) at the rest pose. None if there is nothing to hull.
    """
    q = hand.q_rest.reshape(1, -1)
    T = hand.forward_kinematics(q)[0].detach().cpu().to(torch.float64).numpy()  # (L, 4, 4), root frame
    a, b = hand.capsule_a.detach().cpu().double().numpy(), hand.capsule_b.detach().cpu().double().numpy()
    r = hand.capsule_radius.detach().cpu().double().numpy()
    links = [0]
    names = [str(n) for n in hand.finger_names]
    for f, row in enumerate(hand.finger_links.tolist()):
        first = row[0]
        if first >= 0 and names[f] != "thumb" and "metacarpal" in hand.link_names[first]:
            links.append(first)
    pts = []
    for li in links:
        if r[li] <= 0:
            continue
        cap = capsule_between(a[li], b[li], r[li], sections)
        pts.append(cap.vertices @ T[li, :3, :3].T + T[li, :3, 3])
    if len(pts) < 2:
        return None
    hull = trimesh.convex.convex_hull(np.concatenate(pts))
    return hull


def hand_link_meshes(hand, sections: int = 32) -> list[tuple[int, trimesh.Trimesh]]:
    """(link index, link-frame mesh) pairs that draw ``hand``. A hand whose collision geometry is all capsules (the
    built-in hand): a capsule per link plus the palm hull on the root link. Any other (a robot hand from MJCF):
    its own collision geoms, boxes and meshes as they are."""
    from torchhand.hand._link_geometry import link_geom_meshes
    from torchhand.hand.model import GEOM_TYPES

    if any(GEOM_TYPES[t] != "capsule" for t in hand.geoms.type.tolist()):
        return [(li, trimesh.util.concatenate(ms)) for li, ms in sorted(link_geom_meshes(hand).items())]
    a, b = hand.capsule_a.detach().cpu().double().numpy(), hand.capsule_b.detach().cpu().double().numpy()
    r = hand.capsule_radius.detach().cpu().double().numpy()
    out = []
    palm = palm_hull(hand)
    if palm is not None:
        out.append((0, palm))
    for li in range(hand.num_links):
        if r[li] > 0 and not (li == 0 and palm is not None):
            out.append((li, capsule_between(a[li], b[li], r[li], sections)))
    return out


def dot_mesh(radius: float) -> trimesh.Trimesh:
    """A sphere of ``radius`` metres at the origin (a contact marker)."""
    return trimesh.creation.icosphere(subdivisions=2, radius=float(radius))


def arrow_parts(shaft_radius: float, head_radius: float, head_length: float) -> tuple[trimesh.Trimesh,
                                                                                        trimesh.Trimesh]:
    """An arrow along +z: a shaft of unit length (z in [0, 1], scaled per arrow) and a head whose tip is at z = 0
    pointing to +z from z = -head_length (placed at the arrow's end)."""
    shaft = trimesh.creation.cylinder(radius=shaft_radius, height=1.0, sections=16)
    shaft.apply_translation([0.0, 0.0, 0.5 - 0.5 * (shaft.bounds[0, 2] + shaft.bounds[1, 2])])
    head = trimesh.creation.cone(radius=head_radius, height=head_length, sections=20)
    head.apply_translation([0.0, 0.0, -head_length - head.bounds[0, 2]])
    return shaft, head


def arrow_transforms(tail: np.ndarray, vec: np.ndarray, head_length: float) -> tuple[np.ndarray, np.ndarray]:
    """Instance transforms for arrows from ``tail`` along ``vec`` ((N, 3), metres): shaft (N, 4, 4) with its
    length scaled to ``|vec| - head_length`` and head (N, 4, 4) at the tip."""
    n = len(tail)
    length = np.linalg.norm(vec, axis=-1)
    shaft = np.tile(np.eye(4), (n, 1, 1))
    head = np.tile(np.eye(4), (n, 1, 1))
    for i in range(n):
        R = _frame_with_z(vec[i] if length[i] > 1e-12 else np.array([0.0, 0.0, 1.0]))
        shaft[i, :3, :3] = R @ np.diag([1.0, 1.0, max(length[i] - head_length, 1e-6)])
        shaft[i, :3, 3] = tail[i]
        head[i, :3, :3] = R
        head[i, :3, 3] = tail[i] + vec[i]
    return shaft, head


def table_mesh(center_xy: np.ndarray, height: float, half_size: float, thickness: float = 0.02) -> trimesh.Trimesh:
    """A table top: a box of side ``2 half_size`` whose upper face is the plane z = ``height``."""
    m = trimesh.creation.box(extents=[2 * half_size, 2 * half_size, thickness])
    m.apply_translation([float(center_xy[0]), float(center_xy[1]), height - 0.5 * thickness])
    return m
