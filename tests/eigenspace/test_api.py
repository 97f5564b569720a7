"""Eigenspace API contract: learning job, camera, localize, sessions, next move, bad input."""

from __future__ import annotations

import base64
import io
import time
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image

from chizu.numeric.geometry import wrap_angle
from chizu.service.app import create_app
from chizu.service.settings import Settings

SMALL = {"camera": {"width_px": 32, "height_px": 16}, "learning": {"k": 12},
         "entry": {"samples": 30}, "regions": {"calibration_per_triplet": 2},
         "strategy": {"n_samples": 60}, "learning_strategy": None}
PROBLEM = "application/problem+json"


def wait_job(client: TestClient, location: str) -> dict[str, Any]:
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        j = client.get(location).json()
        if j["status"] in ("done", "failed"):
            return j
        time.sleep(0.2)
    raise AssertionError("learning job did not finish")


@pytest.fixture(scope="module")
def learned(client: TestClient) -> str:
    assert client.post("/worlds", json={"name": "eig_a", "template": "room_a"}).status_code == 201
    r = client.post("/worlds/eig_a/eigenspace", json=SMALL)
    assert r.status_code == 202, r.text
    job = wait_job(client, r.headers["location"])
    assert job["status"] == "done", job
    return "eig_a"


def test_learning_strategy_adds_points_in_the_job(client: TestClient) -> None:
    """By default learning ends with §4.2's additions; the summary traces them."""
    assert client.post("/worlds", json={"name": "eig_s", "template": "room_a"}
                       ).status_code == 201
    cfg = {**SMALL, "learning_strategy": {"target_probability": 1.0, "max_additions": 1}}
    job = wait_job(client, client.post("/worlds/eig_s/eigenspace", json=cfg
                                       ).headers["location"])
    assert job["status"] == "done", job
    s = client.get("/worlds/eig_s/eigenspace").json()
    trace = s["learning_strategy"]
    assert [t["learning_points"] for t in trace] == [25, 26, 26] and s["learning_points"] == 26
    assert trace[0]["added"] is None and len(trace[1]["added"]) == 2
    assert trace[2]["checked"] and trace[2]["triplets"] == s["triplets"]
    assert all(0.0 <= p <= 1.0 for t in trace for p in t["p_z"])
    assert_problem(client.post("/worlds/eig_s/eigenspace", json={
        "learning_strategy": {"max_additions": -1}}), 422, "max_additions")


def turn(client: TestClient, world: str, x: float, y: float, theta: float,
         n: int = 72, fmt: str = "list") -> dict[str, Any]:
    r = client.post(f"/worlds/{world}/camera", json={
        "pose": {"x": x, "y": y, "theta": theta}, "turn": n, "format": fmt})
    assert r.status_code == 200, r.text
    return r.json()  # type: ignore[no-any-return]


def assert_problem(r: Any, status: int, field: str | None = None) -> None:
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith(PROBLEM)
    if field is not None:
        assert field in (r.json().get("field") or "") + str(r.json().get("errors", "")), r.json()


def test_learning_summary_and_facts(client: TestClient, learned: str) -> None:
    s = client.get(f"/worlds/{learned}/eigenspace").json()
    assert s["learning_points"] == 25 and s["directions"] == 72 and s["k"] == 12
    assert s["triplets"] > 10 and 0 <= s["region_coverage"] <= 1
    assert [p["id"] for p in s["points"]] == list(range(25))
    assert len(s["triplet_list"]) == s["triplets"]
    for t in s["triplet_list"]:
        assert len(set(t["points"])) == 3 and all(0 <= i < 25 for i in t["points"])
        assert len(t["directions_rad"]) == 3 and t["area_m2"] > 0
        assert t["candidate_set"] is None or t["candidate_set"] >= 0
    facts = client.get(f"/worlds/{learned}/facts").json()
    assert any("eig_triplet" in f for f in facts)


def test_camera_answers_png_by_default(client: TestClient, learned: str) -> None:
    r = client.post(f"/worlds/{learned}/camera",
                    json={"pose": {"x": 3.0, "y": 4.0, "theta": 0.5}, "turn": 2})
    assert r.status_code == 200 and set(r.json()) == {"images_png"}
    assert len(r.json()["images_png"]) == 2


def test_camera_list_and_png_agree(client: TestClient, learned: str) -> None:
    a = np.array(turn(client, learned, 3.0, 4.0, 0.5, n=2)["images"])
    p = turn(client, learned, 3.0, 4.0, 0.5, n=2, fmt="png")["images_png"]
    assert a.shape == (2, 16, 32)
    b = np.asarray(Image.open(io.BytesIO(base64.b64decode(p[1]))), dtype=float) / 255
    np.testing.assert_allclose(a[1], b, atol=1 / 255 + 1e-4)


def test_localize_at_a_learning_point(client: TestClient, learned: str) -> None:
    imgs = turn(client, learned, 3.0, 5.0, 0.0)["images"]
    r = client.post(f"/worlds/{learned}/localize", json={"images": imgs})
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["state"]["state"] in ("y", "z") and out["candidates"]
    if out["state"]["state"] == "z":
        assert np.hypot(out["pose"]["x"] - 3.0, out["pose"]["y"] - 5.0) < 1.0
    # the same turn as PNG gives the same answer
    png = turn(client, learned, 3.0, 5.0, 0.0, fmt="png")["images_png"]
    r2 = client.post(f"/worlds/{learned}/localize", json={"images_png": png})
    assert r2.json()["state"] == out["state"]


def test_session_stops_and_next_move(client: TestClient, learned: str) -> None:
    r = client.post(f"/worlds/{learned}/localization-sessions")
    assert r.status_code == 201
    sid = r.json()["id"]
    base = f"/worlds/{learned}/localization-sessions/{sid}"
    mv = client.get(base + "/next-move").json()
    assert 0 <= mv["q_z"] <= 1 and set(mv["action"]) == {"alpha_rad", "l_m", "beta_rad"}
    s1 = client.post(base + "/stops", json={"images": turn(client, learned, 4.2, 4.7, 0.3)
                                            ["images"]})
    assert s1.status_code == 200 and s1.json()["stops"] == 1
    # a second stop needs the odometry
    imgs2 = turn(client, learned, 5.2, 4.7, 0.3)["images"]
    assert_problem(client.post(base + "/stops", json={"images": imgs2}), 422, "odometry")
    odo = {"dx": float(np.cos(0.3)), "dy": float(-np.sin(0.3)), "dtheta": 0.0}
    s2 = client.post(base + "/stops", json={"images": imgs2, "odometry": odo})
    assert s2.status_code == 200 and s2.json()["stops"] == 2
    order = {"x": 0, "y": 1, "z": 2}
    assert order[s2.json()["state"]["state"]] >= order[s1.json()["state"]["state"]]
    got = client.get(base).json()
    assert got["stops"] == 2 and got["state"] == s2.json()["state"]


def test_next_move_in_state_x_follows_the_turns_appearance(client: TestClient,
                                                          learned: str) -> None:
    """Before any region is entered, the strategy weighs where the robot may be by what
    its turn looked like: at one corner, facing the room or facing the wall, the
    advised turn alpha differs (eq. 8 alone gives every heading the same advice), and
    the stored session carries the appearance from one request to the next."""
    advice = []
    for x, y, th in ((0.7, 0.7, np.pi / 4), (0.7, 0.7, -3 * np.pi / 4),
                     (9.3, 9.3, -3 * np.pi / 4), (9.3, 9.3, np.pi / 4)):
        sid = client.post(f"/worlds/{learned}/localization-sessions").json()["id"]
        base = f"/worlds/{learned}/localization-sessions/{sid}"
        r = client.post(base + "/stops", json={"images_png": turn(
            client, learned, x, y, th, fmt="png")["images_png"]})
        assert r.status_code == 200, r.text
        if r.json()["state"]["state"] != "x":
            continue
        mv = client.get(base + "/next-move")
        assert mv.status_code == 200, mv.text
        advice.append(((x, y), th, mv.json()["action"]["alpha_rad"]))
    pairs = [(a, b) for a in advice for b in advice if a[0] == b[0] and a[1] < b[1]]
    assert pairs, "no corner turn stayed in state X"
    for a, b in pairs:
        # the two headings are half a turn apart: the advice in the room's frame agrees
        # (within 45 deg), so in the robot's frame the turns differ
        room_a_dir = a[1] + a[2]
        room_b_dir = b[1] + b[2]
        assert abs(wrap_angle(room_a_dir - room_b_dir)) <= np.pi / 4 + 1e-9
        assert abs(wrap_angle(a[2] - b[2])) >= np.pi / 2


def test_bad_images(client: TestClient, learned: str) -> None:
    url = f"/worlds/{learned}/localize"
    imgs = turn(client, learned, 3.0, 5.0, 0.0)["images"]
    assert_problem(client.post(url, json={"images": imgs[:71]}), 422, "images")
    assert_problem(client.post(url, json={"images": [np.zeros((8, 8)).tolist()] * 72}),
                   422, "images")
    too_bright = np.array(imgs)
    too_bright[0, 0, 0] = 2.0
    assert_problem(client.post(url, json={"images": too_bright.tolist()}), 422, "images")
    ragged = [r[:] for r in imgs[0]]
    ragged[3] = ragged[3][:-1]
    assert_problem(client.post(url, json={"images": [ragged] + imgs[1:]}), 422, "images")
    raw = ('{"images": [[[NaN' + ", 0.5" * 31 + "]" + "]" * 2 + "}").encode()
    assert_problem(client.post(url, content=raw, headers={"content-type": "application/json"}),
                   422, "images")
    assert_problem(client.post(url, json={"images_png": ["not base64!"]}), 422, "images_png")
    assert_problem(client.post(url, json={"images": [], "images_png": []}), 422)
    assert_problem(client.post(url, json={}), 422)


def test_unknowns_and_limits(client: TestClient, learned: str) -> None:
    assert_problem(client.post("/worlds/nowhere/localize", json={"images": [[[0.5]]]}), 404,
                   "world")
    assert client.post("/worlds", json={"name": "eig_empty", "template": "room_b"}
                       ).status_code == 201
    # the world is there, its eigenspace is not: 409 naming what is missing
    assert_problem(client.post("/worlds/eig_empty/localize", json={"images": [[[0.5]]]}), 409,
                   "eigenspace")
    assert_problem(client.post("/worlds/eig_empty/localization-sessions"), 409, "eigenspace")
    assert_problem(client.get(f"/worlds/{learned}/localization-sessions/abc"), 422, "sid")
    assert_problem(client.get(f"/worlds/{learned}/localization-sessions/{'0' * 32}"), 404,
                   "session")
    assert_problem(client.get(f"/worlds/{learned}/eigenspace/jobs/abc"), 422, "job_id")
    assert_problem(client.get(f"/worlds/{learned}/eigenspace/jobs/{'0' * 32}"), 404, "job")
    assert_problem(client.post(f"/worlds/{learned}/camera",
                               json={"pose": {"x": 1, "y": 1}, "turn": 100000}), 422, "turn")
    assert_problem(client.post(f"/worlds/{learned}/camera", content=b'{"pose": {"x": Infinity, '
                               b'"y": 1}}', headers={"content-type": "application/json"}),
                   422, "pose")
    assert_problem(client.post(f"/worlds/{learned}/eigenspace",
                               json={"learning": {"k": 0}}), 422, "learning")
    huge = b'{"images": [' + b"0.5," * 3_000_000 + b"0.5]}"
    assert_problem(client.post(f"/worlds/{learned}/localize", content=huge,
                               headers={"content-type": "application/json"}), 413)


def test_failed_learning_job_reports_the_field(client: TestClient) -> None:
    assert client.post("/worlds", json={"name": "eig_bare"}).status_code == 201
    r = client.post("/worlds/eig_bare/eigenspace", json=SMALL)
    job = wait_job(client, r.headers["location"])
    assert job["status"] == "failed" and job["error"]["field"] == "world"
    assert_problem(client.get("/worlds/eig_bare/eigenspace"), 404, "eigenspace")


def test_analysis_and_session_survive_restart(tmp_path: Any) -> None:
    settings = Settings(data_dir=tmp_path, demo_world="")
    with TestClient(create_app(settings)) as c:
        c.post("/worlds", json={"name": "eig_r", "template": "room_a"})
        job = wait_job(c, c.post("/worlds/eig_r/eigenspace", json=SMALL).headers["location"])
        assert job["status"] == "done"
        sid = c.post("/worlds/eig_r/localization-sessions").json()["id"]
        imgs = turn(c, "eig_r", 3.0, 5.0, 0.0)["images"]
        before = c.post(f"/worlds/eig_r/localization-sessions/{sid}/stops",
                        json={"images": imgs}).json()
        summary = c.get("/worlds/eig_r/eigenspace").json()
    with TestClient(create_app(settings)) as c:
        assert c.get("/worlds/eig_r/eigenspace").json()["triplets"] == summary["triplets"]
        after = c.get(f"/worlds/eig_r/localization-sessions/{sid}").json()
        assert after["state"] == before["state"] and after["stops"] == 1
        facts = c.get("/worlds/eig_r/facts").json()
        assert sum("eig_triplet" in f for f in facts) == summary["triplets"]


def test_the_schema_names_every_localization_state_and_outcome(client: TestClient) -> None:
    schemas = client.get("/openapi.json").json()["components"]["schemas"]
    assert set(schemas["LocalizationOut"]["properties"]["outcome"]["enum"]) == {
        "none", "unique", "in_set", "across", "unlisted"}
    states = {schemas[k]["properties"]["state"]["const"] for k in ("StateX", "StateY", "StateZ")}
    assert states == {"x", "y", "z"} and "set" in schemas["StateY"]["required"]
    assert "SessionLocalizationOut" in schemas and "NextMoveOut" in schemas


def test_a_symmetric_room_answers_state_y_from_the_prolog_rules(client: TestClient) -> None:
    """The twin hexagon (every place has a look-alike): candidate-multiple sets form,
    and a turn at a learning point is ambiguous within one set (Fig. 4: state Y(m),
    outcome in_set), with the two look-alike places as candidates."""
    assert client.post("/worlds", json={"name": "twins", "template": "twin_hexagon"}
                       ).status_code == 201
    r = client.post("/worlds/twins/eigenspace", json=SMALL)
    assert wait_job(client, r.headers["location"])["status"] == "done"
    s = client.get("/worlds/twins/eigenspace").json()
    assert s["candidate_sets"] >= 1
    assert any(t["candidate_set"] is not None for t in s["triplet_list"])
    for p in s["points"][::5]:
        t = turn(client, "twins", p["x"], p["y"], 0.0, fmt="png")
        out = client.post("/worlds/twins/localize", json=t).json()
        assert out["state"]["state"] == "y" and isinstance(out["state"]["set"], int), out
        assert out["outcome"] == "in_set" and out["pose"] is None
        xy = [(c["pose"]["x"], c["pose"]["y"]) for c in out["candidates"][:2]]
        assert len(xy) == 2 and np.hypot(xy[0][0] + xy[1][0] - 10, xy[0][1] + xy[1][1] - 8) < 1.0


def test_the_coverage_map_shows_where_a_turn_enters_a_region(client: TestClient,
                                                            learned: str) -> None:
    """The eq.-7 raster over the room's bounds: free cells carry a probability, the rest
    null; its covered share at the default cell is the summary's region coverage; a
    coarser cell gives a coarser raster; a raster too fine or a bad cell is refused."""
    summary = client.get(f"/worlds/{learned}/eigenspace").json()
    m = client.get(f"/worlds/{learned}/eigenspace/coverage").json()
    assert (m["rows"], m["columns"], m["cell_m"]) == (50, 50, 0.2)  # room A: 10 m square
    assert len(m["p_enter"]) == 50 and all(len(r) == 50 for r in m["p_enter"])
    cells = [v for r in m["p_enter"] for v in r]
    free = [v for v in cells if v is not None]
    assert 0 < len(free) < len(cells) and all(0.0 <= v <= 1.0 for v in free)
    assert m["p_enter"][0][0] is None  # the corner cell is within the walls' clearance
    assert m["share"] == pytest.approx(summary["region_coverage"])
    assert m["share"] == pytest.approx(sum(v >= 0.5 for v in free) / len(free))
    coarse = client.get(f"/worlds/{learned}/eigenspace/coverage", params={"cell_m": 1.0}).json()
    assert (coarse["rows"], coarse["columns"]) == (10, 10)
    for bad in ("0", "-1", "nan", "inf", "6", "x"):
        assert_problem(client.get(f"/worlds/{learned}/eigenspace/coverage",
                                  params={"cell_m": bad}), 422, "cell_m")
    assert_problem(client.get(f"/worlds/{learned}/eigenspace/coverage",
                              params={"cell_m": 0.01}), 422, "cell_m")
    assert client.get("/worlds/nowhere/eigenspace/coverage").status_code == 404


def test_an_unanswered_stop_says_which_test_refused_it(client: TestClient,
                                                       learned: str) -> None:
    """A unique answer carries no refusal; a turn from a corner, facing the walls, names
    the first test that held it back, with the figure it refused on."""
    out = client.post(f"/worlds/{learned}/localize",
                      json={"images": turn(client, learned, 9.6, 0.4, 1.0)["images"]}).json()
    assert not out["unique"] and out["answered_by"] is None
    why = out["refused_by"]
    assert why["test"] in ("no_region", "plane_test", "vote_threshold", "vote_margin",
                           "candidate_set")
    if why["test"] == "no_region":
        assert why["d_err_min_m"] >= client.get(f"/worlds/{learned}/eigenspace"
                                                ).json()["d_thd_m"]
    elif why["test"] != "plane_test":
        assert why["votes"] > 0
    for x, y in ((3.0, 5.0), (5.0, 3.0), (7.0, 7.0)):
        a = client.post(f"/worlds/{learned}/localize",
                        json={"images": turn(client, learned, x, y, 0.0)["images"]}).json()
        assert (a["refused_by"] is None) == a["unique"]
        assert (a["answered_by"] in ("vote", "whole_turn_check")) == a["unique"]
