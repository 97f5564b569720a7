"""A viewpoint-planning request end to end (paper Fig. 2): appearance models, candidates
and unknown components in, observation groups (decided by the Prolog grouping rules,
passed in as ``grouper``), their values and observation times, and the best ordered plan
out.

:class:`PlanRequest` holds the planner's parameters for one planning step; the grid is
given beside it. The service's request body (service/schemas/viewpoint.py) is this
request with the API's size caps and an optional posted grid.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, FiniteFloat, model_validator

from chizu.numeric.errors import InvalidInput
from chizu.numeric.occupancy import UnknownComponent
from chizu.numeric.viewpoint.appearance import AppearanceModel, AppearanceParams, MeasurementTables
from chizu.numeric.viewpoint.grid import PlanningGrid, TravelMap
from chizu.numeric.viewpoint.plan import (
    MAX_GROUPS_EXACT,
    GroupCost,
    Loss,
    Plan,
    Problem,
    Solution,
    solve_auto,
    straight,
)
from chizu.numeric.viewpoint.recognition import OBJECT_KINDS, fitted_models
from chizu.numeric.viewpoint.verification import (
    Candidate,
    LocalPlan,
    TableCache,
    Verifier,
    ViewpointSet,
    unknown_region_time,
)
from chizu.numeric.world import ID_PATTERN

MAX_ENTRIES = 64
EXHAUSTIVE_MAX_GROUPS = 9

Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False)]


#: the built-in object types A, B, C (value, mean count per room; appearance fitted to the
#: simulator's measurements), as the CLI, the benchmarks and the mission use them
BUILTIN_OBJECT_TYPES: list[dict[str, Any]] = [
    {"name": "A", "value": 50, "mean_count": 1.0},
    {"name": "B", "value": 100, "mean_count": 0.5},
    {"name": "C", "value": 80, "mean_count": 0.5}]


class ObjectType(BaseModel):
    """A known object type: value V_obj (eq. 16), mean count per room n_bar (eqs. 10, 17)
    and its appearance -- fitted parameters, measurement tables to fit, or (for the
    built-in types A, B, C) nothing: fitted to the simulator's measurements."""

    model_config = ConfigDict(extra="forbid")
    name: str = Field(min_length=1)
    value: NonNeg = 50.0
    mean_count: NonNeg = 0.0
    appearance: AppearanceParams | None = None
    tables: MeasurementTables | None = None
    th_match: Positive = 15.0

    @model_validator(mode="after")
    def _one_source(self) -> ObjectType:
        if self.appearance is not None and self.tables is not None:
            raise ValueError("give appearance or tables, not both")
        return self


class CandidateIn(BaseModel):
    """A candidate object found by colour (§4.1), with its orientation belief if one is
    known (else uniform)."""

    model_config = ConfigDict(extra="forbid")
    id: str = Field(pattern=ID_PATTERN)
    type: str = Field(min_length=1)
    x: FiniteFloat
    y: FiniteFloat
    belief: list[Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]] | None = Field(
        None, description="orientation belief P(theta_i) over N_theta orientations")


class PlanRequest(BaseModel):
    """Everything one planning step needs but the grid (paper §§3-6): the robot and the
    exit, the loss and its time limit, the motion and verification times of eqs. 5-10,
    the value per unknown area of eq. 17, the object types and the candidates, and how
    the global plan is searched."""

    model_config = ConfigDict(extra="forbid")
    robot: tuple[FiniteFloat, FiniteFloat, FiniteFloat] = Field(
        description="robot pose (x, y, theta), m and rad")
    exit: tuple[FiniteFloat, FiniteFloat] = Field(description="the room's exit O (eq. 18)")
    time_limit_s: NonNeg = 60.0
    loss: Literal["L1", "L2", "L3"] = "L2"
    k_lim: NonNeg = 0.5
    speed_m_s: Positive = 0.4
    t_verify_s: NonNeg = 2.0
    t_search_s: NonNeg = Field(5.0, description="t_sea of eq. 9")
    t_dist_s: NonNeg = Field(3.0, description="t_dist of eq. 10")
    k_area: NonNeg = Field(5.0, description="value per m2 of mapped unknown area (eq. 17)")
    min_area_m2: NonNeg | None = Field(None, description="unknown components this large "
                                       "are groups; null: the world's parameter "
                                       "unknown_region_min_area_m2 (0.5 m² by default)")
    clearance_m: NonNeg = 0.25
    object_types: Sequence[ObjectType] = []
    candidates: Sequence[CandidateIn] = []
    use_table: bool = Field(True, description="eq. 6's pattern tables (else exact eq. 5)")
    travel: Literal["geodesic", "straight"] = Field(
        "geodesic", description="travel between the robot, the groups' entry points and "
                                "the exit: shortest paths around obstacles on the grid, or "
                                "straight lines (the paper's eqs. 18-20)")
    solver: Literal["auto", "dp", "bnb", "exhaustive"] = Field(
        "auto", description="global plan: exact DP over subsets (at most 20 groups), branch "
                            "and bound (exact, or its gap when the time budget runs out), "
                            "the paper's exhaustive search (at most 9 groups), or auto: DP "
                            "up to 16 groups, else branch and bound")
    time_budget_s: float = Field(1.0, gt=0, le=60, allow_inf_nan=False,
                                 description="branch and bound stops here and reports "
                                             "its gap")
    runner_ups: int = Field(5, ge=0, le=50)

    @model_validator(mode="after")
    def _consistent(self) -> PlanRequest:
        names = [t.name for t in self.object_types]
        for i, n in enumerate(names):
            if n in names[:i]:
                raise ValueError(f"object_types[{i}].name {n!r} is not unique")
        ids = [c.id for c in self.candidates]
        for i, c in enumerate(ids):
            if c in ids[:i]:
                raise ValueError(f"candidates[{i}].id {c!r} is not unique")
        return self

    def loss_function(self) -> Loss:
        return Loss(kind=self.loss, t_limit_s=self.time_limit_s, k_lim=self.k_lim)


@dataclass(frozen=True)
class GroupSpec:
    """A group as the grouping rules decided it: id, ``objects``/``unknown``, members
    (candidate ids, or the unknown component's label)."""

    id: int
    kind: str
    members: tuple[str | int, ...]


#: (candidates [{id, type, x, y, r_max}], regions [{id, x, y, area_m2}], min_area_m2 or
#: None for the world's parameter)
#: -> groups; the service's implementation asks the Prolog rules (prolog/grouping.pl).
Grouper = Callable[[list[dict[str, object]], list[dict[str, object]], float | None],
                   list[GroupSpec]]


@dataclass(frozen=True)
class PlannedGroup:
    """A group with its value (eqs. 16-17), observation time and entry points."""

    spec: GroupSpec
    name: str
    value: float
    t_obs: float
    entries: np.ndarray
    local: LocalPlan | None = None
    area_m2: float | None = None
    centroid: np.ndarray | None = None


@dataclass
class Prepared:
    """Step 1's result (:meth:`ViewpointPlanner.prepare`): the candidates, the grid's
    unknown components, what the grouping is asked, and the time it took."""

    cands: dict[str, Candidate]
    comps: dict[int, UnknownComponent]
    group_args: tuple[list[dict[str, Any]], list[dict[str, Any]], float | None]
    prepare_ms: float


@dataclass
class PlanReport:
    """The planner's answer: groups, the best plan first, then the runner-ups."""

    groups: list[PlannedGroup]
    plans: list[Plan]
    skipped: list[PlannedGroup] = field(default_factory=list)
    solution: Solution | None = None
    timings_ms: dict[str, float] = field(default_factory=dict)
    tables_built: int = 0
    tables_reused: int = 0
    steps_of: Callable[[Plan], list[PlanStep]] | None = None
    _steps: dict[tuple[int, ...], list[PlanStep]] = field(default_factory=dict)

    def names(self, plan: Plan) -> list[str]:
        return [self.groups[i].name for i in plan.order]

    def steps(self, plan: Plan) -> list[PlanStep]:
        """What the robot does for each group of ``plan``, in order (:func:`plan_steps`;
        computed once per plan)."""
        if self.steps_of is None:
            return []
        if plan.order not in self._steps:
            self._steps[plan.order] = self.steps_of(plan)
        return self._steps[plan.order]


@dataclass(frozen=True)
class PlanStep:
    """One step of a plan a robot can execute: the group, the pose to go to first (a
    viewpoint of the first object to verify, the joint viewpoint of an observe-all group,
    or the entry point of an unknown region), facing the object / group / region; the
    travel to it from the previous step (along the grid's shortest path, or straight),
    the expected verification (or search) time of the group, the chance that the first
    observation there recognises its object (None for unknown regions), and the expected
    time when the group is done."""

    group_id: int
    name: str
    kind: str
    pose: tuple[float, float, float]
    travel_m: float
    travel_s: float
    observe_s: float
    p_recog: float | None
    done_at_s: float


def group_name(i: int) -> str:
    return "G_" + (chr(ord("A") + i) if i < 26 else str(i))


def resolve_models(types: Sequence[ObjectType], seed: int = 0,
                   ) -> dict[str, AppearanceModel]:
    """One appearance model per object type: given parameters, a fit to the given tables,
    or the simulator's fit for a built-in type."""
    out: dict[str, AppearanceModel] = {}
    builtin: dict[str, AppearanceModel] | None = None
    for i, t in enumerate(types):
        if t.appearance is not None:
            out[t.name] = AppearanceModel(t.appearance)
        elif t.tables is not None:
            try:
                out[t.name] = AppearanceModel.fit(t.tables, t.th_match)[0]
            except InvalidInput as e:
                raise InvalidInput(str(e), field=f"object_types[{i}].{e.field}") from None
        elif t.name in OBJECT_KINDS:
            builtin = builtin or fitted_models(seed=seed)
            out[t.name] = builtin[t.name]
        else:
            raise InvalidInput(f"object type {t.name!r} is not built in (A, B, C): give its "
                               "appearance or measurement tables", field=f"object_types[{i}]")
    return out


class LocalPlanCache:
    """The object groups' local plans (t_seq / t_par, entry points) across re-plans.

    A group's local plan depends on its members (ids, types, positions, beliefs), their
    appearance models, the robot's speed, t_verify and clearance, and the grid only near
    the group: its viewpoints lie within R_max of a member and every test of them (free
    cells, clearance, lines of sight) stays inside that box. The key holds a digest of
    that patch of the grid, so a re-plan recomputes only the groups whose surroundings
    the robot's new scans changed (or whose beliefs an observation updated)."""

    def __init__(self, max_entries: int = 4096) -> None:
        self.plans: dict[bytes, tuple[np.ndarray, LocalPlan | None, tuple[str, ...]]] = {}
        self.max_entries = max_entries
        self.hits = 0
        self.misses = 0

    @staticmethod
    def key(members: Sequence[Candidate], grid: PlanningGrid, verifier: Verifier) -> bytes:
        h = hashlib.blake2b(digest_size=20)
        reach = 0.0
        for c in sorted(members, key=lambda c: c.id):
            h.update(c.id.encode())
            h.update(c.type.encode())
            h.update(np.asarray(c.xy, float).tobytes())
            h.update(b"-" if c.belief is None else np.asarray(c.belief, float).tobytes())
            h.update(c.model.params.model_dump_json().encode())
            reach = max(reach, c.model.r_max)
        h.update(np.array([verifier.speed, verifier.t_verify, verifier.clearance,
                           float(verifier.use_table)]).tobytes())
        xy = np.array([c.xy for c in members])
        pad = reach + verifier.clearance + 2 * grid.resolution
        # the box in cells (a box past the grid's edge keeps the part inside)
        lo = np.floor((xy.min(axis=0) - pad - grid.grid.origin) / grid.resolution).astype(int)
        hi = np.floor((xy.max(axis=0) + pad - grid.grid.origin) / grid.resolution).astype(int)
        h.update(grid.digest(lo, hi))
        return h.digest()

    def get(self, key: bytes) -> tuple[np.ndarray, LocalPlan | None, tuple[str, ...]] | None:
        hit = self.plans.get(key)
        if hit is None:
            self.misses += 1
        else:
            self.hits += 1
        return hit

    def put(self, key: bytes, value: tuple[np.ndarray, LocalPlan | None, tuple[str, ...]]
            ) -> None:
        if len(self.plans) >= self.max_entries:
            self.plans.pop(next(iter(self.plans)))
        self.plans[key] = value


class ViewpointPlanner:
    """Plans with one grid; keeps the pattern tables and the groups' local plans across
    calls (re-planning)."""

    def __init__(self, tables: TableCache | None = None) -> None:
        self.tables = tables if tables is not None else TableCache()
        self.local_plans = LocalPlanCache()
        self.viewpoint_sets: dict[bytes, ViewpointSet] = {}
        self.unknown_times: dict[tuple[object, ...], float] = {}
        self._travel: tuple[bytes, TravelMap, dict[bytes, np.ndarray]] | None = None

    def travel(self, grid: PlanningGrid) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
        """Geodesic distances on ``grid``; the travel map and its distance fields are kept
        while the grid stays the same (the online loop re-plans on an unchanged map
        after every observation of an object)."""
        key = grid.digest()
        if self._travel is None or self._travel[0] != key:
            self._travel = (key, TravelMap(grid), {})
        return geodesic(self._travel[1], self._travel[2])

    def models(self, req: PlanRequest) -> dict[str, AppearanceModel]:
        """The request's own models: a type's appearance comes from this request only
        (the built-in fits are cached by :func:`fitted_models`)."""
        return resolve_models(req.object_types)

    def plan(self, req: PlanRequest, grid: PlanningGrid, grouper: Grouper,
             beliefs: dict[str, np.ndarray] | None = None) -> PlanReport:
        """The paper's pipeline (Masuzawa & Miura, §§4-6) in its four steps:
        :meth:`candidates` (the objects to verify with their appearance models and the
        grid's unknown regions), :meth:`group` (observation groups, by the Prolog
        rules), :meth:`value_and_verify` (each group's expected verification time,
        eqs. 5-10, and value, eqs. 15-17) and :meth:`solve` (the ordered plan
        maximising U = V - L(t), eq. 11). ``beliefs`` replace candidates' orientation
        beliefs (the online loop's updates). The service runs it as :meth:`prepare`,
        the grouping, and :meth:`finish`, the numeric parts in a worker process."""
        prep = self.prepare(req, grid, beliefs)
        t0 = time.perf_counter()
        specs = grouper(*prep.group_args)
        return self.finish(req, grid, prep, specs, 1e3 * (time.perf_counter() - t0))

    def prepare(self, req: PlanRequest, grid: PlanningGrid,
                beliefs: dict[str, np.ndarray] | None = None) -> Prepared:
        """Step 1 (:meth:`candidates`) and what step 2's grouping is asked. The robot
        and the exit must stand on the grid (else :class:`InvalidInput` naming them)."""
        t0 = time.perf_counter()
        for name, xy in (("robot", req.robot[:2]), ("exit", req.exit)):
            if not grid.covers(np.asarray(xy, dtype=float)):
                lo, hi = grid.bounds()
                raise InvalidInput(
                    f"the {name} at ({xy[0]:.6g}, {xy[1]:.6g}) m is off the planning grid, "
                    f"which covers x {lo[0]:.2f} to {hi[0]:.2f} m, y {lo[1]:.2f} to "
                    f"{hi[1]:.2f} m", field=name)
        cands, comps = self.candidates(req, grid, beliefs)
        return Prepared(cands, comps, self.group_args(req, cands, comps),
                        1e3 * (time.perf_counter() - t0))

    def finish(self, req: PlanRequest, grid: PlanningGrid, prep: Prepared,
               specs: list[GroupSpec], grouping_ms: float = 0.0) -> PlanReport:
        """Steps 3 and 4 (:meth:`value_and_verify`, :meth:`solve`) for the groups."""
        cands, comps = prep.cands, prep.comps
        t2 = time.perf_counter()
        verifier = Verifier(grid, req.speed_m_s, req.t_verify_s, req.clearance_m,
                            req.use_table, self.tables, self.viewpoint_sets)
        builds, hits = self.tables.builds, self.tables.hits
        planned, skipped = self.value_and_verify(req, grid, specs, cands, comps, verifier)
        t3 = time.perf_counter()
        solution, distance = self.solve(req, grid, planned)
        t4 = time.perf_counter()
        robot, exit_ = np.asarray(req.robot, float), np.asarray(req.exit, float)

        def steps_of(plan: Plan) -> list[PlanStep]:
            return plan_steps(plan, planned, cands, verifier, robot, exit_, req.speed_m_s,
                              distance)

        local, glob = 1e3 * (t3 - t2), 1e3 * (t4 - t3)
        return PlanReport(planned, solution.plans, skipped, solution,
                          {"prepare": prep.prepare_ms, "grouping": grouping_ms,
                           "local": local, "global": glob,
                           "total": prep.prepare_ms + grouping_ms + local + glob},
                          self.tables.builds - builds, self.tables.hits - hits, steps_of)

    def candidates(self, req: PlanRequest, grid: PlanningGrid,
                   beliefs: dict[str, np.ndarray] | None = None,
                   ) -> tuple[dict[str, Candidate], dict[int, UnknownComponent]]:
        """Step 1 (§4.1): the candidate objects with their type's appearance model (§3)
        and orientation belief, and the grid's unknown components by label."""
        models = self.models(req)
        cands: dict[str, Candidate] = {}
        for i, c in enumerate(req.candidates):
            if c.type not in models:
                raise InvalidInput(f"candidate type {c.type!r} is not among object_types",
                                   field=f"candidates[{i}].type")
            m = models[c.type]
            belief = None
            if c.belief is not None:
                b = np.asarray(c.belief, dtype=float)
                if len(b) != m.n_theta or b.sum() <= 0:
                    raise InvalidInput(f"belief needs {m.n_theta} probabilities, not all 0",
                                       field=f"candidates[{i}].belief")
                belief = b / b.sum()
            if beliefs and c.id in beliefs:
                belief = beliefs[c.id]
            cands[c.id] = Candidate(c.id, c.type, np.array([c.x, c.y]), m, belief)
        return cands, {c.label: c for c in grid.unknown_components()}

    @staticmethod
    def group_args(req: PlanRequest, cands: dict[str, Candidate],
                   comps: dict[int, UnknownComponent]
                   ) -> tuple[list[dict[str, Any]], list[dict[str, Any]], float | None]:
        """Step 2 (§4.2) is asked: observation groups -- candidates that one look can
        verify together, and each unknown region large enough -- are decided by a
        :data:`Grouper` (the Prolog rules of prolog/grouping.pl in the service) from
        these candidates (with R_max), regions and minimum area."""
        return ([{"id": c.id, "type": c.type, "x": float(c.xy[0]), "y": float(c.xy[1]),
                  "r_max": max(c.model.r_max, 1e-3)} for c in cands.values()],
                [{"id": k, "x": float(c.centroid[0]), "y": float(c.centroid[1]),
                  "area_m2": c.area_m2} for k, c in comps.items()],
                req.min_area_m2)

    def value_and_verify(self, req: PlanRequest, grid: PlanningGrid, specs: list[GroupSpec],
                         cands: dict[str, Candidate], comps: dict[int, UnknownComponent],
                         verifier: Verifier,
                         ) -> tuple[list[PlannedGroup], list[PlannedGroup]]:
        """Step 3 (§§5-6.1): every group's expected verification time and value -- an
        object group by its best local plan (t_single, t_seq or t_par, eqs. 5-8) and
        the sum of its objects' values; an unknown region by the search time of eqs.
        9-10 from its nearest entry point and eq. 17's value. Returns the groups to
        plan with and the ones that cannot be verified (boxed-in objects, walled-in
        regions)."""
        types = {t.name: t for t in req.object_types}
        models = self.models(req)
        unknown_total = sum(comps[int(s.members[0])].area_m2 for s in specs
                            if s.kind == "unknown")
        planned: list[PlannedGroup] = []
        skipped: list[PlannedGroup] = []
        for spec in specs:
            name = group_name(spec.id)
            if spec.kind == "objects":
                members = [cands[str(m)] for m in spec.members]
                key = LocalPlanCache.key(members, grid, verifier)
                cached = self.local_plans.get(key)
                if cached is None:
                    cached = local_plan(verifier, members)
                    self.local_plans.put(key, cached)
                entries, best_plan, lost = cached
                if lost:  # unverifiable on their own; the rest of the group is not
                    skipped.append(PlannedGroup(GroupSpec(spec.id, "objects", lost), name,
                                                0.0, np.inf, np.zeros((0, 2))))
                    members = [c for c in members if c.id not in lost]
                    if not members:
                        continue
                    spec = GroupSpec(spec.id, spec.kind, tuple(c.id for c in members))
                value = float(sum(types[c.type].value for c in members))
                if best_plan is None:
                    skipped.append(PlannedGroup(spec, name, 0.0, np.inf, entries))
                    continue
                g = PlannedGroup(spec, name, value, best_plan.time_s, entries, best_plan)
            else:
                comp = comps[int(spec.members[0])]
                entries = _thin(comp.entries)
                if len(entries) == 0:  # walled in: no free cell to explore it from
                    skipped.append(PlannedGroup(spec, name, 0.0, np.inf, entries, None,
                                                comp.area_m2, comp.centroid))
                    continue
                t_u = self._unknown_time(req, models, verifier, comp, entries, unknown_total)
                share = comp.area_m2 / unknown_total if unknown_total > 0 else 0.0
                value = req.k_area * comp.area_m2 + share * sum(
                    t.mean_count * t.value for t in req.object_types)  # eq. 17
                g = PlannedGroup(spec, name, value, t_u, entries, None, comp.area_m2,
                                 comp.centroid)
            (planned if np.isfinite(g.t_obs) and len(g.entries) else skipped).append(g)
        return planned, skipped

    def _unknown_time(self, req: PlanRequest, models: dict[str, AppearanceModel],
                      verifier: Verifier, comp: UnknownComponent, entries: np.ndarray,
                      unknown_total: float) -> float:
        """Eqs. 9-10 for one region from its entry point nearest the centroid; they do not
        look at the grid, so the same region, entry point and parameters give the same
        time (re-plans ask again and again): cached."""
        mean_counts = {t.name: t.mean_count for t in req.object_types}
        e = entries[np.argmin(np.hypot(*(entries - comp.centroid).T))]
        ukey = (tuple(np.round(comp.centroid, 9)), tuple(np.round(e, 9)),
                comp.area_m2, unknown_total, req.t_search_s, req.t_dist_s,
                req.speed_m_s, req.t_verify_s, req.clearance_m, req.use_table,
                tuple(sorted((k, m.params.model_dump_json()) for k, m in models.items())),
                tuple(sorted(mean_counts.items())))
        t_u = self.unknown_times.get(ukey)
        if t_u is None:
            t_u = unknown_region_time(verifier, models, mean_counts, comp.centroid, e,
                                      comp.area_m2, unknown_total, req.t_search_s,
                                      req.t_dist_s)
            if len(self.unknown_times) > 4096:
                self.unknown_times.clear()
            self.unknown_times[ukey] = t_u
        return t_u

    def solve(self, req: PlanRequest, grid: PlanningGrid, planned: list[PlannedGroup],
              ) -> tuple[Solution, Callable[[np.ndarray, np.ndarray], np.ndarray]]:
        """Step 4 (§6, eq. 11): the ordered subset of groups maximising U = V - L(t) under
        the request's loss, travel along the grid (geodesic) or straight; exact by DP
        up to MAX_GROUPS_EXACT groups, by branch and bound beyond (solve_auto). Returns
        the solution and the travel distance it used."""
        costs = [GroupCost(g.name, g.spec.kind, g.value, g.t_obs, g.entries) for g in planned]
        robot, exit_ = np.asarray(req.robot, float), np.asarray(req.exit, float)
        distance = self.travel(grid) if req.travel == "geodesic" else straight
        problem = Problem.with_travel(costs, robot, exit_, req.speed_m_s,
                                      req.loss_function(), distance)
        if req.solver == "exhaustive" and problem.n > EXHAUSTIVE_MAX_GROUPS:
            raise InvalidInput(f"{problem.n} groups: the exhaustive solver is limited to "
                               f"{EXHAUSTIVE_MAX_GROUPS}; use solver 'auto'", field="solver")
        if req.solver == "dp" and problem.n > MAX_GROUPS_EXACT:
            raise InvalidInput(f"{problem.n} groups: the DP solver handles at most "
                               f"{MAX_GROUPS_EXACT}; use solver 'auto' or 'bnb'",
                               field="solver")
        return solve_auto(problem, req.runner_ups, req.time_budget_s, req.solver), distance


def local_plan(verifier: Verifier, members: list[Candidate]
               ) -> tuple[np.ndarray, LocalPlan | None, tuple[str, ...]]:
    """A group's entry points, its best local plan (§5: t_single, t_seq or t_par) and
    the members no usable viewpoint recognises (boxed in by walls or by their
    neighbours): those are unverifiable on their own and the plan is for the rest."""
    seen = [bool(np.isfinite(verifier.single(c, c.xy[None], c.xy[None])[0, 0]))
            for c in members]
    lost = tuple(c.id for c, ok in zip(members, seen, strict=True) if not ok)
    members = [c for c, ok in zip(members, seen, strict=True) if ok]
    if not members:
        return np.zeros((0, 2)), None, lost
    entries = np.vstack([verifier.viewpoints(c).entries for c in members])
    if len(entries) == 0:
        return entries, None, lost
    entries = _thin(entries)
    return entries, verifier.best(members, entries, entries), lost


def plan_steps(plan: Plan, groups: list[PlannedGroup], cands: dict[str, Candidate],
               verifier: Verifier, robot: np.ndarray, exit_xy: np.ndarray, speed: float,
               distance: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> list[PlanStep]:
    """The executable steps of ``plan`` (:class:`PlanStep`). The first pose of an object
    group is where the verification policy of eq. 5 would look first from where the
    robot stands (re-planning after each observation refines the rest)."""
    at = np.asarray(robot, float)[:2]
    clock = 0.0
    out = []
    for i in plan.order:
        g = groups[i]
        p_first: float | None = None
        if g.spec.kind == "objects" and g.local is not None:
            members = [cands[str(m)] for m in (g.local.order or g.spec.members)]
            if g.local.strategy == "par" and g.local.joint_point is not None:
                xy = np.asarray(g.local.joint_point, float)
                target = np.mean([c.xy for c in members], axis=0)
                p_first = float(np.mean([c.model.p_recog(xy[None], c.xy, c.prior())[0]
                                         for c in members]))
            else:
                first = members[0]
                vp = verifier.next_viewpoint(first, at, np.asarray(exit_xy, float)[:2])
                xy = vp if vp is not None else g.entries[0]
                target = first.xy
                p_first = float(first.model.p_recog(xy[None], first.xy, first.prior())[0])
        else:
            xy = g.entries[int(np.argmin(distance(at, g.entries)))]
            target = g.centroid if g.centroid is not None else xy
        d = float(distance(at, xy[None])[0])
        heading = float(np.arctan2(target[1] - xy[1], target[0] - xy[0]))
        clock += d / speed + g.t_obs
        out.append(PlanStep(g.spec.id, g.name, g.spec.kind,
                            (float(xy[0]), float(xy[1]), heading), d, d / speed, g.t_obs,
                            p_first, clock))
        at = xy
    return out


def geodesic(travel: TravelMap, fields: dict[bytes, np.ndarray] | None = None
             ) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """Shortest-path distance from the nearest of some sources to targets, one distance
    field per source set (a group's entry points, the robot); ``fields`` may carry them
    over from earlier calls on the same grid."""
    fields = {} if fields is None else fields

    def distance(sources: np.ndarray, targets: np.ndarray) -> np.ndarray:
        src = np.ascontiguousarray(np.atleast_2d(sources), dtype=float)
        key = src.tobytes()
        if key not in fields:
            fields[key] = travel.field(src)
        return travel.distances(fields[key], src, targets)

    return distance


def _thin(points: np.ndarray, at_most: int = MAX_ENTRIES) -> np.ndarray:
    if len(points) <= at_most:
        return points
    return points[np.linspace(0, len(points) - 1, at_most).astype(int)]
