"""The read-only sandboxed query endpoint."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from tests.conftest import make_fig1_world
from tests.service.test_worlds import assert_problem


@pytest.fixture(scope="module")
def world(client: TestClient) -> str:
    make_fig1_world(client, "qw")
    return "qw"


def test_query_answers(client: TestClient, world: str) -> None:
    r = client.post(f"/worlds/{world}/query",
                    json={"goal": "reachable(a, c, P, Method)"})
    assert r.status_code == 200, r.text
    sols = r.json()["solutions"]
    assert {"P": pytest.approx(0.95), "Method": "move2"} in sols
    r = client.post(f"/worlds/{world}/query",
                    json={"goal": "lr(a, L, R, P), P =:= 1.0"}).json()
    assert r["solutions"] == [{"L": "b", "R": "d", "P": 1.0}] and not r["truncated"]


def test_query_truncates(client: TestClient, world: str) -> None:
    r = client.post(f"/worlds/{world}/query", json={"goal": "lr(A, B, C, P)",
                                                     "max_solutions": 3}).json()
    assert len(r["solutions"]) == 3 and r["truncated"]


@pytest.mark.parametrize("goal", ["halt", "assertz(pwned)", "shell(ls)", "call(halt)",
                                  "rec(a, X, P), halt", "X", "format(\"~a\", [x])",
                                  "'world:qw':rec(a, b)", "1 < 2**100000000"])
def test_query_refuses_unsafe(client: TestClient, world: str, goal: str) -> None:
    before = client.app.state.kb.call("facts", world=world)
    assert_problem(client.post(f"/worlds/{world}/query", json={"goal": goal}), 422, "goal")
    assert client.app.state.kb.call("facts", world=world) == before
    assert client.get("/health").status_code == 200


def test_query_bad_input(client: TestClient, world: str) -> None:
    assert_problem(client.post(f"/worlds/{world}/query", json={"goal": "rec(a, "}), 422, "goal")
    assert_problem(client.post(f"/worlds/{world}/query", json={"goal": ""}), 422, "goal")
    assert_problem(client.post(f"/worlds/{world}/query", json={"goal": "x" * 5000}), 422, "goal")
    assert_problem(client.post(f"/worlds/{world}/query", json={"goal": "true",
                                                              "max_solutions": 0}),
                   422, "max_solutions")
    assert_problem(client.post("/worlds/nosuch/query", json={"goal": "true"}), 404)


def test_query_hits_inference_limit(client: TestClient, world: str,
                                    monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(client.app.state.kb, "inference_limit", 200_000)
    goal = ", ".join(f"member(X{i}, [a,b,c,d,e,f,g,h,i,j])" for i in range(12)) + ", fail"
    r = client.post(f"/worlds/{world}/query", json={"goal": goal})
    assert_problem(r, 422, "goal")
    assert "limit" in r.json()["detail"]


def test_query_gathers_with_findall_and_aggregate_all(client: TestClient, world: str) -> None:
    """findall/3 and aggregate_all/3 over allowed goals answer as Prolog would; an
    aggregate that would evaluate arithmetic, or gathers a refused goal, is refused."""
    def one(goal: str) -> dict:  # type: ignore[type-arg]
        r = client.post(f"/worlds/{world}/query", json={"goal": goal})
        assert r.status_code == 200, r.text
        return r.json()["solutions"][0]

    every = client.post(f"/worlds/{world}/query",
                        json={"goal": "reachable(a, To, P, M)", "max_solutions": 500}
                        ).json()["solutions"]
    assert one("aggregate_all(count, reachable(a, _, _, _), N)") == {"N": len(every)}
    assert one("findall(To, reachable(a, To, _, move1), L)")["L"] == [
        s["To"] for s in every if s["M"] == "move1"]
    assert one("aggregate_all(max(P), reachable(a, _, P, _), X)")["X"] == pytest.approx(
        max(s["P"] for s in every))
    assert sorted(one("aggregate_all(set(T), reachable(a, T, _, _), S)")["S"]) == sorted(
        {s["To"] for s in every})
    for goal in ("aggregate_all(sum(P * 2), reachable(a, _, P, _), X)",
                 "aggregate_all(count, assertz(x), N)", "findall(x, halt, L)",
                 "aggregate_all(S, landmark(L), X)", "aggregate_all(foo(L), landmark(L), X)",
                 "aggregate_all(max(2 ** 100000000), landmark(_), X)"):
        assert_problem(client.post(f"/worlds/{world}/query", json={"goal": goal}), 422,
                       "goal")
