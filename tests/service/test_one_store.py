"""One store, one truth: the CLI and a running service on one data directory see each
other's writes. A world the CLI commits a map into, creates or deletes is answered so by
the running service at its next request, without a restart (the store's world versions,
:meth:`chizu.service.worlds.WorldService.ready`)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import httpx

from tests.conftest import ROOT, LiveServer

CLIP = ROOT / "examples" / "aces-clip.clf"


def other_process(data_dir: Path, code: str) -> None:
    """``code`` in a process of its own on ``data_dir``'s store, with ``services`` open
    as every CLI command opens them."""
    prog = ("import asyncio\nfrom chizu.service.container import open_services\n"
            "from chizu.service.settings import get_settings\n"
            "from chizu.numeric.world import WorldDescription\n"
            "services = open_services(get_settings().model_copy(update={'workers': 0}))\n"
            f"try:\n    {code}\nfinally:\n    services.close()\n")
    env = {**os.environ, "CHIZU_DATA_DIR": str(data_dir), "CHIZU_DEMO_WORLD": ""}
    subprocess.run([sys.executable, "-c", prog], env=env, cwd=ROOT, check=True, timeout=300)


def count(url: str, world: str, goal: str) -> int:
    r = httpx.post(f"{url}/worlds/{world}/query", json={"goal": f"aggregate_all(count, "
                                                                f"{goal}, N)"}, timeout=30)
    assert r.status_code == 200, r.text
    return int(r.json()["solutions"][0]["N"])


def test_the_service_sees_what_the_cli_wrote(tmp_path: Path) -> None:
    data = tmp_path / "data"
    server = LiveServer(data)
    try:
        url = server.url
        r = httpx.post(url + "/worlds", json={"name": "lab", "template": "demo"}, timeout=60)
        assert r.status_code == 201, r.text
        assert count(url, "lab", "committed_map(_)") == 0
        r = httpx.get(url + "/worlds/lab/map", timeout=30)  # the world has no map yet
        assert r.status_code == 404 and r.json()["field"] == "map", r.text

        # the CLI commits a SLAM map into the world the service holds
        env = {**os.environ, "CHIZU_DATA_DIR": str(data), "CHIZU_DEMO_WORLD": ""}
        r2 = subprocess.run([sys.executable, "-m", "chizu.service.cli", "slam", str(CLIP),
                             "--world", "lab", "--out", str(tmp_path / "out")], env=env,
                            cwd=ROOT, capture_output=True, text=True, timeout=600)
        assert r2.returncode == 0, r2.stdout + r2.stderr
        assert count(url, "lab", "committed_map(_)") == 1
        assert count(url, "lab", "map_pose(_, _, _, _, _)") > 0
        assert httpx.get(url + "/worlds/lab/map", timeout=30).status_code == 200

        # the service writes on top of it: both are kept
        obs = {"at": "rn0a", "seen": [{"landmark": "c0", "bearing_rad": 0.1, "distance_m": 2.0},
                                      {"landmark": "c1", "bearing_rad": 1.0, "distance_m": 3.0}]}
        r = httpx.post(url + "/worlds/lab/observations", json=obs, timeout=30)
        assert r.status_code == 201, r.text
        assert count(url, "lab", "committed_map(_)") == 1 and count(url, "lab", "rec(_, _, _)") > 0

        # a world another process creates, then deletes
        other_process(data, "asyncio.run(services.worlds.create("
                            "WorldDescription(name='annex', template='demo')))")
        assert "annex" in [w["name"] for w in httpx.get(url + "/worlds", timeout=30).json()]
        assert count(url, "annex", "landmark(_)") == count(url, "lab", "landmark(_)") > 0
        other_process(data, "asyncio.run(services.worlds.delete('annex'))")
        r = httpx.post(url + "/worlds/annex/query", json={"goal": "landmark(L)"}, timeout=30)
        assert r.status_code == 404 and r.json()["field"] == "world"
        r = httpx.get(url + "/worlds/annex/path", params={"from": "rn0a", "to": "c1"},
                      timeout=30)
        assert r.status_code == 404
    finally:
        server.stop()
    # and a restart finds what both wrote
    server = LiveServer(data)
    try:
        assert count(server.url, "lab", "committed_map(_)") == 1
        assert httpx.get(server.url + "/worlds/annex", timeout=30).status_code == 404
    finally:
        server.stop()
