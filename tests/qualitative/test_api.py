"""Contract tests: observations -> relations -> DRM -> path, and bad input."""

from __future__ import annotations

import math

import pytest
from fastapi.testclient import TestClient

from tests.conftest import make_fig1_world, observation
from tests.service.test_worlds import assert_problem


@pytest.fixture(scope="module")
def fig1(client: TestClient) -> str:
    make_fig1_world(client, "fig1")
    return "fig1"


def test_fig1_path_uses_move2(client: TestClient, fig1: str) -> None:
    r = client.get(f"/worlds/{fig1}/path", params={"from": "a", "to": "c"})
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["found"] and body["path"] == ["a", "c"]
    (step,) = body["steps"]
    assert step == {"from": "a", "to": "c", "method": "move2", "p": pytest.approx(0.95),
                    "via": ["b", "d"]}
    assert body["probability"] == pytest.approx(0.95)


def test_relations_with_probabilities(client: TestClient, fig1: str) -> None:
    lr = client.get(f"/worlds/{fig1}/relations", params={"kind": "lr"}).json()
    observed = {(x["at"], x["left"], x["right"]) for x in lr if x["p"] == 1.0}
    assert observed == {("a", "b", "d"), ("b", "c", "a"), ("d", "a", "c")}
    derived = {(x["at"], x["left"], x["right"]): x["p"] for x in lr if x["p"] < 1.0}
    assert derived[("d", "a", "b")] == pytest.approx(0.95)  # rotation of lr(a,b,d)
    rec = client.get(f"/worlds/{fig1}/relations", params={"kind": "rec"}).json()
    assert {"from": "a", "to": "b", "p": 1.0} in rec
    reach = client.get(f"/worlds/{fig1}/relations", params={"kind": "reachable"}).json()
    assert {r["method"] for r in reach} >= {"move1", "move2"}
    assert_problem(client.get(f"/worlds/{fig1}/relations", params={"kind": "bogus"}), 422,
                   "kind")


def test_quantities_are_dropped(client: TestClient, fig1: str) -> None:
    facts = client.app.state.kb.call("facts", world=fig1)
    assert not any(f.startswith(("angle(", "distance(")) for f in facts)


def test_drm_edges(client: TestClient, fig1: str) -> None:
    drm = client.get(f"/worlds/{fig1}/drm").json()
    assert set(drm["nodes"]) == {"a", "b", "c", "d"}
    pairs = [(e["from"], e["to"]) for e in drm["edges"]]
    assert len(pairs) == len(set(pairs))
    assert all(0 < e["p"] <= 1 for e in drm["edges"])


def test_reached_updates_drm(client: TestClient) -> None:
    make_fig1_world(client, "fig1r")
    before = client.get("/worlds/fig1r/path", params={"from": "a", "to": "c"}).json()
    r = client.post("/worlds/fig1r/reached", json={"from": "a", "to": "c"})
    assert r.status_code == 201 and r.json() == {"world": "fig1r", "from": "a", "to": "c",
                                                 "succeeded": 1, "failed": 0}
    after = client.get("/worlds/fig1r/path", params={"from": "a", "to": "c"}).json()
    assert after["steps"][0]["method"] == "move1"
    # rea's 0.99 weighed with the one success (prior worth two trials)
    assert after["probability"] == pytest.approx((2 * 0.99 + 1) / 3)
    assert after["probability"] > before["probability"]
    back = client.get("/worlds/fig1r/path", params={"from": "c", "to": "a"}).json()
    assert back["probability"] >= 0.9


def test_failed_arc_lowers_drm_and_reroutes(client: TestClient) -> None:
    """A failed arc weighs less (Beta posterior mean, prior worth two trials); after a
    failure of a -> c the planner goes round through b or d; the counts show in the DRM
    and survive a replay of the world's events."""
    make_fig1_world(client, "fig1f")
    url = "/worlds/fig1f/failed"
    r = client.post(url, json={"from": "a", "to": "c"})
    assert r.status_code == 201
    assert r.json() == {"world": "fig1f", "from": "a", "to": "c", "succeeded": 0, "failed": 1}
    # move2's 0.95 weighs as two trials: 2 * 0.95 / 3 = 0.63 < a -> b -> c (0.95 * 0.95)
    via = client.get("/worlds/fig1f/path", params={"from": "a", "to": "c"}).json()
    assert len(via["path"]) == 3 and via["path"][1] in ("b", "d"), via
    assert via["probability"] == pytest.approx(0.95 * 0.95)
    assert client.post(url, json={"from": "a", "to": "c"}).json()["failed"] == 2
    edge = next(e for e in client.get("/worlds/fig1f/drm").json()["edges"]
                if (e["from"], e["to"]) == ("a", "c"))
    assert (edge["succeeded"], edge["failed"]) == (0, 2)
    assert edge["p"] == pytest.approx(2 * 0.95 / 4)
    assert_problem(client.post(url, json={"from": "a", "to": "zz"}), 422, "to")
    assert_problem(client.post(url, json={"from": "a"}), 422, "to")
    assert_problem(client.post("/worlds/nosuch/failed", json={"from": "a", "to": "c"}), 404)


def test_no_path_is_a_clear_answer(client: TestClient) -> None:
    client.post("/worlds", json={"name": "island", "landmarks": [{"id": "a"}, {"id": "b"}]})
    r = client.get("/worlds/island/path", params={"from": "a", "to": "b"})
    assert r.status_code == 200
    assert r.json()["found"] is False and "no path" in r.json()["detail"]


def test_unknown_landmark_in_path_422(client: TestClient, fig1: str) -> None:
    """The world exists: a landmark it lacks is a bad parameter, not a missing page."""
    assert_problem(client.get(f"/worlds/{fig1}/path", params={"from": "a", "to": "zz"}),
                   422, "to")
    assert_problem(client.get(f"/worlds/{fig1}/path", params={"from": "A!", "to": "c"}), 422,
                   "from")
    assert_problem(client.get(f"/worlds/{fig1}/path", params={"from": "a"}), 422, "to")


def test_unknown_world_404(client: TestClient) -> None:
    assert_problem(client.get("/worlds/nosuch/drm"), 404)
    assert_problem(client.post("/worlds/nosuch/observations", json=observation("a", ["b"])),
                   404)


def test_bad_observations(client: TestClient) -> None:
    make_fig1_world(client, "fig1b")
    before = client.get("/worlds/fig1b/relations", params={"kind": "lr"}).json()
    url = "/worlds/fig1b/observations"
    raw = ('{"at": "a", "seen": [{"landmark": "b", "bearing_rad": NaN, "distance_m": 1}]}')
    assert_problem(client.post(url, content=raw, headers={"content-type": "application/json"}),
                   422, "seen[0].bearing_rad")
    raw = raw.replace("NaN", "Infinity")
    assert_problem(client.post(url, content=raw, headers={"content-type": "application/json"}),
                   422, "seen[0].bearing_rad")
    assert_problem(client.post(url, json={"seen": []}), 422, "at")
    assert_problem(client.post(url, json={"at": "a"}), 422, "seen")
    bad = observation("a", ["b", "d"])
    bad["seen"][1]["landmark"] = "zz"
    assert_problem(client.post(url, json=bad), 422, "seen[1].landmark")
    bad = observation("a", ["b", "d"])
    bad["seen"][1]["distance_m"] = -1
    assert_problem(client.post(url, json=bad), 422, "seen[1].distance_m")
    bad = observation("a", ["b", "b"])
    assert_problem(client.post(url, json=bad), 422)
    assert_problem(client.post(url, json=observation("a", ["a"])), 422)
    assert_problem(client.post(url, json={"at": "a", "seen": "b"}), 422, "seen")
    # nothing half-written: relations unchanged
    assert client.get("/worlds/fig1b/relations", params={"kind": "lr"}).json() == before


def test_empty_observation_is_valid(client: TestClient) -> None:
    make_fig1_world(client, "fig1e")
    r = client.post("/worlds/fig1e/observations", json={"at": "a", "seen": []})
    assert r.status_code == 201 and r.json()["relations"] == 0


def test_observation_sign_convention(client: TestClient) -> None:
    """lr from simulated bearings matches geometry for any robot heading."""
    coords = {"p": (0.0, 0.0), "q": (1.0, 1.0), "r": (1.0, -1.0)}
    client.post("/worlds", json={"name": "signs",
                                 "landmarks": [{"id": k} for k in coords]})
    for heading in (0.0, 2.0, -3.0):
        o = observation("p", ["q", "r"], coords, heading=heading)
        assert client.post("/worlds/signs/observations", json=o).status_code == 201
        lr = client.get("/worlds/signs/relations", params={"kind": "lr"}).json()
        assert {"at": "p", "left": "q", "right": "r", "p": 1.0} in lr  # q is to the left
    o = observation("p", ["q", "r"], {"p": (0, 0), "q": (1, 0), "r": (-1, 1e-3)})
    client.post("/worlds/signs/observations", json=o)
    al = client.get("/worlds/signs/relations", params={"kind": "align"}).json()
    assert any(a["kind"] == "not_same" and a["p"] == 1.0 for a in al)
    assert math.isfinite(al[0]["p"])


def test_readme_walkthrough(client: TestClient) -> None:
    """The README's curl walk-through, verbatim numbers."""
    client.post("/worlds", json={"name": "readme", "landmarks": [
        {"id": "a"}, {"id": "b"}, {"id": "c"}, {"id": "d"}]})
    for body in (
        {"at": "a", "seen": [{"landmark": "b", "bearing_rad": 1.7682, "distance_m": 5.10},
                             {"landmark": "d", "bearing_rad": 1.3734, "distance_m": 5.10}]},
        {"at": "b", "seen": [{"landmark": "a", "bearing_rad": -1.3734, "distance_m": 5.10},
                             {"landmark": "c", "bearing_rad": 1.3734, "distance_m": 5.10,
                              "features": ["door"]}]},
        {"at": "d", "seen": [{"landmark": "a", "bearing_rad": -1.7682, "distance_m": 5.10},
                             {"landmark": "c", "bearing_rad": 1.7682, "distance_m": 5.10}]},
    ):
        assert client.post("/worlds/readme/observations", json=body).status_code == 201
    r = client.get("/worlds/readme/path", params={"from": "a", "to": "c"}).json()
    assert r == {"found": True, "detail": None, "path": ["a", "c"], "probability": 0.95,
                 "steps": [{"from": "a", "to": "c", "method": "move2", "p": 0.95,
                            "via": ["b", "d"]}]}
    client.post("/worlds/readme/reached", json={"from": "a", "to": "c"})
    back = client.get("/worlds/readme/path", params={"from": "c", "to": "a"}).json()
    assert back["steps"][0]["method"] == "retrace" and back["probability"] == 0.9
