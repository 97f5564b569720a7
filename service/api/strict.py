"""JSON bodies are validated strictly: a number must be a JSON number, a string a JSON
string, an integer a number without a fraction (JSON Schema's "integer": 2 or 2.0).

FastAPI decodes a body with ``json.loads`` and validates the Python objects in
pydantic's lax mode, so ``"x": "12"`` passed as the number 12 and ``true`` as 1.
Strict mode in Python mode is not usable instead: it refuses a list where the model
declares a tuple (poses, odometry). A :class:`StrictJsonRoute`'s
endpoint first validates the raw body once more, as JSON in strict mode (pydantic's
JSON mode: arrays fill tuples, strings never fill numbers). It runs after the route's
dependencies and FastAPI's own validation, so an unknown world is still a 404 before
the body is looked at; a strict error is the usual 422 problem naming the field.
"""

from __future__ import annotations

import email.message
import functools
import inspect
from collections.abc import Callable
from typing import Any

from fastapi import Request
from fastapi.exceptions import RequestValidationError
from fastapi.routing import APIRoute
from pydantic import TypeAdapter, ValidationError


async def check_strict_json(request: Request, adapter: TypeAdapter[Any]) -> None:
    """422 (RequestValidationError) unless the JSON body is valid in strict mode."""
    if not _parsed_as_json(request.headers.get("content-type", "")):
        return
    raw = await request.body()  # kept by the request: read once
    if not raw:
        return
    try:
        adapter.validate_json(raw, strict=True)
    except ValidationError as e:
        # JSON Schema's "integer" is any number without a fraction: 2.0 is one (FastAPI's
        # lax pass then takes it as 2); "2", true and 2.5 are not
        errs = [x for x in e.errors(include_url=False)
                if not (x["type"] == "int_type" and isinstance(x["input"], float)
                        and x["input"].is_integer())]
        if errs:
            raise RequestValidationError([{**x, "loc": ("body", *x["loc"])} for x in errs],
                                         body=raw) from None


def _parsed_as_json(content_type: str) -> bool:
    """Whether FastAPI reads this body as JSON (fastapi.routing, with its default strict
    content type: application/json or application/*+json, in any letter case; without a
    content type the body is bytes, refused as not an object)."""
    if not content_type:
        return False
    m = email.message.Message()
    m["content-type"] = content_type
    sub = m.get_content_subtype()
    return m.get_content_maintype() == "application" and (sub == "json"
                                                          or sub.endswith("+json"))


class StrictJsonRoute(APIRoute):
    def __init__(self, path: str, endpoint: Callable[..., Any], **kwargs: Any) -> None:
        holder: dict[str, TypeAdapter[Any]] = {}
        if inspect.iscoroutinefunction(endpoint):
            endpoint = _checking(endpoint, holder)
        super().__init__(path, endpoint, **kwargs)
        field = self.body_field
        if field is not None and field.field_info.annotation is not None:
            holder["adapter"] = TypeAdapter(field.field_info.annotation)


def _checking(endpoint: Callable[..., Any], holder: dict[str, TypeAdapter[Any]]
              ) -> Callable[..., Any]:
    """``endpoint`` checking the request's body first: through its own ``Request``
    parameter, or one more it is given (FastAPI passes the request to one parameter)."""
    sig = inspect.signature(endpoint, eval_str=True)
    own = [p.name for p in sig.parameters.values() if p.annotation is Request]
    name = own[0] if own else "strict_json_request_"

    @functools.wraps(endpoint)
    async def checked(*args: Any, **kwargs: Any) -> Any:
        request = kwargs[name] if own else kwargs.pop(name)
        adapter = holder.get("adapter")
        if adapter is not None:
            await check_strict_json(request, adapter)
        return await endpoint(*args, **kwargs)

    if not own:
        extra = inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, annotation=Request)
        checked.__signature__ = sig.replace(  # type: ignore[attr-defined]
            parameters=[*sig.parameters.values(), extra])
    return checked
