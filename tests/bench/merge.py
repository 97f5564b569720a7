"""Resume and merge on the shared logs: two robots' logs from one, joined into one map.

Each log is split into two robots' logs at a point (its middle, and for the cases nobody
tuned on, other points); the first is mapped by graph SLAM into a saved map, the second's
odometry is moved by a rigid transform the methods are not told. Then (b) the saved map
is resumed with the second log (``chizu slam LOG --resume``: graph SLAM over the second
log, found in the map, joined to it) and (c) the second log is mapped alone and the two
saved maps merged (``chizu slam-merge``). Both are in the first map's frame; their
relation error over all the log's relations (those spanning the two logs included) is set
beside graph SLAM's over the whole log as one run, in the same process. Writes
docs/results/merge.md.

    .venv/bin/python tests/bench/merge.py [--logs aces,fr079] [--quick]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from chizu.numeric.errors import InvalidInput  # noqa: E402
from chizu.numeric.scan import LaserLog  # noqa: E402
from chizu.numeric.slam.evaluation import relation_errors  # noqa: E402
from chizu.numeric.slam.logs import read_log, read_relations  # noqa: E402
from chizu.numeric.slam.merge import merge, resume  # noqa: E402
from chizu.numeric.slam.runner import SlamOptions, run_log  # noqa: E402
from chizu.numeric.slam.saved_map import saved_map_of_log  # noqa: E402
from tests.bench.map_localization import CASES, DATA, LOGS, split  # noqa: E402
from tests.bench.results import mode, write_page  # noqa: E402


def mapped(log: LaserLog) -> tuple[object, float]:
    t0 = time.perf_counter()
    slam, _ = run_log(log, SlamOptions(method="graph"))
    return saved_map_of_log(slam, log, "graph", 0.05), time.perf_counter() - t0


def one_case(name: str, share: float, whole: tuple[np.ndarray, np.ndarray],
             rel: tuple[np.ndarray, np.ndarray], log: LaserLog) -> dict[str, object]:
    first, second = split(log, share)
    a, _ = mapped(first)
    b, b_s = mapped(second)
    span = (rel[0][:, 0] < second.times[0]) & (rel[0][:, 1] >= second.times[0])

    def errors(times: np.ndarray, poses: np.ndarray) -> tuple[float, float, float, float]:
        e = relation_errors(times, poses, *rel)
        s = relation_errors(times, poses, rel[0][span], rel[1][span])
        return e.trans_m, e.rot_deg, s.trans_m, s.rot_deg

    g = relation_errors(*whole, *rel)
    gs = relation_errors(*whole, rel[0][span], rel[1][span])
    row: dict[str, object] = {
        "case": f"{name}, split at {share:.0%}", "scans": f"{len(first)} + {len(second)}",
        "graph": (g.trans_m, g.rot_deg, gs.trans_m, gs.rot_deg, g.n, int(span.sum()))}
    t0 = time.perf_counter()
    try:
        r, poses = resume(a, b)  # type: ignore[arg-type]
    except InvalidInput as e:  # the maps share no place found: reported, not a crash
        return {**row, "refused": str(e)}
    resume_s = time.perf_counter() - t0 + b_s  # the second log's graph SLAM included
    res = errors(np.concatenate([first.times, second.times]),
                 np.vstack([r.poses[:len(first)], poses]))
    t0 = time.perf_counter()
    m, placed = merge(a, b)  # type: ignore[arg-type]
    merge_s = time.perf_counter() - t0
    order = np.argsort(m.times, kind="stable")
    mer = errors(m.times[order], m.poses[order])
    return {**row, "resume": res, "merge": mer, "agree": f"{placed.agree}/{placed.searched}",
            "resume_rt": second.duration_s / max(resume_s, 1e-9), "merge_s": merge_s}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--logs", default=",".join(LOGS), help="comma-separated")
    p.add_argument("--quick", action="store_true", help="the middle split of each log only")
    args = p.parse_args()
    rows = []
    for name in args.logs.split(","):
        log = read_log(DATA / name / LOGS[name])
        rel = read_relations(DATA / name / f"{name}.relations")
        res = run_log(log, SlamOptions(method="graph"))[1]
        for case, share in CASES:
            if case == name and (share == 0.5 or not args.quick):
                rows.append(one_case(name, share, (res.times, res.poses), rel, log))
                print(rows[-1], flush=True)
    body = [
        "Each log split into two robots' logs at the share of its scans named; the first "
        "mapped by graph SLAM into a saved map, the second's odometry moved by a rigid "
        "transform the methods are not told. Resume: the saved map continued with the "
        "second log. Merge: the second log mapped alone, the two saved maps merged. "
        "Relation errors (Kümmerle et al. 2009: mean translational m / rotational deg) over "
        "all the log's relations, and over those spanning the two logs alone, beside graph "
        "SLAM run over the whole log as one run; ratio: translational error over graph "
        "SLAM's (the goal: at most 1.10). Places agreeing: the second map's keyframes "
        "searched for in the first whose fixes agree on where it lies.", "",
        "| case | scans | graph SLAM, whole log: all (spanning) | resume | ratio | merge "
        "| ratio | places agreeing | resume x real time | merge [s] |",
        "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        gt, gr, gst, gsr, n, ns = r["graph"]  # type: ignore[misc]
        graph = (f"| {r['case']} | {r['scans']} | {gt:.4f} / {gr:.3f} ({gst:.4f} / {gsr:.3f}; "
                 f"{n} relations, {ns} spanning) | ")
        if "refused" in r:
            body.append(graph + f"refused: {r['refused']} | | | | | | |")
            continue
        rt, rr, rst, rsr = r["resume"]  # type: ignore[misc]
        mt, mr, mst, msr = r["merge"]  # type: ignore[misc]
        body.append(
            graph + f"{rt:.4f} / {rr:.3f} ({rst:.4f} / {rsr:.3f}) | "
            f"{rt / gt:.2f} | {mt:.4f} / {mr:.3f} ({mst:.4f} / {msr:.3f}) | {mt / gt:.2f} | "
            f"{r['agree']} | {r['resume_rt']:.0f} | {r['merge_s']:.0f} |")
    print("\n".join(body))
    write_page("merge", "Resume and merge: two robots' logs as one map", body,
               mode(p, args, {"quick": "the middle split of each log only"}))


if __name__ == "__main__":
    main()
