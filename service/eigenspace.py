"""Eigenspace localization in the service: learning jobs, one-turn localization,
multi-stop sessions and the movement strategy's next move.

Flow: ``numeric.eigenspace`` computes; the knowledge base receives the learning
points, triplets and candidate-multiple sets as facts (``eigenspace_facts``) and
decides every X / Y^(m) / Z transition by the Fig. 4 rules in
``prolog/eigenspace.pl`` (``eigenspace_transition``).  Analyses and sessions are
stored in SQLite, so both survive a restart; a learning job is a durable job
(:mod:`service.jobs`): one still running at a restart is reported ``interrupted``
(its result was not stored) and must be posted again.
"""

from __future__ import annotations

import asyncio
import logging
import uuid
from concurrent.futures import Executor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from numeric.camera import Camera, CameraConfig
from numeric.eigenspace.analysis import (
    EigenspaceAnalysis,
    EigenspaceConfig,
    Progress,
    analyse_images,
    learning_pixels,
)
from numeric.eigenspace.image_sets import ImageSet
from numeric.eigenspace.learning_strategy import learn_with_strategy
from numeric.eigenspace.localization import (
    Session,
    Vote,
    session_from_dict,
    session_to_dict,
    turn_candidates,
)
from numeric.eigenspace.movement_strategy import (
    choose_action,
    initial_samples,
    session_belief,
)
from numeric.errors import InvalidInput, NotFound
from service.jobs import JobProgress, Jobs
from service.kb import KnowledgeBase
from service.store import Store
from service.worlds import ArtifactKind, WorldService

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


class EigenspaceService:
    def __init__(self, store: Store, kb: KnowledgeBase, worlds: WorldService, jobs: Jobs,
                 executor: Executor | None = None,
                 max_learning_pixels: int = 200_000_000) -> None:
        self.store, self.kb, self.worlds, self.jobs = store, kb, worlds, jobs
        #: a learning job renders at most this many pixels (the paper's room: 5 M)
        self.max_learning_pixels = max_learning_pixels
        self.executor = executor  # for the Monte Carlo strategy; None = in-process
        self._analyses: dict[str, EigenspaceAnalysis] = {}
        self._session_lock = asyncio.Lock()
        worlds.on_delete.append(self._forget)
        worlds.register(ArtifactKind(
            ARTIFACT, "eigenspace_facts", "eigenspace",
            lambda world, blob: facts_call(world, EigenspaceAnalysis.from_bytes(blob))))

    def _forget(self, world: str) -> None:
        self._analyses.pop(world, None)

    def analysis(self, world: str) -> EigenspaceAnalysis:
        self.worlds.require(world)
        a = self._analyses.get(world)
        if a is None:
            blob = self.store.artifact(world, ARTIFACT)
            if blob is None:
                raise NotFound(f"world {world!r} has no eigenspace yet; POST "
                               f"/worlds/{world}/eigenspace first", field="world")
            a = self._analyses[world] = EigenspaceAnalysis.from_bytes(blob)
        return a

    # -- learning -----------------------------------------------------------------------
    def start_learning(self, world: str, config: EigenspaceConfig,
                       images: ImageSet | None = None) -> dict[str, Any]:
        """A durable learning job (:mod:`service.jobs`): in the simulator, or from a
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

        async def work(progress: JobProgress) -> dict[str, Any]:
            a = await self.learn(world, config, images, progress)
            return a.summary(self.worlds.model(world))

        return self.jobs.start(world, LEARNING_JOB, work)

    def job(self, world: str, job_id: str) -> dict[str, Any]:
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
        async with self.worlds.write_artifact(world, ARTIFACT) as write:
            await write.commit(a.to_bytes(), call=facts_call(world, a))
            self._analyses[world] = a
        return a

    def summary(self, world: str) -> dict[str, Any]:
        """The analysis summary plus what it learned: the learning points (id, x, y) and
        the localizable triplets (their points' ids, the three directions, the triangle's
        area, the common target and the candidate-multiple set, if any)."""
        a = self.analysis(world)
        out = a.summary(self.worlds.model(world))
        facts = facts_call(world, a)  # the rows the knowledge base is given, plus more
        set_of, target = a.set_of(), a.triplets.target
        out["points"] = [{"id": i, "x": x, "y": y} for i, (x, y) in enumerate(facts["points"])]
        out["triplet_list"] = [
            {"id": i, **row, "target": {"x": float(target[i, 0]), "y": float(target[i, 1])},
             "candidate_set": None if set_of[i] < 0 else int(set_of[i])}
            for i, row in enumerate(facts["triplets"])]
        return out

    # -- localization ---------------------------------------------------------------------
    def _check_turn(self, a: EigenspaceAnalysis, images: np.ndarray) -> np.ndarray:
        n = len(a.model.directions)
        if images.ndim != 3 or len(images) != n:
            raise InvalidInput(f"one full turn is {n} images (relative headings 2*pi*j/{n}); "
                               f"got {len(images) if images.ndim else 0}", field="images")
        return a.model.check_images(images)

    async def _transition(self, world: str, state: dict[str, Any], triplets: list[int],
                          unique: bool) -> dict[str, Any]:
        r = await self.kb.acall("eigenspace_transition", world=world, state=state,
                                triplets=triplets, unique=unique)
        return dict(r)

    def _report(self, a: EigenspaceAnalysis, st: SessionState, state: dict[str, Any],
                outcome: str, vote: Vote | None = None) -> dict[str, Any]:
        """The answer: state, outcome, pose (in state Z), candidates; ``vote`` is the
        session's current vote when the caller has it already."""
        s = st.session
        vote = vote if vote is not None else s.vote(a.set_of())
        cands = []
        for cluster, best in list(zip(vote.clusters, s.representatives(vote), strict=True))[:10]:
            p = s.current_pose(best)
            cands.append({"pose": {"x": float(p[0]), "y": float(p[1]), "theta": float(p[2])},
                          "votes": float(vote.votes[best]), "triplet": s.triplet[best],
                          "members": len(cluster)})
        pose = None
        if state.get("state") == "z" and vote.winner is not None:
            p = s.estimate(vote)
            pose = {"x": float(p[0]), "y": float(p[1]), "theta": float(p[2])}
        return {"state": state, "outcome": outcome, "pose": pose, "stops": s.stops,
                "unique": vote.unique, "candidates": cands}

    async def localize(self, world: str, images: np.ndarray) -> dict[str, Any]:
        """One stop from state X: state, pose (when Z) and candidates."""
        a = self.analysis(world)
        imgs = self._check_turn(a, images)
        st = SessionState(world, Session(a.config.localization))
        cands = await asyncio.to_thread(turn_candidates, a.regions, imgs)
        st.session.add_stop(cands, a.config.regions.d_thd_m)
        vote = st.session.vote(a.set_of())
        r = await self._transition(world, st.state, st.session.stop_triplets(0), vote.unique)
        return self._report(a, st, r["state"], r["outcome"], vote)

    async def create_session(self, world: str) -> dict[str, Any]:
        a = self.analysis(world)
        st = SessionState(world, Session(a.config.localization))
        sid = uuid.uuid4().hex
        async with self._session_lock:
            with self.store.transaction() as conn:
                self.store.put_session(conn, sid, world, st.to_dict())
        return {"id": sid, "world": world, "state": st.state, "stops": 0}

    def _session(self, world: str, sid: str) -> SessionState:
        self.worlds.require(world)
        row = self.store.session(sid)
        if row is None or row[0] != world:
            raise NotFound(f"no localization session {sid!r} in world {world!r}",
                           field="session")
        return SessionState.from_dict(world, row[1])

    async def session(self, world: str, sid: str) -> dict[str, Any]:
        st = self._session(world, sid)
        out = self._report(self.analysis(world), st, st.state,
                           st.history[-1]["outcome"] if st.history else "none")
        return {"id": sid, **out}

    async def add_stop(self, world: str, sid: str, images: np.ndarray,
                       motion: np.ndarray | None) -> dict[str, Any]:
        """A stop: images of one full turn and the odometry (dx, dy, dtheta) since the
        previous stop's start, in that stop's frame."""
        a = self.analysis(world)
        imgs = self._check_turn(a, images)
        cands = await asyncio.to_thread(turn_candidates, a.regions, imgs)
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
        return {"id": sid, **self._report(a, st, st.state, r["outcome"], vote)}

    async def next_move(self, world: str, sid: str) -> dict[str, Any]:
        """The movement strategy's action (alpha, l, beta) and its Q(Z) (§3.5)."""
        a = self.analysis(world)
        st = self._session(world, sid)
        w = self.worlds.model(world)
        if st.state.get("state") == "z":
            return {"state": st.state, "action": None, "q_z": 1.0}
        cfg = a.config.strategy
        layout = a.layout(w)
        # samples of where stop 0 may have been (used while the state is X)
        samples0 = initial_samples(w.sample_free, cfg.n_samples,
                                   np.random.default_rng(a.config.seed + 11))
        m = st.state.get("set")
        now, belief = session_belief(st.session, layout, samples0,
                                     m if isinstance(m, int) else None)
        dec = await asyncio.to_thread(choose_action, now, belief, layout, cfg, self.executor)
        return {"state": st.state,
                "action": {"alpha_rad": float(dec.action[0]), "l_m": float(dec.action[1]),
                           "beta_rad": float(dec.action[2])}, "q_z": dec.q_z}

    async def covering(self, world: str, x: float, y: float) -> list[dict[str, Any]]:
        self.analysis(world)
        return list(await self.kb.acall("eigenspace_covering", world=world, x=x, y=y))

    # -- camera -------------------------------------------------------------------------
    def render(self, world: str, pose: np.ndarray, config: CameraConfig | None,
               turn: int | None) -> np.ndarray:
        w = self.worlds.model(world)
        if config is None:
            a = self._analyses.get(world)
            config = a.config.camera if a is not None else CameraConfig()
        cam = Camera(w, config)
        if turn is None:
            return cam.render(pose)[None]
        return cam.render_turn(pose[:2], float(pose[2]), turn)
