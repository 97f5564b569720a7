from fastapi import APIRouter

from service.deps import KbDep, WorldsDep
from service.schemas.common import Health

router = APIRouter(tags=["health"])


@router.get("/health", response_model=Health)
async def health(worlds: WorldsDep, kb: KbDep) -> Health:
    engine = await kb.acall("engine")  # the engine answers, from its one thread
    return Health(status="ok", worlds=len(worlds.names()),
                  engine_thread_alive=kb.engine_thread.is_alive(),
                  prolog_thread=int(engine["thread"]),
                  python_thread=kb.engine_thread.ident or 0)
