"""Qualitative navigation: observations, reached landmarks, relations, DRM and paths."""

from typing import Annotated, Any

from fastapi import APIRouter, Query, Request, status

from chizu.numeric.errors import InvalidInput
from chizu.numeric.observation import Observation
from chizu.numeric.world import ID_PATTERN
from chizu.service.api.strict import StrictJsonRoute
from chizu.service.deps import WorldDep, WorldsDep
from chizu.service.disconnect import unless_disconnected
from chizu.service.kb import KbError
from chizu.service.schemas.qualitative import (
    DrmEdgeOut,
    DrmOut,
    ObservationOut,
    PathOut,
    QueryIn,
    QueryOut,
    ReachedIn,
    ReachedOut,
    RelationKind,
    RelationOut,
    StepOut,
)

router = APIRouter(prefix="/worlds/{world}", tags=["qualitative navigation"],
                   route_class=StrictJsonRoute)
LandmarkQ = Annotated[str, Query(pattern=ID_PATTERN)]


@router.post("/observations", response_model=ObservationOut,
             status_code=status.HTTP_201_CREATED)
async def post_observation(world: WorldDep, body: Observation, worlds: WorldsDep) -> Any:
    """One panoramic observation at landmark ``at``: bearings (robot frame, rad) and
    distances (m) become rec/frec facts and lr/align relations; the quantities are dropped."""
    return await worlds.observe(world, body)


@router.post("/reached", response_model=ReachedOut, status_code=status.HTTP_201_CREATED,
             response_model_by_alias=True)
async def post_reached(world: WorldDep, body: ReachedIn, worlds: WorldsDep) -> Any:
    """Record that the robot drove from ``from`` to ``to`` (the paper's rea/2; one more
    success of the arc, which raises its DRM probability)."""
    r = await worlds.reached(world, body.from_, body.to)
    return ReachedOut(world=r["world"], from_=r["from"], to=r["to"],
                      succeeded=r["succeeded"], failed=r["failed"])


@router.post("/failed", response_model=ReachedOut, status_code=status.HTTP_201_CREATED,
             response_model_by_alias=True)
async def post_failed(world: WorldDep, body: ReachedIn, worlds: WorldsDep) -> Any:
    """Record that the robot set out on the DRM arc ``from`` -> ``to`` and did not
    arrive: one more failure, which lowers the arc's DRM probability."""
    r = await worlds.failed(world, body.from_, body.to)
    return ReachedOut(world=r["world"], from_=r["from"], to=r["to"],
                      succeeded=r["succeeded"], failed=r["failed"])


@router.get("/relations", response_model=list[RelationOut],
            response_model_exclude_unset=True)
async def get_relations(world: WorldDep, worlds: WorldsDep,
                        kind: RelationKind = "lr") -> list[dict[str, Any]]:
    """Relations with their probabilities (observed: 1; derived: P(rule)·ΠP(body))."""
    return await worlds.relations(world, kind)


@router.get("/drm", response_model=DrmOut, response_model_by_alias=True)
async def get_drm(world: WorldDep, worlds: WorldsDep) -> Any:
    """The Direct Reachability Map: best derivation per ordered pair."""
    d = await worlds.drm(world)
    return DrmOut(nodes=d["nodes"], edges=[
        DrmEdgeOut(from_=e["from"], to=e["to"], p=e["p"], method=e["method"], via=e["via"],
                   succeeded=e["succeeded"], failed=e["failed"])
        for e in d["edges"]])


@router.get("/path", response_model=PathOut, response_model_by_alias=True)
async def get_path(world: WorldDep, worlds: WorldsDep,
                   from_: Annotated[str, Query(alias="from", pattern=ID_PATTERN)],
                   to: LandmarkQ) -> Any:
    """The path maximising the product of DRM edge probabilities."""
    p = await worlds.path(world, from_, to)
    if p is None:
        return PathOut(found=False, detail=f"no path from {from_!r} to {to!r} in the DRM "
                       "(observe more landmarks or record reached ones)",
                       path=[], steps=[], probability=0.0)
    return PathOut(found=True, path=p.nodes, probability=p.probability, steps=[
        StepOut(from_=s.source, to=s.target, method=s.method, p=s.p, via=list(s.via))
        for s in p.steps])


@router.post("/query", response_model=QueryOut)
async def post_query(world: WorldDep, body: QueryIn, worlds: WorldsDep,
                     request: Request) -> Any:
    """Read-only Prolog query over the world's relations, e.g.
    ``reachable(c0, To, P, Method), P > 0.9``. Only whitelisted goals run, the world
    argument filled in: control (``,`` ``;`` ``->`` ``\\+`` true fail); the spatial
    relations rec/3, frec/3, lr/4, align/5, rea/2, landmark/1; the DRM's reachable/4-5,
    drm_edge/4; the eigenspace's eig_point/3, eig_triplet/4, eig_candidate_set/2,
    stop_outcome/3, next_state/3, state_after/2, covers/3, triplet_distance/4; the map's
    map_pose/5, map_info/5, unknown_region/5, committed_map/1, loop_closure/4,
    explored_fraction/1, unknown_region_within/5, largest_unknown_region/2,
    map_path_length/1, loop_closure_count/1, closes_loop/2; the viewpoint scene's
    vp_candidate/5, observation_group/3, same_group/2, joinable/2, candidate_group/2,
    unknown_group_area/2, plan_step/4; the last mission's mission_step/3,
    mission_pose/3, mission_path/2, mission_outcome/1; comparisons of numbers or
    variables (no arithmetic); member/2, memberchk/2; findall/3 and aggregate_all/3
    (count, bag, set; sum, max, min of a number or variable) over allowed goals. Time
    and inference limits apply, and a query whose client has gone is dropped if it has
    not started."""
    try:
        return await unless_disconnected(
            request, worlds.query(world, body.goal, body.max_solutions))
    except KbError as e:
        if e.type == "limit":
            raise InvalidInput(f"query exceeded the {e.value} limit", field="goal") from None
        raise
