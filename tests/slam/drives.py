"""Simulated drives shared by the SLAM tests."""

from __future__ import annotations

import numpy as np

from chizu.numeric.laser import LaserConfig
from chizu.numeric.scan import LaserLog
from chizu.numeric.simulator import OdometryConfig
from chizu.numeric.slam.simulate import drive
from chizu.numeric.world import World

#: once around room_a, clear of its boxes
ROOM_A_TOUR = np.array([(1.5, 1.5), (9.2, 1.5), (9.2, 9.2), (1.0, 9.2), (1.0, 1.5)])

#: a near-exact odometry, and one whose heading random-walks 0.2 rad per sqrt(m) with
#: 10 % turn noise
ODOMETRY_QUALITIES = {
    "exact": OdometryConfig(distance_noise_ratio=0.001, turn_noise_ratio=0.001,
                            heading_drift_rad_per_m=0.0),
    "drifting": OdometryConfig(distance_noise_ratio=0.05, turn_noise_ratio=0.1,
                               heading_drift_rad_per_m=0.2),
}

#: between the two: a heading random walk of 0.05 rad per sqrt(m) (0.022 rad per 0.2 m,
#: more than the fixed motion model's 0.015) and 5 % turn noise
MODERATE_ODOMETRY = OdometryConfig(distance_noise_ratio=0.05, turn_noise_ratio=0.05,
                                   heading_drift_rad_per_m=0.05)


def room_a_drives(room: World, laser: LaserConfig | None,
                  qualities: dict[str, OdometryConfig] | None = None) -> dict[str, LaserLog]:
    """:data:`ROOM_A_TOUR` at 0.5 m/s with each of ``qualities`` (by default
    :data:`ODOMETRY_QUALITIES`; seed 1)."""
    return {name: drive(room, ROOM_A_TOUR, odo, laser, 0.5, np.random.default_rng(1), name)
            for name, odo in (qualities or ODOMETRY_QUALITIES).items()}
