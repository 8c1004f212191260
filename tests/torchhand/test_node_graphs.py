"""The node test's GPU paths, run on the CPU: the Levenberg–Marquardt loop without its early stop and the force
solve's steps and checks, each inside a function with no host synchronisation (what a CUDA graph captures), give
the same answers as the CPU's paths."""

from __future__ import annotations

import dataclasses
import functools

import pytest
import torch

import torchhand
from torchhand.kernels import graphs
from torchhand.synthesis.initial import prune_patches
from torchhand.synthesis.node_test import CAUSE_FINGERS, CAUSE_KINEMATIC, Guides, pad_points, run_node_test
from torchhand.synthesis.problem import build_problem


@functools.lru_cache(maxsize=2)
def _pruned(scene_name: str, device: str = "cpu"):
    gen = torch.Generator().manual_seed(0)
    problem = build_problem(torchhand.load_scene(scene_name), gen, device=device)
    return problem, prune_patches(problem, gen, per_finger=64)   # fewer samples than a search tries


def _batch(scene_name: str, N: int, frame: int, roll: bool, seed: int = 0, device: str = "cpu"):
    """N candidates of a built-in scene at the hold frame nearest ``frame`` where the most fingers have pruned
    patch samples, guided there (rolling if ``roll``), from the poses found one frame before."""
    gen = torch.Generator().manual_seed(seed)
    problem, init = _pruned(scene_name, device)
    H, F = problem.H, problem.F

    def count(t):
        return sum(bool(init.samples(t, h, f).numel()) for h in range(H) for f in range(F))

    frame = min(range(1, problem.T), key=lambda t: (-count(t), abs(t - frame)))
    active = torch.tensor([[bool(init.samples(frame, h, f).numel()) for f in range(F)] for h in range(H)])
    obj = torch.zeros(N, H, F, 3, dtype=problem.surface.dtype)
    for h in range(H):
        for f in range(F):
            idx = init.samples(frame, h, f)
            if idx.numel():
                obj[:, h, f] = problem.surface[idx[torch.randint(idx.numel(), (N,), generator=gen).to(idx.device)]]
    link = torch.stack([hd.distal_link for hd in problem.hands])
    local = torch.stack([pad_points(hd) for hd in problem.hands])
    guides = Guides(active.expand(N, H, F).clone(), link.expand(N, H, F).clone(), local.expand(N, H, F, 3).clone(),
                    obj, torch.zeros_like(obj), roll=active.expand(N, H, F).clone() if roll else None)
    guides = Guides(**{f.name: None if getattr(guides, f.name) is None else getattr(guides, f.name).to(device)
                       for f in dataclasses.fields(guides)})
    t = torch.full((N,), frame, device=device)
    q_rest = torch.stack([hd.q_rest for hd in problem.hands])
    warm = run_node_test(problem, t - 1, q_rest.expand(N, H, -1).clone(),
                         torch.ones(N, dtype=torch.bool, device=device), guides)
    return problem, (t, warm.q, torch.zeros(N, dtype=torch.bool, device=device), guides), warm.c_mask


@pytest.mark.parametrize("scene_name, roll", [("box-turn", False), ("box-turn", True), ("box-carry", False)])
def test_gpu_paths_are_sync_free_and_answer_as_the_cpu_paths(scene_name, roll):
    problem, args, prev_mask = _batch(scene_name, 24, 30, roll)
    want = run_node_test(problem, *args, prev_mask=prev_mask)
    before = graphs.STATS["regions"]
    with graphs.gpu_paths(check_syncs=True):
        got = run_node_test(problem, *args, prev_mask=prev_mask)
    for f in dataclasses.fields(want):
        assert torch.equal(getattr(got, f.name), getattr(want, f.name)), f.name
    # the test had work to do: one region per LM solve (and its retry), and where candidates reach the dynamic
    # test, the force solve's steps and checks; the static guides reach it and some pass
    solved = bool(((want.cause != CAUSE_KINEMATIC) & (want.cause != CAUSE_FINGERS)).any())
    assert graphs.STATS["regions"] - before >= (3 if solved else 1)
    assert roll or (solved and bool(want.feasible.any()))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_node_test_replays_its_graphs_and_answers_as_without_them():
    graphs.clear()
    problem, args, prev_mask = _batch("box-turn", 100, 30, False, device="cuda")
    s0 = dict(graphs.STATS)
    first = run_node_test(problem, *args, prev_mask=prev_mask)      # captures (the answers are the eager ones)
    second = run_node_test(problem, *args, prev_mask=prev_mask)     # replays
    assert graphs.STATS["captures"] > s0.get("captures", 0) and graphs.STATS["replays"] > s0.get("replays", 0)
    assert graphs.STATS["failed"] == s0.get("failed", 0)
    for f in dataclasses.fields(first):
        assert torch.equal(getattr(first, f.name), getattr(second, f.name)), f.name
    graphs.set_enabled(False)                                       # eager, unpadded
    try:
        plain = run_node_test(problem, *args, prev_mask=prev_mask)
    finally:
        graphs.set_enabled(True)
    assert torch.equal(plain.cause, first.cause)
    torch.testing.assert_close(plain.q, first.q, rtol=0, atol=1e-4)
