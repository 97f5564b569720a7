"""Persistent store: SQLite in WAL mode under ``CHIZU_DATA_DIR``.

Holds what clients created: worlds (their JSON description) and, per world,
an append-only event log (observations, reached landmarks).  The knowledge
base is rebuilt from it at start-up by replaying the events in order, so a
restart gives back exactly the facts the client created.  Each write is one
SQLite transaction; :meth:`Store.transaction` lets the caller apply the same
change to the knowledge base inside it and roll back if that fails.
"""

from __future__ import annotations

import json
import sqlite3
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

SCHEMA = """
CREATE TABLE IF NOT EXISTS worlds (
    name        TEXT PRIMARY KEY,
    description TEXT NOT NULL,
    created_at  REAL NOT NULL,
    version     INTEGER NOT NULL DEFAULT 0
);
CREATE TABLE IF NOT EXISTS events (
    id          INTEGER PRIMARY KEY AUTOINCREMENT,
    world       TEXT NOT NULL REFERENCES worlds(name) ON DELETE CASCADE,
    kind        TEXT NOT NULL,
    payload     TEXT NOT NULL,
    created_at  REAL NOT NULL
);
CREATE INDEX IF NOT EXISTS events_world ON events(world, id);
CREATE TABLE IF NOT EXISTS artifacts (
    world       TEXT NOT NULL REFERENCES worlds(name) ON DELETE CASCADE,
    kind        TEXT NOT NULL,
    blob        BLOB NOT NULL,
    created_at  REAL NOT NULL,
    PRIMARY KEY (world, kind)
);
CREATE TABLE IF NOT EXISTS slam_runs (
    id          TEXT PRIMARY KEY,
    world       TEXT NOT NULL REFERENCES worlds(name) ON DELETE CASCADE,
    options     TEXT NOT NULL,
    created_at  REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS slam_scans (
    run         TEXT NOT NULL REFERENCES slam_runs(id) ON DELETE CASCADE,
    seq         INTEGER NOT NULL,
    scan        TEXT NOT NULL,
    PRIMARY KEY (run, seq)
);
CREATE TABLE IF NOT EXISTS localization_runs (
    id          TEXT PRIMARY KEY,
    world       TEXT NOT NULL REFERENCES worlds(name) ON DELETE CASCADE,
    options     TEXT NOT NULL,
    created_at  REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS localization_scans (
    run         TEXT NOT NULL REFERENCES localization_runs(id) ON DELETE CASCADE,
    seq         INTEGER NOT NULL,
    scan        TEXT NOT NULL,
    PRIMARY KEY (run, seq)
);
CREATE TABLE IF NOT EXISTS snapshots (
    world       TEXT PRIMARY KEY REFERENCES worlds(name) ON DELETE CASCADE,
    event_id    INTEGER NOT NULL,
    facts       TEXT NOT NULL,
    created_at  REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS jobs (
    id          TEXT PRIMARY KEY,
    world       TEXT NOT NULL REFERENCES worlds(name) ON DELETE CASCADE,
    kind        TEXT NOT NULL,
    status      TEXT NOT NULL,
    stage       TEXT NOT NULL,
    progress    REAL NOT NULL,
    result      TEXT,
    error       TEXT,
    created_at  REAL NOT NULL,
    updated_at  REAL NOT NULL,
    request     BLOB,
    attempts    INTEGER NOT NULL DEFAULT 0
);
CREATE INDEX IF NOT EXISTS jobs_world ON jobs(world, created_at);
CREATE TABLE IF NOT EXISTS sessions (
    id          TEXT PRIMARY KEY,
    world       TEXT NOT NULL REFERENCES worlds(name) ON DELETE CASCADE,
    data        TEXT NOT NULL,
    created_at  REAL NOT NULL
);
"""


#: a world's version counts the writes to what its knowledge base is made of (its events
#: and artifacts), by whichever process makes them: a service and the CLI on one data
#: directory see each other's writes by it (the world service reloads a world whose
#: version moved)
VERSION_TRIGGERS = "".join(f"""
CREATE TRIGGER IF NOT EXISTS {table}_{op.lower()}_version AFTER {op} ON {table} BEGIN
    UPDATE worlds SET version = version + 1 WHERE name = {row}.world;
END;""" for table in ("events", "artifacts") for op, row in (("INSERT", "NEW"),
                                                           ("UPDATE", "NEW"),
                                                           ("DELETE", "OLD")))

#: the runs that stream scans, each with its two tables (``{kind}_runs``, ``{kind}_scans``);
#: only these literals are ever put into the SQL
RunKind = Literal["slam", "localization"]


@dataclass(frozen=True)
class WorldRow:
    name: str
    description: dict[str, Any]
    created_at: float


@dataclass(frozen=True)
class Event:
    id: int
    world: str
    kind: str
    payload: dict[str, Any]


class Store:
    """A small thread-safe wrapper around one SQLite connection."""

    def __init__(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self._conn = sqlite3.connect(path, check_same_thread=False, isolation_level=None)
        self._lock = threading.RLock()
        with self._lock:
            self._conn.execute("PRAGMA journal_mode=WAL")
            self._conn.execute("PRAGMA foreign_keys=ON")
            self._conn.execute("PRAGMA synchronous=NORMAL")
            self._add_columns()
            self._conn.executescript(SCHEMA)
            self._conn.executescript(VERSION_TRIGGERS)

    def _add_columns(self) -> None:
        """A store made before a column was added gets it (with its default)."""
        for table, column, decl in (("worlds", "version", "INTEGER NOT NULL DEFAULT 0"),
                                    ("jobs", "request", "BLOB"),
                                    ("jobs", "attempts", "INTEGER NOT NULL DEFAULT 0")):
            have = {r[1] for r in self._conn.execute(f"PRAGMA table_info({table})")}
            if have and column not in have:
                self._conn.execute(f"ALTER TABLE {table} ADD COLUMN {column} {decl}")

    @contextmanager
    def transaction(self) -> Iterator[sqlite3.Connection]:
        """BEGIN IMMEDIATE ... COMMIT, rolled back if the block raises."""
        with self._lock:
            self._conn.execute("BEGIN IMMEDIATE")
            try:
                yield self._conn
            except BaseException:
                self._conn.execute("ROLLBACK")
                raise
            self._conn.execute("COMMIT")

    def world(self, name: str) -> WorldRow | None:
        with self._lock:
            row = self._conn.execute(
                "SELECT name, description, created_at FROM worlds WHERE name = ?", (name,)
            ).fetchone()
        return None if row is None else WorldRow(row[0], json.loads(row[1]), row[2])

    def world_version(self, name: str) -> tuple[float, int] | None:
        """What identifies the world's stored content now: its creation time (a world
        deleted and made again is another) and its version; None if there is none."""
        with self._lock:
            row = self._conn.execute(
                "SELECT created_at, version FROM worlds WHERE name = ?", (name,)).fetchone()
        return None if row is None else (row[0], row[1])

    def world_count(self) -> int:
        with self._lock:
            return int(self._conn.execute("SELECT count(*) FROM worlds").fetchone()[0])

    def world_names(self) -> list[str]:
        with self._lock:
            rows = self._conn.execute(
                "SELECT name FROM worlds ORDER BY created_at, name").fetchall()
        return [r[0] for r in rows]

    def worlds(self) -> list[WorldRow]:
        with self._lock:
            rows = self._conn.execute(
                "SELECT name, description, created_at FROM worlds ORDER BY created_at, name"
            ).fetchall()
        return [WorldRow(r[0], json.loads(r[1]), r[2]) for r in rows]

    @staticmethod
    def insert_world(conn: sqlite3.Connection, name: str, description: dict[str, Any]) -> None:
        conn.execute("INSERT INTO worlds (name, description, created_at) VALUES (?, ?, ?)",
                     (name, json.dumps(description, allow_nan=False), time.time()))

    @staticmethod
    def delete_world(conn: sqlite3.Connection, name: str) -> None:
        conn.execute("DELETE FROM worlds WHERE name = ?", (name,))

    @staticmethod
    def append_event(conn: sqlite3.Connection, world: str, kind: str,
                     payload: dict[str, Any]) -> int:
        """Append one event; returns its id."""
        cur = conn.execute("INSERT INTO events (world, kind, payload, created_at) "
                           "VALUES (?, ?, ?, ?)",
                           (world, kind, json.dumps(payload, allow_nan=False), time.time()))
        return int(cur.lastrowid or 0)

    def events(self, world: str, after: int = 0) -> list[Event]:
        """The world's events in order, those with an id above ``after`` only."""
        with self._lock:
            rows = self._conn.execute(
                "SELECT id, world, kind, payload FROM events WHERE world = ? AND id > ? "
                "ORDER BY id", (world, after),
            ).fetchall()
        return [Event(r[0], r[1], r[2], json.loads(r[3])) for r in rows]

    # -- snapshots: a world's event-made facts, so start-up replays only what follows ----
    @staticmethod
    def put_snapshot(conn: sqlite3.Connection, world: str, event_id: int, rules: str,
                     facts: list[str]) -> None:
        """The facts as of event ``event_id``, made by the rules whose digest is ``rules``."""
        conn.execute("INSERT OR REPLACE INTO snapshots (world, event_id, facts, created_at) "
                     "VALUES (?, ?, ?, ?)",
                     (world, event_id, json.dumps({"rules": rules, "facts": facts}),
                      time.time()))

    def snapshot(self, world: str) -> tuple[int, str, list[str]] | None:
        """(event id, rules digest, facts) of the world's snapshot, or None."""
        with self._lock:
            row = self._conn.execute("SELECT event_id, facts FROM snapshots WHERE world = ?",
                                     (world,)).fetchone()
        if row is None:
            return None
        try:
            data = json.loads(row[1])
        except ValueError:
            data = {}
        if isinstance(data, list):  # the first format: facts alone, rules unknown
            data = {"facts": data}
        if not isinstance(data, dict):
            data = {}
        return int(row[0]), str(data.get("rules", "")), list(data.get("facts", []))

    @staticmethod
    def delete_snapshot(conn: sqlite3.Connection, world: str) -> None:
        conn.execute("DELETE FROM snapshots WHERE world = ?", (world,))

    def event_count(self, world: str) -> int:
        with self._lock:
            row = self._conn.execute("SELECT COUNT(*) FROM events WHERE world = ?",
                                     (world,)).fetchone()
        return int(row[0])

    # -- learned artifacts (e.g. an eigenspace analysis) and localization sessions ---------
    @staticmethod
    def put_artifact(conn: sqlite3.Connection, world: str, kind: str, blob: bytes) -> None:
        conn.execute("INSERT OR REPLACE INTO artifacts (world, kind, blob, created_at) "
                     "VALUES (?, ?, ?, ?)", (world, kind, blob, time.time()))

    def has_artifact(self, world: str, kind: str) -> bool:
        """Whether ``world`` has an artifact of ``kind`` (its blob is not read)."""
        with self._lock:
            row = self._conn.execute("SELECT 1 FROM artifacts WHERE world = ? AND kind = ?",
                                     (world, kind)).fetchone()
        return row is not None

    def artifact_kinds(self, world: str) -> list[str]:
        """The kinds of artifact ``world`` holds, sorted (no blob is read)."""
        with self._lock:
            rows = self._conn.execute("SELECT kind FROM artifacts WHERE world = ? "
                                      "ORDER BY kind", (world,)).fetchall()
        return [r[0] for r in rows]

    def artifact(self, world: str, kind: str) -> bytes | None:
        with self._lock:
            row = self._conn.execute("SELECT blob FROM artifacts WHERE world = ? AND kind = ?",
                                     (world, kind)).fetchone()
        return None if row is None else bytes(row[0])

    @staticmethod
    def put_session(conn: sqlite3.Connection, sid: str, world: str,
                    data: dict[str, Any]) -> None:
        conn.execute("INSERT INTO sessions (id, world, data, created_at) VALUES (?, ?, ?, ?) "
                     "ON CONFLICT(id) DO UPDATE SET data = excluded.data",
                     (sid, world, json.dumps(data, allow_nan=False), time.time()))

    def session(self, sid: str) -> tuple[str, dict[str, Any]] | None:
        with self._lock:
            row = self._conn.execute("SELECT world, data FROM sessions WHERE id = ?",
                                     (sid,)).fetchone()
        return None if row is None else (row[0], json.loads(row[1]))

    # -- runs that stream scans: SLAM runs, localization runs ---------------------------
    @staticmethod
    def put_run(conn: sqlite3.Connection, kind: RunKind, rid: str, world: str,
                options: dict[str, Any]) -> None:
        conn.execute(f"INSERT INTO {kind}_runs (id, world, options, created_at) "  # noqa: S608
                     "VALUES (?, ?, ?, ?)",
                     (rid, world, json.dumps(options, allow_nan=False), time.time()))

    @staticmethod
    def delete_run(conn: sqlite3.Connection, kind: RunKind, rid: str) -> None:
        conn.execute(f"DELETE FROM {kind}_scans WHERE run = ?", (rid,))  # noqa: S608
        conn.execute(f"DELETE FROM {kind}_runs WHERE id = ?", (rid,))  # noqa: S608

    @staticmethod
    def append_scans(conn: sqlite3.Connection, kind: RunKind, rid: str, first_seq: int,
                     scans: list[dict[str, Any]]) -> None:
        conn.executemany(f"INSERT INTO {kind}_scans (run, seq, scan) VALUES (?, ?, ?)",  # noqa: S608
                         [(rid, first_seq + i, json.dumps(s, allow_nan=False))
                          for i, s in enumerate(scans)])

    @staticmethod
    def drop_scans_from(conn: sqlite3.Connection, kind: RunKind, rid: str,
                        first_seq: int) -> None:
        """Forget run ``rid``'s scans from ``first_seq`` on (a batch stopped midway)."""
        conn.execute(f"DELETE FROM {kind}_scans WHERE run = ? AND seq >= ?",  # noqa: S608
                     (rid, first_seq))

    def runs(self, kind: RunKind) -> list[tuple[str, str, dict[str, Any]]]:
        with self._lock:
            rows = self._conn.execute(f"SELECT id, world, options FROM {kind}_runs "  # noqa: S608
                                      "ORDER BY created_at").fetchall()
        return [(r[0], r[1], json.loads(r[2])) for r in rows]

    def scans(self, kind: RunKind, rid: str) -> list[dict[str, Any]]:
        with self._lock:
            rows = self._conn.execute(f"SELECT scan FROM {kind}_scans WHERE run = ? "  # noqa: S608
                                      "ORDER BY seq", (rid,)).fetchall()
        return [json.loads(r[0]) for r in rows]

    # -- jobs ------------------------------------------------------------------------------
    _JOB_COLUMNS = ("id, world, kind, status, stage, progress, result, error, created_at, "
                    "updated_at, attempts")

    def insert_job(self, jid: str, world: str, kind: str, request: bytes | None = None) -> None:
        """A queued job; ``request`` is what re-runs it after a restart (None: it cannot
        be re-run)."""
        now = time.time()
        with self.transaction() as conn:
            conn.execute("INSERT INTO jobs (id, world, kind, status, stage, progress, "
                         "created_at, updated_at, request) "
                         "VALUES (?, ?, ?, 'queued', 'queued', 0, ?, ?, ?)",
                         (jid, world, kind, now, now, request))

    def unfinished_jobs(self) -> list[tuple[str, str, str, bytes | None, int]]:
        """Jobs queued or running: (id, world, kind, request, attempts), oldest first."""
        with self._lock:
            rows = self._conn.execute(
                "SELECT id, world, kind, request, attempts FROM jobs WHERE status IN "
                "('queued', 'running') ORDER BY created_at, id").fetchall()
        return [(r[0], r[1], r[2], r[3], int(r[4])) for r in rows]

    def update_job(self, jid: str, unfinished_only: bool = False, **fields: Any) -> None:
        """Set some of status, stage, progress, result, error (dicts stored as JSON);
        ``unfinished_only``: only while the job is queued or running (progress reports,
        which must not touch a job that has ended)."""
        cols = [k for k in ("status", "stage", "progress", "result", "error", "attempts")
                if k in fields]
        vals = [json.dumps(fields[k], allow_nan=False) if k in ("result", "error") and
                fields[k] is not None else fields[k] for k in cols]
        guard = " AND status IN ('queued', 'running')" if unfinished_only else ""
        with self.transaction() as conn:
            conn.execute(f"UPDATE jobs SET {', '.join(c + ' = ?' for c in cols)}, "  # noqa: S608
                         f"updated_at = ? WHERE id = ?{guard}", (*vals, time.time(), jid))

    def jobs(self, jid: str | None = None, world: str | None = None,
             status: str | None = None) -> list[dict[str, Any]]:
        where, args = [], []
        for col, v in (("id", jid), ("world", world), ("status", status)):
            if v is not None:
                where.append(f"{col} = ?")
                args.append(v)
        sql = f"SELECT {self._JOB_COLUMNS} FROM jobs"  # noqa: S608 - column names are ours
        if where:
            sql += " WHERE " + " AND ".join(where)
        with self._lock:
            rows = self._conn.execute(sql + " ORDER BY created_at, id", args).fetchall()
        keys = self._JOB_COLUMNS.split(", ")
        out = []
        for r in rows:
            d = dict(zip(keys, r, strict=True))
            for k in ("result", "error"):
                d[k] = None if d[k] is None else json.loads(d[k])
            out.append(d)
        return out

    def close(self) -> None:
        with self._lock:
            self._conn.close()
