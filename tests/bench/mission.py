"""Mission benchmark: the end-to-end mission's success over seeds on the built-in mission
world, and on random offices nobody tuned it on (room sizes, corridor width, goal room,
objects and cabinet drawn per world; the same parameters everywhere).

    .venv/bin/python tests/bench/mission.py [--quick] [--worlds N] [--seeds K]
                                            [--local-workers W]

Each world is one task (service/mission_batch.py) on a Dask LocalCluster of W worker
processes (default 2, this machine's cores; 0: in this process): it learns the world's
eigenspace once (the mission's default: 1 m grid), then every seed wakes the robot up
somewhere else. Writes docs/results/mission.md (the table), and bench-out/mission.csv
and bench-out/mission-KIND.png (the first run of each kind).
"""

from __future__ import annotations

import csv
import statistics
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from chizu.numeric.world import WorldDescription  # noqa: E402
from chizu.numeric.worlds import random_mission_world  # noqa: E402
from chizu.service.executors import batch_executor  # noqa: E402
from chizu.service.mission import MissionConfig  # noqa: E402
from chizu.service.mission_batch import run_missions  # noqa: E402
from tests.bench.results import FULL, write_page  # noqa: E402

OUT = ROOT / "bench-out"
QUICK = "--quick" in sys.argv
#: seeds on the mission world and random offices that `make bench` runs (--quick: 5, 2)
FULL_SEEDS, FULL_WORLDS = 20, 6


def arg(name: str, default: int) -> int:
    return int(sys.argv[sys.argv.index(name) + 1]) if name in sys.argv else default


def table(rows: list[dict[str, Any]]) -> list[str]:
    out = ["| worlds | runs | success | completed | localized by eigenspace (its error < 0.5 m) "
           "| by the wander fallback | eigenspace error [m] (mean ± std) | map anchor error "
           "[m] (mean ± std) | objects verified | false verified | mission time [s] (median, "
           "learning excluded) |",
           "|---|---|---|---|---|---|---|---|---|---|---|"]
    for kind in dict.fromkeys(r["kind"] for r in rows):
        rs = [r for r in rows if r["kind"] == kind]
        errs = [r["localization_error_m"] for r in rs if r["localization_error_m"] is not None]
        eerr = [r["eigenspace_error_m"] for r in rs if r["eigenspace_error_m"] is not None]
        good = sum(e < 0.5 for e in eerr)
        ok = sum(r["success"] for r in rs)
        # every step done, an object verified, none false: the pose's accuracy aside
        done = sum(not r["failed_at"] and r["objects_verified"] >= 1
                   and r["false_verified"] == 0 for r in rs)
        eig = sum(r["localized_by"] == "eigenspace" for r in rs)
        lm = sum(r["localized_by"] == "wander" for r in rs)
        found = sum(r["objects_verified"] for r in rs)
        total = sum(r["objects"] for r in rs)
        out.append(
            f"| {kind} ({len({r['world'] for r in rs})}) | {len(rs)} | {ok}/{len(rs)} "
            f"({ok / len(rs):.0%}) | {done}/{len(rs)} | {eig} ({good}) | {lm} | "
            f"{statistics.mean(eerr):.2f} ± {statistics.pstdev(eerr):.2f} | "
            f"{statistics.mean(errs):.2f} ± {statistics.pstdev(errs):.2f} | {found}/{total} | "
            f"{sum(r['false_verified'] for r in rs)} | "
            f"{statistics.median(r['mission_s'] for r in rs):.1f} |")
    return out


def main() -> None:
    OUT.mkdir(exist_ok=True)
    seeds = arg("--seeds", 5 if QUICK else FULL_SEEDS)
    worlds = arg("--worlds", 2 if QUICK else FULL_WORLDS)
    local = arg("--local-workers", 2)
    mission = WorldDescription(name="mission", template="mission").model_dump(mode="json")
    tasks = [(mission, {}, list(range(seeds)), "mission", True)]
    for k in range(worlds):
        desc, goal, door, room = random_mission_world(k, name=f"office{k}")
        cfg = MissionConfig(goal=goal, door=door, room=room).model_dump(mode="json")
        tasks.append((desc.model_dump(mode="json"), cfg, [0, 1], "random offices", k == 0))
    t0 = time.perf_counter()
    with batch_executor(scheduler=None, local_workers=local) as ex:
        results = run_missions(tasks, ex)
    wall = time.perf_counter() - t0
    rows = [r for rs, _ in results for r in rs]
    for (_, _, _, kind, _), (_, png) in zip(tasks, results, strict=True):
        if png is not None:
            (OUT / f"mission-{kind.replace(' ', '-')}.png").write_bytes(png)
    busy = sum((r["learning_s"] or 0.0) + r["mission_s"] for r in rows)
    where = f"a Dask LocalCluster of {local} worker processes" if local else "this process"
    lines = [f"{seeds} seeds on the mission world, {worlds} random offices x 2 seeds; one "
             f"task per world on {where}: {wall:.0f} s wall, {busy:.0f} s of task time.",
             "", *table(rows), "",
             "Success: every step done, the pose the mission went on from within 0.5 m "
             "and 30 deg of the truth, at least one real object verified and no false one. "
             "Completed: the same without the pose's accuracy."]
    with open(OUT / "mission.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print("\n".join(lines))
    full = (seeds, worlds) == (FULL_SEEDS, FULL_WORLDS) and local == 2
    write_page("mission", "Mission benchmark: the end-to-end mission over seeds and "
               "random offices", lines, FULL if full else
               f"not as `make bench` runs it: {seeds} seeds on the mission world and "
               f"{worlds} random offices (make bench: {FULL_SEEDS} and {FULL_WORLDS})"
               + (f", {local} local workers (make bench: 2)" if local != 2 else ""))


if __name__ == "__main__":
    main()
