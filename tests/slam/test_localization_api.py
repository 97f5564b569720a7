"""Localization runs over REST on a world's committed map, and saved maps uploaded into a
world: a robot streams scans from an unknown start and is found, the run survives a
restart, and bad input (no map, another laser, a corrupt or foreign map) is a problem
naming the field with nothing changed."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from chizu.numeric.geometry import compose
from chizu.numeric.scan import LaserLog
from chizu.numeric.slam import saved_map as sm
from chizu.numeric.slam.runner import SlamOptions, run_log
from chizu.numeric.slam.simulate import drive, simulated_log
from chizu.numeric.world import World
from chizu.numeric.worlds import room_a
from chizu.service.app import create_app
from chizu.service.settings import Settings
from tests.service.test_worlds import assert_problem
from tests.slam.drives import MODERATE_ODOMETRY, ROOM_A_TOUR
from tests.slam.test_api import scan_json

#: where the second robot's odometry starts, unknown to the method
HIDDEN = np.array([3.0, -2.0, 2.0])


@pytest.fixture(scope="module")
def map_file() -> bytes:
    """room_a mapped by graph SLAM from the built-in tour, as ``chizu slam --out``
    saves it."""
    log = simulated_log("room_a", speed_m_s=1.0)
    slam, _ = run_log(log, SlamOptions(method="graph"))
    return sm.to_bytes(sm.saved_map_of_log(slam, log, "graph", 0.05))


@pytest.fixture(scope="module")
def robot() -> LaserLog:
    """The tour driven the other way round, its odometry in a frame of its own."""
    b = drive(World(room_a()), ROOM_A_TOUR[::-1].copy(), MODERATE_ODOMETRY, None, 0.5,
              np.random.default_rng(3), "reverse")
    return LaserLog(b.name, [dataclasses.replace(s, odom=compose(HIDDEN, s.odom))
                             for s in b.scans], b.truth)


@pytest.fixture(scope="module")
def settings(tmp_path_factory: pytest.TempPathFactory) -> Settings:
    return Settings(data_dir=tmp_path_factory.mktemp("localization"), demo_world="",
                    request_budget_s=600.0)


@pytest.fixture(scope="module")
def c(settings: Settings, map_file: bytes) -> Iterator[TestClient]:
    with TestClient(create_app(settings)) as client:
        assert client.post("/worlds", json={"name": "loc", "template": "room_a"}
                           ).status_code == 201
        r = client.put("/worlds/loc/map.chizu", content=map_file,
                       headers={"content-type": "application/octet-stream"})
        assert r.status_code == 200, r.text
        yield client


def post_scans(c: TestClient, rid: str, log: LaserLog, lo: int, hi: int) -> dict[str, Any]:
    body: dict[str, Any] = {}
    for k in range(lo, hi, 250):
        r = c.post(f"/worlds/loc/localization-runs/{rid}/scans",
                   json={"scans": [scan_json(i, log) for i in range(k, min(k + 250, hi))]})
        assert r.status_code == 200, r.text
        body = r.json()
    return body


def test_an_uploaded_map_is_the_worlds_map(c: TestClient, map_file: bytes) -> None:
    m = c.get("/worlds/loc/map").json()
    assert m["run"].startswith("r") and m["free_m2"] > 50  # room_a: 10 m x 10 m
    assert c.get("/worlds/loc/map.chizu").content == map_file
    facts = c.get("/worlds/loc/facts").json()
    assert any(f.startswith("map_pose(") for f in facts)


def test_a_robot_streams_scans_and_is_found(c: TestClient, robot: LaserLog,
                                            settings: Settings) -> None:
    r = c.post("/worlds/loc/localization-runs", json={})
    assert r.status_code == 201, r.text
    rid = r.json()["id"]
    assert r.headers["location"] == f"/worlds/loc/localization-runs/{rid}"
    assert r.json()["state"] == "searching" and r.json()["pose"] is None
    st = post_scans(c, rid, robot, 0, len(robot.scans))
    assert st["state"] == "tracking" and st["scans"] == len(robot.scans)
    assert st["first_fix_s"] is not None and st["first_fix_s"] < 5.0
    assert len(st["fixes"]) == 1 and st["losses"] == []
    truth = robot.truth[-1]
    assert np.hypot(st["pose"]["x"] - truth[0], st["pose"]["y"] - truth[1]) < 0.2
    tr = c.get(f"/worlds/loc/localization-runs/{rid}/trajectory").json()
    ok = [i for i, p in enumerate(tr["poses"]) if p is not None]
    assert len(tr["t"]) == len(robot.scans) and len(ok) > 0.9 * len(robot.scans)
    e = np.hypot(*(np.array([tr["poses"][i][:2] for i in ok]) - robot.truth[ok, :2]).T)
    assert np.median(e) < 0.08
    tum = c.get(f"/worlds/loc/localization-runs/{rid}/trajectory",
                params={"format": "tum"}).text.strip().splitlines()
    assert len(tum) == len(ok)
    listed = c.get("/worlds/loc/localization-runs").json()
    assert {"id": rid, "map": st["map"], "scans": len(robot.scans)} in listed


def test_a_run_survives_a_restart_on_its_own_map(settings: Settings, map_file: bytes,
                                                 robot: LaserLog) -> None:
    """Replayed from its stored scans, a run ends where it was; once the world's map is
    another, a stored run cannot be replayed on it (409, map)."""
    with TestClient(create_app(settings)) as c:
        c.post("/worlds", json={"name": "loc2", "template": "room_a"})
        assert c.put("/worlds/loc2/map.chizu", content=map_file).status_code == 200
        rid = c.post("/worlds/loc2/localization-runs").json()["id"]
        before = c.post(f"/worlds/loc2/localization-runs/{rid}/scans",
                        json={"scans": [scan_json(i, robot) for i in range(120)]}).json()
        assert before["state"] == "tracking"
    with TestClient(create_app(settings)) as c:
        assert c.get(f"/worlds/loc2/localization-runs/{rid}").json() == before
        # another map for the world: a fresh SLAM run's commit
        other = c.post("/worlds/loc2/slam-runs", json={"method": "icp"}).json()["id"]
        c.post(f"/worlds/loc2/slam-runs/{other}/scans",
               json={"scans": [scan_json(i, robot) for i in range(40)]})
        assert c.post(f"/worlds/loc2/slam-runs/{other}/commit").status_code == 200
    with TestClient(create_app(settings)) as c:
        assert_problem(c.get(f"/worlds/loc2/localization-runs/{rid}"), 409, "map")
        assert c.post("/worlds/loc2/localization-runs").status_code == 201  # a new one


def test_bad_localization_input(c: TestClient, robot: LaserLog) -> None:
    c.post("/worlds", json={"name": "nomap", "template": "room_a"})
    assert_problem(c.post("/worlds/nomap/localization-runs"), 409, "map")
    assert_problem(c.post("/worlds/nosuch/localization-runs"), 404)
    assert_problem(c.post("/worlds/loc/localization-runs", json={"seed": 1}), 422, "seed")
    rid = c.post("/worlds/loc/localization-runs").json()["id"]
    url = f"/worlds/loc/localization-runs/{rid}/scans"
    other = scan_json(1, robot)
    other["angle_increment"] *= 2  # a laser of half the resolution: not the map's
    assert_problem(c.post(url, json={"scans": [scan_json(0, robot), other]}), 422, "scans[1]")
    assert_problem(c.post(url, json={"scans": []}), 422, "scans")
    raw = '{"scans": [{"t": NaN, "ranges": [1.0], "angle_min": 0, "angle_increment": 0.1, ' \
          '"odom": [0, 0, 0]}]}'
    assert_problem(c.post(url, content=raw, headers={"content-type": "application/json"}),
                   422, "scans[0].t")
    bad = scan_json(0, robot)
    bad["ranges"] = bad["ranges"][:-1]
    assert_problem(c.post(url, json={"scans": [bad]}), 422, "scans[0]")
    # nothing was taken in
    assert c.get(f"/worlds/loc/localization-runs/{rid}").json()["scans"] == 0
    assert c.post(url, json={"scans": [scan_json(1, robot)]}).json()["scans"] == 1
    assert_problem(c.post(url, json={"scans": [scan_json(0, robot)]}), 422, "scans[0].t")
    assert_problem(c.get("/worlds/loc/localization-runs/l0123"), 404, "run")
    assert_problem(c.get("/worlds/loc/localization-runs/r0123"), 422)
    assert c.delete(f"/worlds/loc/localization-runs/{rid}").status_code == 204
    assert_problem(c.get(f"/worlds/loc/localization-runs/{rid}"), 404, "run")


def test_a_bad_map_upload_changes_nothing(c: TestClient, map_file: bytes,
                                          tmp_path: Path) -> None:
    before = c.get("/worlds/loc/map.chizu").content
    facts = c.get("/worlds/loc/facts").json()
    c.post("/worlds", json={"name": "elsewhere", "template": "room_a"})
    assert c.put("/worlds/elsewhere/map.chizu", content=map_file).status_code == 200
    rid = c.post("/worlds/elsewhere/slam-runs", json={"method": "icp"}).json()["id"]
    c.post(f"/worlds/elsewhere/slam-runs/{rid}/scans",
           json={"scans": [scan_json(i) for i in range(30)]})
    c.post(f"/worlds/elsewhere/slam-runs/{rid}/commit")
    foreign = c.get("/worlds/elsewhere/map.chizu").content  # saved in world "elsewhere"
    for body in (b"", b"not a zip", map_file[: len(map_file) // 2], foreign):
        assert_problem(c.put("/worlds/loc/map.chizu", content=body), 422, "map")
    assert_problem(c.put("/worlds/nosuch/map.chizu", content=map_file), 404)
    assert c.get("/worlds/loc/map.chizu").content == before
    assert c.get("/worlds/loc/facts").json() == facts


def test_a_run_resumes_the_worlds_map(c: TestClient, map_file: bytes,
                                      robot: LaserLog) -> None:
    """``{"resume": true}``: at the commit the run is found in the world's map and joined
    to it; the world's map holds both runs, the run's trajectory is in the map's frame."""
    c.post("/worlds", json={"name": "resumed", "template": "room_a"})
    assert c.put("/worlds/resumed/map.chizu", content=map_file).status_code == 200
    before = sm.from_bytes(c.get("/worlds/resumed/map.chizu").content)
    r = c.post("/worlds/resumed/slam-runs", json={"method": "graph", "resume": True})
    assert r.status_code == 201 and r.json()["options"]["resume"] is True
    rid = r.json()["id"]
    for k in range(0, len(robot.scans), 250):
        assert c.post(f"/worlds/resumed/slam-runs/{rid}/scans", json={"scans": [
            scan_json(i, robot) for i in range(k, min(k + 250, len(robot.scans)))]}
        ).status_code == 200
    assert c.post(f"/worlds/resumed/slam-runs/{rid}/commit").status_code == 200
    after = sm.from_bytes(c.get("/worlds/resumed/map.chizu").content)
    assert len(after) > len(before) and len(after.times) == len(before.times) + len(robot)
    assert after.meta["runs"] == [before.meta["source"], f"SLAM run {rid}"]
    # joined once: a second commit would put the run in the map twice
    raw = c.get("/worlds/resumed/map.chizu").content
    assert_problem(c.post(f"/worlds/resumed/slam-runs/{rid}/commit"), 409, "run")
    assert c.get("/worlds/resumed/map.chizu").content == raw
    tr = c.get(f"/worlds/resumed/slam-runs/{rid}/trajectory").json()
    e = np.hypot(*(np.array(tr["poses"])[:, :2] - robot.truth[:, :2]).T)
    assert np.median(e) < 0.08  # in the map's (here the world's) frame
    # bad input: resume needs graph SLAM, and a map to resume
    assert_problem(c.post("/worlds/resumed/slam-runs", json={"method": "icp", "resume": True}),
                   422, "resume")
    # in a world without a map, the first run to commit founds it
    c.post("/worlds", json={"name": "bare", "template": "room_a"})
    r = c.post("/worlds/bare/slam-runs", json={"resume": True})
    assert r.status_code == 201
    first = r.json()["id"]
    c.post(f"/worlds/bare/slam-runs/{first}/scans",
           json={"scans": [scan_json(i, robot) for i in range(60)]})
    assert c.post(f"/worlds/bare/slam-runs/{first}/commit").status_code == 200
    assert sm.from_bytes(c.get("/worlds/bare/map.chizu").content).meta["source"] == \
        f"SLAM run {first}"
