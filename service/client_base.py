"""What the typed client (:mod:`chizu.service.client`, generated from the OpenAPI) stands
on: how a call is encoded and its answer decoded, the problem+json error, and the sync and
async transports (httpx) with job polling. Written once here; the generated module only
lists the operations."""

from __future__ import annotations

import asyncio
import functools
import json
import time
from collections.abc import AsyncIterator, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import quote

import httpx
from pydantic import BaseModel, TypeAdapter

from chizu.service.schemas.jobs import JobOut

#: a job's statuses that will not change any more
FINAL = ("done", "failed", "cancelled", "interrupted")


class ProblemError(Exception):
    """A 4xx or 5xx answer: its RFC 9457 problem document (``type``, ``title``,
    ``status``, ``detail``, ``field``, ``instance``) as :attr:`problem`."""

    def __init__(self, status: int, problem: dict[str, Any]) -> None:
        self.status, self.problem = status, problem
        self.field: str | None = problem.get("field")
        self.detail: str = str(problem.get("detail") or problem.get("title") or status)
        where = f" (field {self.field})" if self.field else ""
        super().__init__(f"{status} {problem.get('title', '')}: {self.detail}{where}")


class JobError(Exception):
    """A job that ended other than done (failed, cancelled, interrupted): :attr:`job`."""

    def __init__(self, job: JobOut) -> None:
        self.job = job
        why = f": {job.error.detail}" if job.error is not None else ""
        super().__init__(f"job {job.id} ({job.kind}) {job.status}{why}")


@dataclass
class Request:
    """One operation's call: method, path (its parameters quoted in), query, body."""

    method: str
    path: str
    params: dict[str, Any] = field(default_factory=dict)
    json: Any = None
    content: bytes | None = None
    files: Any = None
    data: Mapping[str, str] | None = None

    def kwargs(self) -> dict[str, Any]:
        out: dict[str, Any] = {"params": {k: v for k, v in self.params.items()
                                          if v is not None}}
        if self.json is not None:
            out["json"] = encode(self.json)
        if self.content is not None:
            out["content"] = self.content
        if self.files is not None:
            out["files"] = self.files
        if self.data is not None:
            out["data"] = dict(self.data)
        return out


def segment(value: str) -> str:
    """A path parameter, quoted (a name never changes the path's shape)."""
    return quote(str(value), safe="")


def encode(body: Any) -> Any:
    """A request body: a pydantic model as its JSON (by alias, unset fields left out) or a
    plain mapping as it is."""
    if isinstance(body, BaseModel):
        return body.model_dump(mode="json", by_alias=True, exclude_unset=True)
    return body


def decode(response: httpx.Response, out: Any) -> Any:
    """The answer: raises :class:`ProblemError` for a 4xx/5xx; else ``None`` (no
    content), bytes (``out`` is bytes), text (a text answer), or the JSON validated as
    ``out`` (a model, a ``list[...]``, or ``Any``)."""
    if response.status_code >= 400:
        try:
            problem = response.json()
            if not isinstance(problem, dict):
                raise ValueError
        except ValueError:
            problem = {"status": response.status_code, "title": response.reason_phrase,
                       "detail": response.text[:500]}
        raise ProblemError(response.status_code, problem)
    if response.status_code == 204 or out is None:
        return None
    if out is bytes:
        return response.content
    media = response.headers.get("content-type", "").split(";")[0].strip()
    if media.startswith("text/") or media == "application/yaml":
        return response.text
    return adapter(out).validate_python(response.json())


@functools.lru_cache(maxsize=256)
def adapter(out: Any) -> TypeAdapter[Any]:
    """The validator of an answer's type, built once per type (a list type's costs
    ~20 times a model's validation to build)."""
    return TypeAdapter(out)


@dataclass(frozen=True)
class ServerEvent:
    """One Server-Sent Event: its type, id and data (JSON-decoded)."""

    event: str
    id: str | None
    data: Any


class _EventParser:
    """Server-Sent Events from a stream's lines (the WHATWG event-stream format: fields
    until a blank line, ``data`` lines joined, comments skipped)."""

    def __init__(self) -> None:
        self.event: str = "message"
        self.id: str | None = None
        self.data: list[str] = []

    def feed(self, line: str) -> ServerEvent | None:
        if not line:
            if not self.data:
                self.event = "message"
                return None
            out = ServerEvent(self.event, self.id, json.loads("\n".join(self.data)))
            self.event, self.data = "message", []
            return out
        if line.startswith(":"):
            return None
        name, _, value = line.partition(":")
        value = value[1:] if value.startswith(" ") else value
        if name == "event":
            self.event = value
        elif name == "data":
            self.data.append(value)
        elif name == "id":
            self.id = value
        return None


def _stream_status(response: httpx.Response) -> None:
    """A refused stream raises :class:`ProblemError` (its body read first)."""
    if response.status_code >= 400:
        decode(response, None)


def settled(job: JobOut, timeout_s: float, deadline: float) -> JobOut | None:
    """One poll of a job: the job once done, None while it runs; :class:`JobError` if
    it ended otherwise, ``TimeoutError`` past the deadline (``time.monotonic``)."""
    if job.status in FINAL:
        if job.status != "done":
            raise JobError(job)
        return job
    if time.monotonic() > deadline:
        raise TimeoutError(f"job {job.id} still {job.status} after {timeout_s:g} s")
    return None


class SyncTransport:
    """Calls over an ``httpx.Client`` (a ``fastapi.testclient.TestClient`` too)."""

    def __init__(self, base_url: str = "http://127.0.0.1:8000", timeout_s: float = 60.0,
                 http: httpx.Client | None = None) -> None:
        self.http = http or httpx.Client(base_url=base_url, timeout=timeout_s)
        self._own = http is None

    def call(self, request: Request, out: Any) -> Any:
        return decode(self.http.request(request.method, request.path, **request.kwargs()),
                      out)

    def stream(self, request: Request) -> Iterator[ServerEvent]:
        """A Server-Sent Events operation's events as they come (no read timeout; stop
        iterating to close the stream)."""
        with self.http.stream(request.method, request.path, timeout=httpx.Timeout(
                self.http.timeout.connect, read=None), **request.kwargs()) as r:
            if r.status_code >= 400:
                r.read()
                _stream_status(r)
            parser = _EventParser()
            for line in r.iter_lines():
                if (event := parser.feed(line)) is not None:
                    yield event

    def wait_job(self, job: JobOut | str, timeout_s: float = 600.0,
                 poll_s: float = 0.2) -> JobOut:
        """Poll ``GET /jobs/{id}`` until the job ends: the job when done, else
        :class:`JobError`; ``TimeoutError`` past ``timeout_s``."""
        jid = job if isinstance(job, str) else job.id
        deadline = time.monotonic() + timeout_s
        while (done := settled(self.call(Request("GET", f"/jobs/{segment(jid)}"), JobOut),
                               timeout_s, deadline)) is None:
            time.sleep(poll_s)
        return done

    def close(self) -> None:
        if self._own:
            self.http.close()


class AsyncTransport:
    """Calls over an ``httpx.AsyncClient``."""

    def __init__(self, base_url: str = "http://127.0.0.1:8000", timeout_s: float = 60.0,
                 http: httpx.AsyncClient | None = None) -> None:
        self.http = http or httpx.AsyncClient(base_url=base_url, timeout=timeout_s)
        self._own = http is None

    async def call(self, request: Request, out: Any) -> Any:
        return decode(await self.http.request(request.method, request.path,
                                              **request.kwargs()), out)

    async def stream(self, request: Request) -> AsyncIterator[ServerEvent]:
        """As :meth:`SyncTransport.stream`, without blocking the event loop."""
        async with self.http.stream(request.method, request.path, timeout=httpx.Timeout(
                self.http.timeout.connect, read=None), **request.kwargs()) as r:
            if r.status_code >= 400:
                await r.aread()
                _stream_status(r)
            parser = _EventParser()
            async for line in r.aiter_lines():
                if (event := parser.feed(line)) is not None:
                    yield event

    async def wait_job(self, job: JobOut | str, timeout_s: float = 600.0,
                       poll_s: float = 0.2) -> JobOut:
        """As :meth:`SyncTransport.wait_job`, without blocking the event loop."""
        jid = job if isinstance(job, str) else job.id
        deadline = time.monotonic() + timeout_s
        while (done := settled(await self.call(Request("GET", f"/jobs/{segment(jid)}"),
                                               JobOut), timeout_s, deadline)) is None:
            await asyncio.sleep(poll_s)
        return done

    async def aclose(self) -> None:
        if self._own:
            await self.http.aclose()
