"""A window searched in pieces (torchhand.fill.pieces): past a wall the window goes on, within its node budget."""

from types import SimpleNamespace

import pytest
import torch

from torchhand.fill.pieces import BACK, MIN_FRAMES, search_pieces

FAIL_COST, SOLVE_COST = 100, 50


class _Clip:
    def __init__(self, start, stop):
        self.start, self.stop = start, stop

    def with_frames(self, a, b):
        return _Clip(self.start + a, self.start + b)


def _searcher(walls, log):
    """A search of frames [c, stop) that no path gets through at a wall frame: it reaches the first wall at or
    after c (the wall frame itself fails), or solves the clip."""
    def search(clip, max_nodes, stall):
        log.append((clip.start, max_nodes, stall))
        wall = min([w for w in walls if clip.start <= w < clip.stop], default=None)
        T = clip.stop - clip.start
        if wall is None:
            q = torch.full((T, 1, 2), float(clip.start))
            stats = SimpleNamespace(nodes_tested=SOLVE_COST, deepest_frame=T, stopped_by="solutions",
                                    rejections={"kinematic": 0}, paths_found=1)
            return SimpleNamespace(stats=stats, finals=[SimpleNamespace(q=q)], partial=None)
        d = wall - clip.start
        stats = SimpleNamespace(nodes_tested=FAIL_COST, deepest_frame=d, stopped_by="stalled",
                                rejections={"kinematic": 3}, paths_found=0)
        part = SimpleNamespace(q=torch.full((d, 1, 2), float(clip.start))) if d else None
        return SimpleNamespace(stats=stats, finals=[], partial=part)
    return search


def test_a_window_without_walls_is_one_solved_piece():
    log = []
    pieces, attempts, _ = search_pieces(_Clip(0, 100), 40, 100, budget=1000, stall_nodes=7,
                                        search=_searcher([], log))
    assert [(p.start, p.stop, p.kind) for p in pieces] == [(40, 100, "solved")]
    assert pieces[0].qs[0].shape == (60, 1, 2) and pieces[0].qs[0].dtype == torch.float64
    assert log == [(40, 1000, 7)] and attempts[0].stopped_by == "solutions" and attempts[0].reached == 100


def test_past_a_wall_the_window_goes_on_and_the_wall_frame_stays_unclaimed():
    log = []
    pieces, attempts, _ = search_pieces(_Clip(0, 100), 0, 60, budget=1000, stall_nodes=7,
                                        search=_searcher([20], log))
    # the deepest path to the wall; a fresh search from just before it dies there too; one at the wall fails its
    # first frame; the next starts past it and reaches the end
    assert [a[0] for a in log] == [0, 20 - BACK, 20, 21]
    assert [(p.start, p.stop, p.kind) for p in pieces] == [(0, 20, "partial"), (21, 60, "solved")]
    assert [a.reached for a in attempts] == [20, 20, 20, 60]
    assert [a[1] for a in log] == [1000, 900, 800, 700]              # one budget, shared
    assert all(float(p.qs[0][0, 0, 0]) == p.start for p in pieces)   # each piece is its own search's motion


def test_repeated_failures_skip_further_and_the_budget_bounds_the_work():
    log = []
    walls = [20, 21, 22, 23]                                          # a wall four frames thick
    pieces, attempts, _ = search_pieces(_Clip(0, 100), 0, 60, budget=10_000, stall_nodes=7,
                                        search=_searcher(walls, log))
    assert [a[0] for a in log] == [0, 15, 20, 21, 23, 27]            # at the wall, then 1, 3, 7 frames past it
    assert [(p.start, p.stop, p.kind) for p in pieces] == [(0, 20, "partial"), (27, 60, "solved")]
    log.clear()
    pieces, attempts, _ = search_pieces(_Clip(0, 100), 0, 60, budget=250, stall_nodes=7,
                                        search=_searcher(walls, log))
    assert len(log) == 3 and sum(a.nodes for a in attempts) == 300 and pieces[-1].stop == 20


def test_no_search_on_the_last_few_frames():
    log = []
    stop = 60
    pieces, _, _ = search_pieces(_Clip(0, 100), 0, stop, budget=10_000, stall_nodes=7,
                                 search=_searcher([stop - MIN_FRAMES + 1], log))
    assert [(p.start, p.stop) for p in pieces] == [(0, stop - MIN_FRAMES + 1)]
    assert all(stop - a[0] >= MIN_FRAMES for a in log)


def test_a_real_search_keeps_its_deepest_path():
    """synthesize's ``partial``: the deepest path the search grew, frames [0, deepest_frame), when none is
    written; a search stopped by its stall rule says so."""
    import torchhand
    from torchhand.synthesis.pipeline import synthesize

    scene = torchhand.load_scene("box-turn").with_frames(0, 30)
    res = synthesize(scene, solutions=1, max_nodes=1, seed=0, stall_nodes=1)
    assert res.finals == [] and res.partial is not None
    assert res.partial.q.shape[0] == res.stats.deepest_frame > 0
    assert res.partial.q.shape[1:] == (1, res.problem.hands[0].num_joints)
    assert res.stats.stopped_by in ("max_nodes", "stalled")
    assert torch.isfinite(res.partial.q).all() and res.partial.c_force.shape[0] == res.stats.deepest_frame


def test_a_window_that_raises_is_reported_and_the_others_are_kept(tmp_path, monkeypatch):
    import json
    import sys
    from pathlib import Path

    import torchhand.fill.run as run_mod

    sys.path.insert(0, str(Path(__file__).parent))
    from test_fill import PHASES, _scene

    real = run_mod.window_lane

    def flaky(scene, window, settings, phases=None, shared=None, say=None):
        if window.index == 1:
            raise RuntimeError("boom in the second window")
        return (yield from real(scene, window, settings, phases, shared, say))

    monkeypatch.setattr(run_mod, "window_lane", flaky)
    lines = []
    res = run_mod.fill_capture(_scene(), tmp_path / "o", phases=PHASES, variants=1, window=6, overlap=2,
                               max_nodes=300, seed=0, progress=lines.append)
    assert [r.status for r in res.windows][1] == "error" and res.windows[0].status != "error"
    assert any("boom in the second window" in line for line in lines)
    doc = json.loads((tmp_path / "o" / "phases.json").read_text())
    w = doc["windows"][1]
    assert w["status"] == "error" and w["error"] == "RuntimeError: boom in the second window"
    assert "flaky" in w["traceback"] and w["slide_speed"] is None
    only_1 = [f for f in range(6, 12) if not any(p["start"] <= f < p["stop"] for p in doc["windows"][0]["pieces"])]
    assert (res.frame_status[0][only_1] == 2).all()


def test_windows_in_worker_processes_give_the_same_result(tmp_path, monkeypatch):
    """--jobs 2 runs each window alone in spawned processes (the scene pickled to them); one process runs the
    windows' searches together, their frames stacked into shared node-test calls: the same motions, node tests
    and frame status, and the finishing step's exact-geometry queries work in the workers."""
    import torchhand.synthesis.multi as multi
    import sys
    from pathlib import Path

    import numpy as np

    from torchhand.fill.run import fill_capture

    sys.path.insert(0, str(Path(__file__).parent))
    from test_fill import PHASES, _scene

    import torchhand.fill.run as run_mod

    stacked, lines = [], []
    real = multi.stack_frames
    monkeypatch.setattr(multi, "stack_frames", lambda problems: stacked.append(len(problems)) or real(problems))
    monkeypatch.setattr(run_mod, "REPORT_EVERY_S", 0.0)       # a progress line after every round
    got = {}
    for jobs in (1, 2):
        res = fill_capture(_scene(), tmp_path / f"j{jobs}", phases=PHASES, variants=1, window=6, overlap=2,
                           max_nodes=1500, seed=0, jobs=jobs, progress=lines.append)
        assert [r.status for r in res.windows] == ["solved", "solved"]
        got[jobs] = res
    np.testing.assert_array_equal(got[1].frame_status, got[2].frame_status)
    for a, b in zip(got[1].windows, got[2].windows):
        assert a.nodes == b.nodes and all(torch.equal(x, y) for x, y in zip(a.qs, b.qs))
    assert stacked and max(stacked) == 2           # the two windows' searches were tested together
    assert any(line.startswith("searching: 2 of 2 window(s) running;") for line in lines)
    assert "window 2/2: preparing a search of frames 6-11 (1500 node tests left)" in lines


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_windows_together_run_as_alone(tmp_path):
    """On a CUDA device, the windows' searches tested together (one process) give each window the run it has
    alone there (two worker processes, one window at a time)."""
    import sys
    from pathlib import Path

    from torchhand.fill.run import fill_capture

    sys.path.insert(0, str(Path(__file__).parent))
    from test_fill import PHASES, _scene

    got = [fill_capture(_scene(), tmp_path / f"j{jobs}", phases=PHASES, variants=1, window=6, overlap=2,
                        max_nodes=1500, seed=0, jobs=jobs, device="cuda") for jobs in (1, 2)]
    assert [r.status for r in got[0].windows] == ["solved", "solved"]
    for a, b in zip(got[0].windows, got[1].windows):
        assert a.nodes == b.nodes and all(torch.equal(x, y) for x, y in zip(a.qs, b.qs))


def test_clamped_motion_keeps_the_speed_and_acceleration_bounds():
    from torchhand.fill.stitch import clamp_speed, max_speed

    g = torch.Generator().manual_seed(0)
    q = torch.cumsum(torch.randn(200, 1, 4, generator=g, dtype=torch.float64) * 0.4, 0)
    q[50:60] = q[49]                                                  # a still stretch stays still where it can
    fps, speed = 30.0, 8.0
    out = clamp_speed(q, speed / fps)
    assert max_speed(q, fps) > 3 * speed and max_speed(out, fps) <= speed * (1 + 1e-12)
    acc = ((out[2:] - 2 * out[1:-1] + out[:-2]).abs().amax() * fps ** 2).item()
    assert acc <= 2 * speed * fps * (1 + 1e-12)                       # the checker's 480 rad/s^2 at 8 rad/s, 30 fps
    assert torch.equal(out[0], q[0])
    slow = torch.linspace(0, 1, 100, dtype=torch.float64)[:, None, None].expand(100, 1, 3) * 0.1
    assert torch.equal(clamp_speed(slow, speed / fps), slow)          # within the bound: unchanged


def test_copies_of_a_motion_are_not_written_twice():
    import numpy as np

    from torchhand.fill.fill import _distinct

    a = torch.zeros(10, 1, 3, dtype=torch.float64)
    near = a + 0.01                                                    # 0.6 degrees everywhere
    far = a.clone()
    far[4:] += 0.2
    solved = np.zeros(10, dtype=np.int8)
    first_half = solved.copy()
    first_half[4:] = 2                                                 # claims only frames 0-3, where it equals a
    assert _distinct([a, near, far], [solved] * 3) == [0, 2]
    assert _distinct([a, far], [solved, first_half]) == [0]
