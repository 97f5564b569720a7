"""SLAM benchmark: relation errors on the Freiburg logs for every method and the peers,
the stripe corridor, scan-pair alignment against small_gicp, and where the time goes.

    .venv/bin/python tests/bench/slam.py [--quick] [--logs aces,...] [--methods graph,...]
                                         [--seeds 0,1,2] [--skip-extras] [--out bench-out]

Every (log, method) runs in a fresh process, one after the other, so that its peak memory
is its own and the peers (OpenKarto's matcher, small_gicp; tests/bench/slam_peers.py)
are timed on the same machine in the same run. --quick runs the first 1500 scans of each
log (relations inside that span only). --seeds 0,1,2 runs the particle filters once per
seed (the others once) and adds a table of the mean and the worst seed. Writes
docs/results/slam.md (the tables) and, under --out (bench-out), slam.json, the
trajectories (TUM; traj-LOG-METHOD-sN.tum for seed N > 0), the maps of graph SLAM and of
the improved RBPF's seed 0, and maps-LOG.png (the two side by side).
"""

from __future__ import annotations

import argparse
import cProfile
import json
import pstats
import subprocess
import sys
import time
from concurrent.futures import Executor
from pathlib import Path
from typing import Any

import numpy as np

from chizu.numeric.geometry import compose, invert, relative, wrap_angle
from chizu.numeric.scan import LaserLog
from chizu.numeric.slam.datasets import slam_data_dir
from chizu.numeric.slam.evaluation import (
    LOCAL_MAX_GAP_S,
    LOCAL_ODOM_OK_M,
    LOCAL_OFF_M,
    local_failures,
    relation_errors,
)
from chizu.numeric.slam.logs import read_log, read_relations
from chizu.numeric.slam.matching.intensity_icp import IcpConfig, Reference, intensity_icp
from chizu.numeric.slam.runner import SlamOptions, SlamResult, run_log
from chizu.numeric.slam.simulate import simulated_log

DATA = slam_data_dir() or Path("../shared/data/slam")
LOGS = [("aces", "aces.recon.clf"), ("mit-csail", "mit-csail.clf"),
        ("fr079", "fr079.recon.clf"), ("fr-clinic", "fr-clinic.recon.clf")]
#: SOURCES.md, abs trans (m): SM and RBPF (GMapping) from a secondary source quoting
#: Kümmerle et al. 2009; Graph Mapping and Cartographer from Hess et al. 2016, Table II.
PUBLISHED = {"aces": (0.173, 0.060, 0.044, 0.0375), "mit-csail": (0.106, 0.049, 0.004, 0.0319),
             "fr079": (0.258, 0.061, 0.056, 0.0452), "fr-clinic": (0.434, 0.637, 0.143, 0.1078)}
#: (label, SlamOptions fields) of chizu's methods; "karto" and "small_gicp" are the peers
#: of tests/bench/slam_peers.py, run the same way.
METHODS: dict[str, dict[str, str]] = {
    "odom": {"method": "odom"}, "icp": {"method": "icp"},
    "gated (icp)": {"method": "gated-icp"}, "gated": {"method": "gated"},
    "rbpf (paper proposal)": {"method": "rbpf", "proposal": "odometry"},
    "rbpf (improved)": {"method": "rbpf", "proposal": "improved"},
    "graph": {"method": "graph"},
    "karto": {}, "small_gicp": {}}
LOOP_GAP_S = 60.0
#: one run's figures (slam.json): numbers, names, the local failures' times, and None
#: where a method has no such figure
Row = dict[str, Any]
#: sequential scan-matching peers run by tests/bench/slam_peers.py
PEERS = ("karto", "small_gicp")
#: the methods whose maps are written (at 5 cm) and shown side by side
SHOWN = ("graph", "rbpf (improved)")


def estimate(log: LaserLog, label: str, seed: int) -> tuple[np.ndarray, np.ndarray, float,
                                                            Any, SlamResult | None]:
    """``(times, poses, seconds, estimator, result)`` of method ``label`` on ``log``; the
    peers give no estimator and no result."""
    from tests.bench.slam_peers import peer_odometry

    if label in PEERS:
        times, poses, seconds = peer_odometry(log, label)
        return times, poses, seconds, None, None
    # maps at 5 cm for the methods whose maps are shown; the others drift over hundreds of
    # metres on some logs, so their (unused) maps are kept coarse
    opts = SlamOptions(map_resolution_m=0.05 if label in SHOWN else 0.5,  # type: ignore[arg-type]
                       seed=seed, **METHODS[label])
    slam, res = run_log(log, opts)
    return res.times, res.poses, res.seconds, slam, res


def one_run(name: str, label: str, quick: bool, out: Path,
            seed: int = 0) -> Row:
    """Run ``label`` over log ``name`` in this process: relation errors on all relations
    and on the loop-spanning ones (time gap > 60 s), seconds, real-time factor, peak
    memory of this process; writes the trajectory and (seed 0) the map under ``out``."""
    import resource

    from chizu.numeric.slam.logs import write_tum

    f = dict(LOGS)[name]
    log = read_log(DATA / name / f)
    if quick:
        log = log.head(1500)
    rt, rd = read_relations(DATA / name / f"{name}.relations")
    keep = (rt[:, 1] <= log.scans[-1].t + 1e-6) & (rt[:, 0] >= log.scans[0].t - 1e-6)
    rt, rd = rt[keep], rd[keep]
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    slug = label.split()[0] + ("-improved" if "improved" in label else "") + (
        "-icp" if "(icp)" in label else "")
    slug += f"-s{seed}" if seed else ""
    times, poses, seconds, slam, res = estimate(log, label, seed)
    online = float("nan")  # before the end-of-run alignment, where there is one
    if res is not None and res.online_poses is not None:
        online = relation_errors(times, res.online_poses, rt, rd).trans_m
    if res is not None and label in SHOWN and not seed:
        (out / f"map-{name}-{slug}.png").write_bytes(res.map.to_png())
        (out / f"map-{name}-{slug}.pgm").write_bytes(res.map.to_pgm())
    write_tum(out / f"traj-{name}-{slug}.tum", times, poses)
    e = relation_errors(times, poses, rt, rd)
    fails = local_failures(times, poses, log.times, log.odometry, rt, rd)
    starts = getattr(slam, "loop_starts", None)
    loop = (rt[:, 1] - rt[:, 0]) > LOOP_GAP_S
    el = relation_errors(times, poses, rt[loop], rd[loop]) if np.any(loop) else None
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    nan = float("nan")
    return {"log": name, "method": label, "seed": seed, "scans": len(log),
            "duration_s": log.duration_s,
            "trans": e.trans_m, "trans_std": e.trans_std_m, "rot": e.rot_deg,
            "trans_online": online,
            "rot_std": e.rot_std_deg, "n": e.n,
            "loop_trans": el.trans_m if el else nan,
            "loop_trans_std": el.trans_std_m if el else nan,
            "loop_rot": el.rot_deg if el else nan, "loop_n": el.n if el else 0,
            "seconds": seconds, "realtime": log.duration_s / max(seconds, 1e-9),
            "peak_rss_mb": rss / 1024.0, "peak_rss_base_mb": base / 1024.0,
            "closures": len(getattr(slam, "closures", [])), "local_failures": len(fails),
            # the RBPF's resamplings and accepted loop starts (None for other methods)
            "resamples": getattr(slam, "resamples", None),
            "loop_starts": None if starts is None else len(starts),
            "local_failure_t": [round(float(x - log.times[0]), 1) for x in fails.t1]}


def run_isolated(name: str, label: str, quick: bool, out: Path,
                 seed: int = 0) -> Row:
    """:func:`one_run` in a fresh process, so that peak memory is this run's alone."""
    cmd = [sys.executable, str(Path(__file__)), "--one", name, label, "--out", str(out),
           "--seed", str(seed)]
    if quick:
        cmd.append("--quick")
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=Path(__file__).parents[2])
    if r.returncode != 0:
        raise RuntimeError(f"{name} / {label} / seed {seed} failed:\n{r.stderr[-3000:]}")
    return dict(json.loads(r.stdout.strip().splitlines()[-1]))


def maps_figure(out: Path, names: list[str]) -> None:
    """Per log, the improved RBPF's map beside the graph SLAM map."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from PIL import Image

    titles = {"rbpf-improved": "RBPF, improved proposal (512 particles)",
              "graph": "graph SLAM"}
    for name in names:
        have = [(out / f"map-{name}-{m}.png", t) for m, t in titles.items()
                if (out / f"map-{name}-{m}.png").exists()]
        if not have:
            continue
        fig, axes = plt.subplots(1, len(have), figsize=(7 * len(have), 7), squeeze=False)
        for ax, (p, title) in zip(axes[0], have, strict=True):
            ax.imshow(Image.open(p))
            ax.set_title(f"{name}: {title}")
            ax.axis("off")
        fig.tight_layout()
        fig.savefig(out / f"maps-{name}.png", dpi=110)
        plt.close(fig)


def stochastic(label: str) -> bool:
    """Whether a method's result depends on its seed (the particle filters)."""
    return label.startswith("rbpf")


def accuracy(quick: bool, out: Path, names: list[str], labels: list[str],
             lines: list[str], executor: Executor | None = None, seeds: tuple[int, ...] = (0,),
             ) -> list[Row]:
    """Every (log, method) run, each in a fresh process: one after the other here, or
    all at once on ``executor`` (a Dask cluster's, :mod:`chizu.service.executors`; its
    workers need this repository at the same path). Runs side by side share the cores:
    their times and real-time factors are then not the figures of a run alone. The
    particle filters run once per seed of ``seeds``, the others once."""
    lines += ["## Relation errors (Kümmerle et al. 2009), mean ± std, all relations and "
              f"loop-spanning ones (time gap > {LOOP_GAP_S:.0f} s); local failures: "
              f"relations shorter than {LOCAL_MAX_GAP_S:g} s off by more than "
              f"{LOCAL_OFF_M:g} m where the raw odometry is within {LOCAL_ODOM_OK_M:g} m "
              "(their start times in slam.json)", "",
              "| log | method | seed | trans (m) | before alignment (m) | rot (deg) | "
              "loop trans (m) | loop rot (deg) | local failures | time (s) | x real time | "
              "peak RSS (MB) |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    rows = []
    runs = [(n, m, sd) for n in names for m in labels
            for sd in (seeds if stochastic(m) else (0,))]
    pending = {run: executor.submit(run_isolated, run[0], run[1], quick, out, run[2])
               for run in runs} if executor is not None else {}
    for name in names:
        for run in [r for r in runs if r[0] == name]:
            label = run[1]
            r = (pending[run].result() if pending
                 else run_isolated(name, label, quick, out, run[2]))
            rows.append(r)
            with (out / "slam-rows.jsonl").open("a") as f:
                f.write(json.dumps(r) + "\n")
            lines.append(f"| {name} | {label} | {run[2]} | "
                         f"{r['trans']:.3f} ± {r['trans_std']:.3f} | "
                         f"{float(r.get('trans_online', 'nan')):.3f} | "
                         f"{r['rot']:.2f} ± {r['rot_std']:.2f} | {r['loop_trans']:.3f} ± "
                         f"{r['loop_trans_std']:.3f} | {r['loop_rot']:.2f} | "
                         f"{r['local_failures']} | {r['seconds']:.1f} | "
                         f"{r['realtime']:.1f} | {r['peak_rss_mb']:.0f} |")
            print(lines[-1], flush=True)
        sm, rb, gm, carto = PUBLISHED[name]
        lines.append(f"| {name} | published SM / GMapping / Graph Mapping / Cartographer | | "
                     f"{sm} / {rb} / {gm} / {carto} | | | | | | | | |")
    (out / "slam.json").write_text(json.dumps(rows, indent=1))
    if len(seeds) > 1:
        seed_summary(rows, lines)
    return rows


def seed_summary(rows: list[Row], lines: list[str]) -> None:
    """Per (log, particle filter): the relation error over the seeds, against GMapping's
    published figure."""
    lines += ["", "## Particle filters over seeds: translational relation error (m)", "",
              "| log | method | seeds | mean over seeds | worst seed | loop, worst seed | "
              "GMapping (published) |", "|---|---|---|---|---|---|---|"]
    for name in dict.fromkeys(str(r["log"]) for r in rows):
        for label in dict.fromkeys(str(r["method"]) for r in rows if stochastic(str(r["method"]))):
            rs = [r for r in rows if r["log"] == name and r["method"] == label]
            if not rs:
                continue
            t = np.array([float(r["trans"]) for r in rs])
            w = rs[int(np.argmax(t))]
            lines.append(f"| {name} | {label} | {', '.join(str(r['seed']) for r in rs)} | "
                         f"{t.mean():.3f} | {t.max():.3f} (seed {w['seed']}) | "
                         f"{float(w['loop_trans']):.3f} | {PUBLISHED[name][1]} |")
            print(lines[-1], flush=True)


def corridor(lines: list[str]) -> None:
    log = simulated_log("corridor", seed=0)
    truth = log.truth
    assert truth is not None
    lines += ["", "## Stripe corridor (34 m, odometry under-reads distance by 5 %)", "",
              "| method | alpha | final along-corridor error (m) | mean position error (m) |",
              "|---|---|---|---|"]
    for method, alpha in [("odom", 0.0), ("icp", 0.0), ("icp", 1e-9), ("gated-icp", 0.0),
                          ("gated-icp", 1e-9), ("gated", 0.0), ("gated", 1e-9), ("rbpf", 0.0),
                          ("rbpf", 1e-9)]:
        _, res = run_log(log, SlamOptions(method=method, alpha=alpha))  # type: ignore[arg-type]
        err = np.hypot(*(res.poses[:, :2] - truth[:, :2]).T)
        lines.append(f"| {method} | {alpha:g} | {res.poses[-1, 0] - truth[-1, 0]:+.2f} | "
                     f"{err.mean():.2f} |")
        print(lines[-1], flush=True)


def peers(lines: list[str], pairs_per_log: int) -> None:
    import small_gicp

    lines += ["", f"## Scan pairs vs small_gicp ({pairs_per_log} relation pairs per log, "
              "initial guess = odometry, single thread)", "",
              "| aligner | trans err (m) | rot err (deg) | ms / pair | time vs small_gicp GICP |",
              "|---|---|---|---|---|"]
    results: dict[str, list[tuple[float, float, float]]] = {}
    for name, f in LOGS:
        log = read_log(DATA / name / f)
        rt, rd = read_relations(DATA / name / f"{name}.relations")
        rng = np.random.default_rng(0)
        pick = rng.choice(len(rt), size=min(pairs_per_log, len(rt)), replace=False)
        times = log.times
        for k in pick:
            i1 = int(np.argmin(np.abs(times - rt[k, 0])))
            i2 = int(np.argmin(np.abs(times - rt[k, 1])))
            if abs(times[i1] - rt[k, 0]) > 0.1 or abs(times[i2] - rt[k, 1]) > 0.1:
                continue
            sa, sb = log.scans[i1], log.scans[i2]
            xa, _ = sa.points()
            xb, _ = sb.points()
            if len(xa) < 20 or len(xb) < 20:
                continue
            init = relative(sa.odom, sb.odom)
            for label in ALIGNERS:
                t0 = time.perf_counter()
                est = align(label, small_gicp, xa, xb, init)
                dt = time.perf_counter() - t0
                err = compose(invert(rd[k]), est)
                results.setdefault(label, []).append(
                    (float(np.hypot(err[0], err[1])), float(np.degrees(abs(err[2]))), dt))
    base = np.mean([r[2] for r in results["small_gicp GICP"]])
    for label, errs in results.items():
        a = np.array(errs)
        lines.append(f"| {label} | {a[:, 0].mean():.3f} (median {np.median(a[:, 0]):.3f}) | "
                     f"{a[:, 1].mean():.2f} | {1000 * a[:, 2].mean():.2f} | "
                     f"{a[:, 2].mean() / base:.2f}x |")
        print(lines[-1], flush=True)


def reference_lattice(lines: list[str]) -> None:
    """How the reference relations were made: the share of short relations (time gap
    under LOOP_GAP_S) whose translation differs from the raw odometry's by a point of a
    5 cm lattice (|d| = 0.05 * hypot(i, j) within 1 mm). Where most do, the references
    are odometry corrected in 5 cm steps, so a trajectory exact to the real motion still
    differs from them by the lattice's rounding (about 0.05 * 0.383 = 0.019 m on average
    if that rounding is uniform over a cell), and only an estimate made with the same
    steps can score far below that.

    The rotations too: the reference's rotation minus the odometry's, modulo 0.25°, is
    counted in 0.005° bins; the column is the share in the two fullest bins (2 × 2 %
    if it were spread evenly). A large share says the rotations were corrected in steps
    as well, and a published rotational error below the step says the estimate made the
    same steps as the references, not that the motion can be known that well."""
    lines += ["", "## Reference relations: translation vs raw odometry on a 5 cm lattice", "",
              "| log | short relations | on the lattice | of them exactly odometry | "
              "rotation vs odometry in the two fullest 0.005° bins mod 0.25° |",
              "|---|---|---|---|---|"]
    norms = np.array(sorted({0.05 * float(np.hypot(i, j)) for i in range(12)
                             for j in range(12)}))
    for name, f in LOGS:
        log = read_log(DATA / name / f)
        rt, rd = read_relations(DATA / name / f"{name}.relations")
        short = np.abs(rt[:, 1] - rt[:, 0]) < LOOP_GAP_S
        i1 = np.clip(np.searchsorted(log.times, rt[short, 0] - 1e-4), 0, len(log.times) - 1)
        i2 = np.clip(np.searchsorted(log.times, rt[short, 1] - 1e-4), 0, len(log.times) - 1)
        odom = np.array([s.odom for s in log.scans])
        od = relative(odom[i1], odom[i2])
        d = rd[short, :2] - od[:, :2]
        n = np.hypot(d[:, 0], d[:, 1])
        on = np.min(np.abs(n[:, None] - norms[None, :]), axis=1) < 1e-3
        rot = np.abs(np.degrees(wrap_angle(rd[short, 2] - od[:, 2])))
        bins = np.bincount(np.floor((rot % 0.25) / 0.005).astype(int), minlength=50)
        two = np.sort(bins)[-2:].sum() / max(len(rot), 1)
        lines.append(f"| {name} | {len(n)} | {100 * on.mean():.1f} % | "
                     f"{100 * (n < 1e-3).mean():.1f} % | {100 * two:.1f} % |")
        print(lines[-1], flush=True)


def reference_scan_fit(lines: list[str]) -> None:
    """Whether the reference relations agree with the scans: for each relation shorter
    than 5 s, scan B placed by the reference relation and by the raw odometry's in a
    probability grid of scan A (5 cm, hit 0.7 / miss 0.4, neighbouring returns joined
    into surfaces); the score is the mean cell probability under B's returns. A
    reference *contradicted* by the scans scores 0.05 less than the odometry while
    correcting it by at least 0.1 m or 2°; one that *improves* on it scores 0.05 more.
    Where references are contradicted in stretches, every method's relation error there
    (chizu's and the published ones alike) carries the references' own error."""
    from chizu.numeric.probability_grid import GridConfig, ProbabilityGrid
    from chizu.numeric.slam.keyframes import connect_returns
    from chizu.numeric.slam.matching.correlative import PrecomputedGrid

    lines += ["", "## Reference relations against the scans (relations under 5 s)", "",
              "| log | relations | mean score: reference / odometry | reference improves "
              "on odometry | reference contradicted by the scans | contradicted at (s) |",
              "|---|---|---|---|---|---|"]
    for name, f in LOGS:
        log = read_log(DATA / name / f)
        rt, rd = read_relations(DATA / name / f"{name}.relations")
        t, odom = log.times, log.odometry
        rows = []
        for (a, b), r in zip(rt[rt[:, 1] - rt[:, 0] < 5.0], rd[rt[:, 1] - rt[:, 0] < 5.0],
                             strict=True):
            ia, ib = np.clip(np.searchsorted(t, [a - 1e-4, b - 1e-4]), 0, len(t) - 1)
            xa, xb = log.scans[ia].points()[0], log.scans[ib].points()[0]
            if len(xa) < 20 or len(xb) < 20:
                continue
            g = ProbabilityGrid(GridConfig(resolution_m=0.05, p_hit=0.7, p_miss=0.4))
            g.insert(np.zeros(2), xa, None,
                     connect_returns(xa, None, 0.5, 0.025)[0][len(xa):])
            o = relative(odom[ia], odom[ib])
            grid = PrecomputedGrid(g, depth=0)  # the grid itself, for its score()
            sr, so = (grid.score(xb, x) for x in (r, o))
            fix = max(float(np.hypot(*(r[:2] - o[:2]))) / 0.1,
                      float(np.degrees(abs(wrap_angle(r[2] - o[2])))) / 2.0)
            rows.append((a - t[0], sr, so, fix))
        rr = np.array(rows)
        bad = (rr[:, 1] < rr[:, 2] - 0.05) & (rr[:, 3] >= 1.0)
        good = rr[:, 1] > rr[:, 2] + 0.05
        at = ", ".join(str(int(x)) for x in np.sort(rr[bad, 0])[:12])
        at += " ..." if bad.sum() > 12 else ""
        lines.append(f"| {name} | {len(rr)} | {rr[:, 1].mean():.3f} / {rr[:, 2].mean():.3f} | "
                     f"{100 * good.mean():.1f} % | {100 * bad.mean():.1f} % | {at} |")
        print(lines[-1], flush=True)


ALIGNERS = ["Intensity-ICP point (eq. 2)", "Intensity-ICP point-to-line", "small_gicp GICP",
            "small_gicp ICP", "small_gicp PLANE_ICP"]


def align(label: str, sg, xa: np.ndarray, xb: np.ndarray,  # type: ignore[no-untyped-def]
          init: np.ndarray) -> np.ndarray:
    """Pose of scan b in scan a's frame by the aligner ``label``."""
    if label.startswith("Intensity-ICP"):
        cfg = IcpConfig(metric="line" if "line" in label else "point")
        return intensity_icp(Reference(xa, None, 0.0), xb, None, init, cfg).pose
    return _sg(sg, label.split()[-1], xa, xb, init)


def _sg(sg, kind: str, xa: np.ndarray, xb: np.ndarray, init: np.ndarray) -> np.ndarray:  # type: ignore[no-untyped-def]
    from tests.bench.slam_peers import _extrude, _t4

    r = sg.align(_extrude(xa), _extrude(xb), _t4(init), registration_type=kind,
                 downsampling_resolution=0.05, max_correspondence_distance=1.0, num_threads=1,
                 max_iterations=40)
    t = r.T_target_source
    return np.array([t[0, 3], t[1, 3], np.arctan2(t[1, 0], t[0, 0])])


def profile(lines: list[str]) -> None:
    log = read_log(DATA / "mit-csail" / "mit-csail.clf").head(600)
    for label in ("rbpf (improved)", "graph"):
        prof = cProfile.Profile()
        prof.enable()
        _, res = run_log(log, SlamOptions(**METHODS[label]))  # type: ignore[arg-type]
        prof.disable()
        st = pstats.Stats(prof)
        rows = sorted(((v[3], k) for k, v in st.stats.items()),  # type: ignore[attr-defined]
                      key=lambda r: -r[0])
        lines += ["", f"## Where the time goes: {label} (mit-csail, 600 scans, "
                  f"{res.seconds:.1f} s; cumulative share of the run)", ""]
        seen = 0
        for cum, (fname, _line, func) in rows:
            if any(s in fname for s in ("numeric/slam", "numeric/geometry")) and seen < 8:
                lines.append(f"- `{Path(fname).name}:{func}`: {100 * cum / res.seconds:.0f} %")
                seen += 1


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default="bench-out")
    ap.add_argument("--logs", default=",".join(n for n, _ in LOGS))
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--one", nargs=2, metavar=("LOG", "METHOD"), help=argparse.SUPPRESS)
    ap.add_argument("--seed", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--seeds", default="0",
                    help="seeds of the particle filters, e.g. 0,1,2 (one run per seed and log; "
                         "a table of the mean and worst seed)")
    ap.add_argument("--skip-extras", action="store_true",
                    help="only the relation-error table (no corridor, pairs, profile)")
    ap.add_argument("--local-workers", type=int, default=0,
                    help="run the (log, method) runs on a Dask LocalCluster of N worker "
                         "processes (times are then shared-core times)")
    ap.add_argument("--scheduler", default=None,
                    help="an existing Dask scheduler (or CHIZU_DASK_SCHEDULER)")
    return ap


#: what the options that differ from `make bench` change, in words (the results page)
EXPLAIN = {"quick": "the first 1500 scans of each log (relations inside that span only) "
                    "and 60 scan pairs per log instead of 200",
           "skip_extras": "the relation-error table only",
           "local_workers": "runs side by side: their times are shared-core times"}


def main() -> None:
    from chizu.service.executors import batch_executor
    from tests.bench.results import mode, write_page

    ap = parser()
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(exist_ok=True)
    if args.one:
        print(json.dumps(one_run(args.one[0], args.one[1], args.quick, out, args.seed)))
        return
    names = args.logs.split(",")
    lines: list[str] = []
    with batch_executor(args.scheduler, args.local_workers) as ex:
        if ex is not None:
            lines += ["Runs side by side on Dask: times are shared-core times.", ""]
        accuracy(args.quick, out, names, args.methods.split(","), lines, ex,
                 tuple(dict.fromkeys(int(x) for x in args.seeds.split(","))))
    maps_figure(out, names)
    if not args.skip_extras:
        corridor(lines)
        reference_lattice(lines)
        reference_scan_fit(lines)
        peers(lines, 60 if args.quick else 200)
        profile(lines)
    lines += ["", f"Raw outputs in {out}/: slam.json (every run's figures), the trajectories "
              "(TUM), the maps of graph SLAM and the improved RBPF, maps-LOG.png."]
    print("\n".join(lines))
    write_page("slam", "SLAM benchmark: the Freiburg logs", lines,
               mode(ap, args, EXPLAIN, ignore=("out", "one", "seed", "scheduler")))


if __name__ == "__main__":
    if __package__ in (None, ""):  # run as a script: make `tests.bench` importable
        sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    main()
