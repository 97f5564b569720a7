"""Missions in batches: one task per world, runnable in this process or on Dask
(:mod:`chizu.service.executors`). A task opens its own services (store, Prolog engine) in a
scratch directory, creates the world, runs the seeds and returns one row per run, so the
same function runs on any worker of a cluster; nothing but the rows (and, if asked, the
first run's figure as PNG bytes) comes back."""

from __future__ import annotations

import asyncio
import tempfile
from concurrent.futures import Executor
from pathlib import Path
from typing import Any

from chizu.numeric.world import WorldDescription


def mission_rows(world: dict[str, Any], config: dict[str, Any], seeds: list[int],
                 kind: str = "", figure: bool = False) -> tuple[list[dict[str, Any]],
                                                                bytes | None]:
    """Run the mission on ``world`` (a world description) for each seed with
    ``config`` (a :class:`chizu.service.mission.MissionConfig` as JSON): one row per run, and
    the first run's figure when ``figure``."""
    from chizu.service.container import open_services
    from chizu.service.mission import MissionConfig
    from chizu.service.settings import Settings

    desc = WorldDescription.model_validate(world)
    cfg = MissionConfig.model_validate(config)
    rows: list[dict[str, Any]] = []
    png: bytes | None = None
    with tempfile.TemporaryDirectory() as d:
        svc = open_services(Settings(data_dir=Path(d), demo_world=None, workers=0), demo=False)
        try:
            asyncio.run(svc.worlds.create(desc))
            for k, seed in enumerate(seeds):
                run = asyncio.run(svc.mission.run(desc.name,
                                                  cfg.model_copy(update={"seed": seed})))
                rows.append({"kind": kind, **run.row()})
                if figure and k == 0:
                    out = Path(d) / "mission.png"
                    run.figure(svc.worlds.model(desc.name), str(out))
                    png = out.read_bytes()
        finally:
            svc.close()
    return rows, png


def run_missions(tasks: list[tuple[dict[str, Any], dict[str, Any], list[int], str, bool]],
                 executor: Executor | None = None
                 ) -> list[tuple[list[dict[str, Any]], bytes | None]]:
    """:func:`mission_rows` for every task, in order: here one after the other, or on
    ``executor`` (a Dask cluster's) all at once."""
    if executor is None:
        return [mission_rows(*t) for t in tasks]
    futures = [executor.submit(mission_rows, *t) for t in tasks]
    return [f.result() for f in futures]
