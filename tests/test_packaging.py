"""The distribution: one name, ``chizu``, in site-packages; the rule files inside it; the
version in one place. The wheel is built from the sdist (``python -m build``), installed
into a fresh virtual environment outside the repository and serves the demo world."""

from __future__ import annotations

import os
import site
import subprocess
import sys
import tomllib
import venv
import zipfile
from pathlib import Path

import httpx
import pytest

from tests.conftest import ROOT, LiveServer

PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_every_package_folder_is_installed() -> None:
    """pyproject's package list is the folders holding an ``__init__.py`` under numeric/
    and service/, each as ``chizu.<folder path>``, and the rule files' ``chizu.prolog``."""
    on_disk = {"chizu.prolog"} | {
        "chizu." + ".".join(p.parent.relative_to(ROOT).parts)
        for folder in ("numeric", "service") for p in (ROOT / folder).rglob("__init__.py")}
    assert set(PYPROJECT["tool"]["setuptools"]["packages"]) == on_disk


def test_the_version_is_the_distributions() -> None:
    from chizu.service import __version__
    from chizu.service.app import create_app

    assert __version__ == PYPROJECT["project"]["version"]
    assert create_app().version == __version__
    out = subprocess.run([sys.executable, "-m", "chizu.service.cli", "--version"],
                         capture_output=True, text=True, check=True).stdout
    assert out.strip() == f"chizu {__version__}"


@pytest.fixture(scope="module")
def dist(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The sdist and the wheel built from it (no build isolation: the dev environment's
    setuptools builds, as it would offline)."""
    out = tmp_path_factory.mktemp("dist")
    subprocess.run([sys.executable, "-m", "build", "--no-isolation", "--outdir", str(out),
                    str(ROOT)], check=True, capture_output=True, text=True)
    return out


def test_the_wheel_holds_chizu_only_and_its_rules(dist: Path) -> None:
    """Nothing but ``chizu/`` and its metadata at the top of site-packages (no ``service``,
    ``numeric`` or ``prolog`` to collide with another distribution), and every rule
    file the loader reads."""
    (wheel,) = dist.glob("chizu-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert {n.split("/")[0] for n in names} == {
        "chizu", f"chizu-{PYPROJECT['project']['version']}.dist-info"}
    rules = {Path(n).name for n in names if n.startswith("chizu/prolog/")}
    assert rules == {p.name for p in (ROOT / "prolog").glob("*.pl")}
    assert "chizu/service/cli.py" in names and "chizu/numeric/slam/merge.py" in names
    console = {Path(n).name for n in names if n.startswith("chizu/service/console/static/")}
    assert console == {p.name for p in (ROOT / "service/console/static").iterdir()}


def test_the_installed_wheel_serves_the_demo_world(dist: Path, tmp_path: Path) -> None:
    """A fresh venv outside the repository, the wheel installed into it (its dependencies
    taken from this environment's site-packages by a path file, not from the
    repository): ``chizu --version`` and ``chizu serve`` run from an unrelated directory
    with the package's own files, and the demo world answers a path query."""
    fresh = tmp_path / "venv"
    venv.create(fresh, with_pip=True)
    bin_ = fresh / "bin"
    (wheel,) = dist.glob("chizu-*.whl")
    subprocess.run([bin_ / "pip", "install", "-q", "--no-deps", "--no-index", str(wheel)],
                   check=True, capture_output=True, text=True)
    fresh_site = Path(subprocess.run(
        [bin_ / "python", "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
        capture_output=True, text=True, check=True).stdout.strip())
    (fresh_site / "dependencies.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    away = tmp_path / "elsewhere"
    away.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    where = subprocess.run(
        [bin_ / "python", "-c", "import chizu.service.kb as k; print(k.__file__)"],
        cwd=away, env=env, capture_output=True, text=True, check=True).stdout.strip()
    assert Path(where).is_relative_to(fresh_site), where
    version = subprocess.run([bin_ / "chizu", "--version"], cwd=away, env=env,
                             capture_output=True, text=True, check=True).stdout
    assert version.strip() == f"chizu {PYPROJECT['project']['version']}"

    server = LiveServer(tmp_path / "data", demo=True, command=[str(bin_ / "chizu"), "serve"],
                        cwd=away)
    try:
        r = httpx.get(server.url + "/worlds/demo/path", params={"from": "rn0a", "to": "c1"},
                      timeout=30)
        assert r.status_code == 200, r.text
        assert r.json()["steps"]
        page = httpx.get(server.url + "/", timeout=10)  # the console, from the package
        assert page.status_code == 200 and "/console/console.js" in page.text
        assert httpx.get(server.url + "/console/console.js", timeout=10).status_code == 200
        assert httpx.get(server.url + "/openapi.json",
                         timeout=10).json()["info"]["version"] == \
            PYPROJECT["project"]["version"]
    finally:
        server.stop()
