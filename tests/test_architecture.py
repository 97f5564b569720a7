"""The one-way flow of imports: numeric's shared modules (numeric/*.py: geometry, world,
simulator, scan, observation, occupancy, ...) -> the method packages (numeric/slam,
eigenspace, qualitative, viewpoint; none imports another) -> the modules composing them
(numeric/mission.py: the mission's robot and its evaluation; numeric/figures.py) ->
service (service/kb.py the only module importing pyswip) -> the routes (service/api).
Every import statement counts, also those inside functions. numeric knows no web and no
HTTP: its errors name what went wrong, and service/errors.py alone gives them a status."""

from __future__ import annotations

import ast
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
NUMERIC = ROOT / "numeric"
SERVICE = ROOT / "service"
METHODS = sorted(p.name for p in NUMERIC.iterdir() if (p / "__init__.py").exists())
#: numeric's modules composing the method packages: they may import any of them, and
#: no other numeric module imports them
COMPOSITES = ("mission", "figures")
#: what numeric never imports: the service, web frameworks and clients, HTTP, Prolog
WEB = ("service", "fastapi", "starlette", "uvicorn", "pyswip", "http", "httpx")
#: names that would carry an HTTP status, and the word that would explain one
STATUS_NAMES = {"status", "status_code", "http_status"}
HTTP_WORD = re.compile(r"\bHTTP\b|\bHTTPStatus\b")


def imports(path: Path) -> Iterator[str]:
    """The modules a file imports, named as the repository's folders (``numeric.x`` for
    the installed ``chizu.numeric.x``)."""
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            yield node.module.removeprefix("chizu.")
        elif isinstance(node, ast.Import):
            yield from (a.name.removeprefix("chizu.") for a in node.names)


def back_edges(root: Path) -> list[str]:
    """Imports under ``root`` that run against the flow (as "file -> module")."""
    bad = []
    for f in sorted(root.rglob("*.py")):
        rel = f.relative_to(ROOT)
        own = rel.parts[1] if len(rel.parts) > 2 else None  # method package, or shared
        composite = len(rel.parts) == 2 and rel.stem in COMPOSITES
        for m in imports(f):
            top, *rest = m.split(".")
            if rel.parts[0] == "numeric":
                if top in WEB:
                    bad.append(f"{rel} -> {m}")  # numeric knows no web and no Prolog
                elif top == "numeric" and rest and rest[0] in COMPOSITES and not composite:
                    bad.append(f"{rel} -> {m}")  # shared or method -> their composition
                elif top == "numeric" and rest and rest[0] in METHODS \
                        and rest[0] != own and not composite:
                    bad.append(f"{rel} -> {m}")  # shared -> method, or method -> method
            else:
                if top == "pyswip" and rel != Path("service/kb.py"):
                    bad.append(f"{rel} -> {m}")
                if m.startswith("service.api") and "api" not in rel.parts and \
                        rel != Path("service/app.py"):
                    bad.append(f"{rel} -> {m}")  # the services do not know their routes
    return bad


def http_knowledge(root: Path) -> list[str]:
    """Places under ``root`` that know HTTP (as "file:line"): the word HTTP in code, a
    docstring or a comment, or a status number (100-599) given to a ``status``-like
    name, as an assignment, a class attribute or a keyword argument."""
    bad = []
    for f in sorted(root.rglob("*.py")):
        rel = f.relative_to(ROOT)
        text = f.read_text(encoding="utf-8")
        bad += [f"{rel}:{i}" for i, line in enumerate(text.splitlines(), 1)
                if HTTP_WORD.search(line)]
        for node in ast.walk(ast.parse(text)):
            named: list[tuple[str | None, ast.expr | None]] = []
            if isinstance(node, ast.Assign):
                named = [(getattr(t, "id", getattr(t, "attr", None)), node.value)
                         for t in node.targets]
            elif isinstance(node, ast.AnnAssign):
                named = [(getattr(node.target, "id", getattr(node.target, "attr", None)),
                          node.value)]
            elif isinstance(node, ast.keyword):
                named = [(node.arg, node.value)]
            for name, value in named:
                if name in STATUS_NAMES and isinstance(value, ast.Constant) \
                        and type(value.value) is int and 100 <= value.value <= 599:
                    bad.append(f"{rel}:{node.lineno}")
    return bad


def test_numeric_knows_no_http() -> None:
    """No HTTP status in numeric: its errors are InvalidInput, NotFound, Conflict, and
    service/errors.py's table answers each with its status."""
    assert http_knowledge(NUMERIC) == []


def test_the_http_check_sees_a_status(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The check itself: a class attribute, a keyword and the word are each reported."""
    fake = tmp_path / "numeric"
    fake.mkdir()
    (fake / "a.py").write_text("class E(Exception):\n    status = 404\n")
    (fake / "b.py").write_text("def f(g):\n    return g(status_code=422)\n")
    (fake / "c.py").write_text('"""Answered with HTTP 409."""\n')
    (fake / "d.py").write_text("status = 'done'\nn = 404\n")
    monkeypatch.setattr(__import__(__name__, fromlist=["ROOT"]), "ROOT", tmp_path)
    assert http_knowledge(fake) == ["numeric/a.py:2", "numeric/b.py:2", "numeric/c.py:1"]


def test_every_domain_error_has_one_status() -> None:
    """service/errors.py's table answers every error class of numeric and the service
    (the nearest class in its MRO), and the classes themselves carry none."""
    from chizu.numeric import errors
    from chizu.service.errors import STATUS, status_of

    classes = [c for c in vars(errors).values()
               if isinstance(c, type) and issubclass(c, errors.ChizuError)]
    classes += list(STATUS)
    for c in classes:
        assert "status" not in vars(c), c
        assert 400 <= status_of(c.__new__(c)) <= 599, c
    assert status_of(errors.NotFound("x")) == 404


def test_the_code_imports_its_installed_names() -> None:
    """numeric/ and service/ are installed as chizu.numeric and chizu.service: an import of
    the bare folder name would work from the repository only, and load a second copy of
    the module beside the installed one."""
    bare = []
    for folder in ("numeric", "service", "tests", "docs", "examples"):
        for f in sorted((ROOT / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(f.read_text(encoding="utf-8"))):
                names = [node.module or ""] if isinstance(node, ast.ImportFrom) \
                    and node.level == 0 else [a.name for a in node.names] \
                    if isinstance(node, ast.Import) else []
                bare += [f"{f.relative_to(ROOT)}:{node.lineno}" for n in names
                         if n.split(".")[0] in ("numeric", "service")]
    assert bare == []


def test_the_method_packages_are_found() -> None:
    assert {"slam", "eigenspace", "qualitative", "viewpoint"} <= set(METHODS)
    assert all((NUMERIC / f"{c}.py").exists() for c in COMPOSITES)


@pytest.mark.parametrize("root", [NUMERIC, SERVICE], ids=["numeric", "service"])
def test_no_import_runs_against_the_flow(root: Path) -> None:
    assert back_edges(root) == []


def test_the_check_sees_a_back_edge(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The walker itself: a shared module importing a method package is reported."""
    fake = tmp_path / "numeric"
    (fake / "slam").mkdir(parents=True)
    (fake / "slam" / "__init__.py").write_text("")
    (fake / "shared.py").write_text("def f():\n    from chizu.numeric.slam.x import y\n")
    monkeypatch.setattr(__import__(__name__, fromlist=["ROOT"]), "ROOT", tmp_path)
    assert back_edges(fake) == ["numeric/shared.py -> numeric.slam.x"]


def test_the_check_sees_a_composite_imported(tmp_path: Path,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """A composite (numeric/mission.py) may import a method package; a method package
    importing it is reported."""
    fake = tmp_path / "numeric"
    (fake / "viewpoint").mkdir(parents=True)
    (fake / "viewpoint" / "__init__.py").write_text("")
    (fake / "viewpoint" / "online.py").write_text("from chizu.numeric.mission import Trace\n")
    (fake / "mission.py").write_text("from chizu.numeric.viewpoint.online import Run\n")
    monkeypatch.setattr(__import__(__name__, fromlist=["ROOT"]), "ROOT", tmp_path)
    assert back_edges(fake) == ["numeric/viewpoint/online.py -> numeric.mission"]


def test_the_openapi_documents_every_answer() -> None:
    """Every operation's success answer has a schema (a model, a typed list, or the
    media type of an image or text answer): no bare ``object``."""
    from chizu.service.app import create_app

    spec = create_app().openapi()
    generic = ({}, {"type": "object"}, {"type": "object", "additionalProperties": True})
    bare = []
    for path, ops in spec["paths"].items():
        for method, op in ops.items():
            ok = False
            for code, resp in op["responses"].items():
                if not code.startswith("2"):
                    continue
                ok = ok or code == "204"
                for media, content in resp.get("content", {}).items():
                    schema = {k: v for k, v in content.get("schema", {}).items()
                              if k != "title"}
                    ok = ok or media != "application/json" or schema not in generic
            if not ok:
                bare.append(f"{method.upper()} {path}")
    assert bare == []


def test_the_openapi_documents_every_error_as_a_problem() -> None:
    """Every 4xx and 5xx answer of every operation is declared as
    application/problem+json with the Problem schema (FastAPI's default 422 declared a
    JSON shape chizu never sends); 404 wherever the path names something."""
    from chizu.service.app import create_app

    spec = create_app().openapi()
    assert "HTTPValidationError" not in spec["components"]["schemas"]
    for path, ops in spec["paths"].items():
        for method, op in ops.items():
            errors = {c: r for c, r in op["responses"].items() if c[0] in "45"}
            assert "422" in errors and ("{" not in path or "404" in errors), (method, path)
            for code, resp in errors.items():
                assert list(resp["content"]) == ["application/problem+json"], (path, code)
                assert resp["content"]["application/problem+json"]["schema"] == {
                    "$ref": "#/components/schemas/Problem"}, (path, code)


def test_the_compute_workers_load_no_web_and_no_prolog() -> None:
    """The modules the compute workers import (service.compute's tasks and
    service.viewpoint_tasks) pull in numeric only: no web framework, no pyswip."""
    import subprocess
    import sys

    code = ("import sys, chizu.service.compute, chizu.service.viewpoint_tasks; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in "
            "('pyswip', 'fastapi', 'starlette', 'uvicorn') or m == 'chizu.service.kb'))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, check=True).stdout.strip()
    assert out == "[]", out


def test_the_schema_names_every_built_in_world() -> None:
    """WorldDescription.template's schema enum is the TEMPLATES table (a client generator
    sees which names exist)."""
    import typing

    from chizu.numeric.world import TemplateName
    from chizu.numeric.worlds import TEMPLATES

    assert set(typing.get_args(TemplateName)) == set(TEMPLATES)


def slam_back_edges(root: Path) -> list[str]:
    """Imports inside numeric/slam that run against its own flow: the matching kernels
    (``matching/``) know no estimator and no estimator's stage; the two estimators
    (``rbpf/``, ``graph/``) do not import each other."""
    bad = []
    for f in sorted((root / "numeric" / "slam").rglob("*.py")):
        rel = f.relative_to(root)
        part = rel.parts[2] if len(rel.parts) > 3 else None
        for m in imports(f):
            parts = m.split(".")
            if parts[:2] != ["numeric", "slam"] or len(parts) < 3:
                continue
            if part == "matching" and parts[2] in ("rbpf", "graph", "alignment", "runner"):
                bad.append(f"{rel} -> {m}")
            if part in ("rbpf", "graph") and parts[2] in ("rbpf", "graph") \
                    and parts[2] != part:
                bad.append(f"{rel} -> {m}")
    return bad


def test_the_slam_estimators_share_kernels_but_not_each_other() -> None:
    assert {p.name for p in (NUMERIC / "slam").iterdir() if (p / "__init__.py").exists()} \
        >= {"matching", "rbpf", "graph"}
    assert slam_back_edges(ROOT) == []


def test_the_slam_check_sees_a_back_edge(tmp_path: Path) -> None:
    """The walker itself: a kernel importing an estimator is reported."""
    kernels = tmp_path / "numeric" / "slam" / "matching"
    kernels.mkdir(parents=True)
    (kernels / "k.py").write_text("from chizu.numeric.slam.rbpf.filter import RbpfSlam\n")
    assert slam_back_edges(tmp_path) == [
        "numeric/slam/matching/k.py -> numeric.slam.rbpf.filter"]
