"""Work for a client that may leave: stop waiting, and drop queued engine work, once the
client has disconnected."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable
from typing import Any, Protocol, TypeVar

T = TypeVar("T")


class ClientGone(Exception):
    """The client disconnected before its answer was ready; nothing is sent."""


class Disconnectable(Protocol):
    async def is_disconnected(self) -> bool: ...


async def unless_disconnected(request: Disconnectable, work: Awaitable[T],
                              poll_s: float = 0.1) -> T:
    """Await ``work``, checking every ``poll_s`` whether the client is still there; if
    it left, cancel ``work`` -- a knowledge-base call still queued behind others is then
    dropped before it runs (the engine skips cancelled futures) -- and raise
    :class:`ClientGone`."""
    task: asyncio.Future[Any] = asyncio.ensure_future(work)
    try:
        while True:
            done, _ = await asyncio.wait({task}, timeout=poll_s)
            if done:
                return task.result()  # type: ignore[no-any-return]
            if await request.is_disconnected():
                if task.done():  # it finished meanwhile: its answer (or error) stands
                    return task.result()  # type: ignore[no-any-return]
                task.cancel()
                raise ClientGone
    except BaseException:
        task.cancel()
        raise
