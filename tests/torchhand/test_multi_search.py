"""Many searches in one batch (torchhand.synthesis.multi): each search's run is the one it has alone.

The searches are small (box-turn's first 16 frames, 4 trees of 6 candidates, a node budget) so that the whole file
runs in a few minutes; the contract is byte-identity, so the comparisons are exact.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import pytest
import torch

import torchhand
from torchhand.cli import main as cli
from torchhand.synthesis.initial import prune_patches
from torchhand.errors import ShapeError
from torchhand.synthesis.multi import MultiStats, SearchTask, node_context, search_lanes, search_many, stack_frames
from torchhand.synthesis.node_test import Guides, NodeTestSettings, run_node_test
from torchhand.synthesis.problem import build_problem
from torchhand.synthesis.search import SearchSettings, search

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))

SETTINGS = SearchSettings(trees=4, candidates=6, solutions=2, max_nodes=600, epsilon=3)
SOLUTION_FIELDS = ("q", "c_mask", "c_local", "c_point", "c_normal", "c_force", "env_force", "guiding", "guide_obj",
                   "guide_link", "guide_local")


@pytest.fixture(scope="module")
def base():
    return torchhand.load_scene("box-turn")


@pytest.fixture(scope="module")
def scene(base):
    return base.with_frames(0, 16)


def _prepared(scene, seed, share=None, device="cpu", dtype=torch.float32):
    gen = torch.Generator().manual_seed(seed)
    problem = build_problem(scene, gen, share=share, device=device, dtype=dtype)
    return problem, prune_patches(problem, gen)


def _assert_same_run(alone, outcome):
    sols, stats = alone
    assert len(sols) == len(outcome.solutions)
    for a, b in zip(sols, outcome.solutions):
        for name in SOLUTION_FIELDS:
            assert torch.equal(getattr(a, name), getattr(b, name)), name
        assert a.tree == b.tree
    ours = outcome.stats
    assert (stats.nodes_tested, stats.dead_ends, stats.rejections, stats.rejections_by_frame, stats.paths_found,
            stats.restarts, stats.deepest_frame, stats.stopped_by) == \
        (ours.nodes_tested, ours.dead_ends, ours.rejections, ours.rejections_by_frame, ours.paths_found,
         ours.restarts, ours.deepest_frame, ours.stopped_by)


def _alone(scene, seeds, device="cpu"):
    out = {}
    for seed in seeds:
        problem, init = _prepared(scene, seed, device=device)
        out[seed] = search(problem, init, SETTINGS, seed=seed)
    return out


def _together(scene, seeds, device="cpu"):
    tasks, share = [], None
    for seed in seeds:
        problem, init = _prepared(scene, seed, share=share, device=device)
        share = share or problem
        tasks.append(SearchTask(problem, init, SETTINGS, seed=seed))
    stats = MultiStats()
    return search_many(tasks, stats=stats), stats


@pytest.fixture(scope="module")
def alone(scene):
    """Seeds 3 and 4 of the clip, each searched alone."""
    return _alone(scene, (3, 4))


def test_searches_in_one_batch_run_as_they_do_alone(scene, alone):
    """Two seeds of one scene share their node-test calls; each finds what it finds alone, bit for bit, with the
    same counters, and the calls are larger than one search's."""
    outcomes, stats = _together(scene, (3, 4))
    assert sum(len(s) for s, _ in alone.values()) >= 2        # the comparison covers found paths, not only dead ends
    for seed, o in zip((3, 4), outcomes):
        _assert_same_run(alone[seed], o)
    assert stats.calls > 0 and sum(stats.batch_sizes) == sum(o.stats.nodes_tested for o in outcomes)
    assert max(stats.batch_sizes) > SETTINGS.trees * SETTINGS.candidates      # more than one search can make


def test_searches_of_different_scenes_are_grouped_not_mixed(scene, alone):
    """Two clips of different length cannot share a call: each forms its own group, and each still runs as alone."""
    other = torchhand.load_scene("box-turn").with_frames(4, 16)
    other_alone = _alone(other, (4,))[4]
    tasks = [SearchTask(*_prepared(sc, seed), SETTINGS, seed=seed) for sc, seed in ((scene, 3), (other, 4))]
    assert node_context(tasks[0].problem) != node_context(tasks[1].problem)
    for a, o in zip((alone[3], other_alone), search_many(tasks)):
        _assert_same_run(a, o)


def test_a_shared_problem_is_the_problem_built_alone(scene):
    """``share=`` reuses the SDF and models of another seed's problem and draws only the seed's samples: every
    field equals the one built without it, and the node-test context is the shared one."""
    first = build_problem(scene, torch.Generator().manual_seed(0))
    gen = torch.Generator().manual_seed(7)
    shared = build_problem(scene, gen, share=first)
    alone = build_problem(scene, torch.Generator().manual_seed(7))
    for f in dataclasses.fields(alone):
        a, b = getattr(alone, f.name), getattr(shared, f.name)
        if isinstance(a, torch.Tensor):
            assert torch.equal(a, b), f.name
    assert torch.equal(alone.sdf.values, shared.sdf.values)
    assert node_context(shared) == node_context(first) != node_context(alone)


OTHER_SPEEDS = NodeTestSettings(slide_speed=0.05, table_slide_speed=2e-3)


def _windows(base, scene):
    """Frames 0-16 (seed 3, default settings) and 4-16 (seed 4, other slide speeds) of box-turn, the second built
    with ``statics=`` from the first (as the windows of a capture), and the second searched alone."""
    other = base.with_frames(4, 16)
    gen = torch.Generator().manual_seed(4)
    fresh = build_problem(other, gen)
    other_alone = search(fresh, prune_patches(fresh, gen, settings=OTHER_SPEEDS), SETTINGS,
                         node_settings=OTHER_SPEEDS, seed=4)
    first, init = _prepared(scene, 3)
    gen = torch.Generator().manual_seed(4)
    second = build_problem(other, gen, statics=first)
    tasks = [SearchTask(first, init, SETTINGS, seed=3),
             SearchTask(second, prune_patches(second, gen, settings=OTHER_SPEEDS), SETTINGS, OTHER_SPEEDS, seed=4)]
    return tasks, other_alone


def test_frame_ranges_of_one_scene_share_calls_and_run_as_alone(base, scene, alone):
    """The windows of a capture: two frame ranges of one scene with their own slide speeds (the capture noise of
    each window) are tested in the same calls, their frames stacked (``stack_frames``) and their speeds per row,
    and each runs as it does alone, bit for bit."""
    tasks, other_alone = _windows(base, scene)
    assert node_context(tasks[0].problem) == node_context(tasks[1].problem)
    stats = MultiStats()
    outcomes = search_many(tasks, stats=stats)
    for a, o in zip((alone[3], other_alone), outcomes):
        _assert_same_run(a, o)
    assert max(stats.batch_sizes) > SETTINGS.trees * SETTINGS.candidates
    assert sum(stats.batch_sizes) == sum(o.stats.nodes_tested for o in outcomes)


def test_a_problem_with_statics_is_the_problem_built_alone(base, scene):
    """``statics=`` (another frame range's problem) reuses its SDF and models and builds the rest: every field equals
    the one built without it; frames of another object are refused."""
    first = build_problem(scene, torch.Generator().manual_seed(0))
    other = base.with_frames(30, 50)
    with_statics = build_problem(other, torch.Generator().manual_seed(5), statics=first)
    alone = build_problem(other, torch.Generator().manual_seed(5))
    for f in dataclasses.fields(alone):
        a, b = getattr(alone, f.name), getattr(with_statics, f.name)
        if isinstance(a, torch.Tensor):
            assert torch.equal(a, b), f.name
    for name in ("points", "mask", "sliding_velocity", "support_index", "normal"):
        assert torch.equal(getattr(alone.env, name), getattr(with_statics.env, name)), name
    assert torch.equal(alone.sdf.values, with_statics.sdf.values)
    assert with_statics.sdf is first.sdf and with_statics.hands is first.hands
    with pytest.raises(ShapeError, match="statics"):
        build_problem(torchhand.load_scene("mug-pickup"), torch.Generator(), statics=first)


def test_stacked_frames_hold_each_problem_after_a_copy_of_its_first_frame(base, scene):
    first = build_problem(scene, torch.Generator().manual_seed(0))
    other = build_problem(base.with_frames(30, 50), torch.Generator(), statics=first)
    stacked, starts = stack_frames([first, other])
    assert starts == [1, 18] and stacked.T == 16 + 20 + 2
    for p, s0 in ((first, 1), (other, 18)):
        assert torch.equal(stacked.object_pose[s0 - 1], p.object_pose[0])
        assert torch.equal(stacked.root[:, s0:s0 + p.T], p.root)
        assert torch.equal(stacked.env.mask[s0:s0 + p.T], p.env.mask)
        assert torch.equal(stacked.wrench[s0:s0 + p.T], p.wrench)


def test_lanes_run_searches_one_after_another_and_keep_errors(scene, alone):
    """A lane yields its searches in turn; each runs as alone. A lane that raises ends with its error as its
    result (keep_errors) and the others go on; without keep_errors the error is raised."""
    first, init = _prepared(scene, 3)
    second, init2 = _prepared(scene, 4, share=first)

    def two():
        a = yield SearchTask(first, init, SETTINGS, seed=3)
        b = yield SearchTask(second, init2, SETTINGS, seed=4)
        return a, b

    def broken():
        yield SearchTask(first, init, dataclasses.replace(SETTINGS, max_nodes=50), seed=3)
        raise RuntimeError("lane broke")

    done = []
    (a, b), err = search_lanes([two(), broken()], on_done=lambda i, v: done.append(i))
    _assert_same_run(alone[3], a)
    _assert_same_run(alone[4], b)
    assert isinstance(err, RuntimeError) and str(err) == "lane broke" and sorted(done) == [0, 1]
    with pytest.raises(RuntimeError, match="lane broke"):
        search_lanes([broken()], keep_errors=False)


def test_per_row_slide_speeds_are_each_rows_settings(base):
    """``speeds`` gives each row its own slide speeds: a batch whose rows alternate two settings equals the
    rows of each setting's own call, and the two settings give different verdicts (the speeds matter here: a path
    of box-turn's turn, frames 14-30, tested again frame by frame from its previous poses)."""
    gen = torch.Generator().manual_seed(3)
    p = build_problem(base.with_frames(14, 30), gen)
    path = search(p, prune_patches(p, gen), dataclasses.replace(SETTINGS, max_nodes=1500, solutions=1), seed=3)[0][0]
    t = torch.arange(1, path.q.shape[0])
    guides = Guides(path.guiding[1:], path.guide_link[1:], path.guide_local[1:], path.guide_obj[1:],
                    torch.zeros_like(path.guide_obj[1:]))
    first = torch.zeros_like(path.guiding[1:])
    fast, slow = NodeTestSettings(), NodeTestSettings(slide_speed=1e-3, table_slide_speed=1e-3)

    def node(ns, speeds=None):
        return run_node_test(p, t, path.q[:-1], first, guides, settings=ns, prev_mask=path.c_mask[:-1],
                             speeds=speeds)

    a, b = node(fast), node(slow)
    odd = torch.arange(t.shape[0]) % 2 == 1
    speeds = torch.tensor([[fast.slide_speed, fast.table_slide_speed]], dtype=torch.float64).repeat(t.shape[0], 1)
    speeds[odd] = torch.tensor([slow.slide_speed, slow.table_slide_speed], dtype=torch.float64)
    mixed = node(fast, speeds)
    assert not torch.equal(a.feasible, b.feasible)
    for f in dataclasses.fields(mixed):
        x, y, z = getattr(mixed, f.name), getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, torch.Tensor):
            assert torch.equal(x[~odd], y[~odd]) and torch.equal(x[odd], z[odd]), f.name


def test_a_candidates_node_test_does_not_depend_on_its_batch():
    """The node test of 24 candidates at a box-turn hold frame (float32, the default), whole, in two halves and one
    by one: every output of every row is bit-identical (a batch of one would take BLAS's matrix-vector path, and a
    global early stop would make rows iterate as long as the slowest one)."""
    from bench_synthesis import node_batch

    problem, run = node_batch(24, "cpu", torch.float32)
    cells = dict(zip(run.__code__.co_freevars, (c.cell_contents for c in run.__closure__)))
    t, q_prev, first, guides, warm = (cells[k] for k in ("t", "q_prev", "first", "guides", "warm"))
    whole = run()

    def rows(idx):
        g = Guides(**{f.name: None if getattr(guides, f.name) is None else getattr(guides, f.name)[idx]
                      for f in dataclasses.fields(guides)})
        return run_node_test(problem, t[idx], q_prev[idx], first[idx], g, prev_mask=warm.c_mask[idx])

    parts = [torch.arange(0, 10), torch.arange(10, 24)] + [torch.tensor([i]) for i in (0, 7, 23)]
    assert bool(whole.feasible.any())
    for idx in parts:
        part = rows(idx)
        for f in dataclasses.fields(whole):
            assert torch.equal(getattr(whole, f.name)[idx], getattr(part, f.name)), (f.name, idx.tolist())


def test_seeds_option_writes_each_seed_as_alone(tmp_path, capsys):
    """``torchhand synthesize --seeds 1-2`` writes OUT/seed_1 and OUT/seed_2, each with the solution files that
    ``--seed S`` writes alone (the result digest over every array)."""
    from torchhand.io.digest import solutions_digest

    args = ["synthesize", "box-turn", "--frames", "0:16", "--trees", "4", "--candidates", "6", "--epsilon", "3",
            "--solutions", "1", "--max-nodes", "600", "--no-progress"]
    assert cli(args + ["--seeds", "1-2", "--out", str(tmp_path / "batch")]) == 0
    assert cli(args + ["--seed", "2", "--out", str(tmp_path / "alone")]) == 0
    assert sorted(p.name for p in (tmp_path / "batch").iterdir()) == ["seed_1", "seed_2"]
    assert len(list((tmp_path / "alone" / "solutions").glob("sol_*.npz"))) >= 1
    assert solutions_digest(tmp_path / "batch" / "seed_2") == solutions_digest(tmp_path / "alone")
    assert torchhand.check_result(tmp_path / "batch" / "seed_1").passed
    # each seed's own preparation and finishing; the batch's search, node tests and rate
    stats = [json.loads((tmp_path / "batch" / f"seed_{s}" / "stats.json").read_text()) for s in (1, 2)]
    t1, t2 = (st["timings_s"] for st in stats)
    assert t1["batched"] == t2["batched"] == 2 and t1["search_s"] == t2["search_s"] > 0
    assert t1["batch_nodes"] == t2["batch_nodes"] == stats[0]["nodes_tested"] + stats[1]["nodes_tested"]
    assert 0 < t2["prepare_s"] < t1["total_s"] and t1["prepare_s"] + t2["prepare_s"] < t1["total_s"]
    assert stats[0]["nodes_per_second"] == pytest.approx(t1["batch_nodes"] / t1["search_s"])
    assert "in a batch of 2" in capsys.readouterr().out


@pytest.mark.parametrize("argv, needle", [
    (["--seeds", "3-1"], "--seeds"),
    (["--seeds", "0,0"], "--seeds"),
    (["--seeds", "a-b"], "--seeds"),
    (["--seeds", "0-1", "--seed", "4"], "--seeds"),
])
def test_bad_seeds_are_one_line_and_exit_2(argv, needle, tmp_path, capsys):
    rc = cli(["synthesize", "box-turn", "--out", str(tmp_path / "x")] + argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and needle in err[0]
    assert not (tmp_path / "x").exists() or not any((tmp_path / "x").iterdir())


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_searches_in_one_batch_run_as_they_do_alone(scene):
    """On the GPU the same contract: two seeds together give each seed's alone run on the GPU, bit for bit."""
    alone = _alone(scene, (3, 4), device="cuda")
    outcomes, _ = _together(scene, (3, 4), device="cuda")
    for seed, o in zip((3, 4), outcomes):
        _assert_same_run(alone[seed], o)
