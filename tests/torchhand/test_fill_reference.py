"""The captured fingers as a reference (torchhand.fill.reference) on ManipNet's mug1."""

from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import shared_data_dir
from torchhand.fill.reference import captured_fingertips, compare_fingers, plot_comparison

MUG = shared_data_dir() / "mocap" / "manipnet" / "mug1"


@pytest.mark.skipif(not (MUG / "rightHand.bvh").is_file(), reason=f"ManipNet mug1 not found under {MUG}")
def test_captured_fingertips_are_plausible_and_agree_with_themselves(tmp_path):
    from torchhand.scene.mocap import manipnet_scene

    s = manipnet_scene(MUG, fps=30.0, hands=("right",)).with_frames(614, 674)
    tips = captured_fingertips(s, "right")
    assert tips.shape == (60, 5, 3) and np.isfinite(tips).all()
    reach = np.median(np.linalg.norm(tips - s.hands[0].wrist_pose[:, None, :3, 3].numpy(), axis=-1), 0)
    assert ((reach > 0.09) & (reach < 0.22)).all(), reach           # fingertips a hand's length from the wrist
    c = compare_fingers(tips, None, s, "right")
    summary = c.summary()
    assert summary["tip_distance_mm"]["median"] == 0.0 and summary["contact_agreement"] == 1.0
    assert summary["captured_contact"] > 0.5                        # the hand holds the mug in this segment
    moved = tips + np.array([0.0, 0.0, 0.05])
    assert compare_fingers(moved, None, s, "right").summary()["tip_distance_mm"]["median"] == pytest.approx(50.0)
    assert plot_comparison(c, tmp_path / "cmp.png", fps=s.fps).is_file()
