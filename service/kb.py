"""The Prolog bridge: the only module that imports pyswip.

One dedicated thread imports pyswip (which initialises SWI-Prolog in that
thread), loads the rule files with load_checked/1 (a syntax error or warning
raises at start-up) and then serves jobs from a queue.  Callers never touch
the engine: they submit ``(op, args)`` and await a future.

Every job is one call of ``api:handle(+Request, -Reply)``: the request is
JSON text handed over as a Prolog *string* (data, never parsed as Prolog),
the reply is JSON text copied out before the query is closed, so no pyswip
term, variable or generator ever leaves the engine thread.  The time and
inference limits are applied inside Prolog (call_with_time_limit/2,
call_with_inference_limit/3) around every operation.
"""

from __future__ import annotations

import asyncio
import atexit
import ctypes
import hashlib
import json
import queue
import threading
from concurrent.futures import Future
from pathlib import Path
from typing import Any

from chizu.numeric.errors import ChizuError


class KbError(ChizuError):
    """An operation was refused by the knowledge base."""

    def __init__(self, type_: str, detail: str, field: str | None = None,
                 value: Any = None) -> None:
        super().__init__(f"{type_}: {detail}")
        self.type, self.detail, self.field, self.value = type_, detail, field, value


class KbStartupError(RuntimeError):
    """The rule files could not be loaded cleanly."""


_STOP = object()
#: each engine thread's "the running job was cancelled" flag, by thread ident
_CANCEL_FLAGS: dict[int, threading.Event] = {}
_CANCEL_CB: Any = None  # the registered chizu_cancelled/0 callback (one per process)


def _engine_cancelled() -> int:
    """chizu_cancelled/0: 1 if the calling engine thread's running job was cancelled."""
    flag = _CANCEL_FLAGS.get(threading.get_ident())
    return 1 if flag is not None and flag.is_set() else 0


class KnowledgeBase:
    """Owns the SWI-Prolog engine on one thread; thread-safe and asyncio-friendly."""

    def __init__(self, prolog_dir: Path, time_limit_s: float = 10.0,
                 inference_limit: int = 200_000_000,
                 query_time_limit_s: float | None = None) -> None:
        self.prolog_dir = Path(prolog_dir).resolve()
        self.time_limit_s = time_limit_s
        self.inference_limit = inference_limit
        #: a client's own goals (the query op) get this shorter limit: the engine is
        #: one thread, and a legal goal run to the end of its limit holds every caller
        self.query_time_limit_s = min(time_limit_s, query_time_limit_s or time_limit_s)
        self.prolog_thread_id = 0  #: the engine's Prolog thread id, once it has said
        #: a digest of the rule files: a snapshot made by other rules is not loaded
        self.rules_digest = hashlib.sha256(b"".join(
            p.name.encode() + p.read_bytes()
            for p in sorted(self.prolog_dir.glob("*.pl")))).hexdigest()[:16]
        self._jobs: queue.Queue[Any] = queue.Queue()
        # the job on the engine and whether its caller gave up on it (chizu_cancelled/0)
        self._running: Future[str] | None = None
        self._cancel_lock = threading.Lock()
        self._cancelled = threading.Event()
        self._closed = False
        self._ready: Future[None] = Future()
        self._thread = threading.Thread(target=self._run, name="chizu-prolog", daemon=True)
        self._thread.start()
        self._ready.result()  # raises KbStartupError if the rules did not load

    # -- engine thread -------------------------------------------------------------
    def _run(self) -> None:
        try:
            from pyswip import core as pl  # noqa: PLC0415 (initialises Prolog here)

            self._pl = pl
            # pyswip's exit hook runs PL_cleanup from Python's main thread, which cannot
            # stop the engine thread Prolog lives on and says so ("Failed to stop Prolog
            # threads") at the end of every command; the process is ending and holds no
            # Prolog-side state to flush (the store is Python's), so the hook goes
            atexit.unregister(pl.cleanupProlog)
            if pl.PL_thread_self() == -1:  # Prolog was initialised by an earlier engine thread
                if pl.PL_thread_attach_engine(None) < 0:
                    raise KbStartupError("cannot attach a Prolog engine to this thread")
            self._register_cancel_check()
            self._load_rules()
            self._handle = pl.PL_predicate(b"handle", 2, b"api")
        except BaseException as e:  # noqa: BLE001 — reported to the constructor
            self._ready.set_exception(e if isinstance(e, KbStartupError)
                                      else KbStartupError(str(e)))
            return
        self._ready.set_result(None)
        while True:
            job = self._jobs.get()
            if job is _STOP:
                _CANCEL_FLAGS.pop(threading.get_ident(), None)
                return
            request, fut = job
            # under the lock :meth:`cancel` takes: a cancel either finds the job queued
            # (dropped here) or running (its flag set), never in between
            with self._cancel_lock:
                if not fut.set_running_or_notify_cancel():
                    continue
                self._running = fut
                self._cancelled.clear()
            try:
                fut.set_result(self._call(request))
            except BaseException as e:  # noqa: BLE001 — handed to the caller
                fut.set_exception(e)
            finally:
                with self._cancel_lock:
                    self._running = None

    def _register_cancel_check(self) -> None:
        """api:chizu_cancelled/0, a foreign predicate that succeeds once the running
        job's caller has called :meth:`cancel` (asked by api.pl's periodic check).
        Prolog is one per process and so is the predicate: it looks up the calling
        engine thread's flag (tests open several knowledge bases in one process)."""
        _CANCEL_FLAGS[threading.get_ident()] = self._cancelled
        global _CANCEL_CB
        if _CANCEL_CB is not None:
            return
        cb = ctypes.CFUNCTYPE(ctypes.c_int)(_engine_cancelled)
        reg = self._pl._lib.PL_register_foreign_in_module
        reg.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_int, ctypes.c_void_p,
                        ctypes.c_int]
        if not reg(b"api", b"chizu_cancelled", 0, ctypes.cast(cb, ctypes.c_void_p), 0):
            raise KbStartupError("cannot register api:chizu_cancelled/0")
        _CANCEL_CB = cb  # kept alive: Prolog holds the pointer

    def _load_rules(self) -> None:
        """consult load.pl's load_checked/1; raise on any load error or warning."""
        load = str(self.prolog_dir / "loader.pl").encode()
        reply = self._raw_call(b"load_files", [load], module=b"user")
        if reply is not None:
            raise KbStartupError(f"loading {load.decode()}: {reply}")
        reply = self._raw_call(b"load_checked", [str(self.prolog_dir).encode()],
                               module=b"loader")
        if reply is not None:
            raise KbStartupError(f"loading rule files from {self.prolog_dir}: {reply}")

    def _raw_call(self, name: bytes, string_args: list[bytes], module: bytes) -> str | None:
        """Call module:name(Args...) with atom arguments; return the exception text or None."""
        pl = self._pl
        fid = pl.PL_open_foreign_frame()
        try:
            args = pl.PL_new_term_refs(len(string_args))
            for i, a in enumerate(string_args):
                pl.PL_put_chars(args + i, pl.PL_ATOM | pl.REP_UTF8, len(a), a)
            pred = pl.PL_predicate(name, len(string_args), module)
            qid = pl.PL_open_query(None, pl.PL_Q_NODEBUG | pl.PL_Q_CATCH_EXCEPTION, pred, args)
            try:
                ok = pl.PL_next_solution(qid)
                exc = pl.PL_exception(qid)
                if exc:
                    return self._term_text(exc)
                return None if ok else "goal failed"
            finally:
                pl.PL_close_query(qid)
        finally:
            pl.PL_discard_foreign_frame(fid)

    def _term_text(self, term: int) -> str:
        pl = self._pl
        out = ctypes.c_char_p()
        flags = pl.CVT_ALL | pl.CVT_WRITEQ | pl.REP_UTF8 | pl.BUF_DISCARDABLE
        if pl.PL_get_chars(term, ctypes.byref(out), flags) and out.value is not None:
            return out.value.decode("utf-8", "replace")
        return "<unprintable exception>"

    def _call(self, request: bytes) -> str:
        """Run api:handle(Request, Reply) and copy Reply out as a Python str."""
        pl = self._pl
        fid = pl.PL_open_foreign_frame()
        try:
            args = pl.PL_new_term_refs(2)
            pl.PL_put_chars(args, pl.PL_STRING | pl.REP_UTF8, len(request), request)
            qid = pl.PL_open_query(None, pl.PL_Q_NODEBUG | pl.PL_Q_CATCH_EXCEPTION,
                                   self._handle, args)
            try:
                if not pl.PL_next_solution(qid):
                    exc = pl.PL_exception(qid)
                    raise KbError("internal", self._term_text(exc) if exc else "failed")
                out = ctypes.c_char_p()
                flags = pl.CVT_STRING | pl.CVT_ATOM | pl.REP_UTF8 | pl.BUF_DISCARDABLE
                if not pl.PL_get_chars(args + 1, ctypes.byref(out), flags) or out.value is None:
                    raise KbError("internal", "reply is not text")
                return out.value.decode("utf-8")
            finally:
                pl.PL_close_query(qid)
        finally:
            pl.PL_discard_foreign_frame(fid)

    # -- callers -------------------------------------------------------------------
    def _request(self, op: str, args: dict[str, Any]) -> bytes:
        limit = self.query_time_limit_s if op == "query" else self.time_limit_s
        # a client's own goal stops when its client leaves (cancel, api.pl's checks)
        return json.dumps({"op": op, "args": args, "time_limit_s": limit,
                           "inference_limit": self.inference_limit,
                           "cancellable": op == "query"},
                          # UTF-8 as it is: Prolog's JSON reader takes the \ud83d\ude00
                          # escape of a character outside the BMP for two code points
                          allow_nan=False, ensure_ascii=False).encode("utf-8")

    def submit(self, op: str, **args: Any) -> Future[str]:
        """Queue one operation; the future yields the raw JSON reply."""
        fut: Future[str] = Future()
        with self._cancel_lock:  # close() drains the queue under the same lock
            if self._closed or not self._thread.is_alive():
                fut.set_exception(KbError("unavailable",
                                          "the Prolog engine thread has stopped"))
                return fut
            self._jobs.put((self._request(op, args), fut))
        return fut

    @staticmethod
    def _unwrap(reply: str) -> Any:
        data = json.loads(reply)
        if data.get("ok"):
            return data["result"]
        err = data.get("error", {})
        raise KbError(str(err.get("type", "internal")), str(err.get("detail", "")),
                      err.get("field"), err.get("value"))

    def call(self, op: str, **args: Any) -> Any:
        """Blocking call from any thread except the engine's."""
        return self._unwrap(self.submit(op, **args).result())

    async def acall(self, op: str, **args: Any) -> Any:
        """Awaitable call for async endpoints; cancelling the await drops the job if it
        is still queued and stops it if it is a running client goal (``query``)."""
        fut = self.submit(op, **args)
        try:
            return self._unwrap(await asyncio.wrap_future(fut))
        except asyncio.CancelledError:
            self.cancel(fut)
            raise

    def cancel(self, fut: Future[str]) -> None:
        """Give up on a submitted job: a queued one is dropped (the engine skips it), a
        running cancellable one stops at its next check (within 0.1 s)."""
        with self._cancel_lock:
            if not fut.cancel() and self._running is fut:
                self._cancelled.set()

    @property
    def engine_thread(self) -> threading.Thread:
        return self._thread

    def close(self) -> None:
        """Stop the engine after the jobs queued so far; a job submitted later, or left
        in the queue, fails at once instead of waiting for ever (a worker thread's call
        would otherwise hang the shutdown)."""
        with self._cancel_lock:
            self._closed = True
            self._jobs.put(_STOP)
        self._thread.join(timeout=5)
        while True:
            try:
                job = self._jobs.get_nowait()
            except queue.Empty:
                break
            if job is not _STOP:
                job[1].set_exception(KbError("unavailable", "the knowledge base was closed"))
