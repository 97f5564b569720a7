"""Simulated laser logs on the built-in worlds (URG-04LX with intensities)."""

from __future__ import annotations

import numpy as np

from numeric.laser import Laser, LaserConfig, record_log
from numeric.scan import LaserLog
from numeric.simulator import OdometryConfig, follow_path, odometry_along
from numeric.world import World
from numeric.worlds import from_template

#: Tours (waypoints) and odometry errors per built-in world. The corridor's odometry
#: under-reads distance by 5 % (slippery floor): only the stripes can correct it.
TOURS: dict[str, tuple[list[tuple[float, float]], OdometryConfig]] = {
    "corridor": ([(3.0, 1.0), (37.0, 1.0)],
                 OdometryConfig(distance_noise_ratio=0.02, turn_noise_ratio=0.02,
                                heading_drift_rad_per_m=0.002, distance_bias_ratio=-0.05)),
    "loop": ([(1.0, 1.0), (23.0, 1.0), (23.0, 13.0), (1.0, 13.0), (1.0, 1.0), (9.0, 1.0)],
             OdometryConfig(distance_noise_ratio=0.15, turn_noise_ratio=0.03,
                            heading_drift_rad_per_m=0.02, distance_bias_ratio=-0.02)),
    "room_a": ([(1.5, 1.5), (8.5, 1.5), (8.5, 8.5), (1.5, 8.5), (1.5, 3.0), (5.0, 5.0)],
               OdometryConfig(distance_noise_ratio=0.05, turn_noise_ratio=0.05,
                              heading_drift_rad_per_m=0.02)),
}


def simulated_log(template: str, seed: int = 0, speed_m_s: float = 0.4,
                  laser: LaserConfig | None = None) -> LaserLog:
    """Drive the tour of ``template`` at ``speed_m_s``, one scan per laser period."""
    waypoints, odo = TOURS[template]
    world = World(from_template(template, template))
    rng = np.random.default_rng(seed)
    sensor = Laser(world, laser)
    truth = follow_path(np.array(waypoints), speed_m_s, sensor.config.scan_period_s)
    odom = odometry_along(truth, odo, rng)
    return record_log(world, truth, odom, sensor, rng, name=template)
