"""The mount fit (torchhand.synthesis.mount_fit): it finds back a known displacement of the wrist track, never
scores below the unmoved mount, is deterministic, and the fitted mount travels with the scene (scene.toml)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

import torchhand
from torchhand.errors import FileFormatError, InputValueError
from torchhand.hand.mount import mount_transform, track_hand
from torchhand.synthesis.mount_fit import fit_mount, fit_mounts

from tests.conftest import shared_path


def _displaced(scene, shift):
    """``scene`` with its hand's wrist track moved by ``shift`` (metres, hand frame)."""
    D = torch.eye(4, dtype=torch.float64)
    D[:3, 3] = torch.tensor(shift, dtype=torch.float64)
    t = scene.hands[0]
    return dataclasses.replace(scene, hands=(dataclasses.replace(t, wrist_pose=t.wrist_pose @ D),))


def test_fit_finds_back_a_displaced_track():
    """box-turn's track pulled 15 mm away from the box's side and 10 mm up, so that the thumb no longer reaches it
    on every frame: the fit moves the hand back toward where it was, far enough to reach on (nearly) every frame."""
    d = np.array((0.0, 0.015, 0.010))
    scene = _displaced(torchhand.load_scene("box-turn"), tuple(d))
    fit = fit_mount(scene, "right")
    shift = np.array(fit.mount[:3])
    assert fit.score_unmoved < 0.9 and fit.score > 0.95, fit.describe()
    assert float(shift @ -d) > 0 and np.linalg.norm(shift) <= np.linalg.norm(d) + 0.005, fit.describe()
    again = fit_mount(scene, "right")
    assert again.mount == fit.mount and again.score == fit.score          # deterministic


def test_fit_keeps_a_good_mount_nearly_where_it_is():
    """On the track made for it, the built-in hand moves little: within 2.5 cm and 15 degrees."""
    fit = fit_mount(torchhand.load_scene("box-turn"), "right")
    assert np.linalg.norm(fit.mount[:3]) <= 0.025 and np.linalg.norm(fit.mount[3:]) <= 15.0
    assert fit.score >= fit.score_unmoved


def test_mount_moves_the_model_on_the_track():
    scene = torchhand.load_scene("box-turn")
    t = scene.hands[0]
    mount = (0.01, -0.02, 0.005, 0.0, 0.0, 30.0)
    a, b = track_hand(t), track_hand(dataclasses.replace(t, mount=mount))
    q = a.q_rest[None]
    Ta, Tb = a.forward_kinematics(q)[0], b.forward_kinematics(q)[0]
    M = torch.as_tensor(mount_transform(mount))
    assert torch.allclose(M @ Ta, Tb, atol=1e-12)
    with pytest.raises(InputValueError, match="mount"):
        dataclasses.replace(t, mount=(0.0, 1.0))


def test_fitted_mount_travels_with_the_scene(tmp_path):
    hand = shared_path("hands", "allegro_hand", "right_hand.xml")
    scene = torchhand.load_scene("cube-turn")
    scene = dataclasses.replace(scene, hands=(dataclasses.replace(scene.hands[0], model=str(hand)),))
    fitted, fits = fit_mounts(scene)
    assert len(fits) == 1 and fitted.hands[0].mount == fits[0].mount
    again, none = fit_mounts(fitted)                                        # a mount already given wins
    assert none == () and again.hands[0].mount == fits[0].mount
    fitted.export(tmp_path / "s")
    back = torchhand.load_scene(tmp_path / "s")
    assert back.hands[0].mount == pytest.approx(fits[0].mount, abs=1e-15)
    text = (tmp_path / "s" / "scene.toml").read_text()
    (tmp_path / "s" / "scene.toml").write_text(text.replace("mount = [", "mount = [1, "))
    with pytest.raises(FileFormatError, match="hands\\[0\\].mount"):
        torchhand.load_scene(tmp_path / "s")


def test_fit_does_not_flip_under_a_tiny_perturbation():
    """The fitted mount and rest of the displaced track are the same with the track moved by 1e-9 m and with two
    threads instead of one."""
    scene = _displaced(torchhand.load_scene("box-turn"), (0.0, 0.015, 0.010))
    base = fit_mount(scene, "right")
    nudged = fit_mount(_displaced(scene, (1e-9, -1e-9, 1e-9)), "right")
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(2 if threads != 2 else 1)
        other = fit_mount(scene, "right")
    finally:
        torch.set_num_threads(threads)
    assert nudged.mount == base.mount and nudged.rest == base.rest
    assert other.mount == base.mount and other.rest == base.rest
