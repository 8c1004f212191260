"""Inferred interactions (``torchhand capture from-result``) and the checker's per-solution mass.

A small real ``torchhand synthesize box-turn`` result (test_grasp.small_result, shared with other tests) is the
input. Its first frames hold the box still on the table, so its hand forces are zero; the torque tests therefore
write known forces into a copy of its solution file and compare tau with MuJoCo's mj_applyFT on the result's own
hand.xml.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from torchhand.cli import main as cli

from .test_grasp import small_result


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def _rewrite(sol_file: Path, **changes) -> None:
    with np.load(sol_file) as z:
        data = {k: z[k] for k in z.files}
    data.update(changes)
    np.savez(sol_file, **data)


def _forced_result(tmp_path_factory, tmp_path) -> tuple[Path, np.ndarray]:
    """A copy of the small result whose contact forces (hand on object) are seeded random vectors of 0.1-2 N."""
    res = _copy(small_result(tmp_path_factory), tmp_path / "forced")
    f = res / "solutions" / "sol_000.npz"
    with np.load(f) as z:
        mask = z["contact_mask"]
    rng = np.random.default_rng(7)
    force = rng.normal(size=mask.shape + (3,))
    force *= (0.1 + 1.9 * rng.random(mask.shape))[..., None] / np.linalg.norm(force, axis=-1, keepdims=True)
    force *= mask[..., None]
    _rewrite(f, contact_force=force)
    return res, force


def _quat(R):
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.array([w, x, y, z])


def test_from_result_tau_matches_mujoco_and_theta_r(tmp_path_factory, tmp_path):
    """tau of interaction.npz against MuJoCo (mj_applyFT of the force on the hand at the capture's link-frame point,
    result's hand.xml, free root joint mapped to torque about the root origin and force, world): within 1e-9 of the
    largest; theta_r = theta - C tau exactly, C the Table 1 exploring preset in every frame."""
    mujoco = pytest.importorskip("mujoco")
    from torchhand.interaction import load_capture
    from torchhand.interaction.compliance import TABLE1

    res, force = _forced_result(tmp_path_factory, tmp_path)
    out = tmp_path / "inf"
    assert cli(["capture", "from-result", str(res), "--out", str(out), "--threads", "1",
                "--friction-margin", "1"]) == 0                      # the solution's forces as they are
    cap = load_capture(out / "capture.npz")
    z = np.load(out / "interaction.npz")
    assert cap.source == "inferred" and str(z["source"]) == "inferred"
    # forces on the hand are the solution's forces on the object, negated (every contact kept, none invented)
    np.testing.assert_allclose(np.sort(np.linalg.norm(cap.force, axis=-1).sum(1)),
                               np.sort(np.linalg.norm(force, axis=-1).sum(1)), rtol=1e-12)
    np.testing.assert_allclose(cap.force.sum(1), -force.sum(1), atol=1e-12)
    m = mujoco.MjModel.from_xml_path(str(out / "hand.xml"))
    data = mujoco.MjData(m)
    names = list(cap.joint_names)
    jid = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n) for n in names]
    assert m.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE and min(jid) > 0
    qadr, dadr = m.jnt_qposadr[jid], m.jnt_dofadr[jid]
    D = len(names)
    tau = z["tau"]
    worst = 0.0
    for t in range(cap.num_frames):
        root = cap.root_pose[t]
        data.qpos[:] = m.qpos0
        data.qpos[:3], data.qpos[3:7], data.qpos[qadr] = root[:3, 3], _quat(root[:3, :3]), cap.q[t]
        mujoco.mj_kinematics(m, data)
        mujoco.mj_comPos(m, data)
        qfrc = np.zeros(m.nv)
        for s, link in enumerate(cap.force_link):
            body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, link)
            point = data.xmat[body].reshape(3, 3) @ cap.force_point[t, s] + data.xpos[body]
            mujoco.mj_applyFT(m, data, cap.force[t, s], np.zeros(3), point, body, qfrc)
        S = np.zeros((m.nv, 6 + D))
        S[0:3, 3:6] = np.eye(3)
        S[3:6, 0:3] = root[:3, :3].T
        S[dadr, 6 + np.arange(D)] = 1
        worst = max(worst, float(np.abs(S.T @ qfrc - tau[t]).max()))
    scale = float(np.abs(tau).max())
    assert scale > 0.01 and worst <= 1e-9 * max(scale, 1.0), (worst, scale)
    # C: Table 1 exploring (the index finger's MP / PIP / DIP are the paper's values); theta_r exact
    C = z["C"]
    assert (C == C[0]).all() and z["C_is_default"].all()
    idx = {n: i for i, n in enumerate(str(n) for n in z["names"])}
    assert C[0, idx["index_mcp_flex"]] == TABLE1["exploring"]["mp"]
    assert C[0, idx["index_pip"]] == TABLE1["exploring"]["pip"]
    assert C[0, idx["index_dip"]] == TABLE1["exploring"]["dip"]
    full = np.concatenate([z["root_theta_r"], z["theta_r"]], axis=1)
    np.testing.assert_array_equal(full, z["theta"] - C * tau)
    # the contact points lie on the hand's links: within the synthesis' contact distance of hand.xml's capsules
    summary = json.loads((out / "summary.json").read_text())
    assert summary["source"] == "inferred" and summary["compliance"] == "table1-exploring"


def test_from_result_resynthesis_on_a_smaller_box_passes_the_check(tmp_path_factory, tmp_path):
    """from-result, a box 12 % smaller (bottom kept on the table), resynthesis of frames 2-7, torchhand check.

    These frames are the hand's approach (the inferred forces are zero there), so the resynthesised hand follows its
    reference down to the smaller box without loading it: the box stays where it was, and every figure of the
    checker passes (penetration, contact gaps, cones, balance of the resting box, joint speeds). Loaded contacts on
    the box's edges are measured in scripts/demo_inferred.py."""
    import dataclasses

    import trimesh

    from torchhand.check import check_result
    from torchhand.geometry.objects import RigidObject
    from torchhand.scene import load_scene

    res = small_result(tmp_path_factory)
    out = tmp_path / "inf"
    assert cli(["capture", "from-result", str(res), "--frames", "2:8", "--out", str(out), "--threads", "1"]) == 0
    scene = load_scene(out / "scene")
    assert scene.T == 6
    v = np.asarray(scene.object.mesh.vertices)
    v = np.concatenate([0.88 * v[:, :2], v[:, 2:].min() + 0.88 * (v[:, 2:] - v[:, 2:].min())], axis=1)
    mesh = trimesh.Trimesh(vertices=v, faces=np.asarray(scene.object.mesh.faces), process=False)
    obj = RigidObject.from_trimesh(mesh, mass=scene.object.mass, name="box-smaller")
    dataclasses.replace(scene, object=obj).export(tmp_path / "smaller")
    dest = tmp_path / "rs"
    assert cli(["capture", "resynthesize", str(out / "interaction.npz"), "--scene", str(tmp_path / "smaller"),
                "--out", str(dest), "--dt", str(1 / 60), "--solver", "lemke", "--threads", "1"]) == 0
    stats = json.loads((dest / "stats.json").read_text())
    assert stats["source"] == "inferred" and stats["rollouts"][0]["status"] == "COMPLETED"
    z = np.load(dest / "solutions" / "sol_000.npz")
    pose = z["object_pose"]
    assert np.abs(pose[:, :3, 3] - pose[0, :3, 3]).max() < 1e-4          # the box rests
    report = check_result(dest)
    assert report.passed, report.failures
    f = report.solutions[0].figures
    assert f["force_error"].value < 0.01 and f["object_penetration_m"].value <= 0.002


def test_friction_margin_keeps_the_wrench_inside_smaller_cones(tmp_path_factory, tmp_path):
    """--friction-margin 0.8 on a solution whose forces lie ON their friction cones (the forces of random wrenches
    solved by Clarabel at the full mu, minimum total normal force, the synthesis' own problem): per frame the
    re-solved forces give the same net force and torque about the centre of mass (recomputed here), lie inside
    cones of 0.8 mu about the solution's normals, and their total normal force is Clarabel's optimum of the same
    problem at 0.8 mu (the reference, within 1e-4 relative)."""
    clarabel = pytest.importorskip("clarabel")
    import dataclasses

    from scipy import sparse

    from torchhand.interaction.inferred import with_friction_margin
    from torchhand.io.result import load_result

    res = load_result(small_result(tmp_path_factory))
    sol = res.solution(0)
    mu, com = 0.8, np.asarray(res.scene.object.com, dtype=np.float64)
    T, K = sol.contact_mask.shape
    c = np.einsum("tij,j->ti", sol.object_pose[:, :3, :3], com) + sol.object_pose[:, :3, 3]

    def socp(t, mu_t, wrench):
        """min sum f.n  s.t.  sum f = F, sum r x f = tau, ||f_t|| <= mu_t f.n  (Clarabel): forces (k, 3), optimum."""
        idx = np.nonzero(sol.contact_mask[t])[0]
        k = len(idx)
        n = sol.contact_normal[t, idx]
        r = sol.contact_point[t, idx] - c[t]
        A = np.zeros((6, 3 * k))
        for j in range(k):
            A[:3, 3 * j:3 * j + 3] = np.eye(3)
            x, y, z = r[j]
            A[3:, 3 * j:3 * j + 3] = [[0, -z, y], [z, 0, -x], [-y, x, 0]]
        rows = [sparse.csc_matrix(A)]
        cones = [clarabel.ZeroConeT(6)]
        for j in range(k):
            e1 = np.cross(n[j], [1.0, 0, 0] if abs(n[j, 0]) < 0.9 else [0, 1.0, 0])
            e1 /= np.linalg.norm(e1)
            e2 = np.cross(n[j], e1)
            G = np.zeros((3, 3 * k))
            G[0, 3 * j:3 * j + 3] = -mu_t * n[j]
            G[1, 3 * j:3 * j + 3] = -e1
            G[2, 3 * j:3 * j + 3] = -e2
            rows.append(sparse.csc_matrix(G))
            cones.append(clarabel.SecondOrderConeT(3))
        settings = clarabel.DefaultSettings()
        settings.verbose = False
        settings.tol_gap_abs = settings.tol_gap_rel = settings.tol_feas = 1e-10
        q = np.concatenate([n[j] for j in range(k)])
        s = clarabel.DefaultSolver(sparse.csc_matrix((3 * k, 3 * k)), q, sparse.vstack(rows).tocsc(),
                                   np.concatenate([wrench, np.zeros(3 * k)]), cones, settings).solve()
        return idx, str(s.status), np.asarray(s.x).reshape(k, 3), float(s.obj_val)

    # forces on the cone's edge: each frame with 3+ contacts gets a random wrench solved at the full mu
    rng = np.random.default_rng(3)
    force = np.zeros((T, K, 3))
    frames = [t for t in range(T) if sol.contact_mask[t].sum() >= 3]
    for t in frames:
        w = np.concatenate([rng.normal(0, 0.5, 3) + [0, 0, 2.0], rng.normal(0, 0.01, 3)])
        idx, status, f, _ = socp(t, mu, w)
        if status == "Solved":
            force[t, idx] = f
    solved = [t for t in frames if np.abs(force[t]).sum() > 0]
    assert len(solved) >= 3
    sol = dataclasses.replace(sol, contact_force=force, contact_mask=sol.contact_mask & (np.abs(force).sum(-1) > 0))
    new, rep = with_friction_margin(sol, com, mu, 0.8)
    assert rep.use_before == pytest.approx(1.0, abs=1e-3) and rep.resolved + rep.kept == len(solved)
    compared = 0
    for t in solved:
        f0, f1 = force[t], new.contact_force[t]
        r = sol.contact_point[t] - c[t]
        scale = np.abs(f0).sum()
        np.testing.assert_allclose(f1.sum(0), f0.sum(0), atol=1e-5 * scale)
        np.testing.assert_allclose(np.cross(r, f1).sum(0), np.cross(r, f0).sum(0), atol=1e-6 * scale)
        idx, status, _, opt = socp(t, 0.8 * mu, np.concatenate([f0.sum(0), np.cross(r, f0).sum(0)]))
        if status != "Solved":
            continue                        # needs more than 0.8 mu: a larger margin or the solution's forces
        n = sol.contact_normal[t, idx]
        fn = (f1[idx] * n).sum(-1)
        ft = np.linalg.norm(f1[idx] - fn[:, None] * n, axis=-1)
        assert (ft <= 0.8 * mu * fn + 1e-5 * scale).all()
        assert fn.sum() == pytest.approx(opt, rel=1e-4)
        compared += 1
    assert compared >= 3


def test_from_result_bad_inputs(tmp_path_factory, tmp_path, capsys):
    res = small_result(tmp_path_factory)
    out = tmp_path / "inf"
    assert cli(["capture", "from-result", str(tmp_path / "missing"), "--out", str(out)]) == 2
    assert "does not exist" in capsys.readouterr().err and not out.exists()
    assert cli(["capture", "from-result", str(res), "--solution", "5", "--out", str(out)]) == 2
    assert "--solution" in capsys.readouterr().err
    for frames in ("5:3", "0:99", "a:b", "7:8"):
        assert cli(["capture", "from-result", str(res), "--frames", frames, "--out", str(out)]) == 2
        assert "--frames" in capsys.readouterr().err
    assert cli(["capture", "from-result", str(res), "--out", str(out), "--threads", "1"]) == 0
    before = (out / "interaction.npz").read_bytes()
    assert cli(["capture", "from-result", str(res), "--out", str(out)]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert (out / "interaction.npz").read_bytes() == before
    assert cli(["capture", "from-result", str(res), "--out", str(out), "--overwrite", "--friction-margin", "0"]) == 2
    assert "--friction-margin" in capsys.readouterr().err
    assert cli(["capture", "from-result", str(res), "--out", str(out), "--overwrite", "--compliance",
                "table1-scratching", "--threads", "1"]) == 0
    from torchhand.interaction.compliance import TABLE1

    z = np.load(out / "interaction.npz")
    names = [str(n) for n in z["names"]]
    assert z["C"][0, names.index("index_dip")] == TABLE1["scratching"]["dip"]
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("x")
    assert cli(["capture", "from-result", str(res), "--out", str(tmp_path / "other")]) == 2


def test_checker_uses_the_solutions_own_mass(tmp_path_factory, tmp_path):
    """The box rests on the table, which carries the scene's weight (0.25 kg). Written with ``variant_mass`` 0.5 kg,
    the checker judges that solution with 0.5 kg: force error |m_scene g - m g| / (m g) = 0.5, and the same figure
    as balance_errors at 0.5 kg; without the key it passes as before."""
    from torchhand.check import check_result
    from torchhand.check.geometry import object_mesh
    from torchhand.check.motion import balance_errors
    from torchhand.io.result import load_result

    res = _copy(small_result(tmp_path_factory), tmp_path / "mass")
    before = check_result(res).solutions[0].figures["force_error"]
    assert before.ok
    f = res / "solutions" / "sol_000.npz"
    _rewrite(f, variant_mass=np.array(0.5))
    loaded = load_result(res)
    assert loaded.solution(0).object_mass == 0.5 and loaded.scene.object.mass == 0.25
    after = check_result(res).solutions[0].figures
    assert not after["force_error"].ok
    assert after["force_error"].value == pytest.approx(0.5, abs=0.01)
    g = np.array([0.0, 0.0, -9.81])
    f_err, _ = balance_errors(loaded.solution(0), object_mesh(loaded.scene.object.mesh, 0.5), 0.5, g)
    assert after["force_error"].value == pytest.approx(np.nanmax(f_err), rel=1e-12)
    _rewrite(f, variant_mass=np.array(0.25))
    assert check_result(res).solutions[0].figures["force_error"].value == pytest.approx(before.value, rel=1e-12)
    _rewrite(f, variant_mass=np.array(-1.0))
    from torchhand.errors import FileFormatError

    with pytest.raises(FileFormatError, match="variant_mass"):
        load_result(res).solution(0)
