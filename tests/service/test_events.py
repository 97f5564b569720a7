"""Live events (GET /worlds/{world}/events, Server-Sent Events): what a client sees while
a job runs and scans stream in, that a slow client loses its oldest events and nothing
else, that a stream ends when its client leaves or its world is deleted, and that the
streams a service keeps open are capped (503)."""

from __future__ import annotations

import asyncio
import os
import threading
import time
from collections.abc import Iterator
from typing import Any

import httpx
import pytest

from chizu.service.client import Client, ProblemError
from chizu.service.events import QUEUE_EVENTS, EventHub, TooManySubscribers
from tests.conftest import LiveServer


class Stream:
    """A client of a world's events (the typed client's ``events.get_events``; world
    None: the service-wide ``events.get_job_events``) in a thread: the events it has
    read, as (event, data); ``problem`` if refused."""

    def __init__(self, url: str, world: str | None) -> None:
        self.events: list[tuple[str, Any]] = []
        self.problem: ProblemError | None = None
        self.answered = threading.Event()
        self._stop = threading.Event()
        self._client = Client(url)
        self._t = threading.Thread(target=self._run, args=(world,), daemon=True)
        self._t.start()

    def _run(self, world: str | None) -> None:
        events = (self._client.events.get_job_events() if world is None
                  else self._client.events.get_events(world))
        try:
            for e in events:
                self.answered.set()
                self.events.append((e.event, e.data))
                if self._stop.is_set() or e.event == "world_deleted":
                    return
        except ProblemError as e:
            self.problem = e
        except (httpx.HTTPError, RuntimeError):  # closed by close() or by the server
            pass
        finally:
            self.answered.set()

    def wait_for(self, pred: Any, timeout_s: float = 120) -> list[tuple[str, Any]]:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if any(pred(k, d) for k, d in list(self.events)):
                return self.events
            time.sleep(0.1)
        raise AssertionError(f"no such event in {self.events[-5:]}")

    def close(self) -> None:
        """Leave: the next event (or keep-alive) ends the stream; the client closes."""
        self._stop.set()
        self._client.close()


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveServer]:
    os.environ["CHIZU_MAX_EVENT_STREAMS"] = "3"
    try:
        srv = LiveServer(tmp_path_factory.mktemp("events") / "data")
    finally:
        del os.environ["CHIZU_MAX_EVENT_STREAMS"]
    yield srv
    srv.stop()


def streams(server: LiveServer) -> int:
    return int(httpx.get(server.url + "/health").json()["event_streams"])


def wait_streams(server: LiveServer, n: int, timeout_s: float = 40) -> int:
    """The count of open streams once it is ``n`` or ``timeout_s`` has passed: a stream
    its client left ends at the next event or keep-alive (every 15 s)."""
    deadline = time.monotonic() + timeout_s
    while (k := streams(server)) != n and time.monotonic() < deadline:
        time.sleep(0.2)
    return k


def test_a_job_and_a_slam_run_are_seen_as_they_happen(server: LiveServer) -> None:
    c = httpx.Client(base_url=server.url, timeout=120)
    c.post("/worlds", json={"name": "ev", "template": "room_a"}).raise_for_status()
    s = Stream(server.url, "ev")
    s.wait_for(lambda k, d: k == "open")
    job = c.post("/worlds/ev/eigenspace", json={
        "camera": {"width_px": 32, "height_px": 16, "supersample": 1},
        "learning": {"spacing_m": 1.0, "n_directions": 36}, "learning_strategy": None}).json()
    s.wait_for(lambda k, d: k == "job" and d["id"] == job["id"] and d["status"] == "done")
    mine = [d for k, d in s.events if k == "job" and d["id"] == job["id"]]
    assert mine[0]["status"] in ("queued", "running")
    progress = [d["progress"] for d in mine]
    assert progress == sorted(progress) and len(mine) >= 3
    s.wait_for(lambda k, d: k == "artifact" and d["kind"] == "eigenspace")

    rid = c.post("/worlds/ev/slam-runs", json={"method": "odom"}).json()["id"]
    scans = [{"t": 0.1 * i, "odom": [0.05 * i, 0.0, 0.0], "ranges": [2.0] * 181,
              "angle_min": -1.5707963, "angle_increment": 0.0174533} for i in range(5)]
    for sc in scans:
        c.post(f"/worlds/ev/slam-runs/{rid}/scans", json={"scans": [sc]}).raise_for_status()
    s.wait_for(lambda k, d: k == "slam_pose" and d["scans"] == 5)
    poses = [d for k, d in s.events if k == "slam_pose"]
    assert [d["scans"] for d in poses] == [1, 2, 3, 4, 5] and poses[0]["run"] == rid
    s.close()


def test_every_worlds_jobs_are_on_the_service_wide_stream(server: LiveServer) -> None:
    """GET /jobs/events: the job rows of every world, and nothing else (a jobs list kept
    current without polling)."""
    c = httpx.Client(base_url=server.url, timeout=120)
    for w in ("jobs_a", "jobs_b"):
        c.post("/worlds", json={"name": w, "template": "room_a"}).raise_for_status()
    s = Stream(server.url, None)
    s.wait_for(lambda k, d: k == "open")
    small = {"camera": {"width_px": 32, "height_px": 16, "supersample": 1},
             "learning": {"spacing_m": 1.0, "n_directions": 36}, "learning_strategy": None}
    jobs = [c.post(f"/worlds/{w}/eigenspace", json=small).json() for w in ("jobs_a", "jobs_b")]
    rid = c.post("/worlds/jobs_a/slam-runs", json={"method": "odom"}).json()["id"]
    c.post(f"/worlds/jobs_a/slam-runs/{rid}/scans", json={"scans": [{
        "t": 0.0, "odom": [0.0, 0.0, 0.0], "ranges": [2.0] * 181, "angle_min": -1.5707963,
        "angle_increment": 0.0174533}]}).raise_for_status()
    for job in jobs:
        s.wait_for(lambda k, d, j=job: k == "job" and d["id"] == j["id"]
                   and d["status"] == "done")
    assert {d["world"] for k, d in s.events if k == "job"} == {"jobs_a", "jobs_b"}
    assert {k for k, _ in s.events} == {"open", "job"}  # no pose, no artifact
    s.close()


def test_a_stream_ends_with_its_world_and_with_its_client(server: LiveServer) -> None:
    c = httpx.Client(base_url=server.url, timeout=60)
    c.post("/worlds", json={"name": "gone"}).raise_for_status()
    assert wait_streams(server, 0) == 0  # the other tests' streams have closed
    s = Stream(server.url, "gone")
    try:
        s.wait_for(lambda k, d: k == "open")
        assert streams(server) == 1
    finally:  # the world's deletion ends the stream even when the count was wrong
        c.delete("/worlds/gone").raise_for_status()
    s.wait_for(lambda k, d: k == "world_deleted")
    assert wait_streams(server, 0, timeout_s=10) == 0


def test_streams_are_capped_and_unknown_worlds_refused(server: LiveServer) -> None:
    r = httpx.get(server.url + "/worlds/nowhere/events")
    assert r.status_code == 404 and r.json()["field"] == "world"
    r = httpx.get(server.url + "/worlds/Not-a-name/events")
    assert r.status_code == 422 and r.headers["content-type"] == "application/problem+json"
    httpx.post(server.url + "/worlds", json={"name": "capped"})
    assert wait_streams(server, 0) == 0  # the other tests' streams have closed
    open_ = [Stream(server.url, "capped") for _ in range(3)]
    for s in open_:
        s.wait_for(lambda k, d: k == "open")
    extra = Stream(server.url, "capped")
    extra.answered.wait(10)
    assert extra.problem is not None and extra.problem.status == 503
    assert "event streams" in extra.problem.problem["detail"]
    for s in open_:
        s.close()


def test_a_slow_subscriber_loses_its_oldest_events_and_is_told() -> None:
    async def main() -> None:
        hub = EventHub(max_subscribers=1)
        hub.attach(asyncio.get_running_loop())
        async with hub.subscribe("w") as s:
            with pytest.raises(TooManySubscribers):
                async with hub.subscribe("w"):
                    pass
            for i in range(QUEUE_EVENTS + 10):
                hub.publish("w", "job", {"i": i})
            # from another thread too: delivered on the loop
            t = threading.Thread(target=hub.publish, args=("w", "job", {"i": -1}))
            t.start()
            t.join()
            await asyncio.sleep(0)
            first, dropped = await s.next()  # type: ignore[misc]
            assert dropped == 11 and first.data == {"i": 11}
            rest = [(await s.next())[0].data["i"] for _ in range(QUEUE_EVENTS - 1)]  # type: ignore[index]
            assert rest[-1] == -1 and len(s.events) == 0
            hub.publish("other", "job", {})  # nobody listens: nothing kept
            hub.close_world("w")
            assert await s.next() is None
        assert hub.subscribers == 0

    asyncio.run(main())


def test_the_service_wide_stream_gets_every_worlds_job_events_only() -> None:
    async def main() -> None:
        hub = EventHub()
        hub.attach(asyncio.get_running_loop())
        async with hub.subscribe(None) as s:
            assert hub.listening("w", "job") and not hub.listening("w", "slam_pose")
            hub.publish("w", "slam_pose", {"i": 0})
            hub.publish("w", "job", {"i": 1})
            hub.publish("v", "job", {"i": 2})
            got = [(await s.next())[0].data["i"] for _ in range(2)]  # type: ignore[index]
            assert got == [1, 2] and not s.events
        assert not hub.listening()

    asyncio.run(main())
