"""Geometry derived from a hand's collision geoms when a model is built: surface samples and one capsule per link.

Deterministic: samples are drawn from a fixed random stream (seed 0), so they are part of the model. Conventions: metres, link
frames, MJCF size semantics (:class:`torchhand.hand.model.GeomSpec`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import torch
import trimesh

from ._specs import GEOM_TYPES

if TYPE_CHECKING:  # pragma: no cover
    from ._specs import GeomSpec

__all__ = ["surface_samples", "fit_capsules", "geom_points", "geom_trimesh", "link_geom_meshes"]


def geom_points(g: GeomSpec, n_hint: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Deterministic surface points (n, 3), outward normals and area of one geom, in the LINK frame."""
    size = np.resize(np.asarray(g.size, dtype=np.float64), 3)
    if g.type in ("capsule", "cylinder", "sphere"):
        r = size[0]
        h = size[1] if g.type != "sphere" else 0.0
        if g.type == "capsule" or g.type == "sphere":
            area = 4 * math.pi * r * r + 2 * math.pi * r * 2 * h
        else:
            area = 2 * math.pi * r * 2 * h + 2 * math.pi * r * r
        n = max(n_hint, 8)
        # Fibonacci points on a unit sphere, stretched into the capsule's cylinder part by their z.
        k = np.arange(n) + 0.5
        z = 1 - 2 * k / n
        phi = math.pi * (3 - math.sqrt(5)) * k
        rho = np.sqrt(np.clip(1 - z * z, 0, 1))
        d = np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)
        if g.type == "cylinder":
            # Sides, caps: map by the unit direction's dominant part.
            side = np.abs(z) < 0.5
            p = np.where(side[:, None], np.stack([r * d[:, 0] / np.maximum(rho, 1e-9), r * d[:, 1] /
                                                 np.maximum(rho, 1e-9), h * z / 0.5], 1),
                         np.stack([r * d[:, 0], r * d[:, 1], np.sign(z) * h], 1))
            nrm = np.where(side[:, None], np.stack([d[:, 0], d[:, 1], 0 * z], 1) / np.maximum(rho, 1e-9)[:, None],
                           np.stack([0 * z, 0 * z, np.sign(z)], 1))
        else:
            # Place sphere points on hemispherical caps and stretch a band over the cylinder: the total fraction
            # on the cylinder part matches its share of the area.
            frac = (2 * math.pi * r * 2 * h) / area if area > 0 else 0.0
            zc = np.where(np.abs(z) < frac, z / max(frac, 1e-12) * h, np.sign(z) * h)
            zs = np.where(np.abs(z) < frac, 0.0, (np.abs(z) - frac) / max(1 - frac, 1e-12) * np.sign(z))
            rs = np.sqrt(np.clip(1 - zs * zs, 0, 1))
            nrm = np.stack([rs * np.cos(phi), rs * np.sin(phi), zs], 1)
            p = r * nrm + np.stack([0 * z, 0 * z, zc], 1)
    elif g.type == "box":
        m = trimesh.creation.box(extents=2 * size)
        p, nrm, area = _mesh_points(np.asarray(m.vertices), np.asarray(m.faces), n_hint)
    else:
        p, nrm, area = _mesh_points(np.asarray(g.mesh[0]), np.asarray(g.mesh[1]), n_hint)
    R, tr = g.pose[:3, :3], g.pose[:3, 3]
    return p @ R.T + tr, nrm @ R.T, area


def _mesh_points(V: np.ndarray, Fc: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, float]:
    tri = V[Fc]
    cr = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    areas = 0.5 * np.linalg.norm(cr, axis=1)
    area = float(areas.sum())
    if area <= 0:
        return np.zeros((0, 3)), np.zeros((0, 3)), 0.0
    g = torch.Generator().manual_seed(0)  # fixed stream: samples are part of the model and must be reproducible
    face = torch.multinomial(torch.as_tensor(areas), max(n, 1), replacement=True, generator=g).numpy()
    uv = torch.rand(len(face), 2, generator=g, dtype=torch.float64).numpy()
    flip = uv.sum(1) > 1
    uv[flip] = 1 - uv[flip]
    t = tri[face]
    p = t[:, 0] + uv[:, :1] * (t[:, 1] - t[:, 0]) + uv[:, 1:] * (t[:, 2] - t[:, 0])
    nrm = cr[face] / np.maximum(np.linalg.norm(cr[face], axis=1, keepdims=True), 1e-18)
    return p, nrm, area


def surface_samples(L, geoms, lidx, density, min_per_link):
    pts, nrm, lnk = [], [], []
    # First pass for areas, second for points so that every link gets at least min_per_link.
    areas = [geom_points(g, 8)[2] for g in geoms]
    link_area = np.zeros(L)
    for g, a in zip(geoms, areas):
        link_area[lidx[g.link]] += a
    for g, a in zip(geoms, areas):
        li = lidx[g.link]
        share = a / link_area[li] if link_area[li] > 0 else 1.0
        n = int(max(round(a * density), math.ceil(min_per_link * share)))
        p, nn, _ = geom_points(g, n)
        pts.append(p)
        nrm.append(nn)
        lnk.append(np.full(len(p), li, dtype=np.int64))
    if not pts:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    return np.concatenate(pts), np.concatenate(nrm), np.concatenate(lnk)


def fit_capsules(L, geoms, lidx):
    """One capsule per link approximating its geometry (finger-finger checks, penetration proxies): a capsule geom
    is used as is; otherwise the segment runs along the principal axis of the geometry's points, with the 90th
    percentile of their distance to the axis as radius, or the geometry's half-thickness (along its least principal
    axis) when that is smaller (flat links)."""
    a = np.zeros((L, 3))
    b = np.zeros((L, 3))
    r = np.zeros(L)
    for li in range(L):
        gs = [g for g in geoms if lidx[g.link] == li]
        if not gs:
            continue
        caps = [g for g in gs if g.type == "capsule"]
        if len(gs) == 1 and caps:
            g = caps[0]
            R, tr = g.pose[:3, :3], g.pose[:3, 3]
            h = float(np.resize(g.size, 3)[1])
            a[li] = tr - R[:, 2] * h
            b[li] = tr + R[:, 2] * h
            r[li] = float(np.resize(g.size, 3)[0])
            continue
        p = np.concatenate([geom_points(g, 200)[0] for g in gs])
        c = p.mean(0)
        _, _, vt = np.linalg.svd(p - c, full_matrices=False)
        ax = vt[0]
        s = (p - c) @ ax
        radial = np.linalg.norm((p - c) - np.outer(s, ax), axis=1)
        # a flat link (a robot palm plate) gets its half-thickness, not its half-width: a capsule around the
        # whole plate would stand centimetres off its faces; the plate's faces are covered by the surface samples
        thick = float(np.abs((p - c) @ vt[2]).max())
        rad = min(float(np.percentile(radial, 90)), thick)
        lo, hi = s.min() + rad, s.max() - rad
        if lo > hi:
            lo = hi = 0.5 * (s.min() + s.max())
        a[li], b[li], r[li] = c + lo * ax, c + hi * ax, rad
    return a, b, r


def geom_trimesh(kind: str, size, mesh=None, *, sections: int = 16) -> trimesh.Trimesh:
    """A triangle mesh of one collision geom in its own frame, MJCF size semantics: capsule and cylinder along z
    (radius, half-length), sphere (radius), box (half-extents), mesh (vertices (V, 3), faces (F, 3))."""
    s = np.resize(np.asarray(size, dtype=np.float64), 3)
    if kind == "capsule":
        m = trimesh.creation.capsule(height=2 * s[1], radius=s[0], count=[sections, sections // 2 + 2])
        m.apply_translation(-0.5 * (m.bounds[0] + m.bounds[1]))       # centred (trimesh versions differ)
        return m
    if kind == "sphere":
        return trimesh.creation.icosphere(subdivisions=2, radius=s[0])
    if kind == "cylinder":
        return trimesh.creation.cylinder(radius=s[0], height=2 * s[1], sections=sections)
    if kind == "box":
        return trimesh.creation.box(extents=2 * s)
    V, F = mesh
    return trimesh.Trimesh(np.asarray(V, dtype=np.float64), np.asarray(F), process=False)


def link_geom_meshes(model, *, sections: int = 16) -> dict[int, list[trimesh.Trimesh]]:
    """link index -> the link's collision geoms as triangle meshes in the link frame (:func:`geom_trimesh`)."""
    g = model.geoms
    size = g.size.detach().cpu().double().numpy()
    pose = g.pose.detach().cpu().double().numpy()
    out: dict[int, list[trimesh.Trimesh]] = {}
    for i, (link, t) in enumerate(zip(g.link.tolist(), g.type.tolist())):
        kind = GEOM_TYPES[t]
        mesh = None
        if kind == "mesh":
            mv, mf = g.meshes[int(g.mesh_index[i])]
            mesh = (mv.detach().cpu().double().numpy(), mf.detach().cpu().numpy())
        m = geom_trimesh(kind, size[i], mesh, sections=sections)
        m.apply_transform(pose[i])
        out.setdefault(link, []).append(m)
    return out
