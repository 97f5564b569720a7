"""The documentation site (mkdocs.yml) builds with ``--strict`` and holds what it promises.

A broken link in a note or a results page, a cross-reference in a docstring that does not
resolve, or a module the API reference cannot load fails ``mkdocs build --strict``; this
test runs that build (about 20 s), so ``make test`` fails on them as CI does. It then
checks that every module of ``numeric/`` and ``service/`` got a reference page, that the
HTTP API page names every route of the app, and that no page loads anything from another
host (the site is built and read offline).
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[2]


def _script(name: str) -> ModuleType:
    """A module of docs/_scripts (not a package: loaded from its path)."""
    spec = importlib.util.spec_from_file_location(f"chizu_docs_{name}",
                                                  ROOT / "docs" / "_scripts" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


hooks = _script("hooks")
openapi_page = _script("openapi_page")


def build_site(out: Path) -> None:
    """``mkdocs build --strict`` into ``out``, as ``make docs`` runs it."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get(
        "PYTHONPATH", "")]), "NO_MKDOCS_2_WARNING": "1", "DISABLE_MKDOCS_2_WARNING": "true"}
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir",
                        str(out)], cwd=ROOT, env=env, capture_output=True, text=True,
                       timeout=900)
    assert r.returncode == 0, f"mkdocs build --strict failed:\n{r.stdout}\n{r.stderr}"


def modules_without_a_page(site: Path) -> list[str]:
    missing = []
    for package in ("numeric", "service"):
        for path in (ROOT / package).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            if "__pycache__" in parts:
                continue
            page = site.joinpath("reference", *(parts[:-1] if parts[-1] == "__init__"
                                                else parts), "index.html")
            name = ".".join(p for p in parts if p != "__init__")
            if not page.exists() or name not in page.read_text():
                missing.append(str(path.relative_to(ROOT)))
    return missing


def routes_not_on_the_http_page(site: Path) -> list[str]:
    from chizu.service.app import create_app

    page = (site / "http-api" / "index.html").read_text()
    paths = list(create_app().openapi()["paths"])
    assert "/health" in paths
    return [p for p in paths if f"<code>{p}</code>" not in page]


def pages_loading_from_other_hosts(site: Path) -> list[str]:
    remote = re.compile(r"<(?:script|link|img)\b[^>]*\b(?:src|href)=\"(?:https?:)?//")
    return [str(p.relative_to(site)) for p in site.rglob("*.html")
            if remote.search(p.read_text())]


def test_the_site_builds_strict_with_every_module_route_and_nothing_remote(
        tmp_path: Path) -> None:
    """One build (one test, so that pytest-xdist's workers do not each build it)."""
    site = tmp_path / "site"
    build_site(site)
    assert modules_without_a_page(site) == []
    assert routes_not_on_the_http_page(site) == []
    assert (site / "http-api" / "openapi.json").exists()
    assert (site / "results" / "index.html").exists()
    assert pages_loading_from_other_hosts(site) == []


def test_sphinx_roles_become_code() -> None:
    text = "see :func:`run_log`, :class:`~chizu.numeric.scan.Scan` and :py:mod:`numeric`"
    assert hooks.ROLE.sub(hooks.role_to_code, text) == "see `run_log`, `Scan` and `numeric`"


def test_links_out_of_docs_are_rewritten_or_left_broken(tmp_path: Path) -> None:
    docs = ROOT / "docs"
    page = "notes/x.md"
    on_site = {"notes/y.md"}.__contains__
    md = ("[y](y.md) [runner](../../numeric/slam/runner.py) [readme](../../README.md) "
          "[bench](../../tests/bench/slam.py) [gone](../../numeric/nothing.py) "
          "[url](https://example.org/a.md) [home](docs/index.md)")
    out = hooks.rewrite_links(md, page, docs, on_site)
    assert "[y](y.md)" in out  # a page of the site: MkDocs checks it
    assert "[runner](../reference/numeric/slam/runner.md)" in out
    assert "[readme](../index.md)" in out
    assert "bench (`tests/bench/slam.py`)" in out
    assert "[gone](../../numeric/nothing.py)" in out  # broken: left for --strict
    assert "[url](https://example.org/a.md)" in out
    assert "[home](../index.md)" in out  # written from the repository root, as the README
    fenced = "```\n[runner](../../numeric/slam/runner.py)\n```"
    assert hooks.rewrite_links(fenced, page, docs, on_site) == fenced


def test_openapi_rendering() -> None:
    type_of, prose = openapi_page.type_of, openapi_page.prose
    assert type_of({"$ref": "#/components/schemas/ScanIn"}) == "[`ScanIn`](#schema-scanin)"
    assert type_of({"anyOf": [{"type": "number"}, {"type": "null"}]}) == "`number` | `null`"
    assert type_of({"type": "array", "items": {"type": "integer"}}) == "array of `integer`"
    assert prose("id: ^[a-z][a-z0-9]*$ in `[0, 1]`") == r"id: ^\[a-z\]\[a-z0-9\]*$ in `[0, 1]`"
    spec = {"openapi": "3.1.0", "info": {"title": "t", "version": "1"},
            "paths": {"/a/{x}": {"get": {"tags": ["A"], "summary": "Get A", "parameters": [
                {"name": "x", "in": "path", "required": True, "schema": {"type": "string"}}],
                "responses": {"200": {"description": "ok", "content": {"application/json": {
                    "schema": {"$ref": "#/components/schemas/B"}}}}}}}},
            "components": {"schemas": {"B": {"type": "object", "required": ["n"],
                                             "properties": {"n": {"type": "integer",
                                                                  "minimum": 0}}}}}}
    page = openapi_page.render(spec)
    assert "### `GET /a/{x}` {#get-a-x}" in page
    assert "| 200 | ok | [`B`](#schema-b) (`application/json`) |" in page
    assert "| `n` | `integer` | yes |  | ≥ 0 |  |" in page
