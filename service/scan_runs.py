"""Runs that a robot streams laser scans (with odometry) into: SLAM runs
(:mod:`chizu.service.slam`) and localization runs on a world's map
(:mod:`chizu.service.localization`) share how a batch is taken in.

A batch is validated as a whole first: a malformed scan or a time stamp that does not
increase rejects it and leaves the run as it was. Every accepted scan is stored (SQLite)
before the estimator sees it; estimators are seeded, so after a restart a run is rebuilt
by replaying its scans (lazily, on first use) and ends in the same state. A batch runs
for at most the request budget, then stops between scans: the scans done are kept, the
rest are dropped from the store and the client is told where to go on.
"""

from __future__ import annotations

import asyncio
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

import numpy as np
from pydantic import BaseModel

from chizu.numeric.errors import InvalidInput, NotFound
from chizu.numeric.scan import Scan, beam_angles
from chizu.numeric.slam.saved_map import Laser
from chizu.service.compute import BudgetExceeded
from chizu.service.disconnect import thread_to_end
from chizu.service.schemas.slam import ScanIn
from chizu.service.store import RunKind, Store
from chizu.service.worlds import WorldService

MAX_SCANS_PER_RUN = 200_000


def to_scan(s: ScanIn) -> Scan:
    """The numeric scan of a request item (raises :class:`InvalidInput`)."""
    r = np.asarray(s.ranges, dtype=float)
    return Scan(t=s.t, ranges=r, angles=beam_angles(len(r), s.angle_min, s.angle_increment),
                odom=np.asarray(s.odom, dtype=float),
                intensities=None if s.intensities is None else np.asarray(s.intensities, float),
                min_range_m=s.range_min, max_range_m=s.range_max)


@dataclass
class ScanRun:
    """What every streamed run keeps: its scans so far, the last stamp, the laser of
    its first scan and every scan's odometry."""

    id: str
    world: str
    scans: int = 0
    last_t: float = -np.inf
    replayed: bool = True
    lock: asyncio.Lock = field(default_factory=asyncio.Lock)
    laser: Laser | None = None
    odometry: list[np.ndarray] = field(default_factory=list)

    def status(self) -> BaseModel:
        """What ``GET`` of the run answers (each kind says)."""
        raise NotImplementedError


R = TypeVar("R", bound=ScanRun)


class ScanRuns(Generic[R]):
    """The runs of one kind, by id; subclasses say what a scan does to a run
    (:meth:`_step`) and may check a batch before it is stored (:meth:`_check`)."""

    kind: RunKind
    #: what the runs are called in messages ("SLAM run")
    noun: str

    def __init__(self, store: Store, worlds: WorldService, budget_s: float = 30.0) -> None:
        self.store, self.worlds = store, worlds
        #: a batch of scans is processed for at most this long (then it stops between scans)
        self.budget_s = budget_s
        self.runs: dict[str, R] = {}
        worlds.on_delete.append(self._forget)

    def _forget(self, world: str) -> None:
        for rid in [r.id for r in self.runs.values() if r.world == world]:
            del self.runs[rid]

    def _step(self, run: R, scan: Scan) -> None:
        raise NotImplementedError

    def _check(self, run: R, scans: list[Scan]) -> None:
        """Refuse a batch before anything is stored (raises :class:`InvalidInput`)."""

    async def _prepare(self, run: R) -> None:
        """Before a stored run is replayed (e.g. load what it runs on)."""

    async def _run(self, world: str, rid: str) -> R:
        self.worlds.require(world)  # 404 for an unknown world
        run = self.runs.get(rid)
        if run is None or run.world != world:
            raise NotFound(f"{self.noun} {rid!r} does not exist in world {world!r}",
                           field="run")
        if not run.replayed:
            async with run.lock:
                if not run.replayed:
                    await self._prepare(run)
                    rows = self.store.scans(self.kind, rid)
                    scans = [to_scan(ScanIn.model_validate(r)) for r in rows]
                    await asyncio.to_thread(self._process, run, scans)
                    run.replayed = True
        return run

    def _store_run(self, run: R, options: dict[str, Any]) -> None:
        with self.store.transaction() as conn:
            self.store.put_run(conn, self.kind, run.id, run.world, options)
        self.runs[run.id] = run

    async def _add_scans(self, world: str, rid: str, items: list[ScanIn]) -> R:
        """Validate, store and process one batch (see the module's docstring)."""
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
            self._check(run, scans)
            first = run.scans

            def append() -> None:  # JSON of a batch: tens of ms, off the event loop
                with self.store.transaction() as conn:
                    self.store.append_scans(conn, self.kind, rid, first,
                                            [s.model_dump() for s in items])

            try:
                await thread_to_end(append)
            except asyncio.CancelledError:  # the rows went in all the same: take them out
                with self.store.transaction() as conn:
                    self.store.drop_scans_from(conn, self.kind, rid, first)
                raise
            deadline = time.monotonic() + self.budget_s
            stop = threading.Event()
            try:
                # a cancelled request (the client left, a job cancelled) stops the thread
                # between scans and waits for it, so the store below follows what it did
                # and no later request runs the estimator beside it
                await thread_to_end(self._process, run, scans, deadline, stop,
                                    on_cancel=stop.set)
            finally:
                if run.scans < first + len(scans):  # stopped midway: the store follows
                    with self.store.transaction() as conn:
                        self.store.drop_scans_from(conn, self.kind, rid, run.scans)
            done = run.scans - first
            # a live event: where the run is now (GET /worlds/{world}/events)
            if self.worlds.events.listening(world):
                self.worlds.events.publish(world, f"{self.kind}_pose", {
                    "run": rid, **run.status().model_dump(
                        mode="json", include={"scans", "last_t", "pose", "state"})})
            if done < len(scans):
                raise BudgetExceeded(
                    f"the batch ran past its time budget of {self.budget_s:g} s: its first "
                    f"{done} of {len(scans)} scans were processed and are kept; send "
                    f"scans[{done}:] again (smaller batches)", field="scans")
            return run

    def _process(self, run: R, scans: list[Scan], deadline: float = math.inf,
                 stop: threading.Event | None = None) -> None:
        """Feed ``scans`` to the run, stopping between scans past ``deadline``
        (time.monotonic; the first scan always runs, so every batch moves on) or once
        ``stop`` is set."""
        for i, s in enumerate(scans):
            if i and (time.monotonic() > deadline or (stop is not None and stop.is_set())):
                return
            self._step(run, s)
            if run.laser is None:
                run.laser = Laser.of_scan(s)
            run.odometry.append(s.odom)
            run.scans += 1
            run.last_t = s.t

    async def _delete(self, world: str, rid: str) -> None:
        run = await self._run(world, rid)
        async with run.lock:
            with self.store.transaction() as conn:
                self.store.delete_run(conn, self.kind, rid)
            self.runs.pop(rid, None)
