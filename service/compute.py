"""The compute pool: a request's CPU-heavy work (image decoding, eigenspace projection,
camera rendering) runs in worker processes, each task under a time budget, and is
stopped when its client leaves.

Why processes: Python code holds the GIL, so numeric work in threads serialises with
the event loop and with each other -- localization did not scale past one core. Why
pebble (``pebble.ProcessPool``): a task over its budget, or cancelled because its
client disconnected, gets its worker process terminated and replaced; the standard
library's pools can only wait for it.

The workers are forked from a fork server (``multiprocessing`` "forkserver"), never
from the server itself, whose Prolog engine runs threads that must not be forked. The
task functions below import ``numeric`` only: no web, no Prolog in a worker.

A worker caches what it was sent by key (an eigenspace analysis is 0.5-5 MB): a task
is sent the key alone and answers :data:`MISS` when the worker has not seen it; the
pool then sends it again with the bytes.
"""

from __future__ import annotations

import asyncio
import base64
import binascii
import concurrent.futures
import contextlib
import hashlib
import logging
import multiprocessing
import os
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from multiprocessing import forkserver
from typing import Any, TypeVar

import numpy as np

from chizu.numeric.camera import Camera, CameraConfig
from chizu.numeric.eigenspace.analysis import EigenspaceAnalysis
from chizu.numeric.eigenspace.diagnosis import refusal
from chizu.numeric.eigenspace.image_sets import decode_image, encode_png
from chizu.numeric.eigenspace.localization import Session, TurnCandidates, Vote, turn_candidates
from chizu.numeric.eigenspace.movement_strategy import (
    Decision,
    choose_action,
    initial_samples,
    session_belief,
)
from chizu.numeric.errors import ChizuError, InvalidInput
from chizu.numeric.world import World, WorldDescription

log = logging.getLogger(__name__)
T = TypeVar("T")

MISS = "chizu-compute-cache-miss"  #: a task's answer when its worker lacks the cached bytes
_CACHE_ENTRIES = 4
_cache: OrderedDict[str, Any] = OrderedDict()  # per worker process (or the CLI's)
_cache_lock = threading.Lock()  # without workers, tasks run in threads of one process


class BudgetExceeded(ChizuError):
    """The request's computation ran past its time budget and was stopped."""


class WorkerLost(ChizuError):
    """The worker process running the request's computation died."""


def blob_key(blob: bytes) -> str:
    """The cache key of a blob: its content digest."""
    return hashlib.blake2b(blob, digest_size=16).hexdigest()


@dataclass(frozen=True)
class Cached:
    """Bytes a worker keeps once it has seen them, and how it turns them into an
    object (a module-level function, so that it pickles)."""

    key: str
    blob: bytes
    load: Callable[[bytes], Any]


def _cached(key: str, blob: bytes | None, load: Callable[[bytes], Any]) -> Any:
    """The object for ``key`` in this worker, built from ``blob`` on first use; MISS if
    the worker has not seen it and no bytes came with the task."""
    with _cache_lock:
        if key in _cache:
            _cache.move_to_end(key)
            return _cache[key]
        if blob is None:
            return MISS
        obj = _cache[key] = load(blob)
        while len(_cache) > _CACHE_ENTRIES:
            _cache.popitem(last=False)
        return obj


def _run_cached(fn: Callable[..., Any], keys: tuple[str, ...],
                blobs: tuple[bytes, ...] | None, loads: tuple[Callable[[bytes], Any], ...],
                args: tuple[Any, ...]) -> Any:
    """Worker side of :meth:`ComputePool.run_cached`."""
    objs = [_cached(k, None if blobs is None else b, load)
            for k, b, load in zip(keys, blobs or (None,) * len(keys), loads, strict=True)]
    if any(isinstance(o, str) and o == MISS for o in objs):
        return MISS
    return fn(*objs, *args)


@contextlib.contextmanager
def _environ(**env: str) -> Iterator[None]:
    """``os.environ`` with ``env`` added, for the processes started inside."""
    old = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


class ComputePool:
    """``workers`` processes (0: run tasks in a thread of this process, without a
    budget, for the CLI) and a default budget per task, in seconds."""

    def __init__(self, workers: int, budget_s: float) -> None:
        self.workers, self.budget_s = workers, budget_s
        self._pool: Any = None
        #: pools started again after breaking (GET /health reports it)
        self.restarts = 0
        if workers > 0:
            self._pool = self._start()

    def _start(self) -> Any:
        import pebble

        ctx = multiprocessing.get_context("forkserver")
        # the fork server imports the numeric stack once; each worker forks from it.
        # One BLAS thread per worker: the workers are the parallelism, and idle
        # OpenBLAS threads spin, taking cores from the other workers.
        ctx.set_forkserver_preload(["chizu.service.compute", "chizu.service.viewpoint_tasks"])
        with _environ(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1"):
            forkserver.ensure_running()
        return pebble.ProcessPool(max_workers=self.workers, context=ctx)

    def _schedule(self, fn: Callable[..., Any], args: tuple[Any, ...], budget: float) -> Any:
        """Schedule on the pool; a pool that broke (pebble raises RuntimeError once an
        idle worker was killed) is replaced by a new one, once."""
        try:
            return self._pool.schedule(fn, args=args, timeout=budget)
        except RuntimeError as e:
            log.error("the compute pool broke (%s): starting a new one", e)
            old, self._pool = self._pool, self._start()
            self.restarts += 1
            with contextlib.suppress(Exception):
                old.stop()
            return self._pool.schedule(fn, args=args, timeout=budget)

    async def run(self, fn: Callable[..., T], *args: Any, budget_s: float | None = None) -> T:
        """``fn(*args)`` in a worker, within ``budget_s`` (default: the pool's). Raises
        :class:`BudgetExceeded` past the budget (the worker is stopped), the task's own
        :class:`ChizuError`, or :class:`WorkerLost`. Cancelling the await (the client
        left) stops the worker too."""
        budget = self.budget_s if budget_s is None else budget_s
        if self._pool is None:
            return await asyncio.to_thread(fn, *args)
        fut = self._schedule(fn, args, budget)
        try:
            return await asyncio.wrap_future(fut)  # type: ignore[no-any-return]
        except concurrent.futures.TimeoutError as e:
            raise BudgetExceeded(f"the computation ran past its time budget of {budget:g} s "
                                 "and was stopped; ask for less (fewer or smaller images, a "
                                 "smaller problem)") from e
        except concurrent.futures.CancelledError:
            raise asyncio.CancelledError from None
        except ChizuError:
            raise
        except Exception as e:  # pebble's ProcessExpired: the worker died (killed, OOM)
            if type(e).__name__ == "ProcessExpired":
                log.error("compute worker died: %s", e)
                raise WorkerLost("the worker process computing this request died; try "
                                 "again, with a smaller request if it happens again") from e
            raise

    async def run_cached(self, fn: Callable[..., T], cached: Cached | tuple[Cached, ...],
                         *args: Any, budget_s: float | None = None) -> T:
        """``fn(*objs, *args)`` where each ``obj = c.load(c.blob)`` of ``cached`` is built
        once per worker: the bytes travel only to a worker that has not seen them."""
        cs = cached if isinstance(cached, tuple) else (cached,)
        keys, loads = tuple(c.key for c in cs), tuple(c.load for c in cs)
        if self._pool is None:  # in this process, with the workers' own cache
            return await asyncio.to_thread(_run_cached, fn, keys, tuple(c.blob for c in cs),
                                           loads, args)  # type: ignore[return-value]
        r = await self.run(_run_cached, fn, keys, None, loads, args, budget_s=budget_s)
        if isinstance(r, str) and r == MISS:
            r = await self.run(_run_cached, fn, keys, tuple(c.blob for c in cs), loads, args,
                               budget_s=budget_s)
        return r  # type: ignore[no-any-return]

    def close(self) -> None:
        if self._pool is not None:
            self._pool.stop()
            self._pool.join(timeout=10)
            self._pool = None


# -- tasks (run in a worker; numeric only) -------------------------------------------------
def b64_bytes(text: str, field: str) -> bytes:
    """The bytes of a base64 field; 422 naming it if it is not base64."""
    try:
        return base64.b64decode(text, validate=True)
    except (binascii.Error, ValueError) as e:
        raise InvalidInput(f"not base64: {e}", field=field) from e


def decode_png_turn(images_png: list[str], shape: tuple[int, int] | None) -> np.ndarray:
    """One turn ``(n, H, W)`` from base64 PNG images; a PNG whose header is not
    ``shape`` (H, W) is refused before it is decoded; 422 naming the image."""
    out = [decode_image(f"images_png[{i}]", b64_bytes(s, f"images_png[{i}]"),
                        formats=("PNG",), expect=None if shape is None else (shape[1], shape[0]))
           for i, s in enumerate(images_png)]
    return stack_turn(out, "images_png")


@dataclass(frozen=True)
class TurnPng:
    """A turn as one base64 PNG, its images side by side (``TurnIn.turn_png``)."""

    b64: str


def decode_turn_png(turn: TurnPng, shape: tuple[int, int], n: int) -> np.ndarray:
    """The turn ``(n, H, W)`` of one base64 PNG holding its n images of ``shape`` (H, W)
    side by side, left to right: one file decoded instead of n (its header checked
    first: exactly n x W by H px); 422 naming ``turn_png``."""
    h, w = shape
    strip = decode_image("turn_png", b64_bytes(turn.b64, "turn_png"), formats=("PNG",),
                         expect=(n * w, h), max_side_px=max(n * w, h))
    return np.ascontiguousarray(strip.reshape(h, n, w).transpose(1, 0, 2))


def stack_turn(images: list[np.ndarray], field: str) -> np.ndarray:
    """One turn ``(n, H, W)`` from decoded images, which must share one size."""
    if len({a.shape for a in images}) != 1:
        raise InvalidInput("all images must have the same size", field=field)
    return np.stack(images)


def check_turn(a: EigenspaceAnalysis, images: np.ndarray) -> np.ndarray:
    """A full turn for analysis ``a``: as many images as it has directions, each of its
    size, finite, in [0, 1]; 422 naming ``images`` otherwise."""
    n = len(a.model.directions)
    if images.ndim != 3 or len(images) != n:
        raise InvalidInput(f"one full turn is {n} images (relative headings 2*pi*j/{n}); "
                           f"got {len(images) if images.ndim else 0}", field="images")
    return a.model.check_images(images)


@dataclass(frozen=True)
class FirstStop:
    """A one-stop localization computed in a worker: the triplets the turn entered,
    whether the vote is unique (what the Fig. 4 rules decide the state from) and the
    answer's report (:func:`stop_report`)."""

    triplets: list[int]
    unique: bool
    report: dict[str, Any]


def turn_task(a: EigenspaceAnalysis, world: World, turn: list[str] | TurnPng | np.ndarray
              ) -> TurnCandidates:
    """One turn's region hits (Ohta et al. §3.4: project, region test; the whole-turn
    check against the world's walls). ``turn``: base64 PNGs, one PNG of the whole turn,
    or images."""
    if isinstance(turn, TurnPng):
        imgs = decode_turn_png(turn, a.model.image_shape, len(a.model.directions))
    else:
        imgs = decode_png_turn(turn, a.model.image_shape) if isinstance(turn, list) else turn
    return turn_candidates(a.regions, check_turn(a, imgs),
                           (world.surfaces.a, world.surfaces.b), a.localization)


def first_stop_task(a: EigenspaceAnalysis, world: World,
                    turn: list[str] | TurnPng | np.ndarray) -> FirstStop:
    """A localization from one turn (state X): its hits, the new session's vote (§2.5)
    and the report; only these travel back, not the session."""
    s = Session(a.config.localization)
    s.add_stop(turn_task(a, world, turn), a.config.regions.d_thd_m)
    vote = s.vote(a.set_of())
    return FirstStop(s.stop_triplets(0), vote.unique, stop_report(a, world, s, vote))


def stop_report(a: EigenspaceAnalysis, world: World, s: Session,
                vote: Vote) -> dict[str, Any]:
    """What an answer says of a session's vote: up to 10 candidate poses (the best of
    each cluster of agreeing hits, with its votes, triplet and cluster size), whether
    the vote is unique, the pose estimate (used when the state is Z; with the
    eigenspace and the world's walls it also interpolates the whole latest turn,
    :func:`chizu.numeric.eigenspace.localization.whole_turn_fit`), what made it unique
    (the vote, or the whole-turn check) and, when not unique, which test refused it
    (:func:`chizu.numeric.eigenspace.diagnosis.refusal`)."""
    cands = []
    for cluster, best in list(zip(vote.clusters, s.representatives(vote), strict=True))[:10]:
        p = s.current_pose(best)
        cands.append({"pose": {"x": float(p[0]), "y": float(p[1]), "theta": float(p[2])},
                      "votes": float(vote.votes[best]), "triplet": s.triplet[best],
                      "members": len(cluster)})
    est = None
    if vote.winner is not None:
        p = s.estimate(vote, a.model, (world.surfaces.a, world.surfaces.b))
        est = {"x": float(p[0]), "y": float(p[1]), "theta": float(p[2])}
    why = refusal(a.regions, s, vote)
    refused_by = None if why is None else {
        "test": why.reason, "d_err_min_m": None if why.d_err_min_m is None
        or not np.isfinite(why.d_err_min_m) else why.d_err_min_m,
        "votes": why.votes, "rival_votes": why.rival_votes}
    answered_by = None if not vote.unique else "whole_turn_check" if vote.checked else "vote"
    return {"candidates": cands, "estimate": est, "unique": vote.unique, "stops": s.stops,
            "refused_by": refused_by, "answered_by": answered_by}


def session_report_task(a: EigenspaceAnalysis, world: World, s: Session) -> dict[str, Any]:
    """:func:`stop_report` of a session's vote over all its stops."""
    return stop_report(a, world, s, s.vote(a.set_of()))


def load_world(blob: bytes) -> World:
    """A world model from its description's JSON (a :class:`Cached` loader)."""
    return World(WorldDescription.model_validate_json(blob))


def next_move_task(a: EigenspaceAnalysis, world: World, session: Session,
                   candidate_set: int | None) -> Decision:
    """The movement strategy's next action (Maeda & Shirai §3.5): where the robot may be
    now and its state belief, then the action of the grid maximising Q(Z) (eq. 8)."""
    cfg = a.config.strategy
    layout = a.layout(world)
    # samples of where stop 0 may have been (used while the state is X; more of them
    # when the turns' appearance weighs them, resampled to n_samples)
    samples0 = initial_samples(world.sample_free, cfg.initial_sample_count,
                               np.random.default_rng(a.config.seed + 11))
    now, belief = session_belief(session, layout, samples0, candidate_set, cfg)
    return choose_action(now, belief, layout, cfg)


def camera_task(world: World, config: CameraConfig, pose: np.ndarray, turn: int | None,
                fmt: str) -> dict[str, Any]:
    """Render the simulated camera (one image, or a turn) and encode it: base64 PNG, or
    nested lists rounded to 1e-4."""
    cam = Camera(world, config)
    imgs = cam.render(pose)[None] if turn is None else cam.render_turn(pose[:2],
                                                                       float(pose[2]), turn)
    if fmt == "png":
        return {"images_png": [png_b64(i) for i in imgs]}
    if fmt == "turn_png":
        return {"turn_png": png_b64(np.concatenate(list(imgs), axis=1))}
    return {"images": np.round(imgs, 4).tolist()}


def png_b64(img: np.ndarray) -> str:
    """A grey image in [0, 1] as base64 8-bit PNG."""
    return base64.b64encode(encode_png(img, bits=8)).decode()
