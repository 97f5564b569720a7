"""Localization runs on the world's committed map: create, stream scans, status,
trajectory."""

from __future__ import annotations

from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, Path, Response, status

from chizu.numeric.slam.logs import format_tum
from chizu.service.api.strict import StrictJsonRoute
from chizu.service.deps import LocalizationDep, WorldDep
from chizu.service.schemas.localization import (
    LocalizationRunIn,
    LocalizationRunListed,
    LocalizationRunOut,
    LocalizedTrajectoryOut,
)
from chizu.service.schemas.slam import ScansIn

router = APIRouter(prefix="/worlds/{world}", tags=["Localization"],
                   route_class=StrictJsonRoute)
RunId = Annotated[str, Path(pattern=r"^l[0-9a-f]{1,64}$",
                            description="localization run id")]


@router.post("/localization-runs", status_code=status.HTTP_201_CREATED,
             response_model=LocalizationRunOut)
async def post_run(world: WorldDep, loc: LocalizationDep, response: Response,
                   body: LocalizationRunIn | None = None) -> LocalizationRunOut:
    """Start localizing a robot on the world's committed map (409, field ``map``, if it
    has none). The robot's start is unknown: the run searches the whole map, then
    tracks; a robot carried away is found again. The map is not changed."""
    run = await loc.create(world)
    response.headers["Location"] = f"/worlds/{world}/localization-runs/{run.id}"
    return run


@router.get("/localization-runs", response_model=list[LocalizationRunListed])
async def get_runs(world: WorldDep, loc: LocalizationDep) -> list[LocalizationRunListed]:
    return loc.list_runs(world)


@router.get("/localization-runs/{rid}", response_model=LocalizationRunOut)
async def get_run(world: WorldDep, rid: RunId, loc: LocalizationDep) -> LocalizationRunOut:
    """Where the robot stands: state, pose in the map, time to the first fix, the fixes
    and losses so far."""
    return await loc.status(world, rid)


@router.delete("/localization-runs/{rid}", status_code=status.HTTP_204_NO_CONTENT)
async def delete_run(world: WorldDep, rid: RunId, loc: LocalizationDep) -> Response:
    await loc.delete(world, rid)
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.post("/localization-runs/{rid}/scans", response_model=LocalizationRunOut)
async def post_scans(world: WorldDep, rid: RunId, body: ScansIn,
                     loc: LocalizationDep) -> LocalizationRunOut:
    """Stream up to 500 scans (each with its odometry) in increasing time order, as into
    a SLAM run; the batch is all-or-nothing, and a laser other than the map's is a 422
    naming the scan."""
    return await loc.add_scans(world, rid, body.scans)


@router.get("/localization-runs/{rid}/trajectory", response_model=None, responses={200: {
    "model": LocalizedTrajectoryOut,
    "content": {"text/plain": {"schema": {"type": "string"}}}}})
async def get_trajectory(world: WorldDep, rid: RunId, loc: LocalizationDep,
                         format: str = "json") -> Any:
    """Pose per scan in the map's frame (null where not localized); ``format=tum``
    gives the localized scans as a TUM file."""
    t, poses = await loc.trajectory(world, rid)
    if format == "tum":
        ok = [i for i, p in enumerate(poses) if p is not None]
        return Response(format_tum(np.array([t[i] for i in ok]),
                                   np.array([poses[i] for i in ok]).reshape(-1, 3)),
                        media_type="text/plain")
    return LocalizedTrajectoryOut(t=t, poses=[None if p is None else
                                              [round(float(v), 6) for v in p] for p in poses])
