"""Typed inputs and outputs of the quasi-static step (:mod:`torchhand.interaction.step`), batched over B rollouts.

:class:`StepObject` (the free rigid object), :class:`StepSettings`, :class:`StepState` (the state at step k) and
:class:`StepReport` (what one step solved). Units: metres, seconds, radians, newtons, kilograms; compliance
rad/(N m) (root linear m/N); forces are those ON THE HAND (the paper's f_i).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from torchhand.kernels.contact_lcp import KryPaiLCP

from ..errors import InputValueError
from ._contacts import Contacts

__all__ = ["SOLVERS", "StepObject", "StepSettings", "StepState", "StepReport"]

SOLVERS = ("lemke", "pgs", "auto")


@dataclass(frozen=True, eq=False)
class StepObject:
    """The free rigid object of the step.

    sdf:     its signed distance grid, :class:`~torchhand.geometry.sdf.SDFGrid`, object frame, in the state's dtype and device
             (``SDFGrid.from_mesh`` builds float32: ``.to(dtype=torch.float64)`` for float64 rollouts)
    mass:    kg; com: centre of mass, (3,), object frame, metres; inertia: about the com, (3, 3), object axes, kg m^2
    mu:      friction coefficient with the hand
    support: points the object can rest on, (P, 3), object frame, metres (``support_points`` of its mesh), or None
             (no object-plane contacts)
    masses:  one mass per rollout, (B,) floats, kg, or None (``mass`` for all); the inertia scales by masses / mass
    mus:     one hand-object friction coefficient per rollout, (B,) floats, or None (``mu`` for all)
    mesh:    the exact object mesh, :class:`~torchhand.check.geometry.ObjectMesh` (object frame; a trimesh.Trimesh
             is converted), or None. With ``StepSettings.geometry = "capsules"`` the hand-object slots come from the
             links' capsules against it (:mod:`._contacts`), the geometry ``torchhand check`` uses, and ``sdf`` may
             be None; otherwise from the surface samples in ``sdf``
    rollouts: None, or one StepObject per rollout (:meth:`per_rollout`): B different objects in one batch, each
             with its own mesh (exact, ``geometry="capsules"``), mass properties, friction and support points; the
             other fields are then the first rollout's
    """

    sdf: object
    mass: float
    com: tuple
    inertia: tuple
    mu: float = 1.0
    support: torch.Tensor | None = None
    masses: tuple | None = None
    mus: tuple | None = None
    mesh: object = None
    rollouts: tuple | None = None

    def __post_init__(self):
        if self.rollouts is not None:
            self._check_rollouts()
        if self.mesh is not None and not hasattr(self.mesh, "hull_distance_bound"):
            from ..check.geometry import object_mesh

            object.__setattr__(self, "mesh", object_mesh(self.mesh, float(self.mass)))
        if self.sdf is None and self.mesh is None:
            raise InputValueError("StepObject: give its signed distance grid (sdf) or its exact mesh (mesh)")
        for name in ("masses", "mus"):
            v = getattr(self, name)
            if v is not None:
                v = tuple(float(x) for x in v)
                if not v or not all(x >= 0 for x in v) or (name == "masses" and not all(x > 0 for x in v)):
                    raise InputValueError(f"{name}: expected positive values per rollout, got {v}")
                object.__setattr__(self, name, v)
        if self.support is not None and (not isinstance(self.support, torch.Tensor) or self.support.dim() != 2
                                         or self.support.shape[1] != 3):
            raise InputValueError(f"support: expected a (P, 3) tensor, got {getattr(self.support, 'shape', None)}")
        com = np.asarray(self.com, dtype=np.float64)
        I = np.asarray(self.inertia, dtype=np.float64)
        if com.shape != (3,) or I.shape != (3, 3):
            raise InputValueError(f"com, inertia: expected shapes (3,), (3, 3), got {com.shape}, {I.shape}")
        if not self.mass > 0 or not np.all(np.linalg.eigvalsh(0.5 * (I + I.T)) > 0):
            raise InputValueError(f"mass and inertia must be positive (definite), got {self.mass}, {I.tolist()}")
        object.__setattr__(self, "com", tuple(com.tolist()))
        object.__setattr__(self, "inertia", tuple(map(tuple, I.tolist())))

    @classmethod
    def from_rigid(cls, obj, sdf, mu: float = 1.0, *, support: torch.Tensor | None = None,
                   masses=None, mus=None, mesh=None) -> "StepObject":
        """From a :class:`~torchhand.geometry.objects.RigidObject` and its grid (support, masses, mus, mesh: see the
        fields; ``mesh=True`` takes the object's own mesh)."""
        mesh = obj.mesh if mesh is True else mesh
        return cls(sdf, float(obj.mass), tuple(obj.com), tuple(map(tuple, obj.inertia)), mu, support, masses, mus,
                   mesh)

    @classmethod
    def per_rollout(cls, objects) -> "StepObject":
        """One object per rollout (the ``rollouts`` field): ``objects`` are single StepObjects (no ``masses``,
        ``mus`` or ``rollouts`` of their own), each with its exact ``mesh``; equal objects may be the same one."""
        objects = tuple(objects)
        if not objects:
            raise InputValueError("StepObject.per_rollout: at least one object is needed")
        first = objects[0]
        return cls(first.sdf, first.mass, first.com, first.inertia, first.mu, first.support, None, None, first.mesh,
                   objects)

    def _check_rollouts(self) -> None:
        objs = self.rollouts
        if self.masses is not None or self.mus is not None:
            raise InputValueError("StepObject: give masses and frictions through its per-rollout objects")
        for o in objs:
            if not isinstance(o, StepObject) or o.rollouts is not None or o.masses is not None or o.mus is not None:
                raise InputValueError("StepObject.rollouts: expected single StepObjects, one per rollout")
            if o.mesh is None:
                raise InputValueError("StepObject.rollouts: each rollout's object needs its exact mesh")
        if len({o.support is None for o in objs}) > 1:
            raise InputValueError("StepObject.rollouts: give support points for every rollout's object or none")

    def _rollout_count(self, B: int) -> None:
        if self.rollouts is not None and len(self.rollouts) != B:
            raise InputValueError(f"StepObject.rollouts: {len(self.rollouts)} objects for {B} rollouts")

    def mass_per_rollout(self, B: int, like: torch.Tensor) -> torch.Tensor:
        """Masses, (B,), kg."""
        if self.rollouts is not None:
            self._rollout_count(B)
            return torch.tensor([o.mass for o in self.rollouts], dtype=like.dtype, device=like.device)
        return self._per_rollout(self.masses, self.mass, "masses", B, like)

    def mu_per_rollout(self, B: int, like: torch.Tensor) -> torch.Tensor:
        """Hand-object friction coefficients, (B,)."""
        if self.rollouts is not None:
            self._rollout_count(B)
            return torch.tensor([o.mu for o in self.rollouts], dtype=like.dtype, device=like.device)
        return self._per_rollout(self.mus, self.mu, "mus", B, like)

    def com_per_rollout(self, B: int, like: torch.Tensor) -> torch.Tensor:
        """Centres of mass, (B, 3), object frame, metres."""
        if self.rollouts is not None:
            self._rollout_count(B)
            return torch.tensor([o.com for o in self.rollouts], dtype=like.dtype, device=like.device)
        return torch.tensor(self.com, dtype=like.dtype, device=like.device).expand(B, 3)

    def meshes(self, B: int) -> tuple:
        """The exact mesh of each rollout's object, (B,) (the same object where the rollouts share it)."""
        if self.rollouts is not None:
            self._rollout_count(B)
            return tuple(o.mesh for o in self.rollouts)
        return (self.mesh,) * B

    def support_per_rollout(self, B: int, like: torch.Tensor):
        """Support points (B, P, 3), object frames, padded to the most points, and which are real, (B, P) bool; or
        None without support points."""
        if self.support is None:
            return None
        if self.rollouts is None:
            P = self.support.shape[0]
            return (self.support.to(like).expand(B, P, 3),
                    torch.ones(B, P, dtype=torch.bool, device=like.device))
        self._rollout_count(B)
        P = max(o.support.shape[0] for o in self.rollouts)
        pts = like.new_zeros(B, P, 3)
        real = torch.zeros(B, P, dtype=torch.bool, device=like.device)
        for b, o in enumerate(self.rollouts):
            n = o.support.shape[0]
            pts[b, :n] = o.support.to(like)
            real[b, :n] = True
        return pts, real

    @staticmethod
    def _per_rollout(values, default, name, B, like):
        if values is None:
            return like.new_full((B,), float(default))
        if len(values) != B:
            raise InputValueError(f"StepObject.{name}: {len(values)} values for {B} rollouts")
        return torch.tensor(values, dtype=like.dtype, device=like.device)

    def com_shift(self, B: int, like: torch.Tensor, sign: float = 1.0) -> torch.Tensor:
        """T(sign com): the translation by the centre of mass (sign -1: back), (4, 4), or (B, 4, 4) with an object
        per rollout."""
        T = torch.eye(4, dtype=like.dtype, device=like.device)
        if self.rollouts is None:
            T[:3, 3] = sign * self.com_per_rollout(1, like)[0]
            return T
        T = T.repeat(B, 1, 1)
        T[:, :3, 3] = sign * self.com_per_rollout(B, like)
        return T

    def body_frame(self, object_pose: torch.Tensor) -> torch.Tensor:
        """E_wb = T_world_object @ T(com): the body frame at the centre of mass with the object's axes, (B, 4, 4)."""
        return object_pose @ self.com_shift(object_pose.shape[0], object_pose)

    def spatial_inertia(self, B: int, like: torch.Tensor) -> torch.Tensor:
        """M = diag(I_com, m I3), (B, 6, 6), kg m^2 / kg (per rollout with ``masses`` or ``rollouts``)."""
        if self.rollouts is not None:
            self._rollout_count(B)
            return torch.stack([o.spatial_inertia(1, like)[0] for o in self.rollouts])
        M = torch.zeros(6, 6, dtype=like.dtype, device=like.device)
        M[:3, :3] = torch.tensor(self.inertia, dtype=like.dtype, device=like.device)
        M[3:, 3:] = self.mass * torch.eye(3, dtype=like.dtype, device=like.device)
        if self.masses is None:
            return M.expand(B, 6, 6)
        return M * (self.mass_per_rollout(B, like) / self.mass)[:, None, None]


@dataclass(frozen=True)
class StepSettings:
    """Settings of :func:`~torchhand.interaction.step.quasi_static_step`.

    h: time step, seconds (1/120: the interaction's frame rate); pyramid_m: tangent pairs m (see :mod:`.step`); margin:
    contact candidate distance, metres; gravity: world, m/s^2; solver: "lemke" | "pgs" | "auto"; pgs_max_iters, pgs_tol:
    sweep limit and tolerance on ||min(z, M z + q)||_inf (metres / newtons) of the batched solver (None: its per-dtype
    defaults); lemke_tol: Lemke's tolerance on the same residual (absolute: the LCP's F and E blocks have unit entries);
    1e-7 m / N accepts the round-off of the final basis solve on problems whose A = D^T (G - U_phi) D is far from full
    rank (planar fingers, many contacts); lemke_restarts: covering vectors Lemke tries after a run that does not
    converge (8: the step's LCP matrix is not copositive-plus once the object's U_phi enters - its symmetric part is
    indefinite - so a ray termination need not mean that no solution exists; measured: a resynthesis step that the first
    three covering vectors left at a ray was solved by a later one); geometry: plane contacts (and object contacts when
    the object has its exact ``mesh``) from the surface "samples" or the exact "capsules"; env_compliance: compliance of
    the object-plane contacts, m/N (1e-6: a 3 N box sinks by 0.75 um per corner). Deviation: object-plane slots are
    quasi-rigid (normal and tangential displacement eps f^{k+1} added to nu, as in the elastic contact of Pauly et al.
    2004 the paper builds on), which makes the force distribution over several resting corners unique and the LCP well
    conditioned for Lemke and PGS (with eps = 0 several corners give a rank-deficient A); 0 gives exactly rigid rows;
    clamp_joints: clamp theta^{k+1}'s finger joints to ``hand.joint_limits`` (design note §3 item 13; the amount is
    ``StepReport.joint_clamp``); False reproduces the paper's step, which ignores joint limits; self_contacts:
    finger-finger slots between the capsules of different fingers (:mod:`._contacts`, an extension: the paper's fingers
    pass through each other); self_mu: their friction coefficient (0: frictionless); lemke_warm: Lemke first tries the
    previous step's support (the pyramid directions that carried force, and the sliding multiplier of every contact
    whose force was on its cone's boundary) with a few dense solves, and pivots only when that does not solve the LCP
    to round-off (the contact set changes little between steps); False pivots from scratch every step. Either way a
    Lemke run that does not end in a solution (its pivot limit, or a ray: Lemke's method is not complete for this
    LCP, whose matrix is not copositive-plus) is followed by ``pgs_max_iters`` (default 200) projected Gauss-Seidel
    sweeps whose support is solved exactly and verified within ``lemke_tol``, as a pivoted answer; the step fails
    only if that does not solve it either
    """

    h: float = 1.0 / 120.0
    pyramid_m: int = 4
    margin: float = 0.005
    gravity: tuple = (0.0, 0.0, -9.81)
    solver: str = "lemke"
    pgs_max_iters: int | None = None
    pgs_tol: float | None = None
    lemke_tol: float = 1e-7
    lemke_restarts: int = 8
    geometry: str = "samples"
    env_compliance: float = 1e-6
    clamp_joints: bool = True
    self_contacts: bool = False
    self_mu: float = 0.0
    lemke_warm: bool = True

    def __post_init__(self):
        if not self.h > 0:
            raise InputValueError(f"h: expected > 0 seconds, got {self.h}")
        if not (isinstance(self.pyramid_m, int) and self.pyramid_m >= 1):
            raise InputValueError(f"pyramid_m: expected an integer >= 1, got {self.pyramid_m!r}")
        if self.solver not in SOLVERS:
            raise InputValueError(f"solver: expected one of {', '.join(SOLVERS)}, got {self.solver!r}")
        if not self.margin >= 0:
            raise InputValueError(f"margin: expected >= 0 metres, got {self.margin}")
        if not self.self_mu >= 0:
            raise InputValueError(f"self_mu: expected >= 0, got {self.self_mu}")
        if not (isinstance(self.lemke_restarts, int) and self.lemke_restarts >= 0):
            raise InputValueError(f"lemke_restarts: expected an integer >= 0, got {self.lemke_restarts!r}")
        if not self.env_compliance >= 0:
            raise InputValueError(f"env_compliance: expected >= 0 m/N, got {self.env_compliance}")


@dataclass(frozen=True, eq=False)
class StepState:
    """State of B rollouts at step k (N contact slots, K = 2m + 1 pyramid directions).

    q:           finger joints theta^k, (B, D), radians
    root:        root pose, (B, 4, 4), world (its 6 compliant coordinates are displacements from ``root_r``)
    theta_r:     reference finger joints theta_r^k, (B, D), radians
    root_r:      reference root pose, (B, 4, 4), world
    object_pose: T_world_object E, (B, 4, 4), world (identity when there is no object)
    phi:         object body twist (omega, v) at its centre of mass, object axes, (B, 6), rad/s and m/s
    forces:      f^k per slot, on the hand (on the object for object-plane slots), (B, N, 3), world, newtons
                 (0 on inactive slots)
    beta:        pyramid coordinates of f^k, (B, N, K), newtons (warm start of the batched solver)
    contacts:    :class:`Contacts` at this configuration
    theta_err:   theta_err^k, (B, 6 + D), radians (metres for root translations)
    """

    q: torch.Tensor
    root: torch.Tensor
    theta_r: torch.Tensor
    root_r: torch.Tensor
    object_pose: torch.Tensor
    phi: torch.Tensor
    forces: torch.Tensor
    beta: torch.Tensor
    contacts: Contacts
    theta_err: torch.Tensor


@dataclass(frozen=True, eq=False)
class StepReport:
    """What one step solved, per rollout (B) and slot (N).

    status:     LCP status per rollout, (B,), int8 :class:`~torchhand.kernels.status.SolverStatus` values
    residual:   ||min(z, M z + q)||_inf of the rollout's explicit LCP, (B,), metres / newtons
    iterations: PGS sweeps or Lemke pivots, (B,), int32
    n_contacts: active slots, (B,), int64
    mask:       active slots of the solved problem, (B, N), bool
    D:          pyramid directions, (B, N, 3, K); beta (B, N, K), newtons; lam: slip lambda_i, (B, N), metres
    nu:         separation and tangential slacks, (B, N, K), metres; sigma: F_i beta_i, (B, N), newtons
    du:         predicted relative motion of the hand's contact points w.r.t. the counterpart (Eq. 10), (B, N, 3),
                metres
    s_prime:    (B, N, K), metres
    theta_err_max: ||theta_err^{k+1}||_inf, (B,), radians / metres
    lcp:        the solved problem over the active slots only (:class:`~torchhand.kernels.contact_lcp.KryPaiLCP`,
                Na = max active count, active slots first, padding masked)
    order:      slot index of each of its Na contacts, (B, Na), long
    joint_clamp: ||theta_r^{k+1} + (C J^T f^{k+1})_joints - theta^{k+1}||_inf, how far the step clamped a finger
                joint back into the hand's limits, (B,), radians (0: no joint reached a limit; always 0 with
                ``clamp_joints=False``)
    """

    status: torch.Tensor
    residual: torch.Tensor
    iterations: torch.Tensor
    n_contacts: torch.Tensor
    mask: torch.Tensor
    D: torch.Tensor
    beta: torch.Tensor
    lam: torch.Tensor
    nu: torch.Tensor
    sigma: torch.Tensor
    du: torch.Tensor
    s_prime: torch.Tensor
    theta_err_max: torch.Tensor
    lcp: KryPaiLCP
    order: torch.Tensor
    joint_clamp: torch.Tensor

