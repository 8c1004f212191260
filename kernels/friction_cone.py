"""Batched friction-cone force solver: the dynamic feasibility test of Ye & Liu 2012 (Eqs. 4-8).

For every problem b of the batch, with its active contacts i (point p_i relative to the object's centre of mass,
unit normal n_i pointing into the object, friction coefficient mu_i, weight w_i):

    minimise    sum_i w_i (f_i . n_i)                                  (Eq. 4: total weighted normal force)
    subject to  sum_i f_i = F,   sum_i p_i x f_i = tau                 (Eq. 5: the required wrench (F, tau))
                ||f_i - (f_i . n_i) n_i|| <= mu_i (f_i . n_i)          (Eqs. 6-8: exact second-order cones)

A sliding contact (``sliding_dir`` s_i != 0) is restricted to the cone's boundary ray opposite the sliding
direction, f_i = f_n (n_i - mu_i s_i), f_n >= 0. Problems with no such forces are reported INFEASIBLE with a
certificate, never as a forced answer. Conventions: world frame, metres, newtons; normals point into the object;
wrench = (force, torque about the centre of mass) required from these contacts, all forces acting on the object.

Method: batched ADMM (Douglas-Rachford, OSQP-style splitting) with exact cone projections, residual-balancing rho
and certified stopping rules (:mod:`._cone_admm`), plus semismooth-Newton polishing of its fixed point and of the
nearest-point map for sharp infeasibility certificates (:mod:`._cone_polish`). Before that, a per-problem
normalisation (torque rows divided by the RMS contact distance, wrench scaled to unit norm, weights to unit maximum)
and a pseudo-inverse of the 6 x 6 Gram matrix (rank-deficient grasps, e.g. two contacts, are handled exactly: a
wrench outside the range of the grasp map is infeasible at once). A warm start (the parent node's forces) gets a
dual fitted to it and is polished before the first iteration. Pure tensor code: device and dtype come from the
inputs; the only host syncs are the convergence checks every ``check_every`` iterations (fewer later on).

Classification semantics: CONVERGED means cone-feasible forces with ||A f - b|| <= tol max(1, ||f||) and a
certified duality gap <= tol (1 + objective) (in the normalised units ||(F, tau / L)|| = 1, L the RMS contact
distance, so both are relative to the wrench or to the forces when those are larger); INFEASIBLE means a
separating certificate was found, which proves that no forces with total normal force below ||(F, tau / L)|| /
eps_cert exist (eps_cert per dtype in :func:`cone_tolerances`; for float64 1e-6, so such "solutions" would need a
million times the wrench); MAX_ITERATIONS returns the last cone-feasible iterate and its residual.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import torch

from ._cone_admm import AdmmSettings, admm, build_problem, certificate_margin
from ._cone_polish import warm_point
from ._cone_proj import project_cone
from .frames import tangent_frame
from .status import SolverStatus

__all__ = ["ConeResult", "ConeTolerances", "cone_tolerances", "solve_friction_cone"]


@dataclass(frozen=True)
class ConeTolerances:
    """Per-dtype tolerances of the friction-cone solver (normalised units: ||wrench|| = 1, max weight = 1).

    tol: relative primal residual and duality gap at which a problem counts as CONVERGED
    eps_cert: infeasibility certificates must rule out every solution with total normal force below 1 / eps_cert
    rank: relative eigenvalue threshold of the 6 x 6 Gram matrix (smaller eigenvalues are treated as zero)
    max_iters: default iteration limit
    """

    tol: float
    eps_cert: float
    rank: float
    max_iters: int


_TOLERANCES: tuple[tuple[torch.dtype, ConeTolerances], ...] = (
    (torch.float64, ConeTolerances(tol=1e-6, eps_cert=1e-6, rank=1e-12, max_iters=1000)),
    (torch.float32, ConeTolerances(tol=1e-4, eps_cert=1e-3, rank=1e-6, max_iters=1000)),
)


def cone_tolerances(dtype: torch.dtype) -> ConeTolerances:
    """The tolerance row of ``dtype`` (float32 or float64)."""
    for d, t in _TOLERANCES:
        if d == dtype:
            return t
    raise ValueError(f"solve_friction_cone: dtype must be float32 or float64, got {dtype}")


class ConeResult(NamedTuple):
    """Result of :func:`solve_friction_cone` (B problems, K contact slots).

    forces:     contact forces on the object, (B, K, 3), world, newtons; zero for masked-out contacts and for
                problems that are not CONVERGED / MAX_ITERATIONS (INFEASIBLE, INVALID_INPUT)
    objective:  sum_i w_i f_i . n_i of ``forces``, (B,), newtons
    residual:   ||sum f_i - F|| + ||sum p_i x f_i - tau|| of ``forces``, (B,), N + N m; +inf for INVALID_INPUT
    status:     (B,), int8 values of :class:`torchhand.kernels.status.SolverStatus`
    iterations: ADMM iterations spent on each problem, (B,), int32
    """

    forces: torch.Tensor
    objective: torch.Tensor
    residual: torch.Tensor
    status: torch.Tensor
    iterations: torch.Tensor


def _check_shape(x, name: str, shape: tuple, floating: bool = True) -> None:
    if not isinstance(x, torch.Tensor):
        raise ValueError(f"solve_friction_cone: {name} must be a torch.Tensor of shape {shape}, got {type(x).__name__}")
    if tuple(x.shape) != tuple(shape):
        raise ValueError(f"solve_friction_cone: {name} must have shape {tuple(shape)}, got {tuple(x.shape)}")
    if floating and not x.is_floating_point():
        raise ValueError(f"solve_friction_cone: {name} must be floating point, got {x.dtype}")


def _skew(p: torch.Tensor) -> torch.Tensor:
    """[p]_x with [p]_x v = p x v; p (..., 3) -> (..., 3, 3)."""
    x, y, z = p.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack([torch.stack([o, -z, y], -1), torch.stack([z, o, -x], -1), torch.stack([-y, x, o], -1)], -2)


def _check_args(points, normals, mu, wrench, mask, weights, sliding_dir, warm_start, check_every) -> None:
    """Shapes, dtypes and devices of :func:`solve_friction_cone`'s arguments; ``ValueError`` naming the argument."""
    if not isinstance(points, torch.Tensor) or points.dim() != 3 or points.shape[-1] != 3:
        raise ValueError("solve_friction_cone: points must have shape (B, K, 3), got "
                         f"{tuple(points.shape) if isinstance(points, torch.Tensor) else type(points).__name__}")
    B, K, _ = points.shape
    dtype, device = points.dtype, points.device
    _check_shape(normals, "normals", (B, K, 3))
    _check_shape(mu, "mu", (B, K))
    _check_shape(wrench, "wrench", (B, 6))
    if mask is not None:
        _check_shape(mask, "mask", (B, K), floating=False)
        if mask.dtype != torch.bool:
            raise ValueError(f"solve_friction_cone: mask must be bool, got {mask.dtype}")
    for name, x, shape in (("weights", weights, (B, K)), ("sliding_dir", sliding_dir, (B, K, 3)),
                           ("warm_start", warm_start, (B, K, 3))):
        if x is not None:
            _check_shape(x, name, shape)
    for name, x in (("normals", normals), ("mu", mu), ("wrench", wrench), ("weights", weights),
                    ("sliding_dir", sliding_dir), ("warm_start", warm_start)):
        if x is not None and (x.dtype != dtype or x.device != device):
            raise ValueError(f"solve_friction_cone: {name} must be {dtype} on {device} like points, "
                             f"got {x.dtype} on {x.device}")
    if check_every < 1:
        raise ValueError(f"solve_friction_cone: check_every must be >= 1, got {check_every}")


def _local_axes(act, sliding_dir, nn, mu_c, zero):
    """Local frames: e0 = the normal (static) or the unit sliding ray (mu_eff = 0). Returns R (B, K, 3, 3), columns
    = local axes in world, and mu_eff (B, K)."""
    e0, mu_eff = nn, mu_c
    if sliding_dir is not None:
        s = torch.where(act[..., None], sliding_dir, zero)
        s = s - (s * nn).sum(-1, keepdim=True) * nn
        s_norm = torch.linalg.vector_norm(s, dim=-1)
        sliding = s_norm > 1e-6
        ray = nn - mu_c[..., None] * s / s_norm.clamp_min(1e-6)[..., None]
        ray = ray / torch.linalg.vector_norm(ray, dim=-1, keepdim=True)
        e0 = torch.where(sliding[..., None], ray, nn)
        mu_eff = torch.where(sliding, zero, mu_c)
    t1, t2 = tangent_frame(e0)
    R = torch.stack([e0, t1, t2], -1)                       # (B, K, 3, 3), columns = local axes in world
    return R, mu_eff


def _initial_point(warm_start, R, act, zero, beta, mu_eff, prob, settings, B, K, dtype, device):
    """ADMM's first point: zero, or the warm start's world forces in normalised local coordinates with a dual fitted
    to them."""
    if warm_start is not None:
        # Parent forces -> local, normalised, with a dual fitted to them; polished before the first iteration.
        z0 = (R.transpose(-1, -2) @ torch.where(act[..., None], warm_start, zero)[..., None]).squeeze(-1)
        z0 = project_cone((z0 / beta[:, None, None]).transpose(1, 2).reshape(B, 3 * K), mu_eff)
        rho0 = torch.full((B, 1), settings.rho, dtype=dtype, device=device)
        return warm_point(z0, prob.A, prob.c, mu_eff, act, rho0)
    else:
        return torch.zeros(B, 3 * K, dtype=dtype, device=device)


def _in_world(R, z, status, iterations, beta, actf, w_c, nn, p, F, invalid, B, K, dtype) -> ConeResult:
    """Forces in the world frame, objective and residual in physical units, from ADMM's normalised local point."""
    solved = (status == int(SolverStatus.CONVERGED)) | (status == int(SolverStatus.MAX_ITERATIONS))
    scale = (beta * solved.to(dtype))[:, None, None]
    forces = (R @ z.view(B, 3, K).transpose(1, 2)[..., None]).squeeze(-1) * scale * actf[..., None]
    objective = (w_c * (forces * nn).sum(-1)).sum(-1)
    res_f = forces.sum(1) - F[:, :3]
    res_t = torch.cross(p, forces, dim=-1).sum(1) - F[:, 3:]
    residual = torch.linalg.vector_norm(res_f, dim=-1) + torch.linalg.vector_norm(res_t, dim=-1)
    residual = torch.where(invalid, torch.full_like(residual, math.inf), residual)
    return ConeResult(forces, objective, residual, status, iterations)


def solve_friction_cone(points: torch.Tensor, normals: torch.Tensor, mu: torch.Tensor, wrench: torch.Tensor, *,
                        mask: torch.Tensor | None = None, weights: torch.Tensor | None = None,
                        sliding_dir: torch.Tensor | None = None, warm_start: torch.Tensor | None = None,
                        tol: float | None = None, max_iters: int | None = None,
                        check_every: int = 10, polish: bool = True, polish_from: int | None = None) -> ConeResult:
    """Minimum weighted normal force contact forces that produce a required wrench (Ye & Liu 2012, Eqs. 4-8).

    Args:
        points: contact points relative to the object's centre of mass, (B, K, 3), world, metres
        normals: unit contact normals pointing into the object, (B, K, 3) (renormalised here)
        mu: friction coefficients, (B, K), >= 0
        wrench: required net wrench on the object from these contacts, (B, 6): force (N), torque about the COM (N m)
        mask: active contacts, (B, K) bool; padding is False (its values are ignored). Default: all active
        weights: objective weights w_i, (B, K), >= 0. Default 1
        sliding_dir: unit sliding velocity of each contact, (B, K, 3); zeros = static. Only the part tangent to
            the normal counts. A sliding contact's force is restricted to f = f_n (n - mu s), f_n >= 0
        warm_start: forces of a nearby problem (e.g. the parent node), (B, K, 3), world, newtons
        tol: relative tolerance on the wrench residual and the duality gap; default per dtype (``cone_tolerances``)
        max_iters: iteration limit per problem; default per dtype
        check_every: iterations between convergence checks (the only host syncs)
        polish: Newton-polish the ADMM fixed point (exact active sets, faster to tight tolerances); without it
            plain ADMM, cheaper per check and enough for a feasibility verdict at a loose ``tol``
        polish_from: first iteration at which polishing is tried (default 20): later polishing leaves the easy
            problems to plain ADMM and spends Newton steps on the slow ones only

    Returns:
        :class:`ConeResult`. Problems with NaN/inf in an active entry (or a zero normal, mu < 0, weight < 0) are
        INVALID_INPUT and the rest solve as usual. Raises ``ValueError`` naming the argument on wrong shapes.
    """
    _check_args(points, normals, mu, wrench, mask, weights, sliding_dir, warm_start, check_every)
    B, K, _ = points.shape
    dtype, device = points.dtype, points.device
    tab = cone_tolerances(dtype)
    eps = tab.tol if tol is None else float(tol)
    max_iters = tab.max_iters if max_iters is None else int(max_iters)

    active = torch.ones(B, K, dtype=torch.bool, device=device) if mask is None else mask.to(device)
    w = torch.ones_like(mu) if weights is None else weights

    # --- invalid input: decided per problem, bad problems are neutralised and masked out ----------------------
    nrm = torch.linalg.vector_norm(normals, dim=-1)
    bad_c = ~(torch.isfinite(points).all(-1) & torch.isfinite(normals).all(-1) & torch.isfinite(mu)
              & torch.isfinite(w) & (nrm > 1e-6) & (mu >= 0) & (w >= 0))
    if sliding_dir is not None:
        bad_c |= ~torch.isfinite(sliding_dir).all(-1)
    if warm_start is not None:
        bad_c |= ~torch.isfinite(warm_start).all(-1)
    invalid = (bad_c & active).any(-1) | ~torch.isfinite(wrench).all(-1)
    act = active & ~invalid[:, None]
    actf = act.to(dtype)
    zero = torch.zeros((), dtype=dtype, device=device)
    p = torch.where(act[..., None], points, zero)
    nn = torch.where(act[..., None], normals / nrm.clamp_min(1e-6)[..., None], zero)
    nn = torch.where(act[..., None], nn, torch.tensor([0.0, 0.0, 1.0], dtype=dtype, device=device))
    mu_c = torch.where(act, mu, zero)
    w_c = torch.where(act, w, zero)
    F = torch.where(invalid[:, None], zero, wrench)

    R, mu_eff = _local_axes(act, sliding_dir, nn, mu_c, zero)   # local frames: e0 = normal or sliding ray

    # --- normalisation ---------------------------------------------------------------------------------------
    count = actf.sum(-1)
    L = ((p * p).sum(-1).sum(-1) / count.clamp_min(1)).sqrt()
    L = torch.where(L > 1e-9, L, torch.ones_like(L))         # length scale of the torque rows
    Fs = torch.cat([F[:, :3], F[:, 3:] / L[:, None]], -1)
    beta = torch.linalg.vector_norm(Fs, dim=-1)
    beta = torch.where(beta > 0, beta, torch.ones_like(beta))
    b = Fs / beta[:, None]
    omega = w_c.amax(-1)
    omega = torch.where(omega > 0, omega, torch.ones_like(omega))
    c_world = (w_c / omega[:, None])[..., None] * nn        # objective gradient per contact, world
    c = (R.transpose(-1, -2) @ c_world[..., None]).squeeze(-1)   # (B, K, 3), local
    A_f = R * actf[..., None, None]                           # force rows, (B, K, 3, 3)
    A_t = _skew(p / L[:, None, None]) @ A_f                  # torque rows
    A = torch.cat([A_f, A_t], -2).permute(0, 2, 3, 1).reshape(B, 6, 3 * K)   # component-major columns

    prob, range_infeasible = build_problem(A, b, c.transpose(1, 2).reshape(B, 3 * K), mu_eff, act, tab.rank,
                                           tab.eps_cert)
    # The wrench direction itself is the most common certificate (every cone points away from it): test it first.
    range_infeasible = (range_infeasible | (certificate_margin(prob.b, prob) <= tab.eps_cert)) & ~invalid

    # --- warm start (world forces -> normalised local coordinates) --------------------------------------------
    settings = AdmmSettings(eps=eps, eps_cert=tab.eps_cert, max_iters=max_iters, check_every=check_every,
                            polish=bool(polish))
    if polish_from is not None:
        settings = settings._replace(polish_from=int(polish_from))
    w0 = _initial_point(warm_start, R, act, zero, beta, mu_eff, prob, settings, B, K, dtype, device)

    out = admm(prob, w0, settings, decided=invalid | range_infeasible, check_first=warm_start is not None)
    status = torch.where(range_infeasible, int(SolverStatus.INFEASIBLE), out.status)
    status = torch.where(invalid, int(SolverStatus.INVALID_INPUT), status).to(torch.int8)
    z, iterations = out.z, out.iterations

    return _in_world(R, z, status, iterations, beta, actf, w_c, nn, p, F, invalid, B, K, dtype)
