"""The Kry & Pai contact LCP (kernels/contact_lcp.py): assembly against the paper's block formulas, the contact
PGS against Lemke on the explicit LCP and against closed-form single-contact answers, and the three contact
regimes (breaking contact, sticking, sliding)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import torch

from torchhand.kernels.contact_lcp import (ContactLCPResult, build_kry_pai_lcp, friction_pyramid, kry_pai_s_prime,
                                           solve_contact_lcp)
from torchhand.kernels.lcp import lcp_tolerances
from torchhand.kernels.status import SolverStatus
from torchhand.solvers._lemke import lemke

CONVERGED, INVALID = int(SolverStatus.CONVERGED), int(SolverStatus.INVALID_INPUT)
RES_TOL = {torch.float32: 1e-4, torch.float64: 1e-9}     # explicit-LCP residual reached (N and m mixed)
F_ATOL = {torch.float32: 1e-3, torch.float64: 1e-7}      # force agreement, newtons


def _skew(p: torch.Tensor) -> torch.Tensor:
    x, y, z = p.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack([torch.stack([o, -z, y], -1), torch.stack([z, o, -x], -1), torch.stack([-y, x, o], -1)], -2)


def contact_problem(B: int, N: int, m: int, gen: torch.Generator, dtype=torch.float64, h: float = 0.01):
    """A hand-object contact step in the paper's quantities (drawn in float64, cast to ``dtype``).

    G = J C J^T + root compliance (Eq. 5, 8 joints), U_phi = -h^2 Gamma M^-1 Gamma^T for a 0.2 kg body (§7.1.2,
    body frame = world frame), separations s_i0 in [-1.2, 2.8] mm, a reference change pushing the contacts by
    about a millimetre, previous forces f^k and a body motion u_phi.
    Returns (D, G, U_phi, s', mu) with D (B, N, 3, 2m+1).
    """
    f64 = torch.float64
    rn = lambda *s: torch.randn(*s, generator=gen, dtype=f64)   # noqa: E731
    ru = lambda *s: torch.rand(*s, generator=gen, dtype=f64)    # noqa: E731
    d0 = rn(B, N, 3)
    D = friction_pyramid(d0, m)
    dof = 8
    J = 0.05 * rn(B, 3 * N, dof)                                # m / rad
    C = torch.diag_embed(0.5 + ru(B, dof))                      # rad / (N m)
    G = J @ C @ J.transpose(1, 2) + 2e-4 * torch.eye(3 * N, dtype=f64)
    r = 0.03 * rn(B, N, 3)
    Gamma = torch.cat([-_skew(r), torch.eye(3, dtype=f64).expand(B, N, 3, 3)], -1).reshape(B, 3 * N, 6)
    Minv = torch.diag(torch.tensor([1e4] * 3 + [5.0] * 3, dtype=f64))    # inertia 1e-4 kg m^2, mass 0.2 kg
    U = -h * h * Gamma @ Minv @ Gamma.transpose(1, 2)
    s = 0.002 * (2 * ru(B, N) - 0.6)
    sp = kry_pai_s_prime(D, s, G=G, f_k=0.5 * rn(B, 3 * N), J=J, dtheta_r=0.02 * rn(B, dof),
                         u_phi=0.001 * rn(B, 3 * N))
    mu = 0.2 + 0.8 * ru(B, N)
    return tuple(t.to(dtype) for t in (D, G, U, sp, mu))


def regimes(out: ContactLCPResult, eps: float):
    """Per contact: breaking (no force, positive separation), sticking (force strictly inside the pyramid, no
    slip), sliding (force on the pyramid boundary, positive slip lambda)."""
    b0, nu0 = out.beta[..., 0], out.nu[..., 0]
    breaking = (b0 <= eps) & (nu0 > eps)
    sticking = (b0 > eps) & (out.lam <= eps) & (out.sigma > eps)
    sliding = (b0 > eps) & (out.lam > eps) & (out.sigma.abs() <= eps)
    return breaking, sticking, sliding


# --- assembly ---------------------------------------------------------------------------------------------


def test_friction_pyramid_directions(dtype):
    gen = torch.Generator().manual_seed(0)
    n = torch.randn(7, 4, 3, generator=gen, dtype=torch.float64).to(dtype)
    n[0, 0] = torch.tensor([0.0, 0.0, -1.0])                   # the frame's singular direction
    D = friction_pyramid(n, 3)
    assert D.shape == (7, 4, 3, 7)
    tol = 10 * torch.finfo(dtype).eps
    torch.testing.assert_close(torch.linalg.vector_norm(D, dim=2), torch.ones(7, 4, 7, dtype=dtype), atol=tol, rtol=0)
    torch.testing.assert_close(D[..., 0], n / n.norm(dim=-1, keepdim=True), atol=tol, rtol=0)
    torch.testing.assert_close(D[..., 1::2], -D[..., 2::2], atol=0, rtol=0)          # d_i(2j-1) = -d_i(2j)
    assert (D[..., 0:1] * D[..., 1:]).sum(2).abs().max() <= tol                        # tangents
    with pytest.raises(ValueError, match="m must be >= 1"):
        friction_pyramid(n, 0)
    with pytest.raises(ValueError, match=r"d0 must have shape \(B, N, 3\)"):
        friction_pyramid(n[0], 2)


def test_build_matches_paper_blocks():
    """M and q against a direct NumPy transcription of §7.1.3 with block-diagonal D, E, F."""
    gen = torch.Generator().manual_seed(1)
    B, N, m = 2, 3, 2
    D, G, U, sp, mu = contact_problem(B, N, m, gen)
    lcp = build_kry_pai_lcp(D, G, U, sp, mu)
    K = 2 * m + 1
    for b in range(B):
        Dn = scipy.linalg.block_diag(*[D[b, i].numpy() for i in range(N)])            # (3N, N K)
        En = scipy.linalg.block_diag(*[np.r_[0.0, -np.ones(K - 1)][None] for _ in range(N)])
        Fn = scipy.linalg.block_diag(*[np.r_[mu[b, i].item(), -np.ones(K - 1)][None] for i in range(N)])
        top = np.hstack([Dn.T @ (G[b] - U[b]).numpy() @ Dn, -En.T])
        bottom = np.hstack([Fn, np.zeros((N, N))])
        np.testing.assert_allclose(lcp.M[b].numpy(), np.vstack([top, bottom]), atol=1e-15)
        np.testing.assert_allclose(lcp.q[b].numpy(), np.r_[sp[b].reshape(-1).numpy(), np.zeros(N)], atol=0)


def test_s_prime_formula():
    gen = torch.Generator().manual_seed(2)
    B, N, m, dof = 3, 2, 2, 5
    D = friction_pyramid(torch.randn(B, N, 3, generator=gen, dtype=torch.float64), m)
    s = torch.randn(B, N, generator=gen, dtype=torch.float64)
    G = torch.randn(B, 3 * N, 3 * N, generator=gen, dtype=torch.float64)
    fk, uphi = (torch.randn(B, 3 * N, generator=gen, dtype=torch.float64) for _ in range(2))
    J = torch.randn(B, 3 * N, dof, generator=gen, dtype=torch.float64)
    dth = torch.randn(B, dof, generator=gen, dtype=torch.float64)
    got = kry_pai_s_prime(D, s, G=G, f_k=fk, J=J, dtheta_r=dth, u_phi=uphi)
    for b in range(B):
        Dn = scipy.linalg.block_diag(*[D[b, i].numpy() for i in range(N)])
        s_full = np.zeros(N * (2 * m + 1))
        s_full[:: 2 * m + 1] = s[b].numpy()
        ref = s_full + Dn.T @ (J[b] @ dth[b] - G[b] @ fk[b] - uphi[b]).numpy()
        np.testing.assert_allclose(got[b].reshape(-1).numpy(), ref, atol=1e-12)
    torch.testing.assert_close(kry_pai_s_prime(D, s)[..., 0], s)
    with pytest.raises(ValueError, match="G and f_k"):
        kry_pai_s_prime(D, s, G=G)


# --- single contact, closed form ------------------------------------------------------------------------------


@pytest.mark.parametrize("B", [1, 7])
def test_single_contact_closed_form(B, dtype, device):
    """Isotropic compliance c, a fixed object (U_phi = 0), normal +z, 4 pyramid directions +-x, +-y. Pushing
    s'_0 < 0 gives beta_0 = -s'_0 / c; a tangential drag u along x sticks (f_t = -u / c) while u / c <= mu beta_0
    and otherwise slides (f_t = -mu beta_0, slip lambda = u - c mu beta_0); s'_0 > 0 breaks contact."""
    c, mu = 1e-3, 0.5
    cases = [(0.002, 0.0), (-0.002, 0.0005), (-0.002, 0.003), (-0.001, -0.0002), (-0.001, -0.004),
             (0.0005, 0.01), (-0.003, 0.0)]
    cases = (cases * 2)[:B]
    s0 = torch.tensor([cs[0] for cs in cases], dtype=dtype)
    u = torch.tensor([cs[1] for cs in cases], dtype=dtype)
    D = friction_pyramid(torch.tensor([0.0, 0.0, 1.0], dtype=dtype).expand(B, 1, 3), 2).to(device)
    G = (c * torch.eye(3, dtype=dtype)).expand(B, 3, 3).to(device)
    J = torch.eye(3, dtype=dtype).expand(B, 3, 3).to(device)
    dth = torch.stack([u, torch.zeros_like(u), torch.zeros_like(u)], -1).to(device)
    sp = kry_pai_s_prime(D, s0[:, None].to(device), J=J, dtheta_r=dth)
    lcp = build_kry_pai_lcp(D, G, torch.zeros_like(G), sp, torch.full((B, 1), mu, dtype=dtype, device=device))
    out = solve_contact_lcp(lcp)
    assert (out.status == CONVERGED).all() and (out.residual <= RES_TOL[dtype]).all()
    beta0 = (-s0 / c).clamp_min(0)
    ft = torch.where(u.abs() / c <= mu * beta0, -u / c, -torch.sign(u) * mu * beta0)
    lam = torch.where(u.abs() / c <= mu * beta0, torch.zeros_like(u), u.abs() - c * mu * beta0)
    f_ref = torch.stack([ft, torch.zeros_like(ft), beta0], -1)
    torch.testing.assert_close(out.forces[:, 0].cpu(), f_ref, atol=F_ATOL[dtype], rtol=1e-5)
    torch.testing.assert_close(out.lam[:, 0].cpu(), lam, atol=1e-7, rtol=1e-4)
    breaking, sticking, sliding = (r[:, 0].cpu() for r in regimes(out, 1e-6 if dtype == torch.float32 else 1e-9))
    expect_break = s0 > 0
    expect_stick = ~expect_break & (u.abs() / c < mu * beta0)
    assert (breaking == expect_break).all() and (sticking == expect_stick).all()
    assert (sliding == (~expect_break & ~expect_stick)).all()


# --- random multi-contact problems against Lemke ---------------------------------------------------------------


@pytest.mark.parametrize("B", [1, 7])
def test_random_contacts_against_lemke(B, dtype):
    gen = torch.Generator().manual_seed(10 + B)
    N, m = 4, 2
    D, G, U, sp, mu = contact_problem(B, N, m, gen, dtype)
    lcp = build_kry_pai_lcp(D, G, U, sp, mu)
    out = solve_contact_lcp(lcp, max_iters=3000)
    assert out.beta.shape == (B, N, 5) and out.lam.shape == out.sigma.shape == (B, N)
    assert out.forces.shape == (B, N, 3) and out.nu.shape == (B, N, 5)
    assert (out.status == CONVERGED).all(), out.residual
    assert (out.residual <= max(RES_TOL[dtype], lcp_tolerances(dtype).tol)).all()
    # explicit LCP: z = (beta, lambda) >= 0, w = M z + q >= 0, complementary
    z = torch.cat([out.beta.reshape(B, -1), out.lam], -1)
    w = (lcp.M @ z[..., None]).squeeze(-1) + lcp.q
    torch.testing.assert_close(w, torch.cat([out.nu.reshape(B, -1), out.sigma], -1), atol=1e-6, rtol=0)
    assert z.min() >= 0 and w.min() >= -RES_TOL[dtype]
    for b in range(B):
        ref = lemke(lcp.M[b].double().numpy(), lcp.q[b].double().numpy())
        assert ref.status == SolverStatus.CONVERGED and ref.residual <= 1e-9
        f_ref = torch.einsum("nrk,nk->nr", D[b].double(), torch.from_numpy(ref.x[: N * 5]).reshape(N, 5))
        torch.testing.assert_close(out.forces[b].double(), f_ref, atol=F_ATOL[dtype], rtol=1e-4)


def test_all_three_regimes_occur_in_a_batch():
    gen = torch.Generator().manual_seed(20)
    D, G, U, sp, mu = contact_problem(32, 4, 2, gen)
    out = solve_contact_lcp(build_kry_pai_lcp(D, G, U, sp, mu))
    assert (out.status == CONVERGED).all()
    breaking, sticking, sliding = regimes(out, 1e-9)
    assert breaking.sum() >= 10 and sticking.sum() >= 3 and sliding.sum() >= 10
    assert (breaking | sticking | sliding).float().mean() > 0.95        # (the rest: grazing contacts)
    # physics: no force without contact, friction opposes slip, slip needs a saturated pyramid
    assert (out.beta[breaking] == 0).all()
    assert (out.sigma[sliding].abs() <= 1e-9).all() and (out.lam[sticking] <= 1e-9).all()
    assert (out.nu[..., 0] >= -1e-9).all() and (out.sigma >= -1e-9).all()


def test_mask_padding_and_warm_start():
    gen = torch.Generator().manual_seed(30)
    B, N, m = 7, 3, 2
    D, G, U, sp, mu = contact_problem(B, N, m, gen)
    ref = solve_contact_lcp(build_kry_pai_lcp(D, G, U, sp, mu))
    # pad to 5 contact slots (slots 1 and 3 are padding, filled with NaN)
    idx = torch.tensor([0, 2, 4])
    Dp = torch.full((B, 5, 3, 5), float("nan"), dtype=torch.float64)
    Dp[:, idx] = D
    Gp = torch.full((B, 15, 15), float("nan"), dtype=torch.float64)
    Up = torch.full((B, 15, 15), float("nan"), dtype=torch.float64)
    rows = (3 * idx[:, None] + torch.arange(3)).reshape(-1)
    Gp[:, rows[:, None], rows[None, :]] = G
    Up[:, rows[:, None], rows[None, :]] = U
    spp = torch.full((B, 5, 5), float("nan"), dtype=torch.float64)
    spp[:, idx] = sp
    mup = torch.full((B, 5), float("nan"), dtype=torch.float64)
    mup[:, idx] = mu
    mask = torch.zeros(B, 5, dtype=torch.bool)
    mask[:, idx] = True
    lcp = build_kry_pai_lcp(Dp, torch.nan_to_num(Gp), torch.nan_to_num(Up), torch.nan_to_num(spp),
                            torch.nan_to_num(mup), mask=mask)
    out = solve_contact_lcp(lcp)
    assert (out.status == CONVERGED).all()
    torch.testing.assert_close(out.forces[:, idx], ref.forces, atol=1e-7, rtol=0)
    assert (out.beta[~mask] == 0).all() and (out.lam[~mask] == 0).all() and (out.forces[~mask] == 0).all()
    warm = solve_contact_lcp(build_kry_pai_lcp(D, G, U, sp, mu), beta0=ref.beta)
    assert (warm.status == CONVERGED).all() and (warm.iterations == 0).all()


def test_invalid_problems_and_limits():
    gen = torch.Generator().manual_seed(40)
    D, G, U, sp, mu = contact_problem(7, 3, 2, gen)
    mu[1, 0] = -0.1                                        # negative friction coefficient
    sp[2, 1, 0] = float("nan")
    G[3] = 0.0
    U[3] = 0.0                                             # zero normal compliance: nothing to divide by
    out = solve_contact_lcp(build_kry_pai_lcp(D, G, U, sp, mu))
    assert out.status.tolist()[1:4] == [INVALID] * 3
    assert torch.isinf(out.residual[1:4]).all() and (out.forces[1:4] == 0).all()
    assert (out.status[[0, 4, 5, 6]] == CONVERGED).all()
    D, G, U, sp, mu = contact_problem(7, 3, 2, torch.Generator().manual_seed(41))
    short = solve_contact_lcp(build_kry_pai_lcp(D, G, U, sp, mu), max_iters=1, check_every=1)
    stopped = short.status == int(SolverStatus.MAX_ITERATIONS)
    assert stopped.sum() >= 3 and ((short.status == CONVERGED) | stopped).all()
    assert (short.residual[stopped] > lcp_tolerances(torch.float64).tol).all()
    assert (short.iterations[stopped] == 1).all() and torch.isfinite(short.beta).all()


def test_bad_input():
    gen = torch.Generator().manual_seed(50)
    D, G, U, sp, mu = contact_problem(2, 3, 2, gen)
    with pytest.raises(ValueError, match=r"build_kry_pai_lcp: G must have shape \(2, 9, 9\), got \(2, 9, 8\)"):
        build_kry_pai_lcp(D, G[..., :8], U, sp, mu)
    with pytest.raises(ValueError, match=r"U_phi must have shape"):
        build_kry_pai_lcp(D, G, U[0], sp, mu)
    with pytest.raises(ValueError, match=r"s_prime must have shape \(2, 3, 5\)"):
        build_kry_pai_lcp(D, G, U, sp[..., :4], mu)
    with pytest.raises(ValueError, match=r"D must have shape"):
        build_kry_pai_lcp(D[..., :4], G, U, sp, mu)
    with pytest.raises(ValueError, match="mu must be torch.float64"):
        build_kry_pai_lcp(D, G, U, sp, mu.float())
    with pytest.raises(ValueError, match="mask must be a bool tensor"):
        build_kry_pai_lcp(D, G, U, sp, mu, mask=torch.ones(2, 3))
    lcp = build_kry_pai_lcp(D, G, U, sp, mu)
    with pytest.raises(ValueError, match=r"beta0 must have shape \(2, 3, 5\)"):
        solve_contact_lcp(lcp, beta0=torch.zeros(2, 3, 4, dtype=torch.float64))
    with pytest.raises(ValueError, match="lcp must be a KryPaiLCP"):
        solve_contact_lcp((lcp.M, lcp.q))
    with pytest.raises(ValueError, match="check_every"):
        solve_contact_lcp(lcp, check_every=0)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA not available")
def test_cuda_matches_cpu():
    gen = torch.Generator().manual_seed(60)
    D, G, U, sp, mu = contact_problem(7, 3, 2, gen)
    cpu = solve_contact_lcp(build_kry_pai_lcp(D, G, U, sp, mu))
    gpu = solve_contact_lcp(build_kry_pai_lcp(*(t.cuda() for t in (D, G, U, sp, mu))))
    assert gpu.forces.is_cuda
    torch.testing.assert_close(gpu.status.cpu(), cpu.status)
    torch.testing.assert_close(gpu.forces.cpu(), cpu.forces, atol=1e-7, rtol=0)
