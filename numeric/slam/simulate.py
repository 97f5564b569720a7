"""Simulated laser logs: on the built-in worlds (URG-04LX with intensities), and on
office floors made from a seed (:func:`office_log`) that no parameter was chosen on."""

from __future__ import annotations

import numpy as np

from chizu.numeric.laser import Laser, LaserConfig, record_log
from chizu.numeric.scan import LaserLog
from chizu.numeric.simulator import OdometryConfig, follow_path, odometry_along
from chizu.numeric.world import World
from chizu.numeric.worlds import from_template, office_world

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
    return drive(World(from_template(template, template)), np.array(waypoints), odo,
                 laser, speed_m_s, np.random.default_rng(seed), template)


def drive(world: World, waypoints: np.ndarray, odo: OdometryConfig,
          laser: LaserConfig | None, speed_m_s: float, rng: np.random.Generator,
          name: str) -> LaserLog:
    """The log of a robot driving ``waypoints`` through ``world`` at ``speed_m_s``: true
    poses one laser period apart, odometry with the errors of ``odo``, scans."""
    sensor = Laser(world, laser)
    truth = follow_path(waypoints, speed_m_s, sensor.config.scan_period_s)
    odom = odometry_along(truth, odo, rng)
    return record_log(world, truth, odom, sensor, rng, name=name)


#: the lasers of :func:`office_log`: the URG-04LX of Hara et al. (5.6 m, 240°, the
#: simulator's default) and an LMS-like scanner (30 m, 180° in 1° steps, 5 Hz) as on
#: the benchmark logs
OFFICE_LASERS = {
    "urg": LaserConfig(),
    "lms": LaserConfig(max_range_m=30.0, fov_rad=float(np.pi), step_rad=float(np.radians(1.0)),
                       scan_period_s=0.2),
}


def office_tour(seed: int) -> tuple[World, np.ndarray]:
    """An office floor and a tour of it (waypoints ``(W, 2)``) made from ``seed``: 3 to
    5 identical rooms a side of random width and depth (4.5-7 m), a corridor of random
    width (1.8-2.6 m); the tour visits every room's doorway and inside on the way down
    the corridor and back, then re-enters the first room (places seen 2-5 minutes
    before: the loops)."""
    rng = np.random.default_rng(seed)
    k = int(rng.integers(3, 6))
    rw, rd = float(rng.uniform(4.5, 7.0)), float(rng.uniform(4.5, 7.0))
    cw = float(rng.uniform(1.8, 2.6))
    desc = office_world(name=f"unseen{seed}", rooms_per_side=k, room_width_m=rw,
                        room_depth_m=rd, corridor_width_m=cw)
    yc = 0.5 * cw
    way: list[tuple[float, float]] = [(0.8, yc)]

    def visit(i: int, north: bool) -> None:
        cx = (i + 0.5) * rw + float(rng.uniform(-0.15, 0.15))
        sign = 1.0 if north else -1.0
        wall_y = cw if north else 0.0
        inside = (cx + float(rng.uniform(-0.25, 0.25)) * rw,
                  wall_y + sign * float(rng.uniform(0.35, 0.6)) * rd)
        way.extend([(cx, yc), (cx, wall_y + sign * 0.7), inside, (cx, wall_y + sign * 0.7),
                    (cx, yc)])

    order = [(i, bool(rng.random() < 0.5)) for i in range(k)]
    for i, north in order:  # down the corridor, one side's room per section
        visit(i, north)
    way.append((k * rw - 0.8, yc))
    for i, north in reversed(order):  # and back, the other side's
        visit(i, not north)
    way.append((0.8, yc))
    visit(*order[0])  # the first room again
    return World(desc), np.array(way)


def office_log(seed: int, laser: str) -> LaserLog:
    """The simulated log of ``office_tour(seed)``'s tour at 0.4 m/s with the laser
    ``laser`` (a key of :data:`OFFICE_LASERS`): odometry with a random distance bias of
    up to ±3 %, 5 % distance and turn noise and a heading random walk of 0.02 rad/√m."""
    world, way = office_tour(seed)
    rng = np.random.default_rng(1000 + seed)
    odo = OdometryConfig(distance_noise_ratio=0.05, turn_noise_ratio=0.05,
                         heading_drift_rad_per_m=0.02,
                         distance_bias_ratio=float(rng.uniform(-0.03, 0.03)))
    return drive(world, way, odo, OFFICE_LASERS[laser], 0.4, rng, f"unseen{seed}-{laser}")
