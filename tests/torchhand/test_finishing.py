"""Finishing searched paths as batched work (torchhand.synthesis.finishing): each path's result is its alone one.

Small searches (box-turn's first 16 frames, 4 trees of 6 candidates, a node budget), as in test_multi_search.py; the
contract is byte-identity, so the comparisons are exact.
"""

from __future__ import annotations

import dataclasses

import pytest
import torch

import torchhand
from torchhand.synthesis import finishing
from torchhand.synthesis.finishing import Evaluate, Reconstruct, drive, finalize_steps, run_works
from torchhand.synthesis.multi import MultiStats
from torchhand.synthesis.pipeline import synthesize, synthesize_seeds

OPTIONS = dict(trees=4, candidates=6, epsilon=3, solutions=2, max_nodes=600)
SEEDS = (1, 2, 3, 4)
FINAL_FIELDS = ("q", "c_mask", "c_local", "c_point", "c_normal", "c_force", "env_force", "guiding", "guide_obj",
                "sliding")


@pytest.fixture(scope="module")
def scene():
    return torchhand.load_scene("box-turn").with_frames(0, 16)


@pytest.fixture(scope="module")
def searched(scene):
    """The paths each seed's search handed to its finishing, per seed, and each seed's result alone."""
    paths, alone = {}, {}
    real = finishing.finalize_steps

    def keep(problem, sol, index, **kw):
        paths[seed].append((problem, sol, kw))
        return (yield from real(problem, sol, index, **kw))

    import torchhand.synthesis.pipeline as pipeline
    pipeline.finalize_steps = keep
    try:
        for seed in SEEDS:
            paths[seed] = []
            alone[seed] = synthesize(scene, seed=seed, **OPTIONS)
    finally:
        pipeline.finalize_steps = real
    return paths, alone


def _same_frames(a, b) -> bool:
    return all(torch.equal(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a))


def test_seeds_finish_their_paths_together_as_alone(scene, searched, monkeypatch):
    """``synthesize_seeds``: the searches that found a path wait until half of them have one, then their paths'
    reconstructions and evaluations run as batches of several paths; every seed's solutions and exclusions are
    those it gets alone, bit for bit."""
    _, alone = searched
    stats, sizes = MultiStats(), {"reconstruct": [], "evaluate": []}
    real_rec, real_eval = finishing.reconstruct_paths, finishing.evaluate_motions
    monkeypatch.setattr(finishing, "reconstruct_paths", lambda w: sizes["reconstruct"].append(len(w)) or real_rec(w))
    monkeypatch.setattr(finishing, "evaluate_motions", lambda w: sizes["evaluate"].append(len(w)) or real_eval(w))
    monkeypatch.setattr(finishing, "CPU_MAX_PATHS", None)           # the paths' reconstructions in one call here
    batch = synthesize_seeds(scene, SEEDS, multi_stats=stats, **OPTIONS)
    assert sum(len(r.finals) for r in alone.values()) >= 4
    assert stats.finish_batches > 0 and max(stats.finish_sizes) >= 3      # several paths' work in one batch
    assert max(sizes["reconstruct"]) >= 3 and max(sizes["evaluate"]) >= 3, sizes
    for seed, res in zip(SEEDS, batch):
        ref = alone[seed]
        assert len(res.finals) == len(ref.finals) and res.excluded == ref.excluded
        assert res.stats.nodes_tested == ref.stats.nodes_tested
        for a, b in zip(ref.finals, res.finals):
            for name in FINAL_FIELDS:
                assert torch.equal(getattr(a, name), getattr(b, name)), (seed, name)
            assert (a.reconstructed, a.index) == (b.reconstructed, b.index)
        assert res.timings["finalize_s"] > 0


def test_evaluations_of_many_motions_are_each_as_alone(searched):
    """Evaluations of the searched paths of several seeds (one problem to the node test) and of motions of other
    lengths run as one call per pass; each motion's frame results are those of its own evaluation."""
    paths, _ = searched
    lead = paths[SEEDS[0]][0][0]
    ns = paths[SEEDS[0]][0][2]["ns"]
    sols = [sol for seed in SEEDS for _, sol, _ in paths[seed]]
    works = [Evaluate(lead, s.q, ns, s.c_mask) for s in sols]
    works += [Evaluate(lead, sols[0].q[:9], ns, sols[0].c_mask[:9]), Evaluate(lead, sols[1].q[4:], ns, None)]
    alone = [w.run() for w in works]
    together = run_works(works)
    assert len(works) >= 6
    assert all(_same_frames(a, b) for a, b in zip(alone, together))


def test_work_of_different_problems_is_grouped(scene, searched):
    """Work for problems the node test can tell apart (other frames) is run in its own batch: the keys differ, and
    each result is still its own."""
    paths, _ = searched
    problem, sol, kw = paths[SEEDS[0]][0]
    other = torchhand.synthesis.problem.build_problem(torchhand.load_scene("box-turn").with_frames(2, 18),
                                                      torch.Generator().manual_seed(0))
    a, b = Evaluate(problem, sol.q, kw["ns"], sol.c_mask), Evaluate(other, sol.q, kw["ns"], sol.c_mask)
    assert a.key() != b.key()
    ra, rb = run_works([a, b])
    assert _same_frames(ra, a.run()) and _same_frames(rb, b.run())
    rec = Reconstruct(problem, sol, kw["ns"], kw["joint_speed"], finishing._RECONSTRUCTIONS[0])
    assert rec.key() != a.key() and torch.equal(run_works([rec, a])[0], rec.run())


def test_a_finishing_program_yields_its_work_and_returns_the_verdict(searched):
    """``finalize_steps`` run step by step: a reconstruction first, then evaluations; driven alone it returns what
    ``finalize_solution`` returns."""
    paths, _ = searched
    problem, sol, kw = paths[SEEDS[0]][0]
    program = finalize_steps(problem, sol, 0, **kw)
    kinds = []
    try:
        work = next(program)
        while True:
            kinds.append(type(work).__name__)
            work = program.send(work.run())
    except StopIteration as done:
        fin, reason = done.value
    assert kinds[0] == "Reconstruct" and "Evaluate" in kinds
    again, reason2 = drive(finalize_steps(problem, sol, 0, **kw))
    assert reason == reason2 and (fin is None) == (again is None)
    if fin is not None:
        assert torch.equal(fin.q, again.q) and torch.equal(fin.c_force, again.c_force)


def test_paths_per_reconstruction_call(searched, monkeypatch):
    """A CPU takes ``CPU_MAX_PATHS`` paths per call, a GPU all of them; a problem with a one-finger hand always one
    path per call (and the chunked calls return each path's own result, in order)."""
    paths, _ = searched
    problem, sol, kw = paths[SEEDS[0]][0]
    assert finishing.paths_per_call(problem, "cpu") == finishing.CPU_MAX_PATHS
    assert finishing.paths_per_call(problem, "cuda") is None
    one = dataclasses.replace(problem.hands[0], finger_names=problem.hands[0].finger_names[:1])
    assert finishing.paths_per_call(dataclasses.replace(problem, hands=(one,)), "cuda") == 1
    works = [Reconstruct(problem, s, k["ns"], k["joint_speed"], finishing._RECONSTRUCTIONS[0])
             for p in SEEDS[:2] for _, s, k in paths[p][:1]]
    calls = []
    real = finishing.reconstruct_paths_together
    monkeypatch.setattr(finishing, "reconstruct_paths_together", lambda w: calls.append(len(w)) or real(w))
    monkeypatch.setattr(finishing, "CPU_MAX_PATHS", 1)
    got = finishing.reconstruct_paths(works)
    assert calls == [1] * len(works)
    assert all(torch.equal(g, w.run()) for g, w in zip(got, works))


def test_an_error_in_finishing_work_ends_its_search(scene, monkeypatch):
    """Work that raises is run again alone, and its error is raised inside the search that waits on it: here every
    evaluation fails, so the batch of seeds stops with that error (``search_many`` raises it) instead of hanging."""
    def broken(works):
        raise RuntimeError("evaluation failed")

    monkeypatch.setattr(finishing, "evaluate_motions", broken)
    with pytest.raises(RuntimeError, match="evaluation failed"):
        synthesize_seeds(scene, SEEDS[:2], **OPTIONS)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_seeds_finish_their_paths_together_as_alone(scene):
    """On the GPU the same contract: the seeds' paths finished in batches give each seed's alone result there."""
    opts = dict(OPTIONS, device="cuda")
    alone = [synthesize(scene, seed=s, **opts) for s in SEEDS]
    stats = MultiStats()
    batch = synthesize_seeds(scene, SEEDS, multi_stats=stats, **opts)
    assert stats.finish_batches > 0
    for ref, res in zip(alone, batch):
        assert len(res.finals) == len(ref.finals) and res.excluded == ref.excluded
        for a, b in zip(ref.finals, res.finals):
            for name in FINAL_FIELDS:
                assert torch.equal(getattr(a, name), getattr(b, name)), name
