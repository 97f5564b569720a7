"""Viewpoint plans: observation groups and the best time-constrained plan (§§4-6)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from chizu.service.api.strict import StrictJsonRoute
from chizu.service.deps import ViewpointDep, WorldDep
from chizu.service.schemas.viewpoint import ViewpointGroupsOut, ViewpointPlanIn, ViewpointPlanOut

router = APIRouter(prefix="/worlds/{world}", tags=["viewpoint planning"],
                   route_class=StrictJsonRoute)


@router.post("/viewpoint-plan", response_model=ViewpointPlanOut,
             response_model_exclude_unset=True)
async def post_plan(world: WorldDep, body: ViewpointPlanIn,
                    vp: ViewpointDep) -> ViewpointPlanOut:
    """Group the candidates and unknown regions (Prolog rules), estimate each group's
    verification time (24 viewpoints, eqs. 5-10) and value (eqs. 15-17), and choose the
    ordered plan maximising U = V - L(t) (eq. 11) under loss L1, L2 or L3. The grid is the
    posted one, else the world's committed SLAM map, else the simulator's view from the
    robot's pose. Returns the groups, the chosen plan (empty: leave now) and runner-ups."""
    return await vp.plan(world, body)


@router.get("/viewpoint-groups", response_model=ViewpointGroupsOut,
            response_model_exclude_unset=True)
async def get_groups(world: WorldDep, vp: ViewpointDep) -> Any:
    """The observation groups of the world's last planned scene (Prolog facts)."""
    return await vp.scene(world)
