"""Viewpoint planning in a compute worker (:mod:`service.compute`): the planner's
steps before and after the Prolog grouping, and the answer as JSON. Imports
``numeric`` and the request's schema only (no web, no Prolog): it runs in the workers.

Each worker keeps one :class:`ViewpointPlanner`, so its pattern tables, local plans
and travel maps are reused by the requests that worker serves (re-planning).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from numeric.errors import InvalidInput
from numeric.occupancy import OccupancyMap
from numeric.viewpoint.grid import PlanningGrid, look_around, scanned_grid
from numeric.viewpoint.plan import Plan
from numeric.viewpoint.planner import (
    GroupSpec,
    PlannedGroup,
    PlanReport,
    PlanStep,
    Prepared,
    ViewpointPlanner,
)
from numeric.world import World
from service.schemas.viewpoint import PlanRequest

_planner: ViewpointPlanner | None = None  # this worker's


def planner() -> ViewpointPlanner:
    global _planner
    if _planner is None:
        _planner = ViewpointPlanner()
    return _planner


def planning_grid(source: OccupancyMap | World | None, req: PlanRequest) -> PlanningGrid:
    """The grid to plan on: the posted one (``source`` None), a committed SLAM map, or
    what the robot maps from its pose in the world's simulator (a look around, §4.1)."""
    if source is None:
        if req.grid is None:
            raise InvalidInput("no grid was posted", field="grid")
        return req.grid.to_grid()
    if isinstance(source, OccupancyMap):
        return PlanningGrid(source)
    if len(source.wall_a) == 0:
        raise InvalidInput(f"world {source.description.name!r} has no walls and no committed "
                           "SLAM map: post a grid", field="grid")
    grid = scanned_grid(source, look_around(req.robot))
    if grid.room is None or not grid.room.any():
        raise InvalidInput("the world's walls enclose no space", field="grid")
    return grid


def prepare_task(source: OccupancyMap | World | None, req: PlanRequest
                 ) -> tuple[PlanningGrid, Prepared]:
    """The grid and step 1 (:meth:`ViewpointPlanner.prepare`)."""
    grid = planning_grid(source, req)
    return grid, planner().prepare(req, grid)


def finish_task(grid: PlanningGrid, prep: Prepared, specs: list[GroupSpec], req: PlanRequest,
                world: str, grid_source: str, grouping_ms: float
                ) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Steps 3 and 4 (:meth:`ViewpointPlanner.finish`): the answer, and the best plan's
    steps as the scene's facts take them."""
    report = planner().finish(req, grid, prep, specs, grouping_ms)
    return (report_json(world, report, grid_source, grid, req),
            [step_json(st) for st in report.steps(report.plans[0])])


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
           "t_move_s": _num(plan.t_move), "t_obs_s": _num(plan.t_obs),
           "expected_time_s": _num(plan.time),
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
