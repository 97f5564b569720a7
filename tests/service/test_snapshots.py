"""A world's stored state: start-up loads a snapshot and replays only the events after it,
a snapshot is read as data (ground qualitative facts only), and state stored in an
earlier format still loads."""

from __future__ import annotations

import json
from pathlib import Path

from fastapi.testclient import TestClient


def test_start_up_loads_a_snapshot_instead_of_replaying(tmp_path: Path) -> None:
    """Every SNAPSHOT_EVERY events a world's event-made facts are stored; a restart
    loads them and replays only the events after. The relations are the same as
    before the restart and as a full replay from the events alone."""
    import sqlite3

    from chizu.service.app import create_app
    from chizu.service.settings import Settings
    from chizu.service.worlds import SNAPSHOT_EVERY
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
        assert c.post("/worlds/snap/failed", json={"from": "a", "to": "c"}).status_code == 201
        before = {k: c.get("/worlds/snap/relations", params={"kind": k}).json() for k in kinds}
        before["drm"] = c.get("/worlds/snap/drm").json()
        assert any(e["failed"] for e in before["drm"]["edges"])
    db = sqlite3.connect(settings.db_path)
    (snapped,) = db.execute("SELECT event_id FROM snapshots WHERE world = 'snap'").fetchone()
    (last,) = db.execute("SELECT max(id) FROM events WHERE world = 'snap'").fetchone()
    assert 0 < snapped < last  # a snapshot, and events after it to replay
    with TestClient(create_app(settings)) as c:
        after = {k: c.get("/worlds/snap/relations", params={"kind": k}).json() for k in kinds}
        after["drm"] = c.get("/worlds/snap/drm").json()
    assert after == before
    (blob,) = db.execute("SELECT facts FROM snapshots WHERE world = 'snap'").fetchone()
    for tampered in ({**json.loads(blob), "rules": "other rules"},  # made by other rules
                     {**json.loads(blob), "facts": ["halt"]}):  # refused by load_snapshot
        db.execute("UPDATE snapshots SET facts = ?", (json.dumps(tampered),))
        db.commit()
        with TestClient(create_app(settings)) as c:  # the events alone give the same
            replayed = {k: c.get("/worlds/snap/relations", params={"kind": k}).json()
                        for k in kinds}
            replayed["drm"] = c.get("/worlds/snap/drm").json()
        assert replayed == before
        assert db.execute("SELECT count(*) FROM snapshots").fetchone() == (0,)  # dropped
        db.execute("INSERT INTO snapshots SELECT 'snap', ?, ?, 0", (snapped, blob))
        db.commit()
    db.close()


def test_a_snapshot_is_read_as_data(client: TestClient) -> None:
    """load_snapshot asserts only ground qualitative facts: a goal, a variable or a
    fact of another kind is refused naming it."""
    kb = client.app.state.services.kb  # type: ignore[attr-defined]
    from chizu.service.kb import KbError

    for bad in ("halt", "lr(a, X, c)", "landmark(z)", "lr(a, b", "map_pose(r1, 0, 0, 0, 0)"):
        try:
            kb.call("load_snapshot", world="demo", facts=["rec(c0, c1)", bad])
        except KbError as e:
            assert e.field == "facts[1]", e
        else:
            raise AssertionError(f"{bad!r} was loaded")


def test_stored_state_from_earlier_versions_still_loads(tmp_path: Path) -> None:
    """A snapshot in the first format (a bare list) or unreadable, and an analysis whose
    config a later bound refuses, do not stop a world from loading."""
    from chizu.numeric.eigenspace.analysis import stored_config
    from chizu.service.store import Store

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
