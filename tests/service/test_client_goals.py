"""Hostile and careless clients (issue "Hardening"): each request that once answered 500,
blocked or lost its headers, sent again."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from service.kb import KbError, KnowledgeBase
from tests.eigenspace.test_api import SMALL, wait_job

PROBLEM = "application/problem+json"
ROOT = Path(__file__).resolve().parents[2]


def is_problem(r, status: int, field: str | None = None) -> None:  # type: ignore[no-untyped-def]
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith(PROBLEM), r.headers
    if field is not None:
        assert r.json()["field"] == field, r.text


def test_a_goal_that_raises_is_the_clients_error(client: TestClient) -> None:
    """``X > 1`` (an unbound comparison) was a 500; a type error likewise."""
    for goal in ("X > 1", "landmark(L), L > 1", "reachable(A, B, P, M), M < P"):
        r = client.post("/worlds/demo/query", json={"goal": goal})
        is_problem(r, 422, "goal")
        assert r.json()["type"].endswith("goal-error"), r.text


def test_non_finite_numbers_in_an_answer_are_text(client: TestClient) -> None:
    """``X = 1.0Inf`` and ``X = 1.5NaN`` were a 500 text/plain: JSON has no such numbers."""
    for goal, text in (("X = 1.0Inf", "inf"), ("X = -1.0Inf", "-1.0inf"), ("X = 1.5NaN", "nan")):
        r = client.post("/worlds/demo/query", json={"goal": goal})
        assert r.status_code == 200, r.text
        value = r.json()["solutions"][0]["X"]
        assert isinstance(value, str) and text in value.lower(), value
    json.loads(r.text)  # strict JSON


def test_405_names_the_allowed_methods(client: TestClient) -> None:
    r = client.put("/worlds/demo/query", json={})
    is_problem(r, 405)
    assert "POST" in r.headers["allow"]
    r = client.delete("/health")
    is_problem(r, 405)
    assert "GET" in r.headers["allow"]


def test_a_chunked_body_over_the_limit_is_413(client: TestClient) -> None:
    """No Content-Length (chunked): 9 MiB was "400 error parsing the body"."""

    def chunks() -> Iterator[bytes]:
        for _ in range(9):
            yield b" " * (1 << 20)

    r = client.post("/worlds", content=chunks(), headers={"content-type": "application/json"})
    is_problem(r, 413, "body")

    def small() -> Iterator[bytes]:
        yield b'{"name": "chunked_ok", '
        yield b'"template": "demo"}'

    r = client.post("/worlds", content=small(), headers={"content-type": "application/json"})
    assert r.status_code == 201, r.text  # a chunked body within the limit still works


def test_client_goals_get_the_shorter_limit() -> None:
    """The engine is one thread: a client's own goal runs under kb_query_time_limit_s,
    everything else under kb_time_limit_s."""
    kb = KnowledgeBase.__new__(KnowledgeBase)
    kb.time_limit_s, kb.inference_limit, kb.query_time_limit_s = 10.0, 1000, 2.0
    assert json.loads(kb._request("query", {}))["time_limit_s"] == 2.0
    assert json.loads(kb._request("facts", {}))["time_limit_s"] == 10.0


def png_header(width: int, height: int) -> bytes:
    """A PNG whose header says ``width`` x ``height`` grey pixels (its pixel data is one
    empty deflate stream: any decoder that got that far would fail or bomb)."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b""))
            + chunk(b"IEND", b""))


@pytest.fixture(scope="module")
def learned(client: TestClient) -> str:
    assert client.post("/worlds", json={"name": "hard_eig", "template": "room_a"}
                       ).status_code == 201
    job = wait_job(client, client.post("/worlds/hard_eig/eigenspace", json=SMALL
                                       ).headers["location"])
    assert job["status"] == "done", job
    return "hard_eig"


def test_huge_pngs_are_refused_from_their_header(client: TestClient, learned: str) -> None:
    """A 14 000 x 14 000 PNG was a 500 (Pillow's decompression-bomb error); eight
    4 000 x 4 000 ones were decoded on the event loop for seconds. Now the header is
    compared with the eigenspace's image size first: 422 naming the image, nothing
    decoded. An upload likewise."""
    import base64

    turn = client.post(f"/worlds/{learned}/camera",
                       json={"pose": {"x": 3, "y": 5}, "turn": 72}).json()["images_png"]
    for side, k in ((14_000, 0), (4_000, 5)):
        bad = list(turn)
        bad[k] = base64.b64encode(png_header(side, side)).decode()
        r = client.post(f"/worlds/{learned}/localize", json={"images_png": bad})
        is_problem(r, 422, f"images_png[{k}]")
        assert f"{side} x {side}" in r.json()["detail"] or "bomb" in r.json()["detail"]
    files = [("images", (f"{i}.png", base64.b64decode(p), "image/png"))
             for i, p in enumerate(turn)]
    files[3] = ("images", ("3.png", png_header(4000, 4000), "image/png"))
    is_problem(client.post(f"/worlds/{learned}/localize/images", files=files), 422, "images[3]")
    r = client.post(f"/worlds/{learned}/localize", json={"images_png": turn})
    assert r.status_code == 200, r.text  # the real turn still localizes


def test_a_learning_job_has_a_size_cap(client: TestClient) -> None:
    """Grid spacing 0.06 m x 360 directions x 256 x 256 images was accepted (and would
    run for days); now refused before the job starts, naming the spacing. The paper's
    size starts."""
    assert client.post("/worlds", json={"name": "cap_w", "template": "room_a"}
                       ).status_code == 201
    r = client.post("/worlds/cap_w/eigenspace", json={
        "learning": {"spacing_m": 0.06, "n_directions": 360},
        "camera": {"width_px": 256, "height_px": 256}})
    is_problem(r, 422, "learning.spacing_m")
    assert client.get("/jobs", params={"world": "cap_w"}).json() == []


def test_text_outside_the_bmp_round_trips(client: TestClient) -> None:
    """An emoji in candidates[].type was stored as two unpaired surrogates (the bridge
    sent JSON with \\ud83d\\ude00 escapes, which Prolog read as two code points);
    reading the fact back through /query was a 500. Now the text round-trips."""
    kind = "mug\U0001F600"
    app = {"a": [40, 40, 40, 40], "b": [0.5, 0.5, 0.5, 0.5], "k": 2.0, "theta_half": 0.8}
    body = {"robot": [0.5, 0.5, 0], "exit": [0.5, 0.5], "time_limit_s": 60,
            "object_types": [{"name": kind, "value": 10, "appearance": app}],
            "grid": {"width": 40, "height": 40, "resolution_m": 0.1,
                     "data": [0] * 1600},
            "candidates": [{"id": "c1", "type": kind, "x": 2.0, "y": 2.0}]}
    assert client.post("/worlds", json={"name": "emoji", "template": "demo"}).status_code == 201
    r = client.post("/worlds/emoji/viewpoint-plan", json=body)
    assert r.status_code == 200, r.text
    r = client.post("/worlds/emoji/query", json={"goal": "vp_candidate(c1, T, _, _, _)"})
    assert r.status_code == 200, r.text
    assert r.json()["solutions"] == [{"T": kind}]
    assert any(kind in f for f in client.get("/worlds/emoji/facts").json())


def test_start_up_loads_a_snapshot_instead_of_replaying(tmp_path: Path) -> None:
    """Every SNAPSHOT_EVERY events a world's event-made facts are stored; a restart
    loads them and replays only the events after. The relations are the same as
    before the restart and as a full replay from the events alone."""
    import sqlite3

    from service.app import create_app
    from service.settings import Settings
    from service.worlds import SNAPSHOT_EVERY
    from tests.conftest import make_fig1_world, observation

    settings = Settings(data_dir=tmp_path, demo_world="")
    kinds = ("lr", "align", "rec", "rea", "reachable")
    with TestClient(create_app(settings)) as c:
        make_fig1_world(c, "snap")
        for i in range(SNAPSHOT_EVERY + 30):
            at, seen = (("b", ["a", "c"]), ("d", ["a", "c"]))[i % 2]
            r = c.post("/worlds/snap/observations", json=observation(at, seen, heading=0.01 * i))
            assert r.status_code == 201, r.text
        assert c.post("/worlds/snap/reached", json={"from": "c", "to": "b"}).status_code == 201
        before = {k: c.get("/worlds/snap/relations", params={"kind": k}).json() for k in kinds}
    db = sqlite3.connect(settings.db_path)
    (snapped,) = db.execute("SELECT event_id FROM snapshots WHERE world = 'snap'").fetchone()
    (last,) = db.execute("SELECT max(id) FROM events WHERE world = 'snap'").fetchone()
    assert 0 < snapped < last  # a snapshot, and events after it to replay
    with TestClient(create_app(settings)) as c:
        after = {k: c.get("/worlds/snap/relations", params={"kind": k}).json() for k in kinds}
    assert after == before
    (blob,) = db.execute("SELECT facts FROM snapshots WHERE world = 'snap'").fetchone()
    for tampered in ({**json.loads(blob), "rules": "other rules"},  # made by other rules
                     {**json.loads(blob), "facts": ["halt"]}):  # refused by load_snapshot
        db.execute("UPDATE snapshots SET facts = ?", (json.dumps(tampered),))
        db.commit()
        with TestClient(create_app(settings)) as c:  # the events alone give the same
            replayed = {k: c.get("/worlds/snap/relations", params={"kind": k}).json()
                        for k in kinds}
        assert replayed == before
        assert db.execute("SELECT count(*) FROM snapshots").fetchone() == (0,)  # dropped
        db.execute("INSERT INTO snapshots SELECT 'snap', ?, ?, 0", (snapped, blob))
        db.commit()
    db.close()


def test_a_snapshot_is_read_as_data(client: TestClient) -> None:
    """load_snapshot asserts only ground qualitative facts: a goal, a variable or a
    fact of another kind is refused naming it."""
    kb = client.app.state.services.kb  # type: ignore[attr-defined]
    from service.kb import KbError

    for bad in ("halt", "lr(a, X, c)", "landmark(z)", "lr(a, b", "map_pose(r1, 0, 0, 0, 0)"):
        try:
            kb.call("load_snapshot", world="demo", facts=["rec(c0, c1)", bad])
        except KbError as e:
            assert e.field == "facts[1]", e
        else:
            raise AssertionError(f"{bad!r} was loaded")


def test_health_answers_while_a_query_holds_the_engine(client: TestClient) -> None:
    """A legal goal run to its time limit held the one engine, and /health waited 9.5 s
    behind it. Now /health probes the engine for 20 ms and says it is busy."""
    import threading
    import time

    assert client.get("/health").json()["engine_busy"] is False
    slow = ("reachable(A, B, P, M), reachable(C, D, Q, N), reachable(E, F, R, O), fail")
    done: list[int] = []
    t = threading.Thread(target=lambda: done.append(client.post(
        "/worlds/demo/query", json={"goal": slow}).status_code))
    t.start()
    time.sleep(0.3)  # the query is running
    t0 = time.perf_counter()
    h = client.get("/health")
    waited = time.perf_counter() - t0
    t.join()
    assert h.status_code == 200 and h.json()["engine_busy"] is True, h.text
    assert waited < 0.5, waited  # the goal ran for its whole 2 s limit
    assert done and done[0] in (200, 422)  # finished, or stopped at its limit (load)


def test_a_query_whose_client_left_is_dropped(client: TestClient) -> None:
    """A client goal queued behind a slow one, whose client disconnects meanwhile, is
    dropped before it runs (the engine skips a cancelled call)."""
    import asyncio
    import threading
    import time

    from service.disconnect import ClientGone, unless_disconnected

    kb = client.app.state.services.kb  # type: ignore[attr-defined]
    slow = "reachable(A, B, P, M), reachable(C, D, Q, N), reachable(E, F, R, O), fail"
    busy = threading.Thread(target=lambda: kb.submit("query", world="demo", goal=slow,
                                                     max_solutions=1).result())
    busy.start()
    time.sleep(0.2)
    queued: list[Any] = []

    class Gone:
        async def is_disconnected(self) -> bool:
            return True

    async def ask() -> None:
        fut = kb.submit("query", world="demo", goal="landmark(L)", max_solutions=1)
        queued.append(fut)
        await unless_disconnected(Gone(), asyncio.wrap_future(fut), poll_s=0.01)

    try:
        asyncio.run(ask())
    except ClientGone:
        pass
    else:
        raise AssertionError("the departed client's query was answered")
    busy.join()
    assert queued[0].cancelled()  # dropped, never run


def test_stored_state_from_earlier_versions_still_loads(tmp_path: Path) -> None:
    """A snapshot in the first format (a bare list) or unreadable, and an analysis whose
    config a later bound refuses, do not stop a world from loading."""
    from numeric.eigenspace.analysis import stored_config
    from service.store import Store

    store = Store(tmp_path / "s.sqlite3")
    with store.transaction() as conn:
        store.insert_world(conn, "w", {"name": "w"})
        conn.execute("INSERT INTO snapshots VALUES ('w', 3, ?, 0)", ('["rec(a, b)"]',))
    assert store.snapshot("w") == (3, "", ["rec(a, b)"])  # rules unknown: replayed
    with store.transaction() as conn:
        conn.execute("UPDATE snapshots SET facts = 'not json'")
    assert store.snapshot("w") == (3, "", [])
    store.close()
    cfg = stored_config({"strategy": {"alphas_rad": [90.0]}, "seed": 4})
    assert cfg.seed == 4 and len(cfg.strategy.alphas_rad) == 8  # the defaults


def test_a_running_query_whose_client_left_is_stopped(client: TestClient) -> None:
    """A client goal already running when its client leaves stops at its next check
    (every 0.1 s) instead of holding the one engine to its time limit (2 s)."""
    import asyncio
    import time

    kb = client.app.state.services.kb  # type: ignore[attr-defined]
    slow = "reachable(A, B, P, M), reachable(C, D, Q, N), reachable(E, F, R, O), fail"

    async def leave_early() -> float:
        task = asyncio.ensure_future(kb.acall("query", world="demo", goal=slow,
                                              max_solutions=1))
        await asyncio.sleep(0.3)  # running on the engine
        t0 = time.perf_counter()
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        await kb.acall("worlds")  # waits for the engine to be free
        return time.perf_counter() - t0

    freed_after = asyncio.run(leave_early())
    assert freed_after < 1.0, freed_after  # not the 1.7 s left of its limit
    # and a goal nobody cancels still runs to its limit
    try:
        kb.call("query", world="demo", goal=slow, max_solutions=1)
    except KbError as e:
        assert e.type == "limit", e
