"""SLAM runs in the service: create a run in a world, stream scans (+ odometry) to it,
read the pose and trajectory, fetch the map (PNG, PGM/YAML), commit it to the world.

Flow: ``chizu.numeric.slam`` estimates; committing turns the best map into facts
(``slam_facts``: keyframe poses, occupancy summary, enclosed unknown regions, and the
loop closures of estimators that find them, e.g. graph SLAM) in the world's knowledge
base, where ``prolog/slam.pl`` rules answer questions about it, and
stores the occupancy grid as the world's ``slam_map`` artifact for the planners.

Scans are taken in as :mod:`chizu.service.scan_runs` does for every streamed run (validated
as a batch, stored before the estimator sees them, replayed after a restart).
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import logging
import uuid
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from chizu.numeric.errors import Conflict, InvalidInput, NotFound
from chizu.numeric.occupancy import OccupancyMap, build_occupancy
from chizu.numeric.scan import Scan
from chizu.numeric.slam.merge import resume, runs_of
from chizu.numeric.slam.runner import Slam, create, warm_up
from chizu.numeric.slam.saved_map import SavedMap, from_bytes, saved_map, to_bytes
from chizu.service.scan_runs import ScanRun, ScanRuns
from chizu.service.schemas.common import PoseOut
from chizu.service.schemas.slam import CommitOut, ScanIn, SlamRunIn, SlamRunListed, SlamRunOut
from chizu.service.store import Store
from chizu.service.worlds import ArtifactKind, WorldService

log = logging.getLogger(__name__)
MAP_ARTIFACT = "slam_map"
#: the committed run's saved map (numeric.slam.saved_map), as ``map.chizu`` holds it
SAVED_MAP_ARTIFACT = "saved_map"
FACTS_ARTIFACT = "slam_facts"
#: the committed map's drawing, at most DRAWING_PX pixels a side (``map.png?max_px=2048``,
#: the console's map layer) and its map_server YAML: made once when the map is committed,
#: so the first view of a large map reads an image instead of decoding, downsampling and
#: encoding the whole grid while the user waits
DRAWING_PX = 2048
DRAWING_ARTIFACT = "slam_map_drawing"
DRAWING_YAML_ARTIFACT = "slam_map_drawing_yaml"
__all__ = ["Run", "SlamService", "loop_closures"]


def loop_closures(slam: Slam) -> list[list[int | float]]:
    """The estimator's loop closures as ``[[scan_a, scan_b, score], ...]`` (scan indices
    in arrival order, score rounded to 4 places); ``[]`` for estimators without any
    (odom, icp, gated, rbpf have no ``loop_closures`` method)."""
    found = getattr(slam, "loop_closures", None)
    if not callable(found):
        return []
    return [[int(a), int(b), round(float(score), 4)] for a, b, score in found()]


@dataclass
class Run(ScanRun):
    """A SLAM run: its options and estimator beside what every streamed run keeps."""

    options: SlamRunIn = field(default_factory=SlamRunIn)
    slam: Slam | None = None
    #: a resumed run's poses in the world's map, once committed
    resumed: np.ndarray | None = None
    #: the run's map at (scans, aligned), and drawn at (scans, aligned, max_side)
    _full: tuple[tuple[int, bool], OccupancyMap] | None = None
    _map: tuple[tuple[int, bool, int], OccupancyMap] | None = None

    @property
    def estimator(self) -> Slam:
        assert self.slam is not None
        return self.slam

    def status(self) -> SlamRunOut:
        """The run's options, scans and keyframes so far, the last stamp and pose."""
        pose = self.estimator.pose
        # the options as a copy: the answer does not share the run's own
        return SlamRunOut(id=self.id, world=self.world, options=self.options.model_dump(),
                          scans=self.scans, keyframes=len(self.estimator.keyframes),
                          last_t=None if self.scans == 0 else self.last_t,
                          pose=None if self.scans == 0 else PoseOut(
                              x=float(pose[0]), y=float(pose[1]), theta=float(pose[2])))


class SlamService(ScanRuns[Run]):
    kind = "slam"
    noun = "SLAM run"

    def __init__(self, store: Store, worlds: WorldService, budget_s: float = 30.0) -> None:
        super().__init__(store, worlds, budget_s)
        self._grids: dict[tuple[Any, ...], OccupancyMap] = {}
        self._png: tuple[tuple[Any, ...], bytes] | None = None
        worlds.register(ArtifactKind(FACTS_ARTIFACT, "slam_facts", "slam",
                                     lambda _world, blob: dict(json.loads(blob))))

    def restore_runs(self) -> int:
        """Reload the stored runs (each replayed lazily, on first use); the committed
        maps' facts come back with their worlds (:meth:`WorldService.ready`)."""
        for rid, world, opts in self.store.runs(self.kind):
            o = SlamRunIn.model_validate(opts)
            self.runs[rid] = Run(rid, world, options=o, slam=create(o), replayed=False)
        return len(self.runs)

    def _step(self, run: Run, scan: Scan) -> None:
        run.estimator.process(scan)

    async def create(self, world: str, options: SlamRunIn) -> SlamRunOut:
        self.worlds.require(world)
        rid = "r" + uuid.uuid4().hex[:16]
        # the method's kernels loaded before the first scan, not during it (once)
        await asyncio.to_thread(warm_up, options)
        run = Run(rid, world, options=options, slam=create(options))
        self._store_run(run, options.model_dump())
        return run.status()

    def list_runs(self, world: str) -> list[SlamRunListed]:
        self.worlds.require(world)
        return [SlamRunListed(id=r.id, method=r.options.method,
                              scans=r.scans if r.replayed else None)
                for r in self.runs.values() if r.world == world]

    async def status(self, world: str, rid: str) -> SlamRunOut:
        return (await self._run(world, rid)).status()

    async def add_scans(self, world: str, rid: str, items: list[ScanIn]) -> SlamRunOut:
        return (await self._add_scans(world, rid, items)).status()

    async def trajectory(self, world: str, rid: str) -> tuple[np.ndarray, np.ndarray]:
        """Every scan's stamp and pose; a resumed run's, once committed, in the world's
        map."""
        run = await self._run(world, rid)
        async with run.lock:
            t, p = run.estimator.trajectory()
            if run.resumed is not None and len(run.resumed) == len(t):
                p = run.resumed
            return t, p

    async def grid(self, world: str, rid: str, max_side: int | None = None) -> OccupancyMap:
        """The run's map as the estimator has it now, with at most ``max_side`` cells a
        side if given (:meth:`OccupancyMap.downsampled`); built once per scan count and
        size."""
        run = await self._run(world, rid)
        async with run.lock:
            if run.scans == 0:
                raise Conflict("the run has no scans yet: post scans first", field="run")
            state = (run.scans, run.estimator.aligned)
            if run._full is None or run._full[0] != state:
                run._full = (state, await asyncio.to_thread(
                    build_occupancy, run.estimator.keyframes.frames,
                    run.estimator.map_poses(), run.options.map_resolution_m))
                run._map = None
            if max_side is None:
                return run._full[1]
            if run._map is None or run._map[0] != (*state, max_side):
                run._map = ((*state, max_side),
                            await asyncio.to_thread(run._full[1].downsampled, max_side))
            return run._map[1]

    async def commit(self, world: str, rid: str) -> CommitOut:
        """Make the run's map the world's map: facts into the knowledge base, grid stored.
        A resumed run is first joined to the world's map (:func:`chizu.numeric.slam.merge.resume`):
        the world's map then holds both, in its frame; in a world without a map yet it
        commits as any run does (several robots mapping one building: the first to commit
        founds the map, the others join it)."""
        run = await self._run(world, rid)
        if run.scans:  # global scan alignment first (graph SLAM, the improved RBPF)
            async with run.lock:
                await asyncio.to_thread(run.estimator.finish)
        g = await self.grid(world, rid)
        async with run.lock:
            assert run.laser is not None
            poses = run.estimator.map_poses()
            closures = loop_closures(run.estimator)
            saved = saved_map(run.estimator, run.laser, np.array(run.odometry),
                              run.options.method, run.options.map_resolution_m,
                              {"source": f"SLAM run {rid}", "world": world})
        old = self.store.artifact(world, SAVED_MAP_ARTIFACT) if run.options.resume else None
        if old is not None:  # a world without a map yet: this run's map founds it
            base = await asyncio.to_thread(from_bytes, old, "map")
            if f"SLAM run {rid}" in runs_of(base):
                raise Conflict(f"SLAM run {rid!r} is already part of the world's map: a "
                               "resumed run joins it once", field="run")

            def join() -> tuple[SavedMap, np.ndarray, OccupancyMap]:
                both, mine = resume(base, saved)
                return both, mine, both.occupancy(run.options.map_resolution_m)

            saved, mine, g = await asyncio.to_thread(join)
            run.resumed = mine
            poses, closures = saved.kf_pose, []
        chizu = await asyncio.to_thread(to_bytes, saved)
        return await self._commit_map(world, rid, g, poses, closures, chizu)

    async def upload(self, world: str, blob: bytes) -> CommitOut:
        """Make a saved map (a ``map.chizu`` file: ``chizu slam --out``, another world's
        ``GET .../map.chizu``) the world's map, as a commit does: its keyframe poses and
        grid become facts and the stored map. A map saved from another world is refused
        (field ``map``): its frame is that world's."""
        self.worlds.require(world)
        saved = await asyncio.to_thread(from_bytes, blob, "map")
        made_in = saved.meta.get("world")
        if made_in not in (None, world):
            raise InvalidInput(f"the map was made in world {made_in!r}, not {world!r}",
                               field="map")
        if len(saved) == 0:
            raise InvalidInput("the map has no keyframes", field="map")
        g = await asyncio.to_thread(saved.occupancy)
        rid = "r" + hashlib.sha256(blob).hexdigest()[:16]
        return await self._commit_map(world, rid, g, saved.kf_pose, [], blob)

    async def _commit_map(self, world: str, rid: str, g: OccupancyMap, poses: np.ndarray,
                          closures: list[list[int | float]], chizu: bytes) -> CommitOut:
        """One transaction: the map's facts (keyframe poses, occupancy summary, unknown
        regions, loop closures) into the knowledge base, its grid and saved map stored."""
        summary = g.summary()
        params = await self.worlds.ask(world, "params")
        regions = await asyncio.to_thread(
            g.unknown_regions, float(params["parameters"]["unknown_region_min_area_m2"]))
        call = {"world": world, "run": rid,
                "poses": [[round(float(v), 6) for v in p] for p in poses],
                "info": {k: summary[k] for k in ("resolution_m", "free_m2", "occupied_m2",
                                                 "unknown_m2")},
                "regions": regions, "closures": closures}

        def encode() -> tuple[bytes, dict[str, bytes]]:
            drawing = g.downsampled(DRAWING_PX)
            return json.dumps(call).encode(), {
                MAP_ARTIFACT: g.to_npz(), SAVED_MAP_ARTIFACT: chizu,
                DRAWING_ARTIFACT: drawing.to_png(),
                DRAWING_YAML_ARTIFACT: drawing.to_yaml("map.pgm").encode()}

        blob, extra = await asyncio.to_thread(encode)
        async with self.worlds.write_artifact(world, FACTS_ARTIFACT) as w:
            reply = await w.commit(blob, extra, call)
        return CommitOut(world=world, run=rid, facts=reply, map=summary,
                         unknown_regions=regions, loop_closures=len(closures))

    async def committed_grid(self, world: str, max_side: int | None = None) -> OccupancyMap:
        """The world's committed occupancy grid (404 naming ``map`` before a commit),
        with at most ``max_side`` cells a side if given (:meth:`OccupancyMap.downsampled`).
        Kept per world until its stored content changes: a large map is decoded once."""
        self.worlds.require(world)
        version = self.store.world_version(world)
        key = (world, version, max_side)
        if key not in self._grids:
            blob = self.store.artifact(world, MAP_ARTIFACT)
            if blob is None:
                raise NotFound(f"world {world!r} has no committed map: commit a SLAM run "
                               "or upload a map first", field="map")
            g = await asyncio.to_thread(OccupancyMap.from_npz, blob)
            if max_side is not None:
                g = await asyncio.to_thread(g.downsampled, max_side)
            self._grids[key] = g
            while len(self._grids) > 4:  # the few maps being looked at
                self._grids.pop(next(iter(self._grids)))
        return self._grids[key]

    def _drawing(self, world: str, kind: str, max_side: int | None) -> bytes | None:
        """The drawing made at commit (``DRAWING_PX`` a side), when that size is asked."""
        if max_side != DRAWING_PX:
            return None
        self.worlds.require(world)
        return self.store.artifact(world, kind)

    async def committed_png(self, world: str, max_side: int | None = None) -> bytes:
        """:meth:`committed_grid` as a PNG: the drawing made at commit for
        ``max_side == DRAWING_PX``, else encoded once per version and size."""
        drawing = self._drawing(world, DRAWING_ARTIFACT, max_side)
        if drawing is not None:
            return drawing
        g = await self.committed_grid(world, max_side)
        key = (world, self.store.world_version(world), max_side)
        if self._png is None or self._png[0] != key:
            self._png = (key, await asyncio.to_thread(g.to_png))
        return self._png[1]

    async def committed_yaml(self, world: str, max_side: int | None = None) -> bytes:
        """map_server YAML of :meth:`committed_grid` (of ``map.pgm``, or of the
        downsampled ``map.png`` with ``max_side``)."""
        drawing = self._drawing(world, DRAWING_YAML_ARTIFACT, max_side)
        if drawing is not None:
            return drawing
        return (await self.committed_grid(world, max_side)).to_yaml("map.pgm").encode()

    def saved_map(self, world: str) -> bytes:
        """The world's committed map as a ``map.chizu`` file."""
        self.worlds.require(world)
        blob = self.store.artifact(world, SAVED_MAP_ARTIFACT)
        if blob is None:
            raise NotFound(f"world {world!r} has no committed map: commit a SLAM run "
                           "or upload a map first", field="map")
        return blob

    async def summary(self, world: str) -> Any:
        return await self.worlds.ask(world, "slam_summary")

    async def regions_near(self, world: str, x: float, y: float, radius: float) -> Any:
        return await self.worlds.ask(world, "slam_regions_near", x=x, y=y, radius=radius)

    async def delete(self, world: str, rid: str) -> None:
        await self._delete(world, rid)
