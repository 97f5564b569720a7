from fastapi import APIRouter, status

from chizu.numeric.world import WorldDescription
from chizu.service.api.strict import StrictJsonRoute
from chizu.service.deps import WorldDep, WorldsDep
from chizu.service.schemas.common import WorldSummary

router = APIRouter(prefix="/worlds", tags=["worlds"], route_class=StrictJsonRoute)


@router.get("", response_model=list[WorldSummary])
async def list_worlds(worlds: WorldsDep) -> list[WorldSummary]:
    return [worlds.summary(n) for n in worlds.names()]


@router.post("", response_model=WorldSummary, status_code=status.HTTP_201_CREATED)
async def create_world(body: WorldDescription, worlds: WorldsDep) -> WorldSummary:
    """Create a world from a JSON description, a built-in ``template``, or both."""
    return await worlds.create(body)


@router.get("/{world}", response_model=WorldDescription)
async def get_world(world: WorldDep, worlds: WorldsDep) -> WorldDescription:
    return worlds.model(world).description


@router.delete("/{world}", status_code=status.HTTP_204_NO_CONTENT)
async def delete_world(world: WorldDep, worlds: WorldsDep) -> None:
    await worlds.delete(world)


@router.get("/{world}/facts", response_model=list[str])
async def get_facts(world: WorldDep, worlds: WorldsDep) -> list[str]:
    """Every fact the knowledge base holds for the world (as Prolog text)."""
    return await worlds.facts(world)
