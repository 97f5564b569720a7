"""Several robots streaming into one world at once over REST, one SLAM run each, one map.

    .venv/bin/python tests/bench/robots.py [--log PATH] [--robots 2,4] [--rate 10]
                                           [--scans N]

For each robot count the real service (``chizu serve``, as ``make run`` starts it) runs in
a subprocess with a fresh data directory. A shared log (default aces) is cut into that
many consecutive parts, one robot each; every part but the first has its odometry moved
by a rigid transform of its own that nobody is told. The robots create their runs with
``{"resume": true}`` and stream at once, each in its own thread, one scan per request at
``--rate`` Hz (scan k at t0 + k/rate, at once when behind), as a robot's client would.
Then they commit one after the other: the first founds the world's map, each later one is
found in it and joined (numeric.slam.merge); one whose map shares no place with the world's
yet commits again after the others (a round that joins no one ends it). Measured: the
scans per second the service took from all robots together, each request's latency, how
far behind its schedule a robot fell; each commit's time and outcome; and the relation
error (Kümmerle et al. 2009) of all robots' scans as the world's saved map has them
(``GET .../map.chizu``), beside graph SLAM run over the same scans as one log in this
process. Writes docs/results/robots.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from chizu.numeric.geometry import compose  # noqa: E402
from chizu.numeric.scan import LaserLog  # noqa: E402
from chizu.numeric.slam.evaluation import relation_errors  # noqa: E402
from chizu.numeric.slam.logs import read_log, read_relations  # noqa: E402
from chizu.numeric.slam.runner import SlamOptions, run_log  # noqa: E402
from chizu.numeric.slam.saved_map import from_bytes  # noqa: E402
from chizu.service.client import Client, ProblemError  # noqa: E402
from tests.bench.map_localization import DATA, LOGS  # noqa: E402
from tests.bench.results import mode, write_page  # noqa: E402
from tests.bench.slam_stream import Server, pct, scan_dict  # noqa: E402

WORLD = "robots"


def hidden(k: int) -> np.ndarray:
    """Robot k's odometry frame (robot 0: the log's own)."""
    return np.zeros(3) if k == 0 else np.array([7.0 * k, -5.0 * k, 1.1 * k])


@dataclasses.dataclass
class Robot:
    k: int
    log: LaserLog
    run: str = ""
    latencies_ms: list[float] = dataclasses.field(default_factory=list)
    lags_s: list[float] = dataclasses.field(default_factory=list)
    errors: list[str] = dataclasses.field(default_factory=list)
    commit_s: float = 0.0
    commit: str = ""


def stream(url: str, robot: Robot, rate: float, t0: float) -> None:
    """Robot ``robot``'s scans, one a request, on its schedule from ``t0``."""
    with Client(url, timeout_s=600) as c:
        for i, s in enumerate(robot.log.scans):
            target = t0 + i / rate
            now = time.perf_counter()
            if now < target:
                time.sleep(target - now)
            start = time.perf_counter()
            try:
                c.slam.post_scans(WORLD, robot.run, {"scans": [scan_dict(s)]})
            except ProblemError as e:
                robot.errors.append(f"scan {i}: {e}"[:250])
                if len(robot.errors) > 5:
                    return
            finally:
                robot.latencies_ms.append((time.perf_counter() - start) * 1e3)
                robot.lags_s.append(start - target)


def one_count(n: int, log: LaserLog, rate: float,
              rel: tuple[np.ndarray, np.ndarray]) -> dict[str, Any]:
    size = len(log) // n
    robots = [Robot(k, LaserLog(f"{log.name}-{k}", [
        dataclasses.replace(s, odom=compose(hidden(k), s.odom))
        for s in log.scans[k * size:(k + 1) * size]])) for k in range(n)]
    with tempfile.TemporaryDirectory(prefix="chizu-robots-") as tmp:
        server = Server(Path(tmp))
        try:
            url = server.url
            with Client(url, timeout_s=600) as c:
                c.worlds.create_world({"name": WORLD})
                for r in robots:
                    r.run = c.slam.post_run(WORLD, {"method": "graph", "resume": True}).id
            t0 = time.perf_counter() + 0.1
            threads = [threading.Thread(target=stream, args=(url, r, rate, t0))
                       for r in robots]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            wall = time.perf_counter() - t0
            with Client(url, timeout_s=3600) as c:
                # a robot whose map shares no place with the world's yet commits again
                # once others have joined (the world's map has grown), as a fleet's
                # client would, until a round joins no one
                outcomes: dict[int, list[str]] = {r.k: [] for r in robots}
                waiting = list(robots)
                while waiting:
                    refused = []
                    for r in waiting:
                        s = time.perf_counter()
                        try:
                            c.slam.post_commit(WORLD, r.run)
                            outcomes[r.k].append("founded the map" if r.k == 0 else "joined")
                        except ProblemError as problem:
                            outcomes[r.k].append(f"{problem.status}: {problem.detail}")
                            if problem.status == 422 and problem.field == "map":
                                refused.append(r)  # no shared place yet: later
                        r.commit_s += time.perf_counter() - s
                    if len(refused) == len(waiting):
                        break
                    waiting = refused
                for r in robots:
                    r.commit = ", then ".join(outcomes[r.k])
                # every robot's scans as the world's map now has them
                m = from_bytes(c.slam.get_saved_map(WORLD))
        finally:
            server.stop()
    lat = [x for r in robots for x in r.latencies_ms]
    order = np.argsort(m.times, kind="stable")
    t, p = m.times[order], m.poses[order]
    within = (rel[0][:, 0] >= t.min()) & (rel[0][:, 1] <= t.max())
    e = relation_errors(t, p, rel[0][within], rel[1][within])
    return {"robots": n, "scans": sum(len(r.log) for r in robots), "wall_s": wall,
            "rate": sum(len(r.latencies_ms) for r in robots) / wall,
            "p50": pct(lat, 50), "p95": pct(lat, 95), "max": max(lat),
            "lag": max(max(r.lags_s) for r in robots),
            "errors": sum(len(r.errors) for r in robots),
            "commits": "; ".join(f"{r.commit} ({r.commit_s:.0f} s)" for r in robots),
            "rel": (e.trans_m, e.rot_deg, e.n), "within": within}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--log", default="aces", choices=sorted(LOGS))
    p.add_argument("--robots", default="2,4", help="comma-separated robot counts")
    p.add_argument("--rate", type=float, default=10.0, help="scans per second per robot")
    p.add_argument("--scans", type=int, default=0, help="the log's first N scans (0: all)")
    a = p.parse_args()
    log = read_log(DATA / a.log / LOGS[a.log], limit=a.scans or None)
    rel = read_relations(DATA / a.log / f"{a.log}.relations")
    ref = run_log(log, SlamOptions(method="graph"))[1]
    rows = []
    for n in (int(x) for x in a.robots.split(",")):
        r = one_count(n, log, a.rate, rel)
        g = relation_errors(ref.times, ref.poses, rel[0][r["within"]], rel[1][r["within"]])
        r["graph"] = (g.trans_m, g.rot_deg)
        rows.append(r)
        print({k: v for k, v in r.items() if k != "within"}, flush=True)
    body = [
        f"{a.log} ({len(log)} scans) cut into one part per robot, each streamed at "
        f"{a.rate:g} Hz into its own SLAM run of one world at once, one scan a request; "
        "then committed one after the other (the first founds the world's map, the others "
        "are found in it and joined; one refused because its map shares no place with the "
        "world's yet commits again after the others). Relation errors (mean translational "
        "m / rotational deg) of all robots' trajectories as the world's map has them, "
        "beside graph SLAM over the same scans as one log.", "",
        "| robots | scans | scans/s taken (target) | latency p50 / p95 / max [ms] | "
        "most behind schedule [s] | rejected | commits | map of all robots | graph SLAM, "
        "one log | ratio |",
        "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        t, d, n = r["rel"]
        gt, gd = r["graph"]
        body.append(
            f"| {r['robots']} | {r['scans']} | {r['rate']:.1f} ({r['robots'] * a.rate:g}) | "
            f"{r['p50']:.0f} / {r['p95']:.0f} / {r['max']:.0f} | {r['lag']:.2f} | "
            f"{r['errors']} | {r['commits']} | {t:.4f} / {d:.3f} ({n}) | {gt:.4f} / {gd:.3f} | "
            f"{t / gt:.2f} |")
    print("\n".join(body))
    write_page("robots", "Several robots into one world at once", body, mode(p, a))


if __name__ == "__main__":
    main()
