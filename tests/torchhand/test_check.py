"""torchhand.check: the independent checker of result directories.

One real ``torchhand synthesize box-turn`` result (shared with the render tests) is written once per session; the checker must pass it and flag
each defect planted in a copy of it (a finger under the table, a hand in the object, a force outside its cone, a
wrong object mass, a joint jump, a duplicated solution). Its numbers are compared with MuJoCo's capsule distances
and with trimesh on the hand's surface samples for one frame; bad input, --json, the limits (the checker's own,
never stats.json's; --limit), partial runs, and the import boundary (torchhand.check never imports
torchhand.synthesis) are tested too.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w
import trimesh

import torchhand
from torchhand.check import FIGURES, LIMITS, CheckReport, check_result
from torchhand.check.contacts import cone_violation, violation
from torchhand.check.geometry import object_mesh, segment_segment_distance
from torchhand.check.penetration import finger_depth, finger_pairs, object_depth, pose_hand, table_depth
from torchhand.cli import main as cli
from torchhand.errors import FileFormatError, MissingFileError, UnknownNameError

from tests.conftest import shared_path

REPO = Path(__file__).resolve().parents[2]


# --- fixtures: one real result, copies with one solution for the planted defects -----------------------------

@pytest.fixture(scope="module")
def clean_dir(tmp_path_factory) -> Path:
    """The session's real box-turn result (tests/render/real_result.py: three solutions, hand forces on)."""
    from tests.render.real_result import real_box_turn

    return real_box_turn(tmp_path_factory)


@pytest.fixture(scope="module")
def clean_report(clean_dir) -> CheckReport:
    return check_result(clean_dir)


def _copy(src: Path, dst: Path, solutions=(0,)) -> Path:
    """The result directory with only the given solutions (renumbered from 0)."""
    shutil.copytree(src / "scene", dst / "scene")
    for name in ("hand.xml", "stats.json"):
        shutil.copy(src / name, dst / name)
    (dst / "solutions").mkdir()
    for k, i in enumerate(solutions):
        shutil.copy(src / "solutions" / f"sol_{i:03d}.npz", dst / "solutions" / f"sol_{k:03d}.npz")
    return dst


def _edit_npz(path: Path, **changes) -> None:
    with np.load(path, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    data.update(changes)
    np.savez(path, **data)


def _edit_scene(root: Path, section: str, key: str, value) -> None:
    f = root / "scene" / "scene.toml"
    doc = tomllib.loads(f.read_text())
    doc[section][key] = value
    f.write_text(tomli_w.dumps(doc))


def _load(path: Path) -> dict:
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _posed(root: Path):
    """(result, solution 0, its posed right hand) of a result directory."""
    result = torchhand.load_result(root)
    sol = result.solution(0)
    h = sol.hands[0]
    return result, sol, pose_hand(result.hand_models[h.side], h.side, h.q, h.joint_names, h.root_pose, sol.path)


def _inward_normal(mesh: trimesh.Trimesh, pose: np.ndarray, point: np.ndarray) -> np.ndarray:
    """The mesh's inward face normal (world) at the surface point closest to ``point`` (world)."""
    local = np.linalg.inv(pose) @ np.append(point, 1.0)
    _, _, tri = trimesh.proximity.closest_point(mesh, local[None, :3])
    return -pose[:3, :3] @ mesh.face_normals[int(tri[0])]


# --- the clean result ------------------------------------------------------------------------------------------

def test_clean_result_passes(clean_report):
    assert clean_report.passed, "\n".join(clean_report.failures)
    assert len(clean_report.solutions) == 3 and clean_report.complete


def clean_report_frames(report) -> int:
    from tests.render.real_result import SYNTHESIZE

    a, b = SYNTHESIZE[SYNTHESIZE.index("--frames") + 1].split(":")
    return int(b) - int(a)


def test_report_has_every_figure_of_a_one_hand_table_scene(clean_report):
    for k, s in enumerate(clean_report.solutions):
        expected = [n for n in FIGURES if n != "hand_penetration_m" and (k > 0 or n != "distinct_deg")]
        assert list(s.figures) == expected and s.frames == clean_report_frames(clean_report) and s.index == k
        for name, f in s.figures.items():
            assert f.limit == clean_report.limits[name] and np.isfinite(f.value)
    assert clean_report.limits["joint_acceleration_rad_s2"] == 2 * clean_report.limits["joint_speed_rad_s"] * 30


# --- planted defects -----------------------------------------------------------------------------------------

def test_finger_under_the_table_is_flagged(clean_dir, tmp_path):
    """The table raised so that the lowest capsule point of the motion is 5 mm under it."""
    root = _copy(clean_dir, tmp_path / "r")
    _, _, hand = _posed(root)
    low = np.minimum(hand.a[..., 2], hand.b[..., 2]) - hand.radius                # (T, L)
    t, li = np.unravel_index(int(np.argmin(low)), low.shape)
    _edit_scene(root, "environment", "table_height", float(low[t, li]) + 0.005)
    s = check_result(root).solutions[0]
    fig = s.figures["table_penetration_m"]
    assert not fig.ok and fig.value == pytest.approx(0.005, abs=1e-9)
    assert (fig.frame, fig.where) == (t, f"right/{hand.model.link_names[li]}")
    assert s.failure().startswith("sol_000: ") and f"table penetration 5.0 mm at frame {t}" in s.failure()


def test_hand_pushed_into_the_object_is_flagged(clean_dir, tmp_path):
    """At one frame the wrist moves 8 mm along the inward mesh normal at a contact: that link goes into the box."""
    root = _copy(clean_dir, tmp_path / "r")
    result, sol, _ = _posed(root)
    t, k = np.argwhere(sol.contact_mask)[len(np.argwhere(sol.contact_mask)) // 2]
    n = _inward_normal(result.scene.object.mesh, sol.object_pose[t], sol.contact_point[t, k])
    root_pose = sol.root_pose.copy()
    root_pose[t, :3, 3] += 0.008 * n
    _edit_npz(root / "solutions" / "sol_000.npz", root_pose=root_pose)
    fig = check_result(root).solutions[0].figures["object_penetration_m"]
    assert not fig.ok and fig.frame == t and fig.value > 0.005


def test_force_outside_its_cone_is_flagged_and_inside_is_not(clean_dir, tmp_path):
    """Every force zeroed but one hand force of 2 N: along the mesh's inward normal it passes, pulling it fails
    with a violation of 2 N over the frame's largest force (2 N)."""
    root = _copy(clean_dir, tmp_path / "r")
    result, sol, _ = _posed(root)
    t, k = np.argwhere(sol.contact_mask)[0]
    n = _inward_normal(result.scene.object.mesh, sol.object_pose[t], sol.contact_point[t, k])
    f = np.zeros_like(sol.contact_force)
    env = np.zeros_like(sol.env_contact_force)
    f[t, k] = 2.0 * n                                                           # pushing along the normal
    _edit_npz(root / "solutions" / "sol_000.npz", contact_force=f, env_contact_force=env)
    fig = check_result(root).solutions[0].figures["cone_violation"]
    assert fig.ok and fig.value == 0.0
    f[t, k] = -2.0 * n                                                          # pulling
    _edit_npz(root / "solutions" / "sol_000.npz", contact_force=f)
    s = check_result(root).solutions[0]
    fig = s.figures["cone_violation"]
    assert not fig.ok and fig.frame == t and fig.where.startswith(f"contact {k}, right/")
    assert fig.value == pytest.approx(1.0, abs=1e-12)
    assert f"cone violation 1 at frame {t} (contact {k}, right/" in s.failure()


def test_wrong_object_mass_is_flagged(clean_dir, clean_report, tmp_path):
    """Twice the mass in scene.toml: the forces no longer carry the object (error about half its weight)."""
    root = _copy(clean_dir, tmp_path / "r")
    _edit_scene(root, "object", "mass", 2 * tomllib.loads((root / "scene" / "scene.toml").read_text())["object"]
                ["mass"])
    s = check_result(root).solutions[0]
    assert not s.figures["force_error"].ok and s.figures["force_error"].value > 0.3
    assert "force error" in s.failure()
    assert clean_report.solutions[0].figures["force_error"].value < 0.3


def test_joint_jump_is_flagged(clean_dir, tmp_path):
    """The hand held still in its first pose but one joint 40 degrees off at one frame: the speed is 40 deg x fps
    (first at that frame), the acceleration twice that x fps (at that frame), both named."""
    root = _copy(clean_dir, tmp_path / "r")
    data = _load(root / "solutions" / "sol_000.npz")
    j = [str(n) for n in data["joint_names"]].index("index_pip")
    T = data["q"].shape[0]
    t = T // 2
    q = np.repeat(data["q"][:1], T, axis=0)
    q[t, j] += np.radians(40.0)
    _edit_npz(root / "solutions" / "sol_000.npz", q=q)
    s = check_result(root).solutions[0]
    speed, acc = s.figures["joint_speed_rad_s"], s.figures["joint_acceleration_rad_s2"]
    assert not speed.ok and (speed.where, speed.frame) == ("right/index_pip", t)
    assert speed.value == pytest.approx(np.radians(40) * 30, rel=1e-9)
    assert not acc.ok and (acc.where, acc.frame) == ("right/index_pip", t)
    assert acc.value == pytest.approx(2 * np.radians(40) * 900, rel=1e-9)
    assert "joint speed" in s.failure() and "joint acceleration" in s.failure()


def test_duplicated_solution_is_flagged(clean_dir, tmp_path):
    root = _copy(clean_dir, tmp_path / "r", solutions=(0, 0))
    report = check_result(root)
    first, dup = report.solutions
    assert "distinct_deg" not in first.figures
    fig = dup.figures["distinct_deg"]
    assert not fig.ok and fig.value == 0.0 and fig.where == "sol_000"
    assert report.failures[-1].startswith("sol_001: duplicate of sol_000")


# --- the numbers against references nobody here wrote ---------------------------------------------------------

def test_capsule_figures_match_mujoco_for_one_frame(clean_dir):
    """MuJoCo's capsule-box and capsule-capsule distances for the frame of deepest contact, hand.xml loaded as is
    with the box added as a mocap body: object depths never above MuJoCo's and within half the 1 mm axis spacing
    of them (the signed distance is 1-Lipschitz), finger pairs and the table exactly."""
    mujoco = pytest.importorskip("mujoco")
    result, sol, hand = _posed(clean_dir)
    obj = object_mesh(result.scene.object.mesh, result.scene.object.mass)
    depth = object_depth(hand, obj, sol.object_pose)
    t = int(np.nanargmax(np.nanmax(np.where(np.isnan(depth), -1, depth), axis=1)))
    half = result.scene.object.mesh.extents / 2
    assert np.allclose(result.scene.object.mesh.bounds, [-half, half])           # box-turn's mesh: a centred box
    xml = (clean_dir / "hand.xml").read_text().replace(
        "<worldbody>", f'<worldbody><body name="box" mocap="true"><geom name="box" type="box" '
                       f'size="{half[0]} {half[1]} {half[2]}"/></body>', 1)
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, sol.root_pose[t, :3, :3].reshape(-1))
    d.qpos[:7] = np.concatenate([sol.root_pose[t, :3, 3], quat])
    for j, name in enumerate(hand.model.joint_names):
        d.qpos[m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)]] = hand.q[t, j]
    mujoco.mju_mat2Quat(quat, sol.object_pose[t, :3, :3].reshape(-1))
    d.mocap_pos[0], d.mocap_quat[0] = sol.object_pose[t, :3, 3], quat
    mujoco.mj_kinematics(m, d)
    box = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "box")
    geom = {mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, int(m.geom_bodyid[g])): g for g in range(m.ngeom)
            if g != box}
    fromto = np.zeros(6)
    ref = np.array([-mujoco.mj_geomDistance(m, d, geom[name], box, 0.05, fromto) for name in hand.model.link_names])
    assert ref.max() > 0                                                         # a frame with some contact
    ours = np.nan_to_num(depth[t], nan=-1.0)
    # MuJoCo's capsule-box distance is exact to a few nanometres
    assert (ours <= ref + 1e-8).all(), (ours, ref)
    ours, ref = np.maximum(ours, 0.0), np.maximum(ref, 0.0)                      # depths; clearances are 0
    assert (ours >= ref - 5e-4 - 1e-8).all(), (ours, ref)
    pairs = finger_pairs(hand.model)
    ours = finger_depth(hand, pairs)[t]
    ref = [-mujoco.mj_geomDistance(m, d, geom[hand.model.link_names[a]], geom[hand.model.link_names[b]], 0.2,
                                   fromto) for a, b in pairs]
    np.testing.assert_allclose(ours, ref, atol=1e-9)
    lows = []
    for li, name in enumerate(hand.model.link_names):
        g = geom[name]
        axis = d.geom_xmat[g].reshape(3, 3)[:, 2]
        lows.append(d.geom_xpos[g][2] - abs(axis[2]) * m.geom_size[g][1] - m.geom_size[g][0])
    np.testing.assert_allclose(table_depth(hand, 0.75)[t], 0.75 - np.array(lows), atol=1e-9)


def test_capsule_depths_bound_the_surface_samples(clean_dir):
    """trimesh's signed distance of the hand's surface samples (hand.sample_points, on the capsules' surfaces)
    never exceeds the capsule depth of their link where it penetrates (a negative depth is the clearance of the
    axis points measured, not a bound: then no sample is inside), and comes within the samples' spacing of it."""
    result, sol, hand = _posed(clean_dir)
    obj = object_mesh(result.scene.object.mesh, result.scene.object.mass)
    depth = object_depth(hand, obj, sol.object_pose)
    model = hand.model
    pts, link = model.sample_points.numpy(), model.sample_link.numpy()
    for t in np.unique(np.nonzero(np.nan_to_num(depth, nan=-1) > -0.001)[0])[:8]:
        P = hand.link_pose[t, link]
        world = np.einsum("sij,sj->si", P[:, :3, :3], pts) + P[:, :3, 3]
        inv = np.linalg.inv(sol.object_pose[t])
        sd = trimesh.proximity.signed_distance(result.scene.object.mesh, world @ inv[:3, :3].T + inv[:3, 3])
        for li in np.nonzero(~np.isnan(depth[t]))[0]:
            s = sd[link == li].max()
            assert s <= max(depth[t, li], 0.0) + 1e-9, (t, li, s, depth[t, li])
            if depth[t, li] > 0:
                assert s >= depth[t, li] - 2e-3, (t, li, s, depth[t, li])


def test_segment_distance_against_bounded_least_squares():
    """The closed form against SciPy's bounded least squares min |p1 + s d1 - p2 - t d2| over 0 <= s, t <= 1."""
    from scipy.optimize import lsq_linear

    gen = np.random.default_rng(0)
    p1, q1, p2, q2 = (gen.normal(size=(200, 3)) for _ in range(4))
    q1[:20] = p1[:20]                                                  # a point against a segment
    q2[20:40] = p2[20:40] + 0.5 * (q1[20:40] - p1[20:40])              # parallel segments
    q1[40:50], q2[40:50] = p1[40:50], p2[40:50]                        # two points
    ref = np.array([np.linalg.norm(lsq_linear(np.stack([q1[i] - p1[i], p2[i] - q2[i]], 1), p2[i] - p1[i],
                                              bounds=(0.0, 1.0), method="bvls").fun) for i in range(200)])
    np.testing.assert_allclose(segment_segment_distance(p1, q1, p2, q2), ref, atol=1e-12)


@pytest.mark.parametrize("mesh", [torchhand.load_scene("box-turn").object.mesh, trimesh.creation.icosphere(3, 0.04),
                                  trimesh.creation.capsule(0.05, 0.02, count=[16, 16])],
                         ids=["box", "icosphere", "capsule"])
def test_signed_distance_matches_trimesh(mesh):
    """Distances equal the minimum over every triangle (trimesh.triangles.closest_point); signs equal
    trimesh.proximity.signed_distance's (positive inside)."""
    from trimesh.triangles import closest_point as triangle_closest_point

    obj = object_mesh(mesh, 1.0)
    pts = np.random.default_rng(1).uniform(mesh.bounds[0] - 0.01, mesh.bounds[1] + 0.01, size=(400, 3))
    tris = np.tile(mesh.triangles, (len(pts), 1, 1))
    query = np.repeat(pts, len(mesh.triangles), axis=0)
    brute = np.linalg.norm(triangle_closest_point(tris, query) - query, axis=-1).reshape(len(pts), -1).min(1)
    sd = obj.signed_distance(pts)
    np.testing.assert_allclose(np.abs(sd), brute, atol=1e-12)
    ref = trimesh.proximity.signed_distance(mesh, pts)
    far = np.abs(ref) > 1e-6
    assert (np.sign(sd[far]) == np.sign(ref[far])).all()


def test_small_meshes_searched_whole_give_the_bounded_searchs_answer(monkeypatch):
    """318 points against a box (12 triangles) are searched whole by ObjectMesh.closest; the bounded search (forced by
    a threshold of 0)
    gives the same closest points, distances and triangles, bit for bit, including points equidistant from two faces
    (on the box's diagonal planes, where the lower triangle index must win in both)."""
    import torchhand.check.geometry as geometry

    mesh = torchhand.load_scene("box-turn").object.mesh
    obj = object_mesh(mesh, 1.0)
    gen = np.random.default_rng(3)
    pts = gen.uniform(mesh.bounds[0] - 0.01, mesh.bounds[1] + 0.01, size=(250, 3))
    c = 0.5 * (mesh.bounds[0] + mesh.bounds[1])
    diag = c + gen.uniform(-0.01, 0.01, size=(60, 1)) * np.array([1.0, 1.0, 0.0]) + np.array([0.0, 0.0, 0.001])
    pts = np.concatenate([pts, diag, mesh.vertices])
    assert len(mesh.triangles) * len(pts) <= geometry.BRUTE_PAIRS
    whole = obj.closest(pts)
    monkeypatch.setattr(geometry, "BRUTE_PAIRS", 0)
    bounded = obj.closest(pts)
    for a, b in zip(whole, bounded):
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes()


def test_two_hands_get_a_hand_hand_figure(tmp_path):
    """A two-hand result (the render tests' hand-written fixture): the hand-hand figure names a pair of links of
    the two hands, and its value matches densely sampled capsule axes."""
    from tests.render.fixture_result import write_fixture_result

    root = write_fixture_result(tmp_path / "two", "two-hand-box", frames=4, solutions=1)
    report = check_result(root)
    fig = report.solutions[0].figures["hand_penetration_m"]
    first, second = fig.where.split(" - ")
    assert first.startswith("right/") and second.startswith("left/")
    result = torchhand.load_result(root)
    sol = result.solution(0)
    posed = {h.side: pose_hand(result.hand_models[h.side], h.side, h.q, h.joint_names, h.root_pose, sol.path)
             for h in sol.hands}
    (r, lr), (l, ll) = [(posed[w.split("/")[0]], posed[w.split("/")[0]].model.link_index(w.split("/")[1]))
                        for w in (first, second)]
    s = np.linspace(0.0, 1.0, 4001)[:, None]
    a = r.a[fig.frame, lr] + s * (r.b[fig.frame, lr] - r.a[fig.frame, lr])
    b = l.a[fig.frame, ll] + s * (l.b[fig.frame, ll] - l.a[fig.frame, ll])
    d = min(np.linalg.norm(a[i] - b, axis=-1).min() for i in range(len(a)))
    assert fig.value == pytest.approx(max(r.radius[lr] + l.radius[ll] - d, 0.0), abs=2e-5)


def test_edge_normal_cone():
    """At a box edge, a force along the bisector of the two faces is inside the cone of the edge (mu = 0) though
    outside either face's own cone; on a face only that face's normal counts."""
    obj = object_mesh(trimesh.creation.box(extents=(0.1, 0.1, 0.1)), 1.0)
    edge = np.array([[0.05, 0.0, 0.05]])                                # on the edge of the +x and +z faces
    closest, _, tri = obj.closest(edge)
    (cone,) = obj.normal_cone(closest, tri, 5e-4)
    assert len(cone) == 2
    f = np.array([-1.0, 0.0, -1.0])                                     # pushing in along the bisector
    assert cone_violation(f, cone, 0.0) == pytest.approx(0.0, abs=1e-12)
    assert min(float(violation(f, n, 0.0)) for n in cone) > 0.5
    face = np.array([[0.05, 0.0, 0.0]])
    closest, _, tri = obj.closest(face)
    (cone,) = obj.normal_cone(closest, tri, 5e-4)
    np.testing.assert_allclose(cone, [[-1.0, 0.0, 0.0]], atol=1e-12)


# --- limits, CLI, bad input, partial runs, the import boundary ------------------------------------------------

def test_limits_override_and_unknown_name(clean_dir, tmp_path):
    root = _copy(clean_dir, tmp_path / "r")
    s = check_result(root, limits={"joint_speed_rad_s": 1e-9, "joint_acceleration_rad_s2": 1e9}).solutions[0]
    assert not s.figures["joint_speed_rad_s"].ok and s.figures["joint_acceleration_rad_s2"].ok
    with pytest.raises(UnknownNameError, match="penetration_mm"):
        check_result(root, limits={"penetration_mm": 2.0})
    assert dict(LIMITS)["joint_acceleration_rad_s2"] is None
    with pytest.raises(TypeError):
        LIMITS["cone_violation"] = 1.0


@pytest.fixture(scope="module")
def fast_dir(tmp_path_factory) -> Path:
    """A hand-written one-solution result (4 frames at 30 fps) whose flexion joints turn 1 rad over 3 frames, a joint
    speed of 10 rad/s, and whose stats.json claims ``max_joint_speed`` 20."""
    from tests.render.fixture_result import write_fixture_result

    root = write_fixture_result(tmp_path_factory.mktemp("fast") / "r", "box-turn", frames=4, solutions=1, q_ramp=1.0)
    stats = json.loads((root / "stats.json").read_text())
    (root / "stats.json").write_text(json.dumps(dict(stats, max_joint_speed=20.0)))
    return root


def _limit_cell(table: str, header: str) -> str:
    """The limit row's entry under a column of the printed table (columns are right-aligned)."""
    lines = table.splitlines()
    head = next(ln for ln in lines if ln.startswith("solution"))
    row = next(ln for ln in lines if ln.startswith("limit "))
    end = (head + " ").index(f" {header} ") + 1 + len(header)
    return row[:end].split()[-1]


def test_stats_max_joint_speed_sets_no_limit(fast_dir, tmp_path):
    """stats.json's max_joint_speed (20) is the method's own bound: the checker keeps 8 rad/s, and does not even
    read it (a malformed value is no error)."""
    report = check_result(fast_dir)
    fig = report.solutions[0].figures["joint_speed_rad_s"]
    assert fig.value == pytest.approx(10.0, rel=1e-9) and fig.limit == 8.0 and not fig.ok
    assert report.limits["joint_speed_rad_s"] == 8.0 == LIMITS["joint_speed_rad_s"]
    assert "joint speed 10 rad/s" in report.failures[0] and "> 8 rad/s" in report.failures[0]
    root = shutil.copytree(fast_dir, tmp_path / "r")
    stats = json.loads((root / "stats.json").read_text())
    (root / "stats.json").write_text(json.dumps(dict(stats, max_joint_speed="fast")))
    assert check_result(root).limits["joint_speed_rad_s"] == 8.0


def test_cli_limit_overrides_and_is_shown(fast_dir, tmp_path, capsys):
    """--limit joint_speed_rad_s=12 passes the 10 rad/s motion; the limit row and the JSON report show 12 (and the
    acceleration's default follows it: 2 x 12 x 30); the last --limit of a name counts."""
    out = tmp_path / "report.json"
    cli(["check", str(fast_dir), "--json", str(out), "--no-progress"])
    text = capsys.readouterr().out
    assert _limit_cell(text, "rad/s") == "8.0" and "10.0*" in text
    assert json.loads(out.read_text())["solutions"][0]["figures"]["joint_speed_rad_s"]["ok"] is False
    cli(["check", str(fast_dir), "--limit", "joint_speed_rad_s=12", "--json", str(out), "--no-progress"])
    text = capsys.readouterr().out
    data = json.loads(out.read_text())
    assert data["limits"]["joint_speed_rad_s"] == 12.0 and data["limits"]["joint_acceleration_rad_s2"] == 720.0
    fig = data["solutions"][0]["figures"]["joint_speed_rad_s"]
    assert fig["ok"] is True and fig["limit"] == 12.0 and fig["value"] == pytest.approx(10.0, rel=1e-9)
    assert _limit_cell(text, "rad/s") == "12.0" and _limit_cell(text, "rad/s2") == "720"
    assert "joint speed" not in "".join(data["failures"])
    cli(["check", str(fast_dir), "--limit", "joint_speed_rad_s=12", "--limit", "joint_speed_rad_s=9",
         "--limit", "joint_acceleration_rad_s2=default", "--limit", "distinct_deg=1", "--json", str(out),
         "--no-progress"])
    capsys.readouterr()
    limits = json.loads(out.read_text())["limits"]
    assert limits["joint_speed_rad_s"] == 9.0 and limits["joint_acceleration_rad_s2"] == 2 * 9.0 * 30
    assert limits["distinct_deg"] == 1.0


@pytest.mark.parametrize("value, said", [
    ("joint_speed_rad_s", "--limit: expected NAME=VALUE, got 'joint_speed_rad_s'"),
    ("speed=12", "--limit: unknown figure 'speed'"),
    ("joint_speed_rad_s=fast", "--limit joint_speed_rad_s: expected a number >= 0 or 'default', got 'fast'"),
    ("joint_speed_rad_s=-1", "--limit joint_speed_rad_s: expected a finite number >= 0, got '-1'"),
    ("force_error=nan", "--limit force_error: expected a finite number >= 0, got 'nan'"),
])
def test_bad_limit_exits_2_and_writes_nothing(fast_dir, tmp_path, capsys, value, said):
    out = tmp_path / "report.json"
    assert cli(["check", str(fast_dir), "--limit", value, "--json", str(out), "--no-progress"]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("torchhand: error: ") and said in err[0], err
    assert captured.out == "" and list(tmp_path.iterdir()) == []


def test_cli_json_and_exit_codes(clean_dir, tmp_path, capsys):
    root = _copy(clean_dir, tmp_path / "r", solutions=(0, 0))
    out = tmp_path / "report.json"
    rc = cli(["check", str(root), "--json", str(out), "--no-progress"])
    text = capsys.readouterr().out
    data = json.loads(out.read_text())
    assert rc == 1 and data["passed"] is False and not list(tmp_path.glob(".report.json.*"))
    assert [s["index"] for s in data["solutions"]] == [0, 1]
    assert data["solutions"][1]["figures"]["distinct_deg"] == {"value": 0.0, "limit": 2.0, "frame": None,
                                                              "where": "sol_000", "ok": False}
    assert data["failures"][-1].startswith("sol_001: duplicate of sol_000")
    assert "sol_001: duplicate of sol_000" in text and "FAIL: " in text and "complete run" in text
    single = _copy(clean_dir, tmp_path / "one")
    rc = cli(["check", str(single), "--no-progress"])
    assert rc == (0 if check_result(single).passed else 1)


def test_bad_input_exits_2_with_one_line(clean_dir, tmp_path, capsys):
    assert cli(["check", str(tmp_path / "missing")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("torchhand: error:") and "missing" in err[0]
    root = _copy(clean_dir, tmp_path / "r")
    (root / "solutions" / "sol_000.npz").write_bytes(b"not an npz")
    assert cli(["check", str(root), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("torchhand: error:") and "sol_000.npz" in err[0]
    with pytest.raises(FileFormatError):
        check_result(root)
    with pytest.raises(MissingFileError):
        check_result(tmp_path / "missing")


def test_partial_run_is_checked_and_said(clean_dir, tmp_path, capsys):
    root = _copy(clean_dir, tmp_path / "r")
    stats = json.loads((root / "stats.json").read_text())
    (root / "stats.json").write_text(json.dumps(dict(stats, complete=False)))
    report = check_result(root)
    assert not report.complete and len(report.solutions) == 1
    cli(["check", str(root), "--no-progress"])
    assert "partial run" in capsys.readouterr().out


def test_checker_does_not_import_the_synthesis(clean_dir, tmp_path):
    root = _copy(clean_dir, tmp_path / "r")
    code = ("import sys; from torchhand.check import check_result; r = check_result(sys.argv[1]); "
            "assert len(r.solutions) == 1; "
            "bad = sorted(m for m in sys.modules if m.startswith('torchhand.synthesis')); "
            "assert not bad, bad; print('ok')")
    run = subprocess.run([sys.executable, "-c", code, str(root)], capture_output=True, text=True, cwd=REPO)
    assert run.returncode == 0 and run.stdout.strip() == "ok", run.stderr


def test_mjcf_depth_asks_trimesh_only_inside_the_bounding_box():
    """The depth of surface points into a geom or object mesh (``mjcf_geometry._depth_into``) against trimesh's
    signed distance of all the points: equal whenever a point is inside (the depth is exact); otherwise at least the
    true value and at most 0 (a lower bound of the clearance). Point clouds around a rotated box and a sphere, some
    reaching inside, some not."""
    from torchhand.check.mjcf_geometry import _depth_into

    rng = np.random.default_rng(5)
    box = trimesh.creation.box(extents=(0.03, 0.02, 0.01))
    box.apply_transform(trimesh.transformations.rotation_matrix(0.7, (1.0, 2.0, 0.5)))
    meshes = [box, trimesh.creation.icosphere(subdivisions=3, radius=0.012)]
    inside = outside = 0
    for mesh in meshes:
        for k in range(40):
            centre = rng.normal(scale=0.02, size=3)
            pts = centre + rng.normal(scale=0.004, size=(50, 3))
            ours = _depth_into(mesh, pts)
            truth = float(trimesh.proximity.signed_distance(mesh, pts).max())
            if truth > 0:
                inside += 1
                assert ours == pytest.approx(truth, abs=1e-12)
            else:
                outside += 1
                assert truth - 1e-12 <= ours <= 0.0
    assert inside >= 10 and outside >= 10


def test_signed_distance_sign_survives_a_flipped_face_region():
    """The nearest face's plane decides inside/outside only where the ray test agrees; where they disagree (a
    defective mesh: here a second, inside-out cube), the exact winding number does."""
    import trimesh

    from torchhand.check.geometry import winding_number

    good = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    bad = trimesh.creation.box(extents=(0.04, 0.04, 0.04))
    bad.apply_translation((0.2, 0.0, 0.0))
    bad.invert()                                                          # normals point in
    mesh = trimesh.util.concatenate([good, bad])
    obj = object_mesh(mesh, 1.0)
    pts = np.array([[0.0, 0.0, 0.0],            # inside the good cube
                    [0.2 + 0.03, 0.0, 0.0],     # outside the inverted cube, 1 cm from its face
                    [0.0, 0.0, 0.08]])          # outside both
    np.testing.assert_allclose(winding_number(mesh.triangles.view(np.ndarray), pts), [1.0, 0.0, 0.0], atol=1e-9)
    sd = obj.signed_distance(pts)                                         # positive inside
    assert sd[0] > 0 and sd[1] < 0 and sd[2] < 0
    np.testing.assert_allclose(np.abs(sd), [0.05, 0.01, 0.03], atol=1e-12)


def test_a_table_force_off_the_table_is_flagged(clean_dir, tmp_path):
    """A table contact point lifted 5 mm off the table plane fails table_contact_m; on it, the figure is 0."""
    root = _copy(clean_dir, tmp_path / "r")
    _, sol, _ = _posed(root)
    assert check_result(root).solutions[0].figures["table_contact_m"].value < 1e-6
    t, e = np.argwhere(sol.env_contact_mask)[0]
    p = sol.env_contact_point.copy()
    p[t, e, 2] += 0.005
    _edit_npz(root / "solutions" / "sol_000.npz", env_contact_point=p)
    fig = check_result(root).solutions[0].figures["table_contact_m"]
    assert not fig.ok and fig.value == pytest.approx(0.005, abs=1e-6)
    assert (fig.frame, fig.where) == (t, f"table contact {e}")


@pytest.mark.parametrize("name", ["fandisk.obj", "sphere.ply", "bunny.ply", "teapot.stl"])
def test_crossing_test_on_real_meshes(name):
    """Inside/outside by rays both ways (``check.crossing``) on real meshes from ../shared/data, for points spread
    over the bounding box and points within about 1 mm of the surface (farther than 1e-6 m from it). On the closed
    ones (fandisk, sphere) it is the exact generalized winding number's verdict at every point. On the open ones
    (the bunny's and the teapot's holes) the rays' verdict is trimesh's ray test (the same direction) wherever
    trimesh's two rays agree; where trimesh differs (it retries a random direction when its rays disagree) ours is
    the winding number's. Deterministic."""
    from torchhand.check.crossing import CrossingTest, winding_number

    mesh = trimesh.load(shared_path("meshes", "trimesh", name), force="mesh")
    gen = np.random.default_rng(2)
    lo, hi = mesh.bounds
    pts = lo - 0.1 * (hi - lo) + gen.random((600, 3)) * 1.2 * (hi - lo)
    surface, _ = trimesh.sample.sample_surface(mesh, 400, seed=3)
    pts = np.concatenate([pts, surface + gen.normal(scale=0.005 * mesh.scale, size=surface.shape)])
    pts = pts[np.abs(trimesh.proximity.closest_point(mesh, pts)[1]) > 1e-6]
    test = CrossingTest(mesh.triangles.view(np.ndarray))
    ours = test.contains(pts)
    assert np.array_equal(ours, test.contains(pts))                          # deterministic
    wn = winding_number(mesh.triangles.view(np.ndarray), pts) > 0.5
    if mesh.is_watertight:
        assert np.array_equal(ours, wn), np.nonzero(ours != wn)[0][:10]
    else:
        other = np.nonzero(ours != mesh.ray.contains_points(pts))[0]
        assert np.array_equal(ours[other], wn[other]), other[ours[other] != wn[other]]
    assert 50 <= int(wn.sum()) <= len(pts) - 50


def test_closest_on_a_scan_is_the_nearest_of_every_triangle():
    """ObjectMesh.closest on the bunny scan (16301 triangles; its candidates come from the centroids' k-d tree) for
    points near the surface and up to 10 cm away: the distance equals the minimum over every triangle (trimesh's
    point-triangle distance) to 1e-15 m, on a triangle at that distance."""
    from trimesh.triangles import closest_point as triangle_closest_point

    mesh = trimesh.load(shared_path("meshes", "trimesh", "bunny.ply"), force="mesh")
    obj = object_mesh(mesh, 1.0)
    gen = np.random.default_rng(4)
    surface, _ = trimesh.sample.sample_surface(mesh, 150, seed=5)
    pts = np.concatenate([surface + gen.normal(scale=2e-3, size=surface.shape),
                          mesh.bounds.mean(0) + gen.normal(scale=0.1, size=(50, 3))])
    _, dist, tri = obj.closest(pts)
    tris = mesh.triangles.view(np.ndarray)
    for i, p in enumerate(pts):
        d = np.linalg.norm(triangle_closest_point(tris, np.repeat(p[None], len(tris), 0)) - p, axis=-1)
        assert dist[i] == pytest.approx(d.min(), abs=1e-15)
        assert d[tri[i]] == d.min()
