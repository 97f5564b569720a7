"""A committed map drawn at screen size: blocks of cells merged so that a wall one cell
thick stays visible, free stays free, and the map still covers the same ground."""

from __future__ import annotations

import numpy as np

from chizu.numeric.occupancy import FREE, OCCUPIED, UNKNOWN, OccupancyMap


def test_downsampling_keeps_walls_free_space_and_extent() -> None:
    state = np.full((1000, 600), UNKNOWN, dtype=np.int8)
    state[100:900, 100:500] = FREE
    state[437, 100:500] = OCCUPIED  # a wall one cell thick
    inten = np.full(state.shape, np.nan)
    inten[437, 300] = 7.0
    g = OccupancyMap(np.array([-5.0, 2.0]), 0.05, state, inten)
    d = g.downsampled(128)
    f = 8  # ceil(1000 / 128)
    assert d.shape == (125, 75) and d.resolution_m == 0.05 * f
    assert np.allclose(d.origin, g.origin)
    assert (d.state[437 // f, 100 // f + 1:500 // f - 1] == OCCUPIED).all()
    assert d.state[0, 0] == UNKNOWN and d.state[30, 30] == FREE
    assert np.nanmax(d.intensity) == 7.0 and np.isnan(d.intensity[0, 0])
    # the same ground: the drawing spans at least the map's extent
    assert d.shape[0] * d.resolution_m >= g.shape[0] * g.resolution_m
    assert g.downsampled(1000) is g
