"""Lifelong runs: one shared log driven three times end to end as one graph SLAM run,
forwards, backwards, forwards (the scans of the second pass in reverse order: the robot
retraces its path, so the odometry stays continuous at every turn-round and nothing is
invented between passes), with finished submaps trimmed when older ones had observed
what they did (numeric.slam.graph.submaps, ``submaps.trim_share``) and without.

    .venv/bin/python tests/bench/lifelong.py [--log aces] [--passes 3] [--out bench-out]

Each setting runs in a fresh process; after every pass: resident and peak memory, the
submaps kept and trimmed, the pass's seconds and real-time factor, and its relation error
(Kümmerle et al. 2009) on the log's relations, the online estimate (before any end-of-run
alignment); and at the end each pass's error after the end-of-run alignment of the whole
run. Writes docs/results/lifelong.md and OUT/lifelong.json.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from chizu.numeric.memory import return_large_frees  # noqa: E402
from chizu.numeric.slam.datasets import slam_data_dir  # noqa: E402
from chizu.numeric.slam.evaluation import relation_errors  # noqa: E402
from chizu.numeric.slam.graph import GraphSlam, GraphSlamConfig  # noqa: E402
from chizu.numeric.slam.logs import read_log, read_relations  # noqa: E402
from tests.bench.results import write_page  # noqa: E402
from tests.bench.slam import LOGS  # noqa: E402

DATA = slam_data_dir() or Path("../shared/data/slam")


def rss_mb() -> float:
    """This process's resident memory now (MB)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS"):
            return int(line.split()[1]) / 1024
    return float("nan")


def one(name: str, passes: int, trim: bool) -> list[dict[str, Any]]:
    """The passes over log ``name`` as one run, in this process."""
    return_large_frees()  # as the CLI and the service do
    log = read_log(DATA / name / dict(LOGS)[name])
    rt, rd = read_relations(DATA / name / f"{name}.relations")
    cfg = GraphSlamConfig()
    if not trim:
        cfg.submaps.trim_share = None
    slam = GraphSlam(cfg)
    first, last = log.scans[0].t, log.scans[-1].t
    span, n = last - first + 1.0, len(log)
    rows = []
    for k in range(passes):
        t0 = time.perf_counter()
        back = k % 2 == 1
        for sc in (log.scans[::-1] if back else log.scans):
            slam.process(replace(sc, t=k * span + (last - sc.t if back else sc.t - first)))
        seconds = time.perf_counter() - t0
        _, poses = slam.trajectory()
        mine = poses[k * n:(k + 1) * n]
        e = relation_errors(log.times, mine[::-1] if back else mine, rt, rd)
        rows.append({"log": name, "trim": trim, "pass": k + 1, "trans": e.trans_m,
                     "rot": e.rot_deg, "rss_mb": rss_mb(),
                     "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                     "seconds": seconds, "realtime": log.duration_s / seconds,
                     "submaps": len(slam.submaps),
                     "trimmed": sum(s.trimmed for s in slam.submaps),
                     "closures": len(slam.closures), "nodes": len(slam.local),
                     "graph_nodes": slam.graph.held()})
        print(json.dumps(rows[-1]), flush=True)
    slam.finish()  # the end-of-run alignment over the scans it kept
    _, poses = slam.trajectory()
    for k, row in enumerate(rows):
        mine = poses[k * n:(k + 1) * n]
        row["aligned_trans"] = relation_errors(log.times, mine[::-1] if k % 2 else mine,
                                               rt, rd).trans_m
        row["scans_kept"] = len(slam.scans.kept())
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--log", default="aces")
    ap.add_argument("--passes", type=int, default=3)
    ap.add_argument("--out", default="bench-out")
    ap.add_argument("--one", choices=["trim", "keep"], help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.one:
        for r in one(a.log, a.passes, a.one == "trim"):
            print("ROW " + json.dumps(r), flush=True)
        return
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for setting in ("keep", "trim"):
        r = subprocess.run([sys.executable, __file__, "--one", setting, "--log", a.log,
                            "--passes", str(a.passes)], capture_output=True, text=True,
                           cwd=ROOT, check=True)
        rows += [json.loads(x[4:]) for x in r.stdout.splitlines() if x.startswith("ROW ")]
    (out / "lifelong.json").write_text(json.dumps(rows, indent=1))
    lines = [f"{a.log} driven {a.passes} times end to end as one graph SLAM run "
             "(forwards, backwards, forwards); figures after each pass; relation error of "
             "the pass's own poses on the log's relations, online and after the end-of-run "
             "alignment of the whole run (the trimmed run, which forgets what the map "
             "holds past 10 000 scans, held the points of "
             f"{rows[-1]['scans_kept'] if rows else 0} of its scans); nodes: the run's, and "
             "those its pose graph holds (the others taken out with their trimmed submaps).",
             "", "| submaps | pass | trans (m) | rot (deg) | trans aligned (m) | resident (MB) | "
             "peak (MB) | submaps (trimmed) | nodes (in the graph) | loop closures | seconds | "
             "x real time |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {'trimmed' if r['trim'] else 'all kept'} | {r['pass']} | "
                     f"{r['trans']:.4f} | {r['rot']:.3f} | {r['aligned_trans']:.4f} | "
                     f"{r['rss_mb']:.0f} | "
                     f"{r['peak_mb']:.0f} | {r['submaps']} ({r['trimmed']}) | "
                     f"{r['nodes']} ({r['graph_nodes']}) | "
                     f"{r['closures']} | {r['seconds']:.0f} | {r['realtime']:.1f} |")
    print("\n".join(lines))
    default = a.log == "aces" and a.passes == 3
    write_page("lifelong", "Lifelong runs: one log driven three times as one run", lines,
               "as make bench runs it" if default else f"--log {a.log} --passes {a.passes}")


if __name__ == "__main__":
    main()
