"""Fixtures of the rendering tests: small result directories written by :mod:`.fixture_result`."""

from __future__ import annotations

import pytest

from .fixture_result import write_fixture_result


@pytest.fixture(scope="session")
def box_turn_result(tmp_path_factory):
    """box-turn cut to 10 frames, two solutions, fabricated contacts (see fixture_result)."""
    return write_fixture_result(tmp_path_factory.mktemp("result") / "box-turn", "box-turn", frames=10, solutions=2)


@pytest.fixture(scope="session")
def two_hand_result(tmp_path_factory):
    """two-hand-box cut to 4 frames, one solution."""
    return write_fixture_result(tmp_path_factory.mktemp("result2") / "two-hand-box", "two-hand-box", frames=4,
                                solutions=1)
