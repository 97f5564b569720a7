import asyncio

from fastapi import APIRouter

from chizu.service.api.strict import StrictJsonRoute
from chizu.service.deps import ComputeDep, KbDep, WorldsDep
from chizu.service.schemas.common import Health

router = APIRouter(tags=["health"], route_class=StrictJsonRoute)

#: how long /health waits for the engine to answer before it reports it busy: the
#: engine is one thread, and a legal request may hold it up to its time limit
ENGINE_PROBE_S = 0.02


@router.get("/health", response_model=Health)
async def health(worlds: WorldsDep, kb: KbDep, compute: ComputeDep) -> Health:
    """Liveness without waiting in line: the engine thread is alive, and it answers
    within ENGINE_PROBE_S or is reported busy (a request is running; the probe is
    dropped, not queued behind it)."""
    try:
        # until the engine has answered once, give it longer: its thread id is not known
        engine = await asyncio.wait_for(kb.acall("engine"),
                                        ENGINE_PROBE_S if kb.prolog_thread_id else 1.0)
        kb.prolog_thread_id = int(engine["thread"])
        busy = False
    except TimeoutError:
        busy = True
    return Health(status="ok", worlds=worlds.count(),
                  engine_thread_alive=kb.engine_thread.is_alive(), engine_busy=busy,
                  prolog_thread=kb.prolog_thread_id,
                  python_thread=kb.engine_thread.ident or 0,
                  compute_workers=compute.workers, compute_restarts=compute.restarts,
                  event_streams=worlds.events.subscribers)
