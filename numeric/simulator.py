"""The one simulator: a robot with noisy odometry and a landmark observer.

The camera (:mod:`chizu.numeric.camera`) and the laser (:mod:`chizu.numeric.laser`) ray-cast against
the same :class:`chizu.numeric.world.World`; :func:`follow_path` and :func:`odometry_along` drive
the robot for recorded runs.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, Field

from chizu.numeric.geometry import compose, line_of_sight, relative, segments_cross, wrap_angle
from chizu.numeric.observation import Observation, SeenLandmark
from chizu.numeric.world import World


class ObserverConfig(BaseModel):
    """Landmark observer: recognition radius and measurement noise (1-sigma)."""

    recognition_radius_m: float = Field(8.0, gt=0, le=1000.0, allow_inf_nan=False)
    bearing_noise_rad: float = Field(0.0, ge=0, le=10.0, allow_inf_nan=False)
    distance_noise_m: float = Field(0.0, ge=0, le=100.0, allow_inf_nan=False)
    distance_noise_ratio: float = Field(0.0, ge=0, le=10.0, allow_inf_nan=False,
                                        description="extra sigma per metre of range")


class OdometryConfig(BaseModel):
    """Odometry error: multiplicative sigma on distance and turn, additive heading drift."""

    distance_noise_ratio: float = Field(0.02, ge=0, le=1.0, allow_inf_nan=False)
    turn_noise_ratio: float = Field(0.02, ge=0, le=1.0, allow_inf_nan=False)
    heading_drift_rad_per_m: float = Field(0.005, ge=0, le=1.0, allow_inf_nan=False)
    distance_bias_ratio: float = Field(0.0, ge=-0.5, le=0.5, allow_inf_nan=False,
                                       description="systematic scale error (wheel slip)")


class LandmarkObserver:
    """Recognises landmarks within radius r and line of sight; measures bearing and range."""

    def __init__(self, world: World, config: ObserverConfig, rng: np.random.Generator) -> None:
        self.world, self.config, self.rng = world, config, rng

    def visible(self, xy: np.ndarray) -> np.ndarray:
        """Indices of landmarks recognisable from position ``xy`` (2,)."""
        w = self.world
        if len(w.landmark_xy) == 0:
            return np.zeros(0, dtype=int)
        d = np.linalg.norm(w.landmark_xy - xy, axis=1)
        near = np.flatnonzero((d <= self.config.recognition_radius_m) & (d > 1e-9))
        if len(near) == 0:
            return near
        los = line_of_sight(xy, w.landmark_xy[near], w.wall_a, w.wall_b)
        return near[los]

    def scan(self, pose: np.ndarray) -> list[tuple[str, float, float]]:
        """(landmark id, noisy bearing in the robot frame, noisy range) of every
        recognisable landmark."""
        return [(s.landmark, s.bearing_rad, s.distance_m)
                for s in self._measure_all(pose, exclude=None)]

    def observe(self, pose: np.ndarray, at: str) -> Observation:
        """One panoramic observation from ``pose`` (x, y, theta) taken at landmark ``at``.

        Bearings are in the robot frame (counter-clockwise from the heading),
        distances in metres, both with the configured Gaussian noise.
        """
        return Observation(at=at, seen=self._measure_all(pose, exclude=at))

    def _measure_all(self, pose: np.ndarray, exclude: str | None) -> list[SeenLandmark]:
        xy, theta = np.asarray(pose[:2], dtype=float), float(pose[2])
        seen: list[SeenLandmark] = []
        cfg = self.config
        for i in self.visible(xy):
            lm = self.world.placed_landmarks[i]
            if lm.id == exclude:
                continue
            delta = self.world.landmark_xy[i] - xy
            rng_m = float(np.hypot(*delta))
            world_dir = float(np.arctan2(delta[1], delta[0]))
            b = float(wrap_angle(world_dir - theta + self.rng.normal(0, cfg.bearing_noise_rad)))
            sigma_d = cfg.distance_noise_m + cfg.distance_noise_ratio * rng_m
            dist = max(0.0, rng_m + float(self.rng.normal(0, sigma_d)))
            # a feature is seen when the robot lies within its angular window
            view_from_lm = world_dir + np.pi
            feats = [f.name for f in lm.features
                     if abs(float(wrap_angle(view_from_lm - f.direction_rad))) <= f.half_width_rad]
            seen.append(SeenLandmark(landmark=lm.id, bearing_rad=b, distance_m=dist,
                                     features=feats))
        return seen

    def measure(self, pose: np.ndarray, landmark_id: str) -> tuple[float, float] | None:
        """Noisy (bearing, distance) of one landmark, or None if not recognisable."""
        i = self.world.landmark_index[landmark_id]
        xy = np.asarray(pose[:2], dtype=float)
        if i not in set(self.visible(xy).tolist()):
            return None
        delta = self.world.landmark_xy[i] - xy
        r = float(np.hypot(*delta))
        b = float(wrap_angle(np.arctan2(delta[1], delta[0]) - pose[2]
                             + self.rng.normal(0, self.config.bearing_noise_rad)))
        sd = self.config.distance_noise_m + self.config.distance_noise_ratio * r
        return b, max(0.0, r + float(self.rng.normal(0, sd)))


@dataclass
class Robot:
    """A differential-drive robot moving by (turn, forward) commands with noisy execution.

    ``pose`` is the true pose (x, y, theta); ``travelled_m`` the true path length;
    ``collided`` becomes True when a forward motion would cross a wall (the robot
    stops in front of it).
    """

    world: World
    pose: np.ndarray
    odometry: OdometryConfig
    rng: np.random.Generator
    travelled_m: float = 0.0
    collided: bool = False
    odom_pose: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def turn(self, angle_rad: float) -> None:
        """Turn in place by ``angle_rad`` (executed with multiplicative noise)."""
        actual = angle_rad * (1.0 + self.rng.normal(0, self.odometry.turn_noise_ratio))
        self.pose[2] = float(wrap_angle(self.pose[2] + actual))
        self.odom_pose[2] = float(wrap_angle(self.odom_pose[2] + angle_rad))

    def forward(self, distance_m: float) -> bool:
        """Drive straight; returns False (and stops) on collision with a wall."""
        d = distance_m * (1.0 + self.rng.normal(0, self.odometry.distance_noise_ratio))
        drift = self.rng.normal(0, self.odometry.heading_drift_rad_per_m * max(d, 0.0))
        heading = self.pose[2] + 0.5 * drift
        start = self.pose[:2].copy()
        end = start + d * np.array([np.cos(heading), np.sin(heading)])
        if segments_cross(start, end, self.world.wall_a, self.world.wall_b)[0]:
            self.collided = True
            return False
        self.pose[:2] = end
        self.pose[2] = float(wrap_angle(self.pose[2] + drift))
        self.travelled_m += float(np.hypot(*(end - start)))
        o = self.odom_pose
        o[:2] += distance_m * np.array([np.cos(o[2]), np.sin(o[2])])
        return True


def follow_path(waypoints: np.ndarray, speed_m_s: float, period_s: float,
                turn_rate_rad_s: float = 1.0) -> np.ndarray:
    """True poses ``(N, 3)`` every ``period_s`` of a robot that turns in place towards the
    next waypoint (at ``turn_rate_rad_s``) and drives straight to it at ``speed_m_s``."""
    wp = np.asarray(waypoints, dtype=float)
    pose = np.array([wp[0, 0], wp[0, 1], 0.0])
    if len(wp) > 1:
        pose[2] = np.arctan2(*(wp[1] - wp[0])[::-1])
    out = [pose.copy()]
    for target in wp[1:]:
        heading = float(np.arctan2(target[1] - pose[1], target[0] - pose[0]))
        while abs(float(wrap_angle(heading - pose[2]))) > 1e-9:
            d = float(wrap_angle(heading - pose[2]))
            pose[2] = float(wrap_angle(pose[2] + np.clip(d, -turn_rate_rad_s * period_s,
                                                         turn_rate_rad_s * period_s)))
            out.append(pose.copy())
        while True:
            gap = target - pose[:2]
            dist = float(np.hypot(*gap))
            if dist < 1e-9:
                break
            pose[:2] += gap * min(1.0, speed_m_s * period_s / dist)
            out.append(pose.copy())
    return np.array(out)


def odometry_along(truth: np.ndarray, config: OdometryConfig,
                   rng: np.random.Generator) -> np.ndarray:
    """Odometry poses ``(N, 3)`` for the true poses ``truth``: each true increment
    (in the robot frame) is read with a distance scale error, multiplicative distance and
    turn noise and a
    random-walk heading drift (``heading_drift_rad_per_m`` per sqrt(m) of travel), and
    the noisy increments are integrated from ``truth[0]``."""
    inc = relative(truth[:-1], truth[1:])
    dist = np.hypot(inc[:, 0], inc[:, 1])
    noisy = inc.copy()
    noisy[:, :2] *= (1 + config.distance_bias_ratio
                     + rng.normal(0, config.distance_noise_ratio, len(inc)))[:, None]
    noisy[:, 2] = (inc[:, 2] * (1 + rng.normal(0, config.turn_noise_ratio, len(inc)))
                   + rng.normal(0, config.heading_drift_rad_per_m * np.sqrt(dist + 1e-12)))
    odom = [truth[0].copy()]
    for u in noisy:
        odom.append(compose(odom[-1], u))
    return np.array(odom)
