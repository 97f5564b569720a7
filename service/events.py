"""Live events per world, for the console and API clients alike (``GET
/worlds/{world}/events``, Server-Sent Events): job progress, SLAM poses, mission steps,
committed artifacts. The service-wide stream (``GET /jobs/events``, the world ``None``
here) carries the job events of every world: a jobs list kept current without polling.

Each subscriber has its own bounded queue. A publisher never waits: when a subscriber's
queue is full its oldest event is dropped, and the next event it reads says how many it
lost (``dropped``), so a slow or stalled client costs the service nothing but its queue.
Publishing is thread-safe (work running in threads reports progress too) and costs a
dictionary lookup when nobody listens. A subscriber leaves when its stream ends: the
client disconnected, the world was deleted, or the service is shutting down.
"""

from __future__ import annotations

import asyncio
import itertools
import threading
from collections import deque
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from typing import Any

from chizu.numeric.errors import ChizuError

#: events a subscriber may have waiting before its oldest are dropped
QUEUE_EVENTS = 256
#: event streams open at once, over all worlds
MAX_SUBSCRIBERS = 64
#: the event kinds the service-wide stream (world ``None``) also receives
SERVICE_KINDS = frozenset({"job"})


class TooManySubscribers(ChizuError):
    """Every event stream slot is taken (503)."""


@dataclass(frozen=True)
class Event:
    id: int
    kind: str
    data: dict[str, Any]


@dataclass(eq=False)  # each one itself: kept in sets
class Subscriber:
    """One client's stream: its waiting events and how many were dropped since it last
    read."""

    world: str | None
    events: deque[Event] = field(default_factory=lambda: deque(maxlen=QUEUE_EVENTS))
    dropped: int = 0
    closed: bool = False
    wake: asyncio.Event = field(default_factory=asyncio.Event)

    def push(self, event: Event) -> None:
        if len(self.events) == self.events.maxlen:
            self.dropped += 1  # deque(maxlen) drops the oldest on append
        self.events.append(event)
        self.wake.set()

    def close(self) -> None:
        self.closed = True
        self.wake.set()

    async def next(self) -> tuple[Event, int] | None:
        """The next event and how many were dropped before it; None once closed."""
        while not self.events:
            if self.closed:
                return None
            self.wake.clear()
            await self.wake.wait()
        dropped, self.dropped = self.dropped, 0
        return self.events.popleft(), dropped


class EventHub:
    """The service's live events. Publishers call :meth:`publish` from any thread; the
    hub delivers on the event loop it was :meth:`attach`-ed to (none attached, as in the
    CLI: events go nowhere)."""

    def __init__(self, max_subscribers: int = MAX_SUBSCRIBERS) -> None:
        self.max_subscribers = max_subscribers
        self._subs: dict[str | None, set[Subscriber]] = {}
        self._ids = itertools.count(1)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._lock = threading.Lock()

    def attach(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop

    @property
    def subscribers(self) -> int:
        return sum(len(s) for s in self._subs.values())

    def listening(self, world: str | None = None, kind: str | None = None) -> bool:
        """Whether anyone would receive an event of ``kind`` in ``world`` (None: of any
        world): a publisher whose event costs work to make asks first."""
        if self._loop is None:
            return False
        if world is None:
            return bool(self._subs)
        return bool(self._subs.get(world)) or (kind in SERVICE_KINDS
                                               and bool(self._subs.get(None)))

    def publish(self, world: str, kind: str, data: dict[str, Any]) -> None:
        """Send ``data`` as an event of ``kind`` to every subscriber of ``world`` (and of
        the service-wide stream, for :data:`SERVICE_KINDS`)."""
        loop = self._loop
        if loop is None or not self.listening(world, kind):
            return
        with self._lock:
            event = Event(next(self._ids), kind, data)
        try:
            running = asyncio.get_running_loop()
        except RuntimeError:
            running = None
        if running is loop:
            self._deliver(world, event)
        elif not loop.is_closed():
            loop.call_soon_threadsafe(self._deliver, world, event)

    def _deliver(self, world: str, event: Event) -> None:
        for s in list(self._subs.get(world, ())):
            s.push(event)
        if event.kind in SERVICE_KINDS:
            for s in list(self._subs.get(None, ())):
                s.push(event)

    def close_world(self, world: str | None) -> None:
        """End every stream of ``world`` (it was deleted)."""
        for s in self._subs.pop(world, set()):
            s.close()

    def close(self) -> None:
        """End every stream (the service is stopping)."""
        for world in list(self._subs):
            self.close_world(world)

    @asynccontextmanager
    async def subscribe(self, world: str | None) -> AsyncIterator[Subscriber]:
        """A subscriber of ``world``'s events (None: the service-wide stream) for the
        duration of the block (503 when :data:`MAX_SUBSCRIBERS` streams are open)."""
        if self.subscribers >= self.max_subscribers:
            raise TooManySubscribers(
                f"{self.max_subscribers} event streams are open; close one or try later",
                field=None)
        s = Subscriber(world)
        self._subs.setdefault(world, set()).add(s)
        try:
            yield s
        finally:
            subs = self._subs.get(world)
            if subs is not None:
                subs.discard(s)
                if not subs:
                    self._subs.pop(world, None)
