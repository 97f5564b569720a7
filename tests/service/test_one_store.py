"""One store, one truth: the CLI and a running service on one data directory see each
other's writes. A world the CLI commits a map into, creates or deletes is answered so by
the running service at its next request, without a restart (the store's world versions,
:meth:`chizu.service.worlds.WorldService.ready`)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from chizu.service.client import Client, ProblemError
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


def count(c: Client, world: str, goal: str) -> int:
    out = c.qualitative.post_query(world, {"goal": f"aggregate_all(count, {goal}, N)"})
    return int(out.solutions[0]["N"])


def test_the_service_sees_what_the_cli_wrote(tmp_path: Path) -> None:
    data = tmp_path / "data"
    server = LiveServer(data)
    c = Client(server.url, timeout_s=60)
    try:
        c.worlds.create_world({"name": "lab", "template": "demo"})
        assert count(c, "lab", "committed_map(_)") == 0
        with pytest.raises(ProblemError) as e:  # the world has no map yet
            c.slam.get_world_map("lab")
        assert e.value.status == 404 and e.value.field == "map", e.value

        # the CLI commits a SLAM map into the world the service holds
        env = {**os.environ, "CHIZU_DATA_DIR": str(data), "CHIZU_DEMO_WORLD": ""}
        r2 = subprocess.run([sys.executable, "-m", "chizu.service.cli", "slam", str(CLIP),
                             "--world", "lab", "--out", str(tmp_path / "out")], env=env,
                            cwd=ROOT, capture_output=True, text=True, timeout=600)
        assert r2.returncode == 0, r2.stdout + r2.stderr
        assert count(c, "lab", "committed_map(_)") == 1
        assert count(c, "lab", "map_pose(_, _, _, _, _)") > 0
        c.slam.get_world_map("lab")  # no 404 now

        # the service writes on top of it: both are kept
        obs = {"at": "rn0a", "seen": [{"landmark": "c0", "bearing_rad": 0.1, "distance_m": 2.0},
                                      {"landmark": "c1", "bearing_rad": 1.0, "distance_m": 3.0}]}
        c.qualitative.post_observation("lab", obs)
        assert count(c, "lab", "committed_map(_)") == 1 and count(c, "lab", "rec(_, _, _)") > 0

        # a world another process creates, then deletes
        other_process(data, "asyncio.run(services.worlds.create("
                            "WorldDescription(name='annex', template='demo')))")
        assert "annex" in [w.name for w in c.worlds.list_worlds()]
        assert count(c, "annex", "landmark(_)") == count(c, "lab", "landmark(_)") > 0
        other_process(data, "asyncio.run(services.worlds.delete('annex'))")
        with pytest.raises(ProblemError) as e:
            c.qualitative.post_query("annex", {"goal": "landmark(L)"})
        assert e.value.status == 404 and e.value.field == "world"
        with pytest.raises(ProblemError) as e:
            c.qualitative.get_path("annex", from_="rn0a", to="c1")
        assert e.value.status == 404
    finally:
        c.close()
        server.stop()
    # and a restart finds what both wrote
    server = LiveServer(data)
    c = Client(server.url, timeout_s=30)
    try:
        assert count(c, "lab", "committed_map(_)") == 1
        with pytest.raises(ProblemError) as e:
            c.worlds.get_world("annex")
        assert e.value.status == 404
    finally:
        c.close()
        server.stop()
