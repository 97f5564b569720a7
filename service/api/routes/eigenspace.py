"""Eigenspace localization: learning, one-turn localization, sessions, next move, camera."""

from __future__ import annotations

import asyncio
from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, File, Form, Path, Query, Request, Response, UploadFile, status
from pydantic import ValidationError

from chizu.numeric.eigenspace.analysis import EigenspaceConfig
from chizu.numeric.eigenspace.image_sets import (
    MAX_IMAGES,
    POSES_FILE,
    decode_image,
    parse_size,
    read_image_set,
    read_image_zip,
)
from chizu.numeric.errors import InvalidInput
from chizu.service.api.strict import StrictJsonRoute
from chizu.service.compute import TurnPng, stack_turn
from chizu.service.deps import EigenspaceDep, WorldDep
from chizu.service.disconnect import unless_disconnected
from chizu.service.eigenspace import check_source
from chizu.service.schemas.eigenspace import (
    MAX_TURN_IMAGES,
    CameraIn,
    CameraOut,
    CoverageOut,
    CoveringOut,
    EigenspaceOut,
    LocalizationOut,
    NextMoveOut,
    SessionCreated,
    SessionLocalizationOut,
    StopIn,
    TurnIn,
)
from chizu.service.schemas.jobs import JobOut

router = APIRouter(prefix="/worlds/{world}", tags=["eigenspace localization"],
                   route_class=StrictJsonRoute)
SessionId = Annotated[str, Path(pattern=r"^[0-9a-f]{32}$", description="session id")]
JobId = Annotated[str, Path(pattern=r"^[0-9a-f]{32}$", description="job id")]


def turn_payload(body: TurnIn) -> list[str] | TurnPng | np.ndarray:
    """What the compute workers decode: the base64 PNGs as they came (one per image, or
    one of the whole turn), or the nested lists as an array ``(n, H, W)`` (checked here:
    rows of one length, images of one size)."""
    if body.turn_png is not None:
        return TurnPng(body.turn_png)
    if body.images is None:
        return list(body.images_png or [])
    shapes = {(len(im), len(im[0])) for im in body.images}
    for i, im in enumerate(body.images):
        if len({len(r) for r in im}) != 1:
            raise InvalidInput(f"image {i} has rows of different lengths",
                               field=f"images[{i}]")
    if len(shapes) != 1:
        raise InvalidInput(f"all images must have the same size, got {sorted(shapes)}",
                           field="images")
    return np.asarray(body.images, dtype=float)


def parse_config(text: str | None) -> EigenspaceConfig:
    if text is None or text == "":
        return EigenspaceConfig()
    try:
        return EigenspaceConfig.model_validate_json(text)
    except ValidationError as e:
        err = e.errors()[0]
        where = ".".join(str(p) for p in err["loc"])
        raise InvalidInput(f"config: {err['msg']}", field=f"config.{where}" if where
                           else "config") from None


async def read_uploads(files: list[UploadFile], field: str
                       ) -> list[tuple[str, bytes]]:
    """(file name, bytes) of each part, in order; the name is the part's file name
    without any folder, or ``field[i]`` when it has none."""
    if len(files) > MAX_IMAGES:
        raise InvalidInput(f"at most {MAX_IMAGES} files", field=field)
    out = []
    for i, f in enumerate(files):
        name = (f.filename or "").replace("\\", "/").rsplit("/", 1)[-1] or f"{field}[{i}]"
        out.append((name, await f.read()))
    return out


def by_name(files: list[tuple[str, bytes]]) -> dict[str, bytes]:
    """The parts by file name (an image set names each file once)."""
    out: dict[str, bytes] = {}
    for name, data in files:
        if name in out:
            raise InvalidInput(f"{name} is uploaded twice", field=name)
        out[name] = data
    return out


@router.post("/eigenspace", status_code=status.HTTP_202_ACCEPTED, response_model=JobOut)
async def post_eigenspace(world: WorldDep, config: EigenspaceConfig,
                          eig: EigenspaceDep, response: Response) -> JobOut:
    """Learn the world's eigenspace in the simulator and analyse it (triplets, region
    model, entry model, candidate-multiple sets).  Runs as a job: poll ``Location``."""
    job = eig.start_learning(world, config)
    response.headers["Location"] = f"/worlds/{world}/eigenspace/jobs/{job.id}"
    return job


@router.post("/eigenspace/images", status_code=status.HTTP_202_ACCEPTED,
             response_model=JobOut)
async def post_eigenspace_images(
        world: WorldDep, eig: EigenspaceDep, response: Response,
        archive: Annotated[UploadFile | None, File(
            description=f"a zip of the image folder: {POSES_FILE} and the images it names "
                        "(any number of images)")] = None,
        poses: Annotated[UploadFile | None, File(
            description=f"or {POSES_FILE} (file,x,y,theta[,role]: m, m, rad; role learn "
                        "or calibrate) ...")] = None,
        images: Annotated[list[UploadFile] | None, File(
            description="... and the PNG/JPEG files it names, up to 995 parts (the form's "
                        "1000 parts hold the others too)",
            max_length=995)] = None,
        size: Annotated[str | None, Form(description="resize every image to WIDTHxHEIGHT "
                                         "px, e.g. 64x32")] = None,
        config: Annotated[str | None, Form(description="EigenspaceConfig as JSON "
                                           "(n_directions and the image size come from "
                                           "the images)")] = None) -> JobOut:
    """Learn the world's eigenspace from a camera's own images (multipart upload): one
    full turn per learning point, optional calibration images of known pose for c_a
    and eq. 7. Runs as a job: poll ``Location``. Errors name the file."""
    eig.worlds.model(world)  # 404 before reading anything
    cfg, wh = parse_config(config), parse_size(size)
    check_source(cfg, from_images=True)
    if (archive is None) == (poses is None):
        raise InvalidInput(f"give either archive or {POSES_FILE} with images",
                           field="archive")
    if archive is not None:
        data = await archive.read()
        image_set = await asyncio.to_thread(read_image_zip, data, wh)
    else:
        assert poses is not None
        text = (await poses.read()).decode("utf-8-sig", errors="replace")
        files = by_name(await read_uploads(images or [], "images"))
        image_set = await asyncio.to_thread(read_image_set, text, files, wh)
    job = eig.start_learning(world, cfg, image_set)
    response.headers["Location"] = f"/worlds/{world}/eigenspace/jobs/{job.id}"
    return job


@router.get("/eigenspace/jobs/{job_id}", response_model=JobOut)
async def get_job(world: WorldDep, job_id: JobId, eig: EigenspaceDep) -> JobOut:
    """Progress of a learning job (stage, 0..1), its result (the analysis summary) when
    done, its error if failed; ``interrupted`` if the server stopped while it ran."""
    return eig.job(world, job_id)


@router.get("/eigenspace", response_model=EigenspaceOut)
async def get_eigenspace(world: WorldDep, eig: EigenspaceDep) -> EigenspaceOut:
    """Summary of the learned eigenspace (images, K, triplet count, region coverage) with
    the learning points (``points``) and the localizable triplets (``triplet_list``)."""
    return eig.summary(world)


@router.get("/eigenspace/coverage", response_model=CoverageOut)
async def get_coverage(world: WorldDep, eig: EigenspaceDep,
                       cell_m: Annotated[float, Query(gt=0.0, le=5.0, allow_inf_nan=False,
                                                      description="raster cell (m)")] = 0.2
                       ) -> CoverageOut:
    """The coverage map: per cell of a raster, the probability that one turn there enters
    some localizable region (eq. 7), and the covered share of the free floor. Thin floor
    is where learning points would help (422 when the analysis has no entry model, as
    one learned from a camera's images without calibration images)."""
    return await eig.coverage(world, cell_m)


@router.get("/eigenspace/covering", response_model=list[CoveringOut])
async def get_covering(world: WorldDep, eig: EigenspaceDep,
                       x: Annotated[float, Query(allow_inf_nan=False)],
                       y: Annotated[float, Query(allow_inf_nan=False)]) -> list[dict[str, Any]]:
    """Triplets whose triangle of learning points covers (x, y), with D(s) (Prolog rules)."""
    return await eig.covering(world, x, y)


@router.post("/localize", response_model=LocalizationOut)
async def post_localize(world: WorldDep, body: TurnIn, eig: EigenspaceDep,
                        request: Request) -> LocalizationOut:
    """One full turn of images -> state (X / Y / Z), pose when Z, candidates."""
    eig.analysis(world)  # 409 before decoding anything
    turn = await asyncio.to_thread(turn_payload, body)
    # decoded and matched in a compute worker, stopped if the client leaves
    return await unless_disconnected(request, eig.localize(world, turn))


@router.post("/localize/images", response_model=LocalizationOut)
async def post_localize_images(
        world: WorldDep, eig: EigenspaceDep,
        images: Annotated[list[UploadFile], File(description="one full turn of PNG/JPEG "
                                                 "images, in order of relative heading "
                                                 "2*pi*j/n", min_length=1,
                                                 max_length=MAX_TURN_IMAGES)],
        size: Annotated[str | None, Form(description="resize to WIDTHxHEIGHT px")] = None
        ) -> LocalizationOut:
    """``/localize`` for image files (multipart upload), e.g. straight from a camera."""
    h, w = eig.analysis(world).model.image_shape  # 409 before decoding anything
    wh = parse_size(size)
    files = await read_uploads(images, "images")

    def decode() -> np.ndarray:
        return stack_turn([decode_image(f"images[{i}]", data, wh, expect=(w, h))
                           for i, (_, data) in enumerate(files)], "images")

    return await eig.localize(world, await asyncio.to_thread(decode))


@router.post("/localization-sessions", status_code=status.HTTP_201_CREATED,
             response_model=SessionCreated)
async def post_session(world: WorldDep, eig: EigenspaceDep,
                       response: Response) -> SessionCreated:
    """Start a multi-stop localization (state X)."""
    s = await eig.create_session(world)
    response.headers["Location"] = f"/worlds/{world}/localization-sessions/{s.id}"
    return s


@router.get("/localization-sessions/{sid}", response_model=SessionLocalizationOut)
async def get_session(world: WorldDep, sid: SessionId,
                      eig: EigenspaceDep) -> SessionLocalizationOut:
    return await eig.session(world, sid)


@router.post("/localization-sessions/{sid}/stops", response_model=SessionLocalizationOut)
async def post_stop(world: WorldDep, sid: SessionId, body: StopIn,
                    eig: EigenspaceDep, request: Request) -> SessionLocalizationOut:
    """One stop: a full turn of images plus the odometry since the previous stop."""
    motion = None if body.odometry is None else np.array(
        [body.odometry.dx, body.odometry.dy, body.odometry.dtheta])
    eig.analysis(world)  # 409 before decoding anything
    turn = await asyncio.to_thread(turn_payload, body)
    # decoded and matched in a compute worker; a client that leaves stops it, and its
    # stop is then not recorded (the session is written last, in one transaction)
    return await unless_disconnected(request, eig.add_stop(world, sid, turn, motion))


@router.get("/localization-sessions/{sid}/next-move", response_model=NextMoveOut)
async def get_next_move(world: WorldDep, sid: SessionId, eig: EigenspaceDep,
                        request: Request) -> NextMoveOut:
    """The movement strategy's action (alpha, l, beta) maximising Q(Z), and that Q(Z)
    (computed in a compute worker, stopped if the client leaves)."""
    return await unless_disconnected(request, eig.next_move(world, sid))


@router.post("/camera", response_model=CameraOut, response_model_exclude_unset=True)
async def post_camera(world: WorldDep, body: CameraIn, eig: EigenspaceDep,
                      request: Request) -> CameraOut:
    """Render the simulated camera at a pose (one image, or a full turn): base64 PNG by
    default, nested lists with ``"format": "list"``."""
    pose = np.array([body.pose.x, body.pose.y, body.pose.theta])
    # rendered and encoded in a compute worker, within the request's time budget, and
    # stopped if the client leaves
    return await unless_disconnected(
        request, eig.render(world, pose, body.camera, body.turn, body.format))
