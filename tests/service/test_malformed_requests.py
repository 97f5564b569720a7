"""A seeded bad-input table per endpoint: NaN and Infinity as raw JSON text, an empty
body, the wrong shape, a string for a number, a huge body, text Prolog cannot take.
Each is a 4xx problem+json naming the field (413 for the huge one), and the service
answers /health afterwards. A method a path does not take is a 405 naming the methods it
does; a chunked body over the size limit is a 413."""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import pytest
from fastapi.testclient import TestClient

from tests.conftest import make_fig1_world, observation
from tests.service.test_container_write_path import plan_body
from tests.slam.test_api import scan_json

PROBLEM = "application/problem+json"


def is_problem(r, status: int, field: str | None = None) -> None:  # type: ignore[no-untyped-def]
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith(PROBLEM), r.headers
    if field is not None:
        assert r.json()["field"] == field, r.text


@pytest.fixture(scope="module")
def endpoints(client: TestClient) -> list[tuple[str, dict[str, Any], list[str | int]]]:
    """(path, a valid body, the path to one of its numbers) per POST endpoint."""
    make_fig1_world(client, "rel_fig")
    assert client.post("/worlds", json={"name": "rel_room", "template": "room_a"}
                       ).status_code == 201
    rid = client.post("/worlds/rel_room/slam-runs", json={"method": "gated"}).json()["id"]
    return [
        ("/worlds", {"name": "rel_new", "landmarks": [{"id": "a", "x": 0.0, "y": 0.0}]},
         ["landmarks", 0, "x"]),
        ("/worlds/rel_fig/observations", observation("a", ["b", "d"]),
         ["seen", 0, "bearing_rad"]),
        ("/worlds/rel_fig/query", {"goal": "landmark(L)", "max_solutions": 5},
         ["max_solutions"]),
        ("/worlds/rel_room/camera", {"pose": {"x": 3.0, "y": 5.0}, "turn": 2}, ["pose", "x"]),
        ("/worlds/rel_room/slam-runs", {"method": "gated", "sigma_z": 0.001}, ["sigma_z"]),
        (f"/worlds/rel_room/slam-runs/{rid}/scans", {"scans": [scan_json(0)]},
         ["scans", 0, "t"]),
        ("/worlds/rel_room/viewpoint-plan", plan_body(), ["time_limit_s"]),
    ]


def with_value(body: dict[str, Any], path: list[str | int], raw: str) -> bytes:
    """``body`` as JSON text with the number at ``path`` replaced by the raw text."""
    marker = "__MARK__"
    b = json.loads(json.dumps(body))
    node = b
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = marker
    return json.dumps(b).replace(f'"{marker}"', raw).encode()


CASES = ["nan", "inf", "-inf", "string", "numeric_string", "true", "empty", "array",
         "null_body", "not_json", "huge"]


@pytest.mark.parametrize("case", CASES)
def test_bad_input_table(client: TestClient, endpoints: Any, case: str) -> None:
    for path, body, num in endpoints:
        # "12" and true were taken for numbers (pydantic's lax mode): JSON types are strict
        raw = {"nan": "NaN", "inf": "Infinity", "-inf": "-Infinity",
               "string": '"twelve"', "numeric_string": '"12"', "true": "true"}.get(case)
        if raw is not None:
            content = with_value(body, num, raw)
        else:
            content = {"empty": b"", "array": b"[]", "null_body": b"null",
                       "not_json": json.dumps(body).encode()[:-1],
                       "huge": b'{"x": "' + b"a" * (9 << 20) + b'"}'}[case]
        r = client.post(path, content=content, headers={"content-type": "application/json"})
        want = 413 if case == "huge" else 422
        assert r.status_code == want, (path, case, r.text[:300])
        assert r.headers["content-type"].startswith(PROBLEM), (path, case)
        field = r.json().get("field")
        assert field, (path, case, r.text[:300])
        if raw is not None:  # the field named is the number's own
            assert str(num[-1]) in field, (path, case, field)
        if case == "not_json":
            assert field == "body" and "not valid JSON" in r.json()["detail"], r.text
    assert client.get("/health").status_code == 200


def test_names_prolog_cannot_take(client: TestClient, endpoints: Any) -> None:
    """Ids are ^[a-z][a-zA-Z0-9_]{0,63}$: a quote, a NUL, an emoji or 65 characters is a
    422 naming the field before anything reaches Prolog."""
    for bad in ("a'), halt", "a\u0000b", "caf\u00e9", "\U0001F600", "a" * 65, ""):
        r = client.post("/worlds", json={"name": bad})
        assert r.status_code == 422 and r.json()["field"] == "name", (bad, r.text)
        r = client.post("/worlds/rel_fig/reached", json={"from": bad, "to": "a"})
        assert r.status_code in (404, 422) and r.json()["field"] == "from", (bad, r.text)
    assert client.get("/health").status_code == 200


def test_every_list_in_a_request_is_capped_in_the_schema(client: TestClient) -> None:
    """Size caps are stated in the OpenAPI: no array or map in a request body without a
    maximum (the movement strategy's action lists and a candidate's belief had none,
    and took NaN)."""
    spec = client.get("/openapi.json").json()
    comps = spec["components"]["schemas"]
    open_ended: list[str] = []

    def walk(sch: dict[str, Any], path: str, seen: frozenset[str]) -> None:
        if "$ref" in sch:
            ref = sch["$ref"].split("/")[-1]
            if ref not in seen:
                walk(comps[ref], path, seen | {ref})
            return
        for key in ("anyOf", "oneOf", "allOf"):
            for s in sch.get(key, []):
                walk(s, path, seen)
        if sch.get("type") == "array":
            if "maxItems" not in sch and "prefixItems" not in sch:
                open_ended.append(path)
            walk(sch.get("items", {}), path + "[]", seen)
        for p, s in sch.get("properties", {}).items():
            walk(s, f"{path}.{p}", seen)

    for path, ops in spec["paths"].items():
        for method, op in ops.items():
            for content in op.get("requestBody", {}).get("content", {}).values():
                walk(content["schema"], f"{method.upper()} {path} ", frozenset())
    assert open_ended == []
    r = client.post("/worlds/rel_room/eigenspace", content=b'{"strategy": {"alphas_rad": [NaN]}}',
                    headers={"content-type": "application/json"})
    assert r.status_code == 422 and r.json()["field"] == "strategy.alphas_rad[0]", r.text
    r = client.post("/worlds/rel_room/eigenspace", json={"strategy": {"lengths_m": []}})
    assert r.status_code == 422 and r.json()["field"] == "strategy.lengths_m", r.text


def test_json_types_are_strict(client: TestClient, endpoints: Any) -> None:
    """An integer field takes a number without a fraction (2 or 2.0, as JSON Schema's
    "integer"; not 2.5, "2" or true); a number field a JSON number; a pose's array
    still fills its tuple."""
    grid = {"width": 2, "height": 2, "resolution_m": 0.5, "data": [0, 0, 0, 0]}
    base = {**plan_body(), "grid": grid}
    ok = client.post("/worlds/rel_room/viewpoint-plan", json=base)
    assert ok.status_code == 200, ok.text
    # 2.0 is an integer to JSON Schema (no fraction), so it is taken
    ok2 = client.post("/worlds/rel_room/viewpoint-plan",
                      json={**base, "grid": {**grid, "width": 2.0}})
    assert ok2.status_code == 200, ok2.text
    for bad, field in [({"width": True}, "grid.width"), ({"data": [0, 50.5]}, "grid.data[1]"),
                       ({"data": [0, "12"]}, "grid.data[1]"),
                       ({"resolution_m": "0.5"}, "grid.resolution_m")]:
        r = client.post("/worlds/rel_room/viewpoint-plan",
                        json={**base, "grid": {**grid, **bad}})
        assert r.status_code == 422 and r.json()["field"] == field, (bad, r.text[:300])
    r = client.post("/worlds/rel_room/viewpoint-plan", json={**base, "robot": [1, "1", 0]})
    assert r.status_code == 422 and r.json()["field"] == "robot[1]", r.text[:300]
    # FastAPI reads these as JSON too (any letter case, +json): so are they checked
    body = json.dumps({**base, "grid": {**grid, "width": True}})
    for ctype in ("Application/JSON", "application/problem+json; charset=utf-8"):
        r = client.post("/worlds/rel_room/viewpoint-plan", content=body,
                        headers={"content-type": ctype})
        assert r.status_code == 422 and r.json()["field"] == "grid.width", (ctype, r.text)


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
