"""SLAM benchmark (issue 4): relation errors on the Freiburg logs, the stripe corridor,
scan-pair alignment against small_gicp, and RBPF throughput.

    .venv/bin/python tests/bench/slam.py [--quick] [--out bench-out]

--quick runs the first 1500 scans of each log (relations inside that span only).
Writes OUT/slam.md (the tables) and prints them.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time
from pathlib import Path

import numpy as np

from numeric.geometry import compose, relative
from numeric.slam.datasets import slam_data_dir
from numeric.slam.evaluation import relation_errors
from numeric.slam.intensity_icp import IcpConfig, Reference, intensity_icp
from numeric.slam.logs import read_log, read_relations
from numeric.slam.runner import SlamOptions, run_log
from numeric.slam.simulate import simulated_log

DATA = slam_data_dir() or Path("../shared/data/slam")
LOGS = [("aces", "aces.recon.clf"), ("mit-csail", "mit-csail.clf"),
        ("fr079", "fr079.recon.clf"), ("fr-clinic", "fr-clinic.recon.clf")]
#: SOURCES.md: abs trans (m) - SM / RBPF (GMapping) secondary source; Graph Mapping
#: and Cartographer from Hess et al. 2016, Table II.
PUBLISHED = {"aces": (0.173, 0.060, 0.044, 0.0375), "mit-csail": (0.106, 0.049, 0.004, 0.0319),
             "fr079": (0.258, 0.061, 0.056, 0.0452), "fr-clinic": (0.434, 0.637, 0.143, 0.1078)}
METHODS = [("odom", {}), ("icp", {}), ("gated", {}),
           ("rbpf", {"proposal": "odometry"}), ("rbpf", {"proposal": "gated-icp"})]


def accuracy(quick: bool, lines: list[str]) -> dict[str, float]:
    lines += ["## Relation errors (Kümmerle et al. 2009), mean ± std",
              "", "| log | scans | method | trans (m) | rot (deg) | time (s) | x real time |",
              "|---|---|---|---|---|---|---|"]
    rt_factor: dict[str, float] = {}
    for name, f in LOGS:
        log = read_log(DATA / name / f)
        if quick:
            log = log.head(1500)
        rt, rd = read_relations(DATA / name / f"{name}.relations")
        keep = (rt[:, 1] <= log.scans[-1].t + 1e-6) & (rt[:, 0] >= log.scans[0].t - 1e-6)
        rt, rd = rt[keep], rd[keep]
        for method, extra in METHODS:
            opts = SlamOptions(method=method, map_resolution_m=0.1,  # type: ignore[arg-type]
                               **extra)
            _, res = run_log(log, opts)
            e = relation_errors(res.times, res.poses, rt, rd)
            label = method + (f" ({extra['proposal']})" if extra else "")
            rt_x = log.duration_s / res.seconds
            if method == "rbpf" and extra.get("proposal") == "odometry":
                rt_factor[name] = rt_x
            lines.append(f"| {name} | {len(log)} | {label} | {e.trans_m:.3f} ± {e.trans_std_m:.3f}"
                         f" | {e.rot_deg:.2f} ± {e.rot_std_deg:.2f} | {res.seconds:.1f} "
                         f"| {rt_x:.1f} |")
            print(lines[-1], flush=True)
        sm, rb, gm, carto = PUBLISHED[name]
        lines.append(f"| {name} | | published SM / RBPF (GMapping) / graph / Cartographer | "
                     f"{sm} / {rb} / {gm} / {carto} | | | |")
    return rt_factor


def corridor(lines: list[str]) -> None:
    log = simulated_log("corridor", seed=0)
    truth = log.truth
    assert truth is not None
    lines += ["", "## Stripe corridor (34 m, odometry under-reads distance by 5 %)", "",
              "| method | alpha | final along-corridor error (m) | mean position error (m) |",
              "|---|---|---|---|"]
    for method, alpha in [("odom", 0.0), ("icp", 0.0), ("icp", 1e-9), ("gated", 0.0),
                          ("gated", 1e-9), ("rbpf", 0.0), ("rbpf", 1e-9)]:
        _, res = run_log(log, SlamOptions(method=method, alpha=alpha))  # type: ignore[arg-type]
        err = np.hypot(*(res.poses[:, :2] - truth[:, :2]).T)
        lines.append(f"| {method} | {alpha:g} | {res.poses[-1, 0] - truth[-1, 0]:+.2f} | "
                     f"{err.mean():.2f} |")
        print(lines[-1], flush=True)


def _extrude(xy: np.ndarray) -> np.ndarray:
    """2-D scan -> 3-D wall strips (z = -0.2..0.2) so normals/covariances are defined."""
    return np.vstack([np.column_stack([xy, np.full(len(xy), z)])
                      for z in (-0.2, -0.1, 0, 0.1, 0.2)])


def _t4(p: np.ndarray) -> np.ndarray:
    c, s = np.cos(p[2]), np.sin(p[2])
    t = np.eye(4)
    t[:2, :2] = [[c, -s], [s, c]]
    t[:2, 3] = p[:2]
    return t


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
            a, b = log.scans[i1], log.scans[i2]
            xa, _ = a.points()
            xb, _ = b.points()
            if len(xa) < 20 or len(xb) < 20:
                continue
            init = relative(a.odom, b.odom)
            for label in ALIGNERS:
                t0 = time.perf_counter()
                est = align(label, small_gicp, xa, xb, init)
                dt = time.perf_counter() - t0
                err = compose(relative(rd[k], np.zeros(3)), est)
                results.setdefault(label, []).append(
                    (float(np.hypot(err[0], err[1])), float(np.degrees(abs(err[2]))), dt))
    base = np.mean([r[2] for r in results["small_gicp GICP"]])
    for label, r in results.items():
        a = np.array(r)
        lines.append(f"| {label} | {a[:, 0].mean():.3f} (median {np.median(a[:, 0]):.3f}) | "
                     f"{a[:, 1].mean():.2f} | {1000 * a[:, 2].mean():.2f} | "
                     f"{a[:, 2].mean() / base:.2f}x |")
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
    r = sg.align(_extrude(xa), _extrude(xb), _t4(init), registration_type=kind,
                 downsampling_resolution=0.05, max_correspondence_distance=1.0, num_threads=1,
                 max_iterations=40)
    t = r.T_target_source
    return np.array([t[0, 3], t[1, 3], np.arctan2(t[1, 0], t[0, 0])])


def profile(lines: list[str]) -> None:
    log = read_log(DATA / "mit-csail" / "mit-csail.clf").head(600)
    prof = cProfile.Profile()
    prof.enable()
    _, res = run_log(log, SlamOptions(method="rbpf", particles=512))
    prof.disable()
    st = pstats.Stats(prof)
    rows = sorted(((v[3], k) for k, v in st.stats.items()),  # type: ignore[attr-defined]
                  key=lambda r: -r[0])
    lines += ["", f"## Where RBPF time goes (mit-csail, 600 scans, 512 particles, "
              f"{res.seconds:.1f} s; cumulative share of the run)", ""]
    seen = 0
    for cum, (fname, _line, func) in rows:
        if any(s in fname for s in ("numeric/slam", "numeric/geometry")) and seen < 8:
            lines.append(f"- `{Path(fname).name}:{func}`: {100 * cum / res.seconds:.0f} %")
            seen += 1


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default="bench-out")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(exist_ok=True)
    scope = "quick: first 1500 scans per log" if args.quick else "full logs"
    lines = [f"# SLAM benchmark ({scope})", ""]
    rt = accuracy(args.quick, lines)
    corridor(lines)
    peers(lines, 60 if args.quick else 200)
    lines += ["", "## RBPF throughput (512 particles, odometry proposal)", "",
              "| log | x real time |", "|---|---|"]
    lines += [f"| {k} | {v:.1f} |" for k, v in rt.items()]
    profile(lines)
    (out / "slam.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
