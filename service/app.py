"""FastAPI application factory; the services (service.container) live in the lifespan."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI
from fastapi_offline import FastAPIOffline

from chizu.numeric.memory import return_large_frees
from chizu.service import __version__, console, errors
from chizu.service.api import operation_id
from chizu.service.api.routes import (
    eigenspace,
    events,
    health,
    jobs,
    localization,
    mission,
    qualitative,
    slam,
    viewpoint,
    worlds,
)
from chizu.service.container import ensure_demo, open_services
from chizu.service.settings import Settings, get_settings

log = logging.getLogger("chizu")


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or get_settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        return_large_frees()  # SLAM runs and map builds make and drop large grids
        services = await asyncio.to_thread(open_services, settings, None, False)
        try:
            await ensure_demo(services)  # on this loop: its locks are this loop's
        except BaseException:
            services.close()
            raise
        # the jobs a previous server process was running ended with it: queued again
        # where they can be, else interrupted (the CLI, which opens the same store while
        # a server may run, leaves them alone)
        again, lost = services.jobs.resume_unfinished()
        if again or lost:
            log.warning("jobs the last server process left unfinished: %d queued again, "
                        "%d interrupted", again, lost)
        services.worlds.events.attach(asyncio.get_running_loop())
        app.state.services = services
        app.state.store, app.state.kb, app.state.worlds = (services.store, services.kb,
                                                           services.worlds)
        app.state.eigenspace, app.state.slam = services.eigenspace, services.slam
        app.state.viewpoint = services.viewpoint
        # the OpenAPI schema is built on its first request (half a second for this API):
        # built now, off the event loop, the console's and /docs' first load need not wait
        warm = asyncio.create_task(asyncio.to_thread(app.openapi))
        try:
            yield
        finally:
            services.worlds.events.close()  # open event streams end
            await services.jobs.close()
            services.close()
            await warm

    # the API docs (/docs, /redoc) from files installed with the package, not a CDN: they
    # work on a robot without internet
    app = FastAPIOffline(title="chizu", version=__version__, lifespan=lifespan,
                         description="Hybrid symbolic-numeric planner for mobile robots.",
                         generate_unique_id_function=operation_id,
                         static_url="/docs-static", favicon_url="/console/favicon.svg")
    console.install(app)
    app.include_router(health.router)
    app.include_router(worlds.router)
    app.include_router(qualitative.router)
    app.include_router(eigenspace.router)
    app.include_router(slam.router)
    app.include_router(localization.router)
    app.include_router(viewpoint.router)
    app.include_router(mission.router)
    app.include_router(events.jobs_router)
    app.include_router(jobs.router)
    app.include_router(events.router)
    errors.install(app)
    errors.document_problems(app)
    app.add_middleware(errors.BodySizeLimit, max_bytes=settings.max_body_bytes,
                       upload_bytes=settings.max_upload_bytes,
                       upload_suffixes=("/eigenspace/images", "/map.chizu"))
    return app
