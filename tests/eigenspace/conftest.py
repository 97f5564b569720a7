"""Room A and a small analysis of it (32 x 16 px images, K = 12), shared by the
eigenspace tests: computed once per test process."""

from __future__ import annotations

import pytest

from chizu.numeric.eigenspace.analysis import EigenspaceAnalysis, EigenspaceConfig, analyse
from chizu.numeric.world import World
from chizu.numeric.worlds import room_a

SMALL = {"camera": {"width_px": 32, "height_px": 16}, "learning": {"k": 12},
         "entry": {"samples": 30}, "regions": {"calibration_per_triplet": 2}}


@pytest.fixture(scope="session")
def room() -> World:
    return World(room_a())


@pytest.fixture(scope="session")
def analysis(room: World) -> EigenspaceAnalysis:
    return analyse(room, EigenspaceConfig.model_validate(SMALL))
