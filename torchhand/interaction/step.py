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
   method (``solver="lemke"``, exact, one problem at a time on the CPU, first tried from the previous step's
   support: ``StepSettings.lemke_warm``) or by the batched projected Gauss-Seidel
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

Layout: the types are in :mod:`._step_types`, steps 2-7 and the slacks of the solution in :mod:`._step_lcp`, the
root coordinates in :mod:`._root_coords`, the LCP's warm start from the previous step's support in
:mod:`._warm_lcp`; this module holds the driver, the LCP solve of step 7 and steps 8-9.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch

from torchhand.kernels.contact_lcp import integrate_object, solve_contact_lcp
from torchhand.kernels.status import SolverStatus

from ..conventions import check_tensor
from ..errors import InputValueError
from ..solvers import lcp as lcp_solvers
from ._contacts import Contacts, TablePlane, find_contacts, self_pairs
from ._root_coords import displace_root, root_displacement
from ._step_lcp import SlotSolution, StepTerms, compact_problem, expand_solution, predicted_motion, step_terms
from ._step_types import SOLVERS, StepObject, StepReport, StepSettings, StepState
from ._warm_lcp import WARM_TOL, solve_from_support, support_guess

__all__ = ["StepObject", "StepSettings", "StepState", "StepReport", "TablePlane", "Contacts", "initial_state",
           "quasi_static_step", "root_displacement", "displace_root", "SOLVERS"]


def _find_slots(hand, q, root, object_pose, obj, env, settings) -> Contacts:
    """The contact slots at (q, root, object_pose) (step 1 / step 9)."""
    B = q.shape[0]
    support = None if obj is None else obj.support_per_rollout(B, q)
    mesh = None if obj is None or obj.mesh is None else obj.meshes(B)     # rollouts sharing a mesh share its queries
    return find_contacts(hand, q, root, sdf=None if obj is None else obj.sdf,
                         object_pose=object_pose if obj is not None else None, plane=env, margin=settings.margin,
                         geometry=settings.geometry, object_points=None if support is None else support[0],
                         object_points_mask=None if support is None else support[1], object_mesh=mesh,
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
    c = _find_slots(hand, q, root, object_pose, obj, env, settings)
    N, K = c.mask.shape[1], 2 * settings.pyramid_m + 1
    err = -torch.cat([root_displacement(root, root_r), q - theta_r], -1)
    return StepState(q, root, theta_r, root_r, object_pose, phi, q.new_zeros(B, N, 3), q.new_zeros(B, N, K), c, err)


@dataclass(frozen=True, eq=False)
class _Motion:
    """Step 8: the object's body twist phi^{k+1} (B, 6) and pose E^{k+1} (B, 4, 4), the hand's theta^{k+1} (B, D)
    and root pose (B, 4, 4), and how far the joints were clamped into their limits, (B,), radians."""

    phi: torch.Tensor
    object_pose: torch.Tensor
    q: torch.Tensor
    root: torch.Tensor
    joint_clamp: torch.Tensor


def _check_step_inputs(state: StepState, theta_r_next: torch.Tensor, root_r_next: torch.Tensor, C: torch.Tensor,
                       settings: StepSettings) -> None:
    B, D = state.q.shape
    check_tensor(theta_r_next, "theta_r_next", (B, D))
    check_tensor(root_r_next, "root_r_next", (B, 4, 4))
    check_tensor(C, "C", (B, 6 + D))
    if not bool((C >= 0).all()):
        raise InputValueError("C: compliances must be >= 0 (0 = rigid)")
    K = 2 * settings.pyramid_m + 1
    if state.beta.shape[-1] != K:
        raise InputValueError(f"state.beta has {state.beta.shape[-1]} directions; settings.pyramid_m gives {K}")


def _warm(M: torch.Tensor, q: torch.Tensor, beta_prev: torch.Tensor, mu: torch.Tensor, settings: StepSettings,
          rel: float = 1e-9, tol: float = WARM_TOL):
    """(z, ||min(z, w)||_inf) of the LCP from the support of ``beta_prev`` (:mod:`._warm_lcp`), or None. Accepted
    within ``tol`` relative to the LCP's largest entry: by default round-off (``WARM_TOL``), as accurate as Lemke's
    re-solved basis, so that a warm answer is Lemke's answer or none."""
    na, K = beta_prev.shape
    if na == 0:
        return None
    on, sliding = support_guess(beta_prev.detach().cpu().double().numpy(), mu.detach().cpu().double().numpy(), rel)
    Mn, qn = M.numpy(), q.numpy()
    scale = max(1.0, float(np.abs(Mn).max()), float(np.abs(qn).max()))
    return solve_from_support(Mn, qn, na, K, on, sliding, tol * scale)


def _from_pgs(lcp, b: int, M: torch.Tensor, q: torch.Tensor, beta0: torch.Tensor, na: int, settings: StepSettings):
    """(z, residual) of rollout b's LCP from the support of ``settings.pgs_max_iters`` (default 200) projected
    Gauss-Seidel sweeps (:mod:`._warm_lcp`), verified within ``lemke_tol`` as a pivoted answer is (Lemke found
    none here, so there is no answer of its to match), or None."""
    one = type(lcp)(*(t[b:b + 1] for t in lcp))
    out = solve_contact_lcp(one, beta0=beta0[b:b + 1], max_iters=settings.pgs_max_iters or 200)
    return _warm(M, q, out.beta[0, :na], lcp.mu[b, :na], settings, rel=1e-6, tol=settings.lemke_tol)


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
            Mb, qb = Mc[b][rows][:, rows], qc[b][rows]
            z = _warm(Mb, qb, beta0[b, :na], lcp.mu[b, :na], settings) if settings.lemke_warm else None
            beta[b] = 0
            if z is not None:        # the previous step's support solves it: no pivoting
                beta[b, :na] = torch.from_numpy(z[0][: na * K]).reshape(na, K).to(beta)
                status[b], residual[b], iters[b] = int(SolverStatus.CONVERGED), z[1], 0
                continue
            out = lcp_solvers.solve(Mb, qb, backend="lemke", tol=settings.lemke_tol, restarts=settings.lemke_restarts)
            if out.status != SolverStatus.CONVERGED:
                z = _from_pgs(lcp, b, Mb, qb, beta0, na, settings)
                if z is not None:    # Lemke's path did not end; the support of a few PGS sweeps solves it
                    beta[b, :na] = torch.from_numpy(z[0][: na * K]).reshape(na, K).to(beta)
                    status[b], residual[b], iters[b] = int(SolverStatus.CONVERGED), z[1], out.pivots
                    continue
            beta[b, :na] = torch.from_numpy(out.x[: na * K]).reshape(na, K).to(beta)
            status[b], residual[b], iters[b] = int(out.status), out.residual, out.pivots
    return beta, status.to(D.device), residual.to(D.device), iters.to(D.device)


def _advance(state: StepState, hand, terms: StepTerms, f_next: torch.Tensor, theta_r_next: torch.Tensor,
             root_r_next: torch.Tensor, C: torch.Tensor, obj: StepObject | None, settings: StepSettings) -> _Motion:
    """Step 8: integrate the object under f^{k+1}; theta^{k+1} = theta_r^{k+1} + C J^T f^{k+1} (joints clamped)."""
    B, D = state.q.shape
    like = state.q
    c = terms.contacts
    if obj is not None:
        rigid = terms.rigid
        body = integrate_object(rigid.E_wb, state.phi, rigid.Mb, c.points, -terms.sign[:, None] * f_next, settings.h,
                                rigid.w_ext, terms.on_body)
        phi_next, pose_next = body.phi, body.E @ obj.com_shift(B, like, -1.0)
    else:
        phi_next, pose_next = state.phi, state.object_pose
    delta = C * _generalized_force(c.J, f_next)
    q_free = theta_r_next + delta[:, 6:]
    q_next = hand.clamp_to_limits(q_free) if settings.clamp_joints else q_free
    clamp = (q_free - q_next).abs().amax(-1) if D else q_free.new_zeros(B)
    root_next = displace_root(root_r_next, delta[:, :6])
    return _Motion(phi_next, pose_next, q_next, root_next, clamp)


def _next_state(state: StepState, hand, terms: StepTerms, solved: SlotSolution, motion: _Motion,
                theta_r_next: torch.Tensor, root_r_next: torch.Tensor, C: torch.Tensor, obj: StepObject | None,
                env: TablePlane | None, settings: StepSettings) -> StepState:
    """Step 9: new slots at (theta^{k+1}, E^{k+1}), each keeping its force; theta_err^{k+1} = C (J_new^T - J^T) f."""
    f_next = solved.forces
    c_new = _find_slots(hand, motion.q, motion.root, motion.object_pose, obj, env, settings)
    f_keep = f_next * c_new.mask[..., None]
    theta_err = C * (_generalized_force(c_new.J, f_keep) - _generalized_force(terms.contacts.J, f_next))
    return replace(state, q=motion.q, root=motion.root, theta_r=theta_r_next, root_r=root_r_next,
                   object_pose=motion.object_pose, phi=motion.phi, forces=f_keep,
                   beta=solved.beta * c_new.mask[..., None], contacts=c_new, theta_err=theta_err)


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
    _check_step_inputs(state, theta_r_next, root_r_next, C, settings)
    terms = step_terms(state, theta_r_next, root_r_next, C, obj, env, settings)                # steps 2-7
    problem = compact_problem(terms, state, settings)
    beta_c, status, residual, iters = _solve(problem.lcp, problem.mask, problem.beta0, settings)
    solved = expand_solution(terms, problem, state, beta_c, status, residual, iters)
    motion = _advance(state, hand, terms, solved.forces, theta_r_next, root_r_next, C, obj, settings)   # step 8
    du = predicted_motion(terms, solved.forces, settings)
    new = _next_state(state, hand, terms, solved, motion, theta_r_next, root_r_next, C, obj, env, settings)  # 9
    c = terms.contacts
    report = StepReport(solved.status, solved.residual, solved.iterations, c.mask.sum(1), c.mask, terms.D,
                        solved.beta, solved.lam, solved.nu, solved.sigma, du, terms.s_prime,
                        new.theta_err.abs().amax(-1), problem.lcp, problem.order, motion.joint_clamp)
    return new, report
