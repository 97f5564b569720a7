"""Localization runs: a robot streams scans and odometry, as into a SLAM run, and is
localized on its world's committed map, which stays as it is
(:class:`chizu.numeric.slam.map_localization.MapLocalizer`: global localization over the whole
map from an unknown start, tracking, a new global fix when lost or carried away).

A run is pinned to the map the world had when it started (its sha256). The precomputed
map (likelihood field, global search pyramid) is built once per map and shared by every
run on it, so several robots localizing in one world pay for it once. After a restart a
run is replayed from its stored scans; if the world's map changed since, it cannot be
(409, field ``map``).
"""

from __future__ import annotations

import asyncio
import hashlib
import uuid
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from chizu.numeric.errors import Conflict, InvalidInput
from chizu.numeric.scan import Scan
from chizu.numeric.slam.map_localization import MapLocalizationConfig, MapLocalizer, PreparedMap
from chizu.numeric.slam.saved_map import Laser, from_bytes
from chizu.service.scan_runs import ScanRun, ScanRuns
from chizu.service.schemas.common import PoseOut
from chizu.service.schemas.localization import LocalizationRunListed, LocalizationRunOut
from chizu.service.schemas.slam import ScanIn
from chizu.service.slam import SAVED_MAP_ARTIFACT
from chizu.service.store import Store
from chizu.service.worlds import WorldService

#: prepared maps kept in memory (each a few tens of MB for a large building)
KEEP_MAPS = 4


@dataclass
class LocRun(ScanRun):
    """A localization run: its map's hash, its localizer, and per scan the stamp, the
    pose (None where not localized) and the last match score."""

    map_sha: str = ""
    localizer: MapLocalizer | None = None
    times: list[float] = field(default_factory=list)
    poses: list[np.ndarray | None] = field(default_factory=list)
    state: str = "searching"
    score: float | None = None

    @property
    def loc(self) -> MapLocalizer:
        assert self.localizer is not None
        return self.localizer

    def status(self) -> LocalizationRunOut:
        pose = self.poses[-1] if self.poses else None
        fixes, losses = list(self.loc.fixes), list(self.loc.losses)
        return LocalizationRunOut(
            id=self.id, world=self.world, map=self.map_sha, scans=self.scans,
            last_t=None if self.scans == 0 else self.last_t, state=self.state,  # type: ignore[arg-type]
            pose=None if pose is None else PoseOut(x=float(pose[0]), y=float(pose[1]),
                                                   theta=float(pose[2])),
            score=self.score,
            first_fix_s=None if not fixes else fixes[0] - self.times[0],
            fixes=fixes, losses=losses)


class LocalizationService(ScanRuns[LocRun]):
    kind = "localization"
    noun = "localization run"

    def __init__(self, store: Store, worlds: WorldService, budget_s: float = 30.0,
                 config: MapLocalizationConfig | None = None) -> None:
        super().__init__(store, worlds, budget_s)
        self.config = config or MapLocalizationConfig()
        self._maps: OrderedDict[str, PreparedMap] = OrderedDict()
        self._building = asyncio.Lock()

    def restore_runs(self) -> int:
        """Reload the stored runs; each is replayed on first use."""
        for rid, world, opts in self.store.runs(self.kind):
            self.runs[rid] = LocRun(rid, world, map_sha=str(opts["map"]), replayed=False)
        return len(self.runs)

    def _world_map(self, world: str) -> tuple[str, bytes]:
        blob = self.store.artifact(world, SAVED_MAP_ARTIFACT)
        if blob is None:
            raise Conflict(f"world {world!r} has no committed map to localize on: commit a "
                           "SLAM run or upload a map first", field="map")
        return hashlib.sha256(blob).hexdigest(), blob

    async def _prepared(self, sha: str, blob: bytes) -> PreparedMap:
        """The map ``sha`` prepared: built once, however many runs ask at once."""
        async with self._building:
            if sha not in self._maps:
                cfg = self.config
                self._maps[sha] = await asyncio.to_thread(
                    lambda: PreparedMap.of(from_bytes(blob), cfg))
                while len(self._maps) > KEEP_MAPS:
                    self._maps.popitem(last=False)
            self._maps.move_to_end(sha)
            return self._maps[sha]

    async def _prepare(self, run: LocRun) -> None:
        sha, blob = self._world_map(run.world)
        if sha != run.map_sha:
            raise Conflict(f"the map of world {run.world!r} changed since localization run "
                           f"{run.id!r} started; start a new run", field="map")
        p = await self._prepared(sha, blob)
        run.localizer = MapLocalizer(p.saved, p.config, p)

    def _check(self, run: LocRun, scans: list[Scan]) -> None:
        for i, s in enumerate(scans):
            why = run.loc.check_laser(Laser.of_scan(s))
            if why is not None:
                raise InvalidInput(why, field=f"scans[{i}]")

    def _step(self, run: LocRun, scan: Scan) -> None:
        step = run.loc.process(scan)
        run.times.append(scan.t)
        run.poses.append(step.pose if step.state == "tracking" else None)
        run.state, run.score = step.state, float(step.score)

    async def create(self, world: str) -> LocalizationRunOut:
        self.worlds.require(world)
        sha, blob = self._world_map(world)
        rid = "l" + uuid.uuid4().hex[:16]
        run = LocRun(rid, world, map_sha=sha)
        await self._prepare(run)
        self._store_run(run, {"map": sha})
        return run.status()

    def list_runs(self, world: str) -> list[LocalizationRunListed]:
        self.worlds.require(world)
        return [LocalizationRunListed(id=r.id, map=r.map_sha,
                                      scans=r.scans if r.replayed else None)
                for r in self.runs.values() if r.world == world]

    async def status(self, world: str, rid: str) -> LocalizationRunOut:
        return (await self._run(world, rid)).status()

    async def add_scans(self, world: str, rid: str, items: list[ScanIn]
                        ) -> LocalizationRunOut:
        return (await self._add_scans(world, rid, items)).status()

    async def trajectory(self, world: str, rid: str) -> tuple[list[float],
                                                              list[np.ndarray | None]]:
        run = await self._run(world, rid)
        async with run.lock:
            return list(run.times), list(run.poses)

    async def delete(self, world: str, rid: str) -> None:
        await self._delete(world, rid)
