"""Mission benchmark: the end-to-end mission's success over seeds on the built-in mission
world, and on random offices nobody tuned it on (room sizes, corridor width, goal room,
objects and cabinet drawn per world; the same parameters everywhere).

    .venv/bin/python tests/bench/mission.py [--quick] [--worlds N] [--seeds K]

Each world learns its eigenspace once (the mission's default: 1 m grid); every seed then
wakes the robot up somewhere else. Writes bench-out/mission.md, bench-out/mission.csv and
bench-out/mission.png (the first run).
"""

from __future__ import annotations

import asyncio
import csv
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from numeric.world import WorldDescription  # noqa: E402
from numeric.worlds import random_mission_world  # noqa: E402
from service.container import Services, open_services  # noqa: E402
from service.mission import MissionConfig, mission_figure  # noqa: E402
from service.settings import Settings  # noqa: E402

OUT = ROOT / "bench-out"
QUICK = "--quick" in sys.argv


def arg(name: str, default: int) -> int:
    return int(sys.argv[sys.argv.index(name) + 1]) if name in sys.argv else default


async def run_world(svc: Services, desc: WorldDescription, cfg: MissionConfig, seeds: range,
                    kind: str, rows: list[dict[str, Any]], figure: bool) -> None:
    await svc.worlds.create(desc)
    for seed in seeds:
        run = await svc.mission.run(desc.name, cfg.model_copy(update={"seed": seed}))
        ev = run.steps[-1]["result"]
        failed = next((s["what"] for s in run.steps if s["result"].get("ok") is False), "")
        learn = next((s["result"]["seconds"] for s in run.steps
                      if s["what"] == "learn_eigenspace"), None)
        rows.append({"kind": kind, "world": desc.name, "seed": seed, "success": run.success,
                     "failed_at": failed, "localized_by": ev.get("localized_by", ""),
                     "localization_error_m": ev.get("localization_error_m"),
                     "objects": ev["objects"], "objects_verified": ev["objects_verified"],
                     "false_verified": ev["false_verified"],
                     "mission_s": run.elapsed_s - (learn or 0.0), "learning_s": learn})
        print(f"{kind} {desc.name} seed {seed}: {'ok' if run.success else 'FAILED'} "
              f"{failed} {ev.get('localized_by', '')} "
              f"err {ev.get('localization_error_m', float('nan')):.2f} m, "
              f"{ev['objects_verified']}/{ev['objects']} objects, {run.elapsed_s:.1f} s",
              flush=True)
        if figure and seed == seeds.start:
            mission_figure(run, svc.worlds.model(desc.name), str(OUT / f"mission-{kind}.png"))


def table(rows: list[dict[str, Any]]) -> list[str]:
    out = ["| worlds | runs | success | localized by eigenspace | by the landmark fallback | "
           "position error [m] (mean ± std) | objects verified | false verified | "
           "mission time [s] (median, learning excluded) |",
           "|---|---|---|---|---|---|---|---|---|"]
    for kind in dict.fromkeys(r["kind"] for r in rows):
        rs = [r for r in rows if r["kind"] == kind]
        errs = [r["localization_error_m"] for r in rs if r["localization_error_m"] is not None]
        ok = sum(r["success"] for r in rs)
        eig = sum(r["localized_by"] == "eigenspace" for r in rs)
        lm = sum(r["localized_by"] == "landmark" for r in rs)
        found = sum(r["objects_verified"] for r in rs)
        total = sum(r["objects"] for r in rs)
        out.append(
            f"| {kind} ({len({r['world'] for r in rs})}) | {len(rs)} | {ok}/{len(rs)} "
            f"({ok / len(rs):.0%}) | {eig} | {lm} | "
            f"{statistics.mean(errs):.2f} ± {statistics.pstdev(errs):.2f} | {found}/{total} | "
            f"{sum(r['false_verified'] for r in rs)} | "
            f"{statistics.median(r['mission_s'] for r in rs):.1f} |")
    return out


def main() -> None:
    OUT.mkdir(exist_ok=True)
    seeds = arg("--seeds", 5 if QUICK else 20)
    worlds = arg("--worlds", 2 if QUICK else 6)
    rows: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        svc = open_services(Settings(data_dir=Path(d), demo_world=None, workers=0), demo=False)
        try:
            asyncio.run(run_world(svc, WorldDescription(name="mission", template="mission"),
                                  MissionConfig(), range(seeds), "mission", rows, True))
            for k in range(worlds):
                desc, goal, door, room = random_mission_world(k, name=f"office{k}")
                cfg = MissionConfig(goal=goal, door=door, room=room)
                asyncio.run(run_world(svc, desc, cfg, range(2), "random offices", rows,
                                      k == 0))
        finally:
            svc.close()
    lines = ["# Mission benchmark", "",
             f"`.venv/bin/python tests/bench/mission.py{' --quick' if QUICK else ''}` "
             f"({seeds} seeds on the mission world, {worlds} random offices x 2 seeds; "
             f"{time.perf_counter() - t0:.0f} s in all)", "", *table(rows), "",
             "Success: every step done, the pose the mission went on from within 0.5 m "
             "and 30 deg of the truth, at least one real object verified and no false one."]
    (OUT / "mission.md").write_text("\n".join(lines) + "\n")
    with open(OUT / "mission.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
