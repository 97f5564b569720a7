"""The typed client (chizu.service.client): generated from the OpenAPI and current with
it, a method for every operation in both the sync and the async client, answers parsed
into the service's models, errors raised as ProblemError with the problem+json, and jobs
polled to their end."""

from __future__ import annotations

import asyncio
import inspect
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from chizu.service.api.client_gen import TARGET, generate
from chizu.service.app import create_app
from chizu.service.client import AsyncClient, Client, JobError, ProblemError
from chizu.service.schemas.qualitative import PathOut
from tests.conftest import LiveServer

SMALL = {"camera": {"width_px": 32, "height_px": 16, "supersample": 1},
         "learning": {"spacing_m": 1.0, "n_directions": 36}, "learning_strategy": None}


def test_the_client_is_current_with_the_api() -> None:
    """service/client.py is what the generator writes from today's OpenAPI (run
    ``python -m chizu.service.api.client_gen`` after changing a route)."""
    assert TARGET.read_text() == generate()


def test_every_operation_has_a_method_sync_and_async() -> None:
    spec = create_app().openapi()
    sync, asyn = Client("http://127.0.0.1:1"), AsyncClient("http://127.0.0.1:1")
    for path, item in spec["paths"].items():
        for method, op in item.items():
            group, name = op["operationId"].split(".", 1)
            f, g = getattr(getattr(sync, group), name), getattr(getattr(asyn, group), name)
            # an event stream is iterated (async for), not awaited
            streams = any("text/event-stream" in r.get("content", {})
                          for r in op["responses"].values())
            assert not inspect.iscoroutinefunction(f)
            assert inspect.iscoroutinefunction(g) != streams, (method, path)
            assert f"{method.upper()} {path}:" in (f.__doc__ or ""), (method, path)
            # the path's parameters are the method's first arguments, in the path's order
            params = [p for p in inspect.signature(f).parameters if p != "self"]
            in_path = [seg[1:-1] for seg in path.split("/") if seg.startswith("{")]
            assert params[:len(in_path)] == in_path, (path, params)
    sync.close()
    asyncio.run(asyn.aclose())


def test_calls_answers_and_problems(client: TestClient) -> None:
    chizu = Client(http=client)
    p = chizu.qualitative.get_path("demo", from_="rn0a", to="c1")
    assert isinstance(p, PathOut) and p.found and p.path[0] == "rn0a"
    assert chizu.worlds.create_world({"name": "cl", "template": "demo"}).name == "cl"
    q = chizu.qualitative.post_query("cl", {"goal": "landmark(L)", "max_solutions": 3})
    assert len(q.solutions) == 3 and q.truncated
    with pytest.raises(ProblemError) as e:
        chizu.qualitative.get_path("nosuch", from_="a", to="b")
    assert e.value.status == 404 and e.value.field == "world"
    assert e.value.problem["type"].startswith("/problems/")
    with pytest.raises(ProblemError) as e:
        chizu.qualitative.get_path("demo", from_="rn0a", to="zz")
    assert e.value.status == 422 and e.value.field == "to"
    with pytest.raises(ProblemError) as e:  # a name that would change the path is quoted
        chizu.worlds.get_world("../jobs")
    assert e.value.status in (404, 422)
    chizu.worlds.delete_world("cl")
    assert "cl" not in [w.name for w in chizu.worlds.list_worlds()]


def test_a_job_polled_to_its_end(client: TestClient) -> None:
    chizu = Client(http=client)
    chizu.worlds.create_world({"name": "cj", "template": "room_a"})
    job = chizu.eigenspace.post_eigenspace("cj", SMALL)
    done = chizu.wait_job(job, timeout_s=300, poll_s=0.05)
    assert done.status == "done" and done.result is not None
    assert chizu.eigenspace.get_eigenspace("cj").learning_points == \
        done.result["learning_points"]
    again = chizu.eigenspace.post_eigenspace("cj", {**SMALL, "learning_strategy": {
        "target_probability": 1.0, "max_additions": 3}})
    chizu.jobs.cancel_job(again.id)
    with pytest.raises(JobError) as e:
        chizu.wait_job(again.id, timeout_s=60)
    assert e.value.job.status == "cancelled"


def test_the_async_client_on_a_live_server(tmp_path: Path) -> None:
    server = LiveServer(tmp_path / "data", demo=True)

    async def session() -> tuple[str, int]:
        async with AsyncClient(server.url) as chizu:
            health = await chizu.health.health()
            paths = await asyncio.gather(*(chizu.qualitative.get_path(
                "demo", from_="rn0a", to=to) for to in ("c1", "c0")))
            assert all(p.found for p in paths)
            try:
                await chizu.qualitative.post_query("demo", {"goal": "assertz(x)"})
            except ProblemError as e:
                return health.status, e.status
        return health.status, 0

    try:
        assert asyncio.run(session()) == ("ok", 422)
    finally:
        server.stop()
