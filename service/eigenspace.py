"""Eigenspace localization in the service: learning jobs, one-turn localization,
multi-stop sessions and the movement strategy's next move.

Flow: ``chizu.numeric.eigenspace`` computes; the knowledge base receives the learning
points, triplets and candidate-multiple sets as facts (``eigenspace_facts``) and
decides every X / Y^(m) / Z transition by the Fig. 4 rules in
``prolog/eigenspace.pl`` (``eigenspace_transition``).  Analyses and sessions are
stored in SQLite, so both survive a restart; a learning job is a durable job
(:mod:`chizu.service.jobs`): one still running at a restart is reported ``interrupted``
(its result was not stored) and must be posted again.
"""

from __future__ import annotations

import asyncio
import io
import logging
import uuid
from concurrent.futures import Executor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from chizu.numeric.camera import CameraConfig
from chizu.numeric.eigenspace.analysis import (
    EigenspaceAnalysis,
    EigenspaceConfig,
    Progress,
    analyse_images,
    learning_pixels,
    raster_axes,
)
from chizu.numeric.eigenspace.image_sets import ImageSet
from chizu.numeric.eigenspace.learning_strategy import learn_with_strategy
from chizu.numeric.eigenspace.localization import (
    Session,
    session_from_dict,
    session_to_dict,
)
from chizu.numeric.errors import Conflict, InvalidInput, NotFound
from chizu.service.compute import (
    Cached,
    ComputePool,
    FirstStop,
    TurnPng,
    blob_key,
    camera_task,
    first_stop_task,
    next_move_task,
    session_report_task,
    turn_task,
)
from chizu.service.jobs import JobProgress, Jobs, Work
from chizu.service.schemas.eigenspace import (
    MAX_COVERAGE_CELLS,
    CameraOut,
    CoverageOut,
    EigenspaceOut,
    LearningPointOut,
    LocalizationOut,
    MoveOut,
    NextMoveOut,
    PointOut,
    SessionCreated,
    SessionLocalizationOut,
    TripletOut,
)
from chizu.service.schemas.jobs import JobOut
from chizu.service.store import Store
from chizu.service.worlds import ArtifactKind, WorldService

log = logging.getLogger(__name__)
LEARNING_JOB = "eigenspace_learning"
ARTIFACT = "eigenspace"


@dataclass
class SessionState:
    world: str
    session: Session
    state: dict[str, Any] = field(default_factory=lambda: {"state": "x"})
    history: list[dict[str, Any]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {"session": session_to_dict(self.session), "state": self.state,
                "history": self.history}

    @staticmethod
    def from_dict(world: str, d: dict[str, Any]) -> SessionState:
        return SessionState(world, session_from_dict(d["session"]), d["state"], d["history"])


def facts_call(world: str, a: EigenspaceAnalysis) -> dict[str, Any]:
    """Knowledge-base arguments that assert an analysis as facts."""
    t = a.triplets
    return {"world": world, "points": a.model.points.tolist(),
            "triplets": [{"points": t.point_idx[i].tolist(),
                          "directions_rad": a.model.directions[t.dir_idx[i]].tolist(),
                          "area_m2": float(t.area[i])} for i in range(len(t))],
            "candidate_sets": a.candidate_sets}


def check_source(config: EigenspaceConfig, from_images: bool) -> None:
    """The learning strategy adds points by rendering them: the simulator only (asked
    for by name with a camera's images: 422; by default it is left out)."""
    if (from_images and config.learning_strategy is not None
            and "learning_strategy" in config.model_fields_set):
        raise InvalidInput("the learning strategy (§4.2) adds learning points in the "
                           "simulator; a camera's image set cannot grow by itself: leave "
                           "learning_strategy null", field="config.learning_strategy")


#: the arrays of an :class:`ImageSet`, as a learning request stores them
IMAGE_SET_ARRAYS = ("points", "turns", "calib_poses", "calib_images")


def learning_request(config: EigenspaceConfig, images: ImageSet | None) -> bytes:
    """What a learning job is made again from after a restart: its configuration (JSON)
    and, for a camera's images, the decoded image set (an npz archive)."""
    arrays: dict[str, np.ndarray] = {
        "config": np.frombuffer(config.model_dump_json().encode(), dtype=np.uint8)}
    if images is not None:
        arrays |= {k: getattr(images, k) for k in IMAGE_SET_ARRAYS}
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)  # type: ignore[arg-type]
    return buf.getvalue()


def read_learning_request(request: bytes) -> tuple[EigenspaceConfig, ImageSet | None]:
    with np.load(io.BytesIO(request), allow_pickle=False) as z:
        config = EigenspaceConfig.model_validate_json(z["config"].tobytes())
        images = ImageSet(**{k: z[k] for k in IMAGE_SET_ARRAYS}) \
            if IMAGE_SET_ARRAYS[0] in z.files else None
    return config, images



class EigenspaceService:
    def __init__(self, store: Store, worlds: WorldService, jobs: Jobs,
                 compute: ComputePool, executor: Executor | None = None,
                 max_learning_pixels: int = 200_000_000) -> None:
        self.store, self.worlds, self.jobs = store, worlds, jobs
        #: decoding, projection and rendering run there (worker processes)
        self.compute = compute
        #: a learning job renders at most this many pixels (the paper's room: 5 M)
        self.max_learning_pixels = max_learning_pixels
        self.executor = executor  # for the Monte Carlo strategy; None = in-process
        self._analyses: dict[str, EigenspaceAnalysis] = {}
        self._blobs: dict[str, Cached] = {}  # the analyses as the compute workers get them
        self._session_lock = asyncio.Lock()
        worlds.on_delete.append(self._forget)
        worlds.on_reload.append(self._forget)
        jobs.resumable(LEARNING_JOB, lambda world, request: self._learning(
            world, *read_learning_request(request)))
        worlds.register(ArtifactKind(
            ARTIFACT, "eigenspace_facts", "eigenspace",
            lambda world, blob: facts_call(world, EigenspaceAnalysis.from_bytes(blob))))

    def _forget(self, world: str) -> None:
        self._analyses.pop(world, None)
        self._blobs.pop(world, None)

    def analysis(self, world: str) -> EigenspaceAnalysis:
        """The world's learned eigenspace; 404 without the world, 409 (field
        ``eigenspace``) while it has none: the world is there, the request needs what it
        does not know yet."""
        self.worlds.require(world)
        a = self._analyses.get(world)
        if a is None:
            blob = self.store.artifact(world, ARTIFACT)
            if blob is None:
                raise Conflict(f"world {world!r} has no eigenspace yet; POST "
                               f"/worlds/{world}/eigenspace first", field="eigenspace")
            a = self._keep(world, EigenspaceAnalysis.from_bytes(blob), blob)
        return a

    def _keep(self, world: str, a: EigenspaceAnalysis, blob: bytes) -> EigenspaceAnalysis:
        self._analyses[world] = a
        self._blobs[world] = Cached(blob_key(blob), blob, EigenspaceAnalysis.from_bytes)
        return a

    # -- learning -----------------------------------------------------------------------
    def start_learning(self, world: str, config: EigenspaceConfig,
                       images: ImageSet | None = None) -> JobOut:
        """A durable learning job (:mod:`chizu.service.jobs`): in the simulator, or from a
        camera's ``images``; its result is the analysis summary."""
        w = self.worlds.model(world)
        check_source(config, images is not None)
        try:
            n = 0 if images is not None else learning_pixels(w, config)
        except InvalidInput:  # a world the learning cannot use: the job says why
            n = 0
        if n > self.max_learning_pixels:
            raise InvalidInput(
                f"this learning would render up to {n:,} pixels (grid points and additions "
                f"x learning.n_directions x camera pixels x supersample²); at most "
                f"{self.max_learning_pixels:,}: a coarser learning.spacing_m, fewer "
                "directions or smaller images", field="learning.spacing_m")

        return self.jobs.start(world, LEARNING_JOB, self._learning(world, config, images),
                               learning_request(config, images))

    def _learning(self, world: str, config: EigenspaceConfig,
                  images: ImageSet | None) -> Work:
        """A learning job's work; after a restart it is made again from its stored
        request (:func:`learning_request`): the learning is deterministic given it."""

        async def work(progress: JobProgress) -> dict[str, Any]:
            a = await self.learn(world, config, images, progress)
            return a.summary(self.worlds.model(world))

        return work

    def job(self, world: str, job_id: str) -> JobOut:
        self.worlds.require(world)
        return self.jobs.get(job_id, world)

    async def learn(self, world: str, config: EigenspaceConfig,
                    images: ImageSet | None = None,
                    progress: Progress | None = None) -> EigenspaceAnalysis:
        """Learn and analyse (simulator, or ``images``), then assert the facts and store
        the analysis together: both or neither."""
        w = self.worlds.model(world)
        check_source(config, images is not None)
        if images is None:
            a = await asyncio.to_thread(learn_with_strategy, w, config, progress, self.executor)
        else:
            a = await asyncio.to_thread(analyse_images, w, images, config, progress)
        blob = a.to_bytes()
        async with self.worlds.write_artifact(world, ARTIFACT) as write:
            await write.commit(blob, call=facts_call(world, a))
            self._keep(world, a, blob)
        return a

    def learned(self, world: str) -> EigenspaceAnalysis:
        """:meth:`analysis` for the eigenspace's own resources (``/eigenspace`` and
        what hangs below it): 404 while there is none."""
        try:
            return self.analysis(world)
        except Conflict as e:
            raise NotFound(str(e), field="eigenspace") from None

    def summary(self, world: str) -> EigenspaceOut:
        """The analysis summary plus what it learned: the learning points (id, x, y) and
        the localizable triplets (their points' ids, the three directions, the triangle's
        area, the common target and the candidate-multiple set, if any)."""
        a = self.learned(world)
        facts = facts_call(world, a)  # the rows the knowledge base is given, plus more
        set_of, target = a.set_of(), a.triplets.target
        return EigenspaceOut(
            **a.summary(self.worlds.model(world)),
            points=[LearningPointOut(id=i, x=x, y=y)
                    for i, (x, y) in enumerate(facts["points"])],
            triplet_list=[
                TripletOut(id=i, **row, target=PointOut(x=float(target[i, 0]),
                                                        y=float(target[i, 1])),
                           candidate_set=None if set_of[i] < 0 else int(set_of[i]))
                for i, row in enumerate(facts["triplets"])])

    # -- localization ---------------------------------------------------------------------
    async def _transition(self, world: str, state: dict[str, Any], triplets: list[int],
                          unique: bool) -> dict[str, Any]:
        r = await self.worlds.ask(world, "eigenspace_transition", state=state,
                                  triplets=triplets, unique=unique)
        return dict(r)

    async def _report(self, world: str, session: Session) -> dict[str, Any]:
        """:func:`chizu.service.compute.stop_report` of a session, computed in a compute
        worker (the estimate interpolates the whole latest turn against the walls)."""
        return await self.compute.run_cached(
            session_report_task, (self._blobs[world], self.worlds.cached_model(world)),
            session)

    @staticmethod
    def _answer(state: dict[str, Any], outcome: str, report: dict[str, Any]
                ) -> dict[str, Any]:
        """The fields of an answer: the state (as the Fig. 4 rules gave it), outcome, pose
        (in state Z), candidates (``report``: :func:`chizu.service.compute.stop_report`)."""
        pose = report["estimate"] if state.get("state") == "z" else None
        return {"state": state, "outcome": outcome, "pose": pose, "stops": report["stops"],
                "unique": report["unique"], "candidates": report["candidates"],
                "refused_by": report["refused_by"], "answered_by": report["answered_by"]}

    async def localize(self, world: str, turn: list[str] | TurnPng | np.ndarray) -> LocalizationOut:
        """One stop from state X: state, pose (when Z) and candidates. The turn is
        decoded, matched, voted on and reported in a compute worker; the Fig. 4 rules
        decide the state."""
        self.analysis(world)
        r1: FirstStop = await self.compute.run_cached(
            first_stop_task, (self._blobs[world], self.worlds.cached_model(world)), turn)
        r = await self._transition(world, {"state": "x"}, r1.triplets, r1.unique)
        return LocalizationOut(**self._answer(r["state"], r["outcome"], r1.report))

    async def create_session(self, world: str) -> SessionCreated:
        a = self.analysis(world)
        st = SessionState(world, Session(a.config.localization))
        sid = uuid.uuid4().hex
        async with self._session_lock:
            with self.store.transaction() as conn:
                self.store.put_session(conn, sid, world, st.to_dict())
        return SessionCreated(id=sid, world=world, state=st.state, stops=0)

    def _session(self, world: str, sid: str) -> SessionState:
        self.worlds.require(world)
        row = self.store.session(sid)
        if row is None or row[0] != world:
            raise NotFound(f"no localization session {sid!r} in world {world!r}",
                           field="session")
        return SessionState.from_dict(world, row[1])

    async def session(self, world: str, sid: str) -> SessionLocalizationOut:
        self.analysis(world)
        st = self._session(world, sid)
        return SessionLocalizationOut(id=sid, **self._answer(
            st.state, st.history[-1]["outcome"] if st.history else "none",
            await self._report(world, st.session)))

    async def add_stop(self, world: str, sid: str, turn: list[str] | TurnPng | np.ndarray,
                       motion: np.ndarray | None) -> SessionLocalizationOut:
        """A stop: images of one full turn and the odometry (dx, dy, dtheta) since the
        previous stop's start, in that stop's frame."""
        a = self.analysis(world)  # 409 before the work
        self._session(world, sid)
        cands = await self.compute.run_cached(
            turn_task, (self._blobs[world], self.worlds.cached_model(world)), turn)
        async with self._session_lock:  # read-modify-write of one session at a time
            st = self._session(world, sid)
            if st.session.stops > 0 and motion is None:
                raise InvalidInput("odometry since the previous stop is required after the "
                                   "first stop", field="odometry")
            st.session.add_stop(cands, a.config.regions.d_thd_m, motion)
            vote = st.session.vote(a.set_of())
            k = st.session.stops - 1
            r = await self._transition(world, st.state, st.session.stop_triplets(k),
                                       vote.unique)
            st.state = r["state"]
            st.history.append({"stop": k, "outcome": r["outcome"], "state": r["state"]})
            with self.store.transaction() as conn:
                self.store.put_session(conn, sid, world, st.to_dict())
        return SessionLocalizationOut(id=sid, **self._answer(
            st.state, r["outcome"], await self._report(world, st.session)))

    async def next_move(self, world: str, sid: str) -> NextMoveOut:
        """The movement strategy's action (alpha, l, beta) and its Q(Z) (§3.5),
        computed in a compute worker."""
        self.analysis(world)
        st = self._session(world, sid)
        if st.state.get("state") == "z":
            return NextMoveOut(state=st.state, action=None, q_z=1.0)
        m = st.state.get("set")
        dec = await self.compute.run_cached(
            next_move_task, (self._blobs[world], self.worlds.cached_model(world)),
            st.session, m if isinstance(m, int) else None)
        return NextMoveOut(state=st.state,
                           action=MoveOut(alpha_rad=float(dec.action[0]),
                                          l_m=float(dec.action[1]),
                                          beta_rad=float(dec.action[2])), q_z=dec.q_z)

    async def coverage(self, world: str, cell_m: float) -> CoverageOut:
        """The eq.-7 coverage map (:meth:`EigenspaceAnalysis.coverage_map`)."""
        a = self.learned(world)
        w = self.worlds.model(world)
        xs, ys = raster_axes(w, cell_m)
        cells = len(xs) * len(ys)
        if cells > MAX_COVERAGE_CELLS:
            raise InvalidInput(f"a {cell_m} m raster of this world has {cells} cells, more "
                               f"than {MAX_COVERAGE_CELLS}: choose a larger cell",
                               field="cell_m")
        m = await asyncio.to_thread(a.coverage_map, w, cell_m)
        grid = [[None if not np.isfinite(v) else float(v) for v in row] for row in m.p_enter]
        return CoverageOut(origin=PointOut(x=float(m.origin[0]), y=float(m.origin[1])),
                           cell_m=cell_m, rows=m.p_enter.shape[0], columns=m.p_enter.shape[1],
                           share=m.share, p_enter=grid)

    async def covering(self, world: str, x: float, y: float) -> list[dict[str, Any]]:
        self.learned(world)
        return list(await self.worlds.ask(world, "eigenspace_covering", x=x, y=y))

    # -- camera -------------------------------------------------------------------------
    async def render(self, world: str, pose: np.ndarray, config: CameraConfig | None,
                     turn: int | None, fmt: str = "png") -> CameraOut:
        """The simulated camera at ``pose`` (one image, or a full turn), rendered and
        encoded in a compute worker: ``images_png`` or ``images`` (the other unset)."""
        self.worlds.require(world)
        if config is None:
            a = self._analyses.get(world)
            config = a.config.camera if a is not None else CameraConfig()
        return CameraOut(**await self.compute.run_cached(
            camera_task, self.worlds.cached_model(world), config, pose, turn, fmt))
