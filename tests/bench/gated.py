"""The paper's gated SLAM (Hara et al. §6, eq. 5) on the four Freiburg logs, beside the
sequential scan matchers it is measured against, in one run.

    .venv/bin/python tests/bench/gated.py [--logs aces,...] [--out bench-out]

Methods, each over the whole log in a fresh process (:func:`tests.bench.slam.run_isolated`,
so that time and peak memory are its own), scored with the relation metric of Kümmerle et
al. 2009:

- ``gated``: the single hypothesis with the RBPF's scan matcher as its front end
  (:meth:`chizu.numeric.slam.rbpf.RbpfConfig.single_hypothesis`);
- ``gated (icp)``: the paper's own front end, Intensity-ICP against the keyframes;
- ``karto``: OpenKarto's sequential correlative matcher (:mod:`tests.bench.slam_peers`).

The bound on each log is the better of OpenKarto's error in this run and the published
scan-matching error (Kümmerle et al. 2009), at 20 times real time or faster. Writes
docs/results/gated.md and OUT/gated.json.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from tests.bench.results import write_page  # noqa: E402
from tests.bench.slam import LOGS, PUBLISHED, run_isolated  # noqa: E402

METHODS = ("gated", "gated (icp)", "karto")
#: the real-time factor the gated method must reach
REALTIME = 20.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--logs", default=",".join(n for n, _ in LOGS))
    ap.add_argument("--out", default="bench-out")
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    names = a.logs.split(",")
    rows = []
    lines = ["## Relation errors (m, mean ± std; rotation in degrees) and speed", "",
             "| log | method | trans (m) | rot (deg) | loop trans (m) | local failures | "
             "time (s) | x real time | peak RSS (MB) |", "|---|---|---|---|---|---|---|---|---|"]
    for name in names:
        for label in METHODS:
            r = run_isolated(name, label, False, out)
            rows.append(r)
            lines.append(f"| {name} | {label} | {r['trans']:.3f} ± {r['trans_std']:.3f} | "
                         f"{r['rot']:.2f} | {r['loop_trans']:.3f} | {r['local_failures']} | "
                         f"{r['seconds']:.1f} | "
                         f"{r['realtime']:.1f} | {r['peak_rss_mb']:.0f} |")
            print(lines[-1], flush=True)
    lines += ["", "## Against the bound", "",
              "The bound: the better of OpenKarto's sequential matcher in this run and the "
              "published scan matching (Kümmerle et al. 2009), at "
              f"{REALTIME:g}× real time or faster.", "",
              "| log | gated (m) | OpenKarto (m) | published SM (m) | bound (m) | x real time "
              "| within |", "|---|---|---|---|---|---|---|"]
    for name in names:
        by = {r["method"]: r for r in rows if r["log"] == name}
        g, k = by["gated"], by["karto"]
        bound = min(k["trans"], PUBLISHED[name][0])
        ok = g["trans"] <= bound and g["realtime"] >= REALTIME
        lines.append(f"| {name} | {g['trans']:.3f} | {k['trans']:.3f} | {PUBLISHED[name][0]} "
                     f"| {bound:.3f} | {g['realtime']:.1f} | {'yes' if ok else 'no'} |")
    (out / "gated.json").write_text(json.dumps(rows, indent=1))
    lines += ["", "Local failures (tests/bench/slam.py): relations shorter than 20 s off by more "
              "than 0.3 m where the raw odometry is within 0.1 m; a loop start's correction "
              "counts as one. Trajectories in bench-out/ (traj-LOG-METHOD.tum); every run's "
              "figures in bench-out/gated.json."]
    write_page("gated", "Gated SLAM (Hara et al. §6) against sequential scan matching",
               lines, "as make bench runs it" if a.logs == ",".join(n for n, _ in LOGS)
               else f"--logs {a.logs}")


if __name__ == "__main__":
    main()
