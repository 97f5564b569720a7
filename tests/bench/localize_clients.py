"""Localization throughput against concurrent clients, on a live `chizu serve`: room A
learned at the paper's size, one full turn of 72 PNG images per request (rendered once
by the service's camera), 1, 2 and 8 clients sending the same number of requests.

    .venv/bin/python tests/bench/localize_clients.py [--requests 200] [--out bench-out]

Writes OUT/localize_clients.md: requests per second and p50 / p95 latency, and the
speed-up over one client (the machine's cores bound it: 2 here).
"""

from __future__ import annotations

import argparse
import concurrent.futures
import statistics
import sys
import tempfile
import time
from pathlib import Path

import httpx


def run(url: str, body: dict[str, object], clients: int, n: int) -> tuple[float, list[float]]:
    """(requests per second, latencies) of ``n`` requests from ``clients`` threads."""
    lat: list[float] = []

    def one(_: int) -> None:
        with httpx.Client(base_url=url, timeout=120) as c:
            for _ in range(n // clients):
                t0 = time.perf_counter()
                r = c.post("/worlds/bench/localize", json=body)
                lat.append(time.perf_counter() - t0)
                r.raise_for_status()

    t0 = time.perf_counter()
    with concurrent.futures.ThreadPoolExecutor(clients) as pool:
        list(pool.map(one, range(clients)))
    return len(lat) / (time.perf_counter() - t0), lat


def main() -> None:
    from tests.conftest import LiveServer

    ap = argparse.ArgumentParser()
    ap.add_argument("--requests", type=int, default=200)
    ap.add_argument("--out", default="bench-out")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory() as d:
        srv = LiveServer(Path(d) / "data")
        try:
            with httpx.Client(base_url=srv.url, timeout=600) as c:
                c.post("/worlds", json={"name": "bench", "template": "room_a"}).raise_for_status()
                job = c.post("/worlds/bench/eigenspace", json={"learning_strategy": None})
                job.raise_for_status()
                loc = job.headers["location"]
                while (status := c.get(loc).json()["status"]) in ("queued", "running"):
                    time.sleep(0.5)
                if status != "done":
                    raise SystemExit(f"learning ended {status}: {c.get(loc).json()}")
                turn = c.post("/worlds/bench/camera", json={"pose": {"x": 3.0, "y": 5.0},
                                                            "turn": 72}).json()
            body = {"images_png": turn["images_png"]}
            run(srv.url, body, 1, 10)  # warm up
            lines = ["# Localization throughput against concurrent clients (live server, "
                     "room A, 72-image PNG turns)", "",
                     "| clients | requests/s | p50 (ms) | p95 (ms) | vs 1 client |",
                     "|---|---|---|---|---|"]
            base = 0.0
            for clients in (1, 2, 8):
                rps, lat = run(srv.url, body, clients, args.requests)
                base = base or rps
                q = statistics.quantiles(lat, n=20)
                lines.append(f"| {clients} | {rps:.1f} | {1e3 * statistics.median(lat):.1f} | "
                             f"{1e3 * q[18]:.1f} | {rps / base:.2f}x |")
                print(lines[-1], flush=True)
        finally:
            srv.stop()
    (out / "localize_clients.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    main()
