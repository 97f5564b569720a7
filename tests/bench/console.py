"""The console with large data: how long the map view takes to be drawn in Debian's
chromium (Playwright), from navigation until every layer is drawn, for the demo world
(22 landmarks), an office of 202 landmarks surveyed once (its DRM drawn too) and a world
whose committed map is a 4000 x 4000 grid (drawn from a downsampled image, at most
2048 px a side, walls kept).

    .venv/bin/python tests/bench/console.py [--loads 5]

Writes docs/results/console.md: per world the first load after the server started (nothing
cached in the server or the browser), the median and slowest of ``--loads`` fresh page
loads, and each median against the demo world's in the same run. The target: 1 s.
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from chizu.numeric.occupancy import FREE, OCCUPIED, UNKNOWN, OccupancyMap  # noqa: E402
from chizu.numeric.qualitative.survey import survey  # noqa: E402
from chizu.numeric.simulator import ObserverConfig  # noqa: E402
from chizu.numeric.world import WorldDescription  # noqa: E402
from chizu.numeric.worlds import office_world  # noqa: E402
from chizu.service.container import open_services  # noqa: E402
from chizu.service.settings import Settings  # noqa: E402
from tests.bench.results import mode, write_page  # noqa: E402
from tests.conftest import LiveServer  # noqa: E402
from tests.console.test_console import ARGS, CHROMIUM  # noqa: E402

GRID = 4000


def big_grid() -> OccupancyMap:
    """A 200 m x 200 m floor at 0.05 m: rooms of 10 m walled by one-cell walls."""
    state = np.full((GRID, GRID), FREE, dtype=np.int8)
    state[::200, :] = OCCUPIED
    state[:, ::200] = OCCUPIED
    state[:50, :50] = UNKNOWN
    return OccupancyMap(np.array([0.0, 0.0]), 0.05, state, np.full(state.shape, np.nan))


def prepare(data: Path) -> None:
    """The three worlds, written to the store before the server starts."""
    sv = open_services(Settings(data_dir=data, demo_world="demo", workers=0))

    async def build() -> None:
        desc = office_world(name="office202", rooms_per_side=40)
        await sv.worlds.create(desc)
        cfg = ObserverConfig(bearing_noise_rad=0.01, distance_noise_m=0.02)
        for obs in survey(sv.worlds.model("office202"), cfg, seed=0):
            await sv.worlds.observe("office202", obs)
        await sv.worlds.create(WorldDescription(name="bigmap"))
        await sv.slam._commit_map("bigmap", "r" + "0" * 16, big_grid(), np.zeros((1, 3)), [],
                                  b"")

    try:
        asyncio.run(build())
    finally:
        sv.close()


def load_time(browser: object, url: str, world: str) -> tuple[float, int, int]:
    """Seconds from navigation until the console is drawn; landmarks and grid images."""
    page = browser.new_page(viewport={"width": 1280, "height": 800})  # type: ignore[attr-defined]
    t0 = time.perf_counter()
    page.goto(f"{url}/#/map/{world}")
    page.wait_for_selector("body[data-ready=true]", timeout=60_000)
    dt = time.perf_counter() - t0
    n = page.locator("#layer-landmarks .landmark").count()
    images = page.locator("#layer-grid image").count()
    page.close()
    return dt, n, images


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--loads", type=int, default=5)
    args = ap.parse_args()
    from playwright.sync_api import sync_playwright

    rows = []
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        prepare(Path(d))
        print(f"worlds prepared in {time.perf_counter() - t0:.0f} s", flush=True)
        srv = LiveServer(Path(d), demo=True)
        try:
            with sync_playwright() as p:
                b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
                times: dict[str, list[float]] = {}
                seen: dict[str, tuple[int, int]] = {}
                for _ in range(args.loads):  # the worlds in turn, each load a fresh page
                    for world in ("demo", "office202", "bigmap"):
                        dt, n, images = load_time(b, srv.url, world)
                        times.setdefault(world, []).append(dt)
                        seen[world] = (n, images)
                b.close()
        finally:
            srv.stop()
    base = statistics.median(times["demo"])
    what = {"demo": "demo: 22 landmarks, its DRM",
            "office202": "office: 202 landmarks, 242 walls, its DRM",
            "bigmap": f"a {GRID} x {GRID} committed grid"}
    lines = [f"A fresh page per load at 1280 x 800, {args.loads} loads per world (the worlds "
             "in turn); from navigation until every layer is drawn (the grid image "
             "decoded).", "",
             "| world | landmarks drawn | grid images | first load (s) | median (s) | "
             "slowest (s) | median vs demo |", "|---|---|---|---|---|---|---|"]
    for world, ts in times.items():
        n, images = seen[world]
        lines.append(f"| {what[world]} | {n} | {images} | {ts[0]:.3f} | "
                     f"{statistics.median(ts):.3f} | {max(ts):.3f} | "
                     f"{statistics.median(ts) / base:.2f}x |")
        print(lines[-1], flush=True)
    rows.append(lines)
    write_page("console", "The console with large data", lines, mode(ap, args))


if __name__ == "__main__":
    main()
