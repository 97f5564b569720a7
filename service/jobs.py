"""Durable jobs: long work (an eigenspace learning) is a row in the store with its
status, stage, progress and result, so a client polling it after a restart learns what
happened instead of a 404.

Status: ``queued`` -> ``running`` -> ``done`` | ``failed`` | ``cancelled``. A job
queued or running when the process ended (a crash, a ``kill -9``, a shutdown) is queued
again at the next start and runs from its beginning if its kind registered how to re-run
it from its stored request (:meth:`Jobs.resumable`; an eigenspace learning, deterministic
given its configuration), at most :data:`MAX_ATTEMPTS` times; otherwise it is marked
``interrupted`` (:meth:`Jobs.resume_unfinished`). ``DELETE /jobs/{id}`` cancels a job:
its coroutine is cancelled at once (nothing it had not committed is committed) and the
work in its worker thread stops at its next progress report.
"""

from __future__ import annotations

import asyncio
import logging
import math
import threading
import time
import uuid
from collections.abc import Awaitable, Callable
from typing import Any

from chizu.numeric.errors import ChizuError, Conflict, NotFound
from chizu.service.events import EventHub
from chizu.service.kb import KbError
from chizu.service.schemas.jobs import JobOut
from chizu.service.store import Store

log = logging.getLogger(__name__)

UNFINISHED = ("queued", "running")
#: starts of one job after restarts at most: a job that takes the process down with it
#: every time must not do so for ever
MAX_ATTEMPTS = 3


class JobCancelled(Exception):
    """Raised in a job's worker thread by its progress report once the job is cancelled."""


class JobOverBudget(ChizuError):
    """Raised in a job's worker thread by its progress report once its time is up."""


class JobProgress:
    """What a job's work reports through: ``progress(stage, fraction)``. Writes reach the
    store when the stage changes or every ``interval_s`` at most (the work may report
    thousands of times); raises :class:`JobCancelled` once the job is cancelled and
    :class:`JobOverBudget` once it has run for ``budget_s``."""

    def __init__(self, store: Store, jid: str, cancelled: threading.Event,
                 interval_s: float = 0.5, budget_s: float = math.inf,
                 written: Callable[[str], None] | None = None) -> None:
        self.store, self.jid, self.cancelled = store, jid, cancelled
        self.written = written or (lambda jid: None)  # told after each write
        self.interval_s, self.budget_s = interval_s, budget_s
        self._deadline = time.monotonic() + budget_s
        self._stage: str | None = None
        self._written = 0.0

    def __call__(self, stage: str, frac: float) -> None:
        if self.cancelled.is_set():
            raise JobCancelled(self.jid)
        now = time.monotonic()
        if now > self._deadline:
            raise JobOverBudget(f"the job ran past its time budget of {self.budget_s:g} s "
                                f"(in stage {stage!r}) and was stopped; ask for less "
                                "(e.g. a coarser learning grid)", field=None)
        if stage != self._stage or now - self._written >= self.interval_s:
            self._stage, self._written = stage, now
            self.store.update_job(self.jid, unfinished_only=True, stage=stage,
                                  progress=float(min(max(frac, 0.0), 1.0)))
            self.written(self.jid)


Work = Callable[[JobProgress], Awaitable[dict[str, Any]]]
#: how a kind of job is made again from its world and its stored request
Remake = Callable[[str, bytes], Work]


class Jobs:
    """Durable background jobs; each may run for ``budget_s`` (its progress reports stop
    it past that)."""

    def __init__(self, store: Store, budget_s: float = math.inf,
                 events: EventHub | None = None) -> None:
        self.store, self.budget_s, self.events = store, budget_s, events
        self._tasks: dict[str, asyncio.Task[None]] = {}
        self._cancel: dict[str, threading.Event] = {}
        self._closing = False
        self._remake: dict[str, Remake] = {}

    def resumable(self, kind: str, remake: Remake) -> None:
        """Declare that jobs of ``kind`` can run again after a restart: ``remake(world,
        request)`` gives the work from the request :meth:`start` stored."""
        self._remake[kind] = remake

    def resume_unfinished(self) -> tuple[int, int]:
        """Start-up (on the running event loop): every job still queued or running
        belonged to a process that ended. Those of a resumable kind with a request are
        queued again and started (their ``attempts`` counted, up to
        :data:`MAX_ATTEMPTS`); the others are marked ``interrupted``. Returns (queued
        again, interrupted)."""
        again = lost = 0
        for jid, world, kind, request, attempts in self.store.unfinished_jobs():
            if request is None or not self._rerunnable(kind, request, attempts):
                why = (f"interrupted by {attempts + 1} restarts"
                       if request is not None and kind in self._remake else "interrupted")
                self._update(jid, status="interrupted", stage=why)
                lost += 1
                continue
            try:
                work = self._remake[kind](world, request)
            except Exception:  # noqa: BLE001 - e.g. its world is gone
                log.exception("job %s cannot be made again", jid)
                self._update(jid, status="interrupted", stage="interrupted")
                lost += 1
                continue
            self._update(jid, status="queued", stage="queued again after a restart",
                                  progress=0.0, attempts=attempts + 1)
            self._launch(jid, work)
            again += 1
        return again, lost

    def start(self, world: str, kind: str, work: Work, request: bytes | None = None) -> JobOut:
        """Queue ``work`` as a job of ``kind`` on ``world`` (one unfinished job per world
        and kind: else 409) and run it on the running event loop. ``request``, for a
        :meth:`resumable` kind, is what makes it again after a restart."""
        for st in UNFINISHED:
            if any(j["kind"] == kind for j in self.store.jobs(world=world, status=st)):
                raise Conflict(f"a {kind} job for world {world!r} is already {st}",
                               field="world")
        jid = uuid.uuid4().hex
        self.store.insert_job(jid, world, kind, request if kind in self._remake else None)
        self._published(jid)
        self._launch(jid, work)
        return self.get(jid)

    def _launch(self, jid: str, work: Work) -> None:
        self._cancel[jid] = threading.Event()
        task = asyncio.get_running_loop().create_task(self._run(jid, work))
        self._tasks[jid] = task
        task.add_done_callback(lambda _t: self._forget(jid))

    def _forget(self, jid: str) -> None:
        self._tasks.pop(jid, None)
        self._cancel.pop(jid, None)

    async def _run(self, jid: str, work: Work) -> None:
        """Run ``work``; whatever happens, the row ends in a final status (a failure to
        store the result itself is reported as the job's failure)."""
        status, fields = "failed", {}
        try:
            self._update(jid, status="running", stage="running")
            result = await work(JobProgress(self.store, jid, self._cancel[jid],
                                            budget_s=self.budget_s, written=self._published))
            status, fields = "done", {"stage": "done", "progress": 1.0, "result": result}
        except (asyncio.CancelledError, JobCancelled):
            status = "interrupted" if self._closing else "cancelled"
            fields = {"stage": status}
            if self._closing and self._resumes(jid):  # the next start runs it again
                status, fields = "queued", {"stage": "queued until the next start",
                                            "progress": 0.0}
        except ChizuError as e:
            from chizu.service.errors import status_of  # the table knows this module's errors

            if status_of(e) >= 500 or isinstance(e, KbError):
                log.warning("job %s failed: %s", jid, e)
            fields = {"error": {"detail": str(e), "field": e.field}}
        except Exception as e:  # noqa: BLE001 - reported on the job, logged here
            log.exception("job %s failed", jid)
            fields = {"error": {"detail": f"{type(e).__name__}: {e}", "field": None}}
        finally:
            self._finish(jid, status, fields)

    def _finish(self, jid: str, status: str, fields: dict[str, Any]) -> None:
        try:
            self._update(jid, status=status, **fields)
        except Exception:  # noqa: BLE001 - e.g. a result that is not JSON
            log.exception("storing the outcome of job %s", jid)
            try:
                self._update(jid, status="failed", error={
                    "detail": "the job's outcome could not be stored", "field": None})
            except Exception:  # noqa: BLE001
                log.exception("job %s keeps its last status", jid)

    def _update(self, jid: str, **fields: Any) -> None:
        """Write a job's row, then publish it as a ``job`` event of its world."""
        self.store.update_job(jid, **fields)
        self._published(jid)

    def _published(self, jid: str) -> None:
        """Publish job ``jid``'s row as a ``job`` event (read only if anyone listens)."""
        if self.events is None or not self.events.listening():
            return
        rows = self.store.jobs(jid=jid)
        if rows and self.events.listening(rows[0]["world"], "job"):
            job = JobOut(**rows[0])
            self.events.publish(job.world, "job", job.model_dump(mode="json"))

    def get(self, jid: str, world: str | None = None) -> JobOut:
        rows = self.store.jobs(jid=jid, world=world)
        if not rows:
            where = "" if world is None else f" for world {world!r}"
            raise NotFound(f"no job {jid!r}{where}", field="job")
        return JobOut(**rows[0])

    def list(self, world: str | None = None, status: str | None = None) -> list[JobOut]:
        return [JobOut(**row) for row in self.store.jobs(world=world, status=status)]

    async def cancel(self, jid: str) -> JobOut:
        """Cancel a queued or running job (409 for one that has ended); returns it."""
        job = self.get(jid)
        task = self._tasks.get(jid)
        if job.status not in UNFINISHED or task is None:
            raise Conflict(f"job {jid!r} is {job.status}, not running", field="job")
        self._cancel[jid].set()
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        if self._status(jid) in UNFINISHED:  # cancelled before it ever ran
            self._finish(jid, "cancelled", {"stage": "cancelled"})
        return self.get(jid)

    def _rerunnable(self, kind: str, request: bytes | None, attempts: int) -> bool:
        """Whether a job the process left unfinished is made again at the next start."""
        return request is not None and kind in self._remake and attempts < MAX_ATTEMPTS

    def _resumes(self, jid: str) -> bool:
        """Whether the next start queues job ``jid`` again."""
        return any(j == jid and self._rerunnable(kind, request, attempts)
                   for j, _w, kind, request, attempts in self.store.unfinished_jobs())

    async def close(self) -> None:
        """Shutdown: running jobs stop; a resumable one stays queued for the next start,
        the others end as interrupted."""
        self._closing = True
        tasks = dict(self._tasks)
        for jid, task in tasks.items():
            self._cancel[jid].set()
            task.cancel()
        await asyncio.gather(*tasks.values(), return_exceptions=True)
        for jid in tasks:
            if self._status(jid) in UNFINISHED and not self._resumes(jid):
                self._finish(jid, "interrupted", {"stage": "interrupted"})

    def _status(self, jid: str) -> str | None:
        rows = self.store.jobs(jid=jid)
        return str(rows[0]["status"]) if rows else None
