"""World service: one place that keeps the store and the knowledge base in step.

Write order for every mutation (under one asyncio lock, so writers never
interleave): validate -> apply to the knowledge base (atomic there, a Prolog
transaction) -> commit the event to SQLite.  If the commit fails the world is
rebuilt in the knowledge base from the store, so the two never disagree.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass
from typing import Any

import networkx as nx

from numeric.errors import Conflict, InvalidInput, NotFound
from numeric.observation import Observation, observation_quantities
from numeric.qualitative.drm import (
    DrmPath,
    build_drm,
    edges_from_records,
    max_probability_path,
)
from numeric.world import World, WorldDescription
from numeric.worlds import TEMPLATES, from_template
from service.compute import Cached, blob_key, load_world
from service.kb import KbError, KnowledgeBase
from service.schemas.common import WorldSummary
from service.store import Store

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
        with store.transaction() as conn:
            store.put_artifact(conn, self.world, self.kind.name, blob)
            for name, b in (extra or {}).items():
                store.put_artifact(conn, self.world, name, b)
        return self.reply


#: parameters that were renamed: worlds stored with the old name keep working
RENAMED_PARAMETERS = {"vp_unknown_min_area_m2": "unknown_region_min_area_m2"}

#: a world's event-made facts are snapshotted every this many events: start-up loads
#: the snapshot and replays only the events after it, so its time stays flat
SNAPSHOT_EVERY = 200
#: bumped whenever the Python side of an event (event_call, the quantities of an
#: observation) changes what its facts are: older snapshots are then replayed instead
SNAPSHOT_FORMAT = 1

_READ_ONLY = frozenset({"worlds", "landmarks", "relations", "drm", "facts", "params",
                        "snapshot",
                        "engine", "query", "eigenspace_transition",
                        "eigenspace_covering", "slam_summary", "slam_regions_near",
                        "viewpoint_scene"})


class WorldService:
    def __init__(self, store: Store, kb: KnowledgeBase) -> None:
        self.store, self.kb = store, kb
        self._write = asyncio.Lock()
        self._models: dict[str, World] = {}
        # DRM graphs per world, tagged with the world's version (bumped on every change)
        self._drm_graphs: dict[str, tuple[int, nx.DiGraph]] = {}
        self._versions: dict[str, int] = {}
        #: called with the world's name after it is deleted (caches elsewhere drop it)
        self.on_delete: list[Callable[[str], None]] = []
        #: the artifact kinds whose facts a world's knowledge base holds (register)
        self.artifacts: dict[str, ArtifactKind] = {}
        self._since_snapshot: dict[str, int] = {}  # events appended since the snapshot

    def register(self, kind: ArtifactKind) -> None:
        """Declare an artifact kind: :meth:`restore_all` re-asserts it and
        :meth:`write_artifact` writes it."""
        self.artifacts[kind.name] = kind

    # -- start-up ----------------------------------------------------------------------
    def restore_all(self) -> dict[str, int]:
        """Rebuild every stored world in the knowledge base: its description, its
        events in order, then every registered artifact it has. Returns how many worlds
        and how many of each artifact kind were restored. The app's start-up and every
        CLI command that opens worlds call this (:func:`service.container.open_services`),
        so ``chizu repl`` sees what the service sees."""
        counts = {"worlds": 0, **dict.fromkeys(self.artifacts, 0)}
        for row in self.store.worlds():
            for kind in self._load_into_kb(WorldDescription.model_validate(row.description)):
                counts[kind] += 1
            counts["worlds"] += 1
        return counts

    def _load_into_kb(self, desc: WorldDescription) -> list[str]:
        """(Re)build one world from the store; returns the artifact kinds it had."""
        self._changed(desc.name)
        self.kb.call("create_world", **self.create_call(desc))
        after = self._load_snapshot(desc)
        events = self.store.events(desc.name, after)
        for ev in events:
            op, args = self.event_call(desc.name, ev.kind, ev.payload)
            self.kb.call(op, **args)
        self._since_snapshot[desc.name] = len(events)
        restored = []
        for kind in self.artifacts.values():
            blob = self.store.artifact(desc.name, kind.name)
            if blob is not None:
                self.kb.call(kind.op, **kind.call(desc.name, blob))
                restored.append(kind.name)
        self._models[desc.name] = World(desc)
        return restored

    def _load_snapshot(self, desc: WorldDescription) -> int:
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
                self.kb.call("load_snapshot", world=desc.name, facts=facts)
                return event_id
            except KbError:
                log.exception("snapshot of %s refused: replaying its events", desc.name)
                self.kb.call("create_world", **self.create_call(desc))
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
            self.require(world)
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
        return self.summary(desc.name)

    def require(self, name: str) -> None:
        """404 (NotFound) unless world ``name`` exists; cheap (no geometry is built)."""
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
        """What the world holds: its template, landmarks, walls, objects and events."""
        d = self.model(name).description
        return WorldSummary(name=d.name, template=d.template, landmarks=len(d.landmarks),
                            walls=len(d.walls), objects=len(d.objects),
                            events=self.store.event_count(name))

    def names(self) -> list[str]:
        return [r.name for r in self.store.worlds()]

    async def delete(self, name: str) -> None:
        async with self._write:
            self.require(name)
            with self.store.transaction() as conn:
                self.store.delete_world(conn, name)
            self._models.pop(name, None)
            self._since_snapshot.pop(name, None)
            for hook in self.on_delete:
                hook(name)
            try:
                await self._kb("drop_world", {"world": name})
            except KbError:
                log.exception("dropping world %s from the knowledge base", name)

    # -- qualitative navigation ---------------------------------------------------------
    async def _append(self, world: str, kind: str, payload: dict[str, Any]) -> Any:
        async with self._write:
            self.require(world)
            op, args = self.event_call(world, kind, payload)
            result = await self._kb(op, args)
            try:
                with self.store.transaction() as conn:
                    event_id = self.store.append_event(conn, world, kind, payload)
            except BaseException:
                log.exception("store write failed; rebuilding %s from the store", world)
                self._load_into_kb(self.model(world).description)
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
        self.require(world)
        return list(await self._kb("relations", {"world": world, "kind": kind}))

    async def drm(self, world: str) -> dict[str, Any]:
        self.require(world)
        return dict(await self._kb("drm", {"world": world}))

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
        self.require(world)
        g = await self.drm_graph(world)
        for field, lm in (("from", source), ("to", target)):
            if lm not in g:
                raise InvalidInput(f"landmark {lm!r} is not in world {world!r}", field=field)
        return max_probability_path(g, source, target)

    async def query(self, world: str, goal: str, max_solutions: int) -> dict[str, Any]:
        """A read-only, whitelisted Prolog query over the world (prolog/query.pl)."""
        self.require(world)
        return dict(await self._kb("query", {"world": world, "goal": goal,
                                             "max_solutions": max_solutions}))

    async def facts(self, world: str) -> list[str]:
        self.require(world)
        return list(await self._kb("facts", {"world": world}))
