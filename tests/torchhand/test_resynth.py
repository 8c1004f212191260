"""Resynthesis of an interaction trajectory (Kry & Pai §7-8; torchhand/interaction/resynth.py, grip.py and the
object-table slots of step.py): an object resting on the table, a pinch lifting a light box, a heavier box with and
without delayed grip adjustment, the command line and its result directory under the independent checker, bad
inputs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from .test_step import F64, _pose, box_grid, hand_from_mjcf, pinch_xml
from torchhand.kernels.status import SolverStatus

from torchhand.interaction._contacts import BODY_OBJECT_ENV, support_points
from torchhand.interaction.grip import GripSettings
from torchhand.interaction.resynth import Interaction, load_interaction, object_slip, save_interaction, simulate
from torchhand.interaction.step import StepObject, StepSettings, TablePlane, initial_state, quasi_static_step

CONVERGED = int(SolverStatus.CONVERGED)
HALF = (0.02, 0.02, 0.03)          # 4 x 4 x 6 cm box
ROOT_Z = 0.12                      # pinch palm height: fingertips 4 cm above the table, beside the box
C_PINCH = [0.05] * 3 + [1e-4] * 3 + [1.0, 2.0, 1.0, 2.0]
SQUEEZE = np.array([1.0, 0.5, 1.0, 0.5])


# ----------------------------------------------------------------------------------------------------------------
# builders (also used by scripts/demo_resynth.py)
# ----------------------------------------------------------------------------------------------------------------
def box_mesh(half=HALF) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=2 * np.asarray(half, dtype=np.float64))


def box_step_object(masses, half=HALF, mu: float = 0.8) -> StepObject:
    """A free box with its support points; one mass per rollout."""
    hx, hy, hz = half
    m0 = float(masses[0])
    inertia = m0 / 3 * np.diag([hy * hy + hz * hz, hx * hx + hz * hz, hx * hx + hy * hy])
    return StepObject(box_grid(half), m0, (0.0, 0.0, 0.0), inertia, mu, support=support_points(box_mesh(half).vertices),
                      masses=tuple(masses))


def pinch_reference(fps: float = 120.0, squeeze: float = 0.25, lift: float = 0.05, duration: float = 1.2):
    """Close the pinch over 0.3 s, hold 0.1 s, lift the root by ``lift`` over 0.5 s (smoothstep), hold.
    Returns (theta_r (T, 4), root_r (T, 4, 4), lift start frame)."""
    t = np.arange(round(duration * fps) + 1) / fps
    close = np.clip(t / 0.3, 0, 1)
    s = np.clip((t - 0.4) / 0.5, 0, 1)
    s = s * s * (3 - 2 * s)
    theta_r = squeeze * close[:, None] * SQUEEZE
    root = np.tile(np.eye(4), (len(t), 1, 1))
    root[:, 2, 3] = ROOT_Z + lift * s
    return theta_r, root, round(0.4 * fps)


def run_pinch(masses, grip: str = "none", fps: float = 120.0, solver: str = "lemke", lemke_warm: bool = True,
              **reference):
    """B pinch rollouts on the 4 x 4 x 6 cm box resting on the table at z = 0. Returns (record, lift frame)."""
    B = len(masses)
    theta_r, root, start = pinch_reference(fps, **reference)
    T = theta_r.shape[0]
    hand = hand_from_mjcf(pinch_xml())
    settings = StepSettings(h=1 / fps, solver=solver, geometry="capsules", pgs_max_iters=50, lemke_warm=lemke_warm)
    th = torch.from_numpy(theta_r).expand(B, T, 4).contiguous()
    rr = torch.from_numpy(root).expand(B, T, 4, 4).contiguous()
    C = torch.tensor(C_PINCH, dtype=F64).expand(B, T, 10).contiguous()
    rec = simulate(hand, box_step_object(masses), TablePlane(offset=0.0, mu=0.5), th, rr, C, _pose(z=HALF[2], B=B),
                   settings=settings, grip=GripSettings(grip))
    return rec, start


def pinch_files(directory, *, half=HALF, mass: float = 0.05, fps: float = 60.0, lift: float = 0.05):
    """A scene directory (the pinch as an MJCF hand with a mount sidecar, the box on a table at z = 0) and an
    interaction.npz (source "constructed"); returns (scene dir, interaction path)."""
    from torchhand.geometry.objects import RigidObject
    from torchhand.scene import Environment, HandTrack, Scene

    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    (d / "pinch.xml").write_text(pinch_xml())
    (d / "pinch.torchhand.toml").write_text("[mount]\norigin = [0.0, 0.0, 0.0]\nx_axis = [0.0, 0.0, -1.0]\n"
                                            "y_axis = [0.0, 1.0, 0.0]\n")
    theta_r, root, _ = pinch_reference(fps, lift=lift)
    T = theta_r.shape[0]
    hand_frame = np.eye(4)
    hand_frame[:3, :3] = [[0, 0, 1.0], [0, 1, 0], [-1, 0, 0]]      # hand x = model -z (the fingers hang down)
    wrist = root @ hand_frame
    obj = RigidObject.from_trimesh(box_mesh(half), mass=mass, name="box")
    pose = np.tile(np.eye(4), (T, 1, 1))
    pose[:, 2, 3] = half[2]
    scene = Scene(name="pinch-box", object=obj, object_pose=torch.from_numpy(pose), fps=fps,
                  hands=(HandTrack(side="right", wrist_pose=torch.from_numpy(wrist), model=str(d / "pinch.xml")),),
                  friction=0.8, environment=Environment(table=True, table_height=0.0, friction=0.5))
    scene_dir = scene.export(d / "scene")
    C = np.tile(np.asarray(C_PINCH), (T, 1))
    root_c = np.concatenate([np.zeros((T, 3)), root[:, :3, 3] - root[0, :3, 3]], 1)
    inter = Interaction(fps, ("left_j0", "left_j1", "right_j0", "right_j1"), C, theta_r, root_c, wrist[0],
                        "constructed")
    return scene_dir, save_interaction(inter, d / "interaction.npz")


# ----------------------------------------------------------------------------------------------------------------
# object-table contacts
# ----------------------------------------------------------------------------------------------------------------
def test_support_points_of_a_box_are_its_corners():
    pts = support_points(box_mesh().vertices).numpy()
    assert pts.shape == (8, 3)
    np.testing.assert_allclose(np.abs(pts), np.broadcast_to(HALF, (8, 3)))
    assert support_points(np.random.default_rng(0).normal(size=(200, 3)), max_points=6).shape == (6, 3)


@pytest.mark.parametrize("solver", ["lemke", "auto"])
def test_object_rests_on_the_table(solver):
    """Hand far above; the box's weight is carried by its four bottom corners: balance within 1 % of m g."""
    B, mass = 2, 0.05
    obj = box_step_object([mass, 2 * mass])
    env = TablePlane(offset=0.0, mu=0.5)
    hand = hand_from_mjcf(pinch_xml())
    settings = StepSettings(solver=solver, geometry="capsules", pgs_max_iters=50)
    state = initial_state(hand, torch.zeros(B, 4, dtype=F64), _pose(z=0.3, B=B), object_pose=_pose(z=HALF[2], B=B),
                          obj=obj, env=env, settings=settings)
    C = torch.tensor(C_PINCH, dtype=F64).expand(B, 10)
    for _ in range(10):
        state, rep = quasi_static_step(state, hand, state.theta_r, state.root_r, C, obj, env, settings)
        assert (rep.status == CONVERGED).all()
    on_table = state.contacts.body == BODY_OBJECT_ENV
    assert (rep.mask[:, on_table].sum(1) == 4).all()
    f = torch.einsum("bnrk,bnk->bnr", rep.D, rep.beta)[:, on_table].sum(1)
    weight = 9.81 * torch.tensor([mass, 2 * mass], dtype=F64)
    assert torch.allclose(f[:, 2], weight, rtol=1e-2)
    assert (f[:, :2].abs() < 1e-2 * weight[:, None]).all()
    assert (state.object_pose[:, :3, 3] - torch.tensor([0, 0, HALF[2]], dtype=F64)).abs().max() < 1e-6


# ----------------------------------------------------------------------------------------------------------------
# lifting, slip and grip adjustment
# ----------------------------------------------------------------------------------------------------------------
def test_pinch_lifts_a_light_box():
    rec, start = run_pinch([0.05])
    pose, root = rec["object_pose"][0].numpy(), rec["root"][0].numpy()
    assert int(rec["failed_step"][0]) == -1 and (rec["status"] == CONVERGED).all()
    assert pose[-1, 2, 3] - pose[0, 2, 3] > 0.045                  # lifted with the root (5 cm)
    assert object_slip(root, pose, np.zeros(3), start).max() < 0.002
    assert rec["theta_err"].max() < 1e-2


def test_batched_rollouts_match_single_ones():
    """Two masses in one batch (PGS with Lemke for stragglers) against separate Lemke rollouts: same motion."""
    both, _ = run_pinch([0.05, 0.2], solver="auto", duration=0.6)
    for b, m in enumerate([0.05, 0.2]):
        one, _ = run_pinch([m], duration=0.6)
        np.testing.assert_allclose(both["object_pose"][b].numpy(), one["object_pose"][0].numpy(), atol=2e-4)


def test_variants_in_one_batch_are_solved_as_alone(tmp_path):
    """resynthesize's default for several rollouts solves each rollout's LCP as it would be alone (Lemke from that
    rollout's previous support): three variants (mass, friction, compliance scale) in one batch move as each of them
    run alone, to round-off (the batch's padded matrices can sum in another order), with the same grip events."""
    from torchhand.interaction.resynth import ResynthSettings, Variant, resynthesize
    from torchhand.scene import load_scene

    scene_dir, inter_path = pinch_files(tmp_path / "in")
    scene, inter = load_scene(scene_dir), load_interaction(inter_path)
    variants = (Variant(mass=0.1), Variant(friction=0.4), Variant(compliance_scale=0.5))
    settings = ResynthSettings(grip=GripSettings("imminent"))
    both = resynthesize(inter, scene, variants=variants, settings=settings)
    assert all(r.ok for r in both.rollouts)
    lifted = [float(np.ptp(np.asarray(r.object_pose)[:, 2, 3])) for r in both.rollouts]
    assert min(lifted) > 0.01                      # every variant lifts the box: the comparison is not of rest
    for b, v in enumerate(variants):
        one = resynthesize(inter, scene, variants=(v,), settings=settings).rollouts[0]
        mine = both.rollouts[b]
        # measured: equal, or 1e-14 apart; batched PGS first (solver "auto") is 1e-9 m and 5e-7 N away
        np.testing.assert_allclose(np.asarray(mine.q), np.asarray(one.q), rtol=0, atol=1e-11)
        np.testing.assert_allclose(np.asarray(mine.object_pose), np.asarray(one.object_pose), rtol=0, atol=1e-11)
        np.testing.assert_allclose(np.asarray(mine.contact_force), np.asarray(one.contact_force), rtol=0, atol=1e-10)
        np.testing.assert_array_equal(mine.grip_events, one.grip_events)


def _mesh_step_object(mesh: trimesh.Trimesh, mass: float, mu: float) -> StepObject:
    """A free object from its exact mesh (mass properties and support points of the mesh)."""
    from torchhand.check.geometry import object_mesh

    om = object_mesh(mesh, mass)
    return StepObject(None, mass, tuple(om.com), om.inertia, mu, support=support_points(mesh.vertices), mesh=om)


def test_different_objects_in_one_batch_move_as_each_alone():
    """Two objects as two rollouts of one batch (StepObject.per_rollout): the pinch's 4 x 4 x 6 cm box and a
    cylinder 3.4 cm across (16 support points against the box's 8, another mass and friction). Each moves as it does
    in a batch of its own, to round-off; both are lifted, and the hands differ (the cylinder is narrower)."""
    theta_r, root, start = pinch_reference(120.0, duration=0.8)
    T = theta_r.shape[0]
    hand = hand_from_mjcf(pinch_xml())
    settings = StepSettings(h=1 / 120, solver="lemke", geometry="capsules")
    box = _mesh_step_object(box_mesh(), 0.05, 0.8)
    cyl_mesh = trimesh.creation.cylinder(radius=0.017, height=2 * HALF[2], sections=24)
    cyl = _mesh_step_object(cyl_mesh, 0.08, 0.6)
    assert cyl.support.shape[0] > box.support.shape[0]

    def run(objects):
        B = len(objects)
        return simulate(hand, StepObject.per_rollout(objects), TablePlane(offset=0.0, mu=0.5),
                        torch.from_numpy(theta_r).expand(B, T, 4).contiguous(),
                        torch.from_numpy(root).expand(B, T, 4, 4).contiguous(),
                        torch.tensor(C_PINCH, dtype=F64).expand(B, T, 10).contiguous(),
                        _pose(z=HALF[2], B=B), settings=settings)

    both = run([box, cyl])
    assert (both["failed_step"] == -1).all()
    for b, obj in enumerate([box, cyl]):
        one = run([obj])
        L2 = 2 * hand.num_links           # the hand's slots (the support slots are padded to the batch's most)
        for key, x, y in (("q", both["q"][b], one["q"][0]),
                          ("object_pose", both["object_pose"][b], one["object_pose"][0]),
                          ("forces", both["forces"][b, :, :L2], one["forces"][0, :, :L2])):
            # measured: 1e-12 (q) to 3e-9 m and 7e-9 N; the batch's padded matrices sum in another order, and the
            # resting contacts carry that round-off on
            np.testing.assert_allclose(x.numpy(), y.numpy(), rtol=0, atol=1e-7, err_msg=key)
    lift = both["object_pose"][:, -1, 2, 3] - HALF[2]
    assert float(lift[0]) > 0.02 and float(lift[1]) > 0.02          # both lifted
    assert not torch.allclose(both["q"][0], both["q"][1], atol=1e-4)


def test_heavy_box_slips_less_with_delayed_grip():
    """0.35 kg: without grip adjustment the pinch loses the box; with the 100 ms delayed response it holds it.
    Grip events start at least 100 ms (12 steps at 120 Hz) after the slip onset."""
    none, start = run_pinch([0.35])
    delayed, _ = run_pinch([0.35], grip="delayed")
    slip = {k: object_slip(r["root"][0].numpy(), r["object_pose"][0].numpy(), np.zeros(3), start).max()
            for k, r in (("none", none), ("delayed", delayed))}
    assert slip["none"] > 0.03 and slip["delayed"] < 0.5 * slip["none"]
    assert delayed["object_pose"][0, -1, 2, 3] > HALF[2] + 0.02        # still in the air
    onset = int(delayed["onset"][0])
    frames = [k for _, k, _ in delayed["grip_events"]]
    assert onset >= 0 and frames and min(frames) - onset >= 12
    assert none["grip_events"] == []


def test_imminent_grip_tightens_before_slip():
    rec, start = run_pinch([0.35], grip="imminent")
    frames = [k for _, k, _ in rec["grip_events"]]
    assert frames and min(frames) == int(rec["onset"][0])           # acts at once
    assert object_slip(rec["root"][0].numpy(), rec["object_pose"][0].numpy(), np.zeros(3), start).max() < 0.02


# ----------------------------------------------------------------------------------------------------------------
# command line, result directory, checker
# ----------------------------------------------------------------------------------------------------------------
def test_cli_writes_a_result_the_checker_reads(tmp_path):
    from torchhand.check import check_result
    from torchhand.cli import main
    from torchhand.io.result import load_result

    scene_dir, inter = pinch_files(tmp_path / "in")
    out = tmp_path / "out"
    rc = main(["capture", "resynthesize", str(inter), "--scene", str(scene_dir), "--out", str(out),
               "--mass", "0.05,0.35", "--grip", "delayed", "--solver", "lemke"])
    assert rc == 0
    stats = json.loads((out / "stats.json").read_text())
    assert stats["method"] == "kry_pai" and stats["complete"] and stats["solutions"] == 2
    res = load_result(out)
    sol = np.load(out / "solutions" / "sol_000.npz")
    for key in ("theta_r", "compliance", "slip_ratio", "lcp_status", "lcp_residual", "theta_err", "grip_events",
                "joint_clamp"):
        assert key in sol.files
    T = sol["q"].shape[0]
    assert sol["joint_clamp"].shape == (T,) and sol["joint_clamp"][0] == 0
    assert stats["rollouts"][0]["joint_clamp_frames"] == int((sol["joint_clamp"] > 1e-9).sum())
    assert stats["settings"]["object_contacts"] == "mesh" and stats["settings"]["self_contacts"]
    assert stats["settings"]["finger_friction"] == 0.0
    assert 0 < stats["timings_s"]["median_step_ms"] < 1e4 and stats["per_step_ms"] > 0
    assert sol["slip_ratio"].shape == sol["contact_mask"].shape
    assert res.solution(0).q.shape == (res.scene.T, 4)
    # object-table contacts lie on the table (a corner closing a gap during its step is written where it lands)
    em = sol["env_contact_mask"]
    assert em.any()
    np.testing.assert_allclose(sol["env_contact_point"][em][:, 2], res.scene.environment.table_height, atol=1e-12)
    report = check_result(out)
    first = report.solutions[0]
    # the light box (the scene's mass): penetration, contact gaps, cones and balance pass
    for name in ("object_penetration_m", "table_penetration_m", "contact_object_m", "contact_hand_m",
                 "cone_violation", "force_error"):
        assert first.figures[name].ok, (name, first.figures[name])
    assert first.figures["torque_error"].ok and report.solutions[0].passed
    # The checker judges each rollout with its own mass (the solution's ``variant_mass``), so the 0.35 kg rollout's
    # balance is measured against 0.35 kg, not the scene's 0.05 kg: the same figures as balance_errors at 0.35 kg
    # with mass properties from trimesh, within 2 % of m g during the slip and < 1 % elsewhere.
    from torchhand.check.geometry import object_mesh
    from torchhand.check.motion import balance_errors

    second = report.solutions[1].figures
    assert res.solution(1).object_mass == 0.35 and res.solution(0).object_mass == 0.05
    f_err, t_err = balance_errors(res.solution(1), object_mesh(res.scene.object.mesh, 0.35), 0.35,
                                  np.array([0.0, 0.0, -9.81]))
    assert f_err.max() < 0.02 and np.median(f_err) < 1e-3
    assert second["force_error"].value == pytest.approx(np.nanmax(f_err), rel=1e-9)
    assert second["torque_error"].value == pytest.approx(np.nanmax(t_err), rel=1e-9)
    # variants of one interaction share most of their motion: either not compared (a solution with its own
    # ``variant_mass`` is a separate experiment) or flagged as a duplicate
    assert "distinct_deg" not in second or not second["distinct_deg"].ok
    for name in ("object_penetration_m", "contact_object_m", "contact_hand_m", "cone_violation"):
        assert second[name].ok, (name, second[name])


def test_cli_variant_file_writes_one_checked_result_per_object(tmp_path):
    """capture resynthesize --variants FILE: the pinch's box and a cylinder (a mesh file, 3.4 cm across, another
    friction) as two rollouts of one batch, written as two result directories whose scenes hold each its own object;
    each passes the checker's geometric and balance tests against that object, and each equals its variant run
    alone to round-off. Bad files exit 2 and leave nothing behind."""
    from torchhand.check import check_result
    from torchhand.cli import main
    from torchhand.io.result import load_result

    scene_dir, inter = pinch_files(tmp_path / "in")
    trimesh.creation.cylinder(radius=0.017, height=2 * HALF[2], sections=24).export(tmp_path / "cyl.stl")
    spec = tmp_path / "variants.toml"
    spec.write_text('[[variant]]\nname = "box"\n\n[[variant]]\nname = "cylinder"\nobject = "cyl.stl"\n'
                    'friction = 0.6\n')
    out = tmp_path / "out"
    args = ["capture", "resynthesize", str(inter), "--scene", str(scene_dir)]
    assert main([*args, "--out", str(out), "--variants", str(spec)]) == 0
    results = {name: load_result(out / name) for name in ("box", "cylinder")}
    assert results["cylinder"].scene.object.name == "cyl" and results["box"].scene.object.name != "cyl"
    assert np.ptp(results["cylinder"].scene.object.mesh.vertices[:, 0]) == pytest.approx(0.034, abs=1e-3)
    for name, res in results.items():
        stats = json.loads((out / name / "stats.json").read_text())
        assert stats["complete"] and stats["solutions"] == 1
        report = check_result(out / name)
        for fig in ("object_penetration_m", "contact_object_m", "contact_hand_m", "cone_violation", "force_error",
                    "torque_error"):
            assert report.solutions[0].figures[fig].ok, (name, fig, report.solutions[0].figures[fig])
    alone = tmp_path / "alone"
    spec1 = tmp_path / "one.toml"
    spec1.write_text('[[variant]]\nname = "cylinder"\nobject = "cyl.stl"\nfriction = 0.6\n')
    assert main([*args, "--out", str(alone), "--variants", str(spec1)]) == 0
    a, b = results["cylinder"].solution(0), load_result(alone / "cylinder").solution(0)
    np.testing.assert_allclose(a.q, b.q, rtol=0, atol=1e-7)
    np.testing.assert_allclose(a.object_pose, b.object_pose, rtol=0, atol=1e-7)
    for text in ('[[variant]]\nname = "a"\nsize = 2\n', '[[variant]]\nname = "a/b"\n',
                 '[[variant]]\nname = "a"\nobject = "missing.stl"\n', 'variant = 3\n'):
        spec.write_text(text)
        assert _cli([*args[2:], "--out", str(tmp_path / "bad"), "--variants", str(spec)]) == 2
        assert not (tmp_path / "bad").exists()
    spec.write_text('[[variant]]\nname = "a"\n')
    assert _cli([*args[2:], "--out", str(tmp_path / "bad"), "--variants", str(spec), "--mass", "0.1"]) == 2
    # found after the result directories were claimed: they are given back, and the folder made for them too
    spec.write_text('[[variant]]\nname = "a"\nobject = "cyl.stl"\n')
    assert _cli([*args[2:], "--out", str(tmp_path / "bad"), "--variants", str(spec), "--object-contacts",
                 "sdf"]) == 2
    assert not (tmp_path / "bad").exists()


def test_variant_file_shares_an_object_named_twice(tmp_path):
    """Variants that name one mesh file (by different relative paths) get one object, so that the step queries its
    mesh once for both; a scene directory gives its object; defaults are None (the scene's) and scale 1."""
    from torchhand.interaction._variant_spec import load_variant_file
    from torchhand.scene import load_scene

    scene_dir, _ = pinch_files(tmp_path / "in")
    scene = load_scene(scene_dir)
    (tmp_path / "meshes").mkdir()
    trimesh.creation.cylinder(radius=0.017, height=0.06, sections=24).export(tmp_path / "meshes" / "cyl.stl")
    spec = tmp_path / "v.toml"
    spec.write_text('[[variant]]\nname = "a"\nobject = "meshes/cyl.stl"\nmass = 0.1\n\n'
                    '[[variant]]\nname = "b"\nobject = "./meshes/../meshes/cyl.stl"\ncompliance_scale = 2\n\n'
                    f'[[variant]]\nname = "c"\nobject = "{scene_dir.relative_to(tmp_path)}"\n\n'
                    '[[variant]]\nname = "d"\n')
    (na, a), (nb, b), (nc, c), (nd, d) = load_variant_file(spec, scene)
    assert (na, nb, nc, nd) == ("a", "b", "c", "d")
    assert a.object is b.object and a.object.mass == pytest.approx(scene.object.mass)
    assert (a.mass, b.mass, b.compliance_scale, a.friction) == (0.1, None, 2.0, None)
    assert c.object.name == scene.object.name and d.object is None and d.compliance_scale == 1.0


def _cli(args) -> int:
    from torchhand.cli import main

    return main(["capture", "resynthesize", *args])


def test_cli_bad_inputs(tmp_path, capsys):
    scene_dir, inter = pinch_files(tmp_path / "in")
    out = str(tmp_path / "out")
    assert _cli([str(tmp_path / "missing.npz"), "--scene", str(scene_dir), "--out", out]) == 2
    assert _cli([str(inter), "--scene", str(scene_dir), "--out", out, "--mass", "0.1,abc"]) == 2
    assert _cli([str(inter), "--scene", str(scene_dir), "--out", out, "--mass", "-1"]) == 2
    assert _cli([str(inter), "--scene", str(scene_dir), "--out", out, "--dt", "0.5"]) == 2
    assert _cli([str(inter), "--scene", str(scene_dir), "--out", out, "--finger-friction", "-0.5"]) == 2
    assert _cli([str(inter), "--scene", "box-pickup", "--out", out]) == 2          # joints of another hand
    (tmp_path / "file").write_text("x")
    assert _cli([str(inter), "--scene", str(scene_dir), "--out", str(tmp_path / "file")]) == 2
    bad = dict(np.load(inter))
    bad["theta_r"] = bad["theta_r"].copy()
    bad["theta_r"][3, 1] = np.nan
    np.savez(tmp_path / "nan.npz", **bad)
    assert _cli([str(tmp_path / "nan.npz"), "--scene", str(scene_dir), "--out", out]) == 2
    err = capsys.readouterr().err
    assert "frame 3" in err and "Traceback" not in err
    assert not Path(out).exists() or not any(Path(out).iterdir())


def test_load_interaction_roundtrip(tmp_path):
    _, path = pinch_files(tmp_path)
    inter = load_interaction(path)
    assert inter.source == "constructed" and inter.C.shape == (inter.T, 10) and inter.root_origin.shape == (4, 4)


def _failing_at(real, call: int):
    """Lemke that reports its ``call``-th problem unsolved (a ray)."""
    calls = {"n": 0}

    def failing(M, q, **kw):
        out = real(M, q, **kw)
        calls["n"] += 1
        return out._replace(status=SolverStatus.UNBOUNDED) if calls["n"] == call else out
    return failing


def test_a_lemke_failure_is_solved_from_pgs_sweeps(monkeypatch):
    """Lemke's method is not complete for the step's LCP: where its run ends without a solution, the support of a
    few PGS sweeps is solved exactly and verified, and the rollout goes on as if Lemke had solved that step."""
    import torchhand.solvers.lcp as lcp_module

    ref, _ = run_pinch([0.05, 0.05], duration=0.2, lemke_warm=False)
    monkeypatch.setattr(lcp_module, "lemke", _failing_at(lcp_module.lemke, 2 * 5 + 2))   # step 5, rollout 1
    rec, _ = run_pinch([0.05, 0.05], duration=0.2, lemke_warm=False)
    assert rec["failed_step"].tolist() == [-1, -1]
    np.testing.assert_allclose(rec["object_pose"].numpy(), ref["object_pose"].numpy(), atol=1e-6)


def test_unsolved_lcp_stops_only_that_rollout(tmp_path, monkeypatch, capsys):
    """An LCP that neither Lemke nor the PGS support solves, at step 5 of rollout 1, stops rollout 1 there;
    rollout 0 completes. When every rollout fails the command exits 1 and stats.json names the step."""
    import torchhand.interaction.step as step_module
    import torchhand.solvers.lcp as lcp_module              # the step solves through torchhand.solvers.lcp.solve
    from torchhand.cli import main

    real = lcp_module.lemke
    monkeypatch.setattr(step_module, "_from_pgs", lambda *a, **k: None)
    monkeypatch.setattr(lcp_module, "lemke", _failing_at(real, 2 * 5 + 2))   # one call per rollout and step
    rec, _ = run_pinch([0.05, 0.05], duration=0.2, lemke_warm=False)
    assert rec["failed_step"].tolist() == [-1, 5]

    monkeypatch.setattr(step_module, "_warm", lambda *a, **k: None)          # no support solves any step
    monkeypatch.setattr(lcp_module, "lemke", lambda M, q, **kw: real(M, q, **kw)._replace(
        status=SolverStatus.UNBOUNDED))
    scene_dir, inter = pinch_files(tmp_path / "in")
    out = tmp_path / "out"
    assert main(["capture", "resynthesize", str(inter), "--scene", str(scene_dir), "--out", str(out),
                 "--solver", "lemke"]) == 1
    stats = json.loads((out / "stats.json").read_text())
    assert stats["solutions"] == 0 and stats["rollouts"][0]["failed_step"] == 0
    assert "stopped at step 0 (UNBOUNDED)" in capsys.readouterr().err


def test_resynthesis_of_a_scene_with_an_external_wrench(tmp_path):
    """A scene that carries an ``external_wrench`` (T, 6) gives an output scene at the step's rate (other T and fps)
    without one: the wrench belongs to the source frames, the resynthesised motion has none of its own."""
    import dataclasses

    from torchhand.interaction.resynth import ResynthSettings, resynthesize
    from torchhand.scene import load_scene

    scene_dir, inter_path = pinch_files(tmp_path / "in")
    scene = load_scene(scene_dir)
    scene = dataclasses.replace(scene, external_wrench=torch.zeros(scene.T, 6, dtype=torch.float64))
    inter = load_interaction(inter_path)
    inter = dataclasses.replace(inter, C=inter.C[:6], theta_r=inter.theta_r[:6], root_theta_r=inter.root_theta_r[:6])
    out = resynthesize(inter, scene, settings=ResynthSettings(dt=1 / 120))
    assert out.rollouts[0].ok and out.scene.external_wrench is None
    assert out.scene.T == 11 and out.scene.fps == 120.0


def test_rollouts_run_on_one_torch_thread_and_restore_the_count(tmp_path):
    """The rollout loop holds torch to one intra-op thread (its tensors are small: more threads only contend, 7.8x
    slower measured on a busy 2-core machine) and gives the caller's thread count back afterwards, also when the
    rollouts finish normally; the progress callback sees one thread."""
    from torchhand.interaction.resynth import ResynthSettings, resynthesize
    from torchhand.scene import load_scene

    scene_dir, inter_path = pinch_files(tmp_path / "in")
    seen = []
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        def progress(msg):
            if msg.startswith("step "):
                seen.append(torch.get_num_threads())

        res = resynthesize(load_interaction(inter_path), load_scene(scene_dir), settings=ResynthSettings(),
                           progress=progress)
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
    assert res.rollouts[0].ok and seen and set(seen) == {1}


def test_cli_device_cuda_without_a_gpu_is_bad_input(tmp_path, capsys):
    """--device cuda on a machine without CUDA: exit 2 with one line naming the problem, nothing written."""
    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    scene_dir, inter = pinch_files(tmp_path / "in")
    out = tmp_path / "out"
    assert _cli([str(inter), "--scene", str(scene_dir), "--out", str(out), "--device", "cuda"]) == 2
    assert "no CUDA device" in capsys.readouterr().err
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA not available")
def test_resynthesis_on_cuda_follows_the_cpu(tmp_path):
    """The pinch lift with three variants, its step's tensors on the GPU: every rollout completes and moves as on the
    CPU to round-off (the LCPs are solved on the CPU in both; the GPU's sums may round differently)."""
    from torchhand.interaction.resynth import ResynthSettings, Variant, resynthesize
    from torchhand.scene import load_scene

    scene_dir, inter_path = pinch_files(tmp_path / "in")
    scene, inter = load_scene(scene_dir), load_interaction(inter_path)
    variants = (Variant(mass=0.1), Variant(friction=0.4), Variant(compliance_scale=0.5))
    cpu = resynthesize(inter, scene, variants=variants, settings=ResynthSettings())
    gpu = resynthesize(inter, scene, variants=variants, settings=ResynthSettings(device="cuda"))
    for a, b in zip(cpu.rollouts, gpu.rollouts):
        assert a.ok and b.ok
        np.testing.assert_allclose(np.asarray(b.object_pose), np.asarray(a.object_pose), atol=1e-9)
        np.testing.assert_allclose(np.asarray(b.q), np.asarray(a.q), atol=1e-8)


def test_a_step_given_in_decimals_keeps_the_last_frame():
    """42 frames at 30 fps stepped at 1/240 s are 329 steps, also when the step is written 0.004166666667 (a hair
    longer, so that 1.3667 s / h falls 3e-8 short of 328 steps); a step that truly does not reach the end adds none."""
    from torchhand.interaction.resynth import _resample

    T, D = 42, 3
    inter = Interaction(fps=30.0, joint_names=tuple(f"j{i}" for i in range(D)), C=np.ones((T, 6 + D)),
                        theta_r=np.zeros((T, D)), root_theta_r=np.zeros((T, 6)))
    assert _resample(inter, 1 / 240)[0].shape[0] == 329
    assert _resample(inter, 0.004166666667)[0].shape[0] == 329
    assert _resample(inter, 1 / 239)[0].shape[0] == 327
