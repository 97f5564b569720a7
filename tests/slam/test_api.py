"""SLAM runs over the API: streaming scans, pose, maps, commit into the knowledge base,
malformed scans, persistence, loop closures of a graph-SLAM run as facts."""

from __future__ import annotations

import json
from functools import cache
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from chizu.numeric.scan import LaserLog
from chizu.numeric.slam import saved_map as sm
from chizu.numeric.slam.simulate import simulated_log
from chizu.service.app import create_app
from chizu.service.kb import KbError
from chizu.service.settings import Settings
from chizu.service.slam import FACTS_ARTIFACT

LOG = simulated_log("room_a", seed=0)


@cache
def loop_log() -> LaserLog:
    """The loop tour (about 1000 scans), driven fast enough to close the loop."""
    return simulated_log("loop", seed=1, speed_m_s=0.8)


def scan_json(i: int, log: LaserLog = LOG) -> dict[str, Any]:
    s = log.scans[i]
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
    r = client.post(f"/worlds/{world}/slam-runs", json={"method": "gated-icp"})
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
    # a long run's map is drawn smaller: blocks of cells merged, the YAML to match
    small = client.get(f"/worlds/{world}/slam-runs/{run}/map.png?max_px=16")
    meta = client.get(f"/worlds/{world}/slam-runs/{run}/map.yaml?max_px=16").text
    width, height = int.from_bytes(small.content[16:20], "big"), \
        int.from_bytes(small.content[20:24], "big")  # the PNG's IHDR
    full_w, full_h = int.from_bytes(png.content[16:20], "big"), \
        int.from_bytes(png.content[20:24], "big")
    f = -(-max(full_w, full_h) // 16)  # cells merged a side
    assert max(width, height) <= 16 and (width, height) == (-(-full_w // f), -(-full_h // f))

    def resolution(y: str) -> float:
        return float(y.split("resolution: ")[1].split()[0])

    assert resolution(meta) == pytest.approx(f * resolution(yaml))
    assert meta.split("origin:")[1] == yaml.split("origin:")[1]  # the same corner
    # the full-size map is still the full-size map, and a size out of range is refused
    assert client.get(f"/worlds/{world}/slam-runs/{run}/map.png").content == png.content
    for bad in ("0", "15", "x", "20001"):
        r = client.get(f"/worlds/{world}/slam-runs/{run}/map.png?max_px={bad}")
        assert r.status_code == 422 and r.json()["field"] == "max_px", (bad, r.text)


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
    # the committed grid as images: the run's map, as map_server files
    for ext in ("png", "pgm", "yaml"):
        committed = client.get(f"/worlds/{world}/map.{ext}")
        assert committed.status_code == 200, committed.text
        assert committed.content == client.get(
            f"/worlds/{world}/slam-runs/{run}/map.{ext}").content, ext
    small = client.get(f"/worlds/{world}/map.png?max_px=16")
    meta = client.get(f"/worlds/{world}/map.yaml?max_px=16").text
    width, height = int.from_bytes(small.content[16:20], "big"), \
        int.from_bytes(small.content[20:24], "big")  # the PNG's IHDR
    assert max(width, height) <= 16 and float(meta.split("resolution: ")[1].split()[0]) > \
        float(committed.text.split("resolution: ")[1].split()[0])
    assert client.get(f"/worlds/{world}/map.png?max_px=0").status_code == 422
    # the console's drawing (2048 px a side) is made at commit and stored with the map; this
    # map is smaller, so the drawing is the map itself
    listed = {w["name"]: w for w in client.get("/worlds").json()}
    assert "slam_map_drawing" in listed[world]["artifacts"]
    for ext in ("png", "yaml"):
        assert client.get(f"/worlds/{world}/map.{ext}?max_px=2048").content == \
            client.get(f"/worlds/{world}/map.{ext}").content, ext
    client.post("/worlds", json={"name": "no_map_yet"})
    none = client.get("/worlds/no_map_yet/map.png")
    assert none.status_code == 404 and none.json()["field"] == "map"


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
    assert r.status_code == 409  # no scans yet: a state, not a bad request
    assert client.delete(f"/worlds/{world}/slam-runs/{rid}").status_code == 204
    assert client.get(f"/worlds/{world}/slam-runs/{rid}").status_code == 404
    assert client.get("/worlds/demo/map").status_code == 404  # nothing committed
    r = client.get("/worlds/demo/map.chizu")
    assert r.status_code == 404 and r.headers["content-type"] == "application/problem+json"
    assert r.json()["field"] == "map"


def test_runs_and_maps_survive_restart(tmp_path: Any) -> None:
    # a loaded machine (make test beside SLAM runs) once took 30 s for 6 scans: the
    # default request budget then cut the batch short, which this test is not about
    settings = Settings(data_dir=tmp_path, demo_world="", request_budget_s=600.0)
    with TestClient(create_app(settings)) as c:
        c.post("/worlds", json={"name": "slam_r", "template": "room_a"})
        rid = c.post("/worlds/slam_r/slam-runs", json={"method": "rbpf", "particles": 32,
                                                       "seed": 5}).json()["id"]
        fed = c.post(f"/worlds/slam_r/slam-runs/{rid}/scans",
                     json={"scans": [scan_json(i) for i in range(80)]})
        assert fed.status_code == 200, fed.text
        before = c.get(f"/worlds/slam_r/slam-runs/{rid}").json()
        assert c.post(f"/worlds/slam_r/slam-runs/{rid}/commit").status_code == 200
        committed = c.get("/worlds/slam_r/map").json()
    with TestClient(create_app(settings)) as c:
        after = c.get(f"/worlds/slam_r/slam-runs/{rid}").json()
        assert after["scans"] == 80 and after["pose"] == before["pose"]  # replayed, seeded
        assert c.get("/worlds/slam_r/map").json() == committed


def post_log(c: TestClient, world: str, rid: str, log: LaserLog, batch: int = 500) -> None:
    for k in range(0, len(log.scans), batch):
        r = c.post(f"/worlds/{world}/slam-runs/{rid}/scans",
                   json={"scans": [scan_json(i, log)
                                   for i in range(k, min(k + batch, len(log.scans)))]})
        assert r.status_code == 200, r.text


def closure_facts(c: TestClient, world: str) -> list[str]:
    return sorted(f for f in c.get(f"/worlds/{world}/facts").json()
                  if f.startswith("loop_closure("))


def test_graph_run_commits_loop_closures(tmp_path: Any) -> None:
    log = loop_log()
    settings = Settings(data_dir=tmp_path, demo_world="")
    with TestClient(create_app(settings)) as c:
        assert c.post("/worlds", json={"name": "slam_loop", "template": "loop"}).status_code == 201
        r = c.post("/worlds/slam_loop/slam-runs", json={"method": "graph"})
        assert r.status_code == 201, r.text
        rid = r.json()["id"]
        base = f"/worlds/slam_loop/slam-runs/{rid}"
        post_log(c, "slam_loop", rid, log)
        st = c.get(base).json()
        assert st["scans"] == len(log.scans) and st["options"]["method"] == "graph"
        pose = c.get(base + "/pose").json()["pose"]
        truth = log.truth[-1]
        assert np.hypot(pose["x"] - truth[0], pose["y"] - truth[1]) < 0.5
        assert c.get(base + "/map.pgm").content.startswith(b"P5\n")

        r = c.post(base + "/commit")
        assert r.status_code == 200, r.text
        body = r.json()
        n = body["loop_closures"]
        assert n > 0 and body["facts"]["closures"] == n
        m = c.get("/worlds/slam_loop/map").json()
        assert m["run"] == rid and m["loop_closures"] == n
        facts = closure_facts(c, "slam_loop")
        assert len(facts) == n and all(f.startswith(f"loop_closure({rid},") for f in facts)
        q = c.post("/worlds/slam_loop/query",
                   json={"goal": "committed_map(R), loop_closure(R, A, B, S)",
                         "max_solutions": 1000}).json()
        body_solutions = q["solutions"]
        assert len(body_solutions) == n and not q["truncated"]
        for sol in body_solutions:
            assert sol["R"] == rid and 0 <= sol["A"] < sol["B"] < len(log.scans)
            assert 0 <= sol["S"] <= 1
        # a closure joins the loop's start and end: the matched scan is far later in the
        # run but near the anchor's place (ground truth)
        assert any(sol["B"] - sol["A"] > 100 and np.hypot(
            *(log.truth[sol["A"]][:2] - log.truth[sol["B"]][:2])) < 5.0
            for sol in body_solutions)
        q = c.post("/worlds/slam_loop/query", json={"goal": "loop_closure_count(N)"}).json()
        assert q["solutions"] == [{"N": n}]
        q = c.post("/worlds/slam_loop/query", json={"goal": "closes_loop(A, B)",
                                                    "max_solutions": 1000}).json()
        assert sorted((s["A"], s["B"]) for s in q["solutions"]) == sorted(
            (s["A"], s["B"]) for s in body_solutions)
        stored = json.loads(c.app.state.store.artifact("slam_loop", FACTS_ARTIFACT))
        assert len(stored["closures"]) == n
        committed = c.get("/worlds/slam_loop/map").json()
        # the committed map, saved: its keyframes, its loop constraints, every scan
        got = c.get("/worlds/slam_loop/map.chizu")
        assert got.status_code == 200
        assert got.headers["content-type"] == "application/octet-stream"
        saved = sm.from_bytes(got.content)
        assert len(saved) == st["keyframes"] and len(saved.times) == len(log.scans)
        assert (saved.constraints.kind == sm.EDGE_KINDS.index("loop")).sum() == n
        assert saved.laser.beams == len(log.scans[0].angles)
        assert np.allclose(saved.kf_odom, log.odometry[saved.kf_scan])
    with TestClient(create_app(settings)) as c:  # facts re-asserted from the artifact
        assert c.get("/worlds/slam_loop/map").json() == committed
        assert closure_facts(c, "slam_loop") == facts
        assert c.get("/worlds/slam_loop/map.chizu").content == got.content


def test_commit_without_closures(client: TestClient, world: str, run: str) -> None:
    """A run whose method finds no loop closures (gated) commits none, and replaces
    the closures a previous commit left."""
    kb = client.app.state.kb
    kb.call("slam_facts", world=world, run="rbeef", poses=[[0, 0, 0]],
            info={"resolution_m": 0.05, "free_m2": 1, "occupied_m2": 1, "unknown_m2": 1},
            regions=[], closures=[[0, 5, 0.9]])
    assert closure_facts(client, world) == ["loop_closure(rbeef,0,5,0.9)"]
    r = client.post(f"/worlds/{world}/slam-runs/{run}/commit")
    assert r.status_code == 200, r.text
    assert r.json()["loop_closures"] == 0 and r.json()["facts"]["closures"] == 0
    assert closure_facts(client, world) == []
    assert client.get(f"/worlds/{world}/map").json()["loop_closures"] == 0


def slam_call(world: str, **over: Any) -> dict[str, Any]:
    call = {"world": world, "run": "r1", "poses": [[0, 0, 0], [1, 0, 0]],
            "info": {"resolution_m": 0.05, "free_m2": 4, "occupied_m2": 1, "unknown_m2": 2},
            "regions": [{"x": 1, "y": 1, "area_m2": 1.0}],
            "closures": [[0, 7, 0.75], [3, 9, 1.0]]}
    return {**call, **over}


def test_slam_facts_refuses_bad_closures(client: TestClient) -> None:
    assert client.post("/worlds", json={"name": "slam_bad", "template": "room_a"}
                       ).status_code == 201
    kb = client.app.state.kb
    assert kb.call("slam_facts", **slam_call("slam_bad"))["closures"] == 2
    before = sorted(kb.call("facts", world="slam_bad"))
    assert "loop_closure(r1,3,9,1.0)" in before
    cases = [
        ([[0, 7, 0.5], [1, 2, 0.5], [3, 3, 0.5], [9, 4, 0.5]], "unordered_closure", "closures[2]"),
        ([[9, 4, 0.5]], "unordered_closure", "closures[0]"),
        ([[0, 7, 0.5], [1, 2, 2.0]], "invalid_score", "closures[1]"),
        ([[1, 2, -0.1]], "invalid_score", "closures[0]"),
        ([[1, 2, "0.5"]], "invalid_number", "closures[0]"),
        ([[-1, 2, 0.5]], "invalid_index", "closures[0]"),
        ([[0, 7, 0.5], [1, 2.5, 0.5]], "invalid_index", "closures[1]"),
        ([[1, "r1; halt", 0.5]], "invalid_index", "closures[0]"),
        ([[1, 2]], "invalid_closure", "closures[0]"),
        ([{"a": 1, "b": 2, "score": 0.5}], "invalid_closure", "closures[0]"),
        ({"a": 1}, "invalid_list", "closures"),
    ]
    for closures, type_, field in cases:
        with pytest.raises(KbError) as e:
            kb.call("slam_facts", **slam_call("slam_bad", run="r2", closures=closures))
        assert (e.value.type, e.value.field) == (type_, field), closures
    with pytest.raises(KbError) as e:  # the same closure twice
        kb.call("slam_facts", **slam_call("slam_bad", run="r2",
                                          closures=[[1, 2, 0.5], [1, 2, 0.6]]))
    assert e.value.type == "inconsistent_facts"
    assert sorted(kb.call("facts", world="slam_bad")) == before
    assert client.get("/worlds/slam_bad/map").json()["loop_closures"] == 2
    # a call stored before loop closures existed has no closures key: none
    old = slam_call("slam_bad", run="r3")
    del old["closures"]
    assert kb.call("slam_facts", **old)["closures"] == 0
    assert closure_facts(client, "slam_bad") == []
    assert client.delete("/worlds/slam_bad").status_code == 204


def test_old_facts_artifact_without_closures_restores(tmp_path: Any) -> None:
    settings = Settings(data_dir=tmp_path, demo_world="")
    old = slam_call("slam_old", run="r01d")
    del old["closures"]
    with TestClient(create_app(settings)) as c:
        assert c.post("/worlds", json={"name": "slam_old", "template": "room_a"}
                      ).status_code == 201
        store = c.app.state.store
        with store.transaction() as conn:
            store.put_artifact(conn, "slam_old", FACTS_ARTIFACT, json.dumps(old).encode())
    with TestClient(create_app(settings)) as c:
        m = c.get("/worlds/slam_old/map").json()
        assert m["run"] == "r01d" and m["loop_closures"] == 0
        assert closure_facts(c, "slam_old") == []


def test_run_options_take_the_estimators_bounds(client: TestClient, world: str) -> None:
    """SlamRunIn declares no bound of its own: particles, alpha, sigma_z and seed are
    RbpfConfig's, and the API refuses what the estimator would."""
    from chizu.numeric.slam.rbpf import RbpfConfig
    from chizu.service.schemas.slam import SlamRunIn

    ours = SlamRunIn.model_json_schema()["properties"]
    theirs = RbpfConfig.model_json_schema()["properties"]
    for name in ("particles", "alpha", "sigma_z", "seed", "proposal", "resample"):
        assert ours[name] == theirs[name], name
    cfg = SlamRunIn(method="rbpf", particles=64, seed=3).to_config()
    assert isinstance(cfg, RbpfConfig) and cfg.particles == 64 and cfg.seed == 3
    for body, field in (({"particles": 5000}, "particles"), ({"sigma_z": 0}, "sigma_z"),
                        ({"alpha": -1}, "alpha")):
        r = client.post(f"/worlds/{world}/slam-runs", json=body)
        assert r.status_code == 422 and r.json()["field"] == field, r.text
    r = client.post(f"/worlds/{world}/slam-runs", content=b'{"sigma_z": Infinity}',
                    headers={"content-type": "application/json"})
    assert r.status_code == 422, r.text


def test_a_batch_past_its_budget_keeps_what_it_processed(client: TestClient, world: str) -> None:
    """A batch stops between scans once its time budget is spent: 503 naming how many
    scans were processed; those stay (in memory and in the store, so a restart replays
    the same), the rest are forgotten and can be sent again."""
    r = client.post(f"/worlds/{world}/slam-runs", json={"method": "gated"})
    rid = r.json()["id"]
    base = f"/worlds/{world}/slam-runs/{rid}"
    slam = client.app.state.slam  # type: ignore[attr-defined]
    store = client.app.state.store  # type: ignore[attr-defined]
    budget = slam.budget_s
    slam.budget_s = 1e-9  # only the first scan of a batch fits
    try:
        r = client.post(base + "/scans", json={"scans": [scan_json(i) for i in range(5)]})
    finally:
        slam.budget_s = budget
    assert r.status_code == 503, r.text
    assert r.headers["content-type"] == "application/problem+json"
    assert r.json()["field"] == "scans" and "first 1 of 5" in r.json()["detail"]
    assert client.get(base).json()["scans"] == 1
    assert len(store.scans("slam", rid)) == 1
    r = client.post(base + "/scans", json={"scans": [scan_json(i) for i in range(1, 5)]})
    assert r.status_code == 200 and r.json()["scans"] == 5, r.text
    assert len(store.scans("slam", rid)) == 5


def test_a_cancelled_batch_keeps_store_and_memory_in_step(tmp_path: Any) -> None:
    """A batch whose request is cancelled (the client left, a mission job cancelled)
    stops between scans; the stored scans are exactly the processed ones, and the run
    goes on from there (the filter never ran in two threads at once)."""
    import asyncio

    from chizu.numeric.world import WorldDescription
    from chizu.service.container import open_services
    from chizu.service.schemas.slam import ScanIn, SlamRunIn

    svc = open_services(Settings(data_dir=tmp_path, demo_world=None, workers=0), demo=False)
    log = loop_log()
    items = [ScanIn.model_validate(scan_json(i, log)) for i in range(600)]

    async def go() -> None:
        await svc.worlds.create(WorldDescription(name="w", template="loop"))
        rid = (await svc.slam.create("w", SlamRunIn(method="graph"))).id
        task = asyncio.ensure_future(svc.slam.add_scans("w", rid, items))
        for _ in range(1200):  # cancel once some scans are in (a loaded machine is slow)
            await asyncio.sleep(0.05)
            if svc.slam.runs[rid].scans > 0:
                break
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        n = svc.slam.runs[rid].scans
        assert 0 < n < len(items)
        assert len(svc.store.scans("slam", rid)) == n
        st = await svc.slam.add_scans("w", rid, items[n:n + 5])
        assert st.scans == n + 5 == len(svc.store.scans("slam", rid))

    try:
        asyncio.run(go())
    finally:
        svc.close()
