"""SLAM runs over the API: streaming scans, pose, maps, commit into the knowledge base,
malformed scans, persistence."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from numeric.slam.simulate import simulated_log
from service.app import create_app
from service.settings import Settings

LOG = simulated_log("room_a", seed=0)


def scan_json(i: int) -> dict[str, Any]:
    s = LOG.scans[i]
    return {"t": s.t, "ranges": np.round(s.ranges, 4).tolist(),
            "intensities": np.round(s.intensities, 1).tolist(),
            "angle_min": float(s.angles[0]), "angle_increment": float(s.angles[1] - s.angles[0]),
            "range_min": s.min_range_m, "range_max": s.max_range_m,
            "odom": [float(v) for v in s.odom]}


@pytest.fixture(scope="module")
def world(client: TestClient) -> str:
    r = client.post("/worlds", json={"name": "slam_room", "template": "room_a"})
    assert r.status_code == 201, r.text
    return "slam_room"


@pytest.fixture(scope="module")
def run(client: TestClient, world: str) -> str:
    r = client.post(f"/worlds/{world}/slam-runs", json={"method": "gated"})
    assert r.status_code == 201, r.text
    assert r.headers["location"].endswith(r.json()["id"])
    rid = r.json()["id"]
    for k in range(0, 300, 100):
        r = client.post(f"/worlds/{world}/slam-runs/{rid}/scans",
                        json={"scans": [scan_json(i) for i in range(k, k + 100)]})
        assert r.status_code == 200, r.text
    return str(rid)


def test_stream_pose_and_trajectory(client: TestClient, world: str, run: str) -> None:
    st = client.get(f"/worlds/{world}/slam-runs/{run}").json()
    assert st["scans"] == 300 and st["keyframes"] > 3
    pose = client.get(f"/worlds/{world}/slam-runs/{run}/pose").json()
    truth = LOG.truth[299]
    assert np.hypot(pose["pose"]["x"] - truth[0], pose["pose"]["y"] - truth[1]) < 0.3
    tr = client.get(f"/worlds/{world}/slam-runs/{run}/trajectory").json()
    assert len(tr["poses"]) == 300 and tr["t"][0] == LOG.scans[0].t
    tum = client.get(f"/worlds/{world}/slam-runs/{run}/trajectory?format=tum").text
    assert len(tum.strip().splitlines()) == 300 and len(tum.split("\n")[0].split()) == 8
    assert any(r["id"] == run for r in client.get(f"/worlds/{world}/slam-runs").json())


def test_maps(client: TestClient, world: str, run: str) -> None:
    png = client.get(f"/worlds/{world}/slam-runs/{run}/map.png")
    assert png.status_code == 200 and png.content[:8] == b"\x89PNG\r\n\x1a\n"
    pgm = client.get(f"/worlds/{world}/slam-runs/{run}/map.pgm")
    assert pgm.content.startswith(b"P5\n")
    yaml = client.get(f"/worlds/{world}/slam-runs/{run}/map.yaml").text
    assert "image: map.pgm" in yaml and "origin:" in yaml


def test_commit_asserts_facts(client: TestClient, world: str, run: str) -> None:
    r = client.post(f"/worlds/{world}/slam-runs/{run}/commit")
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["map"]["free_m2"] > 10
    m = client.get(f"/worlds/{world}/map").json()
    assert m["run"] == run and 0 < m["explored_fraction"] <= 1
    assert m["path_length_m"] > 3
    assert len(m["regions"]) == len(body["unknown_regions"])
    facts = client.get(f"/worlds/{world}/facts").json()
    assert sum(f.startswith("map_pose(") for f in facts) == body["facts"]["poses"]
    q = client.post(f"/worlds/{world}/query", json={"goal": "explored_fraction(F)"})
    assert q.status_code == 200, q.text
    near = client.get(f"/worlds/{world}/map/unknown-regions?x=5&y=5&radius=20").json()
    assert len(near) == len(body["unknown_regions"])
    assert all(a["distance"] <= b["distance"] for a, b in zip(near, near[1:], strict=False))
    bad = client.get(f"/worlds/{world}/map/unknown-regions?x=nan&y=5")
    assert bad.status_code == 422


def test_malformed_scans_leave_the_run_unharmed(client: TestClient, world: str, run: str) -> None:
    base = f"/worlds/{world}/slam-runs/{run}"
    before = client.get(base).json()
    good = scan_json(300)

    def post(scans: Any, raw: str | None = None) -> Any:
        if raw is not None:
            return client.post(base + "/scans", content=raw,
                               headers={"content-type": "application/json"})
        return client.post(base + "/scans", json={"scans": scans})

    cases = {
        "nan": post(None, raw='{"scans": [' + str(good).replace("'", '"').replace(
            '"ranges": [', '"ranges": [NaN, ', 1) + "]}"),
        "inf_odom": post(None, raw='{"scans": [' + str({**good, "odom": [0, 0, 0]}).replace(
            "'", '"').replace('"odom": [0, 0, 0]', '"odom": [Infinity, 0, 0]') + "]}"),
        "mismatch": post([{**good, "intensities": good["intensities"][:-1]}]),
        "empty": post([{**good, "ranges": [], "intensities": []}]),
        "no_scans": post([]),
        "negative": post([{**good, "ranges": [-1.0] + good["ranges"][1:]}]),
        "old_t": post([{**good, "t": LOG.scans[10].t}]),
        "order": post([good, {**scan_json(301), "t": good["t"] - 0.05}]),
        "too_many": post([good] * 501),
        "extra": post([{**good, "bogus": 1}]),
    }
    for name, r in cases.items():
        assert r.status_code == 422, (name, r.status_code, r.text)
        assert r.headers["content-type"].startswith("application/problem+json"), name
        assert r.json().get("field") or r.json().get("errors"), name
    assert "ranges" in str(cases["nan"].json())
    assert "intensities" in str(cases["mismatch"].json())
    assert cases["old_t"].json()["field"] == "scans[0].t"
    assert cases["order"].json()["field"] == "scans[1].t"
    after = client.get(base).json()
    assert after["scans"] == before["scans"] and after["pose"] == before["pose"]
    assert client.post(base + "/scans", json={"scans": [good]}).status_code == 200


def test_unknowns(client: TestClient, world: str) -> None:
    assert client.get(f"/worlds/{world}/slam-runs/rdeadbeef").status_code == 404
    assert client.get("/worlds/nope/slam-runs/rdeadbeef").status_code == 404
    assert client.post(f"/worlds/{world}/slam-runs", json={"method": "magic"}).status_code == 422
    assert client.post(f"/worlds/{world}/slam-runs",
                       json={"particles": 0}).status_code == 422
    rid = client.post(f"/worlds/{world}/slam-runs", json={"method": "icp"}).json()["id"]
    r = client.get(f"/worlds/{world}/slam-runs/{rid}/map.png")
    assert r.status_code == 422  # no scans yet
    assert client.delete(f"/worlds/{world}/slam-runs/{rid}").status_code == 204
    assert client.get(f"/worlds/{world}/slam-runs/{rid}").status_code == 404
    assert client.get("/worlds/demo/map").status_code == 404  # nothing committed


def test_runs_and_maps_survive_restart(tmp_path: Any) -> None:
    settings = Settings(data_dir=tmp_path, demo_world="")
    with TestClient(create_app(settings)) as c:
        c.post("/worlds", json={"name": "slam_r", "template": "room_a"})
        rid = c.post("/worlds/slam_r/slam-runs", json={"method": "rbpf", "particles": 32,
                                                       "seed": 5}).json()["id"]
        c.post(f"/worlds/slam_r/slam-runs/{rid}/scans",
               json={"scans": [scan_json(i) for i in range(80)]})
        before = c.get(f"/worlds/slam_r/slam-runs/{rid}").json()
        assert c.post(f"/worlds/slam_r/slam-runs/{rid}/commit").status_code == 200
        committed = c.get("/worlds/slam_r/map").json()
    with TestClient(create_app(settings)) as c:
        after = c.get(f"/worlds/slam_r/slam-runs/{rid}").json()
        assert after["scans"] == 80 and after["pose"] == before["pose"]  # replayed, seeded
        assert c.get("/worlds/slam_r/map").json() == committed
