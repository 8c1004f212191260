"""Contact-sampling synthesis (torchhand.synthesis): wrench, node test, search determinism, the end-to-end run on a
built-in scene checked with exact geometry, the result-directory contract, and bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

import torchhand
from torchhand.cli import main as cli
from torchhand.check import check_result
from torchhand.synthesis.node_test import Guides, NodeTestSettings, pad_points, run_node_test
from torchhand.synthesis.problem import build_problem, required_wrench

G = 9.81
MUG_NODES = 20000   # node tests for the ManipNet mug segment (docs/synthesis.md, BENCHMARKS.md)


# --- the required wrench (Newton–Euler) against a closed form -------------------------------------------------

def test_required_wrench_spinning_and_falling_box():
    """A box spinning at constant omega about a tilted axis while its COM accelerates: F = m (a - g),
    tau = omega x I_w omega (alpha = 0), from finite differences of the poses."""
    fps, T, m = 240.0, 40, 0.5
    inertia = torch.diag(torch.tensor([0.002, 0.003, 0.004], dtype=torch.float64))
    axis = torch.tensor([0.3, -0.2, 0.9], dtype=torch.float64)
    axis = axis / axis.norm()
    w = 2.0
    t = torch.arange(T, dtype=torch.float64) / fps
    R = torch.as_tensor(Rotation.from_rotvec((w * t[:, None] * axis).numpy()).as_matrix())
    acc = torch.tensor([0.5, 0.0, -1.0], dtype=torch.float64)
    pose = torch.eye(4, dtype=torch.float64).repeat(T, 1, 1)
    pose[:, :3, :3] = R
    pose[:, :3, 3] = 0.5 * acc * t[:, None] ** 2
    g = torch.tensor([0, 0, -G], dtype=torch.float64)
    com, wrench = required_wrench(pose, torch.zeros(3, dtype=torch.float64), m, inertia, g, fps)
    torch.testing.assert_close(wrench[:, :3], (m * (acc - g)).expand(T, 3), atol=1e-6, rtol=0)
    omega = w * axis
    Iw = R @ inertia @ R.transpose(-1, -2)
    expected = torch.cross(omega.expand(T, 3), (Iw @ omega), dim=-1)
    torch.testing.assert_close(wrench[2:-2, 3:], expected[2:-2], atol=1e-6, rtol=1e-4)


# --- the node test on a built-in scene ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def box_turn_problem():
    scene = torchhand.load_scene("box-turn")
    return scene, build_problem(scene, torch.Generator().manual_seed(0))


def test_free_hand_is_feasible_while_the_box_rests(box_turn_problem):
    """Before the box moves the table carries it: a hand with no guiding points passes (B = 1 and B = 7)."""
    _, p = box_turn_problem
    hand = p.hands[0]
    for N in (1, 7):
        guides = Guides(torch.zeros(N, 1, 5, dtype=torch.bool), hand.distal_link.expand(N, 1, 5).clone(),
                        pad_points(hand).expand(N, 1, 5, 3).clone(), torch.zeros(N, 1, 5, 3),
                        torch.zeros(N, 1, 5, 3))
        res = run_node_test(p, torch.full((N,), 5), hand.q_rest.expand(N, 1, -1).clone(),
                         torch.ones(N, dtype=torch.bool), guides)
        assert res.q.shape == (N, 1, hand.num_joints)
        assert bool(res.feasible.all())
        # the table carries the weight: the env forces add up to m g
        total = res.env_force.sum(1)
        torch.testing.assert_close(total[:, 2], torch.full((N,), p.weight), atol=1e-3 * p.weight, rtol=0)


def test_guided_fingertip_reaches_its_target_within_joint_limits(box_turn_problem):
    """IK puts the guided pad on a pruned patch sample (within ik_tol), inside the joint limits, nail facing out."""
    _, p = box_turn_problem
    hand = p.hands[0]
    # the centre of the box's top face, seen from the index finger at the hold
    top = torch.tensor([[0.0, 0.0, 0.03]])
    N = 1
    active = torch.zeros(N, 1, 5, dtype=torch.bool)
    active[0, 0, 1] = True
    obj = torch.zeros(N, 1, 5, 3)
    obj[0, 0, 1] = top[0] + torch.tensor([0.02, 0.0, 0.0])
    guides = Guides(active, hand.distal_link.expand(N, 1, 5).clone(), pad_points(hand).expand(N, 1, 5, 3).clone(),
                    obj, torch.zeros(N, 1, 5, 3))
    res = run_node_test(p, torch.tensor([20]), hand.q_rest.expand(N, 1, -1).clone(), torch.ones(N, dtype=torch.bool),
                     guides, dynamics=False)
    lim = hand.joint_limits
    assert bool(((res.q[0, 0] >= lim[:, 0] - 1e-6) & (res.q[0, 0] <= lim[:, 1] + 1e-6)).all())
    if not bool(res.kin_fail[0, 0, 1]):
        assert float(res.guide_err[0, 0, 1]) <= NodeTestSettings().ik_tol
    # a target 30 cm away is unreachable: the finger fails the kinematic test
    far = obj.clone()
    far[0, 0, 1] = torch.tensor([0.3, 0.0, 0.03])
    res = run_node_test(p, torch.tensor([20]), hand.q_rest.expand(N, 1, -1).clone(), torch.ones(N, dtype=torch.bool),
                     Guides(active, guides.link, guides.local, far, guides.slide), dynamics=False)
    assert bool(res.kin_fail[0, 0, 1]) and int(res.cause[0]) == 1


def test_kinematic_verdicts_are_the_node_tests(box_turn_problem):
    """The pruning's kinematic test alone gives the node test's ``kin_fail`` bit for bit, on patch samples of the
    hold (some reachable, some not) and on a single row."""
    from torchhand.synthesis.node_test import kinematic_verdicts

    _, p = box_turn_problem
    hand = p.hands[0]
    N, t = 24, 30
    gen = torch.Generator().manual_seed(5)
    sample = torch.stack([p.patch[0, f, t].nonzero().squeeze(-1)[torch.randint(
        int(p.patch[0, f, t].sum()), (N,), generator=gen)] for f in range(5)], 1)          # (N, 5)
    active = torch.rand(N, 1, 5, generator=gen) < 0.7
    guides = Guides(active, hand.distal_link.expand(N, 1, 5).clone(), pad_points(hand).expand(N, 1, 5, 3).clone(),
                    p.surface[sample][:, None], torch.zeros(N, 1, 5, 3))
    q_prev = hand.q_rest.expand(N, 1, -1).clone()
    first = torch.ones(N, dtype=torch.bool)
    full = run_node_test(p, torch.full((N,), t), q_prev, first, guides, dynamics=False).kin_fail
    assert 0 < int(full.sum()) < int(active.sum())
    assert torch.equal(kinematic_verdicts(p, torch.full((N,), t), q_prev, first, guides), full)
    one = kinematic_verdicts(p, torch.full((1,), t), q_prev[:1], first[:1], guides.rows(torch.tensor([0])))
    assert torch.equal(one, full[:1])


def test_pruning_in_one_call_or_many_keeps_the_same_samples(box_turn_problem):
    """The key frames' candidates are drawn first, then tested: whatever the calls (one per key frame, all at once,
    50 rows) the same samples survive as when each key frame is drawn and tested in turn."""
    from torchhand.synthesis.initial import _draw, _key_frames, _verdicts, prune_patches

    scene, _ = box_turn_problem
    p = build_problem(scene.with_frames(2, 9), torch.Generator().manual_seed(0))     # the approach: 7 key frames
    done = {m: [] for m in ("auto", None, 50)}
    outs = [prune_patches(p, torch.Generator().manual_seed(3), per_finger=40, max_rows=m, progress=done[m].append)
            for m in done]
    _, keys = _key_frames(p, 0.003, 0.05)
    assert done["auto"] == [1] * len(keys) and sum(done[None]) == sum(done[50]) == len(keys)
    gen = torch.Generator().manual_seed(3)
    ref = torch.zeros_like(outs[0].ok)
    tried = 0
    for k, t in enumerate(keys.tolist()):
        sample, active = _draw(p, t, 40, gen)
        if sample.shape[0]:
            good = active & ~_verdicts(p, torch.full((sample.shape[0],), t), sample, active, NodeTestSettings())
            tried += int(active.sum())
            for f in range(p.F):
                ref[k, 0, f, sample[good[:, 0, f], 0, f]] = True
    assert len(keys) > 1 and 0 < int(ref.sum()) < tried
    for out in outs:
        assert torch.equal(out.ok, ref) and torch.equal(out.key_frames, keys)


# --- end to end ------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def box_turn_run(tmp_path_factory):
    """The session's real box-turn result (tests/render/real_result.py: frames 14-37, three solutions within a
    node budget)."""
    from tests.render.real_result import real_box_turn

    return real_box_turn(tmp_path_factory)


def test_synthesize_writes_the_contract(box_turn_run):
    out = box_turn_run
    stats = json.loads((out / "stats.json").read_text())
    for key in ("epsilon", "T", "time_s", "solutions", "dead_ends", "total_frames", "success_frames",
                "success_ratio", "solution_ratio", "nodes_tested", "nodes_per_second", "rejections", "diversity_m"):
        assert key in stats
    assert stats["solutions"] >= 1 and stats["T"] == 24 and stats["complete"] and stats["format_version"] == 1
    assert 0 < stats["solution_ratio"] < stats["success_ratio"] <= 1
    assert (out / "hand.xml").exists() and (out / "scene" / "scene.toml").exists()
    hand = torchhand.default_hand("right")
    sols = sorted((out / "solutions").glob("sol_*.npz"))
    assert len(sols) == stats["solutions"]
    with np.load(sols[0]) as z:
        T, D = 24, hand.num_joints
        assert z["q"].shape == (T, D) and list(z["joint_names"]) == list(hand.joint_names)
        assert z["root_pose"].shape == (T, 4, 4) and z["object_pose"].shape == (T, 4, 4)
        assert float(z["fps"]) == 30.0
        K = z["contact_mask"].shape[1]
        assert K <= 32 and z["contact_link"].shape == (T, K)
        for key in ("contact_point", "contact_normal", "contact_force"):
            assert z[key].shape == (T, K, 3)
        assert ((z["contact_link"] >= 0) == z["contact_mask"]).all()
        assert list(z["contact_link_name"]) == list(hand.link_names)
        E = z["env_contact_mask"].shape[1]
        assert z["env_contact_point"].shape == (T, E, 3) and z["env_contact_force"].shape == (T, E, 3)
        assert z["guiding"].shape == (T, 5) and z["guiding"].dtype == bool
        assert z["guiding"].any() and z["contact_mask"].any()


def test_every_frame_passes_the_exact_checks(box_turn_run):
    """torchhand.check (trimesh's exact distances, not the SDF grid): penetration, contacts, cones, balance,
    joints; the planted defects it must catch are in tests/torchhand/test_check.py."""
    report = check_result(box_turn_run)
    assert report.solutions
    assert report.passed, "\n".join(report.failures)


def test_same_seed_same_solutions(box_turn_problem):
    """Each tree has its own generator stream: the same seed reproduces the search exactly."""
    from torchhand.synthesis.initial import prune_patches
    from torchhand.synthesis.search import SearchSettings, search

    scene = box_turn_problem[0].with_frames(0, 16)
    runs = []
    for _ in range(2):
        gen = torch.Generator().manual_seed(3)
        p = build_problem(scene, gen)
        init = prune_patches(p, gen)
        sols, stats = search(p, init, SearchSettings(trees=4, candidates=6, solutions=2, max_nodes=20000,
                                                     epsilon=3), seed=3)
        runs.append((sols, stats.nodes_tested))
    (a, na), (b, nb) = runs
    assert na == nb and len(a) == len(b) and len(a) >= 1
    for sa, sb in zip(a, b):
        torch.testing.assert_close(sa.q, sb.q)
        assert torch.equal(sa.guiding, sb.guiding)


def test_a_path_completed_as_the_budget_runs_out_is_kept(box_turn_problem):
    """A search whose node budget is spent in the very round that completes a path still returns that path."""
    from torchhand.synthesis.initial import prune_patches
    from torchhand.synthesis.search import SearchSettings, search

    scene = box_turn_problem[0].with_frames(0, 16)

    def run(max_nodes):
        gen = torch.Generator().manual_seed(3)
        p = build_problem(scene, gen)
        return search(p, prune_patches(p, gen), SearchSettings(trees=1, candidates=6, solutions=1,
                                                               max_nodes=max_nodes, epsilon=3), seed=3)

    free, free_stats = run(20000)
    assert len(free) == 1 and free_stats.stopped_by == "solutions"
    tight, tight_stats = run(free_stats.nodes_tested)      # spent by the round that completes the path
    assert tight_stats.stopped_by == "max_nodes" and tight_stats.nodes_tested == free_stats.nodes_tested
    assert len(tight) == 1
    torch.testing.assert_close(tight[0].q, free[0].q)


def test_a_rolling_guide_touches_with_the_capsule_point_facing_its_target(box_turn_problem):
    """A rolling guide's hand point is not fixed: wherever on the distal link it starts (the pad, or behind the
    capsule's proximal end), the finger touches the target within ik_tol with the point of its capsule facing it
    (on the capsule's surface), the same point from either start; held static, either start misses by > 1 cm."""
    from torchhand.synthesis._node_kinematics import rolled_local

    _, p = box_turn_problem
    hand = p.hands[0]
    N, f, t = 1, 2, torch.tensor([20])
    active = torch.zeros(N, 1, 5, dtype=torch.bool)
    active[0, 0, f] = True
    obj = torch.zeros(N, 1, 5, 3)
    obj[0, 0, f] = torch.tensor([0.0, 0.0, 0.03])                    # the centre of the box's top face
    link = hand.distal_link.expand(N, 1, 5).clone()
    d = int(link[0, 0, f])
    a, b, r = hand.capsule_a[d], hand.capsule_b[d], hand.capsule_radius[d]
    ns = NodeTestSettings()
    rolled = []
    for start in (pad_points(hand)[f], a - r * (b - a) / (b - a).norm()):
        local = pad_points(hand).expand(N, 1, 5, 3).clone()
        local[0, 0, f] = start
        static = Guides(active, link, local, obj, torch.zeros(N, 1, 5, 3))
        rolling = Guides(active, link, local, obj, torch.zeros(N, 1, 5, 3), roll=active.clone())
        q0 = hand.q_rest.expand(N, 1, -1).clone()
        first = torch.ones(N, dtype=torch.bool)
        res_s = run_node_test(p, t, q0, first, static, dynamics=False)
        res_r = run_node_test(p, t, q0, first, rolling, dynamics=False)
        assert float(res_s.guide_err[0, 0, f]) > 0.01
        assert float(res_r.guide_err[0, 0, f]) <= ns.ik_tol
        x = rolled_local(p, t, res_r.q, rolling, ns)[0, 0, f].double()
        u = float(((x - a.double()) @ (b - a).double()) / ((b - a).double() @ (b - a).double()))
        axis = a.double() + min(max(u, 0.0), 1.0) * (b - a).double()
        assert abs(float((x - axis).norm()) - float(r)) < 1e-6
        rolled.append(x)
    assert float((rolled[0] - rolled[1]).norm()) < 1e-3


def test_gait_strategy_retries_a_static_contact_that_failed_as_rolling(box_turn_problem):
    """After a kinematic failure of a static finger, ``gait`` resamples it as rolling in some plans (and as static
    or relocating in the others); ``mixed`` never proposes rolling."""
    from torchhand.synthesis.initial import prune_patches
    from torchhand.synthesis.node_test import CAUSE_KINEMATIC, FORCE_INSIDE
    from torchhand.synthesis.search import SearchSettings, _Node, _Search, _Tree

    _, p = box_turn_problem
    init = prune_patches(p, torch.Generator().manual_seed(0), per_finger=8)
    ROLL, STATIC = 4, 0
    kinds = {}
    for strategy in ("gait", "mixed"):
        s = _Search(p, init, SearchSettings(strategy=strategy, candidates=8), NodeTestSettings(), seed=0)
        w = 3
        frames = {"seed_on": torch.ones(w, 1, 5, dtype=torch.bool),
                  "seed_class": torch.full((w, 1, 5), FORCE_INSIDE, dtype=torch.long),
                  "seed_obj": torch.zeros(w, 1, 5, 3)}
        node = _Node(0, w, frames, None, 1, 1)
        node.fail = (CAUSE_KINEMATIC, [1], 0)                     # the index finger failed to keep its contact
        node.template = [(STATIC, -1, 0)] * 5
        tree = _Tree(0, 0)
        kinds[strategy] = [plan[1][0] for _ in range(20) for plan in s._informed(tree, node, w)]
    assert ROLL in kinds["gait"] and ROLL not in kinds["mixed"]


def test_gait_strategy_keeps_a_contact_on_its_cone_boundary_static_where_mixed_slides_it(box_turn_problem):
    """§7's paper cup: under ``gait`` a loaded finger whose force lies on its friction cone's boundary is kept
    static (it may roll later, never slide); ``mixed`` slides such a finger in about half its plans."""
    from torchhand.synthesis.initial import prune_patches
    from torchhand.synthesis.node_test import FORCE_BOUNDARY
    from torchhand.synthesis.search import SearchSettings, _Node, _Search, _Tree

    _, p = box_turn_problem
    init = prune_patches(p, torch.Generator().manual_seed(0), per_finger=8)
    SLIDE, STATIC = 1, 0
    w = 3
    frames = {"seed_on": torch.ones(w, 1, 5, dtype=torch.bool),
              "seed_class": torch.full((w, 1, 5), FORCE_BOUNDARY, dtype=torch.long),
              "seed_obj": torch.zeros(w, 1, 5, 3), "seed_tdir": torch.zeros(w, 1, 5, 3)}
    kinds = {}
    for strategy in ("gait", "mixed"):
        s = _Search(p, init, SearchSettings(strategy=strategy), NodeTestSettings(), seed=0)
        tree = _Tree(0, 0)
        kinds[strategy] = [kind for _ in range(40) for kind, _, _ in s._plan(tree, _Node(0, w, frames, None, 1, 1), w)]
    assert set(kinds["gait"]) == {STATIC}
    assert 0.3 < kinds["mixed"].count(SLIDE) / len(kinds["mixed"]) < 0.7


# --- bad input ---------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("argv,needle", [
    (["synthesize", "no-such-scene", "--out", "X"], "no-such-scene"),
    (["synthesize", "box-turn", "--out", "X", "--frames", "5:2"], "--frames"),
    (["synthesize", "box-turn", "--out", "X", "--solutions", "0"], "--solutions"),
    (["synthesize", "box-turn", "--out", "X", "--time-budget", "-1"], "--time-budget"),
])
def test_bad_input_is_one_line_and_exit_2(argv, needle, tmp_path, capsys):
    argv = [a if a != "X" else str(tmp_path / "out") for a in argv]
    assert cli(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0]
    assert not (tmp_path / "out").exists()          # nothing written for a bad request


def test_infeasible_motion_ends_with_a_report(tmp_path, capsys):
    """An object thrown upward that no hand touches: no solution, exit code 1 and a clear report, quickly."""
    scene = torchhand.load_scene("box-pickup").with_frames(0, 12)
    pose = scene.object_pose.clone()
    pose[:, 2, 3] += 0.5 * torch.arange(12, dtype=torch.float64) ** 2 / 30.0 ** 2 * 40.0   # 4 g upward
    import dataclasses

    bad = dataclasses.replace(scene, object_pose=pose)
    bad.export(tmp_path / "thrown")
    rc = cli(["synthesize", str(tmp_path / "thrown"), "--out", str(tmp_path / "out"), "--max-nodes", "2000",
              "--no-progress"])
    assert rc == 1
    err = capsys.readouterr().err
    assert "no feasible motion" in err


# --- the IK separates by finger; free fingers get out of the object ------------------------------------------------

def test_ik_of_one_finger_ignores_the_other_fingers_targets(box_turn_problem):
    """Every joint moves one finger, so a finger's IK result must not depend on what the other fingers are asked:
    the index finger alone, and the index finger with an unreachable target for the middle finger, give the same
    index-finger joints (per-finger damping and step acceptance)."""
    _, p = box_turn_problem
    hand = p.hands[0]
    N = 2
    active = torch.zeros(N, 1, 5, dtype=torch.bool)
    active[:, 0, 1] = True
    active[1, 0, 2] = True
    obj = torch.zeros(N, 1, 5, 3)
    obj[:, 0, 1] = torch.tensor([0.02, 0.0, 0.03])
    obj[1, 0, 2] = torch.tensor([0.3, 0.0, 0.03])            # 30 cm away: the middle finger cannot get there
    guides = Guides(active, hand.distal_link.expand(N, 1, 5).clone(), pad_points(hand).expand(N, 1, 5, 3).clone(),
                    obj, torch.zeros(N, 1, 5, 3))
    res = run_node_test(p, torch.tensor([20, 20]), hand.q_rest.expand(N, 1, -1).clone(),
                        torch.ones(N, dtype=torch.bool), guides, dynamics=False)
    assert bool(res.kin_fail[1, 0, 2]) and not bool(res.kin_fail[0, 0, 2])
    index_joints = [i for i, n in enumerate(hand.joint_names) if n.startswith("index_")]
    torch.testing.assert_close(res.q[0, 0, index_joints], res.q[1, 0, index_joints], atol=1e-5, rtol=0)
    assert float(res.guide_err[0, 0, 1]) == pytest.approx(float(res.guide_err[1, 0, 1]), abs=1e-5)


def test_free_fingers_started_inside_the_object_are_brought_out(box_turn_problem):
    """A first frame whose starting pose has the fingers flexed deep into the box (the palm is above it) still
    passes the kinematic test: free fingers that stay inside are solved again from the open hand."""
    _, p = box_turn_problem
    hand = p.hands[0]
    from torchhand.hand.collision import hand_object_penetration

    N, t = 1, 30
    flexed = hand.q_rest.clone()
    for i, name in enumerate(hand.joint_names):
        if name.endswith(("mcp_flex", "pip", "dip")) and not name.startswith("thumb"):
            flexed[i] = hand.joint_limits[i, 1]
    pen = hand_object_penetration(hand, hand.forward_kinematics(flexed[None], p.root[0, t:t + 1]), p.sdf,
                                  p.object_pose[t:t + 1])
    depth = -pen.deepest_value[0]
    assert float(depth.max()) > 0.005, "the test needs fingers deep inside the box"
    assert float(depth[0]) <= NodeTestSettings().pen_tol, "... and the palm outside it"
    guides = Guides(torch.zeros(N, 1, 5, dtype=torch.bool), hand.distal_link.expand(N, 1, 5).clone(),
                    pad_points(hand).expand(N, 1, 5, 3).clone(), torch.zeros(N, 1, 5, 3), torch.zeros(N, 1, 5, 3))
    res = run_node_test(p, torch.tensor([t]), flexed.expand(N, 1, -1).clone(), torch.ones(N, dtype=torch.bool),
                        guides, dynamics=False)
    assert int(res.cause[0]) == 0, f"free fingers stayed inside: kin_fail {res.kin_fail.tolist()}"
    assert float(res.penetration[0]) <= NodeTestSettings().pen_tol


def test_release_plan_lets_idle_and_failed_fingers_go(box_turn_problem):
    """After a kinematic failure one candidate releases every finger that failed or carried no force and keeps
    the loaded ones static."""
    from torchhand.synthesis.initial import prune_patches
    from torchhand.synthesis.node_test import FORCE_INSIDE, FORCE_ZERO
    from torchhand.synthesis.search import SearchSettings, _Node, _Search

    _, p = box_turn_problem
    init = prune_patches(p, torch.Generator().manual_seed(0), per_finger=8)
    s = _Search(p, init, SearchSettings(), NodeTestSettings(), seed=0)
    w = 3
    frames = {"seed_on": torch.ones(w, 1, 5, dtype=torch.bool),
              "seed_class": torch.full((w, 1, 5), FORCE_INSIDE, dtype=torch.long)}
    frames["seed_class"][-1, 0, 3] = FORCE_ZERO                # ring finger: no force
    frames["seed_on"][-1, 0, 4] = False                        # little finger: not touching
    node = _Node(0, w, frames, None, 1, 1)
    plan = s._release(node, failed={1})                        # the index finger failed
    kinds = [k for k, _, _ in plan]
    FREE, STATIC = 3, 0
    assert kinds == [STATIC, FREE, STATIC, FREE, FREE]


# --- real motion capture ---------------------------------------------------------------------------------------

def test_manipnet_mug_segment_yields_checked_solutions(tmp_path):
    """Two seconds of ManipNet's mug1 (scene frames 614-674 at 30 fps: the right hand lifts the mug off the table
    and holds it) with the defaults of an imported capture (the slide speed from its noise, the wrist steadied
    within 5 mm and 3 degrees; torchhand.fill.prepare): the search finds motions, every frame passes the exact
    checks, and the files keep the captured wrist beside the used one within the tolerance."""
    from tests.conftest import shared_path
    from torchhand.fill.prepare import prepare_capture
    from torchhand.scene.mocap import manipnet_scene

    root = shared_path("mocap", "manipnet", "mug1")
    scene = manipnet_scene(root, fps=30.0, hands=("right",)).with_frames(614, 674)
    prepared = prepare_capture(scene)
    assert prepared.slide_source == "capture noise" and "right" in prepared.wrist
    result = torchhand.synthesize(prepared.scene, solutions=2, max_nodes=MUG_NODES, seed=0,
                                  node_settings=NodeTestSettings(slide_speed=prepared.slide_speed))
    assert len(result.solutions) >= 1, f"no solution; furthest frame {result.stats.deepest_frame}"
    assert result.solutions[0].q.shape == (60, 30) and result.solutions[0].hand("right").q.shape == (60, 30)
    out = result.save(tmp_path / "mug")
    loaded = torchhand.load_result(out)
    assert np.array_equal(loaded.solutions[0].q, result.solutions[0].q)
    hand = loaded.solutions[0].hand("right")
    np.testing.assert_array_equal(hand.root_pose_captured, scene.hands[0].wrist_pose.numpy())
    moved = np.linalg.norm(hand.root_pose[:, :3, 3] - hand.root_pose_captured[:, :3, 3], axis=-1)
    assert 0 < moved.max() <= 0.005 + 1e-9
    report = check_result(out)
    assert len(report.solutions) == len(result.solutions)
    assert report.passed, "\n".join(report.failures)


def test_edge_proxies_appear_at_an_edge_and_not_on_a_face(box_turn_problem):
    """Area-contact proxies (§7): a fingertip pad lying along the box's top edge gets a proxy on the side face
    (normal turned by ~90 degrees, within reach of the pad); the same pad in the middle of the top face gets
    none. The pad is placed with its distal link's capsule touching the surface at the contact point."""
    import dataclasses

    from torchhand.synthesis.node_test import _edge_proxies

    _, p = box_turn_problem
    hand = p.hands[0]
    t = torch.tensor([0, 0])
    lo, hi = p.surface.amin(0), p.surface.amax(0)                       # the box, object frame
    centre = 0.5 * (lo + hi)
    contact = torch.stack([torch.stack([hi[0] - 0.001, centre[1], hi[2]]),   # 1 mm from the +x top edge
                           torch.stack([centre[0], centre[1], hi[2]])])      # middle of the top face
    T_obj = p.object_pose[0]
    world = (T_obj[:3, :3] @ contact.T).T + T_obj[:3, 3]
    down = -T_obj[:3, 2]                                                  # into the object through the top face
    F, dl = hand.num_fingers, hand.distal_link
    poses = torch.eye(4).repeat(2, hand.num_links, 1, 1)
    a, b, r = hand.capsule_a[dl[1]], hand.capsule_b[dl[1]], hand.capsule_radius[dl[1]]
    # the index distal link's x axis along the edge (object y), its capsule resting on the top face at the contact
    R = torch.stack([T_obj[:3, 1], -T_obj[:3, 0], T_obj[:3, 2]], 1)
    mid = 0.5 * (a + b)
    for n in range(2):
        poses[n, dl[1], :3, :3] = R
        poses[n, dl[1], :3, 3] = world[n] - down * r - R @ mid
    on = torch.zeros(2, F, dtype=torch.bool)
    on[:, 1] = True
    point = torch.zeros(2, F, 3)
    point[:, 1] = world
    normal = torch.zeros(2, F, 3)
    normal[:, 1] = down
    mask, pp, pn, pl = _edge_proxies(p, t, hand, poses, on, point, normal, NodeTestSettings())
    assert bool(mask[0, 1]) and not bool(mask[1, 1])
    assert not bool(mask[:, [0, 2, 3, 4]].any())
    assert float((pn[0, 1] * down).sum()) < 0.5                          # the side face's normal
    side = (T_obj[:3, :3].T @ (pp[0, 1] - T_obj[:3, 3]))
    assert abs(float(side[0] - hi[0])) < 1e-3                             # on the +x face
    # the proxy is a point of the distal link: its local coordinates map back onto it
    back = poses[0, dl[1], :3, :3] @ pl[0, 1] + poses[0, dl[1], :3, 3]
    torch.testing.assert_close(back, pp[0, 1], atol=1e-5, rtol=0)
    off = _edge_proxies(p, t, hand, poses, on, point, normal, dataclasses.replace(NodeTestSettings(), proxy_cos=-2.0))
    assert not bool(off[0].any())
