"""Viewpoint planning (Masuzawa & Miura): the request, the plan answer and the stored
scene's groups. The request is the planner's :class:`chizu.numeric.viewpoint.planner.PlanRequest`
with the API's caps (candidates, object types, name lengths) and an optional grid posted
in ROS's ``nav_msgs/OccupancyGrid`` layout; the same model reads ``chizu plan``'s
SCENE.json."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, FiniteFloat

from chizu.numeric.viewpoint import planner
from chizu.numeric.viewpoint.grid import MAX_CELLS, PlanningGrid, from_occupancy_values

MAX_CANDIDATES = 200
MAX_TYPES = 32
MAX_NAME = 64  #: characters of an object type's name
MAX_BELIEF = 360  #: orientations of a candidate's belief


class ObjectType(planner.ObjectType):
    """A known object type: value V_obj (eq. 16), mean count per room n_bar (eqs. 10, 17)
    and its appearance -- fitted parameters, measurement tables to fit, or (for the
    built-in types A, B, C) nothing: fitted to the simulator's measurements."""

    name: str = Field(min_length=1, max_length=MAX_NAME)


class CandidateIn(planner.CandidateIn):
    """A candidate object found by colour (§4.1)."""

    type: str = Field(min_length=1, max_length=MAX_NAME)
    belief: list[Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]] | None = Field(
        None, max_length=MAX_BELIEF,
        description="orientation belief P(theta_i) over N_theta orientations")


class GridIn(BaseModel):
    """An occupancy grid as ROS ``nav_msgs/OccupancyGrid`` has it: ``data`` row-major with
    x fastest, -1 unknown, 0..100 occupancy; ``origin`` the lower-left corner (m)."""

    model_config = ConfigDict(extra="forbid")
    width: int = Field(ge=1, le=4000)
    height: int = Field(ge=1, le=4000)
    resolution_m: float = Field(gt=0.005, le=5.0, allow_inf_nan=False)
    origin: tuple[FiniteFloat, FiniteFloat] = (0.0, 0.0)
    data: list[Annotated[int, Field(ge=-1, le=100, strict=True)]] = Field(
        max_length=MAX_CELLS, description="-1 unknown, 0..100 occupancy; JSON integers")

    def to_grid(self) -> PlanningGrid:
        return from_occupancy_values(self.width, self.height, self.resolution_m, self.origin,
                                     self.data)


class PlanRequest(planner.PlanRequest):
    """Everything one planning step needs (paper §§3-6)."""

    object_types: Annotated[list[ObjectType], Field(max_length=MAX_TYPES)] = []
    candidates: Annotated[list[CandidateIn], Field(max_length=MAX_CANDIDATES)] = []
    grid: GridIn | None = None


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
