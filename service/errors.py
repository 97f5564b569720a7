"""The one place that maps domain errors to RFC 9457 problem responses."""

from __future__ import annotations

import logging
import re
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from starlette.exceptions import HTTPException as StarletteHTTPException

from chizu.numeric.errors import ChizuError, Conflict, InvalidInput, NotFound
from chizu.service.compute import BudgetExceeded, WorkerLost
from chizu.service.disconnect import ClientGone
from chizu.service.events import TooManySubscribers
from chizu.service.jobs import JobOverBudget
from chizu.service.kb import KbError

#: the problem title of each status (the problem's type is made from it)
TITLES = {404: "Not found", 405: "Method not allowed", 409: "Conflict", 413: "Payload too large",
          422: "Invalid input"}

log = logging.getLogger(__name__)
PROBLEM = "application/problem+json"

#: the HTTP status of each domain error class; an error takes the status of the nearest
#: class in its MRO (a knowledge-base error has its own table, KB_STATUS)
STATUS: dict[type[ChizuError], int] = {
    ChizuError: 400,
    InvalidInput: 422,
    NotFound: 404,
    Conflict: 409,
    BudgetExceeded: 503,  # the request's time budget
    WorkerLost: 503,  # a compute worker died under the request
    JobOverBudget: 503,  # a job's time budget
    TooManySubscribers: 503,  # every live event stream slot is taken
}

# knowledge-base error type -> HTTP status
KB_STATUS = {
    "unknown_world": 404,
    "unknown_map": 404,
    "limit": 503,
    "unavailable": 503,
    "internal": 500,
    "failed": 500,
}


def status_of(exc: ChizuError) -> int:
    """The HTTP status a domain error is answered with (:data:`STATUS`)."""
    return next(STATUS[c] for c in type(exc).__mro__ if c in STATUS)


def problem(status: int, title: str, detail: str, instance: str | None = None,
            field: str | None = None, errors: list[dict[str, Any]] | None = None,
            type_: str | None = None, headers: dict[str, str] | None = None
            ) -> JSONResponse:
    body: dict[str, Any] = {
        "type": f"/problems/{type_ or title.lower().replace(' ', '-')}",
        "title": title, "status": status, "detail": detail,
    }
    if instance:
        body["instance"] = instance
    if field:
        body["field"] = field
    if errors:
        body["errors"] = errors
    return JSONResponse(body, status_code=status, media_type=PROBLEM, headers=headers)


def _loc(loc: tuple[Any, ...]) -> str:
    parts = [str(p) for p in loc if p not in ("body", "query", "path")]
    out = ""
    for p in parts:
        out += f"[{p}]" if p.isdigit() else (f".{p}" if out else p)
    return out or ".".join(str(p) for p in loc)


def install(app: FastAPI) -> None:
    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = []
        for e in exc.errors():
            loc = tuple(e.get("loc", ()))
            if e.get("type") == "json_invalid":  # loc is ("body", character offset)
                where = f" at character {loc[-1]}" if loc and isinstance(loc[-1], int) else ""
                why = (e.get("ctx") or {}).get("error", "")
                errors.append({"field": "body", "message": f"not valid JSON{where}"
                               + (f": {why}" if why else "")})
                continue
            # model-level validators report their own field in the message
            errors.append({"field": _loc(loc), "message": str(e.get("msg", ""))})
        first = errors[0] if errors else {"field": None, "message": "invalid request"}
        return problem(422, "Invalid request",
                       f"{first['field']}: {first['message']}" if first["field"]
                       else str(first["message"]),
                       instance=request.url.path, field=first["field"] or None, errors=errors)

    @app.exception_handler(ClientGone)
    async def _gone(request: Request, exc: ClientGone) -> Response:
        # nobody is there to read it: nginx's "client closed request", for the logs
        return Response(status_code=499)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        title = TITLES.get(exc.status_code, "HTTP error")
        headers = getattr(exc, "headers", None)
        if exc.status_code == 405:  # Allow: every method of the path, not of one route
            allowed = allowed_methods(app, request.url.path)
            if allowed:
                headers = {**(headers or {}), "Allow": ", ".join(allowed)}
        return problem(exc.status_code, title, str(exc.detail), instance=request.url.path,
                       headers=headers)

    @app.exception_handler(ChizuError)
    async def _chizu(request: Request, exc: ChizuError) -> JSONResponse:
        """The one error root, answered with its class's status (:data:`STATUS`)."""
        status = status_of(exc)
        return problem(status, TITLES.get(status, "Bad request"), str(exc),
                       instance=request.url.path, field=exc.field)

    @app.exception_handler(KbError)
    async def _kb(request: Request, exc: KbError) -> JSONResponse:
        status = KB_STATUS.get(exc.type, 422)
        if status >= 500:
            log.error("knowledge base error on %s: %s", request.url.path, exc)
        detail = exc.detail
        if exc.type == "unknown_landmark":
            detail = f"landmark {exc.value!r} is not in this world"
        elif exc.type == "unknown_world":
            detail = f"world {exc.value!r} does not exist"
        elif exc.type == "invalid_id":
            detail = f"{exc.value!r} is not a valid id (^[a-z][a-zA-Z0-9_]{{0,63}}$)"
        return problem(status, exc.type.replace("_", " ").capitalize(), detail,
                       instance=request.url.path, field=exc.field,
                       type_=exc.type.replace("_", "-"))


class BodySizeLimit:
    """ASGI middleware: refuse bodies over ``max_bytes`` (``upload_bytes`` on paths
    ending in one of ``upload_suffixes``: image-set uploads) with 413 before parsing."""

    def __init__(self, app: Any, max_bytes: int, upload_bytes: int | None = None,
                 upload_suffixes: tuple[str, ...] = ()) -> None:
        self.app, self.default_bytes = app, max_bytes
        self.upload_bytes = upload_bytes or max_bytes
        self.upload_suffixes = upload_suffixes

    async def __call__(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        upload = str(scope.get("path", "")).endswith(self.upload_suffixes)
        limit = self.upload_bytes if upload else self.default_bytes
        headers = dict(scope.get("headers") or [])
        declared = headers.get(b"content-length")
        if declared is not None and (not declared.isdigit() or int(declared) > limit):
            await self._reject(scope, send, limit)
            return
        if declared is None and not upload and scope.get("method") in ("POST", "PUT", "PATCH"):
            # a chunked body has no declared length: read it here, up to the limit (8 MiB),
            # so that an oversized one is a 413 (the body parser would call it a 400);
            # image-set uploads (up to 256 MiB) stream on, spooled to disk by the parser
            body = bytearray()
            while True:
                msg = await receive()
                if msg["type"] != "http.request":
                    return  # the client went away
                body += msg.get("body", b"")
                if len(body) > limit:
                    await self._reject(scope, send, limit)
                    return
                if not msg.get("more_body", False):
                    break
            sent = False

            async def replay() -> dict[str, Any]:
                nonlocal sent
                if not sent:
                    sent = True
                    return {"type": "http.request", "body": bytes(body), "more_body": False}
                return dict(await receive())

            await self.app(scope, replay, send)
            return
        seen = 0

        async def limited_receive() -> dict[str, Any]:
            nonlocal seen
            msg: dict[str, Any] = await receive()
            if msg["type"] == "http.request":
                seen += len(msg.get("body", b""))
                if seen > limit:
                    raise _TooLarge
            return msg

        try:
            await self.app(scope, limited_receive, send)
        except _TooLarge:
            await self._reject(scope, send, limit)

    @staticmethod
    async def _reject(scope: dict[str, Any], send: Any, limit: int) -> None:
        resp = problem(413, TITLES[413], f"request body exceeds {limit} bytes",
                       instance=scope.get("path"), field="body")
        await resp(scope, None, send)  # type: ignore[arg-type]


class _TooLarge(Exception):
    pass


PROBLEM_SCHEMA: dict[str, Any] = {
    "title": "Problem", "type": "object", "required": ["type", "title", "status", "detail"],
    "description": "RFC 9457 problem details; ``field`` names the offending input",
    "properties": {
        "type": {"type": "string"}, "title": {"type": "string"},
        "status": {"type": "integer"}, "detail": {"type": "string"},
        "instance": {"type": "string"}, "field": {"type": "string"},
        "errors": {"type": "array", "items": {
            "type": "object", "properties": {"field": {"type": "string"},
                                             "message": {"type": "string"}}}},
    },
}
#: the operations that answer 409 (a name taken, a job already running or ended)
CONFLICTS = {("post", "/worlds"), ("post", "/worlds/{world}/eigenspace"),
             ("post", "/worlds/{world}/eigenspace/images"), ("delete", "/jobs/{job_id}"),
             # a run's map or commit before it has scans
             *(("get", f"/worlds/{{world}}/slam-runs/{{rid}}/map.{ext}")
               for ext in ("png", "pgm", "yaml")),
             ("post", "/worlds/{world}/slam-runs/{rid}/commit"),
             # one mission job per world at a time
             ("post", "/worlds/{world}/missions"),
             # a world that has learned no eigenspace yet
             *(("post", f"/worlds/{{world}}/{tail}") for tail in (
                 "localize", "localize/images", "localization-sessions",
                 "localization-sessions/{sid}/stops")),
             ("get", "/worlds/{world}/localization-sessions/{sid}"),
             ("get", "/worlds/{world}/localization-sessions/{sid}/next-move"),
             # a world without a map to localize on; a run whose map was replaced
             ("post", "/worlds/{world}/localization-runs"),
             *((m, f"/worlds/{{world}}/localization-runs/{{rid}}{tail}")
               for m, tail in (("get", ""), ("delete", ""), ("post", "/scans"),
                               ("get", "/trajectory")))}
_REASONS = {400: "Bad request", 404: "Not found (the field names what)",
            409: "Conflict with the current state", 413: "Payload too large",
            422: "Invalid input (the field names it)",
            500: "Internal error (a bug: please report it)",
            503: "Unavailable: the knowledge base, a time budget or a capacity (event "
                 "streams) is exhausted; the detail says which"}


def allowed_methods(app: FastAPI, path: str) -> list[str]:
    """The methods the OpenAPI documents for ``path`` (HEAD with GET). Starlette's 405
    names only the methods of the first route that matched the path, while a path's
    GET and POST (or DELETE) are separate routes."""
    table = getattr(app.state, "allowed_methods", None)
    if table is None:
        table = []
        for template, ops in app.openapi().get("paths", {}).items():
            rx = re.compile("^" + re.sub(r"\\\{[^/]+?\\\}", "[^/]+", re.escape(template)) + "$")
            methods = sorted(m.upper() for m in ops)
            if "GET" in methods:
                methods.append("HEAD")
            table.append((rx, methods))
        app.state.allowed_methods = table
    return next((m for rx, m in table if rx.match(path)), [])


def document_problems(app: FastAPI) -> None:
    """Make the OpenAPI tell the truth about errors: every operation's 4xx/5xx answers
    are ``application/problem+json`` (PROBLEM_SCHEMA), not FastAPI's default
    ``HTTPValidationError`` JSON; 404 wherever the path names something, 409 where a
    name or a job can clash (CONFLICTS), 400 (unparseable) and 413 wherever there is a
    body, 422 everywhere, 503 for the engine and the compute budget."""
    from fastapi.openapi.utils import get_openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is not None:
            return app.openapi_schema
        spec = get_openapi(title=app.title, version=app.version,
                           description=app.description, routes=app.routes)
        comps = spec.setdefault("components", {}).setdefault("schemas", {})
        comps["Problem"] = PROBLEM_SCHEMA
        for name in ("HTTPValidationError", "ValidationError"):
            comps.pop(name, None)
        ref = {"application/problem+json": {"schema": {"$ref": "#/components/schemas/Problem"}}}
        for path, ops in spec.get("paths", {}).items():
            for method, op in ops.items():
                codes = {422, 500, 503}
                if "{" in path:
                    codes.add(404)
                if (method, path) in CONFLICTS:
                    codes.add(409)
                if "requestBody" in op:
                    codes |= {400, 413}  # a body that cannot be parsed at all; too big
                for code in sorted(codes):
                    op.setdefault("responses", {})[str(code)] = {
                        "description": _REASONS[code], "content": ref}
        app.openapi_schema = spec
        return spec

    app.openapi = openapi  # type: ignore[method-assign]
