"""Writes :mod:`chizu.service.client`, the typed Python client, from the service's
OpenAPI: one method per operation, in a class per routes module, sync (``Client``) and async
(``AsyncClient``), typed with the service's own pydantic models.

    python -m chizu.service.api.client_gen        # rewrites service/client.py

``tests/service/test_client.py`` fails while the file differs from what this writes, so
the client cannot fall behind the API.
"""

from __future__ import annotations

import keyword
import re
import sys
import textwrap
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from chizu.service.app import create_app

TARGET = Path(__file__).resolve().parents[1] / "client.py"

def models() -> dict[str, type[BaseModel]]:
    """Every pydantic model the API's schemas name, by class name."""
    found: dict[str, type[BaseModel]] = {}
    todo: list[type[BaseModel]] = [BaseModel]
    while todo:
        for sub in todo.pop().__subclasses__():
            todo.append(sub)
            if sub.__module__.startswith("chizu.") and "[" not in sub.__name__:
                found.setdefault(sub.__name__, sub)
    return found


def ref_name(schema: dict[str, Any] | None) -> str | None:
    ref = (schema or {}).get("$ref")
    return ref.rsplit("/", 1)[-1] if ref else None


def py_name(name: str) -> str:
    name = re.sub(r"\W", "_", name)
    return name + "_" if keyword.iskeyword(name) else name


def query_type(schema: dict[str, Any]) -> str:
    kinds = [s.get("type") for s in schema.get("anyOf", [schema])]
    base = {"string": "str", "number": "float", "integer": "int", "boolean": "bool"}
    names = [base[k] for k in kinds if k in base]
    return " | ".join(dict.fromkeys(names)) or "Any"


class Operation:
    """One operation of the OpenAPI as the client writes it."""

    def __init__(self, path: str, method: str, op: dict[str, Any],
                 known: dict[str, type[BaseModel]], used: set[str]) -> None:
        self.path, self.method, self.op = path, method.upper(), op
        # operation ids are "<routes module>.<route function>" (chizu.service.api)
        self.group, self.name = op["operationId"].split(".", 1)
        self.known, self.used = known, used
        params = op.get("parameters", [])
        order = re.findall(r"{(\w+)}", path)
        self.path_params = sorted((p for p in params if p["in"] == "path"),
                                  key=lambda p: order.index(p["name"]))
        self.query = [p for p in params if p["in"] == "query"]

    def model(self, name: str | None) -> str | None:
        if name is None or name not in self.known:
            return None
        self.used.add(name)
        return name

    def body(self) -> tuple[list[str], str]:
        """The body's arguments and the Request fields that carry it."""
        content = self.op.get("requestBody", {}).get("content", {})
        required = self.op.get("requestBody", {}).get("required", False)
        if "application/json" in content:
            m = self.model(ref_name(content["application/json"].get("schema")))
            kind = f"{m} | Mapping[str, Any]" if m else "Mapping[str, Any]"
            return [f"body: {kind}" if required else f"body: {kind} | None = None"], \
                "json=body"
        if "application/octet-stream" in content:
            return ["content: bytes"], "content=content"
        if "multipart/form-data" in content:
            return ["files: Any", "data: Mapping[str, str] | None = None"], \
                "files=files, data=data"
        return [], ""

    def answer(self) -> str:
        """The return type, as the client's ``out`` argument and as an annotation."""
        for code, resp in self.op["responses"].items():
            if not code.startswith("2"):
                continue
            content = resp.get("content", {})
            if not content:
                return "None"
            if "text/event-stream" in content:
                return "Iterator[ServerEvent]"
            json_schema = content.get("application/json", {}).get("schema")
            if json_schema is None and "application/json" not in content:
                return "bytes"
            if json_schema is None:
                return "Any"
            if json_schema.get("type") == "array":
                item = self.model(ref_name(json_schema.get("items")))
                return f"list[{item or 'Any'}]"
            m = self.model(ref_name(json_schema))
            out = m or "Any"
            return f"{out} | str" if "text/plain" in content and m else out
        return "None"

    def method_text(self, sync: bool) -> str:
        args = ["self"] + [f"{py_name(p['name'])}: str" for p in self.path_params]
        body_args, body_call = self.body()
        args += body_args
        kw = []
        for p in self.query:
            t = query_type(p["schema"])
            kw.append(f"{py_name(p['name'])}: {t}" if p.get("required") else
                      f"{py_name(p['name'])}: {t} | None = None")
        if kw:
            args += ["*", *kw]
        ret = self.answer()
        out = ret.split(" | ")[0] if ret not in ("None", "Any") else ret
        path = re.sub(r"{(\w+)}", lambda m: "{segment(" + py_name(m.group(1)) + ")}",
                      self.path)
        fields = [repr(self.method), f'f"{path}"' if "{" in path else repr(path)]
        if self.query:
            fields.append("params={" + ", ".join(f"{p['name']!r}: {py_name(p['name'])}"
                                                 for p in self.query) + "}")
        if body_call:
            fields.append(body_call)
        call = f"self._t.call(Request({', '.join(fields)}), {out})"
        events = ret == "Iterator[ServerEvent]"
        if events:  # a stream: iterated, not awaited
            call = f"self._t.stream(Request({', '.join(fields)}))"
            ret = ret if sync else "AsyncIterator[ServerEvent]"
        text = (self.op.get("description") or self.op.get("summary") or self.name).strip()
        first = re.sub(r"\s+", " ", text.split("\n\n")[0]).replace('"', "'")
        first = first.replace("\\", "\\\\").strip()
        doc = f"{self.method} {self.path}: {first.rstrip('.')}."
        is_async = not sync and not events
        head = f"    {'async ' if is_async else ''}def {self.name}({', '.join(args)}) -> {ret}:"
        lines = [head if len(head) <= 100 else
                 f"    {'async ' if is_async else ''}def {self.name}(\n            "
                 + ",\n            ".join(args) + f") -> {ret}:",
                 *docstring(doc),
                 f"        return {'await ' if is_async else ''}{call}"]
        return "\n".join(wrap(line) for line in lines)


def docstring(text: str) -> list[str]:
    """A method's docstring lines, within 100 characters."""
    lines = textwrap.wrap(text, width=100 - 8 - 6)
    return [f'        """{lines[0]}'] + [f"        {ln}" for ln in lines[1:-1]] + \
        ([f'        {lines[-1]}"""'] if len(lines) > 1 else []) if len(lines) > 1 else \
        [f'        """{lines[0]}"""']


def wrap(line: str) -> str:
    """A generated line over 100 characters broken after a comma, inside its call."""
    if len(line) <= 100 or "(" not in line:
        return line
    indent = " " * (len(line) - len(line.lstrip()))
    cut = line.rfind(", ", 0, 100)
    if cut < 0:
        return line
    opening = line.index("(") + 1
    return line[:cut + 1] + "\n" + wrap(indent + " " * 8 + line[cut + 2:]) \
        if cut > opening else line


def generate() -> str:
    spec = create_app().openapi()
    known = models()
    used: set[str] = set()
    ops = [Operation(p, m, op, known, used) for p, item in spec["paths"].items()
           for m, op in item.items()]
    groups = list(dict.fromkeys(op.group for op in ops))
    out = ['"""chizu\'s HTTP API, typed: one method per operation of the OpenAPI, grouped by',
           "the service's routes modules, sync (:class:`Client`) and async",
           "(:class:`AsyncClient`). Errors are :class:`ProblemError` carrying the",
           "problem+json; ``wait_job`` polls a job to its end (:class:`JobError` unless",
           "done).",
           "",
           "    from chizu.service.client import Client",
           "    with Client(\"http://127.0.0.1:8000\") as chizu:",
           "        print(chizu.qualitative.get_path(\"demo\", from_=\"rn0a\", to=\"c1\"))",
           "",
           "Generated by ``python -m chizu.service.api.client_gen`` from the service's",
           "OpenAPI: do not edit.",
           '"""', "", "from __future__ import annotations", "",
           "from collections.abc import AsyncIterator, Iterator, Mapping",
           "from types import TracebackType",
           "from typing import Any", "", "import httpx", ""]
    body = []
    for sync in (True, False):
        prefix = "" if sync else "Async"
        transport = "SyncTransport" if sync else "AsyncTransport"
        for g in groups:
            body += ["", "", f"class {prefix}{g.title()}Api:",
                     f'    """The operations of chizu.service.api.routes.{g}."""', "",
                     f"    def __init__(self, transport: {transport}) -> None:",
                     "        self._t = transport"]
            for op in ops:
                if op.group == g:
                    body += ["", op.method_text(sync)]
    imports: dict[str, list[str]] = {}
    for name in sorted(used):
        imports.setdefault(known[name].__module__, []).append(name)
    imports["chizu.service.client_base"] = ["AsyncTransport", "JobError", "ProblemError",
                                            "Request", "ServerEvent", "SyncTransport",
                                            "segment"]
    for module in sorted(imports):
        names = sorted(imports[module], key=lambda n: (n[0].islower(), n))  # as isort does
        line = f"from {module} import {', '.join(names)}"
        out += [line] if len(line) <= 100 else \
            [f"from {module} import ("] + [f"    {n}," for n in names] + [")"]
    out += ["", '__all__ = ["AsyncClient", "Client", "JobError", "ProblemError", "ServerEvent"]']
    out += body
    out += ["", "", *client_classes(groups)]
    return "\n".join(out) + "\n"


def client_classes(groups: list[str]) -> list[str]:
    sync_attrs = [f"        self.{g} = {g.title()}Api(self._t)" for g in groups]
    async_attrs = [f"        self.{g} = Async{g.title()}Api(self._t)" for g in groups]
    return [
        "class Client:",
        '    """The service at ``base_url`` (or over ``http``, e.g. a FastAPI TestClient)."""',
        "",
        "    def __init__(self, base_url: str = \"http://127.0.0.1:8000\",",
        "                 timeout_s: float = 60.0, http: httpx.Client | None = None) -> None:",
        "        self._t = SyncTransport(base_url, timeout_s, http)",
        *sync_attrs,
        "        self.wait_job = self._t.wait_job",
        "",
        "    def close(self) -> None:",
        "        self._t.close()",
        "",
        "    def __enter__(self) -> Client:",
        "        return self",
        "",
        "    def __exit__(self, et: type[BaseException] | None, e: BaseException | None,",
        "                 tb: TracebackType | None) -> None:",
        "        self.close()",
        "",
        "",
        "class AsyncClient:",
        '    """As :class:`Client`, with ``await``."""',
        "",
        "    def __init__(self, base_url: str = \"http://127.0.0.1:8000\",",
        "                 timeout_s: float = 60.0,",
        "                 http: httpx.AsyncClient | None = None) -> None:",
        "        self._t = AsyncTransport(base_url, timeout_s, http)",
        *async_attrs,
        "        self.wait_job = self._t.wait_job",
        "",
        "    async def aclose(self) -> None:",
        "        await self._t.aclose()",
        "",
        "    async def __aenter__(self) -> AsyncClient:",
        "        return self",
        "",
        "    async def __aexit__(self, et: type[BaseException] | None, e: BaseException | None,",
        "                        tb: TracebackType | None) -> None:",
        "        await self.aclose()",
    ]


def main() -> None:
    text = generate()
    if "--check" in sys.argv:
        sys.exit(0 if TARGET.exists() and TARGET.read_text() == text else 1)
    TARGET.write_text(text)
    print(f"wrote {TARGET}")


if __name__ == "__main__":
    main()
