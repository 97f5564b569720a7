"""Localization only, on a saved map, on the shared logs: two robots' logs from one.

Each log is split into two robots' logs at a point (its middle, and for the cases nobody
tuned on, other points); the first is mapped by graph SLAM into a saved map, the second's
odometry is moved by a rigid transform the method is not told, and the second is
localized on the map from an unknown start (numeric.slam.map_localization). Its relation
error on the relations within the second log is set beside graph SLAM's over the whole
log, run in the same process, on the same relations. Kidnapping: the robot carried off
for 60 s from the second log's middle (those scans dropped, the wheel odometry blind to
the carry); the robot must be found again. Writes
docs/results/map_localization.md.

    .venv/bin/python tests/bench/map_localization.py [--logs aces,fr079] [--quick]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from chizu.numeric.geometry import compose  # noqa: E402
from chizu.numeric.scan import LaserLog  # noqa: E402
from chizu.numeric.slam.datasets import slam_data_dir  # noqa: E402
from chizu.numeric.slam.evaluation import (  # noqa: E402
    RELATION_MAX_DT_S,
    relation_error_poses,
    relation_errors,
)
from chizu.numeric.slam.logs import read_log, read_relations  # noqa: E402
from chizu.numeric.slam.map_localization import (  # noqa: E402
    LocalizationRun,
    MapLocalizationConfig,
    PreparedMap,
    localize_log,
)
from chizu.numeric.slam.runner import SlamOptions, run_log  # noqa: E402
from chizu.numeric.slam.saved_map import SavedMap, saved_map_of_log  # noqa: E402
from tests.bench.results import mode, write_page  # noqa: E402

DATA = slam_data_dir() or Path("../shared/data/slam")
LOGS = {"aces": "aces.recon.clf", "mit-csail": "mit-csail.clf", "fr079": "fr079.recon.clf",
        "fr-clinic": "fr-clinic.recon.clf"}
#: (log, where the first robot's log ends, as a share of the scans): the middle of
#: every log, and two cases drawn after the parameters were fixed
CASES = [(name, 0.5) for name in LOGS] + [("aces", 0.35), ("mit-csail", 0.65)]
#: the second robot's odometry frame, unknown to the method
HIDDEN = np.array([12.0, -7.0, 2.1])
KIDNAP_S = 60.0


def split(log: LaserLog, share: float) -> tuple[LaserLog, LaserLog]:
    """The first robot's log and the second's, the second's odometry moved by HIDDEN."""
    h = int(len(log) * share)
    second = [dataclasses.replace(s, odom=compose(HIDDEN, s.odom)) for s in log.scans[h:]]
    return LaserLog(f"{log.name}-1", log.scans[:h]), LaserLog(f"{log.name}-2", second)


def kidnapped(log: LaserLog) -> tuple[LaserLog, float]:
    """``log`` with the robot carried off for ``KIDNAP_S`` from its middle (those scans
    dropped, the wheel odometry blind to the carry), and the stamp after the gap."""
    t = log.times
    mid = t[0] + (t[-1] - t[0]) / 2
    start, stop = np.searchsorted(t, [mid, mid + KIDNAP_S])
    return log.carried(int(start), int(stop)), float(t[stop])


def back_on_map(m: SavedMap, log: LaserLog, run: LocalizationRun, after: float
                ) -> tuple[float | None, float | None]:
    """Log time from ``after`` to the first scan the map could fix, where the undisturbed
    ``run`` of ``log`` placed it (None: no such scan): the first with at least the
    localizer's ``min_on_map`` share of its returns on cells the map observed, scoring at
    least ``global_min_score`` there; and the first that scores so over all its returns,
    as one scan must for the global search (which cannot tell which returns fall off the
    map, and scores those 0)."""
    cfg = MapLocalizationConfig()
    prepared = PreparedMap.of(m, cfg)
    on: float | None = None
    for scan, t, pose in zip(log.scans, run.times, run.poses, strict=True):
        if t < after or not np.all(np.isfinite(pose)):
            continue
        score, share = prepared.on_map(scan.points()[0], pose)
        if on is None and share >= cfg.min_on_map and score >= cfg.global_min_score:
            on = float(t - after)
        if score * share >= cfg.global_min_score:
            return on, float(t - after)
    return on, None


def map_at(m: SavedMap, poses: np.ndarray) -> SavedMap:
    """``m`` with its scans at ``poses`` (one per scan of the log it was made of, or
    more): the same keyframes, placed by another run."""
    return dataclasses.replace(m, kf_pose=poses[m.kf_scan].copy(),
                               poses=poses[:len(m.times)].copy())


def errors(run: LocalizationRun, rel: tuple[np.ndarray, np.ndarray],
           ) -> tuple[tuple[float, float, int, int], tuple[np.ndarray, np.ndarray]]:
    """The placed scans' errors on ``rel`` (trans, rot, relations scored, relations
    without a pose) and the relations scored."""
    ok = run.placed
    e = relation_errors(run.times[ok], run.poses[ok], *rel)
    scored = relation_error_poses(run.times[ok], run.poses[ok], *rel, RELATION_MAX_DT_S)[1]
    return (e.trans_m, e.rot_deg, e.n, e.missing), (rel[0][scored], rel[1][scored])


def one_case(name: str, share: float, whole: tuple[np.ndarray, np.ndarray],
             rel: tuple[np.ndarray, np.ndarray], log: LaserLog) -> dict[str, object]:
    first, second = split(log, share)
    t0 = time.perf_counter()
    slam, _ = run_log(first, SlamOptions(method="graph"))
    mapping_s = time.perf_counter() - t0
    m = saved_map_of_log(slam, first, "graph", 0.05)
    inside = (rel[0][:, 0] >= second.times[0]) & (rel[0][:, 1] <= second.times[-1])
    rel2 = (rel[0][inside], rel[1][inside])
    run = localize_log(m, second)
    loc, scored = errors(run, rel2)
    g = relation_errors(*whole, *scored)  # on the relations the localization scored
    # the same map's scans where graph SLAM over the whole log put them: how much of the
    # error is the map's (its first half's loops closed by the second half, as a
    # localizer, which does not change the map, cannot)
    at_whole, _ = errors(localize_log(map_at(m, whole[1]), second), scored)
    cut, after = kidnapped(second)
    krun = localize_log(m, cut)
    refix = [f for f in krun.fixes if f >= after]
    # the pose after the new fix, against the undisturbed run's at the same stamps
    both = krun.localized & (krun.times >= (refix[0] if refix else np.inf))
    same = np.isin(run.times, krun.times[both]) & run.localized
    ref = dict(zip(run.times[same], run.poses[same], strict=True))
    off = [float(np.hypot(*(p[:2] - ref[t][:2]))) for t, p in
           zip(krun.times[both], krun.poses[both], strict=True) if t in ref]
    return {"case": f"{name}, split at {share:.0%}", "scans": f"{len(first)} + {len(second)}",
            "keyframes": len(m), "graph": (g.trans_m, g.rot_deg), "loc": loc,
            "at_whole": at_whole, "first_fix": run.first_fix_s(), "losses": len(run.losses),
            "share": float(run.localized.mean()), "placed": float(run.placed.mean()),
            "rt": second.duration_s / max(run.seconds, 1e-9), "mapping_s": mapping_s,
            "refix": None if not refix else refix[0] - after,
            "on_map": back_on_map(m, second, run, after),
            "refix_off": float(np.median(off)) if off else None}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--logs", default=",".join(LOGS), help="comma-separated")
    p.add_argument("--quick", action="store_true", help="the middle split of each log only")
    args = p.parse_args()
    names = args.logs.split(",")
    rows = []
    for name in names:
        log = read_log(DATA / name / LOGS[name])
        rel = read_relations(DATA / name / f"{name}.relations")
        res = run_log(log, SlamOptions(method="graph"))[1]
        whole = (res.times, res.poses)
        for case, share in CASES:
            if case == name and (share == 0.5 or not args.quick):
                rows.append(one_case(name, share, whole, rel, log))
                print(rows[-1], flush=True)

    cfg = MapLocalizationConfig()

    def f(v: object, fmt: str) -> str:
        return "-" if v is None else format(v, fmt)

    body = [
        "Each log split into two robots' logs at the share of its scans named; the first "
        "mapped by graph SLAM, the second's odometry moved by a rigid transform the method "
        "is not told and localized on the first's saved map from an unknown start. Relation "
        "errors (Kümmerle et al. 2009: mean translational m / rotational deg) on the "
        "relations within the second log that have both poses, beside graph SLAM run over "
        "the whole log on the same relations. Kidnapped: "
        f"the robot carried off for {KIDNAP_S:.0f} s from the second log's middle (those "
        "scans dropped, the wheel odometry after the gap going on from where it was before "
        "it, blind to the carry); time from the "
        "first scan after the gap to the new fix, the time "
        "until the robot is back on the map (the first scan, where the undisturbed run "
        f"placed it, with {cfg.min_on_map:.0%} of its returns on cells the map observed, "
        f"scoring {cfg.global_min_score} there as a global fix must: the map cannot fix "
        "it before), the time until one scan alone could be fixed (scoring so over all its "
        "returns, those off the map at 0, as the global search scores them), and the median "
        "distance of "
        "the poses after the fix from the undisturbed run's. Scans "
        "localized: tracked on the map online; placed: with a pose once the log is over "
        "(also those off the map or lost between tracked ones, by local SLAM and the "
        "alignment); the errors are the placed scans'. On a map at whole-log poses: the "
        "second log localized on the same map with its keyframes where graph SLAM over the "
        "whole log placed them (the first log's loops closed by the second, as "
        "localization, which does not change the map, cannot): what it gains over the "
        "localization's error is the map's own.", "",
        "| case | scans | keyframes | localization: trans / rot (relations, without pose) "
        "| graph SLAM, whole log | ratio | on a map at whole-log poses (ratio) | first fix "
        "| scans localized / placed | losses "
        "| x real time | kidnapped: new fix after | back on the map after | one scan "
        "fixable after | off by |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lt, lr, n, miss = r["loc"]  # type: ignore[misc]
        gt, gr = r["graph"]  # type: ignore[misc]
        wt = r["at_whole"][0]  # type: ignore[index]
        body.append(
            f"| {r['case']} | {r['scans']} | {r['keyframes']} | {lt:.4f} / {lr:.3f} ({n}, "
            f"{miss}) | {gt:.4f} / {gr:.3f} | {lt / gt:.2f} | {wt:.4f} ({wt / gt:.2f}) | "
            f"{f(r['first_fix'], '.1f')} s | "
            f"{r['share']:.1%} / {r['placed']:.1%} | {r['losses']} | {r['rt']:.0f} | "
            f"{f(r['refix'], '.1f')} s | {f(r['on_map'][0], '.1f')} s | "  # type: ignore[index]
            f"{f(r['on_map'][1], '.1f')} s | "  # type: ignore[index]
            f"{f(r['refix_off'], '.3f')} m |")
    print("\n".join(body))
    write_page("map_localization", "Localization only, on a saved map", body,
               mode(p, args, {"quick": "the middle split of each log only"}))


if __name__ == "__main__":
    main()
