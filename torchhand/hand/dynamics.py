"""Rigid-body dynamics of a hand on a floating root: point Jacobians, mass matrix, gravity and contact torques.

Generalized coordinates (N = 6 + D)
    velocity ``nu = (w, v, qdot)``: ``w (3)`` the world angular velocity of the root frame, ``v (3)`` the world
    velocity of the root origin ``o = root[:, :3, 3]`` (the point where ``root`` places the root link's parent
    frame, the wrist), then the D joint rates in ``joint_names`` order. A point ``p`` fixed on link ``l`` moves with
    ``dp/dt = w x (p - o) + v + J_q qdot``. Forces dual to ``nu`` are ``(torque about o, force, joint torques)``, all
    world frame: ``tau = J^T f`` for a world force ``f`` at ``p``.

    MuJoCo's free joint uses ``(v, R^T w)`` instead (linear velocity of the body origin in the world frame, angular
    velocity in the body frame; ``R = root[:, :3, :3]``); with ``nu_mj = S nu``,
    ``M = S^T M_mj S``, ``tau = S^T tau_mj`` and ``J = J_mj S``.

Inertials
    ``HandModel.link_mass (L,)`` kg, ``link_com (L, 3)`` metres in the link frame, ``link_inertia (L, 3, 3)`` kg m^2
    about the centre of mass in link-frame axes. Joints are independent (no equality constraints or tendons) and
    have no armature.

Formulas (J^T-based; every link at once, no loop over the batch or the links)::

    M   = sum_l  Jv_l^T m_l Jv_l + Jw_l^T (R_l I_l R_l^T) Jw_l      (Jv_l at the link's centre of mass)
    tau_gravity = - sum_l Jv_l^T m_l g                              (the generalized force that holds the hand still)

``tau_gravity`` has the sign of MuJoCo's ``qfrc_bias`` at zero velocity. Memory grows as B L (6 + D)^2.

The first section builds link inertials from geometry (NumPy, float64, used when models are built); the second
holds the batched functions (torch; float32 and float64; CPU and CUDA; device and dtype from ``q``).
Conventions: metres, kilograms, seconds, newtons, radians; column-vector 4x4 transforms (see
:mod:`torchhand.conventions`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import torch

from torchhand.kernels import kinematics as _kin
from torchhand.kernels.kinematics import JOINT_HINGE

from ..conventions import check_tensor
from ..errors import InputValueError, ShapeError, UnknownNameError

if TYPE_CHECKING:  # pragma: no cover
    from .model import HandModel

__all__ = [
    "DEFAULT_DENSITY",
    "primitive_inertial",
    "mesh_inertial",
    "transform_inertial",
    "combine_inertials",
    "geom_inertial",
    "link_inertials",
    "point_jacobian",
    "kinematic_frames",
    "point_jacobian_at",
    "mass_matrix",
    "gravity_torques",
    "contact_torques",
]

DEFAULT_DENSITY = 1000.0
"""kg/m^3: water, MuJoCo's default geom density; used for links whose inertial comes from their geometry."""

_MIN_VOLUME = 1e-15  # m^3, MuJoCo's mjMINVAL: a mesh enclosing less is massless


# ----------------------------------------------------------------------------------------------------------------
# Link inertials from geometry (NumPy, float64)
# ----------------------------------------------------------------------------------------------------------------
# An inertial is a triple (mass kg, com (3,) metres, inertia (3, 3) kg m^2 about com), all in one frame.


def primitive_inertial(gtype: str, size, density: float, mass: float | None = None):
    """Solid primitive of uniform density, in its own geom frame (MJCF size semantics, axis along z).

    gtype:   "sphere" (radius), "capsule" / "cylinder" (radius, half-length), "box" (half-extents),
             "ellipsoid" (semi-axes)
    density: kg/m^3, used when ``mass`` is None; mass: kg, overrides the density (MuJoCo's geom ``mass``)
    returns: (mass, com (3,) = 0, inertia (3, 3) diagonal about the centre); the formulas are MuJoCo's (exact)
    """
    s = np.resize(np.asarray(size, dtype=np.float64), 3)
    r = s[0]
    if gtype == "sphere":
        vol = 4 * math.pi * r ** 3 / 3
    elif gtype == "capsule":
        vol = math.pi * (r * r * 2 * s[1] + 4 * r ** 3 / 3)
    elif gtype == "cylinder":
        vol = math.pi * r * r * 2 * s[1]
    elif gtype == "box":
        vol = 8 * s[0] * s[1] * s[2]
    elif gtype == "ellipsoid":
        vol = 4 * math.pi * s[0] * s[1] * s[2] / 3
    else:
        raise InputValueError(f"gtype: expected sphere, capsule, cylinder, box or ellipsoid, got {gtype!r}")
    m = density * vol if mass is None else float(mass)
    if gtype == "sphere":
        d = np.full(3, 2 * m * r * r / 5)
    elif gtype == "capsule":
        h = 2 * s[1]
        ms = m * 4 * r / (4 * r + 3 * h)  # the two hemispheres
        mc = m - ms
        ix = mc * (3 * r * r + h * h) / 12 + 2 * ms * r * r / 5 + ms * h * (3 * r + 2 * h) / 8
        d = np.array([ix, ix, mc * r * r / 2 + 2 * ms * r * r / 5])
    elif gtype == "cylinder":
        h = 2 * s[1]
        ix = m * (3 * r * r + h * h) / 12
        d = np.array([ix, ix, m * r * r / 2])
    elif gtype == "box":
        d = m * np.array([s[1] ** 2 + s[2] ** 2, s[0] ** 2 + s[2] ** 2, s[0] ** 2 + s[1] ** 2]) / 3
    else:
        d = m * np.array([s[1] ** 2 + s[2] ** 2, s[0] ** 2 + s[2] ** 2, s[0] ** 2 + s[1] ** 2]) / 5
    return m, np.zeros(3), np.diag(d)


def mesh_inertial(vertices, faces, density: float, mass: float | None = None, mode: str = "exact", *,
                  float32: bool = False):
    """Solid of uniform density bounded by a closed triangle mesh, in the mesh's frame (MuJoCo's algorithm).

    vertices: (V, 3) metres; faces: (F, 3) vertex indices, counter-clockwise seen from outside
    density:  kg/m^3 (or ``mass`` kg, which overrides it)
    mode:     "exact": signed tetrahedra (the divergence theorem, as trimesh's mass properties); an inside-out mesh
              is flipped; "convex": exact on the convex hull; "legacy": MuJoCo's default ``<mesh inertia="legacy">``,
              every tetrahedron counted with a positive volume (exact for convex meshes, more volume otherwise)
    float32:  round vertices and face centres to float32 as MuJoCo's compiler does (to reproduce its numbers)
    returns: (mass, com (3,), inertia (3, 3) about com); zero mass for a mesh enclosing no volume

    Both passes follow MuJoCo's ``mjCMesh::Process``: tetrahedra from the area-weighted face centroid give the
    volume and centre of mass; the mesh is re-centred there and tetrahedra from the centre of mass give the final
    volume and second moments.
    """
    V = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    Fc = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if mode == "convex":
        import trimesh

        hull = trimesh.convex.convex_hull(V)
        V, Fc, mode = np.asarray(hull.vertices, dtype=np.float64), np.asarray(hull.faces, dtype=np.int64), "exact"
    if mode not in ("exact", "legacy"):
        raise InputValueError(f"mode: expected 'exact', 'convex' or 'legacy', got {mode!r}")
    V = V.astype(np.float32 if float32 else np.float64)
    cen, nrm, area = _faces(V, Fc)
    if area.sum() <= 0:
        return 0.0, V.mean(axis=0).astype(np.float64) if len(V) else np.zeros(3), np.zeros((3, 3))
    ref = (area[:, None] * cen).sum(0) / area.sum()
    vol = np.einsum("fi,fi->f", cen - ref, nrm) * area / 3
    sign = 1.0 if vol.sum() >= 0 else -1.0  # an inside-out mesh is flipped
    vol = np.abs(vol) if mode == "legacy" else sign * vol
    if vol.sum() <= _MIN_VOLUME:
        return 0.0, ref, np.zeros((3, 3))
    com = (vol[:, None] * (cen * 0.75 + ref * 0.25)).sum(0) / vol.sum()
    Vc = (V.astype(np.float64) - com).astype(V.dtype)
    cen, nrm, area = _faces(Vc, Fc)
    vol = np.einsum("fi,fi->f", cen, nrm) * area / 3
    vol = np.abs(vol) if mode == "legacy" else sign * vol
    total = float(vol.sum())
    if total <= _MIN_VOLUME:
        return 0.0, com, np.zeros((3, 3))
    # Second moments of the tetrahedra (com, D, E, F): vol / 20 * e_ij, in MuJoCo's order of operations.
    D, E, F = (Vc[Fc[:, k]][:, :, None] for k in range(3))
    Dt, Et, Ft = (x.transpose(0, 2, 1) for x in (D, E, F))
    e = 2 * (D * Dt + E * Et + F * Ft) + D * Et + Dt * E + D * Ft + Dt * F + E * Ft + Et * F  # (F, 3, 3)
    C = (vol[:, None, None] / 20 * e.astype(np.float64)).sum(0)
    m = density * total if mass is None else float(mass)
    return m, com, m / total * (np.trace(C) * np.eye(3) - C)


def _faces(V: np.ndarray, Fc: np.ndarray):
    """Centre (F, 3) (in V's precision), unit normal (F, 3) and area (F,) of every face; faces with
    |cross| < 1e-15 get zero area (MuJoCo's mjMINVAL)."""
    D, E, F = V[Fc[:, 0]], V[Fc[:, 1]], V[Fc[:, 2]]
    cen = ((D + E) + F) / V.dtype.type(3)
    cr = np.cross((E - D).astype(np.float64), (F - D).astype(np.float64))
    length = np.linalg.norm(cr, axis=1)
    ok = length >= 1e-15
    nrm = np.where(ok[:, None], cr / np.where(ok, length, 1.0)[:, None], 0.0)
    return cen.astype(np.float64), nrm, np.where(ok, length / 2, 0.0)


def transform_inertial(inertial, pose):
    """An inertial given in a frame ``pose`` (4, 4) expressed in the parent frame: com -> R com + t, I -> R I R^T."""
    m, c, I = inertial
    R, t = np.asarray(pose, dtype=np.float64)[:3, :3], np.asarray(pose, dtype=np.float64)[:3, 3]
    return m, R @ c + t, R @ I @ R.T


def combine_inertials(parts):
    """The inertial of rigidly joined parts, all in one frame (parallel-axis theorem).

    parts: iterable of (mass, com (3,), inertia (3, 3) about com)
    returns: (mass, com, inertia about com); (0, 0, 0) for no mass
    """
    parts = [(float(m), np.asarray(c, dtype=np.float64), np.asarray(I, dtype=np.float64)) for m, c, I in parts]
    mass = sum(m for m, _, _ in parts)
    if mass <= 0:
        return 0.0, np.zeros(3), np.zeros((3, 3))
    com = sum(m * c for m, c, _ in parts) / mass
    inertia = np.zeros((3, 3))
    for m, c, I in parts:
        d = c - com
        inertia += I + m * (d @ d * np.eye(3) - np.outer(d, d))
    return mass, com, 0.5 * (inertia + inertia.T)


def geom_inertial(geom, density: float = DEFAULT_DENSITY):
    """A solid collision geom of uniform ``density`` kg/m^3 in its link's frame.

    geom: :class:`~torchhand.hand.model.GeomSpec` (primitives analytically, meshes exactly, their convex hull when
          not closed, i.e. when some edge is not shared by exactly two faces)
    returns: (mass kg, com (3,) metres, inertia (3, 3) kg m^2 about com in link axes)
    """
    if geom.type == "mesh":
        V, Fc = np.asarray(geom.mesh[0], dtype=np.float64), np.asarray(geom.mesh[1], dtype=np.int64)
        edges = np.sort(Fc[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        _, counts = np.unique(edges, axis=0, return_counts=True)
        closed = len(counts) > 0 and bool((counts == 2).all())
        local = mesh_inertial(V, Fc, density, mode="exact" if closed else "convex")
    else:
        local = primitive_inertial(geom.type, geom.size, density)
    return transform_inertial(local, geom.pose)


def link_inertials(name: str, link_names, geoms, inertials, density: float = DEFAULT_DENSITY):
    """Inertials of all links: a given :class:`~torchhand.hand.model.InertialSpec`, else the link's collision geoms
    at ``density`` (:func:`geom_inertial`, summed by :func:`combine_inertials`); zero without geometry.

    name: the hand's name (for messages); link_names (L,); geoms: GeomSpecs; inertials: InertialSpecs
    returns: (mass (L,) kg, com (L, 3) metres, inertia (L, 3, 3) kg m^2), NumPy float64
    raises: UnknownNameError, InputValueError (duplicate, negative or non-finite mass, inertia not positive
        semi-definite, bad density), ShapeError
    """
    if not (isinstance(density, (int, float)) and math.isfinite(density) and density >= 0):
        raise InputValueError(f"density: expected a finite non-negative number (kg/m^3), got {density!r}")
    lidx = {n: i for i, n in enumerate(link_names)}
    L = len(link_names)
    given = {}
    for spec in inertials:
        if spec.link not in lidx:
            raise UnknownNameError(f"inertial refers to unknown link {spec.link!r}")
        if spec.link in given:
            raise InputValueError(f"hand {name!r}: link {spec.link!r} has more than one inertial")
        m = float(spec.mass)
        c = np.asarray(spec.com, dtype=np.float64)
        inertia = np.asarray(spec.inertia, dtype=np.float64)
        if c.shape != (3,) or inertia.shape != (3, 3):
            raise ShapeError(f"inertial of link {spec.link!r}: expected com (3,) and inertia (3, 3), got "
                             f"{c.shape} and {inertia.shape}")
        if not (math.isfinite(m) and m >= 0 and np.isfinite(c).all() and np.isfinite(inertia).all()):
            raise InputValueError(f"inertial of link {spec.link!r}: mass must be finite and >= 0, com and inertia "
                                  f"finite; got mass {m}")
        inertia = 0.5 * (inertia + inertia.T)
        if np.linalg.eigvalsh(inertia).min() < -1e-9 * float(np.abs(inertia).max()):
            raise InputValueError(f"inertial of link {spec.link!r}: inertia is not positive semi-definite")
        given[spec.link] = (m, c, inertia)
    per_link = [[] for _ in range(L)]
    for g in geoms:
        per_link[lidx[g.link]].append(g)
    mass, com, inertia = np.zeros(L), np.zeros((L, 3)), np.zeros((L, 3, 3))
    for lname, li in lidx.items():
        part = given.get(lname)
        if part is None:
            part = combine_inertials(geom_inertial(g, density) for g in per_link[li])
        mass[li], com[li], inertia[li] = part
    return mass, com, inertia


# ----------------------------------------------------------------------------------------------------------------
# Batched dynamics (torch)
# ----------------------------------------------------------------------------------------------------------------
def _skew(v: torch.Tensor) -> torch.Tensor:
    """[v]x (..., 3, 3) of v (..., 3): [v]x u = v x u."""
    x, y, z = v.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack([o, -z, y, z, o, -x, -y, x, o], dim=-1).reshape(*v.shape, 3)


def _root_columns(r: torch.Tensor) -> torch.Tensor:
    """d p / d (w, v) for points at ``r = p - o`` (..., 3): (..., 3, 6) = [-[r]x, I]."""
    eye = torch.eye(3, dtype=r.dtype, device=r.device).expand(*r.shape[:-1], 3, 3)
    return torch.cat([-_skew(r), eye], dim=-1)


def point_jacobian(hand: "HandModel", q: torch.Tensor, link_index, points_local: torch.Tensor,
                   root: torch.Tensor | None = None, *, wrt_root: bool = True, check: bool = False) -> torch.Tensor:
    """Jacobian of link-fixed points with respect to the root twist and the joints.

    hand:         HandModel
    q:            joint values, (B, D), radians / metres
    link_index:   link of each point, (P,), long
    points_local: points in their link's frame, (P, 3) or (B, P, 3), metres
    root:         world pose of the root link's parent frame, (B, 4, 4); None = identity
    wrt_root:     True: (B, P, 3, 6 + D), root columns (w: 3, v: 3; see the module docstring) first;
                  False: (B, P, 3, D), the joint columns only (``HandModel.point_jacobian``)
    check:        also check q for NaN and root for rigidity (forces a host sync)
    returns: d p_world / d nu, metres per radian / dimensionless
    """
    q, root = hand._inputs(q, root, check)
    link_index, points_local = hand._point_args(q, link_index, points_local)
    _, x, Jq = _kin.fk_and_point_jacobian(hand._chain(q), q, root, link_index, points_local)
    if not wrt_root:
        return Jq
    return torch.cat([_root_columns(x - root[:, None, :3, 3]), Jq], dim=-1)


def kinematic_frames(hand: "HandModel", q: torch.Tensor, root: torch.Tensor) -> _kin.Frames:
    """One kinematics pass at (q, root), (B, D) and (B, 4, 4): link poses ``.poses`` (B, L, 4, 4) and what
    :func:`point_jacobian_at` needs to give the Jacobians of any link-fixed points there without repeating it."""
    return _kin.frames(hand._chain(q), q, root)


def point_jacobian_at(hand: "HandModel", fr: _kin.Frames, root: torch.Tensor, link_index: torch.Tensor,
                      points_local: torch.Tensor) -> torch.Tensor:
    """:func:`point_jacobian` (``wrt_root=True``) at the configuration of ``fr`` (:func:`kinematic_frames`, taken
    at the same ``root``): (B, P, 3, 6 + D); the same values, without a second kinematics pass."""
    x, Jq = _kin.frames_point_jacobian(hand.chain, fr, link_index, points_local)
    return torch.cat([_root_columns(x - root[:, None, :3, 3]), Jq], dim=-1)


def _link_jacobians(hand: "HandModel", q: torch.Tensor, root: torch.Tensor):
    """Jacobians of every link's centre of mass (linear) and of its rotation (angular).

    returns: (R_world_link (B, L, 3, 3), Jv (B, L, 3, 6 + D), Jw (B, L, 3, 6 + D))
    """
    chain = hand._chain(q)
    T, axis, anchor = _kin.joint_frames(chain, q, root)  # (B, L, 4, 4), (B, D, 3), (B, D, 3)
    B, L = T.shape[:2]
    R = T[..., :3, :3]
    com = (R @ hand.link_com.to(q).unsqueeze(-1)).squeeze(-1) + T[..., :3, 3]  # (B, L, 3)
    support = chain.support.to(q.dtype).unsqueeze(-1)  # (L, D, 1)
    hinge = (chain.joint_type == JOINT_HINGE).to(q.dtype).unsqueeze(-1)  # (D, 1)
    a = axis.unsqueeze(1)  # (B, 1, D, 3)
    r = com.unsqueeze(2) - anchor.unsqueeze(1)  # (B, L, D, 3)
    lin = (torch.linalg.cross(a.expand_as(r), r, dim=-1) * hinge + a * (1 - hinge)) * support
    ang = a * (hinge * support)  # (B, L, D, 3)
    Jv = torch.cat([_root_columns(com - root[:, None, :3, 3]), lin.transpose(-1, -2)], dim=-1)
    eye = torch.eye(3, dtype=q.dtype, device=q.device).expand(B, L, 3, 3)
    Jw = torch.cat([eye, torch.zeros_like(eye), ang.expand(B, L, -1, 3).transpose(-1, -2)], dim=-1)
    return R, Jv, Jw


def mass_matrix(hand: "HandModel", q: torch.Tensor, root: torch.Tensor | None = None, *,
                check: bool = False) -> torch.Tensor:
    """Joint-space inertia matrix of the floating hand.

    q:    (B, D), radians / metres; root: (B, 4, 4) or None (identity)
    returns: M, (B, 6 + D, 6 + D), symmetric positive semi-definite (definite when every DOF moves mass), in the
        coordinates of the module docstring: kinetic energy = nu^T M nu / 2; kg, kg m, kg m^2
    """
    q, root = hand._inputs(q, root, check)
    R, Jv, Jw = _link_jacobians(hand, q, root)
    Iw = R @ hand.link_inertia.to(q) @ R.transpose(-1, -2)  # (B, L, 3, 3) world axes, about each com
    mJv = Jv * hand.link_mass.to(q).view(1, -1, 1, 1)
    M = torch.einsum("blin,blim->bnm", Jv, mJv) + torch.einsum("blin,blim->bnm", Jw, Iw @ Jw)
    return 0.5 * (M + M.transpose(-1, -2))


def _gravity(gravity, q: torch.Tensor) -> torch.Tensor:
    g = torch.as_tensor(gravity, dtype=q.dtype, device=q.device)
    if g.dim() == 1:
        check_tensor(g, "gravity", (3,))
        g = g.expand(q.shape[0], 3)
    else:
        check_tensor(g, "gravity", (q.shape[0], 3))
    return g


def gravity_torques(hand: "HandModel", q: torch.Tensor, root: torch.Tensor | None = None,
                    gravity=(0.0, 0.0, -9.81), *, check: bool = False) -> torch.Tensor:
    """Generalized force that holds the hand still against gravity (MuJoCo's ``qfrc_bias`` at zero velocity).

    q:       (B, D), radians / metres; root: (B, 4, 4) or None (identity)
    gravity: world gravity, (3,) or (B, 3), m/s^2
    returns: (B, 6 + D): torque about the root origin (world, N m), force (world, N), joint torques (N m or N)
    """
    q, root = hand._inputs(q, root, check)
    g = _gravity(gravity, q)
    _, Jv, _ = _link_jacobians(hand, q, root)
    f = hand.link_mass.to(q).view(1, -1, 1) * g.unsqueeze(1)  # (B, L, 3) weight of each link
    return -torch.einsum("blin,bli->bn", Jv, f)


def contact_torques(hand: "HandModel", q: torch.Tensor, root: torch.Tensor | None, link_index,
                    points_local: torch.Tensor, forces: torch.Tensor, *, check: bool = False) -> torch.Tensor:
    """Generalized force J^T f of world forces applied at link-fixed points.

    q:            (B, D), radians / metres; root: (B, 4, 4) or None (identity)
    link_index:   link of each point, (P,), long
    points_local: points in their link's frame, (P, 3) or (B, P, 3), metres
    forces:       world forces at the points, (B, P, 3), newtons (zero rows for padding)
    returns: (B, 6 + D): torque about the root origin (world, N m), force (world, N), joint torques (N m or N)
    """
    J = point_jacobian(hand, q, link_index, points_local, root, check=check)
    B, P = J.shape[:2]
    check_tensor(forces, "forces", (B, P, 3))
    if forces.dtype != q.dtype:
        raise InputValueError(f"forces: dtype {forces.dtype} differs from q's {q.dtype}")
    return torch.einsum("bpin,bpi->bn", J, forces)


def _check_inertials(mass, com, inertia, L: int) -> None:
    """Shapes of the inertial fields (used by HandModel)."""
    for name, x, shape in (("link_mass", mass, (L,)), ("link_com", com, (L, 3)), ("link_inertia", inertia, (L, 3, 3))):
        if tuple(x.shape) != shape:
            raise ShapeError(f"{name}: expected shape {shape}, got {tuple(x.shape)}")
