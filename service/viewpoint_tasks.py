"""Viewpoint planning in a compute worker (:mod:`chizu.service.compute`): the planner's
steps before and after the Prolog grouping, and the answer (:class:`ViewpointPlanOut`). Imports
``numeric`` and the request's schema only (no web, no Prolog): it runs in the workers.

Each worker keeps one :class:`ViewpointPlanner`, so its pattern tables, local plans
and travel maps are reused by the requests that worker serves (re-planning).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from chizu.numeric.errors import InvalidInput
from chizu.numeric.occupancy import OccupancyMap
from chizu.numeric.viewpoint.grid import PlanningGrid, look_around, scanned_grid
from chizu.numeric.viewpoint.plan import Plan
from chizu.numeric.viewpoint.planner import (
    GroupSpec,
    PlannedGroup,
    PlanReport,
    PlanStep,
    Prepared,
    ViewpointPlanner,
)
from chizu.numeric.world import World
from chizu.service.schemas.viewpoint import (
    GroupOut,
    OptimalityOut,
    PlanGridOut,
    PlanOut,
    PlanRequest,
    PlanSummaryOut,
    TablesOut,
    UnverifiableOut,
    ViewpointPlanOut,
)

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
                ) -> tuple[ViewpointPlanOut, list[dict[str, Any]]]:
    """Steps 3 and 4 (:meth:`ViewpointPlanner.finish`): the answer, and the best plan's
    steps as the scene's facts take them."""
    report = planner().finish(req, grid, prep, specs, grouping_ms)
    return (plan_answer(world, report, grid_source, grid, req),
            [step_json(st) for st in report.steps(report.plans[0])])


def step_json(st: PlanStep) -> dict[str, Any]:
    """A plan step as the Prolog op viewpoint_groups takes it."""
    return {"group_id": st.group_id, "pose": list(st.pose), "travel_m": st.travel_m,
            "observe_s": st.observe_s, "p_recog": st.p_recog, "done_at_s": st.done_at_s}


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def plan_summary(report: PlanReport, plan: Plan, req: PlanRequest | None = None
                 ) -> PlanSummaryOut:
    """A plan; an infeasible one (L1 past the time limit: its loss and utility are
    infinite, shown as null) says so in ``status`` and ``reason``."""
    ok = math.isfinite(plan.utility)
    reason = None
    if not ok:
        limit = f" of {req.time_limit_s:g} s" if req is not None else ""
        reason = (f"takes {plan.time:.1f} s, past the hard time limit{limit} (loss "
                  "L1): even leaving at once does not make it" if not plan.order
                  else f"takes {plan.time:.1f} s, past the hard time limit{limit} (loss L1)")
    return PlanSummaryOut(
        groups=report.names(plan),
        # the ids of /viewpoint-groups and the Prolog facts (vp_group/3), same order
        group_ids=[report.groups[i].spec.id for i in plan.order], value=plan.value,
        t_move_s=_num(plan.t_move), t_obs_s=_num(plan.t_obs),
        expected_time_s=_num(plan.time), loss=_num(plan.loss), utility=_num(plan.utility),
        feasible=ok, status="feasible" if ok else "infeasible", reason=reason)


def group_out(g: PlannedGroup) -> GroupOut:
    """A group; an object group's local plan and a region's area and centroid are set
    only for groups that have them (the answer leaves the others out)."""
    extra: dict[str, Any] = {}
    if g.local is not None:
        extra.update(strategy=g.local.strategy, order=list(g.local.order),
                     joint_point=list(g.local.joint_point) if g.local.joint_point else None,
                     t_seq_s=g.local.t_seq_s, t_par_s=g.local.t_par_s,
                     # False: a group past the exact size, its time that of a followable
                     # policy (>= min)
                     exact=g.local.exact)
    if g.area_m2 is not None and g.centroid is not None:
        extra.update(area_m2=g.area_m2, centroid=[float(g.centroid[0]), float(g.centroid[1])])
    return GroupOut(id=g.spec.id, name=g.name, kind=g.spec.kind,
                    members=list(g.spec.members), value=g.value, t_obs_s=_num(g.t_obs),
                    entry_points=len(g.entries), **extra)


def unverifiable_out(g: PlannedGroup) -> UnverifiableOut:
    return UnverifiableOut(name=g.name, kind=g.spec.kind,
                           members=list(g.spec.members),
                           reason="no usable viewpoint recognises it"
                           if g.spec.kind == "objects" else "no entry point")


def plan_answer(world: str, report: PlanReport, grid_source: str,
                grid: PlanningGrid, req: PlanRequest | None = None) -> ViewpointPlanOut:
    """The answer of ``POST .../viewpoint-plan``: the groups, the best plan with its
    steps, the runner-ups, the grid planned on and the planner's costs."""
    best, *rest = report.plans
    sol = report.solution
    return ViewpointPlanOut(
        world=world, groups=[group_out(g) for g in report.groups],
        unverifiable=[unverifiable_out(g) for g in report.skipped],
        plan=PlanOut(**dict(plan_summary(report, best, req)), steps=[
            dataclasses.asdict(st) for st in report.steps(best)]),
        leave_now=not best.order,
        optimality=None if sol is None else OptimalityOut(
            optimal=sol.optimal, gap=_num(sol.gap), upper_bound=_num(sol.upper_bound),
            returned_early=sol.returned_early, nodes=sol.nodes),
        runner_ups=[plan_summary(report, p, req) for p in rest],
        grid=PlanGridOut(source=grid_source,
                         resolution_m=grid.resolution, cells=list(grid.state.shape),
                         unknown_m2=grid.unknown_area()),
        tables=TablesOut(built=report.tables_built, reused=report.tables_reused),
        timings_ms=report.timings_ms)
