"""``chizu repl --live``: a scripted session on the service's own knowledge base, paging
past the first page of answers, the localhost rule, and a goal whose client drops the
connection stopping in the service."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable
from pathlib import Path

import httpx
import pytest
from fastapi.testclient import TestClient

from chizu.service.live_repl import LiveRepl, ReplError, check_local
from tests.conftest import LiveServer


def scripted(lines: list[str]) -> Callable[[str], str]:
    it = iter(lines)

    def read(_prompt: str) -> str:
        try:
            return next(it)
        except StopIteration:
            raise EOFError from None

    return read


def session(client: TestClient, lines: list[str]) -> list[str]:
    out: list[str] = []
    LiveRepl(client, "demo", out.append).run(scripted(lines))
    return out


def test_a_scripted_session(client: TestClient) -> None:
    out = session(client, ["landmark(L).", ";", "",            # two answers, then stop
                           "landmark(nosuch).",                # none
                           "X = 1,", "Y = two.",               # a goal over two lines
                           "assertz(x).",                      # the sandbox refuses it
                           "halt.", "landmark(L)."])           # after halt: nothing
    assert out[0].startswith("L = ") and out[1].startswith("L = ") and out[2] == "."
    assert out[3] == "false."
    assert out[4] == "X = 1,\nY = two" and out[5] == "."
    assert out[6].startswith("% ") and "goal" in out[6]
    assert len(out) == 7  # halt ended it


def test_answers_past_the_first_page(client: TestClient) -> None:
    goal = "member(X, [" + ", ".join(str(i) for i in range(25)) + "])."
    out = session(client, [goal] + [";"] * 30)
    assert out[:25] == [f"X = {i}" for i in range(25)] and out[25] == "."


def test_the_service_must_be_local_unless_allowed() -> None:
    for url in ("http://127.0.0.1:8000", "http://localhost:8000", "http://[::1]:8000"):
        check_local(url, allow_remote=False)
    with pytest.raises(ReplError):
        check_local("http://10.0.0.5:8000", allow_remote=False)
    check_local("http://10.0.0.5:8000", allow_remote=True)


def test_an_unknown_world_is_said_at_the_start(client: TestClient) -> None:
    with pytest.raises(ReplError, match="does not exist"):
        LiveRepl(client, "nosuch").check_world()


def test_a_goal_whose_connection_drops_is_stopped(tmp_path: Path) -> None:
    """What ctrl-C does: the client closes the connection mid-query; the service stops
    the goal, and the next one does not wait for the first's 2 s limit."""
    srv = LiveServer(tmp_path / "data", demo=True)
    try:
        slow = (b'{"goal": "reachable(A, B, P, M), reachable(C, D, Q, N), '
                b'reachable(E, F, R, O), fail"}')
        host, port = "127.0.0.1", srv.port
        with socket.create_connection((host, port)) as s:
            s.sendall(b"POST /worlds/demo/query HTTP/1.1\r\nHost: x\r\n"
                      b"Content-Type: application/json\r\nContent-Length: "
                      + str(len(slow)).encode() + b"\r\n\r\n" + slow)
            time.sleep(0.4)  # the goal is running
        t0 = time.perf_counter()
        r = httpx.post(srv.url + "/worlds/demo/query", json={"goal": "landmark(L)"},
                       timeout=30)
        waited = time.perf_counter() - t0
        assert r.status_code == 200, r.text
        assert waited < 1.2, waited  # not the ~1.6 s the dropped goal had left
    finally:
        srv.stop()


def test_the_cli_finds_the_service_where_chizu_port_says(tmp_path: Path) -> None:
    """``chizu repl W --live`` without ``--url`` talks to the service at CHIZU_HOST and
    CHIZU_PORT, where ``chizu serve`` listens (it ignored the port)."""
    import os
    import subprocess
    import sys

    srv = LiveServer(tmp_path / "data", demo=True)
    try:
        env = {**os.environ, "CHIZU_PORT": str(srv.port), "CHIZU_HOST": "127.0.0.1",
               "CHIZU_DATA_DIR": str(tmp_path / "other")}
        r = subprocess.run([sys.executable, "-m", "chizu.service.cli", "repl", "demo", "--live"],
                           input="landmark(rn0a).\n", capture_output=True, text=True,
                           timeout=120, env=env)
        assert r.returncode == 0, r.stdout + r.stderr
        assert f"at http://127.0.0.1:{srv.port}" in r.stdout and "true" in r.stdout, r.stdout
    finally:
        srv.stop()
