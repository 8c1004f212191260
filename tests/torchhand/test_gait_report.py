"""scripts/gait_report.py: relocation and rolling found from contact tracks, and not found where there is none."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))

from gait_report import _slip, analyse  # noqa: E402

T = 30


def _track(mask, p_obj, p_link, link=None, slide=None, slip=None) -> dict:
    mask = np.asarray(mask, bool)
    return {"hand": "right", "finger": "index", "mask": mask, "p_obj": np.asarray(p_obj, float),
            "p_link": np.asarray(p_link, float), "link": np.where(mask, 7, -1) if link is None else np.asarray(link),
            "slide": np.zeros(T, bool) if slide is None else np.asarray(slide, bool),
            "slip": np.zeros(T) if slip is None else np.asarray(slip, float)}


def _two_runs(second_at: float) -> dict:
    mask = np.zeros(T, bool)
    mask[0:10] = mask[15:25] = True
    p_obj = np.zeros((T, 3))
    p_obj[15:25, 0] = second_at
    return _track(mask, p_obj, np.zeros((T, 3)))


def test_a_finger_that_comes_back_elsewhere_relocates():
    far, near = analyse(_two_runs(0.02), 0.01, 0.003), analyse(_two_runs(0.004), 0.01, 0.003)
    assert far["relocates"] and far["relocations"][0]["frame"] == 15
    assert abs(far["relocations"][0]["distance_m"] - 0.02) < 1e-12
    assert not near["relocates"]
    assert not far["rolls"] and not near["rolls"]


def _rolling(slide=None, on_object=0.0) -> dict:
    mask = np.ones(T, bool)
    p_link = np.zeros((T, 3))
    p_link[:, 1] = np.linspace(0.0, 0.006, T)                  # 6 mm along the phalanx
    p_obj = np.zeros((T, 3))
    p_obj[:, 2] = np.linspace(0.0, on_object, T)
    return _track(mask, p_obj, p_link, slide=slide)


def test_a_contact_moving_on_the_finger_and_not_on_the_object_rolls():
    assert analyse(_rolling(), 0.01, 0.003)["rolls"]
    assert not analyse(_rolling(on_object=0.006), 0.01, 0.003)["rolls"]       # moves as much on both: no
    assert not analyse(_rolling(slide=np.ones(T, bool)), 0.01, 0.003)["rolls"]  # sliding, not rolling


def test_passing_to_another_phalanx_while_static_rolls():
    mask = np.ones(T, bool)
    link = np.where(np.arange(T) < 15, 7, 6)
    out = analyse(_track(mask, np.zeros((T, 3)), np.zeros((T, 3)), link=link), 0.01, 0.003)
    assert out["rolls"] and out["runs"][0]["stretches"][0]["phalanx_change"]


def test_rolling_without_slipping_moves_on_both_surfaces_and_does_not_slip():
    """The contact moves 6 mm on the finger and on the object: rolling without slipping when the touching material
    point slips little (0.05 mm a frame), not when it slips as far as the contact moves (0.2 mm a frame)."""
    rolling = _rolling(on_object=0.006)
    assert analyse(rolling, 0.01, 0.003)["rolls_without_slip"]
    slipping = dict(rolling, slip=np.full(T, 0.006 / (T - 1)))
    assert not analyse(slipping, 0.01, 0.003)["rolls_without_slip"]
    assert not analyse(_rolling(), 0.01, 0.003)["rolls_without_slip"]          # static on the object: no


def _pose(x: float, angle: float = 0.0) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    T_ = np.eye(4)
    T_[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T_[0, 3] = x
    return T_


def test_slip_is_how_far_the_touching_material_point_moves_on_the_object():
    """A link carried along with the object does not slip; one moved 1 mm a frame over a still object slips 1 mm a
    frame; frames where the finger does not touch at both ends count nothing."""
    n = 5
    obj = np.stack([_pose(0.01 * t, 0.1 * t) for t in range(n)])
    carried = np.stack([[o @ _pose(0.02)] for o in obj])                       # (n, 1, 4, 4)
    mask, link, p_link = np.ones(n, bool), np.zeros(n, int), np.tile([0.0, 0.01, 0.0], (n, 1))
    np.testing.assert_allclose(_slip(carried, np.linalg.inv(obj), mask, link, p_link), 0.0, atol=1e-12)
    moved = np.stack([[_pose(0.001 * t)] for t in range(n)])
    still = np.linalg.inv(np.stack([np.eye(4)] * n))
    np.testing.assert_allclose(_slip(moved, still, mask, link, p_link), [0.0] + [0.001] * (n - 1), atol=1e-12)
    mask[2] = False
    assert _slip(moved, still, mask, link, p_link)[2:4].tolist() == [0.0, 0.0]
