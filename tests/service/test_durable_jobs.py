"""Durable jobs: listed, polled and cancelled under /jobs; a learning job that a shutdown
or a kill -9 cuts off is queued again at the restart and runs to its end (a kind that
cannot be re-run is reported ``interrupted``); writes acknowledged before a kill -9 are
all there after it."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path
from typing import Any

import httpx
from fastapi.testclient import TestClient

from chizu.service.app import create_app
from chizu.service.client import Client, ProblemError
from chizu.service.schemas.jobs import JobOut
from chizu.service.settings import Settings
from tests.conftest import make_fig1_world, observation

#: a learning long enough to be caught running (the 2 m grid, images rendered without
#: supersampling: some 4 s, where the writes the tests wait for take well under one) and
#: short enough to run again after a restart
LONG = {"learning_strategy": None, "camera": {"supersample": 1}}


def wait_status(get: Any, statuses: tuple[str, ...], timeout_s: float = 120) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        j = get()
        if j["status"] in statuses:
            return j  # type: ignore[no-any-return]
        time.sleep(0.05)
    raise AssertionError(f"job never reached {statuses}: {j}")


def events(c: Client, world: str) -> int:
    return next(w.events for w in c.worlds.list_worlds() if w.name == world)


def test_cancel_list_and_bad_ids(tmp_path: Path) -> None:
    with TestClient(create_app(Settings(data_dir=tmp_path, demo_world=""))) as c:
        assert c.post("/worlds", json={"name": "w", "template": "room_a"}).status_code == 201
        r = c.post("/worlds/w/eigenspace", json=LONG)
        assert r.status_code == 202 and r.json()["status"] == "queued"
        jid = r.json()["id"]
        assert c.get(r.headers["location"]).json()["id"] == jid  # the world's own URL
        wait_status(lambda: c.get(f"/jobs/{jid}").json(), ("running",))
        busy = c.post("/worlds/w/eigenspace", json=LONG)
        assert busy.status_code == 409 and busy.json()["field"] == "world"
        out = c.delete(f"/jobs/{jid}")
        assert out.status_code == 200 and out.json()["status"] == "cancelled"
        assert c.get("/worlds/w/eigenspace").status_code == 404  # nothing committed
        again = c.delete(f"/jobs/{jid}")
        assert again.status_code == 409 and again.headers["content-type"].startswith(
            "application/problem+json")
        listed = c.get("/jobs", params={"world": "w"}).json()
        assert [(j["id"], j["kind"], j["status"]) for j in listed] == [
            (jid, "eigenspace_learning", "cancelled")]
        assert c.get("/jobs", params={"status": "running"}).json() == []
        assert c.get("/jobs/" + "0" * 32).status_code == 404
        assert c.get("/jobs/not-an-id").status_code == 422
        assert c.get("/jobs", params={"status": "sleeping"}).status_code == 422


def test_a_shutdown_leaves_a_learning_job_for_the_next_start(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path, demo_world="")
    with TestClient(create_app(settings)) as c:
        c.post("/worlds", json={"name": "w", "template": "room_a"})
        jid = c.post("/worlds/w/eigenspace", json=LONG).json()["id"]
        wait_status(lambda: c.get(f"/jobs/{jid}").json(), ("running",))
    with TestClient(create_app(settings)) as c:
        j = wait_status(lambda: c.get(f"/worlds/w/eigenspace/jobs/{jid}").json(),
                        ("done", "failed", "interrupted"), timeout_s=600)
        assert j["status"] == "done" and j["attempts"] == 1, j
        assert c.get("/worlds/w/eigenspace").json()["learning_points"] == \
            j["result"]["learning_points"]


def test_kill_9_during_a_job_and_a_write_loop(tmp_path: Path,
                                              live_server_factory: Any) -> None:
    data = tmp_path / "data"
    srv = live_server_factory(data)
    acked: list[int] = []
    stop = threading.Event()

    def write_loop() -> None:  # observations, one after the other, until the kill
        with Client(srv.url, timeout_s=10) as w:
            k = 0
            while not stop.is_set():
                try:
                    w.qualitative.post_observation(
                        "fig", observation("a", ["b", "d"], heading=0.001 * k))
                except ProblemError:  # refused: not acknowledged
                    pass
                except httpx.HTTPError:  # the server is gone
                    return
                else:
                    acked.append(k)
                k += 1

    with httpx.Client(base_url=srv.url, timeout=30) as http, Client(http=http) as c:
        make_fig1_world(http, "fig")
        base = events(c, "fig")
        c.worlds.create_world({"name": "w", "template": "room_a"})
        jid = c.eigenspace.post_eigenspace("w", LONG).id
        writer = threading.Thread(target=write_loop)
        writer.start()
        wait_status(lambda: c.jobs.get_job(jid).model_dump(), ("running",))
        while len(acked) < 20:
            time.sleep(0.05)
    os.kill(srv.proc.pid, signal.SIGKILL)
    srv.proc.wait()
    stop.set()
    writer.join()
    srv2 = live_server_factory(data)
    with Client(srv2.url, timeout_s=30) as c:
        n = events(c, "fig") - base
        assert n >= len(acked)  # every acknowledged write is there
        assert n <= len(acked) + 1  # at most the one in flight at the kill
        # the learning the kill cut off runs again from its stored request
        assert c.wait_job(jid, timeout_s=600).attempts == 1
        c.eigenspace.get_eigenspace("w")  # committed: no 404


def test_jobs_queued_again_after_a_restart(tmp_path: Path) -> None:
    """Rows left queued or running by a process that ended: a resumable kind with its
    request runs again from it (attempts counted); past MAX_ATTEMPTS, without a
    request, or of a kind that cannot be re-run, the job is interrupted."""
    import asyncio

    from chizu.service.jobs import MAX_ATTEMPTS, Jobs
    from chizu.service.store import Store

    store = Store(tmp_path / "s.sqlite3")
    with store.transaction() as conn:
        store.insert_world(conn, "w", {"name": "w"})
    store.insert_job("a", "w", "learn", b"3")
    store.insert_job("b", "w", "learn", b"4")
    store.update_job("b", status="running", attempts=MAX_ATTEMPTS)
    store.insert_job("c", "w", "learn", None)
    store.insert_job("d", "w", "mission", b"{}")
    store.update_job("a", status="running", stage="learning", progress=0.5)
    made: list[tuple[str, bytes]] = []

    def remake(world: str, request: bytes) -> Any:
        made.append((world, request))

        async def work(progress: Any) -> dict[str, Any]:
            return {"n": int(request) * 2}

        return work

    jobs = Jobs(store)
    jobs.resumable("learn", remake)

    async def scenario() -> tuple[int, int]:
        counts = jobs.resume_unfinished()
        while jobs.get("a").status in ("queued", "running"):
            await asyncio.sleep(0.01)
        return counts

    assert asyncio.run(scenario()) == (1, 3)
    assert made == [("w", b"3")]
    a = jobs.get("a")
    assert (a.status, a.result, a.attempts) == ("done", {"n": 6}, 1)
    assert [jobs.get(j).status for j in "bcd"] == ["interrupted"] * 3
    assert jobs.get("b").stage == f"interrupted by {MAX_ATTEMPTS + 1} restarts"
    store.close()


def test_a_job_cancelled_before_it_starts_is_cancelled(tmp_path: Path) -> None:
    """Cancelled before its task ever ran, a job stayed "queued" and every later learning
    of that world was a 409; now it ends cancelled and the world can learn again."""
    import asyncio

    from chizu.service.jobs import Jobs
    from chizu.service.store import Store

    store = Store(tmp_path / "s.sqlite3")
    with store.transaction() as conn:
        store.insert_world(conn, "w", {"name": "w"})
    jobs = Jobs(store)

    async def scenario() -> tuple[str, str]:
        async def work(progress: Any) -> dict[str, Any]:
            return {"ok": True}

        jid = jobs.start("w", "k", work).id
        cancelled = (await jobs.cancel(jid)).status  # before the task's first step
        again = jobs.start("w", "k", work).id
        await asyncio.sleep(0.05)
        return cancelled, jobs.get(again).status

    assert asyncio.run(scenario()) == ("cancelled", "done")
    store.close()


def test_a_job_past_its_budget_fails_and_says_why(tmp_path: Path) -> None:
    """A job that reports progress past its time budget is stopped there: it ends
    failed with the reason, and the world can start another."""
    import asyncio

    from chizu.service.jobs import Jobs
    from chizu.service.store import Store

    store = Store(tmp_path / "s.sqlite3")
    with store.transaction() as conn:
        store.insert_world(conn, "w", {"name": "w"})
    jobs = Jobs(store, budget_s=0.2)
    steps: list[int] = []

    def slow(progress: Any) -> dict[str, Any]:
        for i in range(100):
            progress("learning", i / 100)
            steps.append(i)
            time.sleep(0.02)
        return {"ok": True}

    async def scenario() -> JobOut:
        async def work(progress: Any) -> dict[str, Any]:
            return await asyncio.to_thread(slow, progress)

        jid = jobs.start("w", "k", work).id
        while jobs.get(jid).status in ("queued", "running"):
            await asyncio.sleep(0.02)
        return jobs.get(jid)

    job = asyncio.run(scenario())
    assert job.status == "failed", job
    assert job.error is not None and "time budget of 0.2 s" in job.error.detail
    assert len(steps) < 50  # stopped, not run to the end
    store.close()
