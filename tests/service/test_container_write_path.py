"""The one write path and the one wiring (service.container): every artifact kind
survives a restart and is what ``chizu repl`` sees; a failed store write leaves the
knowledge base as the store says (also for a world's first artifact); a world rebuilt
after a failed event write keeps its artifacts' facts."""

from __future__ import annotations

import os
import sqlite3
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from chizu.service.app import create_app
from chizu.service.settings import Settings
from tests.eigenspace.test_api import SMALL, wait_job
from tests.slam.test_api import scan_json

ROOT = Path(__file__).resolve().parents[2]
TYPES = [{"name": "A", "value": 50, "mean_count": 1.0}]


def plan_body() -> dict[str, Any]:
    """A walled 4 m x 4 m grid with one unknown square metre and one candidate."""
    cells = np.zeros((40, 40), dtype=int)
    cells[0, :] = cells[-1, :] = cells[:, 0] = cells[:, -1] = 100
    cells[25:35, 25:35] = -1
    return {"robot": [0.5, 0.5, 0], "exit": [0.5, 0.5], "time_limit_s": 60,
            "object_types": TYPES, "min_area_m2": 0.5,
            "grid": {"width": 40, "height": 40, "resolution_m": 0.1, "origin": [0, 0],
                     "data": cells.ravel().tolist()},
            "candidates": [{"id": "c1", "type": "A", "x": 1.5, "y": 2.0}]}


def kinds(facts: list[str]) -> dict[str, int]:
    return {k: sum(f.startswith(k if k.endswith("scene") else k + "(") for f in facts)
            for k in ("eig_triplet", "map_pose", "loop_closure", "committed_map", "vp_group",
                      "vp_plan_step", "unknown_region(scene")}


def make_all_artifacts(c: TestClient, world: str) -> dict[str, int]:
    assert c.post("/worlds", json={"name": world, "template": "room_a"}).status_code == 201
    job = wait_job(c, c.post(f"/worlds/{world}/eigenspace", json=SMALL).headers["location"])
    assert job["status"] == "done", job
    rid = c.post(f"/worlds/{world}/slam-runs", json={"method": "gated"}).json()["id"]
    r = c.post(f"/worlds/{world}/slam-runs/{rid}/scans",
               json={"scans": [scan_json(i) for i in range(120)]})
    assert r.status_code == 200, r.text
    assert c.post(f"/worlds/{world}/slam-runs/{rid}/commit").status_code == 200
    r = c.post(f"/worlds/{world}/viewpoint-plan", json=plan_body())
    assert r.status_code == 200, r.text
    got = kinds(c.get(f"/worlds/{world}/facts").json())
    assert got["eig_triplet"] > 0 and got["map_pose"] > 0 and got["committed_map"] == 1
    assert got["vp_group"] == 2 and got["vp_plan_step"] >= 1  # the object and the region
    assert got["unknown_region(scene"] == 1  # the plan grid's region, beside the map's
    return got


def test_every_artifact_survives_a_restart_and_reaches_the_repl(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path, demo_world="")
    with TestClient(create_app(settings)) as c:
        before = make_all_artifacts(c, "kb")
    with TestClient(create_app(settings)) as c:
        assert kinds(c.get("/worlds/kb/facts").json()) == before
    # the REPL opens the worlds as the app does: the same facts, queried by its helpers
    env = {**os.environ, "CHIZU_DATA_DIR": str(tmp_path), "CHIZU_DEMO_WORLD": ""}
    q = ("aggregate_all(count, triplet_distance(_, 1.0, 1.0, _), NT), "
         "explored_fraction(F), aggregate_all(count, observation_group(_, _, _), NG), "
         "aggregate_all(count, plan_step(_, _, _, _), NS), "
         "format('counts ~w ~w ~w~n', [NT, NG, NS]), F > 0.\nhalt.\n")
    r = subprocess.run([sys.executable, "-m", "chizu.service.cli", "repl", "kb"], input=q,
                       capture_output=True, text=True, timeout=180, env=env, cwd=ROOT)
    assert "world kb loaded" in r.stdout, r.stdout + r.stderr
    assert (f"counts {before['eig_triplet']} {before['vp_group']} {before['vp_plan_step']}"
            in r.stdout), r.stdout + r.stderr


class FailingCommit:
    """A store whose next transaction that writes ``kind`` fails, as a full disk would."""

    def __init__(self, store: Any, kind: str) -> None:
        self.store, self.kind, self.armed = store, kind, True
        self._put = store.put_artifact

    def __enter__(self) -> FailingCommit:
        def put(conn: sqlite3.Connection, world: str, kind: str, blob: bytes) -> None:
            if self.armed and kind == self.kind:
                self.armed = False
                raise sqlite3.OperationalError("database or disk is full")
            self._put(conn, world, kind, blob)

        self.store.put_artifact = put
        return self

    def __exit__(self, *exc: object) -> None:
        self.store.put_artifact = self._put


@pytest.mark.parametrize("first", [True, False], ids=["first-artifact", "replacing"])
def test_a_failed_store_write_leaves_the_stored_facts(tmp_path: Path, first: bool) -> None:
    """The viewpoint scene (grouping asserts it while planning) and the SLAM map: when
    the store write fails, the knowledge base holds what the store holds -- the previous
    artifact, or none at all for a world's first one."""
    settings = Settings(data_dir=tmp_path, demo_world="")
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        assert c.post("/worlds", json={"name": "w", "template": "room_a"}).status_code == 201
        rid = c.post("/worlds/w/slam-runs", json={"method": "gated"}).json()["id"]
        c.post(f"/worlds/w/slam-runs/{rid}/scans",
               json={"scans": [scan_json(i) for i in range(60)]})
        body = plan_body()
        if not first:
            assert c.post(f"/worlds/w/slam-runs/{rid}/commit").status_code == 200
            assert c.post("/worlds/w/viewpoint-plan", json=body).status_code == 200
        stored = kinds(c.get("/worlds/w/facts").json())
        store = c.app.state.services.store  # type: ignore[attr-defined]
        body["candidates"].append({"id": "c2", "type": "A", "x": 2.5, "y": 1.0})
        for kind, call in (("viewpoint_scene", lambda: c.post("/worlds/w/viewpoint-plan",
                                                               json=body)),
                           ("slam_facts", lambda: c.post(f"/worlds/w/slam-runs/{rid}/commit"))):
            with FailingCommit(store, kind):
                assert call().status_code == 500
            assert kinds(c.get("/worlds/w/facts").json()) == stored, kind
        assert stored["committed_map"] == (0 if first else 1)


def test_a_world_rebuilt_after_a_failed_event_keeps_its_artifacts(tmp_path: Path) -> None:
    """A failed event write rebuilds the world from the store (create_world clears all
    of its facts): the committed map's and the scene's facts come back with it."""
    settings = Settings(data_dir=tmp_path, demo_world="")
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        assert c.post("/worlds", json={"name": "w", "template": "demo"}).status_code == 201
        assert c.post("/worlds/w/viewpoint-plan", json=plan_body()).status_code == 200
        stored = kinds(c.get("/worlds/w/facts").json())
        store = c.app.state.services.store  # type: ignore[attr-defined]
        append = store.append_event

        def fail(*a: Any) -> None:
            raise sqlite3.OperationalError("database or disk is full")

        store.append_event = fail
        try:
            r = c.post("/worlds/w/reached", json={"from": "c0", "to": "c1"})
        finally:
            store.append_event = append
        assert r.status_code == 500
        assert kinds(c.get("/worlds/w/facts").json()) == stored and stored["vp_group"] == 2


def test_an_unknown_world_is_a_404_before_the_body_is_decoded(client: TestClient) -> None:
    """WorldDep answers first: a turn of undecodable PNGs, a malformed scan batch, an
    image upload, all to a world that does not exist, are 404s naming the world."""
    for method, url, kw in (
            ("post", "/worlds/nowhere/localize", {"json": {"images_png": ["not png"] * 3}}),
            ("post", "/worlds/nowhere/localize/images",
             {"files": [("images", ("a.png", b"not png", "image/png"))]}),
            ("get", "/worlds/nowhere/eigenspace/covering", {"params": {"x": 0, "y": 0}}),
            ("post", "/worlds/nowhere/viewpoint-plan", {"json": {"robot": [0, 0, 0]}}),
            ("get", "/worlds/nowhere/facts", {})):
        r = getattr(client, method)(url, **kw)
        assert r.status_code == 404, (url, r.text)
        assert r.json()["field"] == "world" and r.headers["content-type"].startswith(
            "application/problem+json")


def test_one_unknown_region_threshold_per_world(client: TestClient) -> None:
    """unknown_region_min_area_m2 (params.pl) decides which unknown regions a plan
    groups when the request names no threshold, and the committed map's regions; a
    world stored with its old name, vp_unknown_min_area_m2, keeps it."""
    body = plan_body()
    del body["min_area_m2"]
    for name, params, regions in (("thr_default", {}, 1),
                                  ("thr_big", {"unknown_region_min_area_m2": 2.0}, 0),
                                  ("thr_old", {"vp_unknown_min_area_m2": 2.0}, 0)):
        r = client.post("/worlds", json={"name": name, "template": "room_a",
                                         "parameters": params})
        assert r.status_code == 201, r.text
        out = client.post(f"/worlds/{name}/viewpoint-plan", json=body).json()
        assert sum(g["kind"] == "unknown" for g in out["groups"]) == regions, name
        scene = client.get(f"/worlds/{name}/viewpoint-groups").json()
        assert scene["min_area_m2"] == (0.5 if not params else 2.0)
