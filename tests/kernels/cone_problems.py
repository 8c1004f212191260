"""Input builders for the friction-cone solver, shared by its tests and ``scripts/bench_cone.py``.

Random grasps of a sphere or a box with 1..K contacts (padding masked out and filled with finite junk), a
gravity + inertia wrench, and a share of problems built to be infeasible (every contact on the top cap of the
object, its friction cone pointing down, while the wrench must hold the object up). Many random grasps with two
or three contacts are infeasible as well (no torque about the line through two contacts), so the mix has both
classes without labels: the reference (Clarabel, :func:`clarabel_solve`) decides. Conventions: metres, newtons,
normals point into the object, wrench = (force, torque about the centre of mass) required from the contacts.
"""

from __future__ import annotations

import math

import numpy as np
import torch

G = 9.81


def _unit(v: torch.Tensor) -> torch.Tensor:
    return v / v.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def random_cone_problems(B: int, K: int, gen: torch.Generator, *, dtype=torch.float64, device="cpu",
                         kmin: int = 2, infeasible_fraction: float = 0.25, sliding_fraction: float = 0.0,
                         random_weights: bool = False) -> dict:
    """A batch of friction-cone problems (keyword arguments of ``solve_friction_cone``).

    Returns ``dict(points (B, K, 3) m, normals (B, K, 3), mu (B, K), wrench (B, 6) N / N m, mask (B, K) bool,
    weights (B, K) or None, sliding_dir (B, K, 3) or None)``. Active contacts come first; padded slots hold
    finite junk. Everything is drawn from ``gen`` (float64 on the CPU) and then moved to ``dtype``/``device``.
    """
    f64 = torch.float64
    kmin = min(kmin, K)
    count = torch.randint(kmin, K + 1, (B,), generator=gen)
    mask = torch.arange(K)[None, :] < count[:, None]
    box = torch.rand(B, generator=gen) < 0.5
    size = 0.02 + 0.04 * torch.rand(B, 3, generator=gen, dtype=f64)          # box half-extents / sphere radius
    radius = size[:, :1]
    # Sphere: uniform directions. Box: a random face, a uniform point on it.
    d = _unit(torch.randn(B, K, 3, generator=gen, dtype=f64))
    sphere_p = d * radius[:, None, :]
    sphere_n = -d
    face = torch.randint(0, 6, (B, K), generator=gen)
    axis, sign = face % 3, (face // 3) * 2 - 1
    u = (torch.rand(B, K, 3, generator=gen, dtype=f64) * 2 - 1) * size[:, None, :]
    onehot = torch.nn.functional.one_hot(axis, 3).to(f64)
    box_p = u * (1 - onehot) + onehot * sign[..., None] * size[:, None, :]
    box_n = -onehot * sign[..., None]
    points = torch.where(box[:, None, None], box_p, sphere_p)
    normals = torch.where(box[:, None, None], box_n, sphere_n)
    mu = 0.3 + 0.7 * torch.rand(B, K, generator=gen, dtype=f64)

    # Infeasible by construction: contacts on the top cap whose cones lie entirely below the horizontal.
    bad = torch.rand(B, generator=gen) < infeasible_fraction
    theta_max = (math.pi / 2 - torch.atan(mu)) * 0.9
    theta = theta_max * torch.rand(B, K, generator=gen, dtype=f64).sqrt()
    phi = 2 * math.pi * torch.rand(B, K, generator=gen, dtype=f64)
    cap = torch.stack([theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos()], -1)
    points = torch.where(bad[:, None, None], cap * radius[:, None, :], points)
    normals = torch.where(bad[:, None, None], -cap, normals)

    # Gravity + inertia: F = m (a - g), tau = I alpha + omega x I omega, with a solid sphere's/box's inertia.
    mass = 0.05 + 0.45 * torch.rand(B, 1, generator=gen, dtype=f64)
    acc = 2.0 * torch.randn(B, 3, generator=gen, dtype=f64)
    force = mass * (acc + torch.tensor([0.0, 0.0, G], dtype=f64))
    force = torch.where(bad[:, None], mass * torch.tensor([0.0, 0.0, G], dtype=f64) + 0.3 * force.abs()
                        * torch.tensor([0.1, 0.1, 1.0], dtype=f64), force)
    s2 = size ** 2
    inertia_box = mass / 3 * (s2.sum(-1, keepdim=True) - s2)
    inertia = torch.where(box[:, None], inertia_box, 0.4 * mass * radius ** 2 * torch.ones(1, 3, dtype=f64))
    alpha = 20.0 * torch.randn(B, 3, generator=gen, dtype=f64)
    omega = 3.0 * torch.randn(B, 3, generator=gen, dtype=f64)
    torque = inertia * alpha + torch.cross(omega, inertia * omega, dim=-1)
    wrench = torch.cat([force, torque], -1)

    weights = None
    if random_weights:
        weights = 0.5 + torch.rand(B, K, generator=gen, dtype=f64)
    sliding = None
    if sliding_fraction > 0:
        slide = (torch.rand(B, K, generator=gen) < sliding_fraction) & mask
        s = torch.randn(B, K, 3, generator=gen, dtype=f64)
        s = _unit(s - (s * normals).sum(-1, keepdim=True) * normals)
        sliding = torch.where(slide[..., None], s, torch.zeros_like(s))
    # Junk in the padding: finite, nonsensical, must be ignored.
    junk = torch.randn(B, K, 3, generator=gen, dtype=f64) * 7
    points = torch.where(mask[..., None], points, junk)
    normals = torch.where(mask[..., None], normals, _unit(junk))
    mu = torch.where(mask, mu, torch.full_like(mu, 3.0))
    out = dict(points=points, normals=normals, mu=mu, wrench=wrench, mask=mask, weights=weights, sliding_dir=sliding)
    return {k: (v.to(device=device, dtype=dtype) if v is not None and v.is_floating_point() else
                (v.to(device) if v is not None else None)) for k, v in out.items()}


def perturb_problems(problems: dict, gen: torch.Generator, scale: float = 0.02) -> dict:
    """A nearby problem: contact points moved by ~scale x 5 cm, wrench changed by ~scale relative (warm starts)."""
    out = dict(problems)
    p = problems["points"]
    out["points"] = p + scale * 0.05 * torch.randn(p.shape, generator=gen, dtype=torch.float64).to(p)
    w = problems["wrench"]
    out["wrench"] = w * (1 + scale * torch.randn(w.shape, generator=gen, dtype=torch.float64).to(w))
    return out


def slice_problems(problems: dict, idx) -> dict:
    return {k: (v[idx] if v is not None else None) for k, v in problems.items()}


# ---------------------------------------------------------------------------------------------------------------
# Reference: Clarabel (interior point, exact second-order cones), one problem at a time through its Python API.

def _tangent_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = np.cross(n, a)
    t1 /= np.linalg.norm(t1)
    return t1, np.cross(n, t1)


def clarabel_solve(points, normals, mu, wrench, mask=None, weights=None, sliding_dir=None) -> dict:
    """Solve one problem (numpy arrays of one batch element) with Clarabel; the matrices are built here.

    Variables: the world-frame force of every active contact. Constraints: the wrench balance (zero cone), a
    second-order cone (mu f.n, f.t1, f.t2) per static contact, and f = a (n - mu s), a >= 0 per sliding contact.
    Returns dict(status: 'feasible' | 'infeasible' | other Clarabel status, objective, forces (K, 3)).
    """
    import clarabel
    from scipy import sparse

    K = points.shape[0]
    act = np.ones(K, bool) if mask is None else np.asarray(mask, bool)
    idx = np.flatnonzero(act)
    k = len(idx)
    w = np.ones(K) if weights is None else np.asarray(weights, float)
    n = 3 * k
    q = np.concatenate([w[i] * normals[i] for i in idx]) if k else np.zeros(0)
    A_eq = np.zeros((6, n))
    rows, b_rows, cones = [A_eq], [np.asarray(wrench, float)], [clarabel.ZeroConeT(6)]
    for j, i in enumerate(idx):
        p, nn = points[i], normals[i] / np.linalg.norm(normals[i])
        A_eq[:3, 3 * j:3 * j + 3] = np.eye(3)
        A_eq[3:, 3 * j:3 * j + 3] = np.array([[0, -p[2], p[1]], [p[2], 0, -p[0]], [-p[1], p[0], 0]])
        s = None if sliding_dir is None else np.asarray(sliding_dir[i], float)
        if s is not None:
            s = s - s.dot(nn) * nn
        if s is not None and np.linalg.norm(s) > 1e-9:
            d = nn - mu[i] * s / np.linalg.norm(s)
            d /= np.linalg.norm(d)
            e1, e2 = _tangent_basis(d)
            block = np.zeros((3, n))
            block[0, 3 * j:3 * j + 3] = e1
            block[1, 3 * j:3 * j + 3] = e2
            block[2, 3 * j:3 * j + 3] = -d
            rows.append(block)
            b_rows.append(np.zeros(3))
            cones += [clarabel.ZeroConeT(2), clarabel.NonnegativeConeT(1)]
        else:
            t1, t2 = _tangent_basis(nn)
            block = np.zeros((3, n))
            block[0, 3 * j:3 * j + 3] = -mu[i] * nn
            block[1, 3 * j:3 * j + 3] = -t1
            block[2, 3 * j:3 * j + 3] = -t2
            rows.append(block)
            b_rows.append(np.zeros(3))
            cones.append(clarabel.SecondOrderConeT(3))
    if k == 0:
        feasible = bool(np.linalg.norm(wrench) == 0)
        return {"status": "feasible" if feasible else "infeasible", "objective": 0.0, "forces": np.zeros((K, 3))}
    A = sparse.csc_matrix(np.vstack(rows))
    b = np.concatenate(b_rows)
    P = sparse.csc_matrix((n, n))
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    sol = clarabel.DefaultSolver(P, q, A, b, cones, settings)
    res = sol.solve()
    st = str(res.status)
    forces = np.zeros((K, 3))
    if st in ("Solved", "AlmostSolved"):
        forces[idx] = np.asarray(res.x).reshape(k, 3)
        status = "feasible"
    elif st in ("PrimalInfeasible", "AlmostPrimalInfeasible"):
        status = "infeasible"
    else:
        status = st
    return {"status": status, "objective": float(res.obj_val) if status == "feasible" else math.nan,
            "forces": forces, "raw_status": st}


def clarabel_batch(problems: dict, idx=None) -> list[dict]:
    """:func:`clarabel_solve` over the batch elements ``idx`` (all by default), float64 numpy copies."""
    np_p = {k: (v.detach().cpu().double().numpy() if v is not None and v.is_floating_point() else
                (v.cpu().numpy() if v is not None else None)) for k, v in problems.items()}
    B = np_p["points"].shape[0]
    out = []
    for b in (range(B) if idx is None else idx):
        out.append(clarabel_solve(**{k: (v[b] if v is not None else None) for k, v in np_p.items()}))
    return out
