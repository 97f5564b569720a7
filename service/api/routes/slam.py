"""SLAM runs: create, stream scans, pose, trajectory, maps, commit to the world."""

from __future__ import annotations

from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, Path, Query, Request, Response, status

from chizu.numeric.slam.logs import format_tum
from chizu.service.api.strict import StrictJsonRoute
from chizu.service.deps import SlamDep, WorldDep
from chizu.service.schemas.slam import (
    CommitOut,
    NearRegionOut,
    ScansIn,
    SlamPoseOut,
    SlamRunIn,
    SlamRunListed,
    SlamRunOut,
    TrajectoryOut,
    WorldMapOut,
)

router = APIRouter(prefix="/worlds/{world}", tags=["SLAM"], route_class=StrictJsonRoute)
RunId = Annotated[str, Path(pattern=r"^r[0-9a-f]{1,64}$", description="SLAM run id")]


@router.post("/slam-runs", status_code=status.HTTP_201_CREATED, response_model=SlamRunOut)
async def post_run(world: WorldDep, options: SlamRunIn, slam: SlamDep,
                   response: Response) -> SlamRunOut:
    """Start a SLAM run (method odom | icp | gated | rbpf | graph, particles, intensity weight
    alpha, RBPF proposal and resampling, map resolution, seed)."""
    run = await slam.create(world, options)
    response.headers["Location"] = f"/worlds/{world}/slam-runs/{run.id}"
    return run


@router.get("/slam-runs", response_model=list[SlamRunListed])
async def get_runs(world: WorldDep, slam: SlamDep) -> list[SlamRunListed]:
    return slam.list_runs(world)


@router.get("/slam-runs/{rid}", response_model=SlamRunOut)
async def get_run(world: WorldDep, rid: RunId, slam: SlamDep) -> SlamRunOut:
    """Scans so far, keyframes, the current pose estimate."""
    return await slam.status(world, rid)


@router.delete("/slam-runs/{rid}", status_code=status.HTTP_204_NO_CONTENT)
async def delete_run(world: WorldDep, rid: RunId, slam: SlamDep) -> Response:
    await slam.delete(world, rid)
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.post("/slam-runs/{rid}/scans", response_model=SlamRunOut)
async def post_scans(world: WorldDep, rid: RunId, body: ScansIn, slam: SlamDep) -> SlamRunOut:
    """Stream up to 500 scans (each with its odometry) in increasing time order; the
    batch is all-or-nothing. Returns the run's status with the new pose."""
    return await slam.add_scans(world, rid, body.scans)


@router.get("/slam-runs/{rid}/pose", response_model=SlamPoseOut)
async def get_pose(world: WorldDep, rid: RunId, slam: SlamDep) -> SlamPoseOut:
    st = await slam.status(world, rid)
    return SlamPoseOut(t=st.last_t, pose=st.pose, scans=st.scans)


@router.get("/slam-runs/{rid}/trajectory", response_model=None, responses={200: {
    "model": TrajectoryOut, "content": {"text/plain": {"schema": {"type": "string"}}}}})
async def get_trajectory(world: WorldDep, rid: RunId, slam: SlamDep,
                         format: str = "json") -> Any:
    """Pose per scan; ``format=tum`` gives a TUM file (``t x y z qx qy qz qw``)."""
    t, p = await slam.trajectory(world, rid)
    if format == "tum":
        return Response(format_tum(t, p), media_type="text/plain")
    return TrajectoryOut(t=t.tolist(), poses=np.round(p, 6).tolist())


#: a drawing's size: a map downsampled to at most this many pixels a side
MaxPx = Annotated[int | None, Query(ge=16, le=20_000, description="at most this many "
                                    "pixels a side: blocks of cells merged, walls kept")]


@router.get("/slam-runs/{rid}/map.png", response_class=Response,
            responses={200: {"content": {"image/png": {}}}})
async def get_map_png(world: WorldDep, rid: RunId, slam: SlamDep,
                      max_px: MaxPx = None) -> Response:
    """The map of the best hypothesis: free white, unknown grey, walls coloured by
    received intensity; its origin and resolution are in ``map.yaml`` (ask both with the
    same ``max_px``)."""
    return Response((await slam.grid(world, rid, max_px)).to_png(), media_type="image/png")


@router.get("/slam-runs/{rid}/map.pgm", response_class=Response,
            responses={200: {"content": {"image/x-portable-graymap": {}}}})
async def get_map_pgm(world: WorldDep, rid: RunId, slam: SlamDep) -> Response:
    """ROS map_server image (0 occupied, 254 free, 205 unknown)."""
    return Response((await slam.grid(world, rid)).to_pgm(),
                    media_type="image/x-portable-graymap")


@router.get("/slam-runs/{rid}/map.yaml", response_class=Response,
            responses={200: {"content": {"application/yaml": {}}}})
async def get_map_yaml(world: WorldDep, rid: RunId, slam: SlamDep,
                       max_px: MaxPx = None) -> Response:
    """ROS map_server metadata for map.pgm (with ``max_px``, of the downsampled
    ``map.png``)."""
    return Response((await slam.grid(world, rid, max_px)).to_yaml("map.pgm"),
                    media_type="application/yaml")


@router.post("/slam-runs/{rid}/commit", response_model=CommitOut)
async def post_commit(world: WorldDep, rid: RunId, slam: SlamDep) -> CommitOut:
    """Make this run's map the world's map: keyframe poses, occupancy summary and
    enclosed unknown regions become facts; the grid is stored for the planners."""
    return await slam.commit(world, rid)


@router.get("/map.chizu", response_class=Response, responses={200: {
    "content": {"application/octet-stream": {}},
    "description": "the committed map as a saved map (docs/notes/saved-map.md): keyframes, "
                   "constraints, trajectory; `chizu slam-localize LOG --map FILE` reads it"}})
async def get_saved_map(world: WorldDep, slam: SlamDep) -> Response:
    """The world's committed map, saved: what a robot localizes in later."""
    return Response(slam.saved_map(world), media_type="application/octet-stream",
                    headers={"Content-Disposition": f'attachment; filename="{world}.chizu"'})


@router.put("/map.chizu", response_model=CommitOut, openapi_extra={"requestBody": {
    "required": True, "content": {"application/octet-stream": {"schema": {
        "type": "string", "format": "binary"}}}}})
async def put_saved_map(world: WorldDep, request: Request, slam: SlamDep) -> CommitOut:
    """Commit a saved map (``chizu slam LOG --out DIR`` wrote DIR/map.chizu; or this
    world's own ``GET .../map.chizu``) as the world's map, as a SLAM run's commit does:
    its poses, occupancy and unknown regions become facts, its grid reaches the planners
    and the mission, localization runs localize on it. A corrupt, truncated or newer map,
    or one saved from another world, is a 422 naming ``map``; nothing is changed then."""
    return await slam.upload(world, await request.body())



@router.get("/map.png", response_class=Response,
            responses={200: {"content": {"image/png": {}}}})
async def get_committed_map_png(world: WorldDep, slam: SlamDep,
                                max_px: MaxPx = None) -> Response:
    """The world's committed map (as its run's ``map.png`` draws it); its origin and
    resolution are in ``map.yaml`` (ask both with the same ``max_px``)."""
    return Response(await slam.committed_png(world, max_px), media_type="image/png")


@router.get("/map.pgm", response_class=Response,
            responses={200: {"content": {"image/x-portable-graymap": {}}}})
async def get_committed_map_pgm(world: WorldDep, slam: SlamDep) -> Response:
    """The world's committed map as a ROS map_server image."""
    return Response((await slam.committed_grid(world)).to_pgm(),
                    media_type="image/x-portable-graymap")


@router.get("/map.yaml", response_class=Response,
            responses={200: {"content": {"application/yaml": {}}}})
async def get_committed_map_yaml(world: WorldDep, slam: SlamDep,
                                 max_px: MaxPx = None) -> Response:
    """ROS map_server metadata of the committed map (for ``map.pgm``; with ``max_px``,
    of the downsampled ``map.png``)."""
    return Response(await slam.committed_yaml(world, max_px), media_type="application/yaml")


@router.get("/map", response_model=WorldMapOut)
async def get_world_map(world: WorldDep, slam: SlamDep) -> Any:
    """The world's committed map as the knowledge base sees it (Prolog rules)."""
    return await slam.summary(world)


@router.get("/map/unknown-regions", response_model=list[NearRegionOut])
async def get_unknown_regions(world: WorldDep, slam: SlamDep,
                              x: Annotated[float, Query(allow_inf_nan=False)],
                              y: Annotated[float, Query(allow_inf_nan=False)],
                              radius: Annotated[float, Query(ge=0, le=1e4,
                                                             allow_inf_nan=False)] = 5.0,
                              ) -> Any:
    """Unknown regions of the committed map within ``radius`` of (x, y), nearest first."""
    return await slam.regions_near(world, x, y, radius)
