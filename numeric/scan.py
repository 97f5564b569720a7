"""Scans with received-light intensity (§3) and the logs they come in."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from chizu.numeric.errors import InvalidInput
from chizu.numeric.geometry import compose, place, relative


@dataclass(frozen=True)
class Scan:
    """One sweep of a planar range finder.

    ``ranges`` (n,) in m along ``angles`` (n,) rad in the sensor frame; ``intensities``
    (n,) the received-light intensity per beam (``None`` when the sensor gives none);
    ``t`` the time stamp in s; ``odom`` the odometry pose (x, y, theta) of the robot at
    ``t``; ``sensor_pose`` the sensor's pose in the robot frame. Beams outside
    ``[min_range_m, max_range_m)`` are no-returns.
    """

    t: float
    ranges: np.ndarray
    angles: np.ndarray
    odom: np.ndarray
    intensities: np.ndarray | None = None
    min_range_m: float = 0.02
    max_range_m: float = 30.0
    sensor_pose: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        validate_scan(self.t, self.ranges, self.angles, self.odom, self.intensities,
                      self.min_range_m, self.max_range_m)

    @property
    def valid(self) -> np.ndarray:
        """Beams with a return inside the usable range."""
        r = self.ranges
        return np.asarray(np.isfinite(r) & (r >= self.min_range_m) & (r < self.max_range_m))

    def points(self) -> tuple[np.ndarray, np.ndarray | None]:
        """Valid returns as points ``(m, 2)`` in the robot frame and their intensities."""
        ok = self.valid
        r, a = self.ranges[ok], self.angles[ok]
        pts = place(np.stack([r * np.cos(a), r * np.sin(a)], axis=1), self.sensor_pose)
        return pts, None if self.intensities is None else self.intensities[ok]

    def misses(self) -> np.ndarray:
        """Ends ``(m, 2)`` (robot frame) of the no-return beams -- ranges at or beyond
        ``max_range_m`` -- placed at ``max_range_m``: space a map may clear, never mark."""
        no = np.asarray(self.ranges >= self.max_range_m)
        a = self.angles[no]
        r = self.max_range_m
        return place(np.stack([r * np.cos(a), r * np.sin(a)], axis=1), self.sensor_pose)


def validate_scan(t: float, ranges: np.ndarray, angles: np.ndarray, odom: np.ndarray,
                  intensities: np.ndarray | None, min_range_m: float,
                  max_range_m: float) -> None:
    """Raise :class:`InvalidInput` naming the field for a malformed scan.

    No-returns must be coded as a range at or beyond ``max_range_m`` (as CARMEN and ROS
    drivers do), not as NaN: a NaN or negative range is an error, not a miss.
    """
    if not np.isfinite(t):
        raise InvalidInput("time stamp must be finite", field="t")
    if ranges.ndim != 1 or len(ranges) == 0:
        raise InvalidInput("ranges must be a non-empty 1-D array", field="ranges")
    if angles.shape != ranges.shape:
        raise InvalidInput(f"angles has {angles.size} values for {ranges.size} ranges",
                           field="angles")
    if not np.all(np.isfinite(ranges)):
        raise InvalidInput("ranges contain NaN or infinity (code a no-return as a range "
                           "at or beyond max_range_m)", field="ranges")
    if np.any(ranges < 0):
        raise InvalidInput("ranges must be >= 0", field="ranges")
    if not np.all(np.isfinite(angles)):
        raise InvalidInput("angles must be finite", field="angles")
    if odom.shape != (3,) or not np.all(np.isfinite(odom)):
        raise InvalidInput("odometry must be 3 finite numbers (x, y, theta)", field="odom")
    if intensities is not None:
        if intensities.shape != ranges.shape:
            raise InvalidInput(f"intensities has {intensities.size} values for "
                               f"{ranges.size} ranges", field="intensities")
        if not np.all(np.isfinite(intensities)):
            raise InvalidInput("intensities must be finite", field="intensities")
    if not (0 <= min_range_m < max_range_m and np.isfinite(max_range_m)):
        raise InvalidInput("need 0 <= min_range_m < max_range_m < inf", field="max_range_m")


def beam_angles(n: int, angle_min: float, increment: float) -> np.ndarray:
    """The ``n`` beam directions ``angle_min + k * increment``."""
    return np.asarray(angle_min + increment * np.arange(n), dtype=float)


@dataclass
class LaserLog:
    """A recorded run: scans in time order (each with its odometry); ``name`` for
    reports; ``truth`` the true poses per scan when the log is simulated."""

    name: str
    scans: list[Scan]
    truth: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.scans)

    @property
    def times(self) -> np.ndarray:
        return np.array([s.t for s in self.scans], dtype=float)

    @property
    def odometry(self) -> np.ndarray:
        return np.array([s.odom for s in self.scans], dtype=float).reshape(-1, 3)

    @property
    def duration_s(self) -> float:
        return float(self.scans[-1].t - self.scans[0].t) if self.scans else 0.0

    def carried(self, start: int, stop: int) -> LaserLog:
        """The log of the robot carried off during scans ``start`` to ``stop - 1``:
        those scans are not logged, and its wheel odometry reads nothing of the carry
        (the wheels did not turn) -- after the gap it goes on from where it was before.
        The kidnapping of Thrun, Burgard, Fox, *Probabilistic Robotics* §8.3.3."""
        if not 0 < start <= stop < len(self):
            raise InvalidInput(f"a carry must lie within the log's {len(self)} scans, after "
                               "its first and before its last", field="scans")
        before, after = self.scans[start - 1].odom, self.scans[stop].odom
        scans = self.scans[:start] + [
            replace(s, odom=compose(before, relative(after, s.odom)))
            for s in self.scans[stop:]]
        keep = np.r_[0:start, stop:len(self)]
        return LaserLog(f"{self.name}-carried", scans,
                        None if self.truth is None else self.truth[keep])

    def head(self, n: int) -> LaserLog:
        """The first ``n`` scans (for quick runs)."""
        return LaserLog(self.name, self.scans[:n],
                        None if self.truth is None else self.truth[:n])
