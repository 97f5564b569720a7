"""An injection attempt through every string field: refused, nothing asserted or executed."""

from __future__ import annotations

from urllib.parse import quote

import pytest
from fastapi.testclient import TestClient

from chizu.service.kb import KbError
from tests.conftest import make_fig1_world, observation

PAYLOADS = [
    "a'), halt, ('",
    "a), assertz(pwned), (",
    "X",
    "a.\n:- halt.",
    "'a'",
    "a:halt",
    "a\u0000b",
    "shell('rm -rf /')",
]


@pytest.fixture(scope="module")
def world(client: TestClient) -> str:
    make_fig1_world(client, "inj")
    return "inj"


def snapshot(client: TestClient, world: str) -> list[str]:
    return sorted(client.app.state.kb.call("facts", world=world))


@pytest.mark.parametrize("payload", PAYLOADS)
def test_http_string_fields(client: TestClient, world: str, payload: str) -> None:
    before = snapshot(client, world)
    worlds_before = client.get("/worlds").json()
    o = observation("a", ["b", "d"])
    attempts = [
        client.post("/worlds", json={"name": payload}),
        client.post("/worlds", json={"name": "ok1", "template": payload}),
        client.post("/worlds", json={"name": "ok2", "landmarks": [{"id": payload}]}),
        client.post("/worlds", json={"name": "ok3", "landmarks": [
            {"id": "a", "features": [{"name": payload}]}]}),
        client.post("/worlds", json={"name": "ok4", "rule_probabilities": {payload: 0.5}}),
        client.post("/worlds", json={"name": "ok5", "parameters": {payload: 0.5}}),
        client.post(f"/worlds/{world}/observations", json={**o, "at": payload}),
        client.post(f"/worlds/{world}/observations",
                    json={**o, "seen": [{**o["seen"][0], "landmark": payload}]}),
        client.post(f"/worlds/{world}/observations",
                    json={**o, "seen": [{**o["seen"][0], "features": [payload]}]}),
        client.post(f"/worlds/{world}/reached", json={"from": payload, "to": "c"}),
        client.post(f"/worlds/{world}/reached", json={"from": "a", "to": payload}),
        client.post(f"/worlds/{world}/failed", json={"from": payload, "to": "c"}),
        client.post(f"/worlds/{world}/failed", json={"from": "a", "to": payload}),
        client.get(f"/worlds/{world}/path", params={"from": payload, "to": "c"}),
        client.get(f"/worlds/{world}/path", params={"from": "a", "to": payload}),
        client.get(f"/worlds/{world}/relations", params={"kind": payload}),
        client.get("/worlds/" + quote(payload, safe="")),
    ]
    for r in attempts:
        assert 400 <= r.status_code < 500, (r.status_code, r.text)
    assert snapshot(client, world) == before
    assert client.get("/worlds").json() == worlds_before
    assert client.get("/health").status_code == 200


@pytest.mark.parametrize("payload", PAYLOADS)
def test_bridge_below_validation(client: TestClient, world: str, payload: str) -> None:
    """Even a caller that skips pydantic cannot get a string parsed as Prolog."""
    kb = client.app.state.kb
    before = snapshot(client, world)
    calls = [
        ("create_world", {"world": payload, "landmarks": []}),
        ("create_world", {"world": "zz1", "landmarks": [payload]}),
        ("observe", {"world": world, "at": payload, "seen": [], "angles": [], "distances": []}),
        ("observe", {"world": world, "at": "a", "seen": [{"landmark": payload}], "angles": [],
                     "distances": []}),
        ("observe", {"world": world, "at": "a", "seen": [], "angles": [[payload, "b", 1.0]],
                     "distances": []}),
        ("reached", {"world": world, "from": payload, "to": "b"}),
        ("failed", {"world": world, "from": "a", "to": payload}),
        ("relations", {"world": world, "kind": payload}),
        ("drm", {"world": payload}),
    ]
    for op, args in calls:
        with pytest.raises(KbError):
            kb.call(op, **args)
    with pytest.raises(KbError) as e:
        kb.call(payload, world=world)
    assert e.value.type == "unknown_op"
    assert snapshot(client, world) == before
    assert "zz1" not in kb.call("worlds")
