"""Missions one after another on one world, as a robot's days go: experience goes into the
DRM both ways (an arc driven raises its edge, one that failed lowers it), a failed arc
makes the robot reach a landmark and plan again instead of ending the mission, and a
world's history does not break a mission that succeeds on a fresh world."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from typing import Any

import pytest

import chizu.service.mission as mission_module
from chizu.numeric.slam.merge import runs_of
from chizu.numeric.slam.saved_map import from_bytes
from chizu.numeric.world import WorldDescription
from chizu.service.container import Services, open_services
from chizu.service.mission import MissionConfig, MissionRun
from chizu.service.settings import Settings
from chizu.service.slam import SAVED_MAP_ARTIFACT
from tests.mission.test_end_to_end import SMALL


@pytest.fixture(scope="module")
def services(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Services]:
    svc = open_services(Settings(data_dir=tmp_path_factory.mktemp("in_a_row"),
                                 demo_world=None, workers=0), demo=False)
    try:
        yield svc
    finally:
        svc.close()


def mission(svc: Services, world: str, seed: int, **config: Any) -> MissionRun:
    if world not in svc.worlds.names():
        asyncio.run(svc.worlds.create(WorldDescription(name=world, template="mission")))
    cfg = MissionConfig.model_validate({**SMALL, "seed": seed, **config})
    return asyncio.run(svc.mission.run(world, cfg))


def steps(run: MissionRun, what: str) -> list[dict[str, Any]]:
    return [s["result"] for s in run.steps if s["what"] == what]


def edge(svc: Services, world: str, a: str, b: str) -> dict[str, Any]:
    drm = asyncio.run(svc.worlds.drm(world))
    return next(e for e in drm["edges"] if (e["from"], e["to"]) == (a, b))


def failing_first(monkeypatch: pytest.MonkeyPatch, n: int) -> list[str]:
    """The first ``n`` arcs the mission sets out on fail where they start (the target is
    not recognised); the rest run in the simulator. Returns the targets that failed."""
    real, failed = mission_module.execute_step, []

    def step(robot: Any, observer: Any, s: Any, nav: Any) -> bool:
        if len(failed) < n:
            failed.append(s.target)
            return False
        return bool(real(robot, observer, s, nav))

    monkeypatch.setattr(mission_module, "execute_step", step)
    return failed


def test_a_failed_arc_is_experience_and_the_robot_plans_again(
        services: Services, monkeypatch: pytest.MonkeyPatch) -> None:
    failed = failing_first(monkeypatch, 1)
    run = mission(services, "replan", 3)
    (arc,) = steps(run, "arc_failed")
    assert failed == [arc["to"]]
    first, second = steps(run, "drm_path")
    assert first["landmarks"][:2] == [arc["from"], arc["to"]] and first["replan"] == 0
    # the world counted the failure and weighs the edge with it
    e = edge(services, "replan", arc["from"], arc["to"])
    assert e["failed"] == 1 and arc["failed"] == 1
    assert e["p"] < 2 / 3 + 1e-9  # at most (2 * 1 + 0) / 3
    # the robot recognised a landmark and planned again from it, and got there
    (again,) = [r for r in steps(run, "reach_landmark") if r.get("how") == "replan"]
    assert second["replan"] == 1 and second["landmarks"][0] == again["landmark"]
    nav = steps(run, "navigate")[-1]
    assert nav["ok"] is True and nav["replans"] == 1
    assert run.success, run.steps[-1]
    assert run.row()["failed_at"] == ""


def test_out_of_replans_the_mission_ends_at_navigate(
        services: Services, monkeypatch: pytest.MonkeyPatch) -> None:
    failing_first(monkeypatch, 100)
    run = mission(services, "no_replan", 3, max_replans=0)
    nav = steps(run, "navigate")[-1]
    assert nav["ok"] is False and nav["replans"] == 0 and "failed" in nav["reason"]
    assert not steps(run, "arc_failed") and len(steps(run, "drm_path")) == 1
    assert run.row()["failed_at"] == "navigate" and not run.success
    path = steps(run, "drm_path")[0]["landmarks"]
    assert edge(services, "no_replan", path[0], path[1])["failed"] == 1


def test_missions_in_a_row_do_as_well_as_on_a_fresh_world(services: Services) -> None:
    """Three seeds one after another on one world: the history (reached and failed arcs,
    earlier maps) breaks none that succeeds fresh (a seed that fails in the row is run
    again on a fresh world, which must fail too), every arc driven or failed is counted
    in the DRM, and the world's map serves the next mission's laser localization and
    grows with its way."""
    rows = {seed: mission(services, "row", seed) for seed in range(3)}
    for seed, run in rows.items():
        if not run.success:  # only a seed that fails here needs its fresh twin to compare
            fresh = mission(services, f"fresh{seed}", seed)
            assert not fresh.success, (seed, run.steps, fresh.steps)
    # from the second mission on the world has a map: where the robot wakes on it, the
    # laser localizes it there, the eigenspace's answer is reported against the laser's
    # pose, and the mission's map extends the world's
    by = {seed: steps(run, "localize")[-1].get("by") for seed, run in rows.items()}
    assert by[0] == "eigenspace" and "laser" in list(by.values())[1:], by
    for seed, run in rows.items():
        if by[seed] != "laser":
            continue
        ev, loc = steps(run, "evaluation")[-1], steps(run, "localize")[-1]
        assert ev["localized_by"] == "laser" and ev["localization_error_m"] < 0.2, ev
        assert "landmark_fix" not in [s["what"] for s in run.steps]
        if loc["state"] == "z":  # against the laser as against the truth, within its error
            assert abs(loc["eigenspace_vs_laser_m"] - ev["eigenspace_error_m"]) < 0.2, loc
        assert steps(run, "slam_map")[-1]["resumed"] is True
    saved = from_bytes(services.worlds.store.artifact("row", SAVED_MAP_ARTIFACT) or b"")
    assert len(runs_of(saved)) >= 2  # the map holds more than one mission's way
    events = [e.kind for e in services.worlds.store.events("row")]
    drm = asyncio.run(services.worlds.drm("row"))["edges"]
    assert sum(e["succeeded"] for e in drm) == events.count("reached") > 0
    assert sum(e["failed"] for e in drm) == events.count("failed")
