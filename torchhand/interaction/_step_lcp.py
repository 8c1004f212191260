"""The contact LCP of one quasi-static step (Kry & Pai 2006 §7.1, steps 2-7 and the slacks of the solution).

Stages over frozen state, in the order :func:`torchhand.interaction.step.quasi_static_step` runs them::

    terms = step_terms(state, theta_r_next, root_r_next, C, obj, env, settings)   # D, G, U_phi, u_phi, mu, s'
    problem = compact_problem(terms, state, settings)                              # the active slots first
    ... the problem is solved by the step (Lemke or batched PGS) ...
    solved = expand_solution(terms, problem, state, beta_c, status, residual, iters)   # beta, lambda, nu, sigma, f
    du = predicted_motion(terms, solved.forces, settings)                          # Eq. 10

Signs (the module docstring of :mod:`torchhand.interaction.step`): a hand-object slot's object receives -f_i, an
object-plane slot's +f_i, so U_phi -> S U_phi S and u_phi -> -S u_phi with S = diag(s_i I3). Units: metres,
seconds, radians, newtons; forces on the hand.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from torchhand.kernels.contact_lcp import (KryPaiLCP, build_kry_pai_lcp, effective_compliance, friction_pyramid,
                                           kry_pai_s_prime, rigid_body_terms)
from torchhand.kernels.status import SolverStatus

from ._contacts import BODY_OBJECT, BODY_OBJECT_ENV, BODY_SELF, Contacts, TablePlane
from ._root_coords import root_displacement
from ._step_types import StepObject, StepSettings, StepState

__all__ = ["RigidTerms", "StepTerms", "CompactProblem", "SlotSolution", "step_terms", "compact_problem",
           "expand_solution", "predicted_motion"]


@dataclass(frozen=True, eq=False)
class RigidTerms:
    """The free object at step k.

    E_wb: body frame at the centre of mass, (B, 4, 4), world; Mb: spatial inertia diag(I_com, m I3), (B, 6, 6);
    w_ext: gravity wrench in the body frame (0, m Theta^T g), (B, 6), newtons
    """

    E_wb: torch.Tensor
    Mb: torch.Tensor
    w_ext: torch.Tensor


@dataclass(frozen=True, eq=False)
class StepTerms:
    """Steps 1-7 at the slots of ``contacts`` (K = 2m + 1 pyramid directions); the matrices over the active slots
    only (Na = the most active slots of a rollout, active slots first in slot order, padding masked), which is
    where they are not zero.

    contacts: the slots at step k; on_tab: object-plane slots, (B, N) bool; on_body: slots whose first body is the
    object (hand-object or object-plane), (B, N) bool; sign: s_i, the sign of the force the object receives, (N,);
    dth: J's input dtheta_r + theta_err, (B, 6 + D); D: pyramid directions, (B, N, 3, K); mu: friction per slot,
    (B, N); f_k: f^k, (B, 3N), newtons; s_prime: (B, N, K), metres (0 on inactive slots); rigid:
    :class:`RigidTerms` or None.
    Over the active slots: order: slot index of each, (B, Na) long; mask_c: (B, Na) bool; J_c: their Jacobian
    rows, (B, 3Na, 6 + D); G: J C J^T, (B, 3Na, 3Na), m/N; U, u: the object's signed U_phi (B, 3Na, 3Na) and
    u_phi (B, 3Na) (zero without an object)
    """

    contacts: Contacts
    on_tab: torch.Tensor
    on_body: torch.Tensor
    sign: torch.Tensor
    dth: torch.Tensor
    D: torch.Tensor
    mu: torch.Tensor
    f_k: torch.Tensor
    s_prime: torch.Tensor
    rigid: RigidTerms | None
    order: torch.Tensor
    mask_c: torch.Tensor
    J_c: torch.Tensor
    G: torch.Tensor
    U: torch.Tensor
    u: torch.Tensor


@dataclass(frozen=True, eq=False)
class CompactProblem:
    """The LCP over the active slots only (Na = max active count, active slots first, padding masked).

    order: slot index of each compact contact, (B, Na), long; mask: the compact mask, (B, Na); lcp:
    :class:`~torchhand.kernels.contact_lcp.KryPaiLCP`; beta0: warm start from f^k's pyramid coordinates, (B, Na, K)
    """

    order: torch.Tensor
    mask: torch.Tensor
    lcp: KryPaiLCP
    beta0: torch.Tensor


@dataclass(frozen=True, eq=False)
class SlotSolution:
    """The solved LCP back on the N slots (rollouts whose LCP is not CONVERGED keep f^k and beta^k).

    status (B,) int8, residual (B,), iterations (B,) int32: the solver's; beta: (B, N, K), newtons; lam: slip
    lambda_i, (B, N), metres; nu: (B, N, K), metres; sigma: (B, N), newtons; forces: f^{k+1}, (B, N, 3), newtons
    """

    status: torch.Tensor
    residual: torch.Tensor
    iterations: torch.Tensor
    beta: torch.Tensor
    lam: torch.Tensor
    nu: torch.Tensor
    sigma: torch.Tensor
    forces: torch.Tensor


def _rigid_terms(state: StepState, obj: StepObject, c: Contacts, sign_c: torch.Tensor, on_body: torch.Tensor,
                 settings: StepSettings, order: torch.Tensor):
    """Step 6 with an object: (:class:`RigidTerms`, signed U_phi (B, 3Na, 3Na), signed u_phi (B, 3Na), its friction
    (B, 1)) over the active slots ``order`` (B, Na) (:func:`_compact`), whose signs s_i are ``sign_c`` (B, Na)."""
    B = state.q.shape[0]
    like = state.q
    E_wb = obj.body_frame(state.object_pose)
    Mb = obj.spatial_inertia(B, like)
    g = torch.tensor(settings.gravity, dtype=like.dtype, device=like.device)
    mass = obj.mass_per_rollout(B, like)
    w_ext = torch.cat([like.new_zeros(B, 3), mass[:, None] * (E_wb[:, :3, :3].transpose(1, 2) @ g)], -1)
    U, u = rigid_body_terms(E_wb, state.phi, Mb, c.points.gather(1, order[..., None].expand(-1, -1, 3)), settings.h,
                            w_ext, on_body.gather(1, order))
    # hand-object slots: the object receives -f (the paper's U_phi, u_phi); object-plane slots: +f
    S3 = sign_c.repeat_interleave(3, dim=1)
    U = U * S3[:, :, None] * S3[:, None, :]
    u = -u * S3
    mu_obj = obj.mu_per_rollout(B, like)[:, None]
    return RigidTerms(E_wb, Mb, w_ext), U, u, mu_obj


def _slot_mu(c: Contacts, mu_obj: torch.Tensor, env: TablePlane | None, settings: StepSettings,
             like: torch.Tensor) -> torch.Tensor:
    """The friction coefficient of every slot, (B, N): the object's (B, 1), the table's, or the fingers'."""
    B = like.shape[0]
    mu_env = like.new_full((B, 1), env.mu if env is not None else 0.0)
    mu = torch.where(c.body == BODY_OBJECT, mu_obj, mu_env)
    return torch.where(c.body == BODY_SELF, like.new_full((B, 1), settings.self_mu), mu)


def step_terms(state: StepState, theta_r_next: torch.Tensor, root_r_next: torch.Tensor, C: torch.Tensor,
               obj: StepObject | None, env: TablePlane | None, settings: StepSettings) -> StepTerms:
    """Steps 2-7 at the slots of ``state.contacts``: pyramids, G = J C J^T, the object's terms, mu and s', the
    matrices over the active slots only (:class:`StepTerms`)."""
    B = state.q.shape[0]
    like = state.q
    c = state.contacts
    N = c.mask.shape[1]
    on_obj = c.mask & (c.body == BODY_OBJECT)
    on_tab = c.mask & (c.body == BODY_OBJECT_ENV)
    on_body = on_obj | on_tab
    sign = torch.where(c.body == BODY_OBJECT_ENV, 1.0, -1.0).to(like)            # force the object receives: s_i f_i
    dth = torch.cat([root_displacement(root_r_next, state.root_r), theta_r_next - state.theta_r], -1)
    dth = dth + state.theta_err
    order, mask_c = _compact(c.mask)         # G and U_phi vanish outside the active slots: computed there only
    idx = _rows(order)
    J_c = c.J.gather(1, idx[..., None].expand(-1, -1, c.J.shape[2]))
    G = effective_compliance(J_c, C, mask_c)
    Dfull = friction_pyramid(c.d0, settings.pyramid_m)
    if obj is not None:
        rigid, U, u, mu_obj = _rigid_terms(state, obj, c, sign[order], on_body, settings, order)
    else:
        rigid = None
        U, u = torch.zeros_like(G), like.new_zeros(B, idx.shape[1])
        mu_obj = like.new_zeros(B, 1)
    mu = _slot_mu(c, mu_obj, env, settings, like)
    fk = state.forces.reshape(B, 3 * N)
    K = Dfull.shape[-1]
    sp_c = kry_pai_s_prime(Dfull.gather(1, order[..., None, None].expand(-1, -1, 3, K)), c.separation.gather(1, order),
                           G=G, f_k=fk.gather(1, idx), J=J_c, dtheta_r=dth, u_phi=u)
    sp = _scatter(sp_c, order, mask_c, N)
    return StepTerms(c, on_tab, on_body, sign, dth, Dfull, mu, fk, sp, rigid, order, mask_c, J_c, G, U, u)


def _rows(order: torch.Tensor) -> torch.Tensor:
    """The 3 rows of each slot of ``order`` (B, Na) in the stacked (B, 3N) layout, (B, 3 Na)."""
    return (order[..., None] * 3 + torch.arange(3, device=order.device)).reshape(order.shape[0], -1)


def _compact(mask: torch.Tensor):
    """Active slots first: order (B, Na) slot indices and the compact mask (B, Na); Na = max active count."""
    B, N = mask.shape
    order = torch.argsort((~mask).to(torch.int8), dim=1, stable=True)
    na = max(int(mask.sum(1).max()), 1)
    order = order[:, :na]
    return order, mask.gather(1, order)


def _scatter(xc: torch.Tensor, order: torch.Tensor, mask_c: torch.Tensor, N: int) -> torch.Tensor:
    """Compact slot values (B, Na, ...) back to the N slots (B, N, ...), zero on inactive slots."""
    B, Na = order.shape
    ones = [1] * (xc.dim() - 2)
    xc = xc * mask_c.reshape(B, Na, *ones).to(xc)
    return xc.new_zeros(B, N, *xc.shape[2:]).scatter(1, order.reshape(B, Na, *ones).expand_as(xc), xc)


def _env_compliance(terms: StepTerms, settings: StepSettings, like: torch.Tensor) -> torch.Tensor:
    """eps on the three rows of every active object-plane slot, 0 elsewhere, (B, 3Na), m/N."""
    on_tab_c = terms.on_tab.gather(1, terms.order)
    return settings.env_compliance * on_tab_c.repeat_interleave(3, dim=1).to(like)


def compact_problem(terms: StepTerms, state: StepState, settings: StepSettings) -> CompactProblem:
    """Step 7's LCP over the active slots (quasi-rigid object-plane slots: G gains eps on their rows)."""
    K = 2 * settings.pyramid_m + 1
    order, mask_c = terms.order, terms.mask_c
    Dc = terms.D.gather(1, order[..., None, None].expand(-1, -1, 3, K))
    # quasi-rigid object-plane slots: nu gains eps f^{k+1} (G holds no f^k term for them, so s' is unchanged)
    G_lcp = terms.G + torch.diag_embed(_env_compliance(terms, settings, state.q))
    lcp = build_kry_pai_lcp(Dc, G_lcp, terms.U, terms.s_prime.gather(1, order[..., None].expand(-1, -1, K)),
                            terms.mu.gather(1, order), mask=mask_c)
    beta0 = torch.where(mask_c[..., None], state.beta.gather(1, order[..., None].expand(-1, -1, K)), 0.0)
    return CompactProblem(order, mask_c, lcp, beta0)


def expand_solution(terms: StepTerms, problem: CompactProblem, state: StepState, beta_c: torch.Tensor,
                    status: torch.Tensor, residual: torch.Tensor, iters: torch.Tensor) -> SlotSolution:
    """The explicit nu, sigma, lambda of the solved compact problem, scattered back to the N slots, and f^{k+1}."""
    B = state.q.shape[0]
    N = terms.contacts.mask.shape[1]
    K = terms.D.shape[-1]
    order, mask_c, lcp = problem.order, problem.mask, problem.lcp
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
    f_new = torch.einsum("bnrk,bnk->bnr", terms.D, beta)
    f_next = torch.where(ok[:, None, None], f_new, state.forces)
    beta = torch.where(ok[:, None, None], beta, state.beta)
    return SlotSolution(status, residual, iters, beta, lam, nu, sigma, f_next)


def predicted_motion(terms: StepTerms, f_next: torch.Tensor, settings: StepSettings) -> torch.Tensor:
    """du: the relative motion of every slot's first body w.r.t. its counterpart (Eq. 10), (B, N, 3), metres (0 on
    inactive slots, whose G, U_phi, u_phi and J rows are 0)."""
    B, N = f_next.shape[:2]
    order, idx = terms.order, _rows(terms.order)
    G, U, u = terms.G, terms.U, terms.u
    f = f_next.reshape(B, -1).gather(1, idx)
    du = ((G @ (f - terms.f_k.gather(1, idx))[..., None]).squeeze(-1) + (terms.J_c @ terms.dth[..., None]).squeeze(-1)
          + _env_compliance(terms, settings, f_next) * f - (U @ f[..., None]).squeeze(-1) - u)
    return _scatter(du.reshape(B, -1, 3), order, terms.mask_c, N)
