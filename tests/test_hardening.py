"""Hostile and careless clients (issue "Hardening"): each request that once answered 500,
blocked or lost its headers, sent again."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

from fastapi.testclient import TestClient

from service.kb import KnowledgeBase

PROBLEM = "application/problem+json"
ROOT = Path(__file__).resolve().parent.parent


def is_problem(r, status: int, field: str | None = None) -> None:  # type: ignore[no-untyped-def]
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith(PROBLEM), r.headers
    if field is not None:
        assert r.json()["field"] == field, r.text


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


def test_405_names_the_allowed_methods(client: TestClient) -> None:
    r = client.put("/worlds/demo/query", json={})
    is_problem(r, 405)
    assert "POST" in r.headers["allow"]
    r = client.delete("/health")
    is_problem(r, 405)
    assert "GET" in r.headers["allow"]


def test_a_chunked_body_over_the_limit_is_413(client: TestClient) -> None:
    """No Content-Length (chunked): 9 MiB was "400 error parsing the body"."""

    def chunks() -> Iterator[bytes]:
        for _ in range(9):
            yield b" " * (1 << 20)

    r = client.post("/worlds", content=chunks(), headers={"content-type": "application/json"})
    is_problem(r, 413, "body")

    def small() -> Iterator[bytes]:
        yield b'{"name": "chunked_ok", '
        yield b'"template": "demo"}'

    r = client.post("/worlds", content=small(), headers={"content-type": "application/json"})
    assert r.status_code == 201, r.text  # a chunked body within the limit still works


def test_client_goals_get_the_shorter_limit() -> None:
    """The engine is one thread: a client's own goal runs under kb_query_time_limit_s,
    everything else under kb_time_limit_s."""
    kb = KnowledgeBase.__new__(KnowledgeBase)
    kb.time_limit_s, kb.inference_limit, kb.query_time_limit_s = 10.0, 1000, 2.0
    assert json.loads(kb._request("query", {}))["time_limit_s"] == 2.0
    assert json.loads(kb._request("facts", {}))["time_limit_s"] == 10.0
