"""The typed hand model: a frozen dataclass of tensors, built once and moved with ``.to(device, dtype)``.

A hand is a kinematic tree of links (MJCF bodies) moved by hinge and slide joints, with collision geometry per link,
surface samples for penetration checks, and per-finger annotations (distal link, nail normal, fingertip pad point,
the three flexion joints coupled by Ye & Liu's Eq. 11). Built from plain specs by :func:`build_hand_model`; the
default 36-DOF human hand is in :mod:`torchhand.hand.default`, MJCF import/export in :mod:`torchhand.hand.mjcf`.

Conventions (see :mod:`torchhand.conventions`): metres, radians, column-vector 4x4 transforms; the root link
(index 0) is the wrist frame whose world pose is the 6-DOF root input.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from torchhand.kernels.kinematics import JOINT_HINGE, JOINT_SLIDE, Chain
from torchhand.kernels import kinematics as _kin

from . import dynamics as _dyn
from ._link_geometry import fit_capsules as _fit_capsules
from ._link_geometry import surface_samples as _surface_samples
from .._tree import tree_to
from ..conventions import check_finite, check_tensor, check_transforms
from ..errors import InputValueError, ShapeError, UnknownNameError

__all__ = [
    "GEOM_TYPES",
    "LinkSpec",
    "JointSpec",
    "GeomSpec",
    "FingerSpec",
    "InertialSpec",
    "LinkGeoms",
    "HandModel",
    "build_hand_model",
]

GEOM_TYPES = ("capsule", "box", "sphere", "cylinder", "mesh")


# ----------------------------------------------------------------------------------------------------------------
# Plain specs (NumPy, float64) from which a model is built
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LinkSpec:
    """name; parent link name (None for the root, which must come first); offset: parent -> link at q = 0, (4, 4)."""

    name: str
    parent: str | None
    offset: np.ndarray


@dataclass(frozen=True)
class JointSpec:
    """A 1-DOF joint moving ``link``. axis (3,) and anchor (3,) in the link frame; limits (2,) radians or metres."""

    name: str
    link: str
    type: str  # "hinge" | "slide"
    axis: np.ndarray
    anchor: np.ndarray
    limits: np.ndarray


@dataclass(frozen=True)
class GeomSpec:
    """Collision geometry on a link, with MJCF's size semantics.

    type: capsule (radius, half-length), cylinder (radius, half-length), sphere (radius), box (half-extents),
    mesh (vertices (V, 3) and faces (F, 3) in the geom frame); pose: geom frame in the link frame, (4, 4); the axis
    of capsules and cylinders is the geom frame's z.
    """

    link: str
    type: str
    size: np.ndarray
    pose: np.ndarray
    mesh: tuple[np.ndarray, np.ndarray] | None = None
    name: str | None = None


@dataclass(frozen=True)
class FingerSpec:
    """A finger (digit): its links from proximal to distal, the nail normal and pad point in the distal link's frame,
    and up to three consecutive flexion joints coupled in Eq. 11 (proximal first; empty when not applicable)."""

    name: str
    links: tuple[str, ...]
    nail_normal: np.ndarray
    tip: np.ndarray
    flexion_joints: tuple[str, ...] = ()


@dataclass(frozen=True)
class InertialSpec:
    """Mass properties of a link: mass, kg; com: centre of mass in the link frame, (3,), metres; inertia: about the
    centre of mass in link-frame axes, (3, 3), kg m^2 (symmetric positive semi-definite)."""

    link: str
    mass: float
    com: np.ndarray
    inertia: np.ndarray


# ----------------------------------------------------------------------------------------------------------------
# The model
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LinkGeoms:
    """Padded collision geometry of all links (G geoms).

    link:       link index of each geom, (G,), long
    type:       index into GEOM_TYPES, (G,), long
    size:       MJCF size triple, (G, 3), metres
    pose:       geom frame in its link frame, (G, 4, 4)
    mesh_index: index into ``meshes`` for mesh geoms, -1 otherwise, (G,), long
    meshes:     tuple of (vertices (V, 3) metres, faces (F, 3) long) in the geom frame
    """

    link: torch.Tensor
    type: torch.Tensor
    size: torch.Tensor
    pose: torch.Tensor
    mesh_index: torch.Tensor
    meshes: tuple = ()


@dataclass(frozen=True)
class HandModel:
    """A hand: kinematic tree, limits, collision geometry, surface samples and finger annotations.

    L links, D joints, G geoms, S surface samples, F fingers, Q collision pairs. Fields:

    name, side ("right" | "left" | "none"), length: wrist-to-middle-fingertip length, metres (0 if unknown)
    link_names (L,), joint_names (D,): names; ``link_names[0]`` is the root (wrist / palm) link
    chain: :class:`~torchhand.kernels.kinematics.Chain`, the tensors the kinematics kernels read
    joint_limits: (D, 2), radians / metres; q_rest: rest pose, (D,)
    geoms: :class:`LinkGeoms`
    capsule_a, capsule_b: (L, 3) link-local capsule segment ends fitted to each link, metres; capsule_radius (L,)
        (0 for links without geometry)
    sample_points (S, 3) link-local, metres; sample_normals (S, 3) outward unit; sample_link (S,) long
    finger_names (F,); finger_links (F, 4) long link indices proximal -> distal, padded with -1;
    link_finger (L,) long finger index of each link, -1 for the palm; links between the palm and a finger's first
        link (a robot finger's base, not in finger_links) count as that finger's;
    distal_link (F,) long; nail_normal (F, 3) unit, distal-link frame; fingertip (F, 3) pad point, distal frame;
    flexion_joints (F, 3) long joint indices for Eq. 11, -1 where not applicable
    collision_pairs (Q, 2) long: link pairs of different fingers checked for finger-finger interpenetration
    link_mass: mass of each link, (L,), kg
    link_com: centre of mass of each link in its frame, (L, 3), metres
    link_inertia: inertia of each link about its centre of mass in link-frame axes, (L, 3, 3), kg m^2
        (the three inertial fields default to zero: a model constructed without them is massless; see
        :func:`build_hand_model` and :mod:`torchhand.hand.dynamics`)
    """

    name: str
    side: str
    length: float
    link_names: tuple
    joint_names: tuple
    chain: Chain
    joint_limits: torch.Tensor
    q_rest: torch.Tensor
    geoms: LinkGeoms
    capsule_a: torch.Tensor
    capsule_b: torch.Tensor
    capsule_radius: torch.Tensor
    sample_points: torch.Tensor
    sample_normals: torch.Tensor
    sample_link: torch.Tensor
    finger_names: tuple
    finger_links: torch.Tensor
    link_finger: torch.Tensor
    distal_link: torch.Tensor
    nail_normal: torch.Tensor
    fingertip: torch.Tensor
    flexion_joints: torch.Tensor
    collision_pairs: torch.Tensor
    _index: dict = field(default_factory=dict, compare=False, repr=False)
    link_mass: torch.Tensor | None = None
    link_com: torch.Tensor | None = None
    link_inertia: torch.Tensor | None = None

    def __post_init__(self):
        L = len(self.link_names)
        like = self.joint_limits
        if self.link_mass is None:
            object.__setattr__(self, "link_mass", like.new_zeros(L))
        if self.link_com is None:
            object.__setattr__(self, "link_com", like.new_zeros(L, 3))
        if self.link_inertia is None:
            object.__setattr__(self, "link_inertia", like.new_zeros(L, 3, 3))
        _dyn._check_inertials(self.link_mass, self.link_com, self.link_inertia, L)

    # --- sizes and names --------------------------------------------------------------------------------------
    @property
    def num_links(self) -> int:
        return len(self.link_names)

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    @property
    def num_fingers(self) -> int:
        return len(self.finger_names)

    @property
    def total_mass(self) -> float:
        """Sum of ``link_mass``, kg (a host sync on GPUs)."""
        return float(self.link_mass.sum())

    @property
    def dtype(self) -> torch.dtype:
        return self.joint_limits.dtype

    @property
    def device(self) -> torch.device:
        return self.joint_limits.device

    def link_index(self, name: str) -> int:
        """Index of link ``name``; :class:`UnknownNameError` lists the known names otherwise."""
        try:
            return self.link_names.index(name)
        except ValueError:
            raise UnknownNameError(f"unknown link {name!r}; known links: {', '.join(self.link_names)}") from None

    def joint_index(self, name: str) -> int:
        """Index of joint ``name``; :class:`UnknownNameError` lists the known names otherwise."""
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise UnknownNameError(f"unknown joint {name!r}; known joints: {', '.join(self.joint_names)}") from None

    def to(self, device=None, dtype: torch.dtype | None = None) -> "HandModel":
        """Copy with tensors on ``device``; floating tensors cast to ``dtype`` (index tensors keep theirs)."""
        return tree_to(self, device=device, dtype=dtype)

    # --- kinematics ---------------------------------------------------------------------------------------------
    def _inputs(self, q: torch.Tensor, root: torch.Tensor | None, check: bool):
        check_tensor(q, "q", (None, self.num_joints))
        B = q.shape[0]
        if root is None:
            root = torch.eye(4, dtype=q.dtype, device=q.device).expand(B, 4, 4)
        else:
            check_tensor(root, "root", (B, 4, 4))
            if root.dtype != q.dtype:
                raise InputValueError(f"root: dtype {root.dtype} differs from q's {q.dtype}")
        if check:
            check_finite(q, "q")
            check_transforms(root, "root")
        return q, root

    def _chain(self, q: torch.Tensor) -> Chain:
        if self.chain.link_offset.device != q.device:
            raise InputValueError(f"q is on {q.device} but the hand model is on {self.device}; use hand.to(device)")
        return self.chain

    def forward_kinematics(self, q: torch.Tensor, root: torch.Tensor | None = None, *, check: bool = False):
        """World poses of the links.

        q:    joint values in ``joint_names`` order, (B, D), radians (hinge) / metres (slide)
        root: world pose of the root link's parent frame (the wrist), (B, 4, 4); None = identity
        check: also check q for NaN and root for rigidity (forces a host sync)
        returns: T_world_link in ``link_names`` order, (B, L, 4, 4)
        """
        q, root = self._inputs(q, root, check)
        return _kin.forward_kinematics(self._chain(q), q, root)

    def point_jacobian(self, q: torch.Tensor, link_index, points_local: torch.Tensor,
                       root: torch.Tensor | None = None, *, wrt_root: bool = False,
                       check: bool = False) -> torch.Tensor:
        """Analytic Jacobian of points fixed on links.

        q:            (B, D), radians / metres
        link_index:   link of each point, (P,), long
        points_local: points in their link's frame, (P, 3) or (B, P, 3), metres
        root:         (B, 4, 4) or None (identity)
        wrt_root:     False: d p_world / d q, (B, P, 3, D); True: (B, P, 3, 6 + D) with the root twist's columns
                      first (world angular velocity, then world velocity of the root origin ``root[:, :3, 3]``;
                      see :func:`torchhand.hand.dynamics.point_jacobian`)
        returns: the Jacobian, (B, P, 3, D) or (B, P, 3, 6 + D)
        """
        if wrt_root:
            return _dyn.point_jacobian(self, q, link_index, points_local, root, check=check)
        return self.points_and_jacobian(q, link_index, points_local, root, check=check)[1]

    def points_and_jacobian(self, q, link_index, points_local, root=None, *, check: bool = False):
        """World positions (B, P, 3) of link-fixed points and their Jacobian (B, P, 3, D) in one pass."""
        q, root = self._inputs(q, root, check)
        link_index, points_local = self._point_args(q, link_index, points_local)
        _, x, J = _kin.fk_and_point_jacobian(self._chain(q), q, root, link_index, points_local)
        return x, J

    def _point_args(self, q, link_index, points_local):
        link_index = torch.as_tensor(link_index, dtype=torch.long, device=q.device)
        if link_index.dim() != 1:
            raise ShapeError(f"link_index: expected shape (P,), got {tuple(link_index.shape)}")
        P = link_index.shape[0]
        if points_local.dim() == 2:
            check_tensor(points_local, "points_local", (P, 3))
        else:
            check_tensor(points_local, "points_local", (q.shape[0], P, 3))
        # A range check costs a host sync on GPUs; there an out-of-range index fails inside torch instead.
        if P and q.device.type == "cpu" and (int(link_index.min()) < 0 or int(link_index.max()) >= self.num_links):
            raise InputValueError(f"link_index: values must be in [0, {self.num_links}), got "
                                  f"[{int(link_index.min())}, {int(link_index.max())}]")
        return link_index, points_local.to(q.dtype)

    def kinematics(self, q, link_index, points_local, root=None, *, check: bool = False):
        """Link poses (B, L, 4, 4), world points (B, P, 3) and their Jacobian (B, P, 3, D) in one pass."""
        q, root = self._inputs(q, root, check)
        link_index, points_local = self._point_args(q, link_index, points_local)
        return _kin.fk_and_point_jacobian(self._chain(q), q, root, link_index, points_local)

    # --- dynamics (coordinates: root twist (w, v), then q; see torchhand.hand.dynamics) ------------------------
    def mass_matrix(self, q: torch.Tensor, root: torch.Tensor | None = None, *, check: bool = False):
        """Joint-space inertia matrix, (B, 6 + D, 6 + D) (:func:`torchhand.hand.dynamics.mass_matrix`)."""
        return _dyn.mass_matrix(self, q, root, check=check)

    def gravity_torques(self, q: torch.Tensor, root: torch.Tensor | None = None, gravity=(0.0, 0.0, -9.81), *,
                        check: bool = False):
        """Generalized force holding the hand against gravity, (B, 6 + D)
        (:func:`torchhand.hand.dynamics.gravity_torques`)."""
        return _dyn.gravity_torques(self, q, root, gravity, check=check)

    def contact_torques(self, q: torch.Tensor, root: torch.Tensor | None, link_index, points_local: torch.Tensor,
                        forces: torch.Tensor, *, check: bool = False):
        """J^T f of world forces (B, P, 3) at link-fixed points, (B, 6 + D)
        (:func:`torchhand.hand.dynamics.contact_torques`)."""
        return _dyn.contact_torques(self, q, root, link_index, points_local, forces, check=check)

    def clamp_to_limits(self, q: torch.Tensor) -> torch.Tensor:
        """q clamped into ``joint_limits``, (B, D)."""
        return torch.maximum(torch.minimum(q, self.joint_limits[:, 1]), self.joint_limits[:, 0])

    def random_q(self, batch: int, generator: torch.Generator) -> torch.Tensor:
        """Uniform random joint values within the limits, (batch, D); randomness from ``generator`` only."""
        u = torch.rand(batch, self.num_joints, generator=generator, dtype=self.dtype,
                       device=generator.device if generator.device.type == self.device.type else "cpu")
        lo, hi = self.joint_limits[:, 0], self.joint_limits[:, 1]
        return lo + u.to(self.device) * (hi - lo)

    # --- MJCF -------------------------------------------------------------------------------------------------
    @classmethod
    def from_mjcf(cls, path, **kwargs) -> "HandModel":
        """Load a hand described in MJCF (see :func:`torchhand.hand.mjcf.load_mjcf`)."""
        from .mjcf import load_mjcf

        return load_mjcf(path, **kwargs)

    def to_mjcf(self) -> str:
        """The model as an MJCF string that MuJoCo loads; the root body carries a free joint (see
        :func:`torchhand.hand.mjcf.hand_to_mjcf`)."""
        from .mjcf import hand_to_mjcf

        return hand_to_mjcf(self)


# ----------------------------------------------------------------------------------------------------------------
# Building
# ----------------------------------------------------------------------------------------------------------------
def build_hand_model(
    name: str,
    links: list[LinkSpec],
    joints: list[JointSpec],
    geoms: list[GeomSpec],
    fingers: list[FingerSpec] = (),
    *,
    side: str = "none",
    length: float = 0.0,
    q_rest: np.ndarray | None = None,
    inertials: list[InertialSpec] = (),
    density: float = _dyn.DEFAULT_DENSITY,
    samples_per_area: float = 60000.0,
    min_samples_per_link: int = 24,
    dtype: torch.dtype = torch.float64,
) -> HandModel:
    """Build a :class:`HandModel` from specs (float64 NumPy in, tensors of ``dtype`` out, on the CPU).

    Links must be listed parents first with the root first. Joints of one link are applied in the order given.
    Inertials: a link listed in ``inertials`` (at most once) takes that mass, centre of mass and inertia; any other
    link is a solid of uniform ``density`` (kg/m^3; default 1000, MuJoCo's default geom density) filling its
    collision geoms, summed per link with the parallel-axis theorem (overlaps count twice, as in MuJoCo): capsule,
    sphere, cylinder and box analytically (MuJoCo's formulas), meshes by exact signed-tetrahedron integration (the
    convex hull when the mesh is not closed); a link without geometry has zero mass.
    Surface samples: ``samples_per_area`` per square metre of geometry (at least ``min_samples_per_link`` per link
    with geometry), placed deterministically.
    """
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
    axes = np.array([_unit(j.axis, f"joint {j.name} axis") for j in joints]).reshape(D, 3)
    jtype = np.array([JOINT_HINGE if j.type == "hinge" else JOINT_SLIDE for j in joints], dtype=np.int64)

    def t(a, dt=dtype):
        return torch.as_tensor(np.asarray(a), dtype=dt)

    chain = Chain(
        link_parent=t(parent, torch.long),
        link_offset=t(np.stack([l.offset for l in links])),
        link_joints=t(link_joints, torch.long),
        joint_link=t(joint_link, torch.long),
        joint_type=t(jtype, torch.long),
        joint_axis=t(axes),
        joint_anchor=t(np.array([j.anchor for j in joints]).reshape(D, 3)),
        support=t(support, torch.bool),
        levels=tuple(t(np.nonzero(depth == k)[0], torch.long) for k in range(int(depth.max()) + 1)),
        slot_links=tuple(t([l for l in range(L) if len(per_link[l]) > k], torch.long) for k in range(J)
                         if any(len(p) > k for p in per_link)),
        slot_joints=tuple(t([per_link[l][k] for l in range(L) if len(per_link[l]) > k], torch.long)
                          for k in range(J) if any(len(p) > k for p in per_link)),
        support_joints=t(_padded([np.nonzero(support[l])[0] for l in range(L)]), torch.long),
    )
    limits = np.array([j.limits for j in joints], dtype=np.float64).reshape(D, 2)
    if (limits[:, 0] > limits[:, 1]).any():
        raise InputValueError(f"hand {name!r}: a joint's lower limit exceeds its upper limit")
    if q_rest is None:
        q_rest = np.clip(np.zeros(D), limits[:, 0], limits[:, 1])

    # Geometry.
    meshes, mesh_index = [], []
    for g in geoms:
        if g.type not in GEOM_TYPES:
            raise InputValueError(f"geom on link {g.link!r}: unknown type {g.type!r}; expected one of {GEOM_TYPES}")
        if g.link not in lidx:
            raise UnknownNameError(f"geom refers to unknown link {g.link!r}")
        if g.type == "mesh":
            mesh_index.append(len(meshes))
            meshes.append((t(g.mesh[0]), t(g.mesh[1], torch.long)))
        else:
            mesh_index.append(-1)
    G = len(geoms)
    link_geoms = LinkGeoms(
        link=t(np.array([lidx[g.link] for g in geoms], dtype=np.int64).reshape(G), torch.long),
        type=t(np.array([GEOM_TYPES.index(g.type) for g in geoms], dtype=np.int64).reshape(G), torch.long),
        size=t(np.array([np.resize(np.asarray(g.size, dtype=np.float64), 3) for g in geoms]).reshape(G, 3)),
        pose=t(np.array([g.pose for g in geoms]).reshape(G, 4, 4)),
        mesh_index=t(np.array(mesh_index, dtype=np.int64).reshape(G), torch.long),
        meshes=tuple(meshes),
    )
    mass, com, inertia = _dyn.link_inertials(name, link_names, geoms, inertials, density)
    cap_a, cap_b, cap_r = _fit_capsules(L, geoms, lidx)
    pts, nrm, lnk = _surface_samples(L, geoms, lidx, samples_per_area, min_samples_per_link)

    # Fingers.
    F = len(fingers)
    finger_links = np.full((F, 4), -1, dtype=np.int64)
    link_finger = np.full(L, -1, dtype=np.int64)
    flex = np.full((F, 3), -1, dtype=np.int64)
    jidx = {n: i for i, n in enumerate(joint_names)}
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
    # Links between the palm and a finger's first link (a robot finger's base: Allegro's ff_base, Shadow's thbase
    # and lfmetacarpal) are that finger's: their joints move it. Not in finger_links, not in finger-finger pairs.
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
    pairs = []
    for a in range(L):
        for b in range(a + 1, L):
            if a in bases or b in bases:
                continue
            fa, fb = link_finger[a], link_finger[b]
            # Finger-finger pairs: links of different fingers, excluding the first (palm-level) link of a 4-link
            # finger, which lies inside the palm next to its neighbours by construction.
            if fa >= 0 and fb >= 0 and fa != fb and cap_r[a] > 0 and cap_r[b] > 0:
                if _palm_level(a, fa, finger_links) or _palm_level(b, fb, finger_links):
                    continue
                pairs.append((a, b))

    return HandModel(
        name=name,
        side=side,
        length=float(length),
        link_names=link_names,
        joint_names=joint_names,
        chain=chain,
        joint_limits=t(limits),
        q_rest=t(q_rest),
        geoms=link_geoms,
        capsule_a=t(cap_a),
        capsule_b=t(cap_b),
        capsule_radius=t(cap_r),
        sample_points=t(pts),
        sample_normals=t(nrm),
        sample_link=t(lnk, torch.long),
        finger_names=tuple(f.name for f in fingers),
        finger_links=t(finger_links, torch.long),
        link_finger=t(link_finger, torch.long),
        distal_link=t(np.array([finger_links[f][finger_links[f] >= 0][-1] for f in range(F)], dtype=np.int64)
                      .reshape(F), torch.long),
        nail_normal=t(np.array([_unit(f.nail_normal, f"finger {f.name} nail normal") for f in fingers]).reshape(F, 3)),
        fingertip=t(np.array([f.tip for f in fingers], dtype=np.float64).reshape(F, 3)),
        flexion_joints=t(flex, torch.long),
        collision_pairs=t(np.array(pairs, dtype=np.int64).reshape(-1, 2), torch.long),
        link_mass=t(mass),
        link_com=t(com),
        link_inertia=t(inertia),
    )


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


def _unit(v, what: str) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(v))
    if not math.isfinite(n) or n < 1e-12:
        raise InputValueError(f"{what}: expected a non-zero finite vector, got {v.tolist()}")
    return v / n
