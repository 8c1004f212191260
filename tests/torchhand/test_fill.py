"""``torchhand fill`` (torchhand.fill.windows, .stitch, .run, the checker's frame_status, the CLI): the window plan,
the stitching rules on synthetic motion, an end-to-end fill of a short built-in scene checked by the checker, a
window that fails flagged per frame, and bad input."""

from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest
import torch

import torchhand
from torchhand.check import check_result
from torchhand.check.checker import frame_status
from torchhand.cli import main as cli
from torchhand.errors import FileFormatError, InputValueError
from torchhand.fill.phases import Phase
from torchhand.fill.stitch import blend_windows, fill_free, max_speed
from torchhand.fill.windows import plan_windows, segments

FPS = 30.0
SPEED = 8.0       # rad/s, the synthesis' and the checker's joint-speed limit


def _phases(*runs):
    out, t = [], 0
    for kind, n in runs:
        out.append(Phase(kind, t, t + n))
        t += n
    return tuple(out)


# --- the window plan -----------------------------------------------------------------------------------------

def test_plan_windows_cover_each_segment_with_exact_overlaps_and_distinct_seeds():
    ph = _phases(("free", 20), ("approach", 15), ("contact", 170), ("release", 15), ("free", 30),
                 ("approach", 10), ("free", 10),                       # an approach without contact: free
                 ("contact", 40), ("release", 10), ("free", 5))
    T = ph[-1].stop
    ws = plan_windows(ph, T, window=60, overlap=15, seed=7)
    assert segments(ph, T) == ((20, 220, 2), (270, 320, 7))
    covered = np.zeros(T, dtype=int)
    for w in ws:
        assert 2 * 15 <= w.frames <= 60
        covered[w.start:w.stop] += 1
    assert (covered[20:220] >= 1).all() and (covered[270:320] == 1).all()
    assert covered.max() == 2 and covered[:20].sum() == 0 and covered[220:270].sum() == 0
    first = [w for w in ws if w.segment == 0]
    assert [w.phase for w in ws] == [2] * len(first) + [7]
    assert first[0].start == 20 and first[-1].stop == 220
    for a, b in zip(first, first[1:]):
        assert a.stop - b.start == 15                                   # exactly the overlap
    seeds = [w.seed for w in ws]
    assert len(set(seeds)) == len(seeds)
    assert seeds == [w.seed for w in plan_windows(ph, T, window=60, overlap=15, seed=7)]    # deterministic
    assert seeds != [w.seed for w in plan_windows(ph, T, window=60, overlap=15, seed=8)]
    assert [w.index for w in ws] == list(range(len(ws)))


def test_plan_windows_bad_input():
    ph = _phases(("free", 10), ("contact", 50))
    with pytest.raises(InputValueError, match="window"):
        plan_windows(ph, 60, window=40, overlap=15)
    with pytest.raises(InputValueError, match="overlap"):
        plan_windows(ph, 60, window=40, overlap=1)
    with pytest.raises(InputValueError, match="cover"):
        plan_windows(ph, 61, window=60, overlap=15)
    with pytest.raises(InputValueError, match="kind"):
        plan_windows((Phase("holding", 0, 60),), 60, window=60, overlap=15)


# --- stitching ---------------------------------------------------------------------------------------------------

def _track(t: torch.Tensor, phase: float, offset: float) -> torch.Tensor:
    """(n, 1, 3) smooth joint angles: slow sinusoids, 1 hand, 3 joints."""
    base = torch.stack([0.3 * torch.sin(t / 10 + phase), 0.2 * torch.cos(t / 7), 0.1 * t / 30], -1)
    return (base + offset).unsqueeze(1).double()


def test_crossfade_keeps_positions_and_velocities_continuous_and_passes_through():
    t = torch.arange(100, dtype=torch.float64)
    qa, qb = _track(t[0:60], 0.0, 0.0), _track(t[45:100], 0.4, 0.25)     # overlap: frames 45-59
    out = blend_windows([(0, 60, qa), (45, 100, qb)], 0, 100)
    assert torch.equal(out[:45], qa[:45]) and torch.equal(out[60:], qb[15:])   # exact away from the join
    v = (out[1:] - out[:-1]) * FPS
    # velocity continuous: no jump at the join's ends larger than the windows' own frame-to-frame change plus the
    # smoothstep's first step (3 / (n + 1)^2 of the offset)
    for k in (44, 45, 59, 60):
        assert float((v[k] - v[k - 1]).abs().max()) < 0.9
    va = (qa[1:] - qa[:-1]) * FPS
    assert float((v[:44] - va[:44]).abs().max()) == 0.0
    assert max_speed(out, FPS) <= SPEED
    # the blend moves monotonically from one window to the other: within the range of both
    lo, hi = torch.minimum(qa[45:], qb[:15]), torch.maximum(qa[45:], qb[:15])
    assert bool(((out[45:60] >= lo - 1e-12) & (out[45:60] <= hi + 1e-12)).all())


def test_free_frames_go_to_rest_within_the_speed_limit():
    T = 120
    t = torch.arange(T, dtype=torch.float64)
    q = _track(t, 0.0, 1.0)                                  # far from rest: the transition needs time
    known = torch.zeros(T, dtype=torch.bool)
    known[:20] = True
    known[90:] = True
    rest = torch.zeros(1, 3, dtype=torch.float64)
    out = fill_free(q, known, rest, FPS, SPEED)
    assert torch.equal(out[known], q[known])                 # solved frames untouched
    assert torch.equal(out[55], rest)                         # the middle of a long gap is the rest pose
    assert max_speed(out, FPS) <= SPEED * (1 + 1e-9)
    assert float((out[20] - q[19]).abs().max()) < 0.2          # the transition starts where the window ends


def test_variants_take_the_best_matching_solution_and_leave_failed_windows_free():
    from types import SimpleNamespace

    from torchhand.fill.stitch import stitch_variants

    ph = _phases(("free", 10), ("contact", 90), ("free", 20))
    T = ph[-1].stop
    ws = plan_windows(ph, T, window=30, overlap=10, seed=0)                # 10-30, 30-50(+10), ..., 4 windows
    assert len(ws) == 4
    const = lambda w, c: torch.full((w.frames, 1, 2), c, dtype=torch.float64)
    runs = [SimpleNamespace(window=ws[0], qs=[const(ws[0], 0.1), const(ws[0], 0.5)]),
            SimpleNamespace(window=ws[1], qs=[const(ws[1], 0.52), const(ws[1], 0.12)]),   # the order swapped
            SimpleNamespace(window=ws[2], qs=[]),                                            # failed
            SimpleNamespace(window=ws[3], qs=[const(ws[3], 0.3)])]
    rest = torch.zeros(1, 2, dtype=torch.float64)
    motions, known = stitch_variants(runs, ph, T, rest, 2, SPEED, FPS)
    assert len(motions) == 2
    mid = (ws[0].stop + ws[1].stop) // 2                                    # inside window 1 only
    assert float(motions[0][mid, 0, 0]) == 0.12 and float(motions[1][mid, 0, 0]) == 0.52
    assert known[ws[0].start:ws[1].stop].all() and known[ws[3].start:ws[3].stop].all()
    assert not known[ws[1].stop:ws[3].start].any() and not known[:ws[0].start].any()
    for q in motions:
        assert max_speed(q, FPS) <= SPEED * (1 + 1e-9)
        assert torch.equal(q[:ws[0].start - 9], rest.expand(ws[0].start - 9, 1, 2))   # far from windows: rest


# --- end to end ------------------------------------------------------------------------------------------------

# the box rests, the hand comes down from above; frames 2-11 are a window
PHASES = _phases(("free", 2), ("approach", 2), ("contact", 6), ("release", 2), ("free", 2))


def _scene():
    """box-turn's first 14 frames, the wrist lifted 12 cm in the free-hand frames (0, 1, 12, 13): the hand is clear
    of the box there, which rests on the table."""
    import dataclasses

    scene = torchhand.load_scene("box-turn").with_frames(0, 14)
    track = scene.hands[0]
    wrist = track.wrist_pose.clone()
    wrist[[0, 1, 12, 13], 2, 3] += 0.12
    return dataclasses.replace(scene, hands=(dataclasses.replace(track, wrist_pose=wrist),))


@pytest.fixture(scope="module")
def filled(tmp_path_factory):
    from torchhand.fill.run import fill_capture

    out = tmp_path_factory.mktemp("fill") / "bt"
    lines = []
    res = fill_capture(_scene(), out, phases=PHASES, variants=2, window=30, overlap=5, max_nodes=2000, seed=0,
                       progress=lines.append)
    return out, res, lines


def test_fill_writes_a_checked_result_covering_every_frame(filled):
    out, res, lines = filled
    T = 14
    assert any("phases" in line for line in lines) and any(line.startswith("window 1/1") for line in lines)
    result = torchhand.load_result(out)
    assert result.complete and len(result.solution_files) == len(res.frame_status) >= 1
    for i in range(len(result.solution_files)):
        sol = result.solution(i)
        assert sol.T == T and sol.q.shape[0] == T
        st = frame_status(sol)
        assert st.dtype == np.int8 and st.shape == (T,) and (st == res.frame_status[i]).all()
        assert (st[[0, 1, 12, 13]] == 1).all()                          # free hand
        assert (st[2:12] == 0).all()                                    # the solved window
        assert max_speed(torch.as_tensor(sol.q), sol.fps) <= SPEED * (1 + 1e-6)
        # free-hand frames: no hand contact, the table carries the resting box (the checker balances these forces)
        assert not sol.contact_mask[[0, 1, 12, 13]].any()
        weight = result.scene.object.mass * 9.81
        lift = (sol.env_contact_force[[0, 1, 12, 13]] * sol.env_contact_mask[[0, 1, 12, 13]][..., None]).sum(1)
        np.testing.assert_allclose(lift[:, 2], weight, rtol=1e-3)
    report = check_result(out)
    assert report.passed, report.failures
    assert all(s.unsolved == () for s in report.solutions)
    doc = json.loads((out / "phases.json").read_text())
    frames = sorted((p["start"], p["stop"]) for p in doc["phases"]["right"])
    assert frames[0][0] == 0 and frames[-1][1] == T and all(a[1] == b[0] for a, b in zip(frames, frames[1:]))
    [w] = doc["windows"]
    assert (w["start"], w["stop"], w["status"]) == (2, 12, "solved") and w["solutions"] >= 1 and w["node_tests"] > 0
    assert doc["slide_speed"] == {"value": 0.02, "source": "default", "per_window": [0.02]}
    stats = json.loads((out / "stats.json").read_text())
    assert stats["complete"] and stats["T"] == T and stats["fill"]["coverage"] == 1.0
    assert len(stats["fill"]["window_time_s"]) == 1 and stats["time_s"] > 0
    png = (out / "timeline.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 5000
    from torchhand.fill.timeline import main as redraw
    assert redraw([str(out), str(out.parent / "again.png")]) == 0 and (out.parent / "again.png").stat().st_size > 5000


def test_a_failed_window_is_flagged_and_counted_apart(tmp_path):
    from torchhand.fill.run import fill_capture

    out = tmp_path / "bt"
    # one round of search: the window's deepest path is a piece of its first frames; the rest is unsolved
    res = fill_capture(_scene(), out, phases=PHASES, variants=2, window=30, overlap=5, max_nodes=1, seed=0)
    assert res.frame_status.shape == (1, 14)                           # no window solution: one motion
    st = res.frame_status[0]
    [run] = res.windows
    assert run.status == "partial" and run.qs == [] and len(run.attempts) == 1
    [piece] = run.pieces
    assert piece.kind == "partial" and piece.start == 2 and 2 < piece.stop < 12
    assert (st[piece.stop:12] == 2).all() and (st[2:piece.stop] != 1).all() and (st[[0, 1, 12, 13]] != 2).all()
    unsolved = np.nonzero(st == 2)[0].tolist()
    mid = unsolved[len(unsolved) // 2]                                 # an unsolved frame between unsolved ones
    assert len(unsolved) >= 3 and mid - 1 in unsolved and mid + 1 in unsolved
    doc = json.loads((out / "phases.json").read_text())
    [w] = doc["windows"]
    assert w["status"] == "partial" and w["solutions"] == 0
    assert w["pieces"] == [{"start": 2, "stop": piece.stop, "kind": "partial", "motions": 1}]
    assert w["searches"][0]["stopped_by"] == "max_nodes" and w["searches"][0]["reached"] == piece.stop
    assert set(w["rejections"]) == {"kinematic", "finger_finger", "dynamic"} and "deepest_frame" in w
    assert doc["unsolved_frames"] == [unsolved]
    report = check_result(out)
    assert report.passed and report.solutions[0].unsolved == tuple(unsolved)
    assert report.solutions[0].to_dict()["unsolved_frames"] == unsolved

    # the checker: frames flagged unsolved are not checked, every other frame is; without frame_status a file is
    # checked in every frame, as before
    path = out / "solutions" / "sol_000.npz"
    with np.load(path) as z:
        arrays = dict(z)
    lim = torchhand.load_result(out).hand_models["right"].joint_limits.numpy()
    arrays["q"] = arrays["q"].copy()
    arrays["q"][mid, 0] = lim[0, 1] + 0.5                              # beyond the joint limit in an unsolved frame
    np.savez(path, **arrays)
    assert check_result(out).passed
    arrays["q"][13, 0] = lim[0, 1] + 0.5                                # and in a free-hand frame: checked
    np.savez(path, **arrays)
    failing = check_result(out)
    assert not failing.passed and failing.solutions[0].figures["joint_limit_rad"].frame == 13
    arrays["q"][13, 0] = arrays["q"][12, 0]
    del arrays["frame_status"]
    np.savez(path, **arrays)
    old = check_result(out)
    assert not old.passed and old.solutions[0].unsolved == ()
    assert old.solutions[0].figures["joint_limit_rad"].frame == mid
    arrays["frame_status"] = np.full(14, 7, dtype=np.int8)             # not a code
    np.savez(path, **arrays)
    with pytest.raises(FileFormatError, match="frame_status"):
        check_result(out)


# --- the CLI ---------------------------------------------------------------------------------------------------

def test_cli_bad_input_exits_2_before_any_work(tmp_path, capsys):
    out = tmp_path / "o"
    assert cli(["fill", "box-turn", "--out", str(out), "--window", "20", "--overlap", "10"]) == 2
    assert "--window" in capsys.readouterr().err and not out.exists()
    assert cli(["fill", "no-such-scene", "--out", str(out)]) == 2
    assert not out.exists() or not any(out.iterdir())
    assert cli(["fill", "box-turn", "--out", str(out), "--slide-speed", "-1"]) == 2
    capsys.readouterr()
    if not torch.cuda.is_available():
        assert cli(["fill", "box-turn", "--out", str(out), "--device", "cuda"]) == 2
        assert "no CUDA device" in capsys.readouterr().err and not out.exists()
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "notes.txt").write_text("mine")
    assert cli(["fill", "box-turn", "--out", str(busy), "--max-nodes", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not empty" in err
    assert (busy / "notes.txt").read_text() == "mine"


def test_cli_refuses_an_earlier_result_without_overwrite(filled, tmp_path, capsys):
    out = tmp_path / "copy"
    shutil.copytree(filled[0], out)
    before = sorted(p.name for p in (out / "solutions").iterdir())
    assert cli(["fill", "box-turn", "--out", str(out), "--max-nodes", "1"]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert sorted(p.name for p in (out / "solutions").iterdir()) == before
    assert math.isfinite(json.loads((out / "stats.json").read_text())["time_s"])
