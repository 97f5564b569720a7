"""The end-to-end mission (service.mission): start one as a job, read the last record."""

from __future__ import annotations

from fastapi import APIRouter, Response, status

from chizu.service.api.strict import StrictJsonRoute
from chizu.service.deps import MissionDep, WorldDep
from chizu.service.schemas.jobs import JobOut
from chizu.service.schemas.mission import MissionConfig, MissionRecordOut

router = APIRouter(prefix="/worlds/{world}", tags=["mission"], route_class=StrictJsonRoute)


@router.post("/missions", status_code=status.HTTP_202_ACCEPTED, response_model=JobOut)
async def post_mission(world: WorldDep, config: MissionConfig, mission: MissionDep,
                       response: Response) -> JobOut:
    """Run the end-to-end mission in the simulator, in this world's knowledge base: wake
    up lost and localize (eigenspace), reach the nearest landmark, follow the DRM's most
    probable path to the goal landmark while mapping (laser SLAM, committed), then plan
    viewpoints and verify the candidate objects in the goal room under the time limit.
    Learns the world's eigenspace and surveys its landmarks first if it has none. One
    mission per world at a time (409 while one runs). Runs as a job: poll ``Location``;
    its result is the record (also the ``mission_step/3`` facts, ``GET .../mission``)."""
    job = await mission.start(world, config)
    response.headers["Location"] = f"/jobs/{job.id}"
    return job


@router.get("/mission", response_model=MissionRecordOut)
async def get_mission(world: WorldDep, mission: MissionDep) -> MissionRecordOut:
    """The world's last mission record, step by step (empty if none ran); the same rows
    as the knowledge base's ``mission_step(S, What, Result)`` facts."""
    return mission.record(world)
