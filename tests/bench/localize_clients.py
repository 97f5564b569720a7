"""Localization throughput against concurrent clients, on a live `chizu serve` with 1
and with 2 compute workers (``CHIZU_WORKERS``): room A learned at the paper's size, one
full turn of 72 PNG images per request (rendered once by the service's camera), 1, 2
and 4 clients sending the same number of requests. The body is encoded once, so the
clients (on the same machine) take little CPU from the server.

    .venv/bin/python tests/bench/localize_clients.py [--requests 300]

Writes docs/results/localize_clients.md: requests per second and p50 / p95 latency per number of
workers and clients, and the speed-up of 2 workers over 1 at each number of clients
(the machine's cores bound it: 2 here, shared by the server's event loop, the
workers and the clients).
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx

from chizu.service.client import Client, ProblemError


class HealthProbe:
    """``GET /health`` every 50 ms from its own thread while a block runs: latencies."""

    def __init__(self, url: str) -> None:
        self.url, self.lat = url, []  # type: ignore[var-annotated]
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run)

    def _run(self) -> None:
        with Client(self.url, timeout_s=60) as c:
            while not self._stop.is_set():
                t0 = time.perf_counter()
                c.health.health()
                self.lat.append(time.perf_counter() - t0)
                time.sleep(0.05)

    def __enter__(self) -> HealthProbe:
        self._t.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._t.join()

    def summary(self) -> str:
        return (f"p50 {1e3 * statistics.median(self.lat):.1f} ms, max "
                f"{1e3 * max(self.lat):.1f} ms over {len(self.lat)}")


def run(url: str, body: bytes, clients: int, n: int) -> tuple[float, list[float]]:
    """(requests per second, latencies) of ``n`` requests from ``clients`` threads."""
    lat: list[float] = []
    headers = {"content-type": "application/json"}

    def one(_: int) -> None:
        # raw: the typed client would encode the turn again for every request
        with httpx.Client(base_url=url, timeout=120) as c:
            for _ in range(n // clients):
                t0 = time.perf_counter()
                r = c.post("/worlds/bench/localize", content=body, headers=headers)
                lat.append(time.perf_counter() - t0)
                r.raise_for_status()

    t0 = time.perf_counter()
    with concurrent.futures.ThreadPoolExecutor(clients) as pool:
        list(pool.map(one, range(clients)))
    return len(lat) / (time.perf_counter() - t0), lat


def cpu_s(pid: int) -> tuple[float, float]:
    """CPU seconds (user + system) of process ``pid`` and of all its descendants (the
    fork server and the compute workers), from /proc."""
    tick = os.sysconf("SC_CLK_TCK")
    stat: dict[int, tuple[int, float]] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                f = (d / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            stat[int(d.name)] = (int(f[1]), (int(f[11]) + int(f[12])) / tick)
    kids: dict[int, list[int]] = {}
    for p, (pp, _) in stat.items():
        kids.setdefault(pp, []).append(p)
    todo, desc = list(kids.get(pid, [])), 0.0
    while todo:
        p = todo.pop()
        desc += stat[p][1]
        todo += kids.get(p, [])
    return stat[pid][1], desc


Row = tuple[int, float, list[float], tuple[float, ...]]


def serve_and_measure(workers: int, n: int) -> list[Row]:
    """A fresh server with ``workers`` compute workers: (clients, req/s, latencies, CPU
    ms per request of the server process, of its workers, of the clients)."""
    from tests.conftest import LiveServer

    os.environ["CHIZU_WORKERS"] = str(workers)
    os.environ["CHIZU_REQUEST_BUDGET_S"] = "3"  # the big render below runs into it
    rows = []
    with tempfile.TemporaryDirectory() as d:
        srv = LiveServer(Path(d) / "data")
        try:
            with Client(srv.url, timeout_s=600) as c:
                c.worlds.create_world({"name": "bench", "template": "room_a"})
                c.wait_job(c.eigenspace.post_eigenspace("bench", {"learning_strategy": None}),
                           timeout_s=3600, poll_s=0.5)
                turn = c.eigenspace.post_camera("bench", {"pose": {"x": 3.0, "y": 5.0},
                                                          "turn": 72})
                strip = c.eigenspace.post_camera("bench", {
                    "pose": {"x": 3.0, "y": 5.0}, "turn": 72, "format": "turn_png"})
            body = json.dumps({"images_png": turn.images_png}).encode()
            bodies = {"images_png (72 PNGs)": body,
                      "turn_png (one PNG)": json.dumps({"turn_png": strip.turn_png}).encode()}
            run(srv.url, body, 2, 20)  # warm up (every worker caches the analysis)
            for clients in (1, 2, 4):
                c0, s0, w0 = time.process_time(), *cpu_s(srv.proc.pid)
                with HealthProbe(srv.url) as probe:
                    rps, lat = run(srv.url, body, clients, n)
                c1, s1, w1 = time.process_time(), *cpu_s(srv.proc.pid)
                HEALTH[f"{workers} worker(s), {clients} localizing client(s)"] = probe.summary()
                cpu = tuple(1e3 * v / len(lat) for v in (s1 - s0, w1 - w0, c1 - c0))
                rows.append((clients, rps, lat, cpu))
                print(f"workers {workers} clients {clients}: {rps:.1f} req/s", flush=True)
            if workers == 1:  # the same turn as 72 PNGs and as one, in turn
                run(srv.url, bodies["turn_png (one PNG)"], 1, 20)
                for clients in (1, 2):
                    for name, b in bodies.items():
                        c0, s0, w0 = time.process_time(), *cpu_s(srv.proc.pid)
                        rps, lat = run(srv.url, b, clients, n)
                        c1, s1, w1 = time.process_time(), *cpu_s(srv.proc.pid)
                        cpu = tuple(1e3 * v / len(lat) for v in (s1 - s0, w1 - w0, c1 - c0))
                        PAYLOADS.append((name, clients, rps, lat, cpu))
                        print(f"{name}, {clients} client(s): {rps:.1f} req/s", flush=True)
            if workers == 1:  # one request at its budget: a 24-image 256 x 256 render
                with HealthProbe(srv.url) as probe, Client(srv.url, timeout_s=600) as c:
                    try:
                        c.eigenspace.post_camera("bench", {
                            "pose": {"x": 3.0, "y": 5.0}, "turn": 24,
                            "camera": {"width_px": 256, "height_px": 256, "supersample": 4}})
                        status = 200
                    except ProblemError as e:  # past its budget: 503 expected
                        status = e.status
                HEALTH[f"a camera render running to its budget ({status})"] = probe.summary()
        finally:
            srv.stop()
    return rows


HEALTH: dict[str, str] = {}  # what GET /health took meanwhile
#: (payload, clients, requests/s, latencies, CPU ms per request) with one worker
PAYLOADS: list[tuple[str, int, float, list[float], tuple[float, ...]]] = []


def main() -> None:
    from tests.bench.results import mode, write_page

    ap = argparse.ArgumentParser()
    ap.add_argument("--requests", type=int, default=300)
    args = ap.parse_args()
    res = {w: serve_and_measure(w, args.requests) for w in (1, 2)}
    lines = [f"A live server on room A, {args.requests} requests of one 72-image PNG turn "
             "each per block.", "",
             "| workers | clients | requests/s | p50 (ms) | p95 (ms) | 2 workers vs 1 | "
             "CPU ms per request: server / workers / clients |",
             "|---|---|---|---|---|---|---|"]
    for w in (1, 2):
        for (clients, rps, lat, cpu), row1 in zip(res[w], res[1], strict=True):
            q = statistics.quantiles(lat, n=20)
            lines.append(f"| {w} | {clients} | {rps:.1f} | {1e3 * statistics.median(lat):.1f} "
                         f"| {1e3 * q[18]:.1f} | {rps / row1[1]:.2f}x | "
                         + " / ".join(f"{v:.1f}" for v in cpu) + " |")
    srv_, wrk, cli = res[2][-1][3]
    lines += ["", f"With 2 cores shared by the server process, the workers and the clients, "
              f"2 workers can give at most {2 * wrk / (srv_ + wrk + cli):.2f}x one worker's "
              "throughput (2 cores over the CPU a request takes in all, against one core over "
              "a worker's part).", "", "`GET /health` every 50 ms meanwhile:", ""]
    lines += [f"- {k}: {v}" for k, v in HEALTH.items()]
    lines += ["", "One worker, the same turn sent as 72 PNG files and as one PNG of the whole "
              "turn (`turn_png`), in turn:", "",
              "| payload | clients | requests/s | p50 (ms) | CPU ms per request: server / "
              "worker / clients | CPU per request vs 72 PNGs |", "|---|---|---|---|---|---|"]
    base = {c: sum(cpu) for name, c, _r, _l, cpu in PAYLOADS if name.startswith("images")}
    for name, clients, rps, lat, cpu in PAYLOADS:
        lines.append(f"| {name} | {clients} | {rps:.1f} | {1e3 * statistics.median(lat):.1f} "
                     f"| {' / '.join(f'{v:.1f}' for v in cpu)} | "
                     f"{sum(cpu) / base[clients]:.2f}x |")
    print("\n".join(lines))
    write_page("localize_clients", "Localization throughput: compute workers x concurrent "
               "clients", lines, mode(ap, args))


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    main()
