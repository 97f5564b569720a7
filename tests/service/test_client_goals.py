"""A client's own Prolog goal on the one engine: a goal that raises is the client's error,
non-finite numbers in an answer come back as text, a client's goal runs under the shorter
time limit, /health answers while a goal holds the engine, and a goal whose client has
left is dropped before it runs or stopped while it runs."""

from __future__ import annotations

import json
from typing import Any

from fastapi.testclient import TestClient

from chizu.service.kb import KbError, KnowledgeBase
from tests.service.test_malformed_requests import is_problem


def test_a_goal_that_raises_is_the_clients_error(client: TestClient) -> None:
    """``X > 1`` (an unbound comparison) was a 500; a type error likewise."""
    for goal in ("X > 1", "landmark(L), L > 1", "reachable(A, B, P, M), M < P"):
        r = client.post("/worlds/demo/query", json={"goal": goal})
        is_problem(r, 422, "goal")
        assert r.json()["type"].endswith("goal-error"), r.text


def test_non_finite_numbers_in_an_answer_are_text(client: TestClient) -> None:
    """``X = 1.0Inf`` and ``X = 1.5NaN`` were a 500 text/plain: JSON has no such numbers."""
    for goal, text in (("X = 1.0Inf", "inf"), ("X = -1.0Inf", "-1.0inf"), ("X = 1.5NaN", "nan")):
        r = client.post("/worlds/demo/query", json={"goal": goal})
        assert r.status_code == 200, r.text
        value = r.json()["solutions"][0]["X"]
        assert isinstance(value, str) and text in value.lower(), value
    json.loads(r.text)  # strict JSON


def test_client_goals_get_the_shorter_limit() -> None:
    """The engine is one thread: a client's own goal runs under kb_query_time_limit_s,
    everything else under kb_time_limit_s."""
    kb = KnowledgeBase.__new__(KnowledgeBase)
    kb.time_limit_s, kb.inference_limit, kb.query_time_limit_s = 10.0, 1000, 2.0
    assert json.loads(kb._request("query", {}))["time_limit_s"] == 2.0
    assert json.loads(kb._request("facts", {}))["time_limit_s"] == 10.0


def test_health_answers_while_a_query_holds_the_engine(client: TestClient) -> None:
    """A legal goal run to its time limit held the one engine, and /health waited 9.5 s
    behind it. Now /health probes the engine for 20 ms and says it is busy."""
    import threading
    import time

    assert client.get("/health").json()["engine_busy"] is False
    slow = ("reachable(A, B, P, M), reachable(C, D, Q, N), reachable(E, F, R, O), fail")
    done: list[int] = []
    t = threading.Thread(target=lambda: done.append(client.post(
        "/worlds/demo/query", json={"goal": slow}).status_code))
    t.start()
    time.sleep(0.3)  # the query is running
    t0 = time.perf_counter()
    h = client.get("/health")
    waited = time.perf_counter() - t0
    t.join()
    assert h.status_code == 200 and h.json()["engine_busy"] is True, h.text
    assert waited < 0.5, waited  # the goal ran for its whole 2 s limit
    assert done and done[0] in (200, 422)  # finished, or stopped at its limit (load)


def test_a_query_whose_client_left_is_dropped(client: TestClient) -> None:
    """A client goal queued behind a slow one, whose client disconnects meanwhile, is
    dropped before it runs (the engine skips a cancelled call)."""
    import asyncio
    import threading
    import time

    from chizu.service.disconnect import ClientGone, unless_disconnected

    kb = client.app.state.services.kb  # type: ignore[attr-defined]
    slow = "reachable(A, B, P, M), reachable(C, D, Q, N), reachable(E, F, R, O), fail"
    busy = threading.Thread(target=lambda: kb.submit("query", world="demo", goal=slow,
                                                     max_solutions=1).result())
    busy.start()
    time.sleep(0.2)
    queued: list[Any] = []

    class Gone:
        async def is_disconnected(self) -> bool:
            return True

    async def ask() -> None:
        fut = kb.submit("query", world="demo", goal="landmark(L)", max_solutions=1)
        queued.append(fut)
        await unless_disconnected(Gone(), asyncio.wrap_future(fut), poll_s=0.01)

    try:
        asyncio.run(ask())
    except ClientGone:
        pass
    else:
        raise AssertionError("the departed client's query was answered")
    busy.join()
    assert queued[0].cancelled()  # dropped, never run


def test_a_running_query_whose_client_left_is_stopped(client: TestClient) -> None:
    """A client goal already running when its client leaves stops at its next check
    (every 0.1 s) instead of holding the one engine to its time limit (2 s)."""
    import asyncio
    import time

    kb = client.app.state.services.kb  # type: ignore[attr-defined]
    slow = "reachable(A, B, P, M), reachable(C, D, Q, N), reachable(E, F, R, O), fail"

    async def leave_early() -> float:
        task = asyncio.ensure_future(kb.acall("query", world="demo", goal=slow,
                                              max_solutions=1))
        await asyncio.sleep(0.3)  # running on the engine
        t0 = time.perf_counter()
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        await kb.acall("worlds")  # waits for the engine to be free
        return time.perf_counter() - t0

    freed_after = asyncio.run(leave_early())
    assert freed_after < 1.0, freed_after  # not the 1.7 s left of its limit
    # and a goal nobody cancels still runs to its limit
    try:
        kb.call("query", world="demo", goal=slow, max_solutions=1)
    except KbError as e:
        assert e.type == "limit", e
