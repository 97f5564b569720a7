"""Live events of a world as Server-Sent Events (service.events): job progress, SLAM
and localization poses, mission steps, committed artifacts; and the job events of every
world on one service-wide stream."""

from __future__ import annotations

from collections.abc import AsyncIterator
from typing import Annotated

from fastapi import APIRouter, Depends
from fastapi.sse import EventSourceResponse, ServerSentEvent

from chizu.service.deps import WorldDep, WorldsDep
from chizu.service.events import Subscriber

router = APIRouter(prefix="/worlds/{world}", tags=["events"])
#: included before the jobs routes: ``/jobs/events`` is not a job id
jobs_router = APIRouter(prefix="/jobs", tags=["events"])


async def _subscriber(world: WorldDep, worlds: WorldsDep) -> AsyncIterator[Subscriber]:
    # around the whole response: the subscriber leaves when the stream ends
    async with worlds.events.subscribe(world) as s:
        yield s


@router.get("/events", response_class=EventSourceResponse)
async def get_events(world: WorldDep, s: Annotated[Subscriber, Depends(_subscriber,
                                                                        scope="request")]
                     ) -> AsyncIterator[ServerSentEvent]:
    """The world's events as they happen (``text/event-stream``): ``job`` (a job of the
    world changed: its row as ``GET /jobs/{id}`` gives it), ``slam_pose`` and
    ``localization_pose`` (a batch of scans was processed: run, scans, stamp, pose),
    ``mission_step`` (a mission recorded a step), ``artifact`` (something was
    committed: its kind), ``world_deleted``. The first event, ``open``, says the stream
    is live. Each client has a bounded queue: an event read after some were dropped
    carries ``dropped`` (how many). Keep-alive comments come every 15 s. 503 while
    ``CHIZU_MAX_EVENT_STREAMS`` streams are open."""
    yield ServerSentEvent(event="open", data={"world": world}, retry=2000)
    async for e in _stream(s):
        yield e


async def _stream(s: Subscriber) -> AsyncIterator[ServerSentEvent]:
    while (item := await s.next()) is not None:
        event, dropped = item
        data = {**event.data, "dropped": dropped} if dropped else event.data
        yield ServerSentEvent(event=event.kind, id=str(event.id), data=data)


async def _job_subscriber(worlds: WorldsDep) -> AsyncIterator[Subscriber]:
    async with worlds.events.subscribe(None) as s:
        yield s


@jobs_router.get("/events", response_class=EventSourceResponse)
async def get_job_events(s: Annotated[Subscriber, Depends(_job_subscriber, scope="request")]
                         ) -> AsyncIterator[ServerSentEvent]:
    """Every world's ``job`` events as they happen (``text/event-stream``): a job's row,
    as ``GET /jobs/{id}`` gives it, at each status and progress change. The first event,
    ``open``, says the stream is live; the queue, ``dropped`` count, keep-alives and the
    limit on open streams are those of ``GET /worlds/{world}/events``."""
    yield ServerSentEvent(event="open", data={"world": None}, retry=2000)
    async for e in _stream(s):
        yield e
