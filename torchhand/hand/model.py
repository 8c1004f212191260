"""The typed hand model: a frozen dataclass of tensors, built once and moved with ``.to(device, dtype)``.

A hand is a kinematic tree of links (MJCF bodies) moved by hinge and slide joints, with collision geometry per link,
surface samples for penetration checks, and per-finger annotations (distal link, nail normal, fingertip pad point,
the three flexion joints coupled by Ye & Liu's Eq. 11). Built from the plain specs of :mod:`torchhand.hand._specs`
(re-exported here) by :func:`build_hand_model`, whose stages are in :mod:`torchhand.hand._build`; the default 36-DOF
human hand is in :mod:`torchhand.hand.default`, MJCF import/export in :mod:`torchhand.hand.mjcf`
(:meth:`HandModel.from_mjcf` builds the :class:`HandSpec` the reader returns, :meth:`HandModel.to_mjcf` calls the writer).

Conventions (see :mod:`torchhand.conventions`): metres, radians, column-vector 4x4 transforms; the root link
(index 0) is the wrist frame whose world pose is the 6-DOF root input.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from torchhand.kernels.kinematics import Chain
from torchhand.kernels import kinematics as _kin

from . import _build
from . import dynamics as _dyn
from ._build import as_tensor
from ._link_geometry import fit_capsules as _fit_capsules
from ._link_geometry import surface_samples as _surface_samples
from ._read import read_hand_file
from ._mjcf_write import hand_to_mjcf
from ._specs import GEOM_TYPES, CouplingSpec, FingerSpec, GeomSpec, HandSpec, InertialSpec, JointSpec, LinkSpec
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
    "CouplingSpec",
    "HandSpec",
    "LinkGeoms",
    "HandModel",
    "build_hand_model",
    "build_from_spec",
]

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
    couplings: the joint couplings the source file declares (:class:`CouplingSpec`: fixed tendons, joint
        equalities), reported only: every joint moves freely within its limits
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
    couplings: tuple = ()

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

    # --- files ------------------------------------------------------------------------------------------------
    @classmethod
    def from_file(cls, path, **kwargs) -> "HandModel":
        """Load a hand from an MJCF or URDF file, compiled by MuJoCo (see :func:`torchhand.hand.mjcf.load_mjcf`;
        ``kwargs``: ``root_body``, ``side``, ``name``)."""
        return build_from_spec(read_hand_file(path, **kwargs))

    @classmethod
    def from_mjcf(cls, path, **kwargs) -> "HandModel":
        """Load a hand described in MJCF (:meth:`from_file`)."""
        return cls.from_file(path, **kwargs)

    @classmethod
    def from_urdf(cls, path, **kwargs) -> "HandModel":
        """Load a hand described in URDF (:meth:`from_file`)."""
        return cls.from_file(path, **kwargs)

    def to_mjcf(self) -> str:
        """The model as an MJCF string that MuJoCo loads; the root body carries a free joint (see
        :func:`torchhand.hand.mjcf.hand_to_mjcf`)."""
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
    couplings: tuple = (),
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
    tree = _build.tree_tables(name, links, joints)
    chain = _build.kinematic_chain(tree, links, joints, dtype)
    limits, q_rest = _build.limits_and_rest(name, joints, q_rest)
    link_geoms = _link_geoms(geoms, tree.lidx, dtype)
    L, lidx = len(links), tree.lidx
    mass, com, inertia = _dyn.link_inertials(name, tree.link_names, geoms, inertials, density)
    cap_a, cap_b, cap_r = _fit_capsules(L, geoms, lidx)
    pts, nrm, lnk = _surface_samples(L, geoms, lidx, samples_per_area, min_samples_per_link)
    ft = _build.finger_tables(fingers, tree, cap_r)
    F, finger_links = len(fingers), ft.finger_links

    def t(a, dt=dtype):
        return as_tensor(a, dt)

    return HandModel(
        name=name,
        side=side,
        length=float(length),
        link_names=tree.link_names,
        joint_names=tree.joint_names,
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
        link_finger=t(ft.link_finger, torch.long),
        distal_link=t(np.array([finger_links[f][finger_links[f] >= 0][-1] for f in range(F)], dtype=np.int64)
                      .reshape(F), torch.long),
        nail_normal=t(np.array([_build.unit(f.nail_normal, f"finger {f.name} nail normal") for f in fingers])
                      .reshape(F, 3)),
        fingertip=t(np.array([f.tip for f in fingers], dtype=np.float64).reshape(F, 3)),
        flexion_joints=t(ft.flexion, torch.long),
        collision_pairs=t(np.array(ft.pairs, dtype=np.int64).reshape(-1, 2), torch.long),
        link_mass=t(mass),
        link_com=t(com),
        link_inertia=t(inertia),
        couplings=tuple(couplings),
    )


def build_from_spec(spec: HandSpec, **kwargs) -> HandModel:
    """:func:`build_hand_model` of a :class:`HandSpec` (``kwargs``: its density, sampling and dtype options)."""
    return build_hand_model(spec.name, spec.links, spec.joints, spec.geoms, spec.fingers, side=spec.side,
                            length=spec.length, q_rest=spec.q_rest, inertials=spec.inertials,
                            couplings=spec.couplings, **kwargs)


def _link_geoms(geoms: list[GeomSpec], lidx: dict, dtype: torch.dtype) -> LinkGeoms:
    """The padded :class:`LinkGeoms` of the geom specs; raises InputValueError (unknown type) or UnknownNameError
    (unknown link)."""
    meshes, mesh_index = [], []
    for g in geoms:
        if g.type not in GEOM_TYPES:
            raise InputValueError(f"geom on link {g.link!r}: unknown type {g.type!r}; expected one of {GEOM_TYPES}")
        if g.link not in lidx:
            raise UnknownNameError(f"geom refers to unknown link {g.link!r}")
        if g.type == "mesh":
            mesh_index.append(len(meshes))
            meshes.append((as_tensor(g.mesh[0], dtype), as_tensor(g.mesh[1], torch.long)))
        else:
            mesh_index.append(-1)
    G = len(geoms)
    return LinkGeoms(
        link=as_tensor(np.array([lidx[g.link] for g in geoms], dtype=np.int64).reshape(G), torch.long),
        type=as_tensor(np.array([GEOM_TYPES.index(g.type) for g in geoms], dtype=np.int64).reshape(G), torch.long),
        size=as_tensor(np.array([np.resize(np.asarray(g.size, dtype=np.float64), 3) for g in geoms]).reshape(G, 3),
                       dtype),
        pose=as_tensor(np.array([g.pose for g in geoms]).reshape(G, 4, 4), dtype),
        mesh_index=as_tensor(np.array(mesh_index, dtype=np.int64).reshape(G), torch.long),
        meshes=tuple(meshes),
    )
