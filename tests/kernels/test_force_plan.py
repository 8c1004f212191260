"""Liu 2009 window QPs and per-frame LPs (kernels/force_plan.py).

References: the physics of the assembled problems (forces from a solution reproduce the wrench, the objective
equals Eq. 3 evaluated on the forces), Clarabel on the window QPs and SciPy HiGHS on the frame LPs. The input
builder :func:`window_problems` (box grasps along smooth trajectories) is shared with
``tests/kernels/test_convex_qp.py`` and ``scripts/bench_qp.py``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from torchhand.kernels.force_plan import assemble_frame_lps, assemble_window_qp, contact_basis

GRAVITY = (0.0, 0.0, -9.81)
FPS = 30.0


def _rot(axis: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """Rotation matrices about unit axes (..., 3) by angles (...), Rodrigues."""
    x, y, z = axis.unbind(-1)
    o = torch.zeros_like(x)
    K = torch.stack([torch.stack([o, -z, y], -1), torch.stack([z, o, -x], -1), torch.stack([-y, x, o], -1)], -2)
    s, c = angle.sin()[..., None, None], angle.cos()[..., None, None]
    return torch.eye(3, dtype=axis.dtype) + s * K + (1 - c) * K @ K


def window_problems(B: int, gen: torch.Generator, *, kind: str = "grasp", table: bool = False, n: int = 6,
                    hand_slots: int = 3, table_slots: int = 4, dtype=torch.float64) -> dict:
    """B box grasps moved along smooth trajectories over a window of n frames (30 fps), as the keyword arguments
    of :func:`assemble_window_qp`.

    Box half extents 4-6 cm, mass 0.5-1.5 kg (uniform density), COM at the box centre, moved by a smooth
    translation (amplitude up to 5 cm) and a rotation about a random axis (up to 0.3 rad) at 0.5-1.5 Hz.
    Kinds (hand contacts in the object frame, normals into the box):

    * ``grasp``: a thumb on the -x face and ``hand_slots - 1`` fingers on the +x face, spread in y and z;
    * ``pinch``: two contacts at the centres of the +-x faces, translation only: A loses rank (no torque about
      x), b stays in its range: feasible;
    * ``pinch_twist``: the same pinch, rotating about x: the torque about x is out of range: infeasible;
    * ``single``: one contact on the -x face: infeasible;
    * ``weak``: the grasp with f_max = 0.2 N, far below the weight: infeasible.

    ``table`` adds ``table_slots`` table contacts (4: the bottom corners; 8: also the bottom edges' midpoints;
    normal +z, mu 0.4, no force limit).
    """
    f64 = torch.float64
    rnd = lambda *s: torch.rand(*s, generator=gen, dtype=f64)  # noqa: E731
    half = 0.04 + 0.02 * rnd(B, 3)
    mass = 0.5 + rnd(B)
    inertia = mass[:, None] / 3 * (half[:, [1, 0, 0]] ** 2 + half[:, [2, 2, 1]] ** 2)       # diag, kg m^2
    t = torch.arange(n, dtype=f64) / FPS                                                     # (n,)
    freq = 2 * math.pi * (0.5 + rnd(B, 1))
    amp = 0.05 * (2 * rnd(B, 3) - 1)
    phase = 2 * math.pi * rnd(B, 1)
    arg = freq * t + phase                                                                   # (B, n)
    pos = amp[:, None] * arg.sin()[..., None]
    acc = -amp[:, None] * (freq ** 2 * arg.sin())[..., None]
    if kind == "pinch":
        axis, th0 = torch.tensor([1.0, 0.0, 0.0], dtype=f64).expand(B, 3), torch.zeros(B, 1, dtype=f64)
    elif kind == "pinch_twist":
        axis, th0 = torch.tensor([1.0, 0.0, 0.0], dtype=f64).expand(B, 3), 0.1 + 0.2 * rnd(B, 1)
    else:
        axis = torch.randn(B, 3, generator=gen, dtype=f64)
        axis, th0 = axis / axis.norm(dim=1, keepdim=True), 0.3 * rnd(B, 1)
    theta, dtheta, ddtheta = th0 * arg.sin(), th0 * freq * arg.cos(), -th0 * freq ** 2 * arg.sin()
    R = _rot(axis[:, None].expand(B, n, 3), theta)                                           # (B, n, 3, 3)
    omega, alpha = axis[:, None] * dtheta[..., None], axis[:, None] * ddtheta[..., None]
    Iw = R @ torch.diag_embed(inertia)[:, None] @ R.transpose(-1, -2)
    Iw_om = (Iw @ omega[..., None]).squeeze(-1)
    torque = (Iw @ alpha[..., None]).squeeze(-1) + torch.cross(omega, Iw_om, dim=-1)
    g = torch.tensor(GRAVITY, dtype=f64)
    wrench = torch.cat([mass[:, None, None] * (acc - g), torque], -1)                        # (B, n, 6)
    # Hand contacts in the object frame.
    if kind in ("pinch", "pinch_twist"):
        pts = torch.stack([torch.stack([-half[:, 0], 0 * half[:, 0], 0 * half[:, 0]], -1),
                           torch.stack([half[:, 0], 0 * half[:, 0], 0 * half[:, 0]], -1)], 1)
        nrm = torch.tensor([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]], dtype=f64).expand(B, 2, 3)
    elif kind == "single":
        pts = torch.stack([-half[:, 0], 0.3 * half[:, 1], 0 * half[:, 0]], -1)[:, None]
        nrm = torch.tensor([[1.0, 0.0, 0.0]], dtype=f64).expand(B, 1, 3)
    else:
        k = hand_slots
        u = 2 * rnd(B, k, 2) - 1
        side = torch.tensor([-1.0] + [1.0] * (k - 1), dtype=f64)
        pts = torch.stack([side * half[:, None, 0], 0.7 * u[..., 0] * half[:, None, 1],
                           0.7 * u[..., 1] * half[:, None, 2]], -1)
        nrm = torch.stack([-side, 0 * side, 0 * side], -1).expand(B, k, 3)
    M_h = pts.shape[1]
    mu = 0.6 + 0.4 * rnd(B, M_h)
    hand = torch.ones(B, M_h, dtype=torch.bool)
    if table:
        corners = torch.tensor([[1, 1], [1, -1], [-1, 1], [-1, -1], [1, 0], [-1, 0], [0, 1], [0, -1]],
                               dtype=f64)[:table_slots]
        k = corners.shape[0]
        tp = torch.stack([corners[:, 0] * half[:, None, 0], corners[:, 1] * half[:, None, 1],
                          -half[:, None, 2].expand(B, k)], -1)
        pts = torch.cat([pts, tp], 1)
        nrm = torch.cat([nrm, torch.tensor([0.0, 0.0, 1.0], dtype=f64).expand(B, k, 3)], 1)
        mu = torch.cat([mu, torch.full((B, k), 0.4, dtype=f64)], 1)
        hand = torch.cat([hand, torch.zeros(B, k, dtype=torch.bool)], 1)
    M = pts.shape[1]
    points = (R[:, :, None] @ pts[:, None, :, :, None]).squeeze(-1) + pos[:, :, None]   # (B, n, M, 3)
    normals = (R[:, :, None] @ nrm[:, None, :, :, None]).squeeze(-1)
    # Previous frame's forces: the weight shared by the hand contacts (a plausible, not optimal, start).
    f_prev = torch.zeros(B, M, 3, dtype=f64)
    f_prev[:, :M_h] = wrench[:, :1, :3] / M_h
    out = dict(points=points, normals=normals, com=pos, mu=mu, wrench=wrench, f_prev=f_prev, hand=hand,
               mask=torch.ones(B, n, M, dtype=torch.bool), f_max=0.2 if kind == "weak" else 30.0)
    return {k: (v.to(dtype) if isinstance(v, torch.Tensor) and v.is_floating_point() else v) for k, v in out.items()}


def lp_args(prob: dict) -> dict:
    return {k: v for k, v in prob.items() if k != "f_prev"}


def clarabel_window(qp, i: int):
    """Clarabel on problem i of a WindowQP (float64). Returns (x, objective without offset, status)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "torchhand"))
    from test_qp import clarabel_qp

    return clarabel_qp(*(getattr(qp, k)[i].double().numpy() for k in ("Q", "p", "G", "h", "A", "b")))


# ------------------------------------------------------------------------------------------------------- tests
@pytest.mark.parametrize("B", [1, 7])
def test_shapes(B, dtype, gen):
    prob = window_problems(B, gen, table=True, dtype=dtype)
    qp = assemble_window_qp(**prob)
    n, M = 6, 7
    nz = 4 * M * n
    assert qp.Q.shape == (B, nz, nz) and qp.p.shape == (B, nz) and qp.offset.shape == (B,)
    assert qp.G.shape == (B, nz + M * n, nz) and qp.h.shape == (B, nz + M * n)
    assert qp.A.shape == (B, 6 * n, nz) and qp.b.shape == (B, 6 * n)
    assert qp.basis.shape == (B, n, M, 3, 4)
    assert all(t.dtype == dtype for t in qp)
    lps = assemble_frame_lps(**lp_args(prob))
    assert lps.G.shape == (B, n, 5 * M, 4 * M) and lps.h.shape == (B, n, 5 * M)
    assert lps.A.shape == (B, n, 6, 4 * M) and lps.b.shape == (B, n, 6)


def test_sizes_of_the_design_note(gen):
    qp = assemble_window_qp(**window_problems(1, gen))
    assert qp.Q.shape[-1] == 72 and qp.A.shape[1] == 36 and qp.G.shape[1] == 90
    qp = assemble_window_qp(**window_problems(1, gen, table=True))
    assert qp.Q.shape[-1] == 168 and qp.A.shape[1] == 36
    qp = assemble_window_qp(**window_problems(1, gen, hand_slots=5, table=True, table_slots=8))
    assert qp.Q.shape[-1] == 312


def test_objective_and_constraints_mean_what_they_say(gen):
    """For random lambda: 1/2 z'Qz + p'z + offset = Eq. 3 on the forces, Az = the forces' wrench per frame,
    the N rows are the hand contacts' normal forces."""
    prob = window_problems(3, gen, table=True)
    qp = assemble_window_qp(**prob)
    B, n, M = prob["mask"].shape
    lam = torch.rand(B, n, M, 4, generator=gen, dtype=torch.float64)
    z = lam.reshape(B, -1)
    f = (qp.basis @ lam.unsqueeze(-1)).squeeze(-1)                                          # (B, n, M, 3)
    prev = torch.cat([prob["f_prev"][:, None], f[:, :-1]], 1)
    eq3 = ((f - prev) ** 2).sum((1, 2, 3))
    obj = 0.5 * (z * (qp.Q @ z[..., None]).squeeze(-1)).sum(1) + (qp.p * z).sum(1) + qp.offset
    torch.testing.assert_close(obj, eq3, rtol=1e-12, atol=1e-12)
    r = prob["points"] - prob["com"][:, :, None]
    w = torch.cat([f.sum(2), torch.cross(r, f, dim=-1).sum(2)], -1)                           # (B, n, 6)
    torch.testing.assert_close((qp.A @ z[..., None]).squeeze(-1), w.reshape(B, -1), rtol=1e-12, atol=1e-12)
    fn = (f * prob["normals"]).sum(-1) * prob["hand"][:, None].double()
    Gz = (qp.G @ z[..., None]).squeeze(-1)
    torch.testing.assert_close(Gz[:, : z.shape[1]], -z)
    torch.testing.assert_close(Gz[:, z.shape[1]:], fn.reshape(B, -1), rtol=1e-12, atol=1e-12)
    assert bool((qp.h[:, z.shape[1]:].reshape(B, n, M)[:, :, :3] == 30.0).all())


def test_basis_edges_sliding_ray_and_mask(gen):
    B, n, M = 2, 3, 2
    normals = torch.randn(B, n, M, 3, generator=gen, dtype=torch.float64)
    normals = normals / normals.norm(dim=-1, keepdim=True)
    mu = torch.full((B, M), 0.5, dtype=torch.float64)
    basis = contact_basis(normals, mu)
    # Each edge has unit normal part and tangential part mu; (1, 1, -1, -1) is in the null space.
    nb = (normals.unsqueeze(-2) @ basis).squeeze(-2)
    torch.testing.assert_close(nb, torch.ones_like(nb))
    tang = basis - normals.unsqueeze(-1) * nb.unsqueeze(-2)
    torch.testing.assert_close(tang.norm(dim=-2), torch.full_like(nb, 0.5))
    null = (basis @ torch.tensor([1.0, 1.0, -1.0, -1.0], dtype=torch.float64)).abs().amax()
    assert float(null) < 1e-14
    sliding = torch.zeros(B, n, M, 3, dtype=torch.float64)
    sliding[0, 1, 0] = torch.cross(normals[0, 1, 0], torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), dim=0)
    mask = torch.ones(B, n, M, dtype=torch.bool)
    mask[1, 2, 1] = False
    basis = contact_basis(normals, mu, sliding=sliding, mask=mask)
    v = sliding[0, 1, 0] / sliding[0, 1, 0].norm()
    torch.testing.assert_close(basis[0, 1, 0, :, 0], normals[0, 1, 0] + 0.5 * v)
    assert bool((basis[0, 1, 0, :, 1:] == 0).all()) and bool((basis[1, 2, 1] == 0).all())
    # A given tangent is used (projected on the tangent plane).
    t = torch.randn(B, n, M, 3, generator=gen, dtype=torch.float64)
    basis = contact_basis(normals, mu, tangent=t)
    t1 = t - (t * normals).sum(-1, keepdim=True) * normals
    torch.testing.assert_close(basis[..., 0] - basis[..., 1], t1 / t1.norm(dim=-1, keepdim=True))


def test_bad_input_raises(gen):
    prob = window_problems(2, gen)
    with pytest.raises(ValueError, match="points must have shape"):
        assemble_window_qp(**{**prob, "points": prob["points"][0]})
    with pytest.raises(ValueError, match=r"mu must have shape \(2, 3\)"):
        assemble_window_qp(**{**prob, "mu": prob["mu"][:, :2]})
    with pytest.raises(ValueError, match="f_prev must have shape"):
        assemble_window_qp(**{**prob, "f_prev": prob["f_prev"][:, :, :2]})
    with pytest.raises(ValueError, match="mask must have shape"):
        assemble_window_qp(**{**prob, "mask": prob["mask"].double()})
    with pytest.raises(ValueError, match="f_max"):
        assemble_window_qp(**{**prob, "f_max": -1.0})
    with pytest.raises(ValueError, match="wrench must have dtype"):
        assemble_frame_lps(**{**lp_args(prob), "wrench": prob["wrench"].float()})


def test_pinch_is_rank_deficient_and_twist_leaves_the_range(gen):
    from torchhand.kernels.convex_qp import reduce_equalities

    for kind, in_range in (("pinch", True), ("pinch_twist", False)):
        qp = assemble_window_qp(**window_problems(3, gen, kind=kind))
        assert int(torch.linalg.matrix_rank(qp.A[0])) == 30                   # 6 frames x 5
        red = reduce_equalities(qp.A, qp.b)
        assert red.rank.tolist() == [30] * 3 and red.in_range.tolist() == [in_range] * 3


def test_frame_lps_against_highs(gen):
    """Per-frame feasibility verdicts of the kernel (torchhand.solvers._qpth.lp_feasible(method="admm")) agree with SciPy
    HiGHS on every instance, feasible and infeasible kinds mixed."""
    from scipy.optimize import linprog

    from torchhand.solvers._qpth import lp_feasible

    ref, ours = [], []
    for kind, table in (("grasp", False), ("grasp", True), ("pinch", False), ("pinch_twist", False),
                        ("single", False), ("weak", False), ("weak", True)):
        lps = assemble_frame_lps(**lp_args(window_problems(2, gen, kind=kind, table=table)))
        G, h, A, b = (t.flatten(0, 1) for t in lps)
        for i in range(G.shape[0]):
            r = linprog(np.zeros(G.shape[-1]), A_ub=G[i].numpy(), b_ub=h[i].numpy(), A_eq=A[i].numpy(),
                        b_eq=b[i].numpy(), bounds=(None, None), method="highs")
            assert r.status in (0, 2), r.message
            ref.append(r.status == 0)
        res = lp_feasible(G, h, A, b, method="admm")
        ours += res.feasible.tolist()
        assert bool((res.status != 2).all())                                 # every verdict decided
    assert 10 <= sum(ref) <= len(ref) - 10                                   # both verdicts present
    assert ours == ref
