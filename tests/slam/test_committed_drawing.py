"""A large committed map's drawing (the console's map layer, ``map.png?max_px=2048``) is
made once, when the map is committed, and served from the store: the same image and
YAML a downsample of the stored grid gives, at most 2048 px a side."""

from __future__ import annotations

import asyncio
from pathlib import Path

import numpy as np

from chizu.numeric.occupancy import FREE, OCCUPIED, UNKNOWN, OccupancyMap
from chizu.numeric.world import WorldDescription
from chizu.service.container import open_services
from chizu.service.settings import Settings
from chizu.service.slam import DRAWING_ARTIFACT, DRAWING_PX


def test_a_large_maps_drawing_is_made_at_commit(tmp_path: Path) -> None:
    state = np.full((2600, 2100), FREE, dtype=np.int8)
    state[::100, :] = OCCUPIED  # one-cell walls
    state[:40, :40] = UNKNOWN
    grid = OccupancyMap(np.array([-3.0, 1.0]), 0.05, state, np.full(state.shape, np.nan))
    sv = open_services(Settings(data_dir=tmp_path, demo_world="demo", workers=0))

    async def run() -> None:
        await sv.worlds.create(WorldDescription(name="big"))
        assert sv.store.artifact("big", DRAWING_ARTIFACT) is None
        await sv.slam._commit_map("big", "r" + "0" * 16, grid, np.zeros((1, 3)), [], b"")
        stored = sv.store.artifact("big", DRAWING_ARTIFACT)
        assert stored is not None and await sv.slam.committed_png("big", DRAWING_PX) == stored
        made = await sv.slam.committed_grid("big", DRAWING_PX)  # decoded and downsampled
        assert made.to_png() == stored
        assert await sv.slam.committed_yaml("big", DRAWING_PX) == \
            made.to_yaml("map.pgm").encode()
        width, height = int.from_bytes(stored[16:20], "big"), int.from_bytes(stored[20:24],
                                                                              "big")
        assert max(width, height) <= DRAWING_PX and (width, height) == made.shape
        # another size is still made on demand
        assert (await sv.slam.committed_grid("big", 500)).shape == (434, 350)  # blocks of 6 x 6

    try:
        asyncio.run(run())
    finally:
        sv.close()
