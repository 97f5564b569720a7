"""SLAM runs in the service: create a run in a world, stream scans (+ odometry) to it,
read the pose and trajectory, fetch the map (PNG, PGM/YAML), commit it to the world.

Flow: ``numeric.slam`` estimates; committing turns the best map into facts
(``slam_facts``: keyframe poses, occupancy summary, enclosed unknown regions, and the
loop closures of estimators that find them, e.g. graph SLAM) in the world's knowledge
base, where ``prolog/slam.pl`` rules answer questions about it, and
stores the occupancy grid as the world's ``slam_map`` artifact for the planners.

Every accepted scan is stored (SQLite) before the estimator sees it; estimators are
seeded, so after a restart a run is rebuilt by replaying its scans (lazily, on first
use) and ends in the same state. A batch is validated as a whole first: a malformed
scan or a time stamp that does not increase rejects the batch and leaves the run as
it was.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import threading
import time
import uuid
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from numeric.errors import Conflict, InvalidInput, NotFound
from numeric.occupancy import OccupancyMap, build_occupancy
from numeric.scan import Scan, beam_angles
from numeric.slam.runner import Slam, SlamOptions, create, warm_up
from numeric.slam.saved_map import Laser, saved_map, to_bytes
from service.compute import BudgetExceeded
from service.disconnect import thread_to_end
from service.kb import KnowledgeBase
from service.schemas.common import PoseOut
from service.schemas.slam import CommitOut, ScanIn, SlamRunListed, SlamRunOut
from service.store import Store
from service.worlds import ArtifactKind, WorldService

log = logging.getLogger(__name__)
MAP_ARTIFACT = "slam_map"
#: the committed run's saved map (numeric.slam.saved_map), as ``map.chizu`` holds it
SAVED_MAP_ARTIFACT = "saved_map"
FACTS_ARTIFACT = "slam_facts"
MAX_SCANS_PER_RUN = 200_000


def loop_closures(slam: Slam) -> list[list[int | float]]:
    """The estimator's loop closures as ``[[scan_a, scan_b, score], ...]`` (scan indices
    in arrival order, score rounded to 4 places); ``[]`` for estimators without any
    (odom, icp, gated, rbpf have no ``loop_closures`` method)."""
    found = getattr(slam, "loop_closures", None)
    if not callable(found):
        return []
    return [[int(a), int(b), round(float(score), 4)] for a, b, score in found()]


def to_scan(s: ScanIn) -> Scan:
    """The numeric scan of a request item (raises :class:`InvalidInput`)."""
    r = np.asarray(s.ranges, dtype=float)
    return Scan(t=s.t, ranges=r, angles=beam_angles(len(r), s.angle_min, s.angle_increment),
                odom=np.asarray(s.odom, dtype=float),
                intensities=None if s.intensities is None else np.asarray(s.intensities, float),
                min_range_m=s.range_min, max_range_m=s.range_max)


@dataclass
class Run:
    id: str
    world: str
    options: SlamOptions
    slam: Slam
    scans: int = 0
    last_t: float = -np.inf
    replayed: bool = True
    lock: asyncio.Lock = field(default_factory=asyncio.Lock)
    #: the laser of the first scan and every scan's odometry, for the saved map
    laser: Laser | None = None
    odometry: list[np.ndarray] = field(default_factory=list)
    _map: tuple[tuple[int, bool], OccupancyMap] | None = None

    def status(self) -> SlamRunOut:
        """The run's options, scans and keyframes so far, the last stamp and pose."""
        pose = self.slam.pose
        # the options as a copy: the answer does not share the run's own
        return SlamRunOut(id=self.id, world=self.world, options=self.options.model_dump(),
                          scans=self.scans, keyframes=len(self.slam.keyframes),
                          last_t=None if self.scans == 0 else self.last_t,
                          pose=None if self.scans == 0 else PoseOut(
                              x=float(pose[0]), y=float(pose[1]), theta=float(pose[2])))


class SlamService:
    def __init__(self, store: Store, kb: KnowledgeBase, worlds: WorldService,
                 budget_s: float = 30.0) -> None:
        self.store, self.kb, self.worlds = store, kb, worlds
        #: a batch of scans is processed for at most this long (then it stops between scans)
        self.budget_s = budget_s
        self.runs: dict[str, Run] = {}
        worlds.on_delete.append(self._forget)
        worlds.register(ArtifactKind(FACTS_ARTIFACT, "slam_facts", "slam",
                                     lambda _world, blob: dict(json.loads(blob))))

    def _forget(self, world: str) -> None:
        for rid in [r.id for r in self.runs.values() if r.world == world]:
            del self.runs[rid]

    def restore_runs(self) -> int:
        """Reload the stored runs (each replayed lazily, on first use); the committed
        maps' facts come back with the worlds (:meth:`WorldService.restore_all`)."""
        for rid, world, opts in self.store.slam_runs():
            o = SlamOptions.model_validate(opts)
            self.runs[rid] = Run(rid, world, o, create(o), replayed=False)
        return len(self.runs)

    async def _run(self, world: str, rid: str) -> Run:
        self.worlds.require(world)  # 404 for an unknown world
        run = self.runs.get(rid)
        if run is None or run.world != world:
            raise NotFound(f"SLAM run {rid!r} does not exist in world {world!r}", field="run")
        if not run.replayed:
            async with run.lock:
                if not run.replayed:
                    rows = self.store.slam_scans(rid)
                    await asyncio.to_thread(self._replay, run, rows)
        return run

    @staticmethod
    def _replay(run: Run, rows: list[dict[str, Any]]) -> None:
        SlamService._process(run, [to_scan(ScanIn.model_validate(r)) for r in rows])
        run.replayed = True

    async def create(self, world: str, options: SlamOptions) -> SlamRunOut:
        self.worlds.require(world)
        rid = "r" + uuid.uuid4().hex[:16]
        # the method's kernels loaded before the first scan, not during it (once)
        await asyncio.to_thread(warm_up, options)
        run = Run(rid, world, options, create(options))
        with self.store.transaction() as conn:
            self.store.put_slam_run(conn, rid, world, options.model_dump())
        self.runs[rid] = run
        return run.status()

    def list_runs(self, world: str) -> list[SlamRunListed]:
        self.worlds.require(world)
        return [SlamRunListed(id=r.id, method=r.options.method,
                              scans=r.scans if r.replayed else None)
                for r in self.runs.values() if r.world == world]

    async def status(self, world: str, rid: str) -> SlamRunOut:
        return (await self._run(world, rid)).status()

    async def add_scans(self, world: str, rid: str, items: list[ScanIn]) -> SlamRunOut:
        run = await self._run(world, rid)
        async with run.lock:
            scans: list[Scan] = []
            last = run.last_t
            for i, item in enumerate(items):
                try:
                    scan = to_scan(item)
                except InvalidInput as e:
                    raise InvalidInput(str(e), field=f"scans[{i}].{e.field}") from None
                if not scan.t > last:
                    raise InvalidInput(f"time stamp {scan.t} does not follow {last} (scans must "
                                       "arrive in increasing time order)", field=f"scans[{i}].t")
                last = scan.t
                scans.append(scan)
            if run.scans + len(scans) > MAX_SCANS_PER_RUN:
                raise InvalidInput(f"a run holds at most {MAX_SCANS_PER_RUN} scans",
                                   field="scans")
            first = run.scans

            def append() -> None:  # JSON of a batch: tens of ms, off the event loop
                with self.store.transaction() as conn:
                    self.store.append_slam_scans(conn, rid, first,
                                                 [s.model_dump() for s in items])

            try:
                await thread_to_end(append)
            except asyncio.CancelledError:  # the rows went in all the same: take them out
                with self.store.transaction() as conn:
                    self.store.drop_slam_scans_from(conn, rid, first)
                raise
            deadline = time.monotonic() + self.budget_s
            stop = threading.Event()
            try:
                # a cancelled request (the client left, a job cancelled) stops the thread
                # between scans and waits for it, so the store below follows what it did
                # and no later request runs the filter beside it
                await thread_to_end(self._process, run, scans, deadline, stop,
                                    on_cancel=stop.set)
            finally:
                if run.scans < first + len(scans):  # stopped midway: the store follows
                    with self.store.transaction() as conn:
                        self.store.drop_slam_scans_from(conn, rid, run.scans)
            done = run.scans - first
            if done < len(scans):
                raise BudgetExceeded(
                    f"the batch ran past its time budget of {self.budget_s:g} s: its first "
                    f"{done} of {len(scans)} scans were processed and are kept; send "
                    f"scans[{done}:] again (smaller batches)", field="scans")
            return run.status()

    @staticmethod
    def _process(run: Run, scans: list[Scan], deadline: float = math.inf,
                 stop: threading.Event | None = None) -> None:
        """Feed ``scans`` to the run's method, stopping between scans past ``deadline``
        (time.monotonic; the first scan always runs, so every batch moves on) or once
        ``stop`` is set."""
        for i, s in enumerate(scans):
            if i and (time.monotonic() > deadline or (stop is not None and stop.is_set())):
                return
            run.slam.process(s)
            if run.laser is None:
                run.laser = Laser.of_scan(s)
            run.odometry.append(s.odom)
            run.scans += 1
            run.last_t = s.t

    async def trajectory(self, world: str, rid: str) -> tuple[np.ndarray, np.ndarray]:
        run = await self._run(world, rid)
        async with run.lock:
            return run.slam.trajectory()

    async def grid(self, world: str, rid: str) -> OccupancyMap:
        run = await self._run(world, rid)
        async with run.lock:
            if run.scans == 0:
                raise Conflict("the run has no scans yet: post scans first", field="run")
            key = (run.scans, run.slam.aligned)
            if run._map is None or run._map[0] != key:
                g = await asyncio.to_thread(build_occupancy, run.slam.keyframes.frames,
                                            run.slam.map_poses(), run.options.map_resolution_m)
                run._map = (key, g)
            return run._map[1]

    async def commit(self, world: str, rid: str) -> CommitOut:
        """Make the run's map the world's map: facts into the knowledge base, grid stored."""
        run = await self._run(world, rid)
        if run.scans:  # global scan alignment first (graph SLAM, the improved RBPF)
            async with run.lock:
                await asyncio.to_thread(run.slam.finish)
        g = await self.grid(world, rid)
        poses = run.slam.map_poses()
        summary = g.summary()
        params = await self.kb.acall("params", world=world)
        regions = await asyncio.to_thread(
            g.unknown_regions, float(params["parameters"]["unknown_region_min_area_m2"]))
        async with run.lock:
            closures = loop_closures(run.slam)
        call = {"world": world, "run": rid,
                "poses": [[round(float(v), 6) for v in p] for p in poses],
                "info": {k: summary[k] for k in ("resolution_m", "free_m2", "occupied_m2",
                                                 "unknown_m2")},
                "regions": regions, "closures": closures}
        async with run.lock:
            assert run.laser is not None
            saved = saved_map(run.slam, run.laser, np.array(run.odometry),
                              run.options.method, run.options.map_resolution_m,
                              {"source": f"SLAM run {rid}", "world": world})
        blob, npz, chizu = await asyncio.to_thread(
            lambda: (json.dumps(call).encode(), g.to_npz(), to_bytes(saved)))
        async with self.worlds.write_artifact(world, FACTS_ARTIFACT) as w:
            reply = await w.commit(blob, {MAP_ARTIFACT: npz, SAVED_MAP_ARTIFACT: chizu}, call)
        return CommitOut(world=world, run=rid, facts=reply, map=summary,
                         unknown_regions=regions, loop_closures=len(closures))

    def saved_map(self, world: str) -> bytes:
        """The world's committed map as a ``map.chizu`` file."""
        self.worlds.require(world)
        blob = self.store.artifact(world, SAVED_MAP_ARTIFACT)
        if blob is None:
            raise NotFound(f"world {world!r} has no committed map: commit a SLAM run "
                           "first", field="map")
        return blob

    async def summary(self, world: str) -> Any:
        self.worlds.require(world)
        return await self.kb.acall("slam_summary", world=world)

    async def regions_near(self, world: str, x: float, y: float, radius: float) -> Any:
        self.worlds.require(world)
        return await self.kb.acall("slam_regions_near", world=world, x=x, y=y, radius=radius)

    async def delete(self, world: str, rid: str) -> None:
        run = await self._run(world, rid)
        async with run.lock:
            with self.store.transaction() as conn:
                self.store.delete_slam_run(conn, rid)
            self.runs.pop(rid, None)
