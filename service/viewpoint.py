"""Viewpoint plans for a world (paper: time-constrained viewpoint planning).

A request carries the robot's pose, the exit, the time limit and loss, the object types
and the candidates; the grid is the posted one, else the map a SLAM run committed to the
world (``slam_map`` artifact), else what the robot would map from its pose in the
world's simulator (a look around, §4.1). Grouping is decided by the Prolog rules
(``prolog/grouping.pl``, op ``viewpoint_groups``), which keep the scene's candidates,
unknown regions and groups as facts of the world (queryable in the REPL and the query
endpoint). The scene is stored, so it survives a restart; a request that fails after
grouping puts the previous scene back.
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import math
from pathlib import Path
from typing import Any

from numeric.errors import InvalidInput
from numeric.occupancy import OccupancyMap
from numeric.viewpoint.grid import PlanningGrid, look_around, scanned_grid
from numeric.viewpoint.plan import Plan
from numeric.viewpoint.planner import (
    GroupSpec,
    PlannedGroup,
    PlanReport,
    PlanRequest,
    PlanStep,
    ViewpointPlanner,
)
from service.kb import KnowledgeBase
from service.slam import MAP_ARTIFACT
from service.store import Store
from service.worlds import ArtifactKind, WorldService

SCENE_ARTIFACT = "viewpoint_scene"


def kb_grouper(kb: KnowledgeBase, world: str, sink: dict[str, Any] | None = None):  # type: ignore[no-untyped-def]
    """A :data:`numeric.viewpoint.planner.Grouper` asking the world's Prolog rules;
    ``sink`` receives the call's arguments (to store the scene)."""

    def group(cands: list[dict[str, Any]], regions: list[dict[str, Any]],
              min_area: float | None) -> list[GroupSpec]:
        args = {"world": world, "candidates": cands, "regions": regions,
                "min_area_m2": min_area}
        reply = kb.call("viewpoint_groups", **args)
        if sink is not None:
            sink.update(args)
        return [GroupSpec(int(g["id"]), str(g["kind"]), tuple(g["members"]))
                for g in reply["groups"]]

    return group


def local_grouper(prolog_dir: Path, world: str = "scene"):  # type: ignore[no-untyped-def]
    """A grouper on a private knowledge base (for the CLI and benchmarks): the same rules,
    a scratch world that is never stored. Returns (grouper, kb); close the kb when done."""
    kb = KnowledgeBase(prolog_dir)
    kb.call("create_world", world=world, landmarks=[])
    return kb_grouper(kb, world), kb


def step_json(st: PlanStep) -> dict[str, Any]:
    """A plan step as the Prolog op viewpoint_groups takes it."""
    return {"group_id": st.group_id, "pose": list(st.pose), "travel_m": st.travel_m,
            "observe_s": st.observe_s, "p_recog": st.p_recog, "done_at_s": st.done_at_s}


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def plan_json(report: PlanReport, plan: Plan, req: PlanRequest | None = None
              ) -> dict[str, Any]:
    """A plan; an infeasible one (L1 past the time limit: its loss and utility are
    infinite, shown as null) says so in ``status`` and ``reason``."""
    ok = math.isfinite(plan.utility)
    out = {"groups": report.names(plan),
           # the ids of /viewpoint-groups and the Prolog facts (vp_group/3), same order
           "group_ids": [report.groups[i].spec.id for i in plan.order], "value": plan.value,
           "t_move_s": plan.t_move, "t_obs_s": plan.t_obs, "expected_time_s": plan.time,
           "loss": _num(plan.loss), "utility": _num(plan.utility),
           "feasible": ok, "status": "feasible" if ok else "infeasible", "reason": None}
    if not ok:
        limit = f" of {req.time_limit_s:g} s" if req is not None else ""
        out["reason"] = (f"takes {plan.time:.1f} s, past the hard time limit{limit} (loss "
                         "L1): even leaving at once does not make it" if not plan.order
                         else f"takes {plan.time:.1f} s, past the hard time limit{limit} "
                              "(loss L1)")
    return out


def group_json(g: PlannedGroup) -> dict[str, Any]:
    out: dict[str, Any] = {"id": g.spec.id, "name": g.name, "kind": g.spec.kind,
                           "members": list(g.spec.members), "value": g.value,
                           "t_obs_s": _num(g.t_obs), "entry_points": len(g.entries)}
    if g.local is not None:
        out["strategy"] = g.local.strategy
        out["order"] = list(g.local.order)
        out["joint_point"] = list(g.local.joint_point) if g.local.joint_point else None
        out["t_seq_s"] = g.local.t_seq_s
        out["t_par_s"] = g.local.t_par_s
        # False: a group past the exact size, its time that of a followable policy (>= min)
        out["exact"] = g.local.exact
    if g.area_m2 is not None and g.centroid is not None:
        out["area_m2"] = g.area_m2
        out["centroid"] = [float(g.centroid[0]), float(g.centroid[1])]
    return out


def report_json(world: str, report: PlanReport, grid_source: str,
                grid: PlanningGrid, req: PlanRequest | None = None) -> dict[str, Any]:
    best, *rest = report.plans
    return {
        "world": world,
        "groups": [group_json(g) for g in report.groups],
        "unverifiable": [{"name": g.name, "kind": g.spec.kind, "members": list(g.spec.members),
                          "reason": "no usable viewpoint recognises it" if g.spec.kind
                          == "objects" else "no entry point"} for g in report.skipped],
        "plan": {**plan_json(report, best, req),
                 "steps": [dataclasses.asdict(st) for st in report.steps(best)]},
        "leave_now": not best.order,
        "optimality": None if report.solution is None else {
            "optimal": report.solution.optimal, "gap": _num(report.solution.gap),
            "upper_bound": _num(report.solution.upper_bound),
            "returned_early": report.solution.returned_early,
            "nodes": report.solution.nodes},
        "runner_ups": [plan_json(report, p, req) for p in rest],
        "grid": {"source": grid_source, "resolution_m": grid.resolution,
                 "cells": list(grid.state.shape), "unknown_m2": grid.unknown_area()},
        "tables": {"built": report.tables_built, "reused": report.tables_reused},
        "timings_ms": report.timings_ms,
    }


class ViewpointService:
    def __init__(self, store: Store, kb: KnowledgeBase, worlds: WorldService) -> None:
        self.store, self.kb, self.worlds = store, kb, worlds
        self.planner = ViewpointPlanner()
        self._lock = asyncio.Lock()  # the planner's pattern tables are not thread-safe
        worlds.register(ArtifactKind(SCENE_ARTIFACT, "viewpoint_groups", "viewpoint",
                                     lambda _world, blob: dict(json.loads(blob))))

    def grid_for(self, world: str, req: PlanRequest) -> tuple[PlanningGrid, str]:
        if req.grid is not None:
            return req.grid.to_grid(), "posted"
        blob = self.store.artifact(world, MAP_ARTIFACT)
        if blob is not None:
            return PlanningGrid(OccupancyMap.from_npz(blob)), "slam_map"
        w = self.worlds.model(world)
        if len(w.wall_a) == 0:
            raise InvalidInput(f"world {world!r} has no walls and no committed SLAM map: "
                               "post a grid", field="grid")
        grid = scanned_grid(w, look_around(req.robot))
        if grid.room is None or not grid.room.any():
            raise InvalidInput("the world's walls enclose no space", field="grid")
        return grid, "simulated"

    async def plan(self, world: str, req: PlanRequest) -> dict[str, Any]:
        self.worlds.require(world)  # 404 for an unknown world
        # grouping asserts the scene as it plans: a failure anywhere puts the stored one back
        async with self.worlds.write_artifact(world, SCENE_ARTIFACT) as w, self._lock:
            scene: dict[str, Any] = {}
            grid, source = await asyncio.to_thread(self.grid_for, world, req)
            report = await asyncio.to_thread(self.planner.plan, req, grid,
                                             kb_grouper(self.kb, world, scene))
            # the best plan's steps join the scene's facts (vp_plan_step/9)
            scene["steps"] = [step_json(st) for st in report.steps(report.plans[0])]
            await w.commit(json.dumps(scene).encode(), call=scene)
        return report_json(world, report, source, grid, req)

    async def scene(self, world: str) -> Any:
        self.worlds.require(world)
        return await self.kb.acall("viewpoint_scene", world=world)
