"""World service: one place that keeps the store and the knowledge base in step.

Write order for every mutation (under one asyncio lock, so writers never
interleave): validate -> apply to the knowledge base (atomic there, a Prolog
transaction) -> commit the event to SQLite.  If the commit fails the world is
rebuilt in the knowledge base from the store, so the two never disagree.

Worlds are loaded into the knowledge base when first asked for (:meth:`WorldService.ready`),
not at start-up, so start-up does not grow with the number of stored worlds. The store
counts every write to a world's events and artifacts (its version, kept by SQLite
triggers), so a world another process wrote -- the CLI on the service's data directory --
is reloaded before it is next read, and one deleted there is dropped.
"""

from __future__ import annotations

import asyncio
import logging
import sqlite3
from collections.abc import AsyncIterator, Callable, Iterator
from contextlib import asynccontextmanager, contextmanager
from dataclasses import dataclass
from typing import Any

import networkx as nx

from chizu.numeric.errors import Conflict, InvalidInput, NotFound
from chizu.numeric.observation import Observation, observation_quantities
from chizu.numeric.qualitative.drm import (
    DrmPath,
    build_drm,
    edges_from_records,
    max_probability_path,
)
from chizu.numeric.world import World, WorldDescription
from chizu.numeric.worlds import TEMPLATES, from_template
from chizu.service.compute import Cached, blob_key, load_world
from chizu.service.events import MAX_SUBSCRIBERS, EventHub
from chizu.service.kb import KbError, KnowledgeBase
from chizu.service.schemas.common import WorldSummary
from chizu.service.store import Event, Store

log = logging.getLogger(__name__)


def resolve_description(desc: WorldDescription) -> WorldDescription:
    """Expand ``template`` into a full description (client fields are added on top)."""
    if desc.template is None:
        return desc
    if desc.template not in TEMPLATES:
        raise InvalidInput(f"unknown template {desc.template!r}; built-ins: "
                           f"{sorted(TEMPLATES)}", field="template")
    base = from_template(desc.template, desc.name)
    return base.model_copy(update={
        "walls": base.walls + desc.walls,
        "landmarks": base.landmarks + desc.landmarks,
        "objects": base.objects + desc.objects,
        "rule_probabilities": {**base.rule_probabilities, **desc.rule_probabilities},
        "parameters": {**base.parameters, **desc.parameters},
        "template": desc.template,
    })


@dataclass(frozen=True)
class ArtifactKind:
    """A kind of stored artifact whose facts live in the knowledge base (a committed
    SLAM map, an eigenspace analysis, a viewpoint scene): ``name`` is its key in the
    store, ``op`` the knowledge-base operation that replaces the world's facts of
    ``domain`` with the ones ``call(world, blob)`` gives from the stored blob. The one
    registry of these (:meth:`WorldService.register`) is what start-up restores and
    what a failed write puts back."""

    name: str
    op: str
    domain: str
    call: Callable[[str, bytes], dict[str, Any]]


class ArtifactWrite:
    """One artifact write inside :meth:`WorldService.write_artifact` (the world's lock
    is held): :meth:`commit` asserts the facts and stores the blobs, both or neither."""

    def __init__(self, worlds: WorldService, world: str, kind: ArtifactKind) -> None:
        self.worlds, self.world, self.kind = worlds, world, kind
        self.reply: Any = None

    async def commit(self, blob: bytes, extra: dict[str, bytes] | None = None,
                     call: dict[str, Any] | None = None) -> Any:
        """Replace the world's facts of this kind (``call``, or the kind's call made
        from ``blob``), then store ``blob`` under the kind's name and every ``extra``
        blob under its own name, in one store transaction. Raises if either fails; the
        enclosing :meth:`WorldService.write_artifact` puts the previous facts back."""
        args = self.kind.call(self.world, blob) if call is None else call
        self.reply = await self.worlds._kb(self.kind.op, args)
        store = self.worlds.store
        with self.worlds._own_write(self.world) as conn:
            store.put_artifact(conn, self.world, self.kind.name, blob)
            for name, b in (extra or {}).items():
                store.put_artifact(conn, self.world, name, b)
        self.worlds.events.publish(self.world, "artifact",
                                   {"kind": self.kind.name, "with": sorted(extra or {})})
        return self.reply


#: parameters that were renamed: worlds stored with the old name keep working
RENAMED_PARAMETERS = {"vp_unknown_min_area_m2": "unknown_region_min_area_m2"}

#: a world's event-made facts are snapshotted every this many events: start-up loads
#: the snapshot and replays only the events after it, so its time stays flat
SNAPSHOT_EVERY = 200
#: stored events replayed per engine call when a world loads
REPLAY_BATCH = 200
#: bumped whenever the Python side of an event (event_call, the quantities of an
#: observation) changes what its facts are: older snapshots are then replayed instead
SNAPSHOT_FORMAT = 1

_READ_ONLY = frozenset({"worlds", "landmarks", "relations", "drm", "facts", "params",
                        "snapshot",
                        "engine", "query", "eigenspace_transition",
                        "eigenspace_covering", "slam_summary", "slam_regions_near",
                        "viewpoint_scene"})


class WorldService:
    def __init__(self, store: Store, kb: KnowledgeBase,
                 max_event_streams: int = MAX_SUBSCRIBERS) -> None:
        self.store, self.kb = store, kb
        #: live events of every world (GET /worlds/{world}/events)
        self.events = EventHub(max_event_streams)
        self._write = asyncio.Lock()
        self._models: dict[str, World] = {}
        # DRM graphs per world, tagged with the world's version (bumped on every change)
        self._drm_graphs: dict[str, tuple[int, nx.DiGraph]] = {}
        self._versions: dict[str, int] = {}
        #: called with the world's name after it is deleted (caches elsewhere drop it)
        self.on_delete: list[Callable[[str], None]] = []
        #: called with the world's name when it is reloaded because another process
        #: wrote it (caches of its artifacts drop them)
        self.on_reload: list[Callable[[str], None]] = []
        #: what of each world the knowledge base holds: the store's (created_at, version)
        #: when it was loaded, kept in step with this service's own writes
        self._loaded: dict[str, tuple[float, int]] = {}
        #: the artifact kinds whose facts a world's knowledge base holds (register)
        self.artifacts: dict[str, ArtifactKind] = {}
        self._since_snapshot: dict[str, int] = {}  # events appended since the snapshot

    def register(self, kind: ArtifactKind) -> None:
        """Declare an artifact kind: :meth:`ready` re-asserts it when it loads a world and
        :meth:`write_artifact` writes it."""
        self.artifacts[kind.name] = kind

    # -- loading on demand -----------------------------------------------------------
    async def ready(self, name: str) -> None:
        """Make sure the knowledge base holds world ``name`` as the store has it now:
        loaded if it is not yet, reloaded if another process wrote it since, dropped
        (and 404, NotFound) if it is gone. One indexed read when nothing changed."""
        if self._loaded.get(name) == self.store.world_version(name) is not None:
            return
        async with self._write:
            await self._ready_locked(name)

    async def ask(self, world: str, op: str, **args: Any) -> Any:
        """A read of ``world``'s facts by knowledge-base operation ``op``, the world
        loaded (or reloaded) first: how every service reads a world's knowledge base."""
        await self.ready(world)
        return await self.kb.acall(op, world=world, **args)

    async def _ready_locked(self, name: str) -> None:
        """:meth:`ready` for a caller holding the writers' lock."""
        version = self.store.world_version(name)
        loaded = self._loaded.get(name)
        if version is not None and loaded == version:
            return
        if loaded is not None:  # deleted or written by another process
            self._loaded.pop(name, None)
            self._models.pop(name, None)
            for hook in self.on_delete if version is None else self.on_reload:
                hook(name)
            if version is None:
                self._since_snapshot.pop(name, None)
                try:
                    await self._kb("drop_world", {"world": name})
                except KbError:
                    log.exception("dropping world %s from the knowledge base", name)
        row = self.store.world(name)
        if row is None:
            raise NotFound(f"world {name!r} does not exist", field="world")
        await self._load_into_kb(WorldDescription.model_validate(row.description))

    async def _load_into_kb(self, desc: WorldDescription) -> None:
        """(Re)build one world from the store: its description, its snapshot and the
        events after it in order, then every registered artifact it has."""
        name = desc.name
        version = self.store.world_version(name)
        self._changed(name)
        await self._kb("create_world", self.create_call(desc))
        after = await self._load_snapshot(desc)
        events = self.store.events(name, after)
        await asyncio.to_thread(self._replay, name, events)  # off the event loop, in order
        self._since_snapshot[name] = len(events)
        for kind in self.artifacts.values():
            blob = self.store.artifact(name, kind.name)
            if blob is not None:
                await self._kb(kind.op, kind.call(name, blob))
        self._models[name] = World(desc)
        if version is not None:
            self._loaded[name] = version

    def _replay(self, name: str, events: list[Event]) -> None:
        """Apply stored events to the world's facts in order, REPLAY_BATCH to an engine
        call (api.pl's batch: a round trip costs as much as an event's own work), from
        a worker thread, off the event loop."""
        for i in range(0, len(events), REPLAY_BATCH):
            calls = [dict(zip(("op", "args"), self.event_call(name, ev.kind, ev.payload),
                              strict=True)) for ev in events[i:i + REPLAY_BATCH]]
            self.kb.call("batch", calls=calls)

    @contextmanager
    def _own_write(self, world: str) -> Iterator[sqlite3.Connection]:
        """A store transaction of this service's on ``world``, whose knowledge base
        already has the change: the loaded version follows it, unless another process
        wrote the world in between (then the next :meth:`ready` reloads it)."""
        with self.store.transaction() as conn:
            before = self.store.world_version(world)
            yield conn
            after = self.store.world_version(world)
        if before is not None and self._loaded.get(world) == before and after is not None:
            self._loaded[world] = after

    async def _load_snapshot(self, desc: WorldDescription) -> int:
        """Load the world's snapshot if the rules that made it are the ones loaded now;
        returns the last event it covers (0: replay every event). A snapshot the rules
        refuse is dropped, and the world is rebuilt from its events alone."""
        try:
            snap = self.store.snapshot(desc.name)
        except Exception:  # noqa: BLE001 - an unreadable row is a stale one
            log.exception("snapshot of %s unreadable", desc.name)
            snap = (0, "", [])
        if snap is None:
            return 0
        event_id, rules, facts = snap
        if rules == self._snapshot_key():
            try:
                await self._kb("load_snapshot", {"world": desc.name, "facts": facts})
                return event_id
            except KbError:
                log.exception("snapshot of %s refused: replaying its events", desc.name)
                await self._kb("create_world", self.create_call(desc))
        with self.store.transaction() as conn:  # stale: the next one is made afresh
            self.store.delete_snapshot(conn, desc.name)
        return 0

    def _snapshot_key(self) -> str:
        """What a snapshot's facts depend on: the rules and the Python side of events."""
        return f"{self.kb.rules_digest}:{SNAPSHOT_FORMAT}"

    # -- the one artifact write path -------------------------------------------------------
    @asynccontextmanager
    async def write_artifact(self, world: str, kind: str) -> AsyncIterator[ArtifactWrite]:
        """A unit of work on one of ``world``'s artifacts: holds the world writers' lock
        (so no other mutation interleaves), 404s for an unknown world, and yields an
        :class:`ArtifactWrite` whose ``commit`` asserts the facts and stores the blobs.
        If anything in the block fails -- the work before the commit (which may itself
        have asserted facts, as viewpoint grouping does), the assert or the store
        write -- the world's facts of that kind are put back to the stored ones (none
        if there are none), and the error propagates."""
        art = self.artifacts[kind]
        async with self._write:
            await self._ready_locked(world)
            previous = self.store.artifact(world, art.name)
            try:
                yield ArtifactWrite(self, world, art)
            except BaseException:
                # shielded: a second cancellation (a shutdown) must not drop the rollback
                # from the engine's queue and leave facts the store does not have
                undo = asyncio.ensure_future(
                    self._kb(art.op, art.call(world, previous)) if previous is not None
                    else self._kb("clear_facts", {"world": world, "domain": art.domain}))
                cancelled = False
                while not undo.done():  # held under the lock until the undo has run
                    try:
                        await asyncio.shield(undo)
                    except asyncio.CancelledError:
                        cancelled = True
                    except Exception:  # noqa: BLE001 - logged below
                        pass
                if not undo.cancelled() and undo.exception() is not None:
                    log.error("putting back %s facts of %s failed: %s", art.name, world,
                              undo.exception())
                if cancelled:
                    raise asyncio.CancelledError from None
                raise

    @staticmethod
    def create_call(desc: WorldDescription) -> dict[str, Any]:
        """The knowledge-base arguments that create ``desc``'s world."""
        params = {RENAMED_PARAMETERS.get(k, k): v for k, v in desc.parameters.items()}
        return {"world": desc.name, "landmarks": [lm.id for lm in desc.landmarks],
                "rule_probabilities": desc.rule_probabilities, "parameters": params}

    @staticmethod
    def event_call(world: str, kind: str,
                    payload: dict[str, Any]) -> tuple[str, dict[str, Any]]:
        if kind == "observation":
            obs = Observation.model_validate(payload)
            angles, distances = observation_quantities(obs)
            return ("observe", {"world": world, "at": obs.at,
                                "seen": [{"landmark": s.landmark, "features": s.features}
                                         for s in obs.seen],
                                "angles": angles, "distances": distances})
        if kind in ("reached", "failed"):
            return (kind, {"world": world, "from": payload["from"], "to": payload["to"]})
        raise ValueError(f"unknown event kind {kind!r}")

    async def _kb(self, op: str, args: dict[str, Any]) -> Any:
        if op not in _READ_ONLY:
            self._changed(str(args.get("world")))
        return await self.kb.acall(op, **args)

    def _changed(self, world: str) -> None:
        self._versions[world] = self._versions.get(world, 0) + 1
        self._drm_graphs.pop(world, None)

    # -- worlds ------------------------------------------------------------------------
    async def create(self, desc: WorldDescription) -> WorldSummary:
        desc = resolve_description(desc)
        async with self._write:
            if self.store.world(desc.name) is not None:
                raise Conflict(f"world {desc.name!r} already exists", field="name")
            await self._kb("create_world", self.create_call(desc))
            try:
                with self.store.transaction() as conn:
                    self.store.insert_world(conn, desc.name, desc.model_dump(mode="json"))
            except BaseException:
                await self._kb("drop_world", {"world": desc.name})
                raise
            self._models[desc.name] = World(desc)
            version = self.store.world_version(desc.name)
            if version is not None:
                self._loaded[desc.name] = version
        return self.summary(desc.name)

    def require(self, name: str) -> None:
        """404 (NotFound) unless world ``name`` exists; cheap (no geometry is built, and
        the knowledge base is not loaded: :meth:`ready` before asking it)."""
        if name not in self._models and self.store.world(name) is None:
            raise NotFound(f"world {name!r} does not exist", field="world")

    def model(self, name: str) -> World:
        if name not in self._models:
            row = self.store.world(name)
            if row is None:
                raise NotFound(f"world {name!r} does not exist", field="world")
            self._models[name] = World(WorldDescription.model_validate(row.description))
        return self._models[name]

    def cached_model(self, name: str) -> Cached:
        """World ``name`` as compute workers receive it (its description, by digest)."""
        blob = self.model(name).description.model_dump_json().encode()
        return Cached(blob_key(blob), blob, load_world)

    def summary(self, name: str) -> WorldSummary:
        """What the world holds: its template, landmarks, walls, objects, events and the
        kinds of its stored artifacts."""
        d = self.model(name).description
        return WorldSummary(name=d.name, template=d.template, landmarks=len(d.landmarks),
                            walls=len(d.walls), objects=len(d.objects),
                            events=self.store.event_count(name),
                            artifacts=self.store.artifact_kinds(name))

    def names(self) -> list[str]:
        return self.store.world_names()

    def count(self) -> int:
        """How many worlds are stored (one count, whatever their number)."""
        return self.store.world_count()

    async def delete(self, name: str) -> None:
        async with self._write:
            self.require(name)
            with self.store.transaction() as conn:
                self.store.delete_world(conn, name)
            self._models.pop(name, None)
            loaded = self._loaded.pop(name, None) is not None
            self._since_snapshot.pop(name, None)
            for hook in self.on_delete:
                hook(name)
            self.events.publish(name, "world_deleted", {"world": name})
            self.events.close_world(name)
            if not loaded:
                return
            try:
                await self._kb("drop_world", {"world": name})
            except KbError:
                log.exception("dropping world %s from the knowledge base", name)

    # -- qualitative navigation ---------------------------------------------------------
    async def _append(self, world: str, kind: str, payload: dict[str, Any]) -> Any:
        async with self._write:
            await self._ready_locked(world)
            op, args = self.event_call(world, kind, payload)
            result = await self._kb(op, args)
            try:
                with self._own_write(world) as conn:
                    event_id = self.store.append_event(conn, world, kind, payload)
            except BaseException:
                log.exception("store write failed; rebuilding %s from the store", world)
                self._loaded.pop(world, None)
                await self._load_into_kb(self.model(world).description)
                raise
            n = self._since_snapshot[world] = self._since_snapshot.get(world, 0) + 1
            if n >= SNAPSHOT_EVERY:
                await self._snapshot(world, event_id)
            return result

    async def _snapshot(self, world: str, event_id: int) -> None:
        """Store the world's event-made facts as of event ``event_id`` (the caller holds
        the writers' lock). A failure only costs the next start-up a longer replay."""
        try:
            facts = await self._kb("snapshot", {"world": world})
            with self.store.transaction() as conn:
                self.store.put_snapshot(conn, world, event_id, self._snapshot_key(),
                                        list(facts))
        except Exception:  # noqa: BLE001 - the events are stored; replay still works
            log.exception("snapshot of %s failed", world)
        self._since_snapshot[world] = 0  # after a failure too: try again SNAPSHOT_EVERY on

    async def observe(self, world: str, obs: Observation) -> Any:
        return await self._append(world, "observation", obs.model_dump(mode="json"))

    async def reached(self, world: str, source: str, target: str) -> Any:
        return await self._append(world, "reached", {"from": source, "to": target})

    async def failed(self, world: str, source: str, target: str) -> Any:
        """The robot set out on the DRM arc ``source`` -> ``target`` and did not arrive."""
        return await self._append(world, "failed", {"from": source, "to": target})

    async def relations(self, world: str, kind: str) -> list[dict[str, Any]]:
        return list(await self.ask(world, "relations", kind=kind))

    async def drm(self, world: str) -> dict[str, Any]:
        return dict(await self.ask(world, "drm"))

    async def drm_graph(self, world: str) -> nx.DiGraph:
        """The DRM as a networkx graph, cached until the world changes."""
        version = self._versions.get(world, 0)
        cached = self._drm_graphs.get(world)
        if cached is not None and cached[0] == version:
            return cached[1]
        drm = await self.drm(world)
        g = build_drm(drm["nodes"], edges_from_records(drm["edges"]))
        if self._versions.get(world, 0) == version:  # no change while we were reading
            self._drm_graphs[world] = (version, g)
        return g

    async def path(self, world: str, source: str, target: str) -> DrmPath | None:
        await self.ready(world)
        g = await self.drm_graph(world)
        for field, lm in (("from", source), ("to", target)):
            if lm not in g:
                raise InvalidInput(f"landmark {lm!r} is not in world {world!r}", field=field)
        return max_probability_path(g, source, target)

    async def query(self, world: str, goal: str, max_solutions: int) -> dict[str, Any]:
        """A read-only, whitelisted Prolog query over the world (prolog/query.pl)."""
        return dict(await self.ask(world, "query", goal=goal, max_solutions=max_solutions))

    async def facts(self, world: str) -> list[str]:
        return list(await self.ask(world, "facts"))
