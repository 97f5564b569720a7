"""Viewpoint planning (Masuzawa & Miura): the plan answer and the stored scene's groups.
The request is the planner's own :class:`numeric.viewpoint.planner.PlanRequest`."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field

from numeric.viewpoint.planner import PlanRequest

ViewpointPlanIn = PlanRequest


class GroupOut(BaseModel):
    """An observation group (§4): its objects or its unknown region, value (eqs.
    15-17), expected verification time (eqs. 5-10; null when none can be given) and, for
    objects, the local strategy (single, seq, par) with its order and joint viewpoint;
    for a region its area and centroid."""

    id: int
    name: str
    kind: Literal["objects", "unknown"]
    members: list[str | int]
    value: float
    t_obs_s: float | None
    entry_points: int
    strategy: str | None = None
    order: list[str] | None = None
    joint_point: list[float] | None = None
    t_seq_s: float | None = None
    t_par_s: float | None = None
    exact: bool | None = Field(None, description="false: past the exact size, the time of "
                               "a followable policy (at least the minimum)")
    area_m2: float | None = None
    centroid: list[float] | None = None


class UnverifiableOut(BaseModel):
    name: str
    kind: Literal["objects", "unknown"]
    members: list[str | int]
    reason: str


class PlanStepOut(BaseModel):
    """Where to stand, the travel there, the verification, P_recog of the first look
    (null for a region) and when the group is done."""

    group_id: int
    name: str
    kind: Literal["objects", "unknown"]
    pose: list[float]
    travel_m: float
    travel_s: float
    observe_s: float
    p_recog: float | None
    done_at_s: float


class PlanSummaryOut(BaseModel):
    """An ordered plan and its utility U = V - L(t) (eq. 11); infeasible (L1 past the
    hard limit: loss and utility null) says why in ``reason``."""

    groups: list[str]
    group_ids: list[int]
    value: float
    # null: infinite (a group the robot cannot reach on the grid)
    t_move_s: float | None
    t_obs_s: float | None
    expected_time_s: float | None
    loss: float | None
    utility: float | None
    feasible: bool
    status: Literal["feasible", "infeasible"]
    reason: str | None


class PlanOut(PlanSummaryOut):
    steps: list[PlanStepOut]


class OptimalityOut(BaseModel):
    optimal: bool
    gap: float | None
    upper_bound: float | None
    returned_early: bool
    nodes: int


class PlanGridOut(BaseModel):
    source: Literal["posted", "slam_map", "simulated"]
    resolution_m: float
    cells: list[int]
    unknown_m2: float


class TablesOut(BaseModel):
    built: int
    reused: int


class ViewpointPlanOut(BaseModel):
    world: str
    groups: list[GroupOut]
    unverifiable: list[UnverifiableOut]
    plan: PlanOut
    leave_now: bool
    optimality: OptimalityOut | None
    runner_ups: list[PlanSummaryOut]
    grid: PlanGridOut
    tables: TablesOut
    timings_ms: dict[str, float]


class SceneGroupOut(BaseModel):
    id: int
    kind: Literal["objects", "unknown"]
    members: list[str | int]
    area_m2: float | None = None


class SceneStepOut(BaseModel):
    group_id: int
    pose: list[float]
    travel_m: float
    observe_s: float
    p_recog: float | None
    done_at_s: float


class ViewpointGroupsOut(BaseModel):
    """The last planned scene as the knowledge base holds it (prolog/grouping.pl)."""

    groups: list[SceneGroupOut]
    min_area_m2: float
    steps: list[SceneStepOut]
