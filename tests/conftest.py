"""Fixtures: one in-process app (TestClient) per session and a live uvicorn server."""

from __future__ import annotations

import math
import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from fastapi.testclient import TestClient

from chizu.service.app import create_app
from chizu.service.settings import Settings

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="session")
def app_settings(tmp_path_factory: pytest.TempPathFactory) -> Settings:
    # the request budget (30 s by default) is a speed limit, which the benchmarks
    # measure, not the tests: on a loaded 2-core machine the awkward viewpoint scenes
    # (28 s alone) ran past it. Tests of the budget itself set their own.
    return Settings(data_dir=tmp_path_factory.mktemp("data"), demo_world="demo",
                    request_budget_s=300.0)


@pytest.fixture(scope="session")
def client(app_settings: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(app_settings)) as c:
        yield c


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class LiveServer:
    """``chizu serve`` in a subprocess on a free loopback port."""

    def __init__(self, data_dir: Path, demo: bool = False,
                 start_timeout_s: float = 60.0, command: list[str] | None = None,
                 cwd: Path = ROOT) -> None:
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        env = {**os.environ, "CHIZU_DATA_DIR": str(data_dir), "CHIZU_PORT": str(self.port),
               "CHIZU_HOST": "127.0.0.1", "CHIZU_DEMO_WORLD": "demo" if demo else ""}
        data_dir.mkdir(parents=True, exist_ok=True)
        # the log goes to a file: an unread pipe fills up and blocks the server
        self.log_path = data_dir / "server.log"
        self._log = self.log_path.open("ab")
        command = command or [sys.executable, "-m", "chizu.service.cli", "serve"]
        self.proc = subprocess.Popen(command, env=env, cwd=cwd, stdout=self._log,
                                     stderr=subprocess.STDOUT)
        deadline = time.monotonic() + start_timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited: {self.log_path.read_text()}")
            try:
                if httpx.get(self.url + "/health", timeout=1).status_code == 200:
                    return
            except httpx.HTTPError:
                time.sleep(0.2)
        self.stop()
        raise RuntimeError("server did not start")

    def stop(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self._log.close()


@pytest.fixture
def live_server_factory() -> Iterator[type[LiveServer]]:
    started: list[LiveServer] = []

    class Factory(LiveServer):
        def __init__(self, data_dir: Path, demo: bool = False,
                 start_timeout_s: float = 60.0) -> None:
            super().__init__(data_dir, demo)
            started.append(self)

    yield Factory
    for s in started:
        s.stop()


# The paper's Fig. 1 as coordinates: A=(0,0), C=(0,10), B=(-1,5), D=(1,5).
FIG1 = {"a": (0.0, 0.0), "b": (-1.0, 5.0), "c": (0.0, 10.0), "d": (1.0, 5.0)}
FIG1_SEEN = {"a": ["b", "d"], "b": ["a", "c"], "d": ["a", "c"]}


def observation(at: str, seen: list[str], coords: dict[str, tuple[float, float]] = FIG1,
                heading: float = 0.3) -> dict:
    """Exact bearings (robot frame, heading ``heading``) and distances from coordinates."""
    ax, ay = coords[at]
    out = []
    for s in seen:
        x, y = coords[s]
        b = math.atan2(y - ay, x - ax) - heading
        b = math.atan2(math.sin(b), math.cos(b))
        out.append({"landmark": s, "bearing_rad": b, "distance_m": math.hypot(x - ax, y - ay)})
    return {"at": at, "seen": out}


def make_fig1_world(c: TestClient | httpx.Client, name: str) -> None:
    r = c.post("/worlds", json={"name": name,
                                "landmarks": [{"id": k, "x": v[0], "y": v[1]}
                                              for k, v in FIG1.items()]})
    assert r.status_code == 201, r.text
    for at, seen in FIG1_SEEN.items():
        r = c.post(f"/worlds/{name}/observations", json=observation(at, seen))
        assert r.status_code == 201, r.text
