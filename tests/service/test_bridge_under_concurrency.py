"""The bridge under concurrency, and restart persistence, against a live server."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import httpx
import pytest

from chizu.service.client import AsyncClient, Client, ProblemError
from chizu.service.schemas.common import Health
from tests.conftest import make_fig1_world, observation

PAIRS = [("a", "c"), ("c", "a"), ("b", "d"), ("d", "b"), ("a", "b")]
KINDS = ["lr", "rec", "align", "reachable"]


def _request(c: Client | AsyncClient, i: int) -> Any:
    """The i-th of 64 reads of world "fig" (a path, relations, the DRM) or /health: the
    answer, or with an AsyncClient its coroutine."""
    k = i % 4
    if k == 0:
        src, dst = PAIRS[i % len(PAIRS)]
        return c.qualitative.get_path("fig", from_=src, to=dst)
    if k == 1:
        return c.qualitative.get_relations("fig", kind=KINDS[(i // 4) % 4])
    if k == 2:
        return c.qualitative.get_drm("fig")
    return c.health.health()


def test_64_concurrent_requests_equal_serial(tmp_path: Path, live_server_factory) -> None:  # type: ignore[no-untyped-def]
    srv = live_server_factory(tmp_path / "data")
    with httpx.Client(base_url=srv.url, timeout=30) as http, Client(http=http) as c:
        make_fig1_world(http, "fig")
        serial = [_request(c, i) for i in range(64)]

    async def burst() -> list[Any]:
        async with AsyncClient(srv.url, timeout_s=60) as ac:
            return await asyncio.gather(*(_request(ac, i) for i in range(64)))

    concurrent = asyncio.run(burst())
    threads = set()
    for i, (a, b) in enumerate(zip(serial, concurrent, strict=True)):
        if isinstance(b, Health):
            threads.add((b.prolog_thread, b.python_thread))
            assert a.prolog_thread == b.prolog_thread
        else:
            assert a == b, i
    assert len(threads) == 1  # one engine thread answered everything


def test_concurrent_writes_are_serialised(tmp_path: Path, live_server_factory) -> None:  # type: ignore[no-untyped-def]
    srv = live_server_factory(tmp_path / "data")
    with httpx.Client(base_url=srv.url, timeout=30) as http:
        make_fig1_world(http, "fig")

    async def writes() -> list[Any]:
        async with AsyncClient(srv.url, timeout_s=60) as ac:
            obs = [ac.qualitative.post_observation("fig", observation("a", ["b", "d"]))
                   for _ in range(16)]
            names = [ac.worlds.create_world({"name": f"w{i % 8}"}) for i in range(16)]
            return await asyncio.gather(*obs, *names, return_exceptions=True)

    rs = asyncio.run(writes())
    assert not [r for r in rs[:16] if isinstance(r, BaseException)]
    refused = [r for r in rs[16:] if isinstance(r, BaseException)]
    assert len(refused) == 8  # one of each pair of names: 409
    assert all(isinstance(r, ProblemError) and r.status == 409 for r in refused), refused
    with Client(srv.url, timeout_s=30) as c:
        names = {w.name for w in c.worlds.list_worlds()}
        assert {f"w{i}" for i in range(8)} <= names


def test_restart_keeps_worlds(tmp_path: Path, live_server_factory) -> None:  # type: ignore[no-untyped-def]
    data = tmp_path / "data"
    srv = live_server_factory(data)
    kinds = ("lr", "align", "rec", "rea", "reachable")
    with httpx.Client(base_url=srv.url, timeout=30) as http, Client(http=http) as c:
        make_fig1_world(http, "keep")
        c.qualitative.post_reached("keep", {"from": "c", "to": "b"})
        c.worlds.create_world({"name": "gone"})
        c.worlds.delete_world("gone")
        before = {k: c.qualitative.get_relations("keep", kind=k) for k in kinds}
        path = c.qualitative.get_path("keep", from_="a", to="c")
        desc = c.worlds.get_world("keep")
    srv.stop()
    srv2 = live_server_factory(data)
    with Client(srv2.url, timeout_s=30) as c:
        assert c.worlds.get_world("keep") == desc
        with pytest.raises(ProblemError) as e:
            c.worlds.get_world("gone")
        assert e.value.status == 404
        assert {k: c.qualitative.get_relations("keep", kind=k) for k in kinds} == before
        assert c.qualitative.get_path("keep", from_="a", to="c") == path


def test_calls_after_close_fail_at_once(tmp_path: Path) -> None:
    """A call submitted after close (a worker thread still running at shutdown) fails
    at once instead of waiting for ever on an engine that has stopped."""
    import threading
    import time

    from chizu.service.kb import KbError, KnowledgeBase
    from chizu.service.settings import Settings

    kb = KnowledgeBase(Settings(data_dir=tmp_path).prolog_dir, time_limit_s=2.0)
    kb.call("create_world", world="w", landmarks=[f"l{i}" for i in range(60)])
    slow = kb.submit("query", world="w", max_solutions=1,  # runs to its 2 s limit
                     goal="landmark(A), landmark(B), landmark(C), landmark(D), "
                          "landmark(E), landmark(F), fail")
    time.sleep(0.2)  # the engine is busy with it
    closing = threading.Thread(target=kb.close)
    closing.start()
    time.sleep(0.2)  # close() has queued the stop and waits for the engine
    late = kb.submit("worlds")  # after the stop: it was never answered
    with pytest.raises(KbError):
        late.result(timeout=3)
    closing.join()
    slow.result(timeout=10)
