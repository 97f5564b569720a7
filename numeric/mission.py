"""The mission's robot in the simulator, and its judgement against the simulator's truth.

The service (service/mission.py) runs the mission through the calls a client makes; what
happens in the simulated world is here. The robot wakes up somewhere in the free space
(:func:`wake_up`), moves in small increments keeping its true and odometry poses
(:class:`TracedRobot`), drives the movement strategy's actions (:func:`drive`), fixes its
pose standing at a landmark (:func:`landmark_pose`) and takes laser scans along its way
(:func:`trace_scans`). :class:`MissionTrace` keeps what the robot never reads -- the
truth -- beside its estimates, for :func:`evaluate` and for the figure
(:func:`chizu.numeric.figures.mission_figure`).

Like :mod:`chizu.numeric.figures`, this module composes the method packages (it uses the
qualitative navigation's heading and the viewpoint summary's result); none of them
imports it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from chizu.numeric.errors import InvalidInput
from chizu.numeric.geometry import compose, free_distance, relative, wrap_angle
from chizu.numeric.laser import Laser
from chizu.numeric.occupancy import OccupancyMap
from chizu.numeric.qualitative.navigation import map_heading
from chizu.numeric.scan import Scan
from chizu.numeric.simulator import LandmarkObserver, OdometryConfig, Robot
from chizu.numeric.viewpoint.online import SummaryRun
from chizu.numeric.world import World

#: a region of the floor: its lower and upper corner (m)
Region = tuple[tuple[float, float], tuple[float, float]]
#: the anchored pose must be this close to the truth for a success (m, rad)
POSE_OK_M = 0.5
POSE_OK_RAD = float(np.deg2rad(30))


@dataclass
class TracedRobot(Robot):
    """The simulator's robot, moving in small increments (at most ``max_step_m`` and
    ``max_turn_rad``, as a base controller at 10 Hz would) and keeping every (true pose,
    odometry pose) after one -- what the laser scans are taken at."""

    max_step_m: float = 0.1
    max_turn_rad: float = 0.2
    trace: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    tracing: bool = False

    def _keep(self) -> None:
        if self.tracing:
            self.trace.append((self.pose.copy(), self.odom_pose.copy()))

    def turn(self, angle_rad: float) -> None:
        n = max(1, math.ceil(abs(angle_rad) / self.max_turn_rad))
        for _ in range(n):
            super().turn(angle_rad / n)
            self._keep()

    def forward(self, distance_m: float) -> bool:
        n = max(1, math.ceil(abs(distance_m) / self.max_step_m))
        for _ in range(n):
            if not super().forward(distance_m / n):
                return False
            self._keep()
        return True

    def go_to(self, xy: np.ndarray) -> bool:
        """Turn towards the point ``xy`` and drive straight to it; False on a collision."""
        heading = float(np.arctan2(*(xy - self.pose[:2])[::-1]))
        self.turn(float(wrap_angle(heading - self.pose[2])))
        return self.forward(float(np.hypot(*(xy - self.pose[:2]))))


def start_points(world: World, region: Region | None, rng: np.random.Generator) -> np.ndarray:
    """Free positions (0.5 m from any surface) where the robot may wake up: anywhere, or
    in ``region``."""
    xy = world.sample_free(2000, rng, clearance_m=0.5)
    if region is not None:
        (x0, y0), (x1, y1) = region
        xy = xy[(xy[:, 0] >= x0) & (xy[:, 0] <= x1) & (xy[:, 1] >= y0) & (xy[:, 1] <= y1)]
        if len(xy) == 0:
            raise InvalidInput("start: the region holds no free space 0.5 m from the "
                               "walls", field="start")
    return xy


def wake_up(world: World, region: Region | None, odometry: OdometryConfig,
            rng: np.random.Generator) -> TracedRobot:
    """The robot at a random free position of ``region`` (or anywhere) with a random
    heading: lost, it knows neither."""
    xy = start_points(world, region, rng)
    p = xy[int(rng.integers(len(xy)))]
    pose = np.array([p[0], p[1], rng.uniform(-np.pi, np.pi)])
    return TracedRobot(world=world, pose=pose, odometry=odometry, rng=rng)


def drive(robot: TracedRobot, alpha_rad: float, l_m: float, beta_rad: float,
          clearance_m: float = 0.3) -> None:
    """The movement strategy's action (alpha, l, beta): turn, drive, turn; the drive
    stops ``clearance_m`` before a wall, as the strategy's model of a move has it
    (Maeda & Shirai §3.4; the robot's laser sees the wall)."""
    robot.turn(alpha_rad)
    room = free_distance(robot.pose[:2], robot.pose[2], robot.world.surfaces.a,
                         robot.world.surfaces.b)[0] - clearance_m
    robot.forward(float(np.clip(min(l_m, room), 0.0, None)))
    robot.collided = False
    robot.turn(beta_rad)


def landmark_pose(world: World, robot: Robot, observer: LandmarkObserver,
                  at: str) -> np.ndarray | None:
    """The pose of a robot standing at landmark ``at``: its position on the world's
    landmark map, the heading from the observed bearings of the other landmarks in
    view (:func:`chizu.numeric.qualitative.navigation.map_heading`); None if no other landmark
    is in view."""
    pos = dict(zip(world.landmark_ids, world.landmark_xy, strict=True))
    heading = map_heading(at, observer.observe(robot.pose, at=at), pos)
    return None if heading is None else np.array([*pos[at], heading])


def trace_scans(world: World, trace: Sequence[tuple[np.ndarray, np.ndarray]],
                est: np.ndarray, odom0: np.ndarray, rng: np.random.Generator,
                period_s: float = 0.1) -> list[Scan]:
    """A laser scan at each (true pose, odometry pose) of ``trace``, every ``period_s``,
    its odometry expressed in the frame of the pose ``est`` the robot fixed when its
    odometry read ``odom0``: what the robot hands to SLAM."""
    laser = Laser(world)
    return [laser.scan(period_s * (k + 1), truth, compose(est, relative(odom0, odom)), rng)
            for k, (truth, odom) in enumerate(trace)]


@dataclass
class MissionTrace:
    """What the simulator knows of one run: the true path and poses the robot never
    reads, beside what it estimated (the poses it fixed, SLAM's path and map, the DRM
    path's landmarks, the viewpoint plan and the goal room's summary)."""

    truth_path: list[np.ndarray] = field(default_factory=list)
    #: the true pose at each localization stop
    stops: list[np.ndarray] = field(default_factory=list)
    slam_path: np.ndarray | None = None
    map: OccupancyMap | None = None
    landmarks: list[str] = field(default_factory=list)
    summary: SummaryRun | None = None
    #: the pose the mission went on from and the true pose then
    fix: tuple[np.ndarray, np.ndarray] | None = None
    #: the eigenspace's pose and the true pose then (None if it gave none)
    eigenspace_fix: tuple[np.ndarray, np.ndarray] | None = None
    #: the odometry pose at :attr:`fix`
    anchor_odom: np.ndarray | None = None
    #: the viewpoint plan's poses (x, y, theta), in its order
    plan_poses: list[tuple[float, float, float]] = field(default_factory=list)
    #: what gave :attr:`fix`: ``eigenspace`` (its pose named a landmark the robot
    #: reached), ``laser`` (a localization run on the world's committed map) or
    #: ``wander`` (the fallback: the landmark the robot wandered to)
    fixed_by: str = "eigenspace"

    def follow(self, robot: TracedRobot) -> None:
        """Move the robot's traced true poses onto the true path (and empty its trace)."""
        self.truth_path.extend(p for p, _ in robot.trace)
        robot.trace.clear()

    def anchor(self, robot: TracedRobot, est: np.ndarray) -> None:
        """The map's frame: the pose ``est`` just fixed; the laser's trace starts here."""
        self.follow(robot)
        robot.tracing = True
        self.fix = (est.copy(), robot.pose.copy())
        self.anchor_odom = robot.odom_pose.copy()


@dataclass(frozen=True)
class Evaluation:
    """A run against the simulator's truth: the error of the pose the map is anchored at
    (None if no pose was fixed) and how it was found (:attr:`MissionTrace.fixed_by`),
    the eigenspace's own error,
    and the objects -- real ones verified, false ones verified."""

    localization_error_m: float | None
    heading_error_rad: float | None
    localized_by: str | None
    eigenspace_error_m: float | None
    objects: int
    objects_verified: int
    false_verified: int

    @property
    def pose_ok(self) -> bool:
        """The anchored pose within :data:`POSE_OK_M` and :data:`POSE_OK_RAD`."""
        return (self.localization_error_m is not None and self.heading_error_rad is not None
                and self.localization_error_m <= POSE_OK_M
                and self.heading_error_rad <= POSE_OK_RAD)

    def success(self, verified: bool) -> bool:
        """The mission succeeded: the verification was done (``verified``), the pose is
        good, at least one real object was verified (if the world has any) and no false
        one."""
        return bool(self.pose_ok and verified and self.objects_verified >= min(1, self.objects)
                    and self.false_verified == 0)

    def record(self) -> dict[str, Any]:
        """The figures as the mission's record lists them (what was not measured left
        out)."""
        out: dict[str, Any] = {}
        if self.localization_error_m is not None:
            out.update(localization_error_m=self.localization_error_m,
                       heading_error_rad=self.heading_error_rad,
                       localized_by=self.localized_by)
        if self.eigenspace_error_m is not None:
            out["eigenspace_error_m"] = self.eigenspace_error_m
        out.update(objects=self.objects, objects_verified=self.objects_verified,
                   false_verified=self.false_verified)
        return out


def evaluate(trace: MissionTrace, world: World) -> Evaluation:
    """Compare the run with the simulator's truth: the anchored pose's position and
    heading errors and what gave it, the eigenspace pose's error, the world's objects
    among those the summary verified."""
    err = herr = eig_err = None
    if trace.fix is not None:
        est, truth = trace.fix
        err = float(np.hypot(*(est[:2] - truth[:2])))
        herr = abs(float(wrap_angle(est[2] - truth[2])))
    if trace.eigenspace_fix is not None:  # the eigenspace's own answer, kept or not
        e, t = trace.eigenspace_fix
        eig_err = float(np.hypot(*(e[:2] - t[:2])))
    objects = {o.id for o in world.description.objects}
    verified = set(trace.summary.verified) if trace.summary is not None else set()
    return Evaluation(err, herr, None if err is None else trace.fixed_by, eig_err, len(objects),
                      len(objects & verified), len(verified - objects))
