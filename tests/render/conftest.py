"""Fixtures of the rendering tests: a real `torchhand synthesize box-turn` output (:mod:`.real_result`) and a small
two-hand result directory written by :mod:`.fixture_result`."""

from __future__ import annotations

import pytest

from .fixture_result import write_fixture_result
from .real_result import real_box_turn


@pytest.fixture(scope="session")
def box_turn_result(tmp_path_factory):
    """box-turn synthesized: two solutions, 12 frames (see real_result.SYNTHESIZE)."""
    return real_box_turn(tmp_path_factory)


@pytest.fixture(scope="session")
def two_hand_result(tmp_path_factory):
    """two-hand-box cut to 4 frames, one solution, fabricated contacts (see fixture_result)."""
    return write_fixture_result(tmp_path_factory.mktemp("result2") / "two-hand-box", "two-hand-box", frames=4,
                                solutions=1)
