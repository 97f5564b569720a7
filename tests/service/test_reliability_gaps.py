"""Faults a probe of the running service found (as a new user and as an attacker would):
each answered 500, a plan for a robot nowhere on the map, or a 404 for a resource that
exists. Each is now a 4xx problem+json naming the field, or a 409 naming what is missing."""

from __future__ import annotations

from typing import Any

import pytest
from fastapi.testclient import TestClient

from tests.service.test_container_write_path import plan_body
from tests.service.test_malformed_requests import is_problem


@pytest.fixture(scope="module")
def room(client: TestClient) -> str:
    assert client.post("/worlds", json={"name": "gap_room", "template": "room_a"}
                       ).status_code == 201
    return "gap_room"


def with_robot(robot: list[float], grid: bool = True) -> dict[str, Any]:
    body = plan_body()
    body["robot"] = robot
    if not grid:
        del body["grid"]
    return body


@pytest.mark.parametrize("grid", [True, False])
def test_subnormal_coordinates_are_numbers_like_any_other(client: TestClient, room: str,
                                                          grid: bool) -> None:
    """Tiny and subnormal numbers plan like their neighbours: on the posted grid's
    corner, or a hair off it (refused, naming the robot)."""
    body = with_robot([5.8e-190, 2.35e-104, 5e-324], grid)
    if not grid:  # room_a's simulated view: its corner is outside the room
        body["robot"], body["exit"] = [3.0, 5.0, 5e-324], [3.0, 5.0 + 2.35e-104]
    r = client.post(f"/worlds/{room}/viewpoint-plan", json=body)
    assert r.status_code == 200, r.text
    if grid:
        body["robot"] = [5.8e-190, -2.35e-104, 0.5]
        is_problem(client.post(f"/worlds/{room}/viewpoint-plan", json=body), 422, "robot")


@pytest.mark.parametrize("robot", [[100.0, 100.0, 0.0], [1e300, 0.0, 0.0],
                                   [-1e300, 1e300, 0.0], [-30.0, 2.0, 0.0]])
@pytest.mark.parametrize("grid", [True, False])
def test_a_robot_off_the_map_is_refused(client: TestClient, room: str, robot: list[float],
                                        grid: bool) -> None:
    r = client.post(f"/worlds/{room}/viewpoint-plan", json=with_robot(robot, grid))
    is_problem(r, 422, "robot")
    assert "robot" in r.json()["detail"]


def test_an_exit_off_the_map_is_refused(client: TestClient, room: str) -> None:
    body = plan_body()
    body["exit"] = [50.0, 0.5]
    is_problem(client.post(f"/worlds/{room}/viewpoint-plan", json=body), 422, "exit")


def test_a_plan_inside_the_grid_still_answers(client: TestClient, room: str) -> None:
    body = plan_body()
    body["robot"] = [2.0, 1.0, 0.0]
    r = client.post(f"/worlds/{room}/viewpoint-plan", json=body)
    assert r.status_code == 200, r.text


def test_state_dependent_refusals_are_409_naming_what_is_missing(client: TestClient,
                                                                  room: str) -> None:
    """404 only where the path names something that does not exist; a world that exists
    but lacks what the request needs (an eigenspace, a map) answers 409."""
    for r in (client.post(f"/worlds/{room}/localize", json={"images": [[[0.5]]]}),
              client.post(f"/worlds/{room}/localization-sessions")):
        is_problem(r, 409, "eigenspace")
        assert "no eigenspace" in r.json()["detail"]
    is_problem(client.post(f"/worlds/{room}/localization-runs"), 409)
    is_problem(client.post("/worlds/nosuch/localize", json={"images": [[[0.5]]]}), 404, "world")
    # a landmark the world lacks, named in the query or the body: a bad value
    is_problem(client.get(f"/worlds/{room}/path", params={"from": "zz", "to": "zz2"}), 422,
               "from")
    # the eigenspace's own resource while there is none: 404
    is_problem(client.get(f"/worlds/{room}/eigenspace"), 404, "eigenspace")
