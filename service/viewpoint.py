"""Viewpoint plans for a world (paper: time-constrained viewpoint planning).

A request carries the robot's pose, the exit, the time limit and loss, the object types
and the candidates; the grid is the posted one, else the map a SLAM run committed to the
world (``slam_map`` artifact), else what the robot would map from its pose in the
world's simulator (a look around, §4.1). Grouping is decided by the Prolog rules
(``prolog/grouping.pl``, op ``viewpoint_groups``), which keep the scene's candidates,
unknown regions and groups as facts of the world (queryable in the REPL and the query
endpoint). The scene is stored, so it survives a restart; a request that fails after
grouping puts the previous scene back.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

from chizu.numeric.occupancy import OccupancyMap
from chizu.numeric.viewpoint.planner import GroupSpec
from chizu.service.compute import Cached, ComputePool, blob_key
from chizu.service.kb import KnowledgeBase
from chizu.service.schemas.viewpoint import PlanRequest, ViewpointPlanOut
from chizu.service.slam import MAP_ARTIFACT
from chizu.service.store import Store
from chizu.service.viewpoint_tasks import finish_task, plan_answer, prepare_task
from chizu.service.worlds import ArtifactKind, WorldService

__all__ = ["ViewpointService", "kb_grouper", "local_grouper", "plan_answer"]

SCENE_ARTIFACT = "viewpoint_scene"


def kb_grouper(kb: KnowledgeBase, world: str):  # type: ignore[no-untyped-def]
    """A :data:`chizu.numeric.viewpoint.planner.Grouper` asking the world's Prolog rules (the
    CLI's and the benchmarks' planner, in-process)."""

    def group(cands: list[dict[str, Any]], regions: list[dict[str, Any]],
              min_area: float | None) -> list[GroupSpec]:
        reply = kb.call("viewpoint_groups", world=world, candidates=cands, regions=regions,
                        min_area_m2=min_area)
        return [GroupSpec(int(g["id"]), str(g["kind"]), tuple(g["members"]))
                for g in reply["groups"]]

    return group


def local_grouper(prolog_dir: Path, world: str = "scene"):  # type: ignore[no-untyped-def]
    """A grouper on a private knowledge base (for the CLI and benchmarks): the same rules,
    a scratch world that is never stored. Returns (grouper, kb); close the kb when done."""
    kb = KnowledgeBase(prolog_dir)
    kb.call("create_world", world=world, landmarks=[])
    return kb_grouper(kb, world), kb


class ViewpointService:
    def __init__(self, store: Store, kb: KnowledgeBase, worlds: WorldService,
                 compute: ComputePool) -> None:
        self.store, self.kb, self.worlds = store, kb, worlds
        #: the planner's numeric steps run there (:mod:`chizu.service.viewpoint_tasks`)
        self.compute = compute
        worlds.register(ArtifactKind(SCENE_ARTIFACT, "viewpoint_groups", "viewpoint",
                                     lambda _world, blob: dict(json.loads(blob))))

    def grid_source(self, world: str, req: PlanRequest) -> tuple[str, Cached | None]:
        """Where the grid comes from (the posted one, the committed SLAM map, the world's
        simulator) and what a worker needs to build it."""
        if req.grid is not None:
            return "posted", None
        blob = self.store.artifact(world, MAP_ARTIFACT)
        if blob is not None:
            return "slam_map", Cached(blob_key(blob), blob, OccupancyMap.from_npz)
        return "simulated", self.worlds.cached_model(world)

    async def plan(self, world: str, req: PlanRequest) -> ViewpointPlanOut:
        """One planning step: the grid and step 1 in a compute worker, the grouping by
        the world's Prolog rules, steps 3-4 and the answer in a compute worker."""
        self.worlds.require(world)  # 404 for an unknown world
        # grouping asserts the scene as it plans: a failure anywhere puts the stored one back
        async with self.worlds.write_artifact(world, SCENE_ARTIFACT) as w:
            source, material = self.grid_source(world, req)
            if material is None:
                grid, prep = await self.compute.run(prepare_task, None, req)
            else:
                grid, prep = await self.compute.run_cached(prepare_task, material, req)
            t0 = time.perf_counter()
            cands, regions, min_area = prep.group_args
            scene: dict[str, Any] = {"world": world, "candidates": cands, "regions": regions,
                                     "min_area_m2": min_area}
            reply = await self.kb.acall("viewpoint_groups", **scene)
            specs = [GroupSpec(int(g["id"]), str(g["kind"]), tuple(g["members"]))
                     for g in reply["groups"]]
            answer, steps = await self.compute.run(
                finish_task, grid, prep, specs, req, world, source,
                1e3 * (time.perf_counter() - t0))
            scene["steps"] = steps  # the best plan's steps join the scene's facts
            await w.commit(json.dumps(scene).encode(), call=scene)
        return answer

    async def scene(self, world: str) -> Any:
        return await self.worlds.ask(world, "viewpoint_scene")
