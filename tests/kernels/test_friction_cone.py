"""Friction-cone force solver (kernels/friction_cone.py): smoke, shapes (B = 1, 7), masks, dtypes, bad input,
invariants in seeded loops, agreement with Clarabel (feasible and infeasible), sliding contacts, warm starts,
the Siconos friction-contact data, CUDA."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cone_problems import clarabel_batch, perturb_problems, random_cone_problems  # noqa: E402

from torchhand.kernels._cone_admm import AdmmSettings, admm, build_problem  # noqa: E402
from torchhand.kernels.friction_cone import ConeResult, cone_tolerances, solve_friction_cone  # noqa: E402
from torchhand.kernels.status import SolverStatus  # noqa: E402

CONVERGED, INFEASIBLE = int(SolverStatus.CONVERGED), int(SolverStatus.INFEASIBLE)
MAX_ITERATIONS, INVALID = int(SolverStatus.MAX_ITERATIONS), int(SolverStatus.INVALID_INPUT)
DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
# Physical-units checks: residual relative to ||wrench||, cone violation relative to the largest force.
RTOL = {torch.float32: 2e-3, torch.float64: 1e-5}
G = 9.81


def ring_grasp(dtype=torch.float64, device="cpu", k=4, mu=0.5, mass=0.2, radius=0.04):
    """k contacts on the equator of a sphere holding it against gravity: optimum sum f_n = m g / mu."""
    phi = torch.arange(k, dtype=torch.float64) * (2 * math.pi / k)
    p = torch.stack([phi.cos(), phi.sin(), torch.zeros_like(phi)], -1) * radius
    args = dict(points=p[None], normals=-p[None] / radius, mu=torch.full((1, k), mu, dtype=torch.float64),
                wrench=torch.tensor([[0, 0, mass * G, 0, 0, 0]], dtype=torch.float64))
    return {key: v.to(device=device, dtype=dtype) for key, v in args.items()}


def check_invariants(res: ConeResult, prob: dict, dtype):
    """Cone membership, wrench balance, objective and zero forces where required, in physical units."""
    f, n, mu = res.forces.double(), prob["normals"].double(), prob["mu"].double()
    n = n / n.norm(dim=-1, keepdim=True)
    mask = prob["mask"] if prob.get("mask") is not None else torch.ones(mu.shape, dtype=torch.bool)
    mask = mask.to(f.device)
    fn = (f * n).sum(-1)
    ft = (f - fn[..., None] * n).norm(dim=-1)
    scale = f.norm(dim=-1).amax(-1, keepdim=True).clamp_min(1e-12)
    sliding = prob.get("sliding_dir")
    static = torch.ones_like(mask) if sliding is None else sliding.norm(dim=-1).to(f.device) == 0
    ok_cone = (ft <= mu * fn + 1e-6 * scale) & (fn >= -1e-9 * scale)
    assert bool(ok_cone[mask & static].all()), "a returned force leaves its friction cone"
    assert bool((f[~mask] == 0).all()), "padding got a force"
    w = prob.get("weights")
    w = torch.ones_like(mu) if w is None else w.double()
    obj = (w * fn * mask).sum(-1)
    conv = res.status == CONVERGED
    assert bool(((res.objective.double() - obj).abs() <= 100 * torch.finfo(dtype).eps * (1 + obj.abs()))[conv].all())
    assert bool((res.objective[conv] >= -1e-9).all())
    F = prob["wrench"].double()
    p = prob["points"].double()
    fm = f * mask[..., None]
    resid = (fm.sum(1) - F[:, :3]).norm(dim=-1) + (torch.cross(p, fm, dim=-1).sum(1) - F[:, 3:]).norm(dim=-1)
    eps = torch.finfo(dtype).eps
    fsum = f.abs().sum((1, 2)) * (1 + p.norm(dim=-1).amax(-1))
    assert bool(((res.residual.double() - resid).abs() <= 1e-3 * resid + 100 * eps * fsum)[conv].all())
    # relative to the wrench, or to the forces when those are larger (ill-conditioned grasps)
    L = (p.norm(dim=-1) * mask).amax(-1).clamp_min(1e-3)
    size = F[:, :3].norm(dim=-1) + F[:, 3:].norm(dim=-1) / L + f.norm(dim=-1).sum(-1)
    assert bool((res.residual.double()[conv] <= RTOL[dtype] * size[conv] + 1e-9).all())
    inf = res.status == INFEASIBLE
    assert bool((res.forces[inf] == 0).all()) and bool((res.objective[inf] == 0).all())
    assert bool(torch.isfinite(res.forces).all() & torch.isfinite(res.objective).all())


# --- smoke, shapes, dtypes, masks ------------------------------------------------------------------------------

def test_smoke_ring_grasp_known_optimum():
    res = solve_friction_cone(**ring_grasp())
    assert int(res.status[0]) == CONVERGED
    assert res.objective.item() == pytest.approx(0.2 * G / 0.5, rel=1e-6)
    assert res.residual.item() < 1e-8
    # every contact is on its cone boundary, pulling up
    assert bool((res.forces[0, :, 2] > 0).all())


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["f32", "f64"])
@pytest.mark.parametrize("B", [1, 7])
def test_shapes_dtypes_devices(B, dtype, device):
    prob = random_cone_problems(B, 5, torch.Generator().manual_seed(B), dtype=dtype, device=device,
                                infeasible_fraction=0.3)
    res = solve_friction_cone(**prob)
    assert isinstance(res, ConeResult)
    assert res.forces.shape == (B, 5, 3) and res.forces.dtype == dtype and res.forces.device.type == device
    for field in (res.objective, res.residual):
        assert field.shape == (B,) and field.dtype == dtype and field.device.type == device
    assert res.status.shape == (B,) and res.status.dtype == torch.int8
    assert res.iterations.shape == (B,) and res.iterations.dtype == torch.int32
    assert set(res.status.tolist()) <= {CONVERGED, INFEASIBLE, MAX_ITERATIONS}
    check_invariants(res, prob, dtype)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["f32", "f64"])
def test_padding_is_ignored(dtype):
    """The same 3-contact problems solved alone and padded to K = 6 with junk (NaN, inf, huge values)."""
    prob = random_cone_problems(16, 3, torch.Generator().manual_seed(3), dtype=dtype, kmin=3)
    ref = solve_friction_cone(**prob)
    pad = lambda x, fill: torch.cat([x, torch.full((16, 3) + x.shape[2:], fill, dtype=x.dtype)], 1)  # noqa: E731
    padded = dict(points=pad(prob["points"], math.nan), normals=pad(prob["normals"], math.inf),
                  mu=pad(prob["mu"], -1.0), wrench=prob["wrench"],
                  mask=torch.cat([torch.ones(16, 3, dtype=torch.bool), torch.zeros(16, 3, dtype=torch.bool)], 1),
                  weights=pad(torch.ones_like(prob["mu"]), math.nan))
    res = solve_friction_cone(**padded)
    assert torch.equal(res.status, ref.status)
    assert bool((res.forces[:, 3:] == 0).all())
    tol = 1e-3 if dtype == torch.float32 else 1e-9
    torch.testing.assert_close(res.forces[:, :3], ref.forces, atol=tol * (1 + ref.forces.abs().max()), rtol=0)


def test_zero_wrench_and_no_contacts():
    prob = ring_grasp()
    prob["wrench"] = torch.zeros(1, 6, dtype=torch.float64)
    res = solve_friction_cone(**prob)
    assert int(res.status[0]) == CONVERGED and res.forces.abs().max() < 1e-12 and res.objective.item() == 0
    prob = ring_grasp()
    res = solve_friction_cone(**prob, mask=torch.zeros(1, 4, dtype=torch.bool))
    assert int(res.status[0]) == INFEASIBLE and int(res.iterations[0]) == 0


# --- bad input ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("arg,value,match", [
    ("points", torch.zeros(2, 4, 2, dtype=torch.float64), "points"),
    ("normals", torch.zeros(2, 3, 3, dtype=torch.float64), "normals"),
    ("mu", torch.zeros(2, 4, 1, dtype=torch.float64), "mu"),
    ("wrench", torch.zeros(2, 3, dtype=torch.float64), "wrench"),
    ("mask", torch.ones(2, 4), "mask"),
    ("weights", torch.ones(2, 5, dtype=torch.float64), "weights"),
    ("sliding_dir", torch.zeros(2, 4, dtype=torch.float64), "sliding_dir"),
    ("warm_start", torch.zeros(4, 3, dtype=torch.float64), "warm_start"),
    ("normals", torch.zeros(2, 4, 3, dtype=torch.float32), "normals"),
])
def test_bad_input_raises_value_error_naming_the_argument(arg, value, match):
    args = dict(points=torch.zeros(2, 4, 3, dtype=torch.float64), normals=torch.ones(2, 4, 3, dtype=torch.float64),
                mu=torch.ones(2, 4, dtype=torch.float64), wrench=torch.zeros(2, 6, dtype=torch.float64))
    args[arg] = value
    with pytest.raises(ValueError, match=match):
        solve_friction_cone(**args)


def test_bad_settings_and_dtype():
    args = [torch.zeros(2, 4, 3), torch.ones(2, 4, 3), torch.ones(2, 4), torch.zeros(2, 6)]
    with pytest.raises(ValueError, match="check_every"):
        solve_friction_cone(*args, check_every=0)
    with pytest.raises(ValueError, match="dtype"):
        solve_friction_cone(*(t.half() for t in args))


def test_nan_inputs_are_invalid_per_problem():
    prob = random_cone_problems(6, 4, torch.Generator().manual_seed(5), kmin=4, infeasible_fraction=0)
    ref = solve_friction_cone(**prob)
    bad = {k: (v.clone() if v is not None else None) for k, v in prob.items()}
    bad["points"][1, 2, 0] = math.nan
    bad["wrench"][3, 4] = math.inf
    bad["mu"][4, 0] = -0.5
    res = solve_friction_cone(**bad)
    assert res.status.tolist()[1] == INVALID and res.status.tolist()[3] == INVALID and res.status.tolist()[4] == INVALID
    keep = [0, 2, 5]
    assert torch.equal(res.status[keep], ref.status[keep])
    torch.testing.assert_close(res.forces[keep], ref.forces[keep])
    assert bool(torch.isfinite(res.forces).all() & torch.isfinite(res.objective).all())
    assert bool(torch.isinf(res.residual[[1, 3, 4]]).all()) and int(res.iterations[1]) == 0


# --- invariants and constructed classes --------------------------------------------------------------------------

@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["f32", "f64"])
def test_invariants_seeded_loop(dtype):
    for seed in range(3):
        prob = random_cone_problems(200, 5, torch.Generator().manual_seed(100 + seed), dtype=dtype,
                                    random_weights=seed == 1, sliding_fraction=0.3 if seed == 2 else 0.0)
        res = solve_friction_cone(**prob)
        check_invariants(res, prob, dtype)
        # float32 cannot reach its tolerance on the odd grasp that needs forces 100x the wrench
        assert (res.status == MAX_ITERATIONS).sum() <= (2 if dtype == torch.float64 else 4)


def test_constructed_infeasible_problems():
    # Every contact on the top cap, cones pointing down, the wrench must lift the object.
    prob = random_cone_problems(50, 5, torch.Generator().manual_seed(9), infeasible_fraction=1.0)
    res = solve_friction_cone(**prob)
    assert bool((res.status == INFEASIBLE).all())
    # Two contacts cannot resist torque about the line through them: infeasible before any iteration.
    p = torch.tensor([[[0.03, 0, 0], [-0.03, 0, 0]]], dtype=torch.float64)
    res = solve_friction_cone(p, -p / 0.03, torch.full((1, 2), 1.0, dtype=torch.float64),
                              torch.tensor([[0, 0, 1.0, 0.01, 0, 0]], dtype=torch.float64))
    assert int(res.status[0]) == INFEASIBLE and int(res.iterations[0]) == 0
    # ... but they can pinch-hold a weight: sum f_n = m g / mu.
    res = solve_friction_cone(p, -p / 0.03, torch.full((1, 2), 0.8, dtype=torch.float64),
                              torch.tensor([[0, 0, 2.0, 0, 0, 0]], dtype=torch.float64))
    assert int(res.status[0]) == CONVERGED and res.objective.item() == pytest.approx(2.0 / 0.8, rel=1e-6)


def test_sliding_contacts_lie_on_their_ray():
    prob = ring_grasp(k=4, mu=0.6)
    s = torch.zeros(1, 4, 3, dtype=torch.float64)
    s[0, 0] = torch.tensor([0, 0, -1.0])      # contact 0 slides down: its friction pushes the object up
    res = solve_friction_cone(**prob, sliding_dir=s)
    assert int(res.status[0]) == CONVERGED
    f, n = res.forces[0, 0], prob["normals"][0, 0]
    fn = f @ n
    torch.testing.assert_close(f, fn * (n - 0.6 * s[0, 0]), atol=1e-10, rtol=0)
    assert fn > 0
    static = solve_friction_cone(**prob)
    assert res.objective.item() == pytest.approx(static.objective.item(), rel=1e-6)   # the optimum uses that ray
    # Sliding up instead: friction would drag the object down there; the other pair carries the weight alone.
    up = solve_friction_cone(**prob, sliding_dir=-s)
    # (never below the static optimum, up to the solver's relative tolerance of 1e-6 on residual and gap)
    assert int(up.status[0]) == CONVERGED and up.objective.item() >= static.objective.item() * (1 - 1e-5)
    f, fn = up.forces[0, 0], up.forces[0, 0] @ n
    torch.testing.assert_close(f, fn * (n + 0.6 * s[0, 0]), atol=1e-10, rtol=0)
    # A three-contact ring cannot balance the torque of a contact dragging down: infeasible, as Clarabel says.
    prob3 = ring_grasp(k=3, mu=0.6)
    up3 = solve_friction_cone(**prob3, sliding_dir=-s[:, :3])
    assert int(up3.status[0]) == INFEASIBLE


# --- reference: Clarabel --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("dtype,sliding", [(torch.float64, 0.0), (torch.float64, 0.4), (torch.float32, 0.0)],
                         ids=["f64", "f64-sliding", "f32"])
def test_agreement_with_clarabel(dtype, sliding):
    pytest.importorskip("clarabel")
    prob = random_cone_problems(300, 5, torch.Generator().manual_seed(42), sliding_fraction=sliding,
                                random_weights=sliding > 0)
    res = solve_friction_cone(**{k: (v.to(dtype) if v is not None and v.is_floating_point() else v)
                                 for k, v in prob.items()})
    ref = clarabel_batch(prob)
    decided = [i for i, r in enumerate(ref) if r["status"] in ("feasible", "infeasible")]
    assert len(decided) >= 290
    ours = ["feasible" if s == CONVERGED else "infeasible" if s == INFEASIBLE else "undecided"
            for s in res.status.tolist()]
    agree = np.mean([ours[i] == ref[i]["status"] for i in decided])
    feasible = [i for i in decided if ref[i]["status"] == "feasible" and ours[i] == "feasible"]
    rel = [abs(res.objective[i].item() - ref[i]["objective"]) / abs(ref[i]["objective"]) for i in feasible]
    n_feas = sum(ref[i]["status"] == "feasible" for i in decided)
    assert 0.2 * len(decided) < n_feas < 0.8 * len(decided), "the mix must hold both classes"
    assert agree >= 0.99, f"classification agreement {agree:.4f}"
    assert max(rel) <= 1e-3, f"objective relative error {max(rel):.2e}"


# --- warm starts ------------------------------------------------------------------------------------------------

def test_warm_start_reduces_iterations():
    prob = random_cone_problems(400, 5, torch.Generator().manual_seed(11), infeasible_fraction=0.0, kmin=4)
    parent = solve_friction_cone(**prob)
    child = perturb_problems(prob, torch.Generator().manual_seed(12), scale=0.01)
    cold = solve_friction_cone(**child)
    warm = solve_friction_cone(**child, warm_start=parent.forces)
    both = (cold.status == CONVERGED) & (warm.status == CONVERGED)
    assert both.float().mean() > 0.3
    assert warm.iterations[both].float().mean() < 0.5 * cold.iterations[both].float().mean()
    torch.testing.assert_close(warm.objective[both], cold.objective[both], rtol=1e-4, atol=1e-8)
    assert torch.equal(cold.status == INFEASIBLE, warm.status == INFEASIBLE)


# --- Siconos friction-contact data ------------------------------------------------------------------------------

def _read_fc3d_dense(path: Path):
    """(W, q, mu) of a dense-storage FrictionContact3D file (d, nc, storage, sizes, W, q, mu), else None."""
    if path.name.startswith("GFC3D"):          # global formulation (M, H, q, b, mu): a different layout
        return None
    tok = [float(t) for t in path.read_text().split()]
    d, nc, storage = int(tok[0]), int(tok[1]), int(tok[2])
    if d != 3 or storage != 0:
        return None
    n = 3 * nc
    i = 3
    while i < 7 and i < len(tok) and tok[i] == n:
        i += 1
    if i < 5 or len(tok) < i + n * n + n + nc:      # sizes "n n" must follow (GFC3D files differ here)
        return None
    W = np.array(tok[i:i + n * n]).reshape(n, n)
    q = np.array(tok[i + n * n:i + n * n + n])
    mu = np.array(tok[i + n * n + n:i + n * n + n + nc])
    return W, q, mu


def _clarabel_rows(clarabel, W, rhs, mu):
    """Clarabel on min sum r_n s.t. W r = rhs, (mu_i r_n, r_t) in SOC (r contact-major, normal first)."""
    from scipy import sparse

    nc, n = len(mu), W.shape[0]
    blocks = [W]
    for i in range(nc):
        blk = np.zeros((3, n))
        blk[0, 3 * i], blk[1, 3 * i + 1], blk[2, 3 * i + 2] = -mu[i], -1, -1
        blocks.append(blk)
    cost = np.zeros(n)
    cost[0::3] = 1
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    sol = clarabel.DefaultSolver(sparse.csc_matrix((n, n)), cost, sparse.csc_matrix(np.vstack(blocks)),
                                 np.concatenate([rhs, np.zeros(n)]),
                                 [clarabel.ZeroConeT(n)] + [clarabel.SecondOrderConeT(3)] * nc, settings).solve()
    return str(sol.status), sol.obj_val


def _core_rows(W, rhs, mu):
    """The same problem through the solver's core (build_problem / admm, any number of rows)."""
    nc, n = len(mu), W.shape[0]
    perm = np.concatenate([np.arange(nc) * 3 + j for j in range(3)])         # contact-major -> component-major
    A = torch.tensor(W[:, perm], dtype=torch.float64)[None]
    rows = A.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    A, b = A / rows, torch.tensor(rhs, dtype=torch.float64)[None] / rows[..., 0]
    beta = b.norm(dim=-1, keepdim=True)
    cost = torch.zeros(1, n, dtype=torch.float64)
    cost[:, :nc] = 1
    tol = cone_tolerances(torch.float64)
    prob, out_of_range = build_problem(A, b / beta, cost, torch.tensor(mu)[None], torch.ones(1, nc, dtype=torch.bool),
                                       tol.rank, tol.eps_cert)
    out = admm(prob, torch.zeros(1, n, dtype=torch.float64),
               AdmmSettings(eps=1e-8, eps_cert=tol.eps_cert, max_iters=2000, check_every=10), decided=out_of_range)
    status = INFEASIBLE if bool(out_of_range[0]) else int(out.status[0])
    z = out.z[0] * beta[0]
    r = z.reshape(3, nc).T.reshape(-1).numpy()
    return status, float(z[:nc].sum()), r


def test_siconos_friction_contact_data(shared_data):
    """The Siconos FC3D instances pose u = W r + q with reactions r (normal first) in the friction cones: Coulomb
    problems with velocities, not wrench problems, so they cannot go through solve_friction_cone's geometry. Two
    cone problems are posed on their data (the Delassus operators W are real, often rank-deficient) and run through
    the solver's core (any number of rows), compared with Clarabel: (1) the sticking question, is there r in the
    cones with W r + q = 0 (every contact velocity zero), with the least total normal reaction; (2) W r = W r0 for an
    r0 strictly inside the cones, feasible by construction. The GFC3D (global), SBM (sparse-block) and 2-D files
    have other layouts and are not read."""
    clarabel = pytest.importorskip("clarabel")

    folder = shared_data / "friction" / "siconos_fc"
    if not folder.exists():
        pytest.skip(f"reference data not found: {folder}")
    cases = [c for c in ((p.name, _read_fc3d_dense(p)) for p in sorted(folder.glob("*.dat"))) if c[1] is not None]
    if not cases:
        pytest.skip("no dense FrictionContact3D file in the Siconos data")
    checked = []
    for name, (W, q, mu) in cases:
        nc = len(mu)
        r0 = np.stack([np.ones(nc), 0.5 * mu, np.zeros(nc)], 1).reshape(-1)      # strictly inside the cones
        # (1) the sticking question on their data, W r = -q; (2) W r = W r0, feasible by construction.
        for label, rhs in (("sticking", -q), ("W r0", W @ r0)):
            ref_status, ref_obj = _clarabel_rows(clarabel, W, rhs, mu)
            status, obj, r = _core_rows(W, rhs, mu)
            checked.append((name, label, ref_status, status))
            # Never the wrong class; MAX_ITERATIONS is tolerated on the Rover operators (condition number ~1e7).
            if ref_status in ("Solved", "AlmostSolved"):
                assert status in (CONVERGED, MAX_ITERATIONS), (name, label)
                assert np.linalg.norm(W @ r - rhs) <= 1e-5 * (1 + np.linalg.norm(rhs)), (name, label)
                assert obj == pytest.approx(ref_obj, rel=1e-4 if status == CONVERGED else 1e-2), (name, label)
            elif ref_status in ("PrimalInfeasible", "AlmostPrimalInfeasible"):
                assert status == INFEASIBLE, (name, label)
    print("siconos problems (file, question, Clarabel, ours):", checked)
    assert len(checked) >= 6
    assert sum(c[3] == MAX_ITERATIONS for c in checked) <= 2


# --- CUDA ---------------------------------------------------------------------------------------------------------

@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA not available")
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["f32", "f64"])
def test_cuda_matches_cpu(dtype):
    torch.backends.cuda.matmul.allow_tf32 = False
    prob = random_cone_problems(256, 5, torch.Generator().manual_seed(21), dtype=dtype)
    cpu = solve_friction_cone(**prob)
    gpu = solve_friction_cone(**{k: (v.cuda() if v is not None else None) for k, v in prob.items()})
    assert gpu.forces.device.type == "cuda"
    agree = (gpu.status.cpu() == cpu.status).float().mean().item()
    assert agree >= 0.98
    both = (gpu.status.cpu() == CONVERGED) & (cpu.status == CONVERGED)
    rtol = 1e-3 if dtype == torch.float32 else 1e-5
    torch.testing.assert_close(gpu.objective.cpu()[both], cpu.objective[both], rtol=rtol, atol=1e-6)
    check_invariants(gpu, {k: (v.cuda() if v is not None else None) for k, v in prob.items()}, dtype)
