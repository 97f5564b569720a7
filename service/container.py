"""The one wiring of chizu's services, shared by the app's lifespan and the CLI.

:func:`open_services` opens the store and the Prolog engine, builds the world service
and the three domain services (each registers the artifact kinds it writes), restores
the stored SLAM runs (worlds load into the knowledge base when first asked for:
:meth:`WorldService.ready`), and creates the demo world if it is configured and missing. So a
``chizu repl WORLD`` or ``chizu eigenspace localize`` sees exactly the knowledge base
the service would start with.
"""

from __future__ import annotations

import asyncio
import logging
from concurrent.futures import Executor
from dataclasses import dataclass

from chizu.numeric.qualitative.survey import survey
from chizu.numeric.simulator import ObserverConfig
from chizu.numeric.world import WorldDescription
from chizu.service.compute import ComputePool
from chizu.service.eigenspace import EigenspaceService
from chizu.service.jobs import Jobs
from chizu.service.kb import KnowledgeBase
from chizu.service.localization import LocalizationService
from chizu.service.mission import MissionService
from chizu.service.settings import Settings, get_settings
from chizu.service.slam import SlamService
from chizu.service.store import Store
from chizu.service.viewpoint import ViewpointService
from chizu.service.worlds import WorldService

log = logging.getLogger("chizu")


@dataclass
class Services:
    """Everything a request or a CLI command needs; :meth:`close` releases it."""

    settings: Settings
    store: Store
    kb: KnowledgeBase
    worlds: WorldService
    jobs: Jobs
    compute: ComputePool
    eigenspace: EigenspaceService
    slam: SlamService
    viewpoint: ViewpointService
    mission: MissionService
    localization: LocalizationService

    def close(self) -> None:
        self.compute.close()
        self.kb.close()
        self.store.close()


async def create_demo(service: WorldService, name: str) -> None:
    """The built-in demo office, surveyed once in the simulator so paths work at once."""
    await service.create(WorldDescription(name=name, template="demo"))
    cfg = ObserverConfig(bearing_noise_rad=0.01, distance_noise_m=0.02)
    for obs in survey(service.model(name), cfg, seed=0):
        await service.observe(name, obs)


async def ensure_demo(services: Services) -> None:
    """Create the configured demo world if it is missing."""
    name = services.settings.demo_world
    if name and services.store.world(name) is None:
        await create_demo(services.worlds, name)


def open_services(settings: Settings | None = None,
                  executor: Executor | None = None, demo: bool = True) -> Services:
    """Open and restore everything (blocking; the app runs it in a worker thread).
    ``demo``: create the configured demo world if it is missing, on an event loop of
    its own (the CLI; the app creates it on its own loop, :func:`ensure_demo`).
    ``executor`` runs the eigenspace learning strategy's Monte Carlo evaluation (None:
    in-process)."""
    settings = settings or get_settings()
    store = Store(settings.db_path)
    try:
        kb = KnowledgeBase(settings.prolog_dir, settings.kb_time_limit_s,
                           settings.kb_inference_limit, settings.kb_query_time_limit_s)
    except BaseException:
        store.close()
        raise
    compute = ComputePool(settings.workers, settings.request_budget_s)
    try:
        worlds = WorldService(store, kb, settings.max_event_streams)
        jobs = Jobs(store, settings.job_budget_s, worlds.events)
        eigenspace = EigenspaceService(store, worlds, jobs, compute, executor,
                                       settings.max_learning_pixels)
        slam = SlamService(store, worlds, settings.request_budget_s)
        viewpoint = ViewpointService(store, kb, worlds, compute)
        localization = LocalizationService(store, worlds, settings.request_budget_s)
        services = Services(settings, store, kb, worlds, jobs, compute, eigenspace, slam,
                            viewpoint, MissionService(worlds, jobs, eigenspace, slam,
                                                      viewpoint, localization),
                            localization)
        runs = services.slam.restore_runs()
        located = services.localization.restore_runs()
        log.info("opened %s: worlds load when first asked for; %d SLAM run(s), "
                 "%d localization run(s) restored", settings.db_path, runs, located)
        if demo:
            asyncio.run(ensure_demo(services))
    except BaseException:
        compute.close()
        kb.close()
        store.close()
        raise
    return services
