"""The end-to-end mission, small: one run through the REST job on the mission world (a
coarse eigenspace so the test learns in seconds), its record as facts, bad input."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from chizu.numeric.world import World
from chizu.numeric.worlds import MISSION_ROOM, mission_world, office_world

#: a coarse eigenspace: small images, 36 directions, the mission's 1 m grid
SMALL = {"eigenspace": {"camera": {"width_px": 32, "height_px": 16, "supersample": 1},
                        "learning": {"spacing_m": 1.0, "n_directions": 36},
                        "learning_strategy": None},
         "time_limit_s": 60.0}


def wait_job(client: TestClient, location: str, timeout_s: float = 300) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        j = client.get(location).json()
        if j["status"] not in ("queued", "running"):
            return j
        time.sleep(0.2)
    raise AssertionError("mission job did not finish")


@pytest.fixture(scope="module")
def mission_run(client: TestClient) -> dict[str, Any]:
    assert client.post("/worlds", json={"name": "mission_t", "template": "mission"}
                       ).status_code == 201
    r = client.post("/worlds/mission_t/missions", json={**SMALL, "seed": 3})
    assert r.status_code == 202, r.text
    assert r.headers["location"] == f"/jobs/{r.json()['id']}"
    job = wait_job(client, r.headers["location"])
    assert job["status"] == "done", job
    return dict(job["result"])


def test_mission_runs_every_step(mission_run: dict[str, Any]) -> None:
    whats = [s["what"] for s in mission_run["steps"]]
    for what in ("survey", "learn_eigenspace", "localize", "reach_landmark", "drm_path",
                 "navigate", "slam_map", "enter_room", "viewpoint_plan", "verify",
                 "evaluation"):
        assert what in whats, (what, whats)
    assert whats[-1] == "evaluation"
    ev = mission_run["steps"][-1]["result"]
    # the eigenspace's pose names the nearest landmark; a robot it left lost wanders
    assert ("nearest_landmark" in whats) == (ev["localized_by"] == "eigenspace"), whats
    if ev["localized_by"] == "eigenspace":  # at the landmark the map is anchored anew
        assert "landmark_fix" in whats and ev["eigenspace_error_m"] < 1.0
    assert ev["localization_error_m"] < 0.5
    assert ev["objects_verified"] >= 1 and ev["false_verified"] == 0
    assert mission_run["success"] is True
    path = next(s["result"] for s in mission_run["steps"] if s["what"] == "drm_path")
    assert path["to"] == "c1" and path["landmarks"][-1] == "c1"
    assert 0 < path["probability"] <= 1


def test_record_is_facts(client: TestClient, mission_run: dict[str, Any]) -> None:
    rec = client.get("/worlds/mission_t/mission").json()
    assert rec["steps"] == mission_run["steps"]

    def q(goal: str) -> list[dict[str, Any]]:
        r = client.post("/worlds/mission_t/query", json={"goal": goal, "max_solutions": 50})
        assert r.status_code == 200, r.text
        return list(r.json()["solutions"])

    assert len(q("mission_step(S, W, R)")) == len(mission_run["steps"])
    assert q("mission_outcome(O)") == [{"O": "succeeded"}]
    pose = q("mission_pose(X, Y, Th)")[0]
    loc = next(s["result"] for s in mission_run["steps"] if s["what"] == "localize"
               and s["result"].get("state") == "z")
    assert pose["X"] == pytest.approx(loc["x"])
    # the steps' products are facts of the same world: the SLAM map, the DRM path
    # (landmarks as atoms, so they join the DRM's relations)
    assert q("committed_map(Run)")[0]["Run"] == next(
        s["result"]["slam_run"] for s in mission_run["steps"] if s["what"] == "slam_map")
    assert q("mission_path(Ls, _), Ls = [A, B|_], drm_edge(A, B, P, M)")
    cands = q("mission_step(_, viewpoint_plan, R), member(candidates = Cs, R)")
    assert cands and cands[0]["Cs"], cands


def test_record_survives_a_restart(tmp_path_factory: pytest.TempPathFactory) -> None:
    """A second app on a fresh data dir, one quick mission that stops early (a start
    region with no free space is refused; a goal far away is not): the record is stored
    and comes back after a restart."""
    from chizu.service.app import create_app
    from chizu.service.client import Client
    from chizu.service.settings import Settings

    settings = Settings(data_dir=tmp_path_factory.mktemp("mission_restart"), demo_world=None)
    with TestClient(create_app(settings)) as c:  # through the typed client
        chizu = Client(http=c)
        chizu.worlds.create_world({"name": "m", "template": "mission"})
        job = chizu.mission.post_mission("m", {**SMALL, "seed": 5, "max_stops": 1})
        assert chizu.wait_job(job, timeout_s=300).status == "done"
        steps = chizu.mission.get_mission("m").steps
        assert steps and steps[-1].what == "evaluation"
    with TestClient(create_app(settings)) as c:
        chizu = Client(http=c)
        assert chizu.mission.get_mission("m").steps == steps
        q = chizu.qualitative.post_query("m", {"goal": "mission_step(S, W, R)",
                                               "max_solutions": 100})
        assert len(q.solutions) == len(steps)


@pytest.mark.parametrize(("body", "status", "field"), [
    ({"goal": "nowhere"}, 422, "goal"),
    ({"goal": "Bad goal"}, 422, "goal"),
    ({"door": [100.0, 100.0]}, 422, "door"),
    ({"door": [6.1, 2.1]}, 422, "door"),
    ({"room": [[12.0, 8.0], [6.0, 2.0]]}, 422, "room"),
    ({"seed": -1}, 422, "seed"),
    ({"max_stops": 0}, 422, "max_stops"),
    ({"time_limit_s": 0}, 422, "time_limit_s"),
    ({"slam_method": "magic"}, 422, "slam_method"),
    ({"surprise": 1}, 422, "surprise"),
    ({"start": [[100.0, 100.0], [101.0, 101.0]]}, 422, "start"),
    ({"eigenspace": {"learning": {"spacing_m": 0.06, "n_directions": 360}}}, 422,
     "eigenspace.learning.spacing_m"),
])
def test_bad_mission_input(client: TestClient, body: dict[str, Any], status: int,
                           field: str) -> None:
    if client.get("/worlds/mission_bad").status_code == 404:
        client.post("/worlds", json={"name": "mission_bad", "template": "mission"})
    r = client.post("/worlds/mission_bad/missions", json=body)
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith("application/problem+json")
    assert field in r.text
    assert client.get("/worlds/mission_bad/mission").json()["steps"] == []


def test_bad_mission_raw_json(client: TestClient) -> None:
    if client.get("/worlds/mission_bad").status_code == 404:
        client.post("/worlds", json={"name": "mission_bad", "template": "mission"})
    for text, field in (('{"door": [NaN, 1]}', "door"), ('{"door": [1e999, 1]}', "door"),
                        ('{"door": [1]}', "door"), ('{"seed": "1"}', "seed"),
                        ('{"observer": {"recognition_radius_m": Infinity}}',
                         "observer.recognition_radius_m"),
                        ('{"odometry": {"turn_noise_ratio": 5}}', "odometry.turn_noise_ratio")):
        r = client.post("/worlds/mission_bad/missions", content=text,
                        headers={"content-type": "application/json"})
        assert r.status_code == 422, (text, r.text)
        assert field in r.text
    assert client.post("/worlds/nope/missions", json={}).status_code == 404


def test_office_rooms_are_inside() -> None:
    """Rooms between partition walls are inside the building (the even-odd rule alone
    put every other office room outside); outside the walls and inside a closed pillar
    is not."""
    w = World(office_world(rooms_per_side=3))
    rooms = np.array([[3.0, 5.0], [9.0, 5.0], [15.0, 5.0], [3.0, -3.0], [15.0, -3.0],
                      [1.0, 1.0]])
    assert w.is_free(rooms).all()
    assert not w.inside(np.array([[-1.0, 5.0], [19.0, 1.0], [9.0, 9.0]])).any()
    m = World(mission_world())
    (x0, y0), (x1, y1) = MISSION_ROOM
    assert m.is_free(np.array([[x0 + 1.0, y0 + 1.0], [x1 - 1.0, y1 - 1.0]])).all()


def test_inside_gapped_and_huge_worlds() -> None:
    """A room with a doorway in its outer wall encloses nothing: the even-odd rule decides
    (its floor stays free); walls millions of metres long rasterise coarsely, not into
    gigabytes."""
    from chizu.numeric.world import Wall, WorldDescription

    gap = [Wall(a=(0, 0), b=(10, 0)), Wall(a=(10, 0), b=(10, 10)),
           Wall(a=(10, 10), b=(6, 10)), Wall(a=(5, 10), b=(0, 10)), Wall(a=(0, 10), b=(0, 0))]
    w = World(WorldDescription(name="gap", walls=gap))
    assert w.is_free(np.array([[5.0, 5.0], [2.0, 2.0]])).all()
    assert not w.is_free(np.array([[-1.0, 5.0]])).any()
    huge = World(WorldDescription(name="huge", walls=[
        Wall(a=(0, 0), b=(4e6, 0)), Wall(a=(4e6, 0), b=(4e6, 3e6)),
        Wall(a=(4e6, 3e6), b=(0, 3e6)), Wall(a=(0, 3e6), b=(0, 0))]))
    assert huge.inside(np.array([[2e6, 1e6]]))[0]
    assert huge._enclosed[2].size <= 2000 * 2000


def test_a_cancelled_mission_says_so(client: TestClient) -> None:
    """DELETE on a running mission's job: the job ends cancelled, its threads stop, and
    the record (facts and store alike) ends with an `aborted` step."""
    assert client.post("/worlds", json={"name": "mission_c", "template": "mission"}
                       ).status_code == 201
    r = client.post("/worlds/mission_c/missions", json={**SMALL, "seed": 1})
    loc = r.headers["location"]
    time.sleep(1.0)  # surveyed, learning the eigenspace
    assert client.delete(loc).status_code == 200
    job = wait_job(client, loc)
    assert job["status"] == "cancelled", job
    steps = client.get("/worlds/mission_c/mission").json()["steps"]
    assert steps[-1]["what"] == "aborted" and steps[-1]["result"]["ok"] is False
    r = client.post("/worlds/mission_c/query", json={"goal": "mission_outcome(O)",
                                                      "max_solutions": 5})
    assert r.json()["solutions"] == [{"O": "failed(aborted)"}]
    r = client.post("/worlds/mission_c/query", json={"goal": "mission_step(S, W, R)",
                                                      "max_solutions": 100})
    assert len(r.json()["solutions"]) == len(steps)


def test_one_mission_per_world(client: TestClient, mission_run: dict[str, Any]) -> None:
    r = client.post("/worlds/mission_t/missions", json={**SMALL, "seed": 4})
    assert r.status_code == 202, r.text
    again = client.post("/worlds/mission_t/missions", json={**SMALL, "seed": 5})
    assert again.status_code == 409, again.text
    assert again.headers["content-type"].startswith("application/problem+json")
    assert wait_job(client, r.headers["location"])["status"] == "done"


def test_the_evaluation_judges_a_trace_against_the_truth(tmp_path: Any) -> None:
    """numeric.mission.evaluate without a run: the anchored pose's errors (0.5 m and
    30 degrees at most), the objects verified, a false one; and the figure of the trace."""
    from chizu.numeric.figures import mission_figure
    from chizu.numeric.mission import MissionTrace, evaluate
    from chizu.numeric.viewpoint.online import SummaryRun

    w = World(mission_world())
    trace = MissionTrace(truth_path=[np.array([1.0, 1.0, 0.0]), np.array([3.0, 1.0, 0.0])],
                         fix=(np.array([1.0, 1.0, 0.1]), np.array([1.18, 1.24, 0.0])),
                         landmarks=["rn0a", "rn0b"])
    ev = evaluate(trace, w)
    assert ev.localization_error_m == pytest.approx(0.3) and ev.localized_by == "eigenspace"
    assert ev.pose_ok and (ev.objects, ev.objects_verified, ev.false_verified) == (3, 0, 0)
    assert not ev.success(verified=True)  # the world has objects and none was verified
    assert list(ev.record()) == ["localization_error_m", "heading_error_rad", "localized_by",
                                 "objects", "objects_verified", "false_verified"]
    trace.summary = SummaryRun(path=[np.array([6.0, 5.0]), np.array([7.0, 6.0])], log=[],
                               verified={"mug": np.array([7.2, 6.6])}, rejected={},
                               unverified={}, grid=None, elapsed_s=10.0)  # type: ignore[arg-type]
    trace.fixed_by = "wander"
    ev = evaluate(trace, w)
    assert ev.localized_by == "wander" and ev.success(verified=True)
    assert not ev.success(verified=False)
    trace.summary.verified["ghost"] = np.array([8.0, 6.0])
    assert evaluate(trace, w).false_verified == 1
    assert not evaluate(trace, w).success(verified=True)
    trace.fix = (np.array([1.0, 1.0, 0.6]), np.array([1.0, 1.0, 0.0]))  # 34 degrees off
    assert not evaluate(trace, w).pose_ok
    mission_figure(trace, w, str(tmp_path / "m.png"), "a trace")
    assert (tmp_path / "m.png").read_bytes()[:4] == b"\x89PNG"
