"""SLAM on offices nobody tuned it on: random floors, random tours, two lasers.

    .venv/bin/python tests/bench/slam_unseen.py [--seeds 1,2] [--lasers urg,lms]
                                                [--methods odom,karto,graph,rbpf]

Every parameter of chizu's SLAM was chosen on the four Freiburg logs. This bench drives
the simulator (one world model, one laser model, one odometry model: ``chizu.numeric.worlds``,
``chizu.numeric.laser``, ``chizu.numeric.simulator``) through office floors made from a seed -- 3 to
5 rooms a side of random width and depth, a corridor of random width -- on a tour that
visits every room's doorway and centre on the way down the corridor and back, then
re-enters the first room (so the last part of the tour returns to places seen 2-5
minutes before). The odometry has a random distance bias of up to ±3 %, 5 % distance
and turn noise and a heading random walk of 0.02 rad per √m. Two lasers: the
URG-04LX of Hara et al. (5.6 m, 240°, the simulator's default) and an LMS-like
scanner (30 m, 180° in 1° steps, as on the benchmark logs).

The references are the true poses: relations (Kümmerle et al. 2009) between scans 1 s
apart every 0.5 s, and between every pair of scans more than 60 s apart whose true
poses lie within 2 m and 0.5 rad of each other (at most 600, evenly picked): the
loop-spanning ones. Each method runs with its defaults (the same parameters as on the
real logs; the improved RBPF with 512 particles, seed 0). Writes
docs/results/slam_unseen.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from chizu.numeric.geometry import relative, wrap_angle
from chizu.numeric.scan import LaserLog
from chizu.numeric.slam.evaluation import RelationErrors, relation_errors
from chizu.numeric.slam.runner import SlamOptions, run_log
from chizu.numeric.slam.simulate import office_log

LOOP_GAP_S = 60.0


def true_relations(log: LaserLog) -> tuple[tuple[np.ndarray, np.ndarray],
                                           tuple[np.ndarray, np.ndarray]]:
    """``(times (R, 2), deltas (R, 3))`` of the short and of the loop-spanning relations
    between the log's true poses (see the module docstring)."""
    t = log.times
    truth = np.asarray(log.truth)
    dt = float(np.median(np.diff(t)))
    gap, every = max(1, round(1.0 / dt)), max(1, round(0.5 / dt))
    i = np.arange(0, len(t) - gap, every)
    short = (np.column_stack([t[i], t[i + gap]]), relative(truth[i], truth[i + gap]))
    a, b = np.triu_indices(len(t), k=1)
    far = t[b] - t[a] > LOOP_GAP_S
    a, b = a[far], b[far]
    near = ((np.hypot(*(truth[b, :2] - truth[a, :2]).T) < 2.0)
            & (np.abs(wrap_angle(truth[b, 2] - truth[a, 2])) < 0.5))
    a, b = a[near], b[near]
    if len(a) > 600:
        pick = np.unique(np.linspace(0, len(a) - 1, 600).astype(int))
        a, b = a[pick], b[pick]
    loop = (np.column_stack([t[a], t[b]]), relative(truth[a], truth[b]))
    return short, loop


def estimate(log: LaserLog, method: str) -> tuple[np.ndarray, np.ndarray, float]:
    """``(times, poses, seconds)`` of ``method`` (chizu's, or the peer ``karto``) on ``log``."""
    if method == "karto":
        from tests.bench.slam_peers import peer_odometry

        return peer_odometry(log, "karto")
    if method == "odom":
        return log.times, log.odometry, 0.0
    t0 = time.perf_counter()
    _, res = run_log(log, SlamOptions(method=method))  # type: ignore[arg-type]
    return res.times, res.poses, time.perf_counter() - t0


def _fmt(e: RelationErrors | None) -> str:
    return "-" if e is None else f"{e.trans_m:.3f} ± {e.trans_std_m:.3f} / {e.rot_deg:.2f}°"


def main() -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # tests.bench.*
    from tests.bench.results import mode, write_page

    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", default="1,2")
    ap.add_argument("--lasers", default="urg,lms")
    ap.add_argument("--methods", default="odom,karto,graph,rbpf")
    a = ap.parse_args()
    lines = ["Relation error (Kümmerle et al. 2009), translational mean ± std (m) / "
             "rotational mean (deg), on the relations 1 s apart and on the loop-spanning "
             "ones (more than 60 s apart, true poses within 2 m); speed as a multiple of "
             "the log's real time.", "",
             "| office | laser | scans | tour (m) | method | 1 s relations | loop-spanning "
             "| x real time |", "|---|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    for seed in (int(s) for s in a.seeds.split(",")):
        for laser in a.lasers.split(","):
            log = office_log(seed, laser)
            truth = np.asarray(log.truth)
            tour = float(np.sum(np.hypot(*np.diff(truth[:, :2], axis=0).T)))
            (st, sd), (lt, ld) = true_relations(log)
            for method in a.methods.split(","):
                times, poses, sec = estimate(log, method)
                e = relation_errors(times, poses, st, sd)
                el = relation_errors(times, poses, lt, ld) if len(lt) else None
                speed = f"{log.duration_s / sec:.1f}" if sec > 0 else "-"
                row = (f"| {seed} | {laser} | {len(log)} | {tour:.0f} | {method} | {_fmt(e)} "
                       f"| {_fmt(el)} | {speed} |")
                lines.append(row)
                print(row, flush=True)
    write_page("slam_unseen", "SLAM on unseen offices (simulated; references are the true "
               "poses)", lines, mode(ap, a))


if __name__ == "__main__":
    main()
