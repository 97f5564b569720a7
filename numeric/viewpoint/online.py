"""The online summarisation loop (Masuzawa & Miura, §7.3, Fig. 2) in the simulator.

The robot enters the room at its door with a time limit. It looks around (laser scans
in four directions; the map trusts odometry, §4.1) and detects candidate objects by
colour -- every object in line of sight within the camera's range, at a stereo-noisy
position, plus the occasional false candidate. Then, until the plan is to leave:

1. plan (groups by the Prolog rules, local times §5, global plan §6) with the time left;
2. execute the plan's first group -- verify its candidates (move to the best viewpoint
   of eq. 5 for the current belief, observe, update the belief by eqs. 1-2, repeat until
   recognised or no viewpoint can recognise it any more), or go to an unknown region's
   entry point and scan it;
3. update the map and the candidates, and re-plan.

Travel follows the shortest path on the current grid (skimage's minimum-cost path, the
same costs as the planner's geodesic estimates). Under L1 the time limit is hard and the
plan's times are expectations, so the execution is monitored: a look, a joint
observation or a search is started only if the robot can still reach the door in time
after it; otherwise that candidate or region is left and the robot re-plans. A search
that reveals less than ``min_area_m2`` of its region gives the rest up (nothing more is
visible from where the robot can stand). Every step is logged.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from skimage.graph import MCP_Geometric

from chizu.numeric.geometry import line_of_sight
from chizu.numeric.occupancy import FREE, UNKNOWN
from chizu.numeric.viewpoint.appearance import AppearanceModel
from chizu.numeric.viewpoint.grid import PlanningGrid, look_around, scanned_grid, travel_cost
from chizu.numeric.viewpoint.planner import (
    CandidateIn,
    Grouper,
    ObjectType,
    PlannedGroup,
    PlanReport,
    PlanRequest,
    ViewpointPlanner,
)
from chizu.numeric.viewpoint.recognition import Recogniser
from chizu.numeric.viewpoint.verification import Candidate, Verifier
from chizu.numeric.world import World


class SummaryConfig(BaseModel):
    """The run's settings; the planner's parameters as in :class:`PlanRequest`. The
    verification and search times default to a slow robot like the paper's humanoid
    (stop, pan the head, stereo, SIFT): 6 s per look, 12 s to map a region."""

    model_config = ConfigDict(extra="forbid")
    time_limit_s: float = Field(55.0, ge=0)
    loss: str = Field("L2", pattern="^L[123]$")
    k_lim: float = Field(0.5, ge=0)
    speed_m_s: float = Field(0.4, gt=0)
    t_verify_s: float = Field(6.0, ge=0)
    t_search_s: float = Field(12.0, ge=0)
    t_dist_s: float = Field(3.0, ge=0)
    k_area: float = Field(5.0, ge=0)
    min_area_m2: float = Field(1.0, ge=0)
    detect_range_m: float = Field(5.0, gt=0)
    position_noise: float = Field(0.03, ge=0, description="stereo noise per metre of range")
    false_candidates: int = Field(1, ge=0, le=10)
    max_steps: int = Field(30, ge=1, le=500)
    travel: str = Field("geodesic", pattern="^(geodesic|straight)$",
                        description="the planner's travel estimate (PlanRequest.travel)")
    seed: int = 0


@dataclass
class LogEntry:
    step: int
    t_s: float
    action: str
    detail: dict[str, Any]


@dataclass
class SummaryRun:
    """What the robot did and found."""

    path: list[np.ndarray]
    log: list[LogEntry]
    verified: dict[str, np.ndarray]
    rejected: dict[str, np.ndarray]
    unverified: dict[str, np.ndarray]
    grid: PlanningGrid
    elapsed_s: float
    plans: list[list[str]] = field(default_factory=list)

    def summary(self, world: World) -> dict[str, Any]:
        truth = {o.id for o in world.description.objects}
        room = self.grid.room if self.grid.room is not None else np.ones_like(self.grid.state, bool)
        known = int(np.count_nonzero(room & (self.grid.state != -1)))
        cells = max(int(np.count_nonzero(room)), 1)
        return {"elapsed_s": self.elapsed_s, "verified": sorted(self.verified),
                "rejected": sorted(self.rejected), "unverified": sorted(self.unverified),
                "objects_in_world": len(truth),
                "objects_verified": len(truth & set(self.verified)),
                "explored_fraction": known / cells,
                "steps": len(self.plans)}


@dataclass
class _Run:
    """What the robot knows and has done so far in one run: its pose and clock, the scans
    and the map they make, the unknown cells given up, the candidates (id -> type and
    estimated position), their beliefs and outcomes, and the record."""

    pose: np.ndarray
    scans: np.ndarray
    grid: PlanningGrid
    #: unknown cells a search could not see into: not a region to explore again
    given_up: np.ndarray
    on_step: Callable[[LogEntry], None] | None
    t: float = 0.0
    cands: dict[str, tuple[str, np.ndarray]] = field(default_factory=dict)
    beliefs: dict[str, np.ndarray] = field(default_factory=dict)
    verified: dict[str, np.ndarray] = field(default_factory=dict)
    rejected: dict[str, np.ndarray] = field(default_factory=dict)
    out_of_time: set[str] = field(default_factory=set)
    path: list[np.ndarray] = field(default_factory=list)
    log: list[LogEntry] = field(default_factory=list)
    plans: list[list[str]] = field(default_factory=list)

    def record(self, action: str, **detail: Any) -> None:
        e = LogEntry(len(self.plans), self.t, action, detail)
        self.log.append(e)
        if self.on_step:
            self.on_step(e)

    def open_ids(self) -> list[str]:
        """The candidates still to verify: not verified, rejected or left for lack of
        time."""
        return [c for c in self.cands if c not in self.verified and c not in self.rejected
                and c not in self.out_of_time]

    def mask_given_up(self) -> None:
        """Take the given-up unknown cells out of the room mask: not a region to plan
        for again."""
        room = self.grid.room if self.grid.room is not None else np.ones_like(self.given_up)
        self.grid = PlanningGrid(self.grid.grid, room & ~self.given_up)

    def result(self) -> SummaryRun:
        unverified = {c: v[1] for c, v in self.cands.items()
                      if c not in self.verified and c not in self.rejected}
        return SummaryRun(self.path, self.log, {k: self.cands[k][1] for k in self.verified},
                          self.rejected, unverified, self.grid, self.t, self.plans)


class Summariser:
    """Runs the loop for one world; ``grouper`` is the Prolog grouping (see the service)."""

    def __init__(self, world: World, object_types: list[ObjectType], grouper: Grouper,
                 config: SummaryConfig, door: np.ndarray,
                 planner: ViewpointPlanner | None = None,
                 area: tuple[tuple[float, float], tuple[float, float]] | None = None) -> None:
        """``area``: the room's lower and upper corner when the world holds more than the
        room (an office floor): the room mask keeps only the cells inside it, so the plan
        explores this room, not the building."""
        self.world = world
        self.area = area
        self._within: np.ndarray | None = None  # the area's cells (every grid: one frame)
        self.types = object_types
        self.grouper = grouper
        self.cfg = config
        self.door = np.asarray(door, float)
        self.planner = planner or ViewpointPlanner()
        self.rng = np.random.default_rng(config.seed)
        self.recogniser = Recogniser(world, th_match=15.0)
        self.truth = {o.id: o for o in world.description.objects}

    # -- sensing ----------------------------------------------------------------------
    def _detect(self, xy: np.ndarray, cands: dict[str, tuple[str, np.ndarray]]) -> list[str]:
        """Colour detection from ``xy``: objects in line of sight and range (§4.1)."""
        new = []
        w = self.world
        for o in w.description.objects:
            if o.id in cands or o.type not in {t.name for t in self.types}:
                continue
            c = np.array([o.x, o.y])
            d = float(np.hypot(*(c - xy)))
            # the line may graze the object's own faces: test against the walls only
            if d > self.cfg.detect_range_m or not line_of_sight(xy, c[None], w.wall_a,
                                                                w.wall_b)[0]:
                continue
            est = c + self.rng.normal(0, self.cfg.position_noise * d, 2)
            cands[o.id] = (o.type, est)
            new.append(o.id)
        return new

    def detect(self, xy: np.ndarray) -> dict[str, tuple[str, np.ndarray]]:
        """The candidates colour detection finds from ``xy``: id -> (type, position)."""
        cands: dict[str, tuple[str, np.ndarray]] = {}
        self._detect(np.asarray(xy, dtype=float), cands)
        return cands

    def _false_candidates(self, grid: PlanningGrid, cands: dict[str, tuple[str, np.ndarray]],
                          ) -> None:
        free = np.argwhere((grid.state == FREE) & (grid.clearance > 0.8))
        for k in range(self.cfg.false_candidates):
            if len(free) == 0:
                return
            i, j = free[self.rng.integers(len(free))]
            cands[f"false{k + 1}"] = (self.types[k % len(self.types)].name,
                                      grid.centres(np.array(i), np.array(j)))

    def _scanned(self, scans: np.ndarray) -> PlanningGrid:
        """The grid of the scans so far (:func:`scanned_grid`), within :attr:`area`."""
        grid = scanned_grid(self.world, scans)
        if self.area is None:
            return grid
        if self._within is None or self._within.shape != grid.state.shape:
            (x0, y0), (x1, y1) = self.area
            i, j = np.indices(grid.state.shape)
            c = grid.centres(i.ravel(), j.ravel())
            self._within = ((c[:, 0] >= x0) & (c[:, 0] <= x1) & (c[:, 1] >= y0)
                            & (c[:, 1] <= y1)).reshape(grid.state.shape)
        room = grid.room if grid.room is not None else np.ones_like(self._within)
        return PlanningGrid(grid.grid, room & self._within)

    # -- motion -----------------------------------------------------------------------
    def _route(self, grid: PlanningGrid, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Shortest path a -> b on the grid (the planner's travel costs,
        :func:`chizu.numeric.viewpoint.grid.travel_cost`); a straight line if none."""
        cost = travel_cost(grid)
        ia, ja, ina = grid.cells(a)
        ib, jb, inb = grid.cells(b)
        if not (ina and inb):
            return np.array([a, b])
        cost[ia, ja] = cost[ib, jb] = 1.0
        mcp = MCP_Geometric(cost)
        costs, _ = mcp.find_costs([(int(ia), int(ja))], [(int(ib), int(jb))])
        if not np.isfinite(costs[ib, jb]):
            return np.array([a, b])
        cells = np.array(mcp.traceback((int(ib), int(jb))))
        pts = grid.centres(cells[:, 0], cells[:, 1])
        return np.vstack([a, pts[1:-1], b]) if len(pts) > 2 else np.array([a, b])

    # -- the loop (Fig. 2) ------------------------------------------------------------
    def run(self, on_step: Callable[[LogEntry], None] | None = None) -> SummaryRun:
        """Enter, then plan and execute the plan's first group until the plan is to leave
        (or ``max_steps`` plans); ``on_step`` sees every log entry as it is made."""
        run = self._enter(on_step)
        for _ in range(self.cfg.max_steps):
            req = self._request(run)
            report: PlanReport = self.planner.plan(req, run.grid, self.grouper, run.beliefs)
            best = report.plans[0]
            names = report.names(best)
            run.plans.append(names)
            run.record("plan", plan=names, utility=best.utility, expected_time_s=best.time,
                       time_left_s=req.time_limit_s,
                       groups={g.name: list(map(str, g.spec.members)) for g in report.groups})
            if not best.order:
                break
            g = report.groups[best.order[0]]
            if g.spec.kind == "unknown":
                self._explore(run, g)
            else:
                self._verify_group(run, g, req)
        self._move(run, self.door)
        run.record("leave", elapsed_s=run.t, verified=sorted(run.verified))
        return run.result()

    def _enter(self, on_step: Callable[[LogEntry], None] | None) -> _Run:
        """At the door: look around (four scans), map, detect the candidates by colour
        (and the false ones)."""
        pose = np.array([*self.door, np.pi / 2])
        scans = look_around(self.door)
        grid = self._scanned(scans)
        run = _Run(pose, scans, grid, np.zeros(grid.state.shape, dtype=bool), on_step)
        self._detect(pose[:2], run.cands)
        self._false_candidates(run.grid, run.cands)
        run.path.append(pose[:2].copy())
        run.record("enter", candidates=sorted(run.cands), unknown_m2=run.grid.unknown_area())
        return run

    def _request(self, run: _Run) -> PlanRequest:
        """The plan request for the time left, from the robot's pose, over the open
        candidates."""
        cfg, cands = self.cfg, run.cands
        return PlanRequest(
            robot=tuple(run.pose), exit=tuple(self.door),  # type: ignore[arg-type]
            time_limit_s=max(cfg.time_limit_s - run.t, 0.0), loss=cfg.loss,  # type: ignore[arg-type]
            k_lim=cfg.k_lim, speed_m_s=cfg.speed_m_s, t_verify_s=cfg.t_verify_s,
            t_search_s=cfg.t_search_s, t_dist_s=cfg.t_dist_s, k_area=cfg.k_area,
            min_area_m2=cfg.min_area_m2, object_types=self.types,
            travel=cfg.travel,  # type: ignore[arg-type]
            candidates=[CandidateIn(id=c, type=cands[c][0], x=float(cands[c][1][0]),
                                    y=float(cands[c][1][1])) for c in run.open_ids()],
            runner_ups=2)

    # -- executing a group -------------------------------------------------------------
    def _move(self, run: _Run, to: np.ndarray) -> None:
        """Drive along the grid's shortest path to ``to``; the clock runs."""
        route = self._route(run.grid, run.pose[:2], to)
        run.t += float(np.sum(np.hypot(*np.diff(route, axis=0).T))) / self.cfg.speed_m_s
        run.path.extend(route[1:])
        run.pose = np.array([*to, run.pose[2]])

    def _length(self, run: _Run, a: np.ndarray, b: np.ndarray) -> float:
        route = self._route(run.grid, a, b)
        return float(np.sum(np.hypot(*np.diff(route, axis=0).T)))

    def _fits(self, run: _Run, to: np.ndarray, busy_s: float) -> bool:
        """L1's limit is hard: an action is taken only if the robot can still go there,
        spend ``busy_s`` and reach the door in time (the plan's times are expectations;
        this monitors the execution)."""
        cfg = self.cfg
        if cfg.loss != "L1":
            return True
        need = (self._length(run, run.pose[:2], to) + self._length(run, to, self.door)) \
            / cfg.speed_m_s + busy_s
        return run.t + need <= cfg.time_limit_s

    def _search_point(self, grid: PlanningGrid, g: PlannedGroup, xy: np.ndarray
                      ) -> np.ndarray:
        """Where to search an unknown region from: the free cell (0.25 m clear) nearest
        its entry point nearest ``xy``."""
        e = g.entries[np.argmin(np.hypot(*(g.entries - xy).T))]
        free = np.argwhere((grid.state == FREE) & (grid.clearance >= 0.25))
        if len(free):
            fc = grid.centres(free[:, 0], free[:, 1])
            e = fc[np.argmin(np.hypot(*(fc - e).T))]
        return np.asarray(e)

    def _explore(self, run: _Run, g: PlannedGroup) -> None:
        """Search an unknown region (§5.3): go to its entry point, look around, map and
        detect; a region the time limit leaves no room for is given up."""
        cfg = self.cfg
        assert g.centroid is not None
        e = self._search_point(run.grid, g, run.pose[:2])
        region = run.grid.unknown_labels[0] == int(g.spec.members[0])
        if not self._fits(run, e, cfg.t_search_s):
            run.given_up |= region
            run.mask_given_up()
            run.record("skip", group=g.name, reason="time limit")
            return
        self._move(run, e)
        run.scans = np.vstack([run.scans, look_around(e)])
        run.t += cfg.t_search_s
        run.grid = self._scanned(run.scans)
        found = self._detect(e, run.cands)
        # a search that revealed less than a region worth exploring gives the rest up:
        # from its reachable entry points nothing more can be seen, and searching it
        # again would spend t_sea for nothing
        still = region & (run.grid.state == UNKNOWN)
        revealed = float(region.sum() - still.sum()) * run.grid.resolution**2
        if revealed < cfg.min_area_m2:
            run.given_up |= still
        if run.given_up.any():
            run.mask_given_up()
        run.record("explore", group=g.name, at=e.tolist(), found=found,
                   unknown_m2=run.grid.unknown_area(), revealed_m2=revealed,
                   given_up=revealed < cfg.min_area_m2)

    def _verify_group(self, run: _Run, g: PlannedGroup, req: PlanRequest) -> None:
        """Verify an object group (§5): one joint observation first when its local plan
        is t_par (eq. 8) and it fits, then each member still open in the plan's order."""
        cfg = self.cfg
        verifier = Verifier(run.grid, cfg.speed_m_s, cfg.t_verify_s, req.clearance_m,
                            False, self.planner.tables)
        models = self.planner.models(req)
        members = [str(m) for m in (g.local.order if g.local else g.spec.members)]
        if (g.local is not None and g.local.strategy == "par" and g.local.joint_point
                and self._fits(run, np.array(g.local.joint_point),
                               cfg.t_verify_s * len(members))):
            jp = np.array(g.local.joint_point)
            self._move(run, jp)
            for cid in members:
                self._observe(run, cid, models)
            run.t += cfg.t_verify_s * len(members)
            run.record("observe_joint", group=g.name, at=jp.tolist(),
                       verified=[c for c in members if c in run.verified])
        for cid in members:
            self._verify_one(run, cid, verifier, models)

    def _verify_one(self, run: _Run, cid: str, verifier: Verifier,
                    models: dict[str, AppearanceModel]) -> None:
        """Eq. 5's policy, re-planned after every look: go to the best viewpoint for the
        current belief and observe, until the candidate is recognised, no viewpoint can
        recognise it any more (rejected), or the next look does not fit the limit."""
        while cid not in run.verified and cid not in run.rejected:
            kind, xy = run.cands[cid]
            c = Candidate(cid, kind, xy, models[kind], run.beliefs.get(cid))
            vp = verifier.next_viewpoint(c, run.pose[:2], self.door)
            if vp is None:
                run.rejected[cid] = xy
                run.record("reject", candidate=cid)
                return
            if not self._fits(run, vp, self.cfg.t_verify_s):
                run.out_of_time.add(cid)
                run.record("skip", candidate=cid, reason="time limit")
                return
            self._move(run, vp)
            run.t += self.cfg.t_verify_s
            ok = self._observe(run, cid, models)
            run.record("observe", candidate=cid, at=vp.tolist(), recognised=ok)
            if not ok and cid in run.beliefs and run.beliefs[cid].sum() == 0:
                run.rejected[cid] = xy
                run.record("reject", candidate=cid)

    def _observe(self, run: _Run, cid: str, models: dict[str, AppearanceModel]) -> bool:
        """Observe candidate ``cid`` from where the robot stands: matches from the
        simulated recogniser (none for a false candidate), belief update by eqs. 1-2 with
        the orientations this viewpoint would have recognised removed on a failure
        (eq. 4)."""
        xy = run.pose[:2]
        kind, est = run.cands[cid]
        model = models[kind]
        z = (self.recogniser.observe(xy, cid, self.rng) if cid in self.truth
             else np.zeros(4))
        if self.recogniser.recognised(z):
            run.verified[cid] = est
            return True
        b = model.posterior(z, xy, est, run.beliefs.get(cid))
        b = b * ~model.recognisable(xy[None, :], est)[0]
        run.beliefs[cid] = b / b.sum() if b.sum() > 0 else b
        return False
