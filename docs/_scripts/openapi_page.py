"""The HTTP API page: an OpenAPI 3 schema rendered as one Markdown page.

The site is built and read offline, so the schema is rendered at build time rather than
by Swagger UI or ReDoc fetched from a CDN: an index of the endpoints, then per tag each
endpoint's parameters, request body and responses, then every component schema with its
fields (type, whether required, default, constraints, description). Types that refer to
a component schema link to its section.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable
from typing import Any

METHODS = ("get", "post", "put", "patch", "delete", "head", "options")
#: JSON-schema constraints shown beside a field's type, with their signs
CONSTRAINTS = {"minimum": "≥", "exclusiveMinimum": ">", "maximum": "≤",
               "exclusiveMaximum": "<", "minLength": "length ≥", "maxLength": "length ≤",
               "minItems": "items ≥", "maxItems": "items ≤", "pattern": "pattern"}


def slug(text: str) -> str:
    """An HTML id from ``text``: lower case, runs of other characters as one hyphen."""
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")


def schema_anchor(name: str) -> str:
    return "schema-" + slug(name)


def operation_anchor(method: str, path: str) -> str:
    return slug(f"{method} {path}")


def prose(text: Any) -> str:
    """Free text of the schema as Markdown: brackets outside code spans escaped, so that a
    description such as ``id: ^[a-z][a-z0-9]*$`` is not read as a reference link."""
    parts = str(text).split("`")
    return "`".join(re.sub(r"([\[\]])", r"\\\1", p) if i % 2 == 0 else p
                    for i, p in enumerate(parts))


def cell(text: Any) -> str:
    """``text`` fit for a table cell: one line, pipes escaped."""
    return " ".join(str(text).split()).replace("|", "\\|")


def type_of(schema: dict[str, Any]) -> str:
    """A short Markdown rendering of a JSON schema's type (component references linked)."""
    if "$ref" in schema:
        name = schema["$ref"].rsplit("/", 1)[-1]
        return f"[`{name}`](#{schema_anchor(name)})"
    for key in ("anyOf", "oneOf", "allOf"):
        if key in schema:
            parts = dict.fromkeys(type_of(s) for s in schema[key])
            return (" & " if key == "allOf" else " | ").join(parts)
    if "const" in schema:
        return f"`{json.dumps(schema['const'])}`"
    if "enum" in schema:
        return "one of " + ", ".join(f"`{json.dumps(v)}`" for v in schema["enum"])
    kind = schema.get("type")
    if isinstance(kind, list):
        return " | ".join(type_of({**schema, "type": k}) for k in kind)
    if kind == "array":
        if "prefixItems" in schema:
            return "[" + ", ".join(type_of(s) for s in schema["prefixItems"]) + "]"
        return f"array of {type_of(schema.get('items', {}))}"
    if kind == "object" and isinstance(schema.get("additionalProperties"), dict):
        return f"object of {type_of(schema['additionalProperties'])}"
    if kind is None:
        return "any"
    fmt = schema.get("format") or schema.get("contentMediaType")
    return f"`{kind}`" + (f" ({fmt})" if fmt else "")


def constraints(schema: dict[str, Any]) -> str:
    """The schema's bounds (``≥ 0``, ``items ≤ 500``, ``pattern `^[a-z]...```)."""
    out = []
    for key, sign in CONSTRAINTS.items():
        if key in schema:
            value = f"`{schema[key]}`" if key == "pattern" else schema[key]
            out.append(f"{sign} {value}")
    for sub in schema.get("anyOf", []):  # Optional[X]: X's bounds
        if sub.get("type") != "null":
            out.extend(c for c in constraints(sub).split(", ") if c and c not in out)
    return ", ".join(out)


def field_rows(schema: dict[str, Any]) -> list[str]:
    """One table row per property of an object schema."""
    required = set(schema.get("required", []))
    rows = []
    for name, prop in schema.get("properties", {}).items():
        default = f"`{json.dumps(prop['default'])}`" if "default" in prop else ""
        rows.append(f"| `{name}` | {cell(type_of(prop))} | {'yes' if name in required else ''}"
                    f" | {cell(default)} | {cell(constraints(prop))} | "
                    f"{cell(prose(prop.get('description', '')))} |")
    return rows


def _body(content: dict[str, Any]) -> str:
    """``type (media type)`` of each media type of a request or response body."""
    return "; ".join(f"{type_of(c.get('schema', {}))} (`{mime}`)" for mime, c in content.items())


def operation(method: str, path: str, op: dict[str, Any]) -> list[str]:
    """The section of one endpoint."""
    lines = [f"### `{method.upper()} {path}` {{#{operation_anchor(method, path)}}}", ""]
    if op.get("summary"):
        lines += [f"**{op['summary']}**", ""]
    if op.get("description"):
        lines += [prose(op["description"].strip()), ""]
    params = op.get("parameters", [])
    if params:
        lines += ["| parameter | in | type | required | constraints | description |",
                  "|---|---|---|---|---|---|"]
        lines += [f"| `{p['name']}` | {p['in']} | {cell(type_of(p.get('schema', {})))} | "
                  f"{'yes' if p.get('required') else ''} | "
                  f"{cell(constraints(p.get('schema', {})))} | "
                  f"{cell(prose(p.get('description', '')))} |" for p in params]
        lines.append("")
    body = op.get("requestBody")
    if body:
        lines += [f"Request body{' (required)' if body.get('required') else ''}: "
                  f"{_body(body.get('content', {}))}", ""]
    lines += ["| status | meaning | body |", "|---|---|---|"]
    lines += [f"| {code} | {cell(prose(r.get('description', '')))} | "
              f"{cell(_body(r.get('content', {})))} |"
              for code, r in sorted(op.get("responses", {}).items())]
    return [*lines, ""]


def _operations(spec: dict[str, Any]) -> Iterable[tuple[str, str, str, dict[str, Any]]]:
    """``(tag, method, path, operation)`` in the schema's order."""
    for path, item in spec.get("paths", {}).items():
        for method in METHODS:
            if method in item:
                op = item[method]
                yield (op.get("tags") or ["other"])[0], method, path, op


def render(spec: dict[str, Any], json_name: str = "openapi.json") -> str:
    """The whole page for ``spec``; ``json_name``: where the page's download link points."""
    info = spec.get("info", {})
    ops = list(_operations(spec))
    lines = ["# HTTP API", "",
             f"{info.get('title', 'The API')} {info.get('version', '')}: "
             f"{info.get('description', '')}".strip(), "",
             "This page is generated at build time from the OpenAPI "
             f"{spec.get('openapi', '')} schema of `chizu.service.app.create_app()` (the same "
             f"schema `chizu serve` answers on `/openapi.json`); download it as "
             f"[{json_name}]({json_name}). Errors are RFC 9457 problem details "
             "(`application/problem+json`).", "",
             "| method | path | summary |", "|---|---|---|"]
    lines += [f"| `{m.upper()}` | [`{p}`](#{operation_anchor(m, p)}) | "
              f"{cell(op.get('summary', ''))} |" for _, m, p, op in ops]
    lines.append("")
    for tag in dict.fromkeys(t for t, *_ in ops):
        lines += [f"## {tag}", ""]
        for _, m, p, op in (o for o in ops if o[0] == tag):
            lines += operation(m, p, op)
    schemas = spec.get("components", {}).get("schemas", {})
    if schemas:
        lines += ["## Schemas", ""]
    for name in sorted(schemas, key=str.lower):
        s = schemas[name]
        lines += [f"### `{name}` {{#{schema_anchor(name)}}}", ""]
        if s.get("description"):
            lines += [prose(s["description"].strip()), ""]
        rows = field_rows(s)
        if rows:
            lines += ["| field | type | required | default | constraints | description |",
                      "|---|---|---|---|---|---|", *rows, ""]
        elif "properties" not in s:
            lines += [f"Type: {type_of(s)}", ""]
    return "\n".join(lines) + "\n"
