"""Liu 2009 contact-force planning (Sec. 4, Eqs. 1-4) as standard-form QPs and per-frame LPs.

Conventions: world frame, metres, seconds, newtons. Normals n_i point into the object; f_i = B_i lambda_i is the
force of the hand (or the table) on the object; the wrench is (force, torque about the object's centre of mass).

Variables (window of n frames t = 0..n-1, M contact slots i, 4 coefficients j), frame-major::

    z = vec(lambda_i^t) in R^(4 M n),   index (t * M + i) * 4 + j

Basis (Eq. 2): a static contact uses the pyramid edges B_i = [n + mu t1, n - mu t1, n + mu t2, n - mu t2]
(not normalised, so n^T B_i lambda_i = sum_j lambda_ij is the normal force); (t1, t2) come from
:func:`.frames.tangent_frame` of n unless ``tangent`` gives t1 (then t2 = n x t1). A sliding contact (``sliding``
non-zero at that frame) uses the single ray n + mu v_hat (Fig. 3; v_hat = the unit tangential velocity of the hand
point relative to the object point, so friction drags the object along with the hand) in column 0; columns 1-3
are zero. Masked-out (slot, frame) pairs have four zero columns.

Window QP (Eq. 4) in the form of :func:`torchhand.solvers._qpth.solve_qp` / :func:`.convex_qp.solve_convex_qp`::

    minimise  sum_t sum_i |B_i^t lambda_i^t - B_i^(t-1) lambda_i^(t-1)|^2      (Eq. 3; t = -1 is f_prev)
            = 1/2 z^T Q z + p^T z + offset
    s.t.      sum_i [I; [r_i^t]x] B_i^t lambda_i^t = w_t   for every t           (Eq. 1; A (6n rows), b)
              -lambda <= 0;  n_i^T B_i^t lambda_i^t <= f_max for hand contacts    (G = [-I; N], h = [0; f_max])

Deviations and choices (documented here, not in the paper):
    * Smoothness is measured on world forces f_i^t = B_i^t lambda_i^t (the paper's G(lambda_i, t) written with the
      basis of each frame, as Sec. 4.1 suggests when the basis changes).
    * Zero columns (sliding padding, masked pairs) would leave their lambda free; a unit diagonal is added to Q on
      them, which pins them to 0 at the optimum without changing the objective's value there.
    * The normal-force row exists for every (frame, slot) to keep shapes fixed; it is zero (0 <= f_max, always
      satisfied) for table contacts and masked pairs.
    * The force limit bounds the normal force n^T f <= f_max (Liu: "can not generate gripping force more than
      30 N"); table contacts only have lambda >= 0.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from .frames import tangent_frame

__all__ = ["WindowQP", "FrameLPs", "contact_basis", "assemble_window_qp", "assemble_frame_lps"]


class WindowQP(NamedTuple):
    """Standard-form window QP (B problems, n frames, M slots, nz = 4 M n).

    Q: (B, nz, nz), N^-2 per lambda^2 (lambda in newtons), PSD; p: (B, nz), newtons
    G: (B, 4Mn + Mn, nz) = [-I; N]; h: (B, 4Mn + Mn), newtons
    A: (B, 6n, nz) (force rows, then torque rows, per frame); b: (B, 6n), N and N m
    offset: constant term sum_i |f_prev_i|^2 of Eq. 3, (B,), N^2 (objective = 1/2 z^T Q z + p^T z + offset)
    basis: B_i^t, (B, n, M, 3, 4), unitless: forces f = basis @ lambda
    """

    Q: torch.Tensor
    p: torch.Tensor
    G: torch.Tensor
    h: torch.Tensor
    A: torch.Tensor
    b: torch.Tensor
    offset: torch.Tensor
    basis: torch.Tensor


class FrameLPs(NamedTuple):
    """Eq. 4 without the objective, one feasibility LP per frame (Sec. 4.3), nz = 4 M per frame.

    G: (B, n, 5M, 4M) = [-I; N]; h: (B, n, 5M), newtons; A: (B, n, 6, 4M); b: (B, n, 6), N and N m.
    Flatten the first two dimensions (``x.flatten(0, 1)``) for a batch of B n LPs.
    """

    G: torch.Tensor
    h: torch.Tensor
    A: torch.Tensor
    b: torch.Tensor


def _err(fn: str, name: str, shape: str, x) -> ValueError:
    got = tuple(x.shape) if isinstance(x, torch.Tensor) else type(x).__name__
    return ValueError(f"{fn}: {name} must have shape {shape}, got {got}")


def _skew(r: torch.Tensor) -> torch.Tensor:
    """[r]_x, (..., 3) -> (..., 3, 3)."""
    x, y, z = r.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack([torch.stack([o, -z, y], -1), torch.stack([z, o, -x], -1), torch.stack([-y, x, o], -1)], -2)


def contact_basis(normals: torch.Tensor, mu: torch.Tensor, *, mask: torch.Tensor | None = None,
                  sliding: torch.Tensor | None = None, tangent: torch.Tensor | None = None) -> torch.Tensor:
    """Force bases B_i^t (Eq. 2, see the module docstring).

    Args:
        normals: unit contact normals into the object, (B, n, M, 3) (normalised here)
        mu: friction coefficients, (B, M), unitless
        mask: active (frame, slot) pairs, (B, n, M) bool, or None (all active)
        sliding: tangential sliding directions v_hat, (B, n, M, 3) (normalised here; zero = static), or None
        tangent: first tangent t1 per pair, (B, n, M, 3) (projected and normalised here), or None

    Returns:
        basis, (B, n, M, 3, 4), unitless
    """
    fn = "contact_basis"
    if not isinstance(normals, torch.Tensor) or normals.dim() != 4 or normals.shape[-1] != 3:
        raise _err(fn, "normals", "(B, n, M, 3)", normals)
    B, n, M, _ = normals.shape
    if not isinstance(mu, torch.Tensor) or tuple(mu.shape) != (B, M):
        raise _err(fn, "mu", f"({B}, {M})", mu)
    tiny = torch.finfo(normals.dtype).tiny
    nrm = normals / torch.linalg.vector_norm(normals, dim=-1, keepdim=True).clamp_min(tiny)
    if tangent is None:
        t1, t2 = tangent_frame(nrm)
    else:
        if not isinstance(tangent, torch.Tensor) or tangent.shape != normals.shape:
            raise _err(fn, "tangent", f"({B}, {n}, {M}, 3)", tangent)
        t1 = tangent - (tangent * nrm).sum(-1, keepdim=True) * nrm
        t1 = t1 / torch.linalg.vector_norm(t1, dim=-1, keepdim=True).clamp_min(tiny)
        t2 = torch.cross(nrm, t1, dim=-1)
    m = mu.view(B, 1, M, 1)
    basis = torch.stack([nrm + m * t1, nrm - m * t1, nrm + m * t2, nrm - m * t2], -1)
    if sliding is not None:
        if not isinstance(sliding, torch.Tensor) or sliding.shape != normals.shape:
            raise _err(fn, "sliding", f"({B}, {n}, {M}, 3)", sliding)
        v = sliding - (sliding * nrm).sum(-1, keepdim=True) * nrm
        vn = torch.linalg.vector_norm(v, dim=-1, keepdim=True)
        slides = vn.squeeze(-1) > 0
        ray = nrm + m * v / vn.clamp_min(tiny)
        slid = torch.stack([ray, torch.zeros_like(ray), torch.zeros_like(ray), torch.zeros_like(ray)], -1)
        basis = torch.where(slides[..., None, None], slid, basis)
    if mask is not None:
        if not isinstance(mask, torch.Tensor) or tuple(mask.shape) != (B, n, M) or mask.dtype != torch.bool:
            raise _err(fn, "mask", f"({B}, {n}, {M}) bool", mask)
        basis = basis * mask[..., None, None].to(basis.dtype)
    return basis


def _wrench_map(points: torch.Tensor, com: torch.Tensor, basis: torch.Tensor) -> torch.Tensor:
    """Per-frame wrench of unit lambdas, (B, n, 6, 4M): rows [B_i; [r_i]x B_i], r_i = p_i - c."""
    B, n, M = basis.shape[:3]
    r = points - com.unsqueeze(2)
    tor = _skew(r) @ basis                                                 # (B, n, M, 3, 4)
    W = torch.cat([basis, tor], -2)                                        # (B, n, M, 6, 4)
    return W.permute(0, 1, 3, 2, 4).reshape(B, n, 6, 4 * M)


def _limits(basis: torch.Tensor, normals: torch.Tensor, hand: torch.Tensor, f_max) -> tuple[torch.Tensor, torch.Tensor]:
    """Normal-force rows N (B, n, M, 4M) and their bounds (B, n, M)."""
    B, n, M = basis.shape[:3]
    tiny = torch.finfo(normals.dtype).tiny
    nrm = normals / torch.linalg.vector_norm(normals, dim=-1, keepdim=True).clamp_min(tiny)
    nb = (nrm.unsqueeze(-2) @ basis).squeeze(-2) * hand.view(B, 1, M, 1).to(basis.dtype)   # (B, n, M, 4)
    eye = torch.eye(M, dtype=basis.dtype, device=basis.device)
    N = (eye.view(1, 1, M, M, 1) * nb.unsqueeze(2)).reshape(B, n, M, 4 * M)
    fm = f_max if isinstance(f_max, torch.Tensor) else basis.new_full((B, M), float(f_max))
    return N, fm.view(B, 1, M).expand(B, n, M)


def _validate(fn, points, normals, com, mu, wrench, mask, hand, f_max):
    if not isinstance(points, torch.Tensor) or points.dim() != 4 or points.shape[-1] != 3:
        raise _err(fn, "points", "(B, n, M, 3)", points)
    B, n, M, _ = points.shape
    if not points.is_floating_point():
        raise ValueError(f"{fn}: points must be floating point, got {points.dtype}")
    for x, name, shape in ((normals, "normals", (B, n, M, 3)), (com, "com", (B, n, 3)), (mu, "mu", (B, M)),
                           (wrench, "wrench", (B, n, 6))):
        if not isinstance(x, torch.Tensor) or tuple(x.shape) != shape:
            raise _err(fn, name, str(shape), x)
        if x.dtype != points.dtype:
            raise ValueError(f"{fn}: {name} must have dtype {points.dtype} (that of points), got {x.dtype}")
    for x, name, shape in ((mask, "mask", (B, n, M)), (hand, "hand", (B, M))):
        if x is not None and (not isinstance(x, torch.Tensor) or tuple(x.shape) != shape or x.dtype != torch.bool):
            raise _err(fn, name, f"{shape} bool", x)
    if isinstance(f_max, torch.Tensor):
        if tuple(f_max.shape) != (B, M):
            raise _err(fn, "f_max", f"({B}, {M})", f_max)
    elif not (isinstance(f_max, (int, float)) and f_max > 0):
        raise ValueError(f"{fn}: f_max must be a positive number or a (B, M) tensor, got {f_max!r}")
    return B, n, M


def assemble_window_qp(points: torch.Tensor, normals: torch.Tensor, com: torch.Tensor, mu: torch.Tensor,
                       wrench: torch.Tensor, f_prev: torch.Tensor, *, mask: torch.Tensor | None = None,
                       hand: torch.Tensor | None = None, f_max: float | torch.Tensor = 30.0,
                       sliding: torch.Tensor | None = None, tangent: torch.Tensor | None = None) -> WindowQP:
    """Liu 2009 Eq. 4 for a window of n frames as a standard-form QP (see the module docstring).

    Args:
        points: contact points on the object, (B, n, M, 3), world, metres (p^{k-1} moved with the object)
        normals: contact normals into the object, (B, n, M, 3), world, unit
        com: object centre of mass per frame, (B, n, 3), world, metres
        mu: friction coefficient per slot, (B, M), unitless
        wrench: required wrench w_t = (m (a - g); I_w alpha + omega x I_w omega) - w_ext, (B, n, 6), N and N m
        f_prev: forces of the frame before the window, B^{k-1} lambda^{k-1}, (B, M, 3), world, newtons
        mask: active (frame, slot) pairs, (B, n, M) bool, or None (all active)
        hand: hand contacts (True) or table contacts (False), (B, M) bool, or None (all hand)
        f_max: normal-force limit of hand contacts, newtons: a number or (B, M)
        sliding: sliding directions v_hat, (B, n, M, 3) (zero = static), or None (all static)
        tangent: first tangents t1, (B, n, M, 3), or None (:func:`.frames.tangent_frame` of the normals, which
            flips where a normal crosses z = 0: pass transported tangents for smooth bases)

    Returns:
        :class:`WindowQP`
    """
    fn = "assemble_window_qp"
    B, n, M = _validate(fn, points, normals, com, mu, wrench, mask, hand, f_max)
    if not isinstance(f_prev, torch.Tensor) or tuple(f_prev.shape) != (B, M, 3):
        raise _err(fn, "f_prev", f"({B}, {M}, 3)", f_prev)
    dt, dev = points.dtype, points.device
    hand = torch.ones(B, M, dtype=torch.bool, device=dev) if hand is None else hand
    basis = contact_basis(normals, mu, mask=mask, sliding=sliding, tangent=tangent)   # (B, n, M, 3, 4)
    k = 4 * M
    nz = n * k
    # Eq. 3: D z - d stacks f^t - f^{t-1} per (t, i); D is block bidiagonal with blocks B_i^t.
    eyeM = torch.eye(M, dtype=dt, device=dev)
    blk = (eyeM.view(1, 1, M, 1, M, 1) * basis.unsqueeze(4)).reshape(B, n, 3 * M, k)  # blkdiag_i B_i^t
    Dm = points.new_zeros(B, n, 3 * M, n, k)
    t_idx = torch.arange(n, device=dev)
    Dm[:, t_idx, :, t_idx] = blk.transpose(0, 1)
    if n > 1:
        Dm[:, t_idx[1:], :, t_idx[:-1]] = -blk[:, :-1].transpose(0, 1)
    Dm = Dm.reshape(B, 3 * M * n, nz)
    d = points.new_zeros(B, n, 3 * M)
    d[:, 0] = f_prev.reshape(B, 3 * M)
    d = d.reshape(B, 3 * M * n)
    Q = 2 * Dm.transpose(1, 2) @ Dm
    p = -2 * (Dm.transpose(1, 2) @ d.unsqueeze(-1)).squeeze(-1)
    free = (basis.abs().sum(-2) == 0).reshape(B, nz).to(dt)                          # zero columns
    Q = Q + torch.diag_embed(free)
    offset = (f_prev * f_prev).sum((1, 2))
    # Eq. 1 per frame, block diagonal over frames.
    W = _wrench_map(points, com, basis)                                              # (B, n, 6, k)
    A = points.new_zeros(B, n, 6, n, k)
    A[:, t_idx, :, t_idx] = W.transpose(0, 1)
    A = A.reshape(B, 6 * n, nz)
    b = wrench.reshape(B, 6 * n)
    # Limits: -lambda <= 0 and n^T B lambda <= f_max (hand contacts).
    N, fm = _limits(basis, normals, hand, f_max)                                     # (B, n, M, k), (B, n, M)
    Nf = points.new_zeros(B, n, M, n, k)
    Nf[:, t_idx, :, t_idx] = N.transpose(0, 1)
    G = torch.cat([-torch.eye(nz, dtype=dt, device=dev).expand(B, nz, nz), Nf.reshape(B, n * M, nz)], 1)
    h = torch.cat([points.new_zeros(B, nz), fm.reshape(B, n * M).to(dt)], 1)
    return WindowQP(Q=Q, p=p, G=G, h=h, A=A, b=b, offset=offset, basis=basis)


def assemble_frame_lps(points: torch.Tensor, normals: torch.Tensor, com: torch.Tensor, mu: torch.Tensor,
                       wrench: torch.Tensor, *, mask: torch.Tensor | None = None, hand: torch.Tensor | None = None,
                       f_max: float | torch.Tensor = 30.0, sliding: torch.Tensor | None = None,
                       tangent: torch.Tensor | None = None) -> FrameLPs:
    """Eq. 4 without the objective, split per frame: the feasibility LPs of the additional-contacts test (Sec. 4.3).

    Arguments as :func:`assemble_window_qp` (no f_prev). The constraints of Eq. 4 separate per frame, so the window
    is feasible iff every frame's LP is.

    Returns:
        :class:`FrameLPs` with leading (B, n)
    """
    fn = "assemble_frame_lps"
    B, n, M = _validate(fn, points, normals, com, mu, wrench, mask, hand, f_max)
    dev, dt = points.device, points.dtype
    hand = torch.ones(B, M, dtype=torch.bool, device=dev) if hand is None else hand
    basis = contact_basis(normals, mu, mask=mask, sliding=sliding, tangent=tangent)
    k = 4 * M
    W = _wrench_map(points, com, basis)
    N, fm = _limits(basis, normals, hand, f_max)
    G = torch.cat([-torch.eye(k, dtype=dt, device=dev).expand(B, n, k, k), N], 2)
    h = torch.cat([points.new_zeros(B, n, k), fm.to(dt)], 2)
    return FrameLPs(G=G, h=h, A=W, b=wrench)
