"""POST /worlds/{world}/viewpoint-plan: the paper's decisions through the API, the
Prolog groups behind them, bad input as problem responses, persistence; the online loop
and the CLI."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from chizu.numeric.viewpoint.online import Summariser, SummaryConfig
from chizu.numeric.viewpoint.planner import ObjectType
from chizu.numeric.world import World
from chizu.numeric.worlds import SUMMARY_DOOR, random_summary_room, summary_room
from chizu.service.app import create_app
from chizu.service.settings import Settings
from chizu.service.viewpoint import local_grouper

ROOT = Path(__file__).resolve().parents[2]
DOOR = list(SUMMARY_DOOR)
TYPES = [{"name": "A", "value": 50, "mean_count": 1.0},
         {"name": "B", "value": 100, "mean_count": 0.5},
         {"name": "C", "value": 80, "mean_count": 0.5}]


def table1_body(loss: str) -> dict[str, Any]:
    """Table 1: k_lim 0.5, v 0.4 m/s, t_limit 30 s; a near object A (value 50) and a far
    object B (value 100); no unknown region (threshold above the room's area)."""
    return {"robot": [*DOOR, 1.57], "exit": DOOR, "time_limit_s": 30, "loss": loss,
            "k_lim": 0.5, "speed_m_s": 0.4, "t_verify_s": 10.0, "min_area_m2": 100,
            "object_types": TYPES[:2],
            "candidates": [{"id": "a_near", "type": "A", "x": 5.6, "y": 1.5},
                           {"id": "b_far", "type": "B", "x": 1.0, "y": 4.9}]}


@pytest.fixture(scope="module")
def rooms(client: TestClient) -> TestClient:
    for name, template in (("vp_a", "fig11a"), ("vp_b", "fig11b"), ("vp_s", "summary_room")):
        r = client.post("/worlds", json={"name": name, "template": template})
        assert r.status_code == 201, r.text
    return client


@pytest.mark.parametrize(("loss", "plan"), [("L1", ["G_A"]), ("L2", ["G_B"]),
                                            ("L3", ["G_A", "G_B"])])
def test_table1_decisions(rooms: TestClient, loss: str, plan: list[str]) -> None:
    r = rooms.post("/worlds/vp_a/viewpoint-plan", json=table1_body(loss))
    assert r.status_code == 200, r.text
    out = r.json()
    assert [g["members"] for g in out["groups"]] == [["a_near"], ["b_far"]]
    assert sorted(out["plan"]["groups"]) == plan
    t = {tuple(p["groups"]): p for p in [out["plan"], *out["runner_ups"]]}
    if loss == "L2":  # eq. 13 on the planner's own times
        for p in t.values():
            over = max(p["expected_time_s"] - 30, 0)
            assert p["loss"] == pytest.approx(0.5 * over**2)
    if loss == "L1":
        assert all(p["loss"] is None for p in t.values() if p["expected_time_s"] >= 30)


def test_plan_structure_and_prolog_groups(rooms: TestClient) -> None:
    body = {"robot": [*DOOR, 1.57], "exit": DOOR, "time_limit_s": 40, "loss": "L2",
            "object_types": TYPES, "min_area_m2": 1.5,
            "candidates": [{"id": f"obj{i}", "type": o.type, "x": o.x, "y": o.y}
                           for i, o in enumerate(World(summary_room("x", "fig11b"))
                                                 .description.objects, 1)]}
    out = rooms.post("/worlds/vp_b/viewpoint-plan", json=body).json()
    kinds = [g["kind"] for g in out["groups"]]
    assert kinds.count("objects") == 3 and kinds.count("unknown") == 2
    assert ["obj1", "obj2"] in [g["members"] for g in out["groups"]]
    utilities = [p["utility"] for p in [out["plan"], *out["runner_ups"]]]
    assert utilities == sorted(utilities, reverse=True)
    assert out["grid"]["source"] == "simulated"
    # the groups are Prolog facts of the world: the endpoint and the sandboxed query
    groups = rooms.get("/worlds/vp_b/viewpoint-groups").json()["groups"]
    assert [g["members"] for g in groups] == [g["members"] for g in out["groups"]]
    # a plan a robot can execute: per group the pose to go to, the way there, the time
    steps = out["plan"]["steps"]
    assert [st["group_id"] for st in steps] == out["plan"]["group_ids"]
    at = np.array(DOOR)
    for st in steps:
        xy = np.array(st["pose"][:2])
        assert st["travel_m"] >= np.hypot(*(xy - at)) - 1e-6  # never shorter than a line
        assert st["travel_s"] == pytest.approx(st["travel_m"] / 0.4)
        assert (st["p_recog"] is None) == (st["kind"] == "unknown")
        assert st["p_recog"] is None or 0.0 < st["p_recog"] <= 1.0
        at = xy
    assert [st["done_at_s"] for st in steps] == sorted(st["done_at_s"] for st in steps)
    # the same steps are Prolog facts of the world: the REPL and /query walk the plan
    q = rooms.post("/worlds/vp_b/query", json={"goal": "plan_step(K, G, P, T)"})
    assert q.status_code == 200, q.text
    sols = sorted(q.json()["solutions"], key=lambda s: s["K"])
    assert [s["G"] for s in sols] == out["plan"]["group_ids"]
    assert rooms.get("/worlds/vp_b/viewpoint-groups").json()["steps"][0]["pose"] == \
        pytest.approx(steps[0]["pose"])
    # the plan's group ids are the facts' ids, in the plan's order
    by_id = {g["id"]: g["members"] for g in groups}
    by_name = {g["name"]: g["members"] for g in out["groups"]}
    assert [by_id[i] for i in out["plan"]["group_ids"]] == [
        by_name[n] for n in out["plan"]["groups"]]
    q = rooms.post("/worlds/vp_b/query", json={"goal": "same_group(obj1, X)"})
    assert q.status_code == 200, q.text
    assert sorted(s["X"] for s in q.json()["solutions"]) == ["obj1", "obj2"]
    # the exhaustive reference agrees
    ex = rooms.post("/worlds/vp_b/viewpoint-plan", json={**body, "solver": "exhaustive"})
    assert ex.json()["plan"]["utility"] == pytest.approx(out["plan"]["utility"])
    # and so does branch and bound, which proves it
    # (a budget no loaded machine runs out of: this asks for the proof, not the speed)
    bb = rooms.post("/worlds/vp_b/viewpoint-plan",
                    json={**body, "solver": "bnb", "time_budget_s": 60}).json()
    assert bb["plan"]["utility"] == pytest.approx(out["plan"]["utility"])
    assert bb["optimality"]["optimal"] and bb["optimality"]["gap"] == pytest.approx(0.0)
    assert out["optimality"]["optimal"] and not out["optimality"]["returned_early"]


def _grid_body(data: list[int], w: int = 40, h: int = 40) -> dict[str, Any]:
    return {"width": w, "height": h, "resolution_m": 0.1, "origin": [0, 0], "data": data}


def test_posted_grid_gives_an_unknown_region(rooms: TestClient) -> None:
    cells = np.zeros((40, 40), dtype=int)            # [y, x] rows
    cells[0, :] = cells[-1, :] = cells[:, 0] = cells[:, -1] = 100
    cells[25:35, 25:35] = -1                          # 1 m2 unknown in the corner
    body = {"robot": [0.5, 0.5, 0], "exit": [0.5, 0.5], "time_limit_s": 60,
            "object_types": TYPES, "min_area_m2": 0.5, "grid": _grid_body(cells.ravel().tolist()),
            "candidates": [{"id": "c1", "type": "A", "x": 1.5, "y": 2.0}]}
    out = rooms.post("/worlds/demo/viewpoint-plan", json=body).json()
    unk = [g for g in out["groups"] if g["kind"] == "unknown"]
    assert len(unk) == 1 and unk[0]["area_m2"] == pytest.approx(1.0)
    assert unk[0]["centroid"] == pytest.approx([3.0, 3.0])
    assert out["grid"]["source"] == "posted"


def test_a_twelve_object_cluster_plans_with_a_bound(rooms: TestClient) -> None:
    """One group of 12 objects (before: no answer in 300 s): planned, its time flagged as
    a bound (a followable policy's), every member in the order."""
    cells = np.zeros((100, 100), dtype=int)           # 10 m x 10 m at 10 cm
    cells[0, :] = cells[-1, :] = cells[:, 0] = cells[:, -1] = 100
    xy = [(4.0 + 0.7 * (i % 4), 4.0 + 0.7 * (i // 4)) for i in range(12)]
    body = {"robot": [0.5, 0.5, 0], "exit": [0.5, 0.5], "time_limit_s": 300,
            "object_types": TYPES, "grid": _grid_body(cells.ravel().tolist(), 100, 100),
            "candidates": [{"id": f"o{i}", "type": "A", "x": x, "y": y}
                           for i, (x, y) in enumerate(xy)]}
    r = rooms.post("/worlds/demo/viewpoint-plan", json=body)
    assert r.status_code == 200, r.text
    (g,) = [g for g in r.json()["groups"] if g["kind"] == "objects"]
    assert len(g["members"]) == 12 and g["exact"] is False
    assert sorted(g["order"]) == sorted(f"o{i}" for i in range(12)) or g["strategy"] == "par"
    assert g["t_obs_s"] > 12 * 2.0                      # at least the 12 verifications


def test_unreachable_places_are_unverifiable_not_errors(rooms: TestClient) -> None:
    """An unknown block walled in on a posted grid: a valid plan that lists what cannot
    be reached (was a 500). A robot off the map altogether is refused, naming it."""
    out = rooms.post("/worlds/vp_a/viewpoint-plan", json={
        **table1_body("L2"), "robot": [100, 100, 0], "exit": [0, 0]})
    assert out.status_code == 422 and out.json()["field"] == "robot", out.text
    cells = [100] * 4 + [100, -1, -1, 100] * 2 + [100] * 4
    out = rooms.post("/worlds/vp_a/viewpoint-plan", json={
        **table1_body("L2"), "robot": [0.75, 0.75, 0], "exit": [0.75, 0.75],
        "min_area_m2": 0.1, "grid": {"width": 4, "height": 4, "resolution_m": 0.5,
                                     "data": cells}})
    assert out.status_code == 200, out.text
    assert {"kind": "unknown", "reason": "no entry point"}.items() <= next(
        u for u in out.json()["unverifiable"] if u["kind"] == "unknown").items()


def test_awkward_scenes_get_a_plan_or_a_named_4xx(rooms: TestClient) -> None:
    """Awkward scenes: two objects on one spot, an object outside the room, and a grid
    of ~10 000 one-cell unknown holes each get a valid plan (or a 4xx naming the
    field), never a 500 or a hang."""
    on_one_spot = {**table1_body("L2"), "candidates": [
        {"id": "a1", "type": "A", "x": 2.0, "y": 2.0}, {"id": "a2", "type": "A", "x": 2.0,
                                                         "y": 2.0}]}
    outside = {**table1_body("L2"), "candidates": [
        {"id": "far", "type": "A", "x": 80.0, "y": -40.0}]}
    holes = np.zeros((200, 200), dtype=int)           # 20 m x 20 m at 0.1 m
    holes[1:-1:2, 1:-1:2] = -1                         # 9 801 enclosed one-cell holes
    holes[0, :] = holes[-1, :] = holes[:, 0] = holes[:, -1] = 100
    many = {**table1_body("L2"), "robot": [1.05, 1.05, 0], "exit": [1.05, 1.05],
            "min_area_m2": 0.0, "grid": _grid_body(holes.ravel().tolist(), 200, 200)}
    for body in (on_one_spot, outside, many):
        out = rooms.post("/worlds/vp_a/viewpoint-plan", json=body)
        assert out.status_code == 200 or (400 <= out.status_code < 500
                                          and out.json().get("field")), out.text
        assert out.status_code == 200, out.text       # all three are plannable
    assert rooms.get("/health").status_code == 200


def test_a_boxed_in_object_does_not_sink_its_group(rooms: TestClient) -> None:
    """Two objects close enough to form one group, one walled in so that no viewpoint
    sees it: that one is unverifiable, the other is still planned."""
    cells = np.zeros((80, 80), dtype=int)             # 8 m x 8 m at 0.1 m, [y, x]
    cells[0, :] = cells[-1, :] = cells[:, 0] = cells[:, -1] = 100
    yy, xx = np.mgrid[0:80, 0:80]
    ring = np.abs(np.hypot(xx - 30, yy - 30) - 4) < 1   # a ring of 0.4 m round (3, 3)
    cells[ring] = 100
    body = {"robot": [6.5, 6.5, 0], "exit": [6.5, 6.5], "time_limit_s": 120, "loss": "L3",
            "object_types": TYPES, "grid": _grid_body(cells.ravel().tolist(), 80, 80),
            "candidates": [{"id": "boxed", "type": "A", "x": 3.0, "y": 3.0},
                           {"id": "free", "type": "A", "x": 5.0, "y": 3.0}]}
    out = rooms.post("/worlds/demo/viewpoint-plan", json=body)
    assert out.status_code == 200, out.text
    planned = [g for g in out.json()["groups"] if g["kind"] == "objects"]
    assert [g["members"] for g in planned] == [["free"]]
    lost = [u for u in out.json()["unverifiable"] if u["kind"] == "objects"]
    assert [u["members"] for u in lost] == [["boxed"]]
    assert planned[0]["name"] in out.json()["plan"]["groups"]


def test_an_infeasible_plan_says_so(rooms: TestClient) -> None:
    """L1 with the exit out of reach in time: the best plan is to leave, and it says it
    is infeasible and why, instead of bare nulls."""
    body = {**table1_body("L1"), "time_limit_s": 1.0, "robot": [5.5, 4.5, 0]}
    out = rooms.post("/worlds/vp_a/viewpoint-plan", json=body).json()
    plan = out["plan"]
    assert plan["status"] == "infeasible" and not plan["feasible"]
    assert plan["utility"] is None and "time limit of 1 s" in plan["reason"]
    ok = rooms.post("/worlds/vp_a/viewpoint-plan", json=table1_body("L1")).json()["plan"]
    assert ok["status"] == "feasible" and ok["reason"] is None


def test_empty_candidates_and_no_time_means_leave(rooms: TestClient) -> None:
    body = {**table1_body("L1"), "time_limit_s": 0}
    out = rooms.post("/worlds/vp_a/viewpoint-plan", json=body).json()
    assert out["leave_now"] and out["plan"]["groups"] == []
    body = {**table1_body("L3"), "candidates": []}
    assert rooms.post("/worlds/vp_a/viewpoint-plan", json=body).json()["plan"]["groups"] == []


@pytest.mark.parametrize(("patch", "status", "field"), [
    ({"loss": "L4"}, 422, "loss"),
    ({"time_limit_s": -1}, 422, "time_limit_s"),
    ({"k_lim": -0.5}, 422, "k_lim"),
    ({"time_budget_s": 0}, 422, "time_budget_s"),
    ({"grid": {"width": 2, "height": 1, "resolution_m": 0.5,
               "data": [0, 100000000000000000000]}}, 422, "grid.data"),
    ({"object_types": [{"name": "A", "appearance": {"a": [100, 100, 100, 100],
                                                    "b": [0, 0, 0, 0], "k": 5,
                                                    "theta_half": 0.8}}]},
     422, "object_types[0].appearance.b[0]"),
    ({"object_types": [{"name": "A", "appearance": {"a": [100, 100, 100, 100],
                                                    "b": [1e-9, 1, 1, 1], "k": 5,
                                                    "theta_half": 0.8}}]},
     422, "object_types[0].appearance"),
    ({"object_types": [{"name": "A", "tables": {
        "distance": [{"face": f, "d_m": d, "matches": 40} for f in range(4) for d in (1, 2)],
        "angle": [{"theta_rad": t, "ratio": r} for t, r in ((0, 1), (0.8, 0.5), (1.2, 0.1))]}}]},
     422, "object_types[0].tables.distance"),
    ({"solver": "greedy"}, 422, "solver"),
    ({"speed_m_s": 0}, 422, "speed_m_s"),
    ({"robot": [1, 2]}, 422, "robot[2]"),
    ({"exit": ["x", 0]}, 422, "exit[0]"),
    ({"candidates": [{"id": "c1", "type": "A", "x": "NaN", "y": 1}]}, 422, "candidates[0].x"),
    ({"candidates": [{"id": "c1", "type": "A", "x": 1e400, "y": 1}]}, 422, "candidates[0].x"),
    ({"candidates": [{"id": "Bad id", "type": "A", "x": 1, "y": 1}]}, 422, "candidates[0].id"),
    ({"candidates": [{"id": "c1", "type": "Z", "x": 1, "y": 1}]}, 422, "candidates[0].type"),
    ({"candidates": [{"id": "c1", "type": "A", "x": 1, "y": 1}] * 2}, 422, None),
    ({"candidates": [{"id": f"c{i}", "type": "A", "x": 1, "y": 1} for i in range(201)]},
     422, "candidates"),
    ({"candidates": [{"id": "c1", "type": "A", "x": 1, "y": 1, "belief": [1, 0]}]},
     422, "candidates[0].belief"),
    ({"object_types": [{"name": "mug", "value": 1}],
      "candidates": [{"id": "c1", "type": "mug", "x": 1, "y": 1}]}, 422, "object_types[0]"),
    ({"object_types": [{"name": "A", "value": -1}]}, 422, "object_types[0].value"),
    ({"grid": _grid_body([0] * 10)}, 422, "grid.data"),
    ({"grid": _grid_body([7] * 1599 + [101])}, 422, "grid.data"),
    ({"grid": {**_grid_body([0] * 1600), "resolution_m": float("inf")}}, 422,
     "grid.resolution_m"),
    ({"grid": _grid_body([], 0, 0)}, 422, "grid.width"),
    ({"unknown": 1}, 422, "unknown"),
])
def test_bad_input_is_a_problem_response(rooms: TestClient, patch: dict[str, Any], status: int,
                                         field: str | None) -> None:
    before = rooms.get("/worlds/vp_a/viewpoint-groups").json()
    body = json.dumps({**table1_body("L2"), **patch}, allow_nan=True).replace(
        "Infinity", "1e999")
    r = rooms.post("/worlds/vp_a/viewpoint-plan", content=body,
                   headers={"content-type": "application/json"})
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith("application/problem+json")
    if field is not None:  # grid.data's item is named: grid.data[1599]
        got = r.json()["field"]
        assert got == field or (field == "grid.data" and got.startswith("grid.data[")), got
    assert rooms.get("/worlds/vp_a/viewpoint-groups").json() == before


def test_exhaustive_limit_and_unknown_world(rooms: TestClient) -> None:
    body = {**table1_body("L2"), "solver": "exhaustive",
            "candidates": [{"id": f"c{i}", "type": "A", "x": 0.6 + 0.6 * (i % 10),
                            "y": 1.0 + 3.5 * (i // 10)} for i in range(20)],
            "min_area_m2": 100}
    r = rooms.post("/worlds/vp_a/viewpoint-plan", json=body)
    # 20 candidates 0.6 m apart join into few groups: allowed, or refused naming solver
    assert r.status_code == 200 or r.json()["field"] == "solver"
    r = rooms.post("/worlds/nowhere/viewpoint-plan", json=table1_body("L2"))
    assert r.status_code == 404
    assert rooms.get("/worlds/nowhere/viewpoint-groups").status_code == 404


def test_huge_payload_is_413(rooms: TestClient) -> None:
    body = {**table1_body("L2"), "grid": _grid_body([0] * 4_400_000, 2200, 2000)}
    r = rooms.post("/worlds/vp_a/viewpoint-plan", json=body)
    assert r.status_code == 413


def test_scene_survives_a_restart(tmp_path: Path) -> None:
    s = Settings(data_dir=tmp_path, demo_world="")
    with TestClient(create_app(s)) as c:
        assert c.post("/worlds", json={"name": "room", "template": "fig11a"}).status_code == 201
        assert c.post("/worlds/room/viewpoint-plan", json=table1_body("L3")).status_code == 200
        groups = c.get("/worlds/room/viewpoint-groups").json()
    with TestClient(create_app(s)) as c:
        assert c.get("/worlds/room/viewpoint-groups").json() == groups
        assert len(groups["groups"]) == 2


# -- the online loop (§7.3) and the CLI -------------------------------------------------
@pytest.fixture(scope="module")
def grouper() -> Iterator[Any]:
    g, kb = local_grouper(ROOT / "prolog")
    yield g
    kb.close()


def test_l1_monitor_keeps_the_hard_limit_when_a_group_takes_longer_than_expected(
        grouper: Any) -> None:
    """Random room 2: the plan's one group of three was expected to end at 37 s of 40;
    its looks took longer (travel around the cabinets inside the group) and the robot
    reached the door at 42 s. The monitor skips the last look instead."""
    w = World(random_summary_room(2))
    types = [ObjectType.model_validate(t) for t in TYPES]
    run = Summariser(w, types, grouper, SummaryConfig(time_limit_s=40, loss="L1"),
                     np.array(SUMMARY_DOOR)).run()
    assert run.elapsed_s <= 40
    skipped = [e.detail["candidate"] for e in run.log if e.action == "skip"]
    assert skipped and all(c in run.unverified for c in skipped)
    assert run.verified                      # what fitted was still done
    # L2 prices the overrun instead: no monitor, no skips
    run2 = Summariser(w, types, grouper, SummaryConfig(time_limit_s=40, loss="L2"),
                      np.array(SUMMARY_DOOR)).run()
    assert not any(e.action == "skip" for e in run2.log)


def test_online_summary_verifies_both_objects(grouper: Any) -> None:
    w = World(summary_room())
    types = [ObjectType.model_validate(t) for t in TYPES]
    run = Summariser(w, types, grouper, SummaryConfig(time_limit_s=55, loss="L2"),
                     np.array(SUMMARY_DOOR)).run()
    s = run.summary(w)
    # L2 punishes the overrun: the near kettle first, the false candidate rejected, and
    # the far mug left out once time runs short (on a map whose walls are not painted
    # free the mug does not fit; L1 below verifies both)
    assert "kettle" in s["verified"]
    assert s["rejected"] == ["false1"]           # the false candidate is never recognised
    assert run.elapsed_s < 55 + 10
    assert s["explored_fraction"] > 0.8
    assert run.log[-1].action == "leave" and run.plans[-1] == []
    # L1 is a hard limit: with travel along shortest paths the plan keeps it (straight
    # lines had promised the mug too and overran to 58 s); with 70 s both fit
    run1 = Summariser(w, types, grouper, SummaryConfig(time_limit_s=55, loss="L1"),
                      np.array(SUMMARY_DOOR)).run()
    assert run1.summary(w)["verified"] == ["kettle"] and run1.elapsed_s <= 55
    run2 = Summariser(w, types, grouper, SummaryConfig(time_limit_s=70, loss="L1"),
                      np.array(SUMMARY_DOOR)).run()
    assert run2.summary(w)["verified"] == ["kettle", "mug"] and run2.elapsed_s <= 70
    # with no time at all under L1 the robot leaves at once
    run0 = Summariser(w, types, grouper, SummaryConfig(time_limit_s=0, loss="L1"),
                      np.array(SUMMARY_DOOR)).run()
    assert run0.verified == {} and run0.plans == [[]]


def test_cli_plan_and_summarise(tmp_path: Path) -> None:
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps(table1_body("L2")))
    env_cmd = [sys.executable, "-m", "chizu.service.cli"]
    r = subprocess.run([*env_cmd, "plan", str(scene), "--world", "fig11a",
                        "--png", str(tmp_path / "plan.png")],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert '"groups": [\n      "G_B"\n    ]' in r.stdout or '"G_B"' in r.stdout
    assert (tmp_path / "plan.png").read_bytes()[:4] == b"\x89PNG"
    r = subprocess.run([*env_cmd, "summarise", "summary_room", "--time-limit", "70",
                        "--loss", "L1",
                        "--out", str(tmp_path / "run")],
                       cwd=ROOT, capture_output=True, text=True, timeout=300,
                       env={"CHIZU_DATA_DIR": str(tmp_path / "data"), "PATH": "/usr/bin:/bin",
                            "HOME": str(tmp_path)})
    assert r.returncode == 0, r.stdout + r.stderr
    log = json.loads((tmp_path / "run" / "run.json").read_text())
    assert log["summary"]["objects_verified"] == 2
    assert (tmp_path / "run" / "run.png").exists()
    bad = subprocess.run([*env_cmd, "plan", str(tmp_path / "missing.json")], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2
