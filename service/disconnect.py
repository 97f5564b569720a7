"""Work for a client that may leave: stop waiting, and drop queued engine work, once the
client has disconnected; or, for work in a thread that must not run on unseen, ask it to
stop and wait for it to end (:func:`thread_to_end`)."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
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


async def thread_to_end(fn: Callable[..., T], *args: Any,
                        on_cancel: Callable[[], None] | None = None) -> T:
    """``fn(*args)`` in a thread, awaited to its end even when the caller is cancelled
    (the client left, a job was cancelled): ``on_cancel`` is called then, for ``fn`` to
    notice and stop early, and the cancellation is raised once the thread has ended --
    so no thread of cancelled work goes on beside the next request or writes after it.
    An error of ``fn`` is raised before the cancellation."""
    work = asyncio.ensure_future(asyncio.to_thread(fn, *args))
    cancelled = False
    while not work.done():
        try:
            await asyncio.shield(work)
        except asyncio.CancelledError:
            if not cancelled and on_cancel is not None:
                on_cancel()
            cancelled = True
        except BaseException:  # noqa: BLE001 - work.result() below raises it
            pass
    result = work.result()
    if cancelled:
        raise asyncio.CancelledError
    return result
