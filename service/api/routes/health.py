from fastapi import APIRouter

from service.deps import KbDep, WorldsDep
from service.schemas import Health

router = APIRouter(tags=["health"])


@router.get("/health", response_model=Health)
async def health(worlds: WorldsDep, kb: KbDep) -> Health:
    await kb.acall("worlds")  # the engine answers
    return Health(status="ok", worlds=len(worlds.names()),
                  engine_thread_alive=kb.engine_thread.is_alive())
