"""Eigenspace localization: learning, one-turn localization, sessions, next move, camera."""

from __future__ import annotations

import base64
import binascii
import io
from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, Query, Response, status
from PIL import Image, UnidentifiedImageError

from numeric.eigenspace.analysis import EigenspaceConfig
from numeric.errors import InvalidInput
from service.api.routes.worlds import WorldName
from service.deps import EigenspaceDep
from service.schemas import (
    CameraIn,
    LocalizationOut,
    NextMoveOut,
    SessionCreated,
    SessionLocalizationOut,
    StopIn,
    TurnIn,
)

router = APIRouter(prefix="/worlds/{world}", tags=["eigenspace localization"])


def decode_turn(body: TurnIn) -> np.ndarray:
    """Images ``(n, H, W)`` from nested lists or base64 PNG; 4xx naming the field."""
    if body.images is not None:
        shapes = {(len(im), len(im[0])) for im in body.images}
        for i, im in enumerate(body.images):
            if len({len(r) for r in im}) != 1:
                raise InvalidInput(f"image {i} has rows of different lengths",
                                   field=f"images[{i}]")
        if len(shapes) != 1:
            raise InvalidInput(f"all images must have the same size, got {sorted(shapes)}",
                               field="images")
        return np.asarray(body.images, dtype=float)
    out = []
    for i, s in enumerate(body.images_png or []):
        try:
            raw = base64.b64decode(s, validate=True)
            with Image.open(io.BytesIO(raw)) as png:
                if png.format != "PNG":
                    raise InvalidInput("not a PNG file", field=f"images_png[{i}]")
                out.append(np.asarray(png.convert("L"), dtype=np.float64) / 255.0)
        except (binascii.Error, ValueError, UnidentifiedImageError, OSError) as e:
            raise InvalidInput(f"not a base64 PNG image: {e}", field=f"images_png[{i}]") from e
    if len({a.shape for a in out}) != 1:
        raise InvalidInput("all images must have the same size", field="images_png")
    return np.stack(out)


def encode_png(img: np.ndarray) -> str:
    buf = io.BytesIO()
    Image.fromarray(np.round(np.clip(img, 0, 1) * 255).astype(np.uint8), mode="L").save(
        buf, format="PNG")
    return base64.b64encode(buf.getvalue()).decode()


@router.post("/eigenspace", status_code=status.HTTP_202_ACCEPTED)
async def post_eigenspace(world: WorldName, config: EigenspaceConfig,
                          eig: EigenspaceDep, response: Response) -> dict[str, Any]:
    """Learn the world's eigenspace in the simulator and analyse it (triplets, region
    model, entry model, candidate-multiple sets).  Runs as a job: poll ``Location``."""
    job = eig.start_learning(world, config)
    response.headers["Location"] = f"/worlds/{world}/eigenspace/jobs/{job.id}"
    return job.public()


@router.get("/eigenspace/jobs/{job_id}")
async def get_job(world: WorldName, job_id: str, eig: EigenspaceDep) -> dict[str, Any]:
    """Progress of a learning job (stage, 0..1), its summary when done, its error if failed."""
    return eig.job(world, job_id).public()


@router.get("/eigenspace")
async def get_eigenspace(world: WorldName, eig: EigenspaceDep) -> dict[str, Any]:
    """Summary of the learned eigenspace (images, K, triplet count, region coverage) with
    the learning points (``points``) and the localizable triplets (``triplet_list``)."""
    return eig.summary(world)


@router.get("/eigenspace/covering")
async def get_covering(world: WorldName, eig: EigenspaceDep,
                       x: Annotated[float, Query(allow_inf_nan=False)],
                       y: Annotated[float, Query(allow_inf_nan=False)]) -> list[dict[str, Any]]:
    """Triplets whose triangle of learning points covers (x, y), with D(s) (Prolog rules)."""
    return await eig.covering(world, x, y)


@router.post("/localize", response_model=LocalizationOut)
async def post_localize(world: WorldName, body: TurnIn, eig: EigenspaceDep) -> dict[str, Any]:
    """One full turn of images -> state (X / Y / Z), pose when Z, candidates."""
    return await eig.localize(world, decode_turn(body))


@router.post("/localization-sessions", status_code=status.HTTP_201_CREATED,
             response_model=SessionCreated)
async def post_session(world: WorldName, eig: EigenspaceDep,
                       response: Response) -> dict[str, Any]:
    """Start a multi-stop localization (state X)."""
    s = await eig.create_session(world)
    response.headers["Location"] = f"/worlds/{world}/localization-sessions/{s['id']}"
    return s


@router.get("/localization-sessions/{sid}", response_model=SessionLocalizationOut)
async def get_session(world: WorldName, sid: str, eig: EigenspaceDep) -> dict[str, Any]:
    return await eig.session(world, sid)


@router.post("/localization-sessions/{sid}/stops", response_model=SessionLocalizationOut)
async def post_stop(world: WorldName, sid: str, body: StopIn,
                    eig: EigenspaceDep) -> dict[str, Any]:
    """One stop: a full turn of images plus the odometry since the previous stop."""
    motion = None if body.odometry is None else np.array(
        [body.odometry.dx, body.odometry.dy, body.odometry.dtheta])
    return await eig.add_stop(world, sid, decode_turn(body), motion)


@router.get("/localization-sessions/{sid}/next-move", response_model=NextMoveOut)
async def get_next_move(world: WorldName, sid: str, eig: EigenspaceDep) -> dict[str, Any]:
    """The movement strategy's action (alpha, l, beta) maximising Q(Z), and that Q(Z)."""
    return await eig.next_move(world, sid)


@router.post("/camera")
async def post_camera(world: WorldName, body: CameraIn, eig: EigenspaceDep) -> dict[str, Any]:
    """Render the simulated camera at a pose (one image, or a full turn): base64 PNG by
    default, nested lists with ``"format": "list"``."""
    pose = np.array([body.pose.x, body.pose.y, body.pose.theta])
    imgs = eig.render(world, pose, body.camera, body.turn)
    if body.format == "png":
        return {"images_png": [encode_png(i) for i in imgs]}
    return {"images": np.round(imgs, 4).tolist()}
