"""One robot, one knowledge base: the end-to-end mission in the simulator.

A simulated robot wakes up lost in a world and runs the four methods through the same
service calls a client makes, so every result lands in the world's knowledge base:

1. **localize** -- a full turn of camera images per stop, sent to an eigenspace session
   (Maeda & Shirai, §3: candidate regions, the Fig. 4 state rules in Prolog), the
   movement strategy's next move (§3.5) driven with noisy odometry, until state Z;
2. **nearest_landmark / reach_landmark** -- the estimated pose names the nearest
   landmark in line of sight, and the robot homes on it (the DRM paper's §6: reach a
   landmark first). A robot still lost after ``max_stops`` wanders until it recognises
   a landmark and takes its pose there (``reach_landmark`` with ``how = wander``);
3. **drm_path / navigate** -- the DRM's most probable path to the goal landmark (eq. 4)
   is followed by the qualitative navigation methods (move1-3, §6); each arc the robot
   completes is reported as a ``reached`` event, each it fails as a ``failed`` one (the
   DRM weighs its edges with both), and after a failure the robot recognises a landmark
   and re-plans from there;
4. **slam_map** -- the laser scans taken on the way (odometry in the frame of the
   localized pose) go to a SLAM run (graph SLAM by default) whose map is committed: its
   unknown regions become facts;
5. **enter_room / viewpoint_plan / verify** -- at the goal room's door the candidate
   objects seen from there are planned for (Masuzawa & Miura: groups by the Prolog
   rules, on the committed map) and the online loop (§7.3) verifies them under the
   time limit.

After every step the whole record so far is asserted as ``mission_step(S, What,
Result)`` facts (prolog/mission.pl) and stored with the world, so ``chizu repl WORLD``
and ``/query`` see it. A last ``evaluation`` step compares with the simulator's ground
truth (never read by the robot). This module orchestrates: the robot in the simulator and
the evaluation are :mod:`chizu.numeric.mission`'s, the figure
:func:`chizu.numeric.figures.mission_figure`.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from chizu.numeric.camera import Camera
from chizu.numeric.eigenspace.analysis import learning_pixels
from chizu.numeric.errors import Conflict, InvalidInput
from chizu.numeric.geometry import line_of_sight, relative, wrap_angle
from chizu.numeric.laser import Laser
from chizu.numeric.mission import (
    MissionTrace,
    TracedRobot,
    drive,
    evaluate,
    landmark_pose,
    start_points,
    trace_scans,
    wake_up,
)
from chizu.numeric.qualitative.navigation import (
    NavConfig,
    execute_step,
    home_on,
    reach_any_landmark,
)
from chizu.numeric.qualitative.survey import survey
from chizu.numeric.scan import Scan
from chizu.numeric.simulator import LandmarkObserver, ObserverConfig
from chizu.numeric.viewpoint import planner
from chizu.numeric.viewpoint.online import Summariser, SummaryConfig
from chizu.numeric.viewpoint.planner import BUILTIN_OBJECT_TYPES, GroupSpec
from chizu.numeric.world import World
from chizu.service.disconnect import thread_to_end
from chizu.service.eigenspace import EigenspaceService
from chizu.service.jobs import JobProgress, Jobs
from chizu.service.localization import LocalizationService
from chizu.service.schemas.jobs import JobOut
from chizu.service.schemas.mission import MissionConfig, MissionRecordOut
from chizu.service.schemas.slam import CommitOut, ScanIn, SlamRunIn
from chizu.service.schemas.viewpoint import CandidateIn, ObjectType, PlanRequest
from chizu.service.slam import SAVED_MAP_ARTIFACT, SlamService
from chizu.service.viewpoint import SCENE_ARTIFACT, ViewpointService
from chizu.service.worlds import ArtifactKind, WorldService

__all__ = ["MissionConfig", "MissionFailed", "MissionRun", "MissionService", "scan_in"]

log = logging.getLogger(__name__)
MISSION_ARTIFACT = "mission"
MISSION_JOB = "mission"


class MissionFailed(Exception):
    """A step could not be done; the record says which (``ok = false``)."""


@dataclass
class MissionRun:
    """What happened: the record (the facts' rows) and, for the evaluation and the
    figure, the simulator's trace of the run."""

    world: str
    config: MissionConfig
    steps: list[dict[str, Any]] = field(default_factory=list)
    trace: MissionTrace = field(default_factory=MissionTrace)
    success: bool = False
    elapsed_s: float = 0.0
    #: the robot's clock for the laser scans it takes (s, 10 Hz)
    clock_s: float = 0.0

    def result(self) -> dict[str, Any]:
        """The mission job's result: the outcome and the record."""
        return {"world": self.world, "seed": self.config.seed, "success": self.success,
                "elapsed_s": self.elapsed_s, "steps": self.steps}

    @property
    def learning_s(self) -> float:
        """Seconds spent learning the world's eigenspace (0 if it had one)."""
        return float(sum(s["result"].get("seconds", 0.0) for s in self.steps
                         if s["what"] == "learn_eigenspace"))

    def row(self) -> dict[str, Any]:
        """One line of a results table: the outcome, the step that ended the run (if
        one did), the evaluation's figures, the times."""
        ev = self.steps[-1]["result"] if self.steps else {}
        failed = next((s["what"] for s in self.steps if s["result"].get("ok") is False), "")
        return {"world": self.world, "seed": self.config.seed, "success": self.success,
                "failed_at": failed, "localized_by": ev.get("localized_by", ""),
                "localization_error_m": ev.get("localization_error_m"),
                "eigenspace_error_m": ev.get("eigenspace_error_m"),
                "objects": ev.get("objects", 0),
                "objects_verified": ev.get("objects_verified", 0),
                "false_verified": ev.get("false_verified", 0),
                "mission_s": self.elapsed_s - self.learning_s,
                "learning_s": self.learning_s or None,
                "wall_time_s": round(self.elapsed_s, 2)}

    def figure(self, world: World, path_png: str) -> None:
        """The run as a PNG (:func:`chizu.numeric.figures.mission_figure`), titled with its
        outcome and times."""
        from chizu.numeric.figures import mission_figure

        outcome = "succeeded" if self.success else "failed"
        learn = self.learning_s
        title = (f"mission on {self.world}, seed {self.config.seed}: {outcome} "
                 f"({len(self.steps)} steps, {self.elapsed_s - learn:.1f} s"
                 + (f" + {learn:.0f} s learning)" if learn else ")"))
        mission_figure(self.trace, world, path_png, title,
                       f"SLAM ({self.config.slam_method})")


def _plain(v: Any) -> Any:
    """A JSON value of a step's result (numpy scalars and arrays made plain)."""
    if isinstance(v, np.ndarray):
        return [_plain(x) for x in v.tolist()]
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return round(float(v), 6)
    return str(v)


def scan_in(scan: Scan) -> ScanIn:
    """A simulated :class:`chizu.numeric.scan.Scan` as a client would post it (the simulator's
    laser measures intensities)."""
    assert scan.intensities is not None
    return ScanIn(t=scan.t, ranges=np.round(scan.ranges, 4).tolist(),
                  intensities=np.round(scan.intensities, 1).tolist(),
                  angle_min=float(scan.angles[0]),
                  angle_increment=float(scan.angles[1] - scan.angles[0]),
                  range_min=scan.min_range_m, range_max=scan.max_range_m,
                  odom=tuple(float(v) for v in scan.odom))


class MissionService:
    """Runs missions on a world through the domain services (one knowledge base)."""

    def __init__(self, worlds: WorldService, jobs: Jobs,
                 eigenspace: EigenspaceService, slam: SlamService,
                 viewpoint: ViewpointService, localization: LocalizationService) -> None:
        self.worlds, self.jobs = worlds, jobs
        self.eigenspace, self.slam, self.viewpoint = eigenspace, slam, viewpoint
        self.localization = localization
        worlds.register(ArtifactKind(
            MISSION_ARTIFACT, "mission_steps", "mission",
            lambda world, blob: {"world": world, "steps": json.loads(blob)["steps"]}))

    async def start(self, world: str, config: MissionConfig) -> JobOut:
        """A durable job (:mod:`chizu.service.jobs`) running one mission; its result is
        :meth:`MissionRun.result`. The input is checked first (404 / 422, no job)."""
        await asyncio.to_thread(self.check, world, config)

        async def work(progress: JobProgress) -> dict[str, Any]:
            run = await self.run(world, config, lambda what, frac: progress(what, frac))
            return run.result()

        return self.jobs.start(world, MISSION_JOB, work)

    def record(self, world: str) -> MissionRecordOut:
        """The world's last mission record as stored (the facts' rows)."""
        self.worlds.require(world)
        blob = self.worlds.store.artifact(world, MISSION_ARTIFACT)
        steps = json.loads(blob)["steps"] if blob is not None else []
        return MissionRecordOut(world=world, steps=steps)

    def check(self, world: str, config: MissionConfig) -> None:
        """404 / 422 before any work: the world, the goal landmark, the room and door."""
        w = self.worlds.model(world)
        if config.goal not in w.landmark_index:
            raise InvalidInput(f"landmark {config.goal!r} has no position in world "
                               f"{world!r}", field="goal")
        (x0, y0), (x1, y1) = config.room
        if not (x0 < x1 and y0 < y1):
            raise InvalidInput("room: the lower corner must be below and left of the upper",
                               field="room")
        if not (x0 <= config.door[0] <= x1 and y0 <= config.door[1] <= y1):
            raise InvalidInput("door: the point must lie inside the room", field="door")
        if not w.is_free(np.array(config.door), 0.2)[0]:
            raise InvalidInput("door: the point is not in the free space", field="door")
        start_points(w, config.start, np.random.default_rng(0))
        try:
            self.eigenspace.analysis(world)
        except Conflict:  # the mission will learn one: the learning job's cap applies
            n = learning_pixels(w, config.eigenspace)
            if n > self.eigenspace.max_learning_pixels:
                raise InvalidInput(
                    f"learning this world's eigenspace would render up to {n:,} pixels; at "
                    f"most {self.eigenspace.max_learning_pixels:,}: a coarser "
                    "eigenspace.learning.spacing_m, fewer directions or smaller images",
                    field="eigenspace.learning.spacing_m") from None

    async def run(self, world: str, config: MissionConfig,
                  progress: Callable[[str, float], None] | None = None) -> MissionRun:
        """Run the mission (see the module's docstring); a failed step ends it early with
        ``ok = false`` in its record, and the evaluation says what was reached."""
        await asyncio.to_thread(self.check, world, config)
        report = progress or (lambda what, frac: None)
        t0 = time.perf_counter()
        run = MissionRun(world, config)
        w = self.worlds.model(world)
        rng = np.random.default_rng(config.seed)
        robot: TracedRobot | None = None
        start: str | None = None
        try:
            await self._prepare(run, w, report)
            robot = await asyncio.to_thread(wake_up, w, config.start, config.odometry, rng)
            run.trace.truth_path.append(robot.pose.copy())
            observer = LandmarkObserver(w, config.observer, rng)
            nav = NavConfig()
            fixed = await self._localize(run, w, robot, rng, report)
            if fixed is not None:
                est, by = fixed
                run.trace.fixed_by = by
                run.trace.anchor(robot, est)
                start = await self._reach_nearest(run, w, robot, observer, nav, est, report)
                fix = (None if start is None or by == "laser"
                       else landmark_pose(w, robot, observer, start))
                if fix is not None:  # at the landmark the pose is known better than the
                    # eigenspace's: re-anchor (a laser fix on the map is better still)
                    run.trace.anchor(robot, fix)
                    await self._record(run, "landmark_fix", landmark=start, x=fix[0],
                                       y=fix[1], theta=fix[2], ok=True)
            if start is None:  # still lost, or the pose named a landmark that is not
                # there (a wrong pose): the DRM paper's way, reach some landmark first
                start, est = await self._recover(run, w, robot, observer, nav, rng, report)
                run.trace.fixed_by = "wander"
                run.trace.anchor(robot, est)
            # a full turn where the map starts: its first scans see all round (and a goal
            # that is the landmark already reached still gets a map)
            await thread_to_end(robot.turn, 2 * np.pi)
            await self._navigate(run, robot, observer, nav, start, rng, report)
            await self._map(run, w, robot, rng, report)
            await self._summarise(run, w, robot, report)
        except MissionFailed as e:
            log.info("mission on %s (seed %d) stopped: %s", world, config.seed, e)
        except BaseException as e:  # cancelled, or an error: the record says so, then on
            why = "cancelled" if isinstance(e, asyncio.CancelledError) else (
                f"{type(e).__name__}: {e}")
            with contextlib.suppress(Exception):
                await asyncio.shield(self._record(run, "aborted", reason=why[:500], ok=False))
            raise
        if robot is not None:
            run.trace.follow(robot)
        run.elapsed_s = time.perf_counter() - t0
        await self._evaluate(run, w)
        report("done", 1.0)
        return run

    # -- the record -------------------------------------------------------------------
    async def _record(self, run: MissionRun, what: str, **result: Any) -> None:
        run.steps.append({"step": len(run.steps), "what": what,
                          "result": {k: _plain(v) for k, v in result.items()}})
        blob = json.dumps({"world": run.world, "steps": run.steps}).encode()
        async with self.worlds.write_artifact(run.world, MISSION_ARTIFACT) as write:
            await write.commit(blob, call={"world": run.world, "steps": run.steps})
        self.worlds.events.publish(run.world, "mission_step", run.steps[-1])

    async def _fail(self, run: MissionRun, what: str, why: str, **result: Any) -> None:
        await self._record(run, what, ok=False, reason=why, **result)
        raise MissionFailed(f"{what}: {why}")

    # -- 0: what the world needs ------------------------------------------------------
    async def _prepare(self, run: MissionRun, w: World,
                       report: Callable[[str, float], None]) -> None:
        await self._record(run, "survey", **await self._ensure_drm(run.world, w))
        try:
            self.eigenspace.analysis(run.world)
        except Conflict:
            report("learning the eigenspace", 0.02)
            t = time.perf_counter()
            a = await self.eigenspace.learn(run.world, run.config.eigenspace, None,
                                            lambda stage, frac: report(stage, 0.02 + 0.1 * frac))
            await self._record(run, "learn_eigenspace", learning_points=len(a.model.points),
                               triplets=len(a.triplets), seconds=time.perf_counter() - t,
                               ok=True)

    async def _ensure_drm(self, world: str, w: World) -> dict[str, Any]:
        """The DRM needs observations from the landmarks: a survey in the simulator (one
        panoramic observation at each landmark no observation was taken at yet, so a
        survey cut short is completed by the next mission)."""

        def missing() -> list[Any]:
            seen = {e.payload.get("at") for e in self.worlds.store.events(world)
                    if e.kind == "observation"}
            cfg = ObserverConfig(bearing_noise_rad=0.01, distance_noise_m=0.02)
            return [o for o in survey(w, cfg, seed=0) if o.at not in seen]

        obs = await asyncio.to_thread(missing)
        for o in obs:
            await self.worlds.observe(world, o)
        drm = await self.worlds.drm(world)
        return {"observations": len(obs), "edges": len(drm["edges"]), "ok": True}

    # -- 1: wake up lost and localize -------------------------------------------------
    async def _localize(self, run: MissionRun, w: World, robot: TracedRobot,
                        rng: np.random.Generator, report: Callable[[str, float], None],
                        ) -> tuple[np.ndarray, str] | None:
        """Eigenspace stops with the movement strategy's moves in between, until the
        Fig. 4 rules reach state Z (at most ``max_stops``). Where the world has a
        committed map, the robot also turns once round with its laser at every stop,
        the scans streamed to a localization run on that map
        (:class:`~chizu.service.localization.LocalizationService`): the laser's pose is then
        the one the mission goes on from, and the eigenspace's answer is reported
        against it -- the reference a real robot has (the simulator's truth is only
        for the evaluation). Returns the pose and what gave it (``laser`` or
        ``eigenspace``), None when neither did."""
        a = self.eigenspace.analysis(run.world)
        cam = Camera(w, a.config.camera.model_copy(update={"noise_sigma":
                                                           run.config.camera_noise}), rng=rng)
        n = len(a.model.directions)
        sid = (await self.eigenspace.create_session(run.world)).id
        rid = await self._laser_run(run.world)
        prev: np.ndarray | None = None
        laser: np.ndarray | None = None
        try:
            for k in range(run.config.max_stops):
                report(f"localizing: stop {k + 1}", 0.05 + 0.25 * k / run.config.max_stops)
                imgs = await asyncio.to_thread(cam.render_turn, robot.pose[:2], robot.pose[2],
                                               n)
                motion = None if prev is None else relative(prev, robot.odom_pose)
                ans = await self.eigenspace.add_stop(run.world, sid, imgs, motion)
                truth = robot.pose.copy()
                run.trace.stops.append(truth)
                if rid is not None:
                    laser = await self._laser_turn(run, w, robot, rng, rid)
                state = ans.state.state
                if state == "z" and ans.pose is not None:
                    p = ans.pose
                    est = np.array([p.x, p.y, p.theta], dtype=float)
                    run.trace.eigenspace_fix = (est.copy(), truth)
                    versus = {} if laser is None else {
                        "laser_x": laser[0], "laser_y": laser[1], "laser_theta": laser[2],
                        "eigenspace_vs_laser_m": float(np.hypot(*(est[:2] - laser[:2]))),
                        "eigenspace_vs_laser_rad": abs(float(wrap_angle(est[2] - laser[2])))}
                    await self._record(run, "localize", session=sid, stops=k + 1, state="z",
                                       x=est[0], y=est[1], theta=est[2],
                                       by="eigenspace" if laser is None else "laser",
                                       **versus, ok=True)
                    return (est, "eigenspace") if laser is None else (laser, "laser")
                if k == run.config.max_stops - 1:
                    break  # no move after the last stop: the laser's pose is where it stands
                act = (await self.eigenspace.next_move(run.world, sid)).action
                prev = robot.odom_pose.copy()
                if act is not None:
                    await thread_to_end(drive, robot, act.alpha_rad, act.l_m, act.beta_rad)
                run.trace.truth_path.append(robot.pose.copy())
            if laser is not None:  # the eigenspace gave no pose; the laser on the map did
                await self._record(run, "localize", session=sid, stops=run.config.max_stops,
                                   state=state, by="laser", x=laser[0], y=laser[1],
                                   theta=laser[2], eigenspace="no unique pose", ok=True)
                return laser, "laser"
            await self._record(run, "localize", session=sid, stops=run.config.max_stops,
                               state=state, localized=False,
                               reason=f"no unique pose after {run.config.max_stops} stops")
            return None
        finally:
            if rid is not None:
                with contextlib.suppress(Exception):
                    await self.localization.delete(run.world, rid)

    async def _laser_run(self, world: str) -> str | None:
        """A localization run on the world's committed map; None when it has none."""
        try:
            return (await self.localization.create(world)).id
        except Conflict:
            return None

    async def _laser_turn(self, run: MissionRun, w: World, robot: TracedRobot,
                          rng: np.random.Generator, rid: str) -> np.ndarray | None:
        """The robot turns once round on the spot, a laser scan at each step of the turn
        (10 Hz on the robot's clock, its own odometry), streamed to localization run
        ``rid``; the pose it gives at the end of the turn, None while it has no fix."""

        def turn() -> list[ScanIn]:
            robot.tracing = True
            robot.turn(2 * np.pi)
            taken = list(robot.trace)
            run.trace.follow(robot)
            robot.tracing = False
            sensor, out = Laser(w), []
            for truth, odom in taken:
                run.clock_s += 0.1
                out.append(scan_in(sensor.scan(run.clock_s, truth, odom, rng)))
            return out

        st = await self.localization.add_scans(run.world, rid, await thread_to_end(turn))
        if st.state != "tracking" or st.pose is None:
            return None
        return np.array([st.pose.x, st.pose.y, st.pose.theta])

    async def _recover(self, run: MissionRun, w: World, robot: TracedRobot,
                       observer: LandmarkObserver, nav: NavConfig, rng: np.random.Generator,
                       report: Callable[[str, float], None]) -> tuple[str, np.ndarray]:
        """Still lost after the stops: wander until a landmark is recognised and home on
        it (the DRM paper's §6, :func:`reach_any_landmark`); standing there, the pose is
        the landmark's position and the heading the one the bearings of the other
        landmarks in view give on the world's landmark map (:func:`map_heading`)."""
        report("lost: reaching any landmark", 0.3)
        lm = await self._reach_any(run, robot, observer, nav, rng, "wander")
        est = landmark_pose(w, robot, observer, lm)
        if est is None:
            await self._fail(run, "reach_landmark", "no other landmark in view to take the "
                             "heading from", how="wander", landmark=lm)
        assert est is not None
        await self._record(run, "reach_landmark", landmark=lm, how="wander",
                           travelled_m=robot.travelled_m, x=est[0], y=est[1],
                           theta=est[2], ok=True)
        return lm, est

    async def _reach_any(self, run: MissionRun, robot: TracedRobot,
                         observer: LandmarkObserver, nav: NavConfig,
                         rng: np.random.Generator, how: str) -> str:
        """The landmark :func:`reach_any_landmark` reaches; the mission fails at
        ``reach_landmark`` if it wandered without recognising one."""
        lm = await thread_to_end(reach_any_landmark, robot, observer, nav, rng)
        if lm is None:
            await self._fail(run, "reach_landmark", "wandered without recognising a "
                             "landmark", how=how)
        assert lm is not None
        return lm

    # -- 2-3: the nearest landmark, the DRM path, navigation ---------------------------
    async def _reach_nearest(self, run: MissionRun, w: World, robot: TracedRobot,
                             observer: LandmarkObserver, nav: NavConfig, est: np.ndarray,
                             report: Callable[[str, float], None]) -> str | None:
        """The landmark nearest to the estimated pose in line of sight on the world's
        map, then homing on it (move1); None if it is not recognised there."""
        report("reaching the nearest landmark", 0.35)
        d = np.hypot(*(w.landmark_xy - est[:2]).T)
        seen = line_of_sight(est[:2], w.landmark_xy, w.wall_a, w.wall_b)
        if not seen.any():
            await self._record(run, "nearest_landmark", x=est[0], y=est[1], found=False,
                               reason="no landmark in line of sight of the estimated pose")
            return None
        i = int(np.argmin(np.where(seen, d, np.inf)))
        start = w.landmark_ids[i]
        await self._record(run, "nearest_landmark", x=est[0], y=est[1], landmark=start,
                           distance_m=d[i], ok=True)
        ok = await thread_to_end(home_on, robot, observer, start, nav)
        if not ok:  # not in view where the pose says: the pose is wrong
            robot.collided = False
            await self._record(run, "reach_landmark", landmark=start, reached=False,
                               reason="not recognised where the pose puts it",
                               travelled_m=robot.travelled_m)
            return None
        await self._record(run, "reach_landmark", landmark=start, reached=True,
                           travelled_m=robot.travelled_m, ok=True)
        return start

    async def _navigate(self, run: MissionRun, robot: TracedRobot,
                        observer: LandmarkObserver, nav: NavConfig, start: str,
                        rng: np.random.Generator,
                        report: Callable[[str, float], None]) -> None:
        """The DRM's most probable path from ``start`` to the goal, executed arc by arc.

        Experience goes into the world both ways: each arc driven is a ``reached`` event,
        each arc the robot set out on and did not finish a ``failed`` one, which lowers
        that edge's probability (prolog/drm.pl). After a failure the robot re-plans from
        where it stands, as it began (the DRM paper's §6): it recognises the nearest
        landmark, homes on it, and takes the most probable path from there with what it
        just learned -- at most ``max_replans`` times."""
        goal = run.config.goal
        report("following the DRM path", 0.45)
        t0 = robot.travelled_m
        at = start
        for replan in range(run.config.max_replans + 1):
            path = await self.worlds.path(run.world, at, goal)
            if path is None:
                await self._fail(run, "drm_path", "the DRM has no path", **{"from": at},
                                 to=goal)
            assert path is not None
            run.trace.landmarks = path.nodes
            await self._record(run, "drm_path", **{"from": at}, to=goal,
                               landmarks=path.nodes, methods=[s.method for s in path.steps],
                               probability=path.probability, replan=replan, ok=True)
            failed = None
            for k, s in enumerate(path.steps):
                if not await thread_to_end(execute_step, robot, observer, s, nav):
                    failed = k
                    break
                await self.worlds.reached(run.world, path.nodes[k], s.target)
            if failed is None:
                await self._record(run, "navigate", arcs=len(path.steps),
                                   travelled_m=robot.travelled_m - t0, at=goal,
                                   replans=replan, ok=True)
                return
            s = path.steps[failed]
            reason = "collision" if robot.collided else f"{s.method} to {s.target} failed"
            robot.collided = False
            arc = await self.worlds.failed(run.world, path.nodes[failed], s.target)
            if replan == run.config.max_replans:
                await self._fail(run, "navigate", reason, arcs_done=failed,
                                 arcs=len(path.steps), travelled_m=robot.travelled_m - t0,
                                 replans=replan)
            await self._record(run, "arc_failed", **{"from": path.nodes[failed]},
                               to=s.target, method=s.method, reason=reason,
                               succeeded=arc["succeeded"], failed=arc["failed"])
            report("re-planning: reaching a landmark", 0.45)
            lm = await self._reach_any(run, robot, observer, nav, rng, "replan")
            await self._record(run, "reach_landmark", landmark=lm, how="replan",
                               travelled_m=robot.travelled_m, ok=True)
            at = lm

    # -- 4: the map ---------------------------------------------------------------------
    async def _map(self, run: MissionRun, w: World, robot: TracedRobot,
                   rng: np.random.Generator, report: Callable[[str, float], None]) -> None:
        """The laser scans of the way (odometry in the localized pose's frame) into a
        SLAM run, then committed: the world's map and its unknown regions."""
        report("mapping", 0.6)
        assert run.trace.fix is not None and run.trace.anchor_odom is not None
        est, odom0 = run.trace.fix[0], run.trace.anchor_odom

        def take() -> list[ScanIn]:
            return [scan_in(s) for s in trace_scans(w, robot.trace, est, odom0, rng)]

        scans = await asyncio.to_thread(take)
        if len(scans) < 2:
            await self._fail(run, "slam_map", "the robot did not move", scans=len(scans))
        # the way extends the world's map (its poses are in the world's frame however
        # they were fixed); one that shares no place with it makes a map of its own
        resume = (run.config.slam_method == "graph"
                  and self.slam.store.has_artifact(run.world, SAVED_MAP_ARTIFACT))
        rid, c = await self._slam_commit(run, scans, resume)
        if c is None:
            resume = False
            rid, c = await self._slam_commit(run, scans, False)
        assert c is not None
        times, poses = await self.slam.trajectory(run.world, rid)
        run.trace.slam_path = np.asarray(poses)
        run.trace.map = await self.slam.grid(run.world, rid)
        await self.slam.delete(run.world, rid)  # the committed map and facts stay
        await self._record(run, "slam_map", slam_run=rid, method=run.config.slam_method,
                           resumed=resume, scans=len(scans), loop_closures=c.loop_closures,
                           unknown_regions=len(c.unknown_regions), free_m2=c.map.free_m2,
                           ok=True)

    async def _slam_commit(self, run: MissionRun, scans: list[ScanIn], resume: bool,
                           ) -> tuple[str, CommitOut | None]:
        """A SLAM run of ``scans`` committed into the world (``resume``: joined to its
        map); None for the commit when the run shares no place with that map (the run
        is deleted then)."""
        rid = (await self.slam.create(run.world, SlamRunIn(method=run.config.slam_method,
                                                          resume=resume))).id
        for i in range(0, len(scans), 200):
            await self.slam.add_scans(run.world, rid, scans[i:i + 200])
        try:
            return rid, await self.slam.commit(run.world, rid)
        except InvalidInput:
            if not resume:
                raise
            await self.slam.delete(run.world, rid)
            return rid, None

    # -- 5: the goal room ---------------------------------------------------------------
    async def _summarise(self, run: MissionRun, w: World, robot: TracedRobot,
                         report: Callable[[str, float], None]) -> None:
        cfg = run.config
        door = np.array(cfg.door, dtype=float)
        ok = await thread_to_end(robot.go_to, door)
        await self._record(run, "enter_room", door=door, ok=ok)
        if not ok:
            raise MissionFailed("could not enter the room")
        report("planning viewpoints", 0.75)
        types = [ObjectType.model_validate(t) for t in BUILTIN_OBJECT_TYPES]
        grouper = self._grouper(run.world, asyncio.get_running_loop())
        summariser = Summariser(w, list[planner.ObjectType](types), grouper,
                                SummaryConfig(time_limit_s=cfg.time_limit_s, loss=cfg.loss,
                                              seed=cfg.seed),
                                door, area=cfg.room)
        # the candidates seen from the door, planned for on the committed map
        seen = await asyncio.to_thread(summariser.detect, door)
        req = PlanRequest(robot=(float(door[0]), float(door[1]), float(np.pi / 2)),
                          exit=(float(door[0]), float(door[1])),
                          time_limit_s=cfg.time_limit_s, loss=cfg.loss, object_types=types,
                          candidates=[CandidateIn(id=c, type=t, x=float(xy[0]),
                                                  y=float(xy[1]))
                                      for c, (t, xy) in seen.items()])
        plan = await self.viewpoint.plan(run.world, req)
        best = plan.plan
        run.trace.plan_poses = [(st.pose[0], st.pose[1], st.pose[2]) for st in best.steps]
        await self._record(run, "viewpoint_plan", candidates=sorted(seen),
                           grid=plan.grid.source, groups=best.groups,
                           expected_time_s=best.expected_time_s or -1.0,
                           utility=best.utility or 0.0, feasible=best.feasible, ok=True)
        report("verifying candidates", 0.8)
        stop = threading.Event()

        def step(_: Any) -> None:
            if stop.is_set():
                raise MissionFailed("cancelled")

        summary = await thread_to_end(summariser.run, step, on_cancel=stop.set)
        run.trace.summary = summary
        s = summary.summary(w)
        await self._record(run, "verify", verified=s["verified"], rejected=s["rejected"],
                           unverified=s["unverified"], elapsed_s=s["elapsed_s"],
                           explored_fraction=s["explored_fraction"], plans=s["steps"],
                           time_limit_s=cfg.time_limit_s, ok=True)

    def _grouper(self, world: str, loop: asyncio.AbstractEventLoop
                 ) -> Callable[..., list[GroupSpec]]:
        """The online loop's grouping by the world's Prolog rules, called from the loop's
        thread: each grouping is a viewpoint-scene write on the event loop (the world's
        write path, as a plan's), so the facts and the stored scene stay in step."""

        async def write(args: dict[str, Any]) -> Any:
            async with self.worlds.write_artifact(world, SCENE_ARTIFACT) as w:
                return await w.commit(json.dumps(args).encode(), call=args)

        def group(cands: list[dict[str, Any]], regions: list[dict[str, Any]],
                  min_area: float | None) -> list[GroupSpec]:
            args = {"world": world, "candidates": cands, "regions": regions,
                    "min_area_m2": min_area}
            reply = asyncio.run_coroutine_threadsafe(write(args), loop).result()
            return [GroupSpec(int(g["id"]), str(g["kind"]), tuple(g["members"]))
                    for g in reply["groups"]]

        return group

    # -- the judgement ------------------------------------------------------------------
    async def _evaluate(self, run: MissionRun, w: World) -> None:
        """Against the simulator's truth (:func:`chizu.numeric.mission.evaluate`): the
        localization error at the stop that gave the pose, how it was found, the objects
        verified; a success needs every step done up to the verification too."""
        done = {s["what"] for s in run.steps if s["result"].get("ok") is not False}
        ev = evaluate(run.trace, w)
        run.success = ev.success("verify" in done)
        await self._record(run, "evaluation", steps_done=len(run.steps), **ev.record(),
                           wall_time_s=run.elapsed_s, success=run.success)
