"""Peer baselines for the SLAM benchmark, measured in the same run as chizu's numbers.

    .venv/bin/python tests/bench/slam_peers.py [--quick] [--peers karto,small_gicp,...]
                                               [--logs aces,...] [--out bench-out]

Peers, each run as sequential scan-matching odometry (no loop closing, no graph) on the four
Freiburg benchmark logs and scored with the relation metric of Kümmerle et al. 2009:

- ``karto``: OpenKarto's correlative scan matcher (PyPI ``karto-scanmatcher``, the
  ScanMatcher of OpenKarto with Python bindings) driven the way OpenKarto's
  ``Mapper::Process`` drives its sequential matcher: a scan is processed once the robot has
  moved ``MinimumTravelDistance`` or turned ``MinimumTravelHeading`` since the last processed
  scan; it is matched, starting from the odometry prediction, against the "running scans"
  (``ScanBufferSize`` / ``ScanBufferMaximumScanDistance``); scans in between follow
  odometry from the last matched pose. With loop closing off this is OpenKarto's front end.
  ``karto_rt40`` is the same with the laser's RangeThreshold raised from OpenKarto's 12 m
  to the reader's 40 m cap.
- ``small_gicp``: small_gicp GICP (2-D scans extruded to z in {-0.2..0.2}, as
  ``tests/bench/slam.py`` does) with the same motion filter, each processed scan aligned
  to a local map made of the last few processed scans (``small_gicp_prev``: the previous
  processed scan only; not run by default).
- ``odometry``: the log's odometry poses, as a floor.

``peer_odometry(log, name)`` returns ``(times (N,), poses (N, 3), seconds)`` for the peer
``name``; seconds is the wall time of the peer's work (log reading excluded), every
library single-threaded. Writes OUT/slam_peers.md and prints it.
"""

from __future__ import annotations

import argparse
import math
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from chizu.numeric.geometry import compose, invert, place, relative
from chizu.numeric.scan import LaserLog, Scan
from chizu.numeric.slam.datasets import slam_data_dir
from chizu.numeric.slam.evaluation import poses_at, relation_errors
from chizu.numeric.slam.logs import read_log, read_relations

DATA = slam_data_dir() or Path("../shared/data/slam")
LOGS = [("aces", "aces.recon.clf"), ("mit-csail", "mit-csail.clf"),
        ("fr079", "fr079.recon.clf"), ("fr-clinic", "fr-clinic.recon.clf")]

PeerResult = tuple[np.ndarray, np.ndarray, float]

# --- OpenKarto defaults (open_karto src/Mapper.cpp, Mapper::InitializeParameters, and
# include/open_karto/Karto.h, LaserRangeFinder) ----------------------------------------
#: MinimumTravelDistance (m), MinimumTravelHeading (rad), MinimumTimeInterval (s).
MIN_TRAVEL_M = 0.2
MIN_TRAVEL_HEADING_RAD = math.radians(10.0)
MIN_TIME_INTERVAL_S = 3600.0
#: ScanBufferSize, ScanBufferMaximumScanDistance (m): the running scans matched against.
SCAN_BUFFER_SIZE = 70
SCAN_BUFFER_MAX_DISTANCE_M = 20.0
#: LaserRangeFinder RangeThreshold (m); the Mapper also sizes the sequential matcher's
#: correlation grid with it (margin = RangeThreshold around the 0.3 m search window).
RANGE_THRESHOLD_M = 12.0
#: ScanMatcherConfig attribute -> OpenKarto default. The binding's own defaults differ on
#: the four marked ones (binding value in the comment); range_threshold (binding 40 m) is
#: set from RANGE_THRESHOLD_M.
KARTO_MATCHER: dict[str, float | bool] = {
    "search_size": 0.3,                                    # CorrelationSearchSpaceDimension
    "resolution": 0.01,                                    # CorrelationSearchSpaceResolution
    "smear_deviation": 0.03,                               # ...SmearDeviation
    "distance_variance_penalty": 0.3**2,                   # binding 0.5
    "angle_variance_penalty": math.radians(20.0) ** 2,     # binding 0.349 (20 deg, unsquared)
    "minimum_distance_penalty": 0.5,                       # binding 1.0 (= no distance penalty)
    "minimum_angle_penalty": 0.9,
    "use_response_expansion": False,                       # binding True
    "coarse_search_angle_offset": math.radians(20.0),      # CoarseSearchAngleOffset
    "coarse_angle_resolution": math.radians(2.0),          # CoarseAngleResolution
    # FineSearchAngleOffset (0.2 deg) is used by MatchScan as the fine *resolution*;
    # the fine search spans +- coarse_angle_resolution / 2.
    "fine_search_angle_resolution": math.radians(0.2),
}

# --- small_gicp ------------------------------------------------------------------------
#: Processed scans in the local map a new scan is aligned to (1 = previous scan only).
GICP_LOCAL_MAP_SCANS = 5
GICP_DOWNSAMPLE_M = 0.05
GICP_MAX_CORRESPONDENCE_M = 1.0
GICP_MAX_ITERATIONS = 40
_Z_LAYERS = (-0.2, -0.1, 0.0, 0.1, 0.2)


def _sensor_odom(scan: Scan) -> np.ndarray:
    return compose(scan.odom, scan.sensor_pose)


def moved_enough(last: tuple[float, np.ndarray] | None, t: float, sensor_odom: np.ndarray) -> bool:
    """OpenKarto's ``Mapper::HasMovedEnough`` on the sensor's odometric poses: ``last`` is
    (time, sensor odometric pose) of the last processed scan."""
    if last is None:
        return True
    t0, p0 = last
    if t - t0 >= MIN_TIME_INTERVAL_S:
        return True
    if abs(relative(p0, sensor_odom)[2]) >= MIN_TRAVEL_HEADING_RAD:
        return True
    d2 = float(np.sum((sensor_odom[:2] - p0[:2]) ** 2))
    return d2 >= MIN_TRAVEL_M**2 - 1e-6


def _predict(last_odom: np.ndarray, last_pose: np.ndarray, odom: np.ndarray) -> np.ndarray:
    """Odometry increment since the last processed scan applied to its corrected pose
    (OpenKarto: ``Transform(lastOdom, lastCorrected).TransformPose(odom)``)."""
    return compose(last_pose, relative(last_odom, odom))


def sequential(log: LaserLog,
               correct: Callable[[int, Scan, np.ndarray], np.ndarray]) -> PeerResult:
    """OpenKarto's sequential front end around a scan matcher: a scan is processed only
    when the sensor has moved enough since the last processed one (:func:`moved_enough`),
    starting from the odometry increment since then applied to that scan's corrected
    pose (:func:`_predict`); ``correct(i, scan, predicted)`` returns its corrected pose.
    The scans in between keep the prediction. Times the loop."""
    last: tuple[float, np.ndarray] | None = None
    last_odom = last_pose = np.zeros(3)
    poses = np.empty((len(log), 3))
    t_start = time.perf_counter()
    for i, scan in enumerate(log.scans):
        pose = scan.odom.copy() if last is None else _predict(last_odom, last_pose, scan.odom)
        s_odom = _sensor_odom(scan)
        if moved_enough(last, scan.t, s_odom):
            pose = correct(i, scan, pose)
            last, last_odom, last_pose = (scan.t, s_odom), scan.odom.copy(), pose
        poses[i] = pose
    return log.times, poses, time.perf_counter() - t_start


def raw_odometry(log: LaserLog) -> PeerResult:
    t0 = time.perf_counter()
    poses = log.odometry
    return log.times, poses, time.perf_counter() - t0


def _karto_ranges(scan: Scan, drop_beyond_m: float | None) -> list[float]:
    """Ranges for Karto. No-return beams (chizu's ``~valid``: the logs' 50 / 81.9 m codes
    and anything at or beyond the reader's 40 m cap) become NaN, which Karto skips both in
    the query lookup (``INVALID_SCAN``) and in the correlation grid -- how it sees the inf
    of a ROS driver; passed through, the codes would become phantom points at 50-82 m.
    Returns between RangeThreshold and 40 m are passed through, as OpenKarto matches its
    *unfiltered* point readings (``GetPointReadings()`` default), unless ``drop_beyond_m``
    is given (then they become NaN too)."""
    r = np.asarray(scan.ranges, dtype=float).copy()
    r[~scan.valid] = np.nan
    if drop_beyond_m is not None:
        r[r > drop_beyond_m] = np.nan
    return list(r.tolist())


def karto_odometry(log: LaserLog, range_threshold_m: float = RANGE_THRESHOLD_M,
                   drop_beyond_threshold: bool = False) -> PeerResult:
    """OpenKarto sequential scan matching (see the module doc) with the laser's
    RangeThreshold ``range_threshold_m``; ``drop_beyond_threshold`` removes returns beyond
    it instead of letting Karto match them as unfiltered points."""
    import karto_scanmatcher as ks

    cfg = ks.ScanMatcherConfig()
    for attr, value in KARTO_MATCHER.items():
        setattr(cfg, attr, value)
    cfg.range_threshold = range_threshold_m
    matcher = ks.Wrapper(cfg)
    drop = range_threshold_m if drop_beyond_threshold else None

    def ranges(scan: Scan) -> list[float]:
        return _karto_ranges(scan, drop)

    lasers: dict[tuple[int, float, float], Any] = {}
    running: list[Any] = []        # ks.LocalizedRangeScan; corrected_pose = sensor pose

    def correct(i: int, scan: Scan, pose: np.ndarray) -> np.ndarray:
        a = scan.angles
        key = (len(a), float(a[0]), float(a[1] - a[0]))
        if key not in lasers:
            lasers[key] = ks.LaserScanConfig(key[1], float(a[-1]), key[2], scan.min_range_m,
                                             scan.max_range_m, range_threshold_m, "laser")
        sensor = compose(pose, scan.sensor_pose)
        kscan = ks.LocalizedRangeScan(lasers[key], ranges(scan),
                                      ks.Pose2(*_sensor_odom(scan)), ks.Pose2(*sensor), i,
                                      scan.t)
        if running:  # not the first processed scan
            best = matcher.match_scan(kscan, running, True, True).best_pose
            sensor = np.array([best.x, best.y, best.yaw])
            kscan.corrected_pose = ks.Pose2(*sensor)
            pose = compose(sensor, invert(scan.sensor_pose))
        running.append(kscan)
        while len(running) > 1:
            front, back = running[0].corrected_pose, running[-1].corrected_pose
            d2 = (front.x - back.x) ** 2 + (front.y - back.y) ** 2
            if len(running) <= SCAN_BUFFER_SIZE and d2 <= SCAN_BUFFER_MAX_DISTANCE_M**2 - 1e-6:
                break
            running.pop(0)
        return pose

    return sequential(log, correct)


def _extrude(xy: np.ndarray) -> np.ndarray:
    """2-D points -> 3-D wall strips (z = -0.2..0.2) so GICP covariances are defined."""
    return np.vstack([np.column_stack([xy, np.full(len(xy), z)]) for z in _Z_LAYERS])


def _t4(p: np.ndarray) -> np.ndarray:
    c, s = math.cos(p[2]), math.sin(p[2])
    t = np.eye(4)
    t[:2, :2] = [[c, -s], [s, c]]
    t[:2, 3] = p[:2]
    return t


def gicp_odometry(log: LaserLog, local_map_scans: int = GICP_LOCAL_MAP_SCANS) -> PeerResult:
    """small_gicp GICP sequential odometry (see the module doc): each processed scan is
    aligned to the last ``local_map_scans`` processed scans, placed at their estimated
    poses, starting from the odometry prediction."""
    import small_gicp as sg

    keyframes: list[np.ndarray] = []      # world-frame 2-D points of processed scans

    def correct(i: int, scan: Scan, pose: np.ndarray) -> np.ndarray:
        xy, _ = scan.points()
        if keyframes and len(xy) >= 10:
            target = np.vstack(keyframes[-local_map_scans:]) - pose[:2]   # near the origin
            init = pose.copy()
            init[:2] = 0.0
            res = sg.align(_extrude(target), _extrude(xy), _t4(init), registration_type="GICP",
                           downsampling_resolution=GICP_DOWNSAMPLE_M,
                           max_correspondence_distance=GICP_MAX_CORRESPONDENCE_M,
                           num_threads=1, max_iterations=GICP_MAX_ITERATIONS)
            t = res.T_target_source
            pose = np.array([pose[0] + t[0, 3], pose[1] + t[1, 3],
                             math.atan2(t[1, 0], t[0, 0])])
        keyframes.append(place(xy, pose))
        if len(keyframes) > local_map_scans:
            keyframes.pop(0)
        return pose

    return sequential(log, correct)


#: Peers run by default, in table order. ``karto`` uses OpenKarto's defaults throughout;
#: ``karto_rt40`` only raises RangeThreshold to the reader's 40 m cap (what slam_toolbox
#: users do with ``max_laser_range``); ``karto_drop12`` (not run by default) drops returns
#: beyond 12 m instead of matching them as unfiltered points.
PEERS: dict[str, Callable[[LaserLog], PeerResult]] = {
    "karto": karto_odometry,
    "karto_rt40": lambda log: karto_odometry(log, range_threshold_m=40.0),
    "small_gicp": gicp_odometry,
    "odometry": raw_odometry}
EXTRA_PEERS: dict[str, Callable[[LaserLog], PeerResult]] = {
    "karto_drop12": lambda log: karto_odometry(log, drop_beyond_threshold=True),
    "small_gicp_prev": lambda log: gicp_odometry(log, local_map_scans=1)}


def peer_odometry(log: LaserLog, name: str) -> PeerResult:
    """``(times (N,), poses (N, 3), seconds)`` of the peer ``name`` (a key of PEERS or
    EXTRA_PEERS)."""
    return {**PEERS, **EXTRA_PEERS}[name](log)


def _row(name: str, log: LaserLog, peer: str, times: np.ndarray, poses: np.ndarray,
         wall: float, cpu: float, rt: np.ndarray, rd: np.ndarray) -> str:
    e = relation_errors(times, poses, rt, rd)
    (p1, ok1), (p2, ok2) = (poses_at(times, poses, col, 0.1) for col in rt.T)
    ok = ok1 & ok2
    err = compose(invert(rd[ok]), relative(p1[ok], p2[ok]))  # inv(ref) * est
    median = float(np.median(np.hypot(err[:, 0], err[:, 1])))
    rt_x = f"{log.duration_s / wall:.0f}" if wall > 0.01 else "-"
    return (f"| {name} | {len(log)} | {log.duration_s:.0f} | {peer} | "
            f"{e.trans_m:.3f} ± {e.trans_std_m:.3f} | {median:.3f} | "
            f"{e.rot_deg:.2f} ± {e.rot_std_deg:.2f} | {wall:.1f} | {cpu:.1f} | {rt_x} |")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="first 1500 scans of each log")
    ap.add_argument("--peers", default=",".join(PEERS),
                    help=f"comma-separated, from {[*PEERS, *EXTRA_PEERS]}")
    ap.add_argument("--logs", default=",".join(n for n, _ in LOGS))
    ap.add_argument("--out", default="bench-out")
    args = ap.parse_args()
    peers = [p for p in args.peers.split(",") if p]
    unknown = set(peers) - set(PEERS) - set(EXTRA_PEERS)
    if unknown:
        ap.error(f"unknown peers {sorted(unknown)}; choose from {[*PEERS, *EXTRA_PEERS]}")
    out = Path(args.out)
    out.mkdir(exist_ok=True)
    scope = "quick: first 1500 scans per log" if args.quick else "full logs"
    karto = ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                      for k, v in KARTO_MATCHER.items())
    lines = [
        f"# Peer baselines, sequential scan-matching odometry ({scope})", "",
        "Relation errors (Kümmerle et al. 2009) over all relations of each log, mean ± std "
        "(median trans in its own column); wall and CPU time of the peer's own work (log "
        "reading excluded), single thread; x real time = log duration / wall time. "
        f"Machine: {os.cpu_count()} CPUs; CPU time below wall time means other processes "
        "competed for them.", "",
        f"- karto: OpenKarto ScanMatcher (karto-scanmatcher), OpenKarto defaults {karto}, "
        f"RangeThreshold={RANGE_THRESHOLD_M:g} m; MinimumTravelDistance={MIN_TRAVEL_M:g} m, "
        f"MinimumTravelHeading={math.degrees(MIN_TRAVEL_HEADING_RAD):g} deg, "
        f"ScanBufferSize={SCAN_BUFFER_SIZE}, "
        f"ScanBufferMaximumScanDistance={SCAN_BUFFER_MAX_DISTANCE_M:g} m. No-return beams "
        "are passed as NaN; returns beyond RangeThreshold are matched (OpenKarto uses its "
        "unfiltered points).",
        "- karto_rt40: the same with RangeThreshold = 40 m (the reader's range cap).",
        f"- small_gicp: GICP, scans extruded to z in {list(_Z_LAYERS)}, local map of the last "
        f"{GICP_LOCAL_MAP_SCANS} processed scans, downsampling {GICP_DOWNSAMPLE_M:g} m, max "
        f"correspondence {GICP_MAX_CORRESPONDENCE_M:g} m, {GICP_MAX_ITERATIONS} iterations; "
        "same motion filter.",
        "- odometry: the log's odometry.", "",
        "| log | scans | duration (s) | peer | trans (m) | median trans (m) | rot (deg) "
        "| wall (s) | CPU (s) | x real time |",
        "|---|---|---|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    wanted = args.logs.split(",")
    for name, f in LOGS:
        if name not in wanted:
            continue
        log = read_log(DATA / name / f)
        if args.quick:
            log = log.head(1500)
        rt, rd = read_relations(DATA / name / f"{name}.relations")
        keep = (rt[:, 1] <= log.scans[-1].t + 1e-6) & (rt[:, 0] >= log.scans[0].t - 1e-6)
        rt, rd = rt[keep], rd[keep]
        for peer in peers:
            cpu0 = time.process_time()
            times, poses, wall = peer_odometry(log, peer)
            cpu = time.process_time() - cpu0
            lines.append(_row(name, log, peer, times, poses, wall, cpu, rt, rd))
            print(lines[-1], flush=True)
    (out / "slam_peers.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
