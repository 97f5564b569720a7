"""Start-up time against stored writes: a world with N observation events, restored
from its snapshot (the event-made facts every SNAPSHOT_EVERY events, then the events
after it) and, in the same run, by replaying every event (the snapshot deleted).

    .venv/bin/python tests/bench/restart.py [--writes 1000,10000,100000]

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
    from numeric.observation import Observation
    from numeric.world import WorldDescription
    from tests.conftest import FIG1, observation

    await sv.worlds.create(WorldDescription.model_validate(
        {"name": "fig", "landmarks": [{"id": k, "x": v[0], "y": v[1]}
                                      for k, v in FIG1.items()]}))
    for i in range(n):
        at, seen = (("b", ["a", "c"]), ("d", ["a", "c"]))[i % 2]
        await sv.worlds.observe("fig", Observation.model_validate(
            observation(at, seen, heading=0.001 * i)))


def start_up(settings) -> float:  # type: ignore[no-untyped-def]
    """Seconds to open (restore) every service once, best of three."""
    from service.container import open_services

    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        open_services(settings).close()
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> None:
    from service.container import open_services
    from service.settings import Settings
    from tests.bench.results import mode, write_page

    ap = argparse.ArgumentParser()
    ap.add_argument("--writes", default="1000,10000,100000")
    args = ap.parse_args()
    lines = ["| writes | start-up, snapshot + tail (s) | start-up, full replay (s) | ratio |",
             "|---|---|---|---|"]
    for n in (int(w) for w in args.writes.split(",")):
        with tempfile.TemporaryDirectory() as d:
            settings = Settings(data_dir=Path(d), demo_world="")
            sv = open_services(settings)
            asyncio.run(fill(sv, n))
            sv.close()
            snap = start_up(settings)
            db = sqlite3.connect(settings.db_path)
            db.execute("DELETE FROM snapshots")
            db.commit()
            db.close()
            full = start_up(settings)
        lines.append(f"| {n} | {snap:.3f} | {full:.3f} | {full / snap:.1f}x |")
        print(lines[-1], flush=True)
    write_page("restart", "Start-up time against stored writes (one world, observation "
               "events)", lines, mode(ap, args))


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    main()
