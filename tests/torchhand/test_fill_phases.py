"""Phases of a capture (torchhand.fill.phases) and its noise (torchhand.fill.noise): rules on synthetic signals,
the real ManipNet capture, robustness to jitter."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from tests.conftest import shared_data_dir
from torchhand.errors import InputValueError
from torchhand.fill.noise import SLIDE_SPEED_RANGE, capture_noise
from torchhand.fill.phases import (PHASE_KINDS, Phase, PhaseSettings, format_phases, hand_object_distance,
                                   phases_from_signals, segment_phases)

MUG = shared_data_dir() / "mocap" / "manipnet" / "mug1"
needs_mug = pytest.mark.skipif(not (MUG / "rightHand.bvh").is_file(),
                               reason=f"ManipNet mug1 capture not found under {MUG} (set TORCHHAND_SHARED_DATA)")


def _check_cover(phases, T):
    assert phases[0].start == 0 and phases[-1].stop == T
    assert all(a.stop == b.start and a.kind != b.kind for a, b in zip(phases[:-1], phases[1:]))
    assert all(p.kind in PHASE_KINDS and p.stop > p.start for p in phases)


def test_rules_on_signals():
    """Far, closing in, holding a moving object, leaving: free, approach, contact, release, free; a one-frame
    dip and a short gap do not make phases of their own."""
    fps = 30.0
    d = np.r_[np.full(30, 0.3), np.linspace(0.3, 0.05, 15), np.full(60, 0.01), np.linspace(0.05, 0.3, 15),
              np.full(30, 0.3)]
    speed = np.zeros_like(d)
    speed[50:100] = 0.3
    d[70:74] = 0.06                       # a short gap while the object moves: still contact (moving, near)
    d[10] = 0.0                           # a one-frame dip far away: dropped (shorter than min_contact)
    ph = phases_from_signals(d, speed, fps)
    _check_cover(ph, len(d))
    assert [p.kind for p in ph] == ["free", "approach", "contact", "release", "free"]
    contact = ph[2]
    assert contact.start <= 45 and contact.stop >= 105
    assert ph[1].frames <= 15 and ph[3].frames <= 15            # margins bounded by 0.5 s
    assert Phase("contact", 3, 9).to_json() == {"kind": "contact", "start": 3, "stop": 9}
    assert "contact" in format_phases(ph, fps)


def test_all_free_when_the_hand_stays_away():
    d = np.full(40, 0.4)
    speed = np.full(40, 0.5)                 # another hand moves the object: not this hand's contact
    assert [p.kind for p in phases_from_signals(d, speed, 30.0)] == ["free"]


def test_settings_validation():
    with pytest.raises(InputValueError, match="contact_distance"):
        PhaseSettings(contact_distance=-1.0)


@pytest.fixture(scope="module")
def mug():
    from torchhand.scene.mocap import manipnet_scene
    return manipnet_scene(MUG, fps=30.0, hands=("right",))


@needs_mug
def test_mug_phases_cover_the_capture_and_hold_the_lift(mug):
    ph = segment_phases(mug, "right")
    _check_cover(ph, mug.T)
    contact = np.zeros(mug.T, bool)
    for p in ph:
        if p.kind == "contact":
            contact[p.start:p.stop] = True
    assert contact[614:674].all()                                  # the lift and hold of the segment test
    assert ph[0].kind == "free" and ph[0].stop >= 20              # the hand starts away from the mug
    assert 0.3 < contact.mean() < 0.8
    with pytest.raises(InputValueError, match="no 'left' hand"):
        segment_phases(mug, "left")


@needs_mug
def test_mug_phases_survive_tiny_jitter(mug):
    """0.1 mm and 0.05 degree of noise on the wrist change no phase boundary by more than a frame."""
    g = torch.Generator().manual_seed(0)
    W = mug.hands[0].wrist_pose.clone()
    W[:, :3, 3] += 1e-4 * torch.randn(W.shape[0], 3, generator=g, dtype=W.dtype)
    jittered = dataclasses.replace(mug, hands=(dataclasses.replace(mug.hands[0], wrist_pose=W),))
    a, b = segment_phases(mug, "right"), segment_phases(jittered, "right")
    assert [p.kind for p in a] == [p.kind for p in b]
    assert max(abs(p.start - q.start) for p, q in zip(a, b)) <= 1


@needs_mug
def test_noise_gives_the_slide_speed_tuned_by_hand_and_grows_with_jitter(mug):
    seg = mug.with_frames(614, 674)
    noise = capture_noise(seg, "right", segment_phases(seg, "right"))
    assert 0.04 <= noise.slide_speed <= 0.065 and noise.frames == 59     # by hand: 0.05
    assert 1.0 < noise.jitter_mm < 3.0
    g = torch.Generator().manual_seed(1)
    W = seg.hands[0].wrist_pose.clone()
    W[:, :3, 3] += 2e-3 * torch.randn(W.shape[0], 3, generator=g, dtype=W.dtype)
    noisy = dataclasses.replace(seg, hands=(dataclasses.replace(seg.hands[0], wrist_pose=W),))
    more = capture_noise(noisy, "right", segment_phases(seg, "right"))
    assert more.jitter_mm > noise.jitter_mm and more.slide_speed > noise.slide_speed
    assert SLIDE_SPEED_RANGE[0] <= more.slide_speed <= SLIDE_SPEED_RANGE[1]
    none = capture_noise(seg, "right", (Phase("free", 0, seg.T),))
    assert none.slide_speed == SLIDE_SPEED_RANGE[0] and none.frames == 0


def _box_scene(wrist_x: np.ndarray, object_x: np.ndarray | None = None):
    """A 10 cm cube at the origin (or moving along x by ``object_x``) and a right hand with the identity rotation
    whose grasp centre ``(0.6 L, 0, -0.04)`` lies at ``(wrist_x + 0.6 L, 0, 0)``: its distance to the cube is
    ``-0.05 - (wrist_x + 0.6 L)`` while it is left of the cube."""
    import trimesh

    from torchhand.geometry.objects import RigidObject
    from torchhand.scene import HandTrack, Scene

    T, L = len(wrist_x), 0.19
    W = torch.eye(4, dtype=torch.float64).repeat(T, 1, 1)
    W[:, 0, 3] = torch.as_tensor(wrist_x)
    W[:, 2, 3] = 0.04
    O = torch.eye(4, dtype=torch.float64).repeat(T, 1, 1)
    if object_x is not None:
        O[:, 0, 3] = torch.as_tensor(object_x)
    box = RigidObject.from_trimesh(trimesh.creation.box(extents=(0.1, 0.1, 0.1)), mass=0.2, name="box")
    return Scene(name="box", object=box, object_pose=O, fps=30.0, hands=(HandTrack("right", W, length=L),),
                 friction=0.8)


def test_distance_and_phases_on_a_synthetic_scene():
    """The distance is the exact one of the grasp centre; a still cube and a far hand: all free; the hand kept 1 cm
    off the cube: all contact; a far hand while the cube moves: still free (someone else moves it)."""
    L, T = 0.19, 40
    far = _box_scene(np.full(T, -0.05 - 0.6 * L - 0.2))
    np.testing.assert_allclose(hand_object_distance(far, "right"), 0.2, atol=1e-9)
    assert segment_phases(far, "right") == (Phase("free", 0, T),)
    near = _box_scene(np.full(T, -0.05 - 0.6 * L - 0.01))
    np.testing.assert_allclose(hand_object_distance(near, "right"), 0.01, atol=1e-9)
    assert segment_phases(near, "right") == (Phase("contact", 0, T),)
    moving = _box_scene(np.full(T, -0.05 - 0.6 * L - 0.3), object_x=np.linspace(0.0, 0.2, T))
    assert segment_phases(moving, "right") == (Phase("free", 0, T),)
    # the hand comes in, stays 2 s within 1 cm, and leaves: approach, contact, release around one contact phase
    d = np.r_[np.linspace(0.3, 0.01, 30), np.full(60, 0.01), np.linspace(0.01, 0.3, 30)]
    ph = segment_phases(_box_scene(-0.05 - 0.6 * L - d), "right")
    _check_cover(ph, len(d))
    assert [p.kind for p in ph] == ["free", "approach", "contact", "release", "free"]
