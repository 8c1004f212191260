"""The wrist steadied against a held object within a tolerance (torchhand.fill.wrist)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from torchhand.errors import InputValueError
from torchhand.fill.wrist import WristTolerance, parse_tolerance, steady_wrist
from torchhand.geometry.poses import quat_to_matrix


def _poses(rot: torch.Tensor, pos: torch.Tensor) -> torch.Tensor:
    T = torch.eye(4, dtype=torch.float64).repeat(rot.shape[0], 1, 1)
    T[:, :3, :3], T[:, :3, 3] = rot, pos
    return T


def _jittered_grip(T=120, jitter_mm=2.0, jitter_deg=1.0, seed=0):
    """An object turning and rising; a wrist held rigidly to it, plus per-frame jitter (the capture's noise)."""
    g = torch.Generator().manual_seed(seed)
    s = torch.linspace(0, 1, T, dtype=torch.float64)
    axis = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    ang = 1.2 * s
    q = torch.stack([torch.cos(ang / 2), *(torch.sin(ang / 2)[None] * axis[:, None])], -1)
    obj = _poses(quat_to_matrix(q), torch.stack([0.1 * s, 0 * s, 0.2 * s], -1))
    rel = _poses(torch.eye(3, dtype=torch.float64).expand(T, 3, 3), torch.tensor([0.0, -0.08, 0.03]).expand(T, 3))
    noise_q = torch.cat([torch.ones(T, 1, dtype=torch.float64),
                         0.5 * math.radians(jitter_deg) * torch.randn(T, 3, generator=g, dtype=torch.float64)], 1)
    noise = _poses(quat_to_matrix(noise_q / noise_q.norm(dim=-1, keepdim=True)),
                   1e-3 * jitter_mm * torch.randn(T, 3, generator=g, dtype=torch.float64))
    return obj, obj @ rel @ noise


def _relative_step(wrist, obj):
    rel = torch.linalg.solve(obj, wrist)
    return (rel[1:, :3, 3] - rel[:-1, :3, 3]).norm(dim=-1)


def test_steady_wrist_removes_jitter_within_the_tolerance():
    obj, wrist = _jittered_grip()
    held = np.zeros(120, bool)
    held[30:100] = True
    tol = WristTolerance()
    adj = steady_wrist(wrist, obj, held, fps=30.0, tolerance=tol)
    assert adj.translation.max() <= tol.translation + 1e-12 and adj.rotation.max() <= tol.rotation + 1e-9
    before = _relative_step(wrist, obj)[35:95].median()
    after = _relative_step(adj.used, obj)[35:95].median()
    assert after < 0.3 * before, f"object-relative step {after * 1e3:.2f} mm vs {before * 1e3:.2f} mm captured"
    far = torch.tensor(adj.weight.numpy() == 0)
    assert far[:10].all() and torch.equal(adj.used[far], wrist[far])       # untouched far from the held frames
    assert adj.summary()["frames_moved"] >= 70
    R = adj.used[:, :3, :3]
    torch.testing.assert_close(R @ R.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand_as(R))


def test_zero_tolerance_keeps_the_capture_and_parsing():
    obj, wrist = _jittered_grip(T=40)
    adj = steady_wrist(wrist, obj, np.ones(40, bool), fps=30.0, tolerance=parse_tolerance("0"))
    assert torch.equal(adj.used, wrist.double()) and float(adj.translation.max()) == 0.0
    t = parse_tolerance("5,3")
    assert t.translation == pytest.approx(0.005) and t.rotation == pytest.approx(math.radians(3))
    for bad in ("5", "a,b", "-1,2", "1,2,3"):
        with pytest.raises(InputValueError, match="wrist-tolerance"):
            parse_tolerance(bad)
    with pytest.raises(InputValueError, match="held"):
        steady_wrist(wrist, obj, np.ones(39, bool), fps=30.0)


def test_a_tiny_tolerance_bounds_every_frame():
    obj, wrist = _jittered_grip(jitter_mm=4.0, jitter_deg=2.0, seed=3)
    tol = WristTolerance(translation=0.001, rotation=math.radians(0.5))
    adj = steady_wrist(wrist, obj, np.ones(120, bool), fps=30.0, tolerance=tol)
    assert adj.translation.max() <= 0.001 + 1e-12 and adj.rotation.max() <= math.radians(0.5) + 1e-9
    assert _relative_step(adj.used, obj).median() < _relative_step(wrist, obj).median()


def test_a_steadied_scene_keeps_the_capture_through_files_and_slices(tmp_path):
    """with_wrist keeps the captured track; it survives the scene directory, with_frames and resample."""
    import torchhand
    from torchhand.fill.wrist import with_wrist
    from torchhand.scene import load_scene

    scene = load_scene("box-turn")
    side = scene.hands[0].side
    captured = scene.hands[0].wrist_pose.clone()
    moved = captured.clone()
    moved[:, :3, 3] += 0.001
    s2 = with_wrist(scene, side, moved)
    assert torch.equal(s2.hands[0].captured_wrist_pose, captured) and torch.equal(s2.hands[0].wrist_pose, moved)
    s3 = with_wrist(s2, side, captured)                       # moving again keeps the original capture
    assert torch.equal(s3.hands[0].captured_wrist_pose, captured)
    back = load_scene(s2.export(tmp_path / "scene"))
    assert torch.equal(back.hands[0].captured_wrist_pose, captured)
    assert torch.equal(back.with_frames(3, 9).hands[0].captured_wrist_pose, captured[3:9])
    assert back.resample(15.0).hands[0].captured_wrist_pose.shape[0] == back.resample(15.0).T
    assert load_scene("box-turn").hands[0].captured_wrist_pose is None
    del torchhand
