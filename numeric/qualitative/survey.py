"""Step 1 of the paper in the simulator: observe from every landmark (a survey)."""

from __future__ import annotations

import numpy as np

from chizu.numeric.observation import Observation
from chizu.numeric.simulator import LandmarkObserver, ObserverConfig
from chizu.numeric.world import World


def survey(world: World, config: ObserverConfig, seed: int = 0) -> list[Observation]:
    """One panoramic observation at each placed landmark, random heading, seeded noise."""
    rng = np.random.default_rng(seed)
    observer = LandmarkObserver(world, config, rng)
    out = []
    for lid, xy in zip(world.landmark_ids, world.landmark_xy, strict=True):
        pose = np.array([xy[0], xy[1], rng.uniform(-np.pi, np.pi)])
        out.append(observer.observe(pose, at=lid))
    return out
