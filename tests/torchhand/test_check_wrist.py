"""The checker's wrist deviation: information from a solution file's root_pose_captured, never a verdict."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from torchhand.check.wrist import wrist_deviation
from torchhand.io.result import HandSolution


def _rot_z(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def test_wrist_deviation_per_frame_against_known_offsets():
    T = 5
    cap = np.tile(np.eye(4), (T, 1, 1))
    used = cap.copy()
    used[:, 0, 3] += np.array([0, 1, 2, 3, 4]) * 1e-3                  # 0..4 mm along x
    used[2, :3, :3] = _rot_z(math.radians(2.0))                          # 2 degrees at frame 2
    hands = (HandSolution(side="right", q=np.zeros((T, 3)), joint_names=("a", "b", "c"), root_pose=used,
                          root_pose_captured=cap),
             HandSolution(side="left", q=np.zeros((T, 3)), joint_names=("a", "b", "c"), root_pose=cap))
    d = wrist_deviation(SimpleNamespace(hands=hands))
    assert set(d) == {"right"}                                           # the left hand keeps no captured track
    r = d["right"]
    np.testing.assert_allclose(r["translation_mm"], [0, 1, 2, 3, 4], atol=1e-9)
    np.testing.assert_allclose(r["rotation_deg"], [0, 0, 2, 0, 0], atol=1e-6)
    assert r["max_translation_mm"] == 4.0 and abs(r["max_rotation_deg"] - 2.0) < 1e-6 and r["frames_moved"] == 4
    assert wrist_deviation(SimpleNamespace(hands=hands[1:])) == {}
