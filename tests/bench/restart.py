"""Start-up time against what is stored.

- Stored worlds: the service opened (store, Prolog engine, rules; worlds load when first
  asked for) on a data directory of N worlds, against the empty one in the same run,
  and `chizu serve` from its start to its first /health answer; then the first request
  to one world (its load) and the next.
- Stored writes: a world with N observation events, loaded from its snapshot (the
  event-made facts every SNAPSHOT_EVERY events, then the events after it) and, in the
  same run, by replaying every event (the snapshot deleted).

    .venv/bin/python tests/bench/restart.py [--worlds 0,243,2318,10000]
                                            [--writes 1000,10000,100000]

Writes docs/results/restart.md.
"""

from __future__ import annotations

import argparse
import asyncio
import sqlite3
import sys
import tempfile
import time
from pathlib import Path


async def fill(sv, n: int) -> None:  # type: ignore[no-untyped-def]
    """World "fig" (the paper's Fig. 1) and ``n`` observation events."""
    from chizu.numeric.observation import Observation
    from chizu.numeric.world import WorldDescription
    from tests.conftest import FIG1, observation

    await sv.worlds.create(WorldDescription.model_validate(
        {"name": "fig", "landmarks": [{"id": k, "x": v[0], "y": v[1]}
                                      for k, v in FIG1.items()]}))
    for i in range(n):
        at, seen = (("b", ["a", "c"]), ("d", ["a", "c"]))[i % 2]
        await sv.worlds.observe("fig", Observation.model_validate(
            observation(at, seen, heading=0.001 * i)))


def start_up(settings, world: str | None = None) -> float:  # type: ignore[no-untyped-def]
    """Seconds to open the services and, with ``world``, load that world (its first
    request), best of three."""
    from chizu.service.container import open_services

    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        sv = open_services(settings)
        if world is not None:
            asyncio.run(sv.worlds.ready(world))
        best = min(best, time.perf_counter() - t0)
        sv.close()
    return best


def serve_to_health(data_dir: Path) -> float:
    """Seconds from starting `chizu serve` to its first /health answer (best of two)."""

    from tests.conftest import LiveServer

    best = float("inf")
    for _ in range(2):
        t0 = time.perf_counter()
        server = LiveServer(data_dir)
        best = min(best, time.perf_counter() - t0)
        server.stop()
    return best


def first_requests(data_dir: Path, world: str) -> tuple[float, float]:
    """Seconds of the first query to ``world`` in a fresh service (it loads the world)
    and of the next one, both over a connection already open (a /health first, which
    loads no world)."""
    from chizu.service.client import Client
    from tests.conftest import LiveServer

    server = LiveServer(data_dir)
    try:
        times = []
        with Client(server.url, timeout_s=60) as c:
            c.health.health()
            for _ in range(2):
                t0 = time.perf_counter()
                c.qualitative.post_query(world, {"goal": "landmark(L)"})
                times.append(time.perf_counter() - t0)
        return times[0], times[1]
    finally:
        server.stop()


def stored_worlds(counts: list[int]) -> list[str]:
    """The start-up table against the number of stored worlds (each the demo template
    with three observations)."""
    from chizu.numeric.observation import Observation
    from chizu.numeric.world import WorldDescription
    from chizu.service.container import open_services
    from chizu.service.settings import Settings

    lines = ["| stored worlds | open the services (s) | x the empty store | "
             "`chizu serve` to /health (s) | first query to a world (s) | next query (s) |",
             "|---|---|---|---|---|---|"]
    seen = [{"landmark": "c0", "bearing_rad": 0.2, "distance_m": 2.0},
            {"landmark": "c1", "bearing_rad": 1.1, "distance_m": 3.5}]

    async def fill(sv, start: int, stop: int) -> None:  # type: ignore[no-untyped-def]
        for i in range(start, stop):
            name = f"w{i}"
            await sv.worlds.create(WorldDescription(name=name, template="demo"))
            for k in range(3):
                await sv.worlds.observe(name, Observation.model_validate(
                    {"at": "rn0a", "seen": [{**x, "bearing_rad": x["bearing_rad"] + 0.01 * k}
                                            for x in seen]}))

    with tempfile.TemporaryDirectory() as d:
        settings = Settings(data_dir=Path(d), demo_world="")
        have, base = 0, None
        for n in sorted(counts):
            sv = open_services(settings)
            asyncio.run(fill(sv, have, n))
            sv.close()
            have = n
            opened = start_up(settings)
            base = opened if base is None else base
            health = serve_to_health(Path(d))
            first, second = first_requests(Path(d), f"w{n - 1}") if n else (float("nan"),) * 2
            lines.append(f"| {n} | {opened:.3f} | {opened / base:.2f} | {health:.2f} | "
                         f"{first:.3f} | {second:.3f} |")
            print(lines[-1], flush=True)
    return lines


def main() -> None:
    from chizu.service.container import open_services
    from chizu.service.settings import Settings
    from tests.bench.results import mode, write_page

    ap = argparse.ArgumentParser()
    ap.add_argument("--worlds", default="0,243,2318,10000")
    ap.add_argument("--writes", default="1000,10000,100000")
    args = ap.parse_args()
    lines = ["## Stored worlds", "",
             *stored_worlds([int(n) for n in args.worlds.split(",")]), "",
             "## Stored writes: one world's load (open the services and its first request)",
             "", "| writes | load, snapshot + tail (s) | load, full replay (s) | ratio |",
             "|---|---|---|---|"]
    for n in (int(w) for w in args.writes.split(",")):
        with tempfile.TemporaryDirectory() as d:
            settings = Settings(data_dir=Path(d), demo_world="")
            sv = open_services(settings)
            asyncio.run(fill(sv, n))
            sv.close()
            snap = start_up(settings, "fig")
            db = sqlite3.connect(settings.db_path)
            db.execute("DELETE FROM snapshots")
            db.commit()
            db.close()
            full = start_up(settings, "fig")
        lines.append(f"| {n} | {snap:.3f} | {full:.3f} | {full / snap:.1f}x |")
        print(lines[-1], flush=True)
    write_page("restart", "Start-up time against stored worlds and writes", lines,
               mode(ap, args))


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    main()
