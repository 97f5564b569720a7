"""The bridge under concurrency, and restart persistence, against a live server."""

from __future__ import annotations

import asyncio
from pathlib import Path

import httpx
import pytest

from tests.conftest import make_fig1_world, observation


def _requests() -> list[tuple[str, dict]]:
    reqs: list[tuple[str, dict]] = []
    pairs = [("a", "c"), ("c", "a"), ("b", "d"), ("d", "b"), ("a", "b")]
    for i in range(64):
        k = i % 4
        if k == 0:
            src, dst = pairs[i % len(pairs)]
            reqs.append(("/worlds/fig/path", {"from": src, "to": dst}))
        elif k == 1:
            kind = ["lr", "rec", "align", "reachable"][(i // 4) % 4]
            reqs.append(("/worlds/fig/relations", {"kind": kind}))
        elif k == 2:
            reqs.append(("/worlds/fig/drm", {}))
        else:
            reqs.append(("/health", {}))
    return reqs


def test_64_concurrent_requests_equal_serial(tmp_path: Path, live_server_factory) -> None:  # type: ignore[no-untyped-def]
    srv = live_server_factory(tmp_path / "data")
    with httpx.Client(base_url=srv.url, timeout=30) as c:
        make_fig1_world(c, "fig")
        reqs = _requests()
        serial = [c.get(u, params=p) for u, p in reqs]
    assert all(r.status_code == 200 for r in serial)

    async def burst() -> list[httpx.Response]:
        async with httpx.AsyncClient(base_url=srv.url, timeout=60) as ac:
            return await asyncio.gather(*(ac.get(u, params=p) for u, p in reqs))

    concurrent = asyncio.run(burst())
    assert [r.status_code for r in concurrent] == [200] * 64
    threads = set()
    for (u, _), a, b in zip(reqs, serial, concurrent, strict=True):
        if u == "/health":
            threads.add((b.json()["prolog_thread"], b.json()["python_thread"]))
            assert a.json()["prolog_thread"] == b.json()["prolog_thread"]
        else:
            assert a.json() == b.json(), u
    assert len(threads) == 1  # one engine thread answered everything


def test_concurrent_writes_are_serialised(tmp_path: Path, live_server_factory) -> None:  # type: ignore[no-untyped-def]
    srv = live_server_factory(tmp_path / "data")
    with httpx.Client(base_url=srv.url, timeout=30) as c:
        make_fig1_world(c, "fig")

    async def writes() -> list[httpx.Response]:
        async with httpx.AsyncClient(base_url=srv.url, timeout=60) as ac:
            obs = [ac.post("/worlds/fig/observations", json=observation("a", ["b", "d"]))
                   for _ in range(16)]
            names = [ac.post("/worlds", json={"name": f"w{i % 8}"}) for i in range(16)]
            return await asyncio.gather(*obs, *names)

    rs = asyncio.run(writes())
    assert [r.status_code for r in rs[:16]] == [201] * 16
    codes = sorted(r.status_code for r in rs[16:])
    assert codes == [201] * 8 + [409] * 8
    with httpx.Client(base_url=srv.url, timeout=30) as c:
        names = {w["name"] for w in c.get("/worlds").json()}
        assert {f"w{i}" for i in range(8)} <= names


def test_restart_keeps_worlds(tmp_path: Path, live_server_factory) -> None:  # type: ignore[no-untyped-def]
    data = tmp_path / "data"
    srv = live_server_factory(data)
    with httpx.Client(base_url=srv.url, timeout=30) as c:
        make_fig1_world(c, "keep")
        assert c.post("/worlds/keep/reached", json={"from": "c", "to": "b"}).status_code == 201
        assert c.post("/worlds", json={"name": "gone"}).status_code == 201
        assert c.delete("/worlds/gone").status_code == 204
        before = {k: c.get("/worlds/keep/relations", params={"kind": k}).json()
                  for k in ("lr", "align", "rec", "rea", "reachable")}
        path = c.get("/worlds/keep/path", params={"from": "a", "to": "c"}).json()
        desc = c.get("/worlds/keep").json()
    srv.stop()
    srv2 = live_server_factory(data)
    with httpx.Client(base_url=srv2.url, timeout=30) as c:
        assert c.get("/worlds/keep").json() == desc
        assert c.get("/worlds/gone").status_code == 404
        after = {k: c.get("/worlds/keep/relations", params={"kind": k}).json()
                 for k in before}
        assert after == before
        assert c.get("/worlds/keep/path", params={"from": "a", "to": "c"}).json() == path


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
