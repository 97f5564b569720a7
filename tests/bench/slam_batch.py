"""SLAM batches on Dask: the same tasks in this process and on a LocalCluster of 2
worker processes (this machine's cores), wall time and whether the results agree.

    .venv/bin/python tests/bench/slam_batch.py [--limit 1500] [--method gated-icp]

Tasks: the four Freiburg logs (the first --limit scans of each) with --method. Writes
docs/results/slam_batch.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np


def main() -> None:
    from chizu.numeric.slam.batch import run_batch, tasks_for
    from chizu.numeric.slam.datasets import slam_data_dir
    from chizu.service.executors import batch_executor
    from tests.bench.results import mode, write_page

    ap = argparse.ArgumentParser()
    ap.add_argument("--limit", type=int, default=1500)
    ap.add_argument("--method", default="gated-icp")
    args = ap.parse_args()
    d = slam_data_dir()
    logs = [d / "aces" / "aces.recon.clf", d / "mit-csail" / "mit-csail.clf",
            d / "fr079" / "fr079.recon.clf", d / "fr-clinic" / "fr-clinic.recon.clf"]
    tasks = tasks_for([p for p in logs if p.exists()], {"method": args.method},
                      limit=args.limit)
    t0 = time.perf_counter()
    here = run_batch(tasks)
    t_here = time.perf_counter() - t0
    with batch_executor(local_workers=2) as ex:
        t1 = time.perf_counter()
        there = run_batch(tasks, ex)
        t_there = time.perf_counter() - t1
    same = all(np.allclose(np.asarray(a.trajectory), np.asarray(b.trajectory), atol=1e-9)
               for a, b in zip(here, there, strict=True))
    lines = [f"{len(tasks)} runs: {args.method}, the first {args.limit} scans of each log.",
             "", "| where | wall time (s) | speed-up |", "|---|---|---|",
             f"| this process, one after the other | {t_here:.1f} | 1.00x |",
             f"| Dask LocalCluster, 2 worker processes | {t_there:.1f} | "
             f"{t_here / t_there:.2f}x |", "",
             f"Results identical: {same} (trajectories to 1e-9). The cluster's start-up "
             "(about 2 s) is outside its time."]
    print("\n".join(lines))
    write_page("slam_batch", "SLAM batches on Dask", lines, mode(ap, args))


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    main()
