"""Dependencies as Annotated aliases; heavy resources live on app.state (lifespan).
The getters are ``async``: FastAPI runs a plain ``def`` dependency in a thread, a hop
per dependency per request for a lookup."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Path, Request

from chizu.numeric.world import ID_PATTERN
from chizu.service.compute import ComputePool
from chizu.service.eigenspace import EigenspaceService
from chizu.service.jobs import Jobs
from chizu.service.kb import KnowledgeBase
from chizu.service.localization import LocalizationService
from chizu.service.mission import MissionService
from chizu.service.settings import Settings, get_settings
from chizu.service.slam import SlamService
from chizu.service.viewpoint import ViewpointService
from chizu.service.worlds import WorldService


async def _worlds(request: Request) -> WorldService:
    return request.app.state.worlds  # type: ignore[no-any-return]


async def _eigenspace(request: Request) -> EigenspaceService:
    return request.app.state.eigenspace  # type: ignore[no-any-return]


async def _slam(request: Request) -> SlamService:
    return request.app.state.slam  # type: ignore[no-any-return]


async def _localization(request: Request) -> LocalizationService:
    return request.app.state.services.localization  # type: ignore[no-any-return]


async def _viewpoint(request: Request) -> ViewpointService:
    return request.app.state.viewpoint  # type: ignore[no-any-return]


async def _jobs(request: Request) -> Jobs:
    return request.app.state.services.jobs  # type: ignore[no-any-return]


async def _compute(request: Request) -> ComputePool:
    return request.app.state.services.compute  # type: ignore[no-any-return]


async def _mission(request: Request) -> MissionService:
    return request.app.state.services.mission  # type: ignore[no-any-return]


async def _kb(request: Request) -> KnowledgeBase:
    return request.app.state.kb  # type: ignore[no-any-return]


SettingsDep = Annotated[Settings, Depends(get_settings)]
WorldsDep = Annotated[WorldService, Depends(_worlds)]
KbDep = Annotated[KnowledgeBase, Depends(_kb)]
EigenspaceDep = Annotated[EigenspaceService, Depends(_eigenspace)]
SlamDep = Annotated[SlamService, Depends(_slam)]
LocalizationDep = Annotated[LocalizationService, Depends(_localization)]
ViewpointDep = Annotated[ViewpointService, Depends(_viewpoint)]
JobsDep = Annotated[Jobs, Depends(_jobs)]
MissionDep = Annotated[MissionService, Depends(_mission)]
ComputeDep = Annotated[ComputePool, Depends(_compute)]


async def _existing_world(world: Annotated[str, Path(pattern=ID_PATTERN, description="world id")],
                          worlds: WorldsDep) -> str:
    """The path's world, 404 once here if it does not exist: before the body's images
    are decoded or any work is done."""
    await worlds.ready(world)
    return world


WorldDep = Annotated[str, Depends(_existing_world)]
