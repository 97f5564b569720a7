"""Contract tests: worlds resource and problem responses."""

from __future__ import annotations

from fastapi.testclient import TestClient

PROBLEM = "application/problem+json"


def assert_problem(r, status: int, field: str | None = None) -> dict:  # type: ignore[no-untyped-def]
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith(PROBLEM)
    body = r.json()
    assert body["status"] == status and body["title"] and body["detail"]
    if field is not None:
        assert body.get("field") == field or any(
            e["field"] == field for e in body.get("errors", [])), body
    return body


def test_health(client: TestClient) -> None:
    r = client.get("/health")
    assert r.status_code == 200
    assert r.json()["status"] == "ok" and r.json()["engine_thread_alive"]


def test_demo_world_served(client: TestClient) -> None:
    names = [w["name"] for w in client.get("/worlds").json()]
    assert "demo" in names
    demo = client.get("/worlds/demo").json()
    assert len(demo["landmarks"]) == 22


def test_create_get_delete(client: TestClient) -> None:
    body = {"name": "lab", "walls": [{"a": [0, 0], "b": [10, 0], "texture": "brick",
                                      "reflectivity": 0.6}],
            "landmarks": [{"id": "door1", "x": 1.0, "y": 2.0,
                           "features": [{"name": "sign", "direction_rad": 0.0,
                                         "half_width_rad": 0.8}]}],
            "objects": [{"id": "box1", "type": "A", "x": 3.0, "y": 4.0, "theta": 0.3,
                         "size_m": [0.4, 0.3, 0.5]}]}
    r = client.post("/worlds", json=body)
    assert r.status_code == 201, r.text
    assert r.json()["landmarks"] == 1 and r.json()["walls"] == 1
    got = client.get("/worlds/lab").json()
    assert got["landmarks"][0]["id"] == "door1" and got["objects"][0]["id"] == "box1"
    assert client.delete("/worlds/lab").status_code == 204
    assert_problem(client.get("/worlds/lab"), 404)
    assert_problem(client.delete("/worlds/lab"), 404)


def test_name_only_world_and_template(client: TestClient) -> None:
    assert client.post("/worlds", json={"name": "empty1"}).status_code == 201
    r = client.post("/worlds", json={"name": "office2", "template": "demo"})
    assert r.status_code == 201 and r.json()["landmarks"] == 22


def test_duplicate_world_409(client: TestClient) -> None:
    assert client.post("/worlds", json={"name": "dup"}).status_code == 201
    assert_problem(client.post("/worlds", json={"name": "dup"}), 409, "name")


def test_unknown_template_422(client: TestClient) -> None:
    """A template name outside the schema's enum is a body error (it was a 404)."""
    assert_problem(client.post("/worlds", json={"name": "t1", "template": "nosuch"}), 422,
                   "template")


def test_invalid_world_names(client: TestClient) -> None:
    for bad in ["Bad", "1x", "a b", "x'), halt, ('", "", "a" * 65]:
        assert_problem(client.post("/worlds", json={"name": bad}), 422, "name")
    assert_problem(client.get("/worlds/Bad%20name"), 422, "world")


def test_nan_and_inf_rejected(client: TestClient) -> None:
    for lit in ["NaN", "Infinity", "-Infinity"]:
        raw = '{"name": "nanw", "landmarks": [{"id": "a", "x": LIT, "y": 0}]}'.replace("LIT", lit)
        r = client.post("/worlds", content=raw, headers={"content-type": "application/json"})
        assert_problem(r, 422, "landmarks[0].x")
    assert client.get("/worlds/nanw").status_code == 404  # nothing half-written


def test_wrong_shapes(client: TestClient) -> None:
    assert_problem(client.post("/worlds", json={"name": "s1", "walls": [{"a": [0, 0, 1],
                                                                          "b": [1, 1]}]}),
                   422, "walls[0].a")
    assert_problem(client.post("/worlds", json={"name": "s2", "walls": [{"a": [0, 0],
                                                                          "b": [0, 0]}]}), 422)
    assert_problem(client.post("/worlds", json={"name": "s3", "landmarks": [{"id": "a",
                                                                              "x": 1.0}]}), 422)
    assert_problem(client.post("/worlds", json=[1, 2]), 422)
    assert_problem(client.post("/worlds", content=b"{not json",
                               headers={"content-type": "application/json"}), 422)
    assert_problem(client.post("/worlds", json={"name": "s4", "unknown_field": 1}), 422,
                   "unknown_field")


def test_duplicate_landmark_ids(client: TestClient) -> None:
    r = client.post("/worlds", json={"name": "s5", "landmarks": [{"id": "a"}, {"id": "a"}]})
    assert_problem(r, 422)


def test_bad_rule_probability(client: TestClient) -> None:
    assert_problem(client.post("/worlds", json={"name": "s6",
                                                "rule_probabilities": {"move2": 1.5}}),
                   422, "rule_probabilities.move2")
    r = client.post("/worlds", json={"name": "s7", "rule_probabilities": {"nosuch": 0.5}})
    assert_problem(r, 422, "rule_probabilities.nosuch")
    assert client.get("/worlds/s7").status_code == 404


def test_huge_payload_413(client: TestClient, app_settings) -> None:  # type: ignore[no-untyped-def]
    wall = b'{"a":[0,0],"b":[1,1]}'
    big = b'{"name": "huge", "walls": [' + b",".join([wall] * 400_000) + b"]}"
    assert len(big) > app_settings.max_body_bytes
    r = client.post("/worlds", content=big, headers={"content-type": "application/json"})
    assert_problem(r, 413)
    assert client.get("/worlds/huge").status_code == 404


def test_too_many_items_422(client: TestClient) -> None:
    walls = [{"a": [0, 0], "b": [1, 1]}] * 20_001
    assert_problem(client.post("/worlds", json={"name": "many", "walls": walls}), 422, "walls")


def test_unknown_route_problem(client: TestClient) -> None:
    assert_problem(client.get("/nope"), 404)
