"""Effective compliance and the free rigid body of Kry & Pai's contact step (Sec. 6.2, 7.1.2): G = J C J^T (Eq. 5),
the body's U_phi and u_phi for :func:`.contact_lcp.build_kry_pai_lcp`, and the body's update after the contact
forces are known. Spatial algebra (twists (omega, v), wrenches (tau, f), the paper's order) is :mod:`.spatial`'s.
Pure tensor math.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from ._contact_checks import _check, _err
from .spatial import adjoint, exp_twist, gamma, spatial_cross

__all__ = ["RigidBodyStep", "effective_compliance", "rigid_body_terms", "integrate_object"]



class RigidBodyStep(NamedTuple):
    """Result of :func:`integrate_object`.

    phi: new body twist phi^{k+1} = (omega, v), (B, 6), body coordinates, rad/s and m/s
    E:   new pose E_wb^{k+1} = E_wb^k exp(h phi^{k+1}^), (B, 4, 4), world <- body
    w:   contact wrench on the body w^{k+1} = -Ad^T Gamma^T f^{k+1}, (tau, f), (B, 6), body coordinates
    """

    phi: torch.Tensor
    E: torch.Tensor
    w: torch.Tensor


def _mask_rows(fn: str, mask, B: int, N: int, like: torch.Tensor) -> torch.Tensor:
    if mask is None:
        return torch.ones(B, N, dtype=like.dtype, device=like.device)
    if not isinstance(mask, torch.Tensor) or tuple(mask.shape) != (B, N) or mask.dtype != torch.bool:
        raise ValueError(f"{fn}: mask must be a bool tensor of shape {(B, N)}, got "
                         f"{tuple(mask.shape) if isinstance(mask, torch.Tensor) else type(mask).__name__}")
    return mask.to(like.dtype)


def _step_h(fn: str, h, B: int, like: torch.Tensor) -> torch.Tensor:
    """h as a (B, 1, 1) tensor (float or (B,) input)."""
    ht = torch.as_tensor(h, dtype=like.dtype, device=like.device)
    if ht.dim() > 1 or (ht.dim() == 1 and ht.shape[0] != B):
        raise ValueError(f"{fn}: h must be a float or a ({B},) tensor, got shape {tuple(ht.shape)}")
    return ht.reshape(-1, 1, 1).expand(B, 1, 1)


def effective_compliance(J: torch.Tensor, c: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """Effective endpoint compliance G = J diag(c) J^T (Eq. 5).

    Args:
        J: stacked contact Jacobians J_i (Eq. 4), (B, 3N, D'), metres per radian (per metre for root translations);
            with torchhand's root columns (angular, linear) first, the root entries of ``c`` couple every contact
            pair through the wrist (Fig. 10)
        c: diagonal of the compliance C, (B, D'), rad/(N m) (m/N for root translations), >= 0 (0 = rigid)
        mask: active contact slots, (B, N) bool; rows and columns of padded slots are 0

    Returns:
        G, (B, 3N, 3N), metres per newton, symmetric positive semidefinite.
    """
    fn = "effective_compliance"
    if not isinstance(J, torch.Tensor) or J.dim() != 3 or J.shape[1] % 3 != 0:
        raise _err(fn, "J", "(B, 3N, D')", J)
    B, n3, Dp = J.shape
    _check(fn, J, "J", (B, n3, Dp))
    _check(fn, c, "c", (B, Dp), J)
    act = _mask_rows(fn, mask, B, n3 // 3, J).repeat_interleave(3, dim=1)
    Jm = J * act[..., None]
    G = (Jm * c[:, None, :]) @ Jm.transpose(1, 2)
    return 0.5 * (G + G.transpose(1, 2))


def _check_body(fn: str, E_wb, phi, M_body, r) -> int:
    """Shapes of a body's pose (B, 4, 4), twist (B, 6), spatial inertia (B, 6, 6) and contact points (B, N, 3).

    returns: B
    """
    _check(fn, E_wb, "E_wb", (E_wb.shape[0] if isinstance(E_wb, torch.Tensor) else -1, 4, 4))
    B = E_wb.shape[0]
    _check(fn, phi, "phi", (B, 6), E_wb)
    _check(fn, M_body, "M_body", (B, 6, 6), E_wb)
    if not isinstance(r, torch.Tensor) or r.dim() != 3 or r.shape[0] != B or r.shape[2] != 3:
        raise _err(fn, "r", f"({B}, N, 3)", r)
    return B


def rigid_body_terms(E_wb: torch.Tensor, phi: torch.Tensor, M_body: torch.Tensor, r: torch.Tensor, h,
                     w_ext: torch.Tensor, mask: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Contact-point motion through a free rigid body over one step, implicit in the contact forces (§7.1.2):

        U_phi = -h^2 Gamma Ad M^-1 Ad^T Gamma^T,
        u_phi = h Gamma Ad (phi^k + h M^-1 ([phi^k]^T M phi^k + w_ext)),   Ad = Ad(E_wb),

    so that the body's points r_i move by U_phi f^{k+1} + u_phi when the hand receives f^{k+1} (the body -f^{k+1}).

    Args:
        E_wb: body pose, world <- body, (B, 4, 4); the body frame should sit at the centre of mass with the
            object's axes (then M is block diagonal and gravity enters only as a force)
        phi: body twist phi^k = (omega, v), (B, 6), body coordinates, rad/s and m/s
        M_body: spatial inertia in body coordinates, (B, 6, 6): diag(I_com, m I3) at the centre of mass,
            kg m^2 and kg; symmetric positive definite
        r: contact points r_i^k, (B, N, 3), world, metres
        h: time step, float or (B,), seconds
        w_ext: external wrench (tau, f) in body coordinates, (B, 6), N m and N; gravity is (0, m Theta^T g)
        mask: slots that touch this body, (B, N) bool; other rows and columns are 0 (a fixed environment has
            U_phi = u_phi = 0)

    Returns:
        (U_phi (B, 3N, 3N) metres per newton, negative semidefinite; u_phi (B, 3N) metres)
    """
    fn = "rigid_body_terms"
    B = _check_body(fn, E_wb, phi, M_body, r)
    _check(fn, r, "r", tuple(r.shape), E_wb)
    _check(fn, w_ext, "w_ext", (B, 6), E_wb)
    N = r.shape[1]
    act = _mask_rows(fn, mask, B, N, E_wb).repeat_interleave(3, dim=1)
    hh = _step_h(fn, h, B, E_wb)
    GA = (gamma(r) * act[..., None]) @ adjoint(E_wb)                                 # (B, 3N, 6)
    L = torch.linalg.cholesky(0.5 * (M_body + M_body.transpose(1, 2)))
    X = torch.cholesky_solve(GA.transpose(1, 2), L)                                  # M^-1 Ad^T Gamma^T
    U = -(hh * hh) * (GA @ X)
    bias = (spatial_cross(phi).transpose(1, 2) @ (M_body @ phi[..., None])).squeeze(-1) + w_ext
    phi_free = phi + hh[:, 0] * torch.cholesky_solve(bias[..., None], L).squeeze(-1)
    u = hh[:, 0] * (GA @ phi_free[..., None]).squeeze(-1)
    return 0.5 * (U + U.transpose(1, 2)), u


def integrate_object(E_wb: torch.Tensor, phi: torch.Tensor, M_body: torch.Tensor, r: torch.Tensor,
                     f_next: torch.Tensor, h, w_ext: torch.Tensor,
                     mask: torch.Tensor | None = None) -> RigidBodyStep:
    """One step of the body under the new contact forces (§7.1.2, §7.1.3 update):

        w^{k+1} = -Ad^T Gamma^T f^{k+1},  phi^{k+1} = phi^k + h M^-1 (w^{k+1} + [phi^k]^T M phi^k + w_ext),
        E^{k+1} = E^k exp(h phi^{k+1}^)   (exact SE(3) exponential of the body twist; the paper names no map).

    Args:
        E_wb, phi, M_body, r, h, w_ext, mask: as in :func:`rigid_body_terms`
        f_next: contact forces f^{k+1} ON THE HAND at r, (B, N, 3), world, newtons (the body receives -f)

    Returns:
        :class:`RigidBodyStep`. Semi-implicit Euler: first order in h (the body point motion it implies is
        U_phi f^{k+1} + u_phi to first order).
    """
    fn = "integrate_object"
    B = _check_body(fn, E_wb, phi, M_body, r)
    N = r.shape[1]
    _check(fn, f_next, "f_next", (B, N, 3), E_wb)
    _check(fn, w_ext, "w_ext", (B, 6), E_wb)
    act = _mask_rows(fn, mask, B, N, E_wb)
    hh = _step_h(fn, h, B, E_wb)[:, 0]
    w_world = (gamma(r).transpose(1, 2) @ (f_next * act[..., None]).reshape(B, 3 * N, 1)).squeeze(-1)
    w = -(adjoint(E_wb).transpose(1, 2) @ w_world[..., None]).squeeze(-1)
    bias = (spatial_cross(phi).transpose(1, 2) @ (M_body @ phi[..., None])).squeeze(-1)
    L = torch.linalg.cholesky(0.5 * (M_body + M_body.transpose(1, 2)))
    phi_next = phi + hh * torch.cholesky_solve((w + bias + w_ext)[..., None], L).squeeze(-1)
    return RigidBodyStep(phi_next, E_wb @ exp_twist(phi_next, hh[:, 0]), w)
