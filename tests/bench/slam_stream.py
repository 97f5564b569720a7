"""Does a REST SLAM run keep up with a robot streaming laser scans at 10 Hz?

    .venv/bin/python tests/bench/slam_stream.py [--log PATH] [--scans N] [--methods graph,rbpf]
                                                [--rate 10] [--particles 512]
                                                [--fallback-particles 128] [--out bench-out]

For each method the real service (``chizu serve``: uvicorn, one worker) is started in a
subprocess on a free loopback port with a temporary data directory, so the HTTP and JSON
cost is the real one. The first N scans of a Freiburg CARMEN log (default aces, 1500
scans) are posted to a new run **one scan per request** (``ScansIn`` takes 1..500 per
request; a robot sends each sweep as it comes), scan k at t0 + k/rate or at once when
behind; one request at a time, as a robot's client would.

Measured per method: request latency (p50/p95/p99/max), lag behind the schedule (max and
at the end; share of scans sent more than one period late), the rate achieved, the
processing capacity N / sum(latency) as a multiple of the target rate, the server's CPU
time per scan (a figure the other load on a shared machine barely moves) and the CPU the
rest of the machine used meanwhile. Halfway through, malformed scans (a NaN range,
intensities of the wrong length, a time stamp that goes back) must get a 4xx
``application/problem+json`` and leave the run as it was; the stream then goes on and
the pose must keep moving. Afterwards GET map.png / map.pgm / map.yaml / trajectory must
return 200 with a consistent map, and POST commit must succeed. Before the streams, one
360-beam and one 1081-beam scan (with intensities), and a 500-scan batch of 1081-beam
scans, check what the body-size limit lets through.

An RBPF run that does not keep up at --particles is repeated at --fallback-particles
(labelled). Writes docs/results/slam_stream.md (the tables) and OUT/slam-stream.json
(every latency; OUT is --out, bench-out).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import Any

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from chizu.numeric.scan import Scan  # noqa: E402
from chizu.numeric.slam.datasets import slam_data_dir  # noqa: E402
from chizu.numeric.slam.logs import read_log  # noqa: E402
from chizu.service.client import Client, ProblemError  # noqa: E402
from tests.conftest import LiveServer  # noqa: E402

WORLD = "stream"
PROBLEM = "application/problem+json"
TICK = os.sysconf("SC_CLK_TCK")


def default_log() -> Path:
    d = slam_data_dir() or Path("/work/shared/data/slam")
    return d / "aces" / "aces.recon.clf"


class Server(LiveServer):
    """``python -m service.cli serve`` (what ``make run`` starts) on a free port, with
    its CPU time and peak memory."""

    def __init__(self, data_dir: Path) -> None:
        super().__init__(data_dir, start_timeout_s=90.0)

    def cpu_s(self) -> float:
        """User + system CPU seconds of the server process so far."""
        f = Path(f"/proc/{self.proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(f[11]) + int(f[12])) / TICK

    def peak_rss_mb(self) -> float:
        for line in Path(f"/proc/{self.proc.pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
        return float("nan")


def busy_jiffies() -> int:
    """Busy CPU time of the whole machine (all cores), in clock ticks."""
    v = [int(x) for x in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    return sum(v) - v[3] - v[4]  # minus idle and iowait


def scan_dict(s: Scan) -> dict[str, Any]:
    """A scan as the API takes it (``ScanIn``); ranges to 0.1 mm like a sensor driver."""
    d: dict[str, Any] = {
        "t": float(s.t), "ranges": np.round(s.ranges, 4).tolist(),
        "angle_min": float(s.angles[0]),
        "angle_increment": float(s.angles[1] - s.angles[0]),
        "range_min": float(s.min_range_m), "range_max": float(s.max_range_m),
        "odom": [float(v) for v in s.odom]}
    if s.intensities is not None:
        d["intensities"] = np.round(s.intensities, 1).tolist()
    return d


def body(scans: list[dict[str, Any]]) -> bytes:
    return json.dumps({"scans": scans}).encode()


def pct(x: list[float], q: float) -> float:
    return float(np.percentile(x, q)) if x else float("nan")


def is_problem(r: httpx.Response) -> bool:
    return 400 <= r.status_code < 500 and r.headers.get("content-type", "").startswith(PROBLEM)


@dataclass
class Stream:
    label: str
    options: dict[str, Any]
    scans: int = 0
    sent: int = 0
    latencies_ms: list[float] = field(default_factory=list)
    lags_s: list[float] = field(default_factory=list)
    wall_s: float = 0.0
    final_lag_s: float = 0.0
    server_cpu_s: float = 0.0
    other_cores: float = 0.0
    load: tuple[float, float] = (0.0, 0.0)
    peak_rss_mb: float = 0.0
    stopped_at: int | None = None
    errors: list[str] = field(default_factory=list)
    bad: dict[str, Any] = field(default_factory=dict)
    endpoints: dict[str, Any] = field(default_factory=dict)
    health_p50_ms: float = 0.0

    def verdict(self, rate: float) -> str:
        """"yes": on schedule (<= 1 % of scans a period late, lag <= 1 s); "bounded":
        the backlog never grows past 1 s but more scans are late (some updates take
        longer than a period); "no": the lag grew, the stream stopped or a scan failed."""
        late = sum(lg > 1 / rate for lg in self.lags_s)
        if (self.stopped_at is not None or self.errors or self.final_lag_s > 1.0
                or max(self.lags_s, default=0) > 1.0):
            return "no"
        return "yes" if late <= 0.01 * max(self.sent, 1) else "bounded"


class EndpointCheck:
    """Calls of a run's outputs after the stream, each checked for an answer and a sane
    body; ``out`` gathers the figures, ``problems`` what failed."""

    def __init__(self, c: Client, http: httpx.Client, run: str) -> None:
        self.c, self.http, self.run = c, http, run
        self.out: dict[str, Any] = {}
        self.problems: list[str] = []

    def call(self, what: str, op: Callable[..., Any], *args: Any,
             **kwargs: Any) -> tuple[Any, float]:
        """``op(WORLD, run, *args, **kwargs)``: its answer (None after a problem) and ms."""
        t = time.perf_counter()
        try:
            answer = op(WORLD, self.run, *args, **kwargs)
        except ProblemError as e:
            answer = None
            self.problems.append(f"{what}: {e}"[:250])
        return answer, (time.perf_counter() - t) * 1e3

    def png(self) -> None:
        from PIL import Image

        # the first map request builds the grid
        content, ms = self.call("GET map.png", self.c.slam.get_map_png)
        if content is None:
            return
        img = Image.open(BytesIO(content))
        free = float(np.mean(np.asarray(img.convert("L")) > 250))
        self.out["png"] = {"ms": ms, "kb": len(content) / 1024, "size": img.size,
                           "free": free}
        if content[:8] != b"\x89PNG\r\n\x1a\n" or free <= 0.01:
            self.problems.append(f"map.png: not a map ({free:.3f} free)")

    def pgm(self) -> None:
        content, ms = self.call("GET map.pgm", self.c.slam.get_map_pgm)
        if content is None:
            return
        m = re.match(rb"P5\s+(?:#.*\n\s*)*(\d+)\s+(\d+)\s+(\d+)\s", content)
        if m is None:
            self.problems.append("map.pgm: no P5 header")
            return
        w, h = int(m[1]), int(m[2])
        px = np.frombuffer(content[m.end():], np.uint8)
        occ, free = float(np.mean(px == 0)), float(np.mean(px == 254))
        self.out["pgm"] = {"ms": ms, "size": (w, h), "occupied": occ, "free": free}
        if px.size != w * h or occ <= 0 or free <= 0.01:
            self.problems.append(f"map.pgm: {px.size} bytes for {w}x{h}, occ {occ}, "
                                 f"free {free}")
        if "png" in self.out and tuple(self.out["png"]["size"]) != (w, h):
            self.problems.append(f"map.png {self.out['png']['size']} vs map.pgm {(w, h)}")

    def yaml(self) -> None:
        content, ms = self.call("GET map.yaml", self.c.slam.get_map_yaml)
        if content is None:
            return
        y = content.decode()
        res = re.search(r"resolution:\s*([0-9.eE+-]+)", y)
        self.out["yaml"] = {"ms": ms, "resolution": float(res[1]) if res else None}
        if not ("image: map.pgm" in y and res is not None and "origin:" in y):
            self.problems.append(f"map.yaml: {y[:200]!r}")

    def trajectory(self, scans: int, last_pose: dict[str, float], sent_t: list[float]) -> None:
        # raw: the answer's size on the wire is one of the figures
        t = time.perf_counter()
        r = self.http.get(f"/worlds/{WORLD}/slam-runs/{self.run}/trajectory")
        ms = (time.perf_counter() - t) * 1e3
        if r.status_code != 200:
            self.problems.append(f"GET trajectory: {r.status_code} {r.text[:200]}")
        else:
            tr = r.json()
            n = len(tr["poses"])
            self.out["trajectory"] = {"ms": ms, "poses": n, "kb": len(r.content) / 1024}
            if n != scans or not np.allclose(tr["t"], sent_t):
                self.problems.append(f"trajectory: {n} poses for {scans} scans")
            # /pose is the estimate the trajectory ends with (graph SLAM: iSAM2's current
            # estimate of the latest node, read without changing the run)
            end = tr["poses"][-1]
            gap = math.hypot(end[0] - last_pose["x"], end[1] - last_pose["y"])
            self.out["trajectory"]["end_vs_pose_mm"] = gap * 1e3
            if gap > 0.01:  # rounding of the JSON, no more
                self.problems.append(f"trajectory ends {gap:.2f} m from the last pose")
        tum, ms = self.call("GET trajectory?format=tum", self.c.slam.get_trajectory,
                            format="tum")
        if tum is not None and len(tum.strip().splitlines()) != scans:
            self.problems.append("trajectory?format=tum: wrong line count")

    def commit(self) -> None:
        t, status = time.perf_counter(), 200
        try:
            self.c.slam.post_commit(WORLD, self.run)
        except ProblemError as e:
            status = e.status
            self.problems.append(f"POST commit: {e}"[:250])
        self.out["commit"] = {"ms": (time.perf_counter() - t) * 1e3, "status": status}


def check_maps(c: Client, http: httpx.Client, run: str, scans: int,
               last_pose: dict[str, float], sent_t: list[float]) -> dict[str, Any]:
    """Get the maps and the trajectory after the stream, then commit; each must answer and
    be sane. The figures by endpoint, and ``problems``."""
    check = EndpointCheck(c, http, run)
    check.png()
    check.pgm()
    check.yaml()
    check.trajectory(scans, last_pose, sent_t)
    check.commit()
    return {**check.out, "problems": check.problems}


def bad_scans(c: httpx.Client, base: str, good: dict[str, Any],
              previous_t: float) -> dict[str, Any]:
    """Malformed one-scan requests; each must be a 4xx problem and leave the run as it was."""
    before = c.get(base).json()
    x = "__not_a_number__"

    def raw(scan: dict[str, Any], literal: bytes) -> bytes:  # JSON has no NaN: write it raw
        return body([scan]).replace(json.dumps(x).encode(), literal, 1)

    cases = {
        "NaN range": raw({**good, "ranges": [x, *good["ranges"][1:]]}, b"NaN"),
        "intensities of another length": body(
            [{**good, "intensities": [1.0] * (len(good["ranges"]) - 1)}]),
        "time going back": body([{**good, "t": previous_t}]),
        "inf odometry": raw({**good, "odom": [x, *good["odom"][1:]]}, b"Infinity"),
        "no ranges": body([{**good, "ranges": [], "intensities": None}]),
    }
    out: dict[str, Any] = {"cases": {}}
    for name, b in cases.items():
        t = time.perf_counter()
        r = c.post(base + "/scans", content=b, headers={"content-type": "application/json"})
        out["cases"][name] = {"status": r.status_code, "problem": is_problem(r),
                              "ms": (time.perf_counter() - t) * 1e3,
                              "field": r.json().get("field") if is_problem(r) else None}
    after = c.get(base).json()
    out["unchanged"] = (after["scans"] == before["scans"] and after["pose"] == before["pose"])
    out["all_4xx_problem"] = all(v["problem"] for v in out["cases"].values())
    out["pose_before"] = before["pose"]
    out["scans_before"] = before["scans"]
    return out


@dataclass(frozen=True)
class Feed:
    """What a stream sends: the scans (request bodies, and as dicts), at ``rate`` Hz; a
    stream more than ``give_up_lag_s`` behind its schedule stops."""

    bodies: list[bytes]
    dicts: list[dict[str, Any]]
    rate: float
    give_up_lag_s: float


def health_p50_ms(c: httpx.Client, n: int = 30) -> float:
    """Median latency of ``GET /health``: the HTTP stack's own cost, the baseline (raw,
    as the scans are sent)."""
    hs = []
    for _ in range(n):
        t = time.perf_counter()
        c.get("/health")
        hs.append((time.perf_counter() - t) * 1e3)
    return pct(hs, 50)


def send_scans(c: httpx.Client, base: str, feed: Feed, st: Stream) -> dict[str, Any]:
    """Post the scans one a request, scan k at t0 + k/rate (at once when behind), with the
    malformed scans after the middle one; the last answer. Fills ``st``'s latencies,
    lags and counts. Raw: each body is encoded once beforehand, so the latency is the
    request's and the client's CPU stays out of the server's way."""
    period, n = 1.0 / feed.rate, len(feed.bodies)
    bad_at = n // 2
    hdr = {"content-type": "application/json"}
    last: dict[str, Any] = {}
    t0 = time.perf_counter() + 0.05
    for k, b in enumerate(feed.bodies):
        target = t0 + k * period
        now = time.perf_counter()
        if now < target:
            time.sleep(target - now)
        start = time.perf_counter()
        r = c.post(base + "/scans", content=b, headers=hdr)
        end = time.perf_counter()
        st.sent += 1
        st.latencies_ms.append((end - start) * 1e3)
        st.lags_s.append(start - target)
        if r.status_code != 200:
            st.errors.append(f"scan {k}: {r.status_code} {r.text[:200]}")
            if len(st.errors) > 5:
                break
            continue
        last = r.json()
        st.scans = last["scans"]
        st.final_lag_s = end - target
        if k == bad_at:
            st.bad = bad_scans(c, base, feed.dicts[k + 1] if k + 1 < n else feed.dicts[k],
                               feed.dicts[k]["t"])
        if k == bad_at + 1 and st.bad:
            st.bad["next_good_scans"] = last["scans"]
            st.bad["next_good_ok"] = last["scans"] == st.bad["scans_before"] + 1
        if end - target > feed.give_up_lag_s:
            st.stopped_at = k + 1
            break
    st.wall_s = time.perf_counter() - t0
    return last


def stream(url: str, label: str, options: dict[str, Any], feed: Feed,
           server: Server) -> Stream:
    """One SLAM run over REST fed by ``feed``: latencies, lags, the CPU of the server and
    of the rest of the machine meanwhile, the malformed scans' answers and the outputs'
    checks."""
    st = Stream(label, options)
    # the typed client shares the raw one's connection
    with httpx.Client(base_url=url, timeout=600) as c, Client(http=c) as chizu:
        st.health_p50_ms = health_p50_ms(c)
        run = chizu.slam.post_run(WORLD, options).id
        base = f"/worlds/{WORLD}/slam-runs/{run}"
        cpu0, busy0, load0 = server.cpu_s(), busy_jiffies(), os.getloadavg()[0]
        client0 = time.process_time()
        last = send_scans(c, base, feed, st)
        client_cpu = time.process_time() - client0
        st.server_cpu_s = server.cpu_s() - cpu0
        busy = (busy_jiffies() - busy0) / TICK
        st.other_cores = max(0.0, busy - st.server_cpu_s - client_cpu) / max(st.wall_s, 1e-9)
        st.load = (load0, os.getloadavg()[0])
        if st.bad and last.get("pose") and st.bad.get("pose_before"):
            p0, p1 = st.bad["pose_before"], last["pose"]
            st.bad["moved_after_m"] = math.hypot(p1["x"] - p0["x"], p1["y"] - p0["y"])
            o0 = feed.dicts[len(feed.bodies) // 2]["odom"]
            o1 = feed.dicts[st.scans - 1]["odom"]
            st.bad["odom_moved_m"] = math.hypot(o1[0] - o0[0], o1[1] - o0[1])
        if st.scans:
            sent_t = [d["t"] for d in feed.dicts[:st.scans]]
            st.endpoints = check_maps(chizu, c, run, st.scans, last["pose"], sent_t)
        st.peak_rss_mb = server.peak_rss_mb()
    return st


def size_checks(url: str, dicts: list[dict[str, Any]], max_body: int) -> list[list[str]]:
    """One 360-beam and one 1081-beam scan (with intensities) and a 500-scan batch of
    1081-beam scans: does the body-size limit let a real laser's scans through?"""
    rows = []
    rng = np.random.default_rng(0)

    def synthetic(beams: int, t: float) -> dict[str, Any]:
        fov = 270.0 if beams == 1081 else 360.0
        inc = math.radians(fov) / (beams - (1 if beams == 1081 else 0))
        return {"t": t, "ranges": np.round(rng.uniform(0.5, 29.0, beams), 3).tolist(),
                "intensities": np.round(rng.uniform(0, 8000, beams), 0).tolist(),
                "angle_min": -math.radians(fov) / 2, "angle_increment": inc,
                "range_min": 0.02, "range_max": 30.0, "odom": [0.0, 0.0, 0.0]}

    # raw posts: the point is the body-size limit (bodies' size on the wire, a 413)
    with httpx.Client(base_url=url, timeout=600) as c, Client(http=c) as chizu:
        rid = chizu.slam.post_run(WORLD, {"method": "odom"}).id
        base = f"/worlds/{WORLD}/slam-runs/{rid}/scans"
        t = 1.0
        for what, scans in [("1 scan, 360 beams + intensities", [synthetic(360, t)]),
                            ("1 scan, 1081 beams + intensities", [synthetic(1081, t + 1)]),
                            ("500 scans, 1081 beams + intensities",
                             [synthetic(1081, t + 2 + 0.025 * i) for i in range(500)]),
                            ("500 scans of the log (180 beams)",
                             [{**d, "t": t + 20 + 0.1 * i} for i, d in enumerate(dicts[:500])])]:
            b = body(scans)
            s = time.perf_counter()
            r = c.post(base, content=b, headers={"content-type": "application/json"})
            ms = (time.perf_counter() - s) * 1e3
            verdict = str(r.status_code) + ("" if r.status_code == 200 else
                                            f" {r.json().get('title', '')}")
            rows.append([what, f"{len(b) / 1024:.0f} KiB", verdict, f"{ms:.0f}"])
    rows.append(["(body limit, CHIZU_MAX_BODY_BYTES)", f"{max_body / 1024:.0f} KiB", "", ""])
    return rows


def fmt_stream(s: Stream, rate: float) -> str:
    lat = s.latencies_ms
    late = sum(lg > 1 / rate for lg in s.lags_s)
    busy_s = sum(lat) / 1e3
    cap = s.scans / busy_s if busy_s else float("nan")
    achieved = s.sent / s.wall_s if s.wall_s else float("nan")
    kept = {"yes": "yes", "bounded": "lag bounded, not every scan on time",
            "no": f"no (stopped at {s.stopped_at})" if s.stopped_at else "no"}[s.verdict(rate)]
    return (f"| {s.label} | {s.scans} | {pct(lat, 50):.1f} / {pct(lat, 95):.1f} / "
            f"{pct(lat, 99):.1f} / {max(lat, default=float('nan')):.0f} | "
            f"{max(s.lags_s, default=0):.2f} | {s.final_lag_s:.2f} | "
            f"{late} ({late / max(s.sent, 1):.1%}) | {achieved:.2f} | "
            f"{cap:.0f} ({cap / rate:.1f}×) | {1e3 * s.server_cpu_s / max(s.scans, 1):.1f} | "
            f"{s.health_p50_ms:.2f} | {s.other_cores:.2f} (load {s.load[0]:.1f}→{s.load[1]:.1f})"
            f" | {s.peak_rss_mb:.0f} | **{kept}** |")


def fmt_endpoints(s: Stream) -> str:
    e = s.endpoints
    b = s.bad
    if b:
        codes = ", ".join(f"{k} {v['status']}" for k, v in b["cases"].items())
        # the pose must move on after the bad scans as far as odometry says, give or take
        moving = (b.get("moved_after_m", 0) > 0.5 * b.get("odom_moved_m", 0)
                  or b.get("odom_moved_m", 0) < 0.05)
        ok = b["all_4xx_problem"] and b["unchanged"] and b.get("next_good_ok", False) and moving
        bad = (f"{codes}; problem+json: {'yes' if b['all_4xx_problem'] else 'NO'}; "
               f"run unchanged: {'yes' if b['unchanged'] else 'NO'}; next scan counted: "
               f"{'yes' if b.get('next_good_ok') else 'NO'}; moved "
               f"{b.get('moved_after_m', 0):.1f} m after "
               f"(odometry {b.get('odom_moved_m', 0):.1f} m) "
               f"→ **{'ok' if ok else 'FAIL'}**")
    else:
        bad = "not reached"

    def cell(key: str, extra: str) -> str:
        return f"{e[key]['ms']:.0f} ms, {extra}" if key in e else "FAIL"

    png = cell("png", f"{e['png']['size'][0]}×{e['png']['size'][1]}, {e['png']['kb']:.0f} KiB"
               ) if "png" in e else "FAIL"
    pgm = cell("pgm", f"{e['pgm']['occupied']:.1%} occupied, {e['pgm']['free']:.0%} free"
               ) if "pgm" in e else "FAIL"
    yml = cell("yaml", f"{e['yaml']['resolution']} m") if "yaml" in e else "FAIL"
    tra = cell("trajectory", f"{e['trajectory']['poses']} poses, "
               f"{e['trajectory']['kb']:.0f} KiB, ends "
               f"{e['trajectory']['end_vs_pose_mm']:.0f} mm from /pose"
               ) if "trajectory" in e else "FAIL"
    com = (f"{e['commit']['status']}, {e['commit']['ms']:.0f} ms" if "commit" in e else "FAIL")
    verdict = "ok" if e and not e["problems"] else "FAIL: " + "; ".join(e.get("problems", []))
    return f"| {s.label} | {png} | {pgm} | {yml} | {tra} | {com} | {verdict} | {bad} |"


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--log", type=Path, default=None, help="CARMEN log (default: aces)")
    ap.add_argument("--scans", type=int, default=1500, help="first N scans of the log")
    ap.add_argument("--methods", default="graph,rbpf", help="comma-separated: graph, rbpf, ...")
    ap.add_argument("--rate", type=float, default=10.0, help="target scan rate (Hz)")
    ap.add_argument("--particles", type=int, default=512, help="RBPF particles")
    ap.add_argument("--fallback-particles", type=int, default=128,
                    help="rerun RBPF with this many particles if it does not keep up (0: no)")
    ap.add_argument("--give-up-lag", type=float, default=120.0,
                    help="stop a stream once it is this many seconds behind")
    ap.add_argument("--skip-size-checks", action="store_true")
    ap.add_argument("--out", type=Path, default=Path("bench-out"))
    return ap


def method_runs(a: argparse.Namespace) -> list[tuple[str, dict[str, Any]]]:
    """``(label, run options)`` of each method of ``--methods``."""
    runs: list[tuple[str, dict[str, Any]]] = []
    for m in [m.strip() for m in a.methods.split(",") if m.strip()]:
        if m == "rbpf":
            runs.append((f"rbpf improved, {a.particles} particles",
                         {"method": "rbpf", "proposal": "improved", "particles": a.particles}))
        else:
            runs.append((m, {"method": m}))
    return runs


def serve_and_stream(label: str, opts: dict[str, Any], feed: Feed,
                     size_checks_max_body: int | None) -> tuple[Stream, list[list[str]]]:
    """A fresh server and world, the body-size checks first if ``size_checks_max_body``
    is given, then one stream; errors the server logged count as the stream's."""
    size_rows: list[list[str]] = []
    with tempfile.TemporaryDirectory(prefix="chizu-stream-") as tmp:
        server = Server(Path(tmp))
        try:
            with Client(server.url, timeout_s=60) as c:
                c.worlds.create_world({"name": WORLD})
            if size_checks_max_body is not None:
                size_rows = size_checks(server.url, feed.dicts, size_checks_max_body)
            print(f"streaming {label} ...", flush=True)
            s = stream(server.url, label, opts, feed, server)
        finally:
            server.stop()
        errors_logged = [ln for ln in server.log_path.read_text().splitlines()
                         if " 500 " in ln or "Traceback" in ln]
        s.errors.extend(errors_logged[:5])
    return s, size_rows


def report(results: list[Stream], size_rows: list[list[str]], intro: str,
           rate: float, scans: int) -> list[str]:
    """The page's tables: the streams, the outputs after them, the body sizes."""
    cores = os.cpu_count() or 1
    other = max(s.other_cores for s in results)
    lines = [
        intro, "",
        f"Machine: {cores} cores; up to {other:.2f} cores were busy with other work during "
        "the streams" + (" (another benchmark was running: latencies and capacity are "
                         "pessimistic; server CPU ms/scan is the steadier figure)."
                         if other > 0.3 else "."), "",
        "| method | scans | latency p50 / p95 / p99 / max (ms) | max lag (s) | final lag (s) "
        "| sent > 1 period late | achieved (Hz) | capacity scans/s (× target) "
        "| server CPU ms/scan | /health p50 (ms) | other cores busy | server peak RSS (MB) "
        "| kept up |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        *[fmt_stream(s, rate) for s in results], "",
        "Capacity = scans / sum of request latencies (what one client sending back to back "
        "would get). Kept up = yes: the lag behind the schedule stays ≤ 1 s and ≤ 1 % of "
        "scans are sent more than one period late; lag bounded: the lag stays ≤ 1 s but more "
        "scans are late (single updates longer than a period); no: the lag grew.", "",
        "After the stream (first GET of a map builds the grid; the others reuse it), and the "
        f"malformed scans sent after scan {scans // 2}:", "",
        "| method | map.png | map.pgm | map.yaml | trajectory | commit | maps | bad scans |",
        "|---|---|---|---|---|---|---|---|",
        *[fmt_endpoints(s) for s in results]]
    gaps = [s.label for s in results
            if s.endpoints.get("trajectory", {}).get("end_vs_pose_mm", 0) > 50]
    if gaps:
        lines += ["", f"{', '.join(gaps)}: GET pose is not where GET trajectory ends."]
    errs = [f"- {s.label}: {e}" for s in results for e in s.errors]
    if errs:
        lines += ["", "Errors:", *errs]
    if size_rows:
        lines += ["", "Body sizes (a separate odom run):", "",
                  "| body | size | status | ms |", "|---|---|---|---|",
                  *["| " + " | ".join(r) + " |" for r in size_rows]]
    return lines


def main() -> None:
    from chizu.service.settings import Settings
    from tests.bench.results import mode, write_page

    ap = parser()
    a = ap.parse_args()
    path = a.log or default_log()
    log = read_log(path).head(a.scans)
    dicts = [scan_dict(s) for s in log.scans]
    feed = Feed([body([d]) for d in dicts], dicts, a.rate, a.give_up_lag)
    log_rate = len(log) / max(log.duration_s, 1e-9)
    a.out.mkdir(parents=True, exist_ok=True)
    print(f"{path.name}: {len(dicts)} scans of {len(dicts[0]['ranges'])} beams "
          f"(log rate {log_rate:.1f} Hz), one scan per request "
          f"({np.mean([len(b) for b in feed.bodies]) / 1024:.1f} KiB) at {a.rate:g} Hz; "
          f"{os.cpu_count() or 1} cores, load {os.getloadavg()[0]:.1f}", flush=True)
    runs = method_runs(a)
    results: list[Stream] = []
    size_rows: list[list[str]] = []
    while runs:
        label, opts = runs.pop(0)
        check_sizes = not size_rows and not a.skip_size_checks
        s, rows = serve_and_stream(label, opts, feed,
                                   Settings().max_body_bytes if check_sizes else None)
        size_rows = size_rows or rows
        results.append(s)
        print(fmt_stream(s, a.rate), flush=True)
        if (opts["method"] == "rbpf" and s.verdict(a.rate) != "yes" and a.fallback_particles
                and opts["particles"] != a.fallback_particles):
            runs.insert(0, (f"rbpf improved, {a.fallback_particles} particles (fallback)",
                            {**opts, "particles": a.fallback_particles}))
    intro = (f"{path.name}, first {len(dicts)} scans ({len(dicts[0]['ranges'])} beams), one "
             f"scan per POST at {a.rate:g} Hz (the log's own rate is {log_rate:.1f} Hz), "
             "uvicorn + one worker on loopback, a fresh server and run per method.")
    lines = report(results, size_rows, intro, a.rate, len(dicts))
    print("\n" + "\n".join(lines))
    write_page("slam_stream", "SLAM streaming over REST: does a run keep up with the robot?",
               lines, mode(ap, a, ignore=("out",)))
    (a.out / "slam-stream.json").write_text(json.dumps(
        [{"label": s.label, "options": s.options, "scans": s.scans,
          "latencies_ms": s.latencies_ms, "lags_s": s.lags_s, "wall_s": s.wall_s,
          "server_cpu_s": s.server_cpu_s, "other_cores": s.other_cores,
          "bad": s.bad, "endpoints": s.endpoints, "errors": s.errors} for s in results],
        default=str))


if __name__ == "__main__":
    main()
