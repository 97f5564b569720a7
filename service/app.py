"""FastAPI application factory; the engine, store and worlds live in the lifespan."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI

from numeric.qualitative.survey import survey
from numeric.simulator import ObserverConfig
from numeric.world import WorldDescription
from service import errors
from service.api.routes import eigenspace, health, qualitative, slam, viewpoint, worlds
from service.eigenspace import EigenspaceService
from service.kb import KnowledgeBase
from service.settings import Settings, get_settings
from service.slam import SlamService
from service.store import Store
from service.viewpoint import ViewpointService
from service.worlds import WorldService

log = logging.getLogger("chizu")


async def create_demo(service: WorldService, name: str) -> None:
    """The built-in demo office, surveyed once in the simulator so paths work at once."""
    await service.create(WorldDescription(name=name, template="demo"))
    cfg = ObserverConfig(bearing_noise_rad=0.01, distance_noise_m=0.02)
    for obs in survey(service.model(name), cfg, seed=0):
        await service.observe(name, obs)


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or get_settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        store = Store(settings.db_path)
        kb = await asyncio.to_thread(KnowledgeBase, settings.prolog_dir,
                                     settings.kb_time_limit_s, settings.kb_inference_limit)
        service = WorldService(store, kb)
        n = await asyncio.to_thread(service.restore)
        log.info("restored %d world(s) from %s", n, settings.db_path)
        if settings.demo_world and store.world(settings.demo_world) is None:
            await create_demo(service, settings.demo_world)
        eig = EigenspaceService(store, kb, service)
        m = await asyncio.to_thread(eig.restore)
        log.info("restored %d eigenspace analys(e)s", m)
        app.state.store, app.state.kb, app.state.worlds = store, kb, service
        app.state.eigenspace = eig
        sl = SlamService(store, kb, service)
        k = await asyncio.to_thread(sl.restore)
        log.info("restored %d committed SLAM map(s)", k)
        app.state.slam = sl
        vp = ViewpointService(store, kb, service)
        v = await asyncio.to_thread(vp.restore)
        log.info("restored %d viewpoint scene(s)", v)
        app.state.viewpoint = vp
        try:
            yield
        finally:
            kb.close()
            store.close()

    app = FastAPI(title="chizu", version="0.1.0", lifespan=lifespan,
                  description="Hybrid symbolic-numeric planner for mobile robots.")
    app.include_router(health.router)
    app.include_router(worlds.router)
    app.include_router(qualitative.router)
    app.include_router(eigenspace.router)
    app.include_router(slam.router)
    app.include_router(viewpoint.router)
    errors.install(app)
    app.add_middleware(errors.BodySizeLimit, max_bytes=settings.max_body_bytes,
                       upload_bytes=settings.max_upload_bytes,
                       upload_suffixes=("/eigenspace/images",))
    return app
