"""Text outside Unicode's basic plane (an emoji) round-trips through the bridge to Prolog
and back."""

from __future__ import annotations

from fastapi.testclient import TestClient


def test_text_outside_the_bmp_round_trips(client: TestClient) -> None:
    """An emoji in candidates[].type was stored as two unpaired surrogates (the bridge
    sent JSON with \\ud83d\\ude00 escapes, which Prolog read as two code points);
    reading the fact back through /query was a 500. Now the text round-trips."""
    kind = "mug\U0001F600"
    app = {"a": [40, 40, 40, 40], "b": [0.5, 0.5, 0.5, 0.5], "k": 2.0, "theta_half": 0.8}
    body = {"robot": [0.5, 0.5, 0], "exit": [0.5, 0.5], "time_limit_s": 60,
            "object_types": [{"name": kind, "value": 10, "appearance": app}],
            "grid": {"width": 40, "height": 40, "resolution_m": 0.1,
                     "data": [0] * 1600},
            "candidates": [{"id": "c1", "type": kind, "x": 2.0, "y": 2.0}]}
    assert client.post("/worlds", json={"name": "emoji", "template": "demo"}).status_code == 201
    r = client.post("/worlds/emoji/viewpoint-plan", json=body)
    assert r.status_code == 200, r.text
    r = client.post("/worlds/emoji/query", json={"goal": "vp_candidate(c1, T, _, _, _)"})
    assert r.status_code == 200, r.text
    assert r.json()["solutions"] == [{"T": kind}]
    assert any(kind in f for f in client.get("/worlds/emoji/facts").json())
