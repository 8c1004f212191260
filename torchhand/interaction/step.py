"""One quasi-static step of interaction synthesis (Kry & Pai 2006 §7.1), batched over B rollouts.

State at step k (:class:`StepState`): the compliant hand (finger joints q^k, root pose), its reference (theta_r^k and
the reference root pose), the object (pose, body twist phi^k), the contact forces f^k on the hand per contact slot,
the contact slots at this configuration and the equilibrium error theta_err^k. :func:`quasi_static_step` maps it to
step k + 1 given the next reference (theta_r^{k+1}, root reference), the compliance C and the models:

1. contacts: the slots of :mod:`torchhand.interaction._contacts` (deepest point per link against the object - its
   signed distance grid, or with ``geometry="capsules"`` and :attr:`StepObject.mesh` the link's capsule against the
   exact mesh - and against a fixed plane, candidates up to ``margin`` away, padded with a mask); they
   were found at the end of the previous step (step 9) or by :func:`initial_state`;
2. friction pyramids D_i with ``pyramid_m`` tangent pairs (§7.1.1);
3-5. G = J C J^T over the 6 + D generalized coordinates (root angular, root linear, joints): the root entries of
   C couple every pair of contacts (Eq. 5, Fig. 10);
6. U_phi, u_phi of the free object (body frame at its centre of mass with the object's axes, M = diag(I_com, m I3),
   gravity w_ext = (0, m Theta^T g)); plane slots have U_phi = u_phi = 0;
7. s' = s + D^T (J (dtheta_r + theta_err) - G f^k - u_phi) and the LCP of §7.1.3, solved per rollout by Lemke's
   method (``solver="lemke"``, exact, one problem at a time on the CPU) or by the batched projected Gauss-Seidel
   of :func:`torchhand.kernels.contact_lcp.solve_contact_lcp` (``"pgs"``; ``"auto"`` re-solves the rollouts PGS
   leaves unconverged with Lemke); only the active slots enter the problem;
8. f^{k+1} = D beta; phi^{k+1}, E^{k+1} = E^k exp(h phi^{k+1}^) (exact SE(3) exponential of the body twist);
   theta^{k+1} = theta_r^{k+1} + C J^T f^{k+1}: finger joints directly, and the six root entries displace the
   reference root pose (rotation vector applied on the left, about the root origin; translation added);
9. contact update: new slots at (theta^{k+1}, E^{k+1}); each slot keeps its force, and
   theta_err^{k+1} = C (J_new^T - J^T) f^{k+1}, which the next step adds to dtheta_r (as the paper says).

Generalized coordinates (6 + D) are those of ``torchhand.hand.dynamics.point_jacobian(..., wrt_root=True)`` and of
:func:`torchhand.interaction.default_compliance`. Units: metres, seconds, radians, newtons; compliance rad/(N m)
(root linear m/N); forces are those ON THE HAND (the paper's f_i; torchhand's ``contact_force`` on the object is -f).

Choices the paper leaves open (design note §3): ``pyramid_m = 4`` by default, because an inscribed 2m-gon holds only mu
cos(pi / 2m) in its worst direction, 0.866 mu at m = 3, below the 0.9 mu imminent-slip threshold of §8.1, while m = 4
holds 0.924 mu; h = 1/120 s; plane contacts are hand-plane rows with the hand's G block and U_phi = 0 (an extension);
finger-finger contacts (``StepSettings.self_contacts``, an extension) are rows of the relative Jacobian J_a - J_b of the
two fingers' surface points, also with U_phi = 0. Object-plane contacts (an extension, design note §3 item 12): when the
object has support points (:attr:`StepObject.support`) and there is a plane, each support point is a slot whose first
body is the object and whose counterpart is the rigid plane: G block 0, J rows 0, and the object's rigid-body terms with
the sign of the force the object receives. With sign s_i = -1 for a hand-object slot (the object receives -f_i) and s_i
= +1 for an object-plane slot (it receives +f_i), every object slot moves by p_i = u_i + h^2 Gamma_i Ad M^-1 Ad^T sum_j
s_j Gamma_j^T f_j, and the relative motion of the slot's first body is du_i = (hand motion) + s_i p_i; so Eq. 10 holds
with U_phi -> S U_phi S and u_phi -> -S u_phi, S = diag(s_i I3). An object then rests on the table (its weight carried
by those slots) and is lifted when the hand's forces take it over. Joint limits (the paper ignores them, §8.3; design
note §3 item 13): step 8 clamps theta^{k+1}'s finger joints into the hand's limits (``StepSettings.clamp_joints``,
default on) and reports how far (``StepReport.joint_clamp``). theta_err is left as Eq. 7 gives it: the next step then
predicts the clamped joint's motion from where it actually is, which is exact while it stays at its limit (the clamp is
absolute, recomputed from theta_r and C J^T f every step, so it does not accumulate); only the step at which a joint
reaches its limit mispredicts, by that step's clamp.

Batched variants: :class:`StepObject` may carry one mass and one hand-object friction coefficient per rollout
(``masses``, ``mus``; the inertia scales with the mass), so that B rollouts of different objects share one batched
LCP.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch

from torchhand.kernels.contact_lcp import (KryPaiLCP, build_kry_pai_lcp, effective_compliance, friction_pyramid,
                                           integrate_object, kry_pai_s_prime, rigid_body_terms, solve_contact_lcp)
from torchhand.kernels.spatial import exp_twist, so3_log
from torchhand.kernels.status import SolverStatus

from ..conventions import check_tensor
from ..errors import InputValueError
from ..solvers._lemke import lemke
from ._contacts import BODY_OBJECT, BODY_OBJECT_ENV, BODY_SELF, Contacts, TablePlane, find_contacts, self_pairs

__all__ = ["StepObject", "StepSettings", "StepState", "StepReport", "TablePlane", "Contacts", "initial_state",
           "quasi_static_step", "root_displacement", "displace_root", "SOLVERS"]

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

    def __post_init__(self):
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

    def mass_per_rollout(self, B: int, like: torch.Tensor) -> torch.Tensor:
        """Masses, (B,), kg."""
        return self._per_rollout(self.masses, self.mass, "masses", B, like)

    def mu_per_rollout(self, B: int, like: torch.Tensor) -> torch.Tensor:
        """Hand-object friction coefficients, (B,)."""
        return self._per_rollout(self.mus, self.mu, "mus", B, like)

    @staticmethod
    def _per_rollout(values, default, name, B, like):
        if values is None:
            return like.new_full((B,), float(default))
        if len(values) != B:
            raise InputValueError(f"StepObject.{name}: {len(values)} values for {B} rollouts")
        return torch.tensor(values, dtype=like.dtype, device=like.device)

    def body_frame(self, object_pose: torch.Tensor) -> torch.Tensor:
        """E_wb = T_world_object @ T(com): the body frame at the centre of mass with the object's axes, (B, 4, 4)."""
        T = torch.eye(4, dtype=object_pose.dtype, device=object_pose.device)
        T[:3, 3] = torch.tensor(self.com, dtype=object_pose.dtype, device=object_pose.device)
        return object_pose @ T

    def spatial_inertia(self, B: int, like: torch.Tensor) -> torch.Tensor:
        """M = diag(I_com, m I3), (B, 6, 6), kg m^2 / kg (per rollout with ``masses``)."""
        M = torch.zeros(6, 6, dtype=like.dtype, device=like.device)
        M[:3, :3] = torch.tensor(self.inertia, dtype=like.dtype, device=like.device)
        M[3:, 3:] = self.mass * torch.eye(3, dtype=like.dtype, device=like.device)
        if self.masses is None:
            return M.expand(B, 6, 6)
        return M * (self.mass_per_rollout(B, like) / self.mass)[:, None, None]


@dataclass(frozen=True)
class StepSettings:
    """Settings of :func:`quasi_static_step`.

    h: time step, seconds (1/120: the interaction's frame rate); pyramid_m: tangent pairs m (module docstring); margin:
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
    pass through each other); self_mu: their friction coefficient (0: frictionless)
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


def root_displacement(root: torch.Tensor, root_r: torch.Tensor) -> torch.Tensor:
    """The six root coordinates of ``root`` relative to ``root_r``: (rotation vector of R R_r^T, p - p_r), (B, 6)."""
    R = root[:, :3, :3] @ root_r[:, :3, :3].transpose(-1, -2)
    return torch.cat([so3_log(R), root[:, :3, 3] - root_r[:, :3, 3]], -1)


def displace_root(root_r: torch.Tensor, delta: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`root_displacement`: R = exp([d_omega]x) R_r, p = p_r + d_v. delta (B, 6) -> (B, 4, 4)."""
    rot = exp_twist(torch.cat([delta[:, :3], torch.zeros_like(delta[:, :3])], -1), 1.0)[:, :3, :3]
    out = root_r.clone()
    out[:, :3, :3] = rot @ root_r[:, :3, :3]
    out[:, :3, 3] = root_r[:, :3, 3] + delta[:, 3:]
    return out


def _contacts(hand, q, root, object_pose, obj, env, settings) -> Contacts:
    return find_contacts(hand, q, root, sdf=None if obj is None else obj.sdf,
                         object_pose=object_pose if obj is not None else None, plane=env, margin=settings.margin,
                         geometry=settings.geometry, object_points=None if obj is None else obj.support,
                         object_mesh=None if obj is None else obj.mesh,
                         self_pairs=self_pairs(hand) if settings.self_contacts else None)


def _generalized_force(J: torch.Tensor, f: torch.Tensor) -> torch.Tensor:
    """J^T f: (B, 3N, 6 + D), (B, N, 3) -> (B, 6 + D)."""
    return (J.transpose(1, 2) @ f.reshape(f.shape[0], -1, 1)).squeeze(-1)


def initial_state(hand, q: torch.Tensor, root: torch.Tensor, *, object_pose: torch.Tensor | None = None,
                  phi: torch.Tensor | None = None, obj: StepObject | None = None, env: TablePlane | None = None,
                  settings: StepSettings = StepSettings(), theta_r: torch.Tensor | None = None,
                  root_r: torch.Tensor | None = None) -> StepState:
    """A state without contact forces at (q, root), with its contact slots.

    q: (B, D), radians; root: (B, 4, 4); object_pose: (B, 4, 4) (needed with ``obj``); phi: (B, 6) (default 0)
    theta_r, root_r: the reference at this step (default q, root); theta_err = -(theta - theta_r) so that Eq. 7
    holds with f = 0
    """
    B, D = q.shape
    check_tensor(root, "root", (B, 4, 4))
    if obj is not None and object_pose is None:
        raise InputValueError("initial_state: object_pose (B, 4, 4) is needed with an object")
    if object_pose is None:
        object_pose = torch.eye(4, dtype=q.dtype, device=q.device).expand(B, 4, 4).clone()
    check_tensor(object_pose, "object_pose", (B, 4, 4))
    theta_r = q.clone() if theta_r is None else theta_r
    root_r = root.clone() if root_r is None else root_r
    phi = q.new_zeros(B, 6) if phi is None else phi
    check_tensor(phi, "phi", (B, 6))
    c = _contacts(hand, q, root, object_pose, obj, env, settings)
    N, K = c.mask.shape[1], 2 * settings.pyramid_m + 1
    err = -torch.cat([root_displacement(root, root_r), q - theta_r], -1)
    return StepState(q, root, theta_r, root_r, object_pose, phi, q.new_zeros(B, N, 3), q.new_zeros(B, N, K), c, err)


def _compact(mask: torch.Tensor):
    """Active slots first: order (B, Na) slot indices and the compact mask (B, Na); Na = max active count."""
    B, N = mask.shape
    order = torch.argsort((~mask).to(torch.int8), dim=1, stable=True)
    na = max(int(mask.sum(1).max()), 1)
    order = order[:, :na]
    return order, mask.gather(1, order)


def _gather_blocks(X: torch.Tensor, order: torch.Tensor) -> torch.Tensor:
    """X (B, 3N, 3N) restricted to the 3x3 blocks of ``order`` (B, Na) -> (B, 3Na, 3Na)."""
    idx = (order[..., None] * 3 + torch.arange(3, device=order.device)).reshape(order.shape[0], -1)
    X = X.gather(1, idx[..., None].expand(-1, -1, X.shape[2]))
    return X.gather(2, idx[:, None, :].expand(-1, idx.shape[1], -1))


def _scatter(xc: torch.Tensor, order: torch.Tensor, mask_c: torch.Tensor, N: int) -> torch.Tensor:
    """Compact slot values (B, Na, ...) back to the N slots (B, N, ...), zero on inactive slots."""
    B, Na = order.shape
    ones = [1] * (xc.dim() - 2)
    xc = xc * mask_c.reshape(B, Na, *ones).to(xc)
    return xc.new_zeros(B, N, *xc.shape[2:]).scatter(1, order.reshape(B, Na, *ones).expand_as(xc), xc)


def _solve(lcp, mask_c: torch.Tensor, beta0: torch.Tensor, settings: StepSettings):
    """beta (B, Na, K), status, residual, iterations over the compact problem."""
    D = lcp.D
    B, Na, _, K = D.shape
    status = torch.zeros(B, dtype=torch.int8)
    residual = torch.zeros(B, dtype=D.dtype)
    iters = torch.zeros(B, dtype=torch.int32)
    beta = D.new_zeros(B, Na, K)
    todo = torch.ones(B, dtype=torch.bool)
    if settings.solver in ("pgs", "auto"):
        out = solve_contact_lcp(lcp, beta0=beta0, tol=settings.pgs_tol, max_iters=settings.pgs_max_iters)
        beta, status, residual, iters = out.beta, out.status.cpu(), out.residual.cpu(), out.iterations.cpu()
        todo = status != int(SolverStatus.CONVERGED) if settings.solver == "auto" else torch.zeros_like(todo)
    counts = mask_c.sum(1).cpu()
    if bool(todo.any()):
        Mc, qc = lcp.M.detach().cpu().double(), lcp.q.detach().cpu().double()
        beta = beta.clone()
        for b in todo.nonzero().flatten().tolist():
            na = int(counts[b])
            # active slots come first: the LCP of the active contacts is the leading block (beta rows, then lambda)
            rows = torch.cat([torch.arange(na * K), Na * K + torch.arange(na)])
            out = lemke(Mc[b][rows][:, rows], qc[b][rows], tol=settings.lemke_tol, restarts=settings.lemke_restarts)
            beta[b] = 0
            beta[b, :na] = torch.from_numpy(out.x[: na * K]).reshape(na, K).to(beta)
            status[b], residual[b], iters[b] = int(out.status), out.residual, out.pivots
    return beta, status.to(D.device), residual.to(D.device), iters.to(D.device)


def quasi_static_step(state: StepState, hand, theta_r_next: torch.Tensor, root_r_next: torch.Tensor,
                      C: torch.Tensor, obj: StepObject | None = None, env: TablePlane | None = None,
                      settings: StepSettings = StepSettings()) -> tuple[StepState, StepReport]:
    """Advance B rollouts by one step (module docstring, steps 1-9).

    state: :class:`StepState` at step k
    hand: HandModel (same dtype and device as the state)
    theta_r_next: reference finger joints theta_r^{k+1}, (B, D), radians
    root_r_next: reference root pose at k + 1, (B, 4, 4)
    C: compliance of the 6 + D generalized coordinates, (B, 6 + D), rad/(N m) (root linear m/N), >= 0
    obj: the free object or None; env: a fixed plane or None (the slot layout must match ``state.contacts``)
    settings: :class:`StepSettings`
    returns: (state at k + 1, :class:`StepReport`). A rollout whose LCP is not CONVERGED keeps its previous
        forces (zero change) and is flagged by ``report.status``.
    """
    B, D = state.q.shape
    like = state.q
    check_tensor(theta_r_next, "theta_r_next", (B, D))
    check_tensor(root_r_next, "root_r_next", (B, 4, 4))
    check_tensor(C, "C", (B, 6 + D))
    if not bool((C >= 0).all()):
        raise InputValueError("C: compliances must be >= 0 (0 = rigid)")
    c = state.contacts
    N = c.mask.shape[1]
    K = 2 * settings.pyramid_m + 1
    if state.beta.shape[-1] != K:
        raise InputValueError(f"state.beta has {state.beta.shape[-1]} directions; settings.pyramid_m gives {K}")
    h = settings.h
    on_obj = c.mask & (c.body == BODY_OBJECT)
    on_tab = c.mask & (c.body == BODY_OBJECT_ENV)
    on_body = on_obj | on_tab
    sign = torch.where(c.body == BODY_OBJECT_ENV, 1.0, -1.0).to(like)            # force the object receives: s_i f_i
    S3 = sign.repeat_interleave(3)
    # steps 2-7
    dth = torch.cat([root_displacement(root_r_next, state.root_r), theta_r_next - state.theta_r], -1)
    dth = dth + state.theta_err
    G = effective_compliance(c.J, C, c.mask)
    Dfull = friction_pyramid(c.d0, settings.pyramid_m)
    if obj is not None:
        E_wb = obj.body_frame(state.object_pose)
        Mb = obj.spatial_inertia(B, like)
        g = torch.tensor(settings.gravity, dtype=like.dtype, device=like.device)
        mass = obj.mass_per_rollout(B, like)
        w_ext = torch.cat([like.new_zeros(B, 3), mass[:, None] * (E_wb[:, :3, :3].transpose(1, 2) @ g)], -1)
        U, u = rigid_body_terms(E_wb, state.phi, Mb, c.points, h, w_ext, on_body)
        # hand-object slots: the object receives -f (the paper's U_phi, u_phi); object-plane slots: +f
        U = U * S3[:, None] * S3[None, :]
        u = -u * S3
        mu_obj = obj.mu_per_rollout(B, like)[:, None]
    else:
        U, u = torch.zeros_like(G), like.new_zeros(B, 3 * N)
        mu_obj = like.new_zeros(B, 1)
    mu_env = like.new_full((B, 1), env.mu if env is not None else 0.0)
    mu = torch.where(c.body == BODY_OBJECT, mu_obj, mu_env)
    mu = torch.where(c.body == BODY_SELF, like.new_full((B, 1), settings.self_mu), mu)
    fk = state.forces.reshape(B, 3 * N)
    sp = kry_pai_s_prime(Dfull, c.separation, G=G, f_k=fk, J=c.J, dtheta_r=dth, u_phi=u)
    order, mask_c = _compact(c.mask)
    Dc = Dfull.gather(1, order[..., None, None].expand(-1, -1, 3, K))
    # quasi-rigid object-plane slots: nu gains eps f^{k+1} (G holds no f^k term for them, so s' is unchanged)
    G_lcp = G + torch.diag_embed(settings.env_compliance * on_tab.repeat_interleave(3, dim=1).to(like))
    lcp = build_kry_pai_lcp(Dc, _gather_blocks(G_lcp, order), _gather_blocks(U, order),
                            sp.gather(1, order[..., None].expand(-1, -1, K)), mu.gather(1, order), mask=mask_c)
    beta0 = torch.where(mask_c[..., None], state.beta.gather(1, order[..., None].expand(-1, -1, K)), 0.0)
    beta_c, status, residual, iters = _solve(lcp, mask_c, beta0, settings)
    # explicit nu, sigma, lambda of the solved compact problem
    Na = order.shape[1]
    r = torch.baddbmm(lcp.q[:, :Na * K, None], lcp.M[:, :Na * K, :Na * K], beta_c.reshape(B, -1, 1))
    lam_c = (-r.reshape(B, Na, K)[..., 1:]).amax(-1).clamp_min(0) * mask_c
    z = torch.cat([beta_c.reshape(B, -1), lam_c], -1)
    w = torch.baddbmm(lcp.q[..., None], lcp.M, z[..., None]).squeeze(-1)
    ok = status == int(SolverStatus.CONVERGED)
    beta = _scatter(beta_c, order, mask_c, N)
    lam = _scatter(lam_c, order, mask_c, N)
    nu = _scatter(w[:, :Na * K].reshape(B, Na, K), order, mask_c, N)
    sigma = _scatter(w[:, Na * K:], order, mask_c, N)
    f_new = torch.einsum("bnrk,bnk->bnr", Dfull, beta)
    f_next = torch.where(ok[:, None, None], f_new, state.forces)
    beta = torch.where(ok[:, None, None], beta, state.beta)
    # step 8
    if obj is not None:
        body = integrate_object(E_wb, state.phi, Mb, c.points, -sign[:, None] * f_next, h, w_ext, on_body)
        Tinv = torch.eye(4, dtype=like.dtype, device=like.device)
        Tinv[:3, 3] = -torch.tensor(obj.com, dtype=like.dtype, device=like.device)
        phi_next, pose_next = body.phi, body.E @ Tinv
    else:
        phi_next, pose_next = state.phi, state.object_pose
    delta = C * _generalized_force(c.J, f_next)
    q_free = theta_r_next + delta[:, 6:]
    q_next = hand.clamp_to_limits(q_free) if settings.clamp_joints else q_free
    clamp = (q_free - q_next).abs().amax(-1) if D else q_free.new_zeros(B)
    root_next = displace_root(root_r_next, delta[:, :6])
    du = ((G @ (f_next.reshape(B, -1) - fk)[..., None]).squeeze(-1) + (c.J @ dth[..., None]).squeeze(-1)
          + settings.env_compliance * on_tab.repeat_interleave(3, dim=1).to(like) * f_next.reshape(B, -1)
          - (U @ f_next.reshape(B, -1, 1)).squeeze(-1) - u).reshape(B, N, 3)
    # step 9
    c_new = _contacts(hand, q_next, root_next, pose_next, obj, env, settings)
    f_keep = f_next * c_new.mask[..., None]
    theta_err = C * (_generalized_force(c_new.J, f_keep) - _generalized_force(c.J, f_next))
    new = replace(state, q=q_next, root=root_next, theta_r=theta_r_next, root_r=root_r_next,
                  object_pose=pose_next, phi=phi_next, forces=f_keep, beta=beta * c_new.mask[..., None],
                  contacts=c_new, theta_err=theta_err)
    report = StepReport(status, residual, iters, c.mask.sum(1), c.mask, Dfull, beta, lam, nu, sigma, du, sp,
                        theta_err.abs().amax(-1), lcp, order, clamp)
    return new, report
