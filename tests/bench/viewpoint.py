"""Viewpoint-planning benchmark: the paper's Table 1 and Fig. 11(b), the pattern table's
speed-up, planning time against the number of groups (exact DP vs the paper's exhaustive
search), and the online summarisation run of §7.3.

    .venv/bin/python tests/bench/viewpoint.py [--quick]

Writes docs/results/viewpoint.md and the figures in bench-out/. Times are medians on this machine;
compare the ratios, not the absolute figures (shared, noisy 2-core machines).
"""

from __future__ import annotations

import itertools
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from chizu.numeric.figures import plan_figure, run_figure  # noqa: E402
from chizu.numeric.viewpoint.grid import TravelMap, look_around, scanned_grid, true_grid  # noqa: E402
from chizu.numeric.viewpoint.online import Summariser, SummaryConfig  # noqa: E402
from chizu.numeric.viewpoint.plan import (  # noqa: E402
    DP_AUTO_MAX,
    GroupCost,
    Loss,
    Problem,
    evaluate,
    solve,
    solve_bnb,
    solve_exhaustive,
)
from chizu.numeric.viewpoint.planner import (  # noqa: E402
    BUILTIN_OBJECT_TYPES,
    PlanRequest,
    ViewpointPlanner,
    geodesic,
)
from chizu.numeric.viewpoint.verification import TableCache  # noqa: E402
from chizu.numeric.world import World  # noqa: E402
from chizu.numeric.worlds import SUMMARY_DOOR, summary_room  # noqa: E402
from chizu.service.viewpoint import local_grouper  # noqa: E402
from tests.bench.results import FULL, write_page  # noqa: E402

OUT = ROOT / "bench-out"
TYPES = BUILTIN_OBJECT_TYPES
DOOR = list(SUMMARY_DOOR)


def median_ms(fn: Callable[[], Any], repeat: int) -> float:
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return 1e3 * statistics.median(ts)


def scene(layout: str, loss: str, **kw: Any) -> tuple[PlanRequest, Any]:
    w = World(summary_room("x", layout))
    grid = scanned_grid(w, look_around(DOOR))
    cands = [{"id": o.id, "type": o.type, "x": o.x, "y": o.y} for o in w.description.objects]
    body = {"robot": [*DOOR, 1.57], "exit": DOOR, "time_limit_s": 30, "loss": loss,
            "k_lim": 0.5, "speed_m_s": 0.4, "object_types": TYPES, "candidates": cands,
            "runner_ups": 10, **kw}
    return PlanRequest.model_validate(body), grid


def fmt(x: float | None, nd: int = 2) -> str:
    if x is None or not np.isfinite(x):
        return "∞" if (x is not None and x > 0) else "-∞"
    return f"{x:.{nd}f}"


def table1(grouper: Any, lines: list[str]) -> None:
    lines += ["## Table 1 (Fig. 11(a)): k_lim 0.5, v 0.4 m/s, t_limit 30 s, t_verify 10 s", "",
              "Room `fig11a`: near object A (value 50), far object B (value 100), start = "
              "exit at the door; grid = what the robot maps from the door.", "",
              "| plan | V | expected time (s) | L1 | L2 (eq. 13) | U L1 | U L2 | U L3 |",
              "|---|---|---|---|---|---|---|---|"]
    planner = ViewpointPlanner()
    rows: dict[tuple[str, ...], dict[str, Any]] = {}
    chosen = {}
    for loss in ("L1", "L2", "L3"):
        req, grid = scene("fig11a", loss, t_verify_s=10.0, min_area_m2=100.0,
                          object_types=TYPES[:2])
        rep = planner.plan(req, grid, grouper)
        chosen[loss] = " → ".join(rep.names(rep.plans[0])) or "(leave)"
        for p in rep.plans:
            key = tuple(rep.names(p))
            rows.setdefault(key, {"V": p.value, "t": p.time})[loss] = (p.loss, p.utility)
    for key, r in sorted(rows.items(), key=lambda kv: (len(kv[0]), kv[0])):
        if not key:
            continue
        lines.append(f"| {' → '.join(key)} | {r['V']:.0f} | {r['t']:.2f} | "
                     f"{fmt(r['L1'][0])} | {fmt(r['L2'][0])} | {fmt(r['L1'][1])} | "
                     f"{fmt(r['L2'][1])} | {fmt(r['L3'][1])} |")
    lines += ["", f"Chosen: L1 → **{chosen['L1']}**, L2 → **{chosen['L2']}**, "
              f"L3 → **{chosen['L3']}** (paper: G_A; G_B; G_A → G_B — G_A near, G_B far). "
              "Paper's L2 losses: G_B 2.76, G_A → G_B 296.26.", ""]


def _group_costs(rep: Any) -> list[GroupCost]:
    return [GroupCost(g.name, g.spec.kind, g.value, g.t_obs, g.entries) for g in rep.groups]


#: Fig. 11(b)'s plans in the paper, by loss; its letters A-C are object groups, D-E
#: unknown regions
PAPER_FIG11B = {"L1": "B → C → E", "L2": "B → C → D", "L3": "B → C → D"}


def fig11b_plans(grouper: Any, req: PlanRequest, grid: Any, lines: list[str]
                 ) -> dict[str, tuple[PlanRequest, Any]]:
    """The scene's groups, then the chosen plan and runner-up under each loss beside the
    paper's (a figure per loss); ``(request, report)`` by loss."""
    planner = ViewpointPlanner()
    rep = planner.plan(req, grid, grouper)
    lines += ["| group | kind | members | V | t_obs (s) | how |", "|---|---|---|---|---|---|"]
    for g in rep.groups:
        how = (f"{g.local.strategy} {','.join(g.local.order)}" if g.local
               else f"explore {g.area_m2:.2f} m²")
        lines.append(f"| {g.name} | {g.spec.kind} | {','.join(map(str, g.spec.members))} | "
                     f"{g.value:.1f} | {g.t_obs:.2f} | {how} |")
    lines += ["", "| loss | chosen plan | V | time (s) | U | runner-up | paper |",
              "|---|---|---|---|---|---|---|"]
    reports: dict[str, tuple[PlanRequest, Any]] = {}
    for loss in ("L1", "L2", "L3"):
        r = req.model_copy(update={"loss": loss})
        rep = planner.plan(r, grid, grouper)
        best, second = rep.plans[0], rep.plans[1] if len(rep.plans) > 1 else None
        lines.append(f"| {loss} | {' → '.join(rep.names(best)) or '(leave)'} | "
                     f"{best.value:.1f} | {best.time:.2f} | {fmt(best.utility)} | "
                     f"{' → '.join(rep.names(second)) if second else ''} | "
                     f"{PAPER_FIG11B[loss]} |")
        plan_figure(rep, r, grid, str(OUT / f"viewpoint_fig11b_{loss}.png"))
        reports[loss] = (r, rep)
    return reports


def paper_plans(reports: dict[str, tuple[PlanRequest, Any]], grid: Any,
                lines: list[str]) -> None:
    """The paper's plans evaluated with chizu's values and times, under the matching of
    its letters to our groups (objects A-C to ours, regions D-E to ours) that suits each
    plan best."""
    lines += ["", "The paper's plans evaluated with chizu's values and times, under the "
              "matching of its letters to our groups that suits each plan best:", "",
              "| loss | paper's plan | as our groups | V | time (s) | U | our optimum U |",
              "|---|---|---|---|---|---|---|"]
    for loss, (r, rep) in reports.items():
        prob = Problem.with_travel(_group_costs(rep), np.array(r.robot), np.array(r.exit),
                                   r.speed_m_s, r.loss_function(), geodesic(TravelMap(grid)))
        objs = [i for i, g in enumerate(rep.groups) if g.spec.kind == "objects"]
        unks = [i for i, g in enumerate(rep.groups) if g.spec.kind == "unknown"]
        best_u, best_map = -np.inf, None
        for po in itertools.permutations(objs):
            for pu in itertools.permutations(unks):
                letter = dict(zip("ABCDE", list(po) + list(pu), strict=False))
                order = tuple(letter[c] for c in PAPER_FIG11B[loss].split(" → "))
                plan = evaluate(prob, order)
                u = plan.utility if np.isfinite(plan.utility) else -np.inf
                if best_map is None or u > best_u:
                    best_u, best_map = u, (order, plan)
        assert best_map is not None
        order, plan = best_map
        lines.append(f"| {loss} | {PAPER_FIG11B[loss]} | "
                     f"{' → '.join(rep.groups[i].name for i in order)} | {plan.value:.1f} | "
                     f"{plan.time:.2f} | {fmt(plan.utility)} | "
                     f"{fmt(rep.plans[0].utility)} |")


def planning_times(grouper: Any, req: PlanRequest, grid: Any, lines: list[str],
                   repeat: int) -> None:
    """Planning time of the whole request (grouping in Prolog, local plans, global plan):
    re-planning, the paper's exhaustive search, a first plan, without the pattern
    tables, and the global plan alone."""
    warm = ViewpointPlanner(TableCache())
    warm.plan(req, grid, grouper)
    t_dp = median_ms(lambda: warm.plan(req, grid, grouper), repeat)
    ex = req.model_copy(update={"solver": "exhaustive"})
    t_ex = median_ms(lambda: warm.plan(ex, grid, grouper), repeat)
    cold = median_ms(lambda: ViewpointPlanner(TableCache()).plan(req, grid, grouper),
                     max(3, repeat // 4))
    rep = warm.plan(req, grid, grouper)
    gl = median_ms(lambda: solve(Problem.build(
        _group_costs(rep), np.array(req.robot), np.array(req.exit), req.speed_m_s,
        req.loss_function())), repeat)
    # the pattern table's speed-up (eq. 6 vs eq. 5 on the free viewpoints, fresh tables)
    notab = req.model_copy(update={"use_table": False})
    t_notab = median_ms(lambda: ViewpointPlanner(TableCache()).plan(notab, grid, grouper),
                        max(3, repeat // 4))
    lines += ["", f"Planning the scene ({len(rep.groups)} groups), median of {repeat}:", "",
              "| what | time (ms) |", "|---|---|",
              f"| whole request, tables warm (re-planning), exact DP | **{t_dp:.1f}** |",
              f"| whole request, tables warm, the paper's exhaustive search | {t_ex:.1f} |",
              f"| whole request, first plan (tables built) | {cold:.1f} |",
              f"| whole request, no tables (exact eq. 5 on the free viewpoints) | {t_notab:.1f} |",
              f"| global plan only (DP) | {gl:.2f} |", "",
              f"Goal ≤ 20 ms for a Fig. 11(b)-size scene (paper ≈ 900 ms on a Core 2 Duo): "
              f"{'met' if t_dp <= 20 else 'missed'} at {t_dp:.1f} ms. Pattern tables: a first "
              f"plan takes {cold / t_notab:.2f}× the time of planning without tables, a "
              f"re-plan {t_dp / t_notab:.2f}× (paper: ≈ 1/6).", ""]


def fig11b(grouper: Any, lines: list[str], repeat: int) -> None:
    lines += ["## Fig. 11(b): four candidates, three object groups, two unknown regions", "",
              "Room `fig11b` seen from the door; t_limit 30 s, k_lim 0.5, v 0.4 m/s, "
              "t_verify 2 s, unknown regions ≥ 1.5 m² (smaller shadows are not groups).", ""]
    req, grid = scene("fig11b", "L2", t_verify_s=2.0, min_area_m2=1.5)
    reports = fig11b_plans(grouper, req, grid, lines)
    paper_plans(reports, grid, lines)
    planning_times(grouper, req, grid, lines, repeat)


def scaling(lines: list[str], quick: bool) -> None:
    lines += ["## Planning time vs number of groups (global plan, L2)", "",
              "Random groups in a 10 m room (3 entry points each, values 5-100, t_obs 1-15 s, "
              "t_limit 60 s). Exhaustive = every ordered subset (the paper); DP = Held-Karp "
              "over subsets (chizu's default). Optimum utilities compared where both run.", "",
              "| groups | ordered plans | exhaustive (ms) | DP (ms) | speed-up | same optimum |",
              "|---|---|---|---|---|---|"]
    rng = np.random.default_rng(0)
    sizes = [3, 5, 7, 9, 12, 15] if quick else [3, 4, 5, 6, 7, 8, 9, 10, 12, 15, 16, 18, 20]
    for n in sizes:
        groups = [GroupCost(f"g{i}", "objects", float(rng.uniform(5, 100)),
                            float(rng.uniform(1, 15)), rng.uniform(0, 10, (3, 2)))
                  for i in range(n)]
        p = Problem.build(groups, np.array([0.5, 0.5, 0.0]), np.array([0.5, 0.5]), 0.4,
                          Loss(kind="L2", t_limit_s=60, k_lim=0.5))
        plans = sum(int(np.prod(range(n - r + 1, n + 1))) for r in range(1, n + 1))
        rep = 5 if n <= 12 else 2
        t_dp = median_ms(lambda p=p: solve(p), rep)  # type: ignore[misc]
        if n <= (8 if quick else 9):
            t0 = time.perf_counter()
            ref = solve_exhaustive(p)
            t_ex = 1e3 * (time.perf_counter() - t0)
            same = abs(ref[0].utility - solve(p)[0].utility) < 1e-9
            lines.append(f"| {n} | {plans:,} | {t_ex:.1f} | {t_dp:.2f} | {t_ex / t_dp:.0f}× | "
                         f"{'yes' if same else '**NO**'} |")
        else:
            lines.append(f"| {n} | {plans:,} | — | {t_dp:.2f} | — | — |")
    lines.append("")


def branch_and_bound(lines: list[str], quick: bool) -> None:
    """The global plan past the DP's reach: branch and bound, exact within its budget or
    with the gap to its upper bound."""
    lines += ["## Global plan past 20 groups: branch and bound (1 s budget)", "",
              "Random scenes as above (10 m room, t_limit 60 s, k_lim 0.5). Branch and bound "
              "over layers of partial tours with a knapsack bound, started from the DP's "
              "plans over 14 of the groups; exact when it runs out of states, else it "
              "reports the gap to its upper bound. Up to 20 groups the DP runs in the same "
              "scene for comparison.", "",
              "| groups | loss | scenes | proven optimal within 1 s | median time (ms) | "
              "largest gap (% of utility) | same utility as the DP |",
              "|---|---|---|---|---|---|---|"]
    scenes = 2 if quick else 8
    warm = Problem.build([GroupCost(f"g{i}", "objects", 10.0, 1.0, np.full((1, 2), float(i)))
                          for i in range(DP_AUTO_MAX + 1)], np.zeros(3), np.zeros(2), 0.4,
                         Loss(kind="L2"))
    solve_bnb(warm, 0, 10.0)  # numba's compiled kernels load on first use (not timed)
    for n in ([20, 30] if quick else [18, 20, 25, 30, 35]):
        for kind in ("L1", "L2", "L3"):
            rng = np.random.default_rng(n * 10 + len(kind))
            proven, times, gaps, same = 0, [], [], []
            for _ in range(scenes):
                groups = [GroupCost(f"g{i}", "objects", float(rng.uniform(5, 100)),
                                    float(rng.uniform(1, 15)), rng.uniform(0, 10, (3, 2)))
                          for i in range(n)]
                p = Problem.build(groups, np.array([0.5, 0.5, 0.0]), np.array([0.5, 0.5]),
                                  0.4, Loss(kind=kind, t_limit_s=60, k_lim=0.5))
                t0 = time.perf_counter()
                sol = solve_bnb(p, 0, 1.0)
                times.append(1e3 * (time.perf_counter() - t0))
                proven += sol.optimal
                gaps.append(100 * sol.gap / max(abs(sol.plans[0].utility), 1e-9))
                if n <= 20:
                    same.append(abs(solve(p, 0)[0].utility - sol.plans[0].utility) < 1e-6)
            lines.append(f"| {n} | {kind} | {scenes} | {proven} | {np.median(times):.0f} | "
                         f"{max(gaps):.1f} | "
                         f"{f'{sum(same)} of {len(same)}' if same else '—'} |")
            print(lines[-1], flush=True)
    lines.append("")


def cluster_scene(k: int, seed: int = 0) -> tuple[PlanRequest, Any]:
    """A 10 m x 10 m room with one cluster of k objects of type A (one group) in its
    middle, the robot at the door; the true map."""
    from chizu.numeric.world import Wall, WorldDescription, WorldObject

    rng = np.random.default_rng(seed)
    side = 1.2 + 0.5 * np.sqrt(k)  # ~1 m between neighbours: one group
    xy: list[np.ndarray] = []
    tries = 0
    while len(xy) < k:
        p = rng.uniform(5.0 - side / 2, 5.0 + side / 2, 2)
        if all(np.hypot(*(p - q)) > 0.8 for q in xy):
            xy.append(p)
        tries += 1
        if tries % 2000 == 0:  # too tight: a slightly larger patch
            side *= 1.05
    walls = [Wall(a=a, b=b) for a, b in (((0, 0), (10, 0)), ((10, 0), (10, 10)),
                                         ((10, 10), (0, 10)), ((0, 10), (0, 0)))]
    w = World(WorldDescription(name="cluster", walls=walls, objects=[
        WorldObject(id=f"o{i}", type="A", x=float(p[0]), y=float(p[1]),
                    theta=float(rng.uniform(-np.pi, np.pi))) for i, p in enumerate(xy)]))
    body = {"robot": [0.5, 0.5, 0.0], "exit": [0.5, 0.5], "time_limit_s": 300, "loss": "L2",
            "object_types": TYPES, "candidates": [
                {"id": o.id, "type": o.type, "x": o.x, "y": o.y} for o in w.description.objects]}
    return PlanRequest.model_validate(body), true_grid(w)


def group_size(grouper: Any, lines: list[str], quick: bool) -> None:
    """Planning time against objects per group, 1-16: exact local plans up to
    ``EXACT_GROUP`` objects, a bound beyond, and how far the bound is from exact."""
    from chizu.numeric.viewpoint import verification as ver

    lines += ["## Planning time vs objects per group (local plan: t_seq, t_par)", "",
              "One cluster of k objects of type A (one group) in a 10 m room, the true map; "
              "the whole request (grouping, local plans, global plan). t_seq and t_par are "
              f"exact up to {ver.EXACT_GROUP} objects (every order and hand-over viewpoint, "
              "dynamic programming over subsets); beyond, a bound: the time of one chain over "
              "every hand-over viewpoint, a policy the robot can follow. The last column "
              "forces the bound on small groups to show how far it is from the exact value "
              "(same run).", "",
              "| objects | groups | first plan (ms) | re-plan (ms) | t_obs (s) | how | exact | "
              "bound / exact |", "|---|---|---|---|---|---|---|---|"]
    ks = [1, 2, 3, 4, 6, 8, 12, 16] if quick else list(range(1, 17))
    first, again = [], []
    for k in ks:
        req, grid = cluster_scene(k)
        planner = ViewpointPlanner(TableCache())
        t0 = time.perf_counter()
        rep = planner.plan(req, grid, grouper)
        first.append(1e3 * (time.perf_counter() - t0))
        again.append(median_ms(lambda p=planner, r=req, g=grid: p.plan(r, g, grouper), 3))
        objs = [g for g in rep.groups if g.local is not None]
        if not objs:  # an object boxed in by its neighbours: the group is unverifiable
            lines.append(f"| {k} | 0 | {first[-1]:.0f} | {again[-1]:.0f} | — | "
                         "unverifiable | | |")
            continue
        big = max(objs, key=lambda g: len(g.spec.members))
        gap = ""
        if 2 <= k <= ver.EXACT_GROUP:
            keep = ver.EXACT_GROUP
            try:
                ver.EXACT_GROUP = 1
                bound = ViewpointPlanner(TableCache()).plan(req, grid, grouper)
            finally:
                ver.EXACT_GROUP = keep
            bb = max((g for g in bound.groups if g.local is not None),
                     key=lambda g: len(g.spec.members))
            gap = f"{bb.t_obs / big.t_obs:.3f}"
        lines.append(f"| {k} | {len(objs)} | {first[-1]:.0f} | {again[-1]:.0f} | "
                     f"{big.t_obs:.1f} | {big.local.strategy if big.local else ''} | "
                     f"{'yes' if big.local and big.local.exact else 'bound'} | {gap} |")
    group_size_figure(ks, first, again)
    i12 = ks.index(12)
    lines += ["", f"12 objects: {first[i12]:.0f} ms first plan, {again[i12]:.0f} ms re-plan "
              "(goal ≤ 200 ms). Figure: bench-out/viewpoint_group_size.png.", ""]


def group_size_figure(ks: list[int], first: list[float], again: list[float]) -> None:
    """bench-out/viewpoint_group_size.png: planning time against objects per group."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from chizu.numeric.viewpoint import verification as ver

    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.plot(ks, first, "o-", label="first plan")
    ax.plot(ks, again, "s--", label="re-plan (tables warm)")
    ax.axvline(ver.EXACT_GROUP + 0.5, color="grey", lw=0.8)
    ax.set_xlabel("objects in the group")
    ax.set_ylabel("planning time (ms)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(OUT / "viewpoint_group_size.png", dpi=120)


def online(grouper: Any, lines: list[str]) -> None:
    lines += ["## Online summarisation (§7.3), room `summary_room`", "",
              "Two objects (one behind a cabinet) and one false candidate; the robot enters "
              "at the door, plans, moves, observes, re-plans until the plan is to leave. "
              "t_verify 6 s, t_sea 12 s (a slow robot like the paper's humanoid). The paper's "
              "real-robot run: L3 needed 90 s, so t_limit was set to 55 s (60 %).", "",
              "| loss | t_limit (s) | took (s) | verified | rejected | explored | re-plans |",
              "|---|---|---|---|---|---|---|"]
    w = World(summary_room())
    from chizu.numeric.viewpoint.planner import ObjectType

    types = [ObjectType.model_validate(t) for t in TYPES]
    for loss, limit in (("L3", 300.0), ("L2", 55.0), ("L1", 55.0), ("L2", 40.0),
                        ("L1", 25.0)):
        run = Summariser(w, types, grouper, SummaryConfig(time_limit_s=limit, loss=loss),
                         np.array(SUMMARY_DOOR)).run()
        s = run.summary(w)
        lines.append(f"| {loss} | {limit:g} | {run.elapsed_s:.1f} | "
                     f"{', '.join(s['verified']) or '—'} | {', '.join(s['rejected']) or '—'} | "
                     f"{s['explored_fraction']:.2f} | {s['steps']} |")
        if loss == "L2":
            run_figure(run, w, str(OUT / "viewpoint_summary_L2.png"))
    lines += ["", "Figure: bench-out/viewpoint_summary_L2.png (path, map, verified objects).", ""]


def online_random(grouper: Any, lines: list[str], quick: bool) -> None:
    """The online loop in rooms nobody tuned on, with cabinets in the way: does
    it keep L1's time limit, with travel along shortest paths vs straight lines; and the
    re-plan times over the whole runs."""
    from chizu.numeric.viewpoint.planner import ObjectType, ViewpointPlanner
    from chizu.numeric.worlds import random_summary_room

    rooms = 6 if quick else 20
    limit = 40.0
    lines += [f"## Online loop in {rooms} random rooms (L1, t_limit {limit:g} s)", "",
              "`random_summary_room(seed)`: the summary room's outline and door, 1-3 "
              "cabinets, 2-4 objects; t_verify 6 s, t_sea 12 s. Every plan request of the "
              "runs is timed (first plans, whose pattern tables are built, included). "
              "Under L1 the execution is monitored: a look or search that would not leave "
              "time to reach the door is skipped and the robot re-plans (skips counted).",
              "", "| travel estimate | runs within the limit | mean / largest overrun (s) | "
              "objects verified | monitor skips | every plan p50 / p95 (ms) | "
              "re-plans p50 / p95 (ms) (count) |", "|---|---|---|---|---|---|---|"]
    types = [ObjectType.model_validate(t) for t in TYPES]
    for travel in ("geodesic", "straight"):
        over, verified, skips, times, replans = [], 0, 0, [], []
        for seed in range(rooms):
            w = World(random_summary_room(seed))
            planner = ViewpointPlanner()
            plan = planner.plan
            run_times: list[float] = []

            def timed(*a: Any, _plan: Any = plan, _times: list[float] = run_times,
                      **k: Any) -> Any:
                t0 = time.perf_counter()
                out = _plan(*a, **k)
                _times.append(1e3 * (time.perf_counter() - t0))
                return out

            planner.plan = timed  # type: ignore[method-assign]
            run = Summariser(w, types, grouper, SummaryConfig(
                time_limit_s=limit, loss="L1", travel=travel), np.array(SUMMARY_DOOR),
                planner).run()
            over.append(max(0.0, run.elapsed_s - limit))
            verified += len(run.verified)
            skips += sum(e.action == "skip" for e in run.log)
            times += run_times
            replans += run_times[1:]  # after the first plan, whose tables are built
        t, rt = np.array(times), np.array(replans)
        lines.append(f"| {travel} | {sum(o <= 1e-6 for o in over)} of {rooms} | "
                     f"{np.mean(over):.1f} / {np.max(over):.1f} | {verified} | {skips} | "
                     f"{np.percentile(t, 50):.0f} / {np.percentile(t, 95):.0f} | "
                     f"{np.percentile(rt, 50):.1f} / {np.percentile(rt, 95):.1f} "
                     f"({len(rt)}) |")
        print(lines[-1], flush=True)
    lines.append("")


def estimates(grouper: Any, lines: list[str], quick: bool) -> None:
    """How well a group's planned time (travel to its first viewpoint along the grid
    plus the expected verification time of §5, eq. 6's tables with straight legs
    between the viewpoints of a group) matches what the executed verification took, in
    the random rooms without a time limit (L3)."""
    from chizu.numeric.viewpoint.planner import ObjectType, PlanReport, ViewpointPlanner
    from chizu.numeric.worlds import random_summary_room

    rooms = 6 if quick else 20
    types = [ObjectType.model_validate(t) for t in TYPES]
    rows: list[tuple[int, float, float]] = []
    for seed in range(rooms):
        w = World(random_summary_room(seed))
        planner = ViewpointPlanner()
        reports: list[PlanReport] = []
        plan = planner.plan

        def keep(*a: Any, _plan: Any = plan, _out: list[PlanReport] = reports,
                 **k: Any) -> Any:
            out = _plan(*a, **k)
            _out.append(out)
            return out

        planner.plan = keep  # type: ignore[method-assign]
        run = Summariser(w, types, grouper, SummaryConfig(time_limit_s=300, loss="L3"),
                         np.array(SUMMARY_DOOR), planner).run()
        at = [e.t_s for e in run.log if e.action == "plan"]
        for i, rep in enumerate(reports[:-1]):
            best = rep.plans[0]
            if best.order and rep.groups[best.order[0]].spec.kind == "objects":
                step = rep.steps(best)[0]
                rows.append((len(rep.groups[best.order[0]].spec.members),
                             step.travel_s + step.observe_s, at[i + 1] - at[i]))
    r = np.array(rows)
    ratio = r[:, 2] / r[:, 1]
    big = r[:, 0] >= 3
    lines += [f"## Planned vs executed group times ({rooms} random rooms, L3)", "",
              "Each object group the robot verified: the plan's time for it (geodesic "
              "travel to its first viewpoint + the expected verification time of §5) "
              "against the time the execution took until the next plan.", "",
              "| groups | executed / planned: median | p90 | largest | groups of ≥ 3 "
              "objects: median / largest |", "|---|---|---|---|---|",
              f"| {len(r)} | {np.median(ratio):.2f} | {np.percentile(ratio, 90):.2f} | "
              f"{ratio.max():.2f} | {np.median(ratio[big]):.2f} / {ratio[big].max():.2f} |",
              ""]


def main() -> None:
    quick = "--quick" in sys.argv
    OUT.mkdir(exist_ok=True)
    grouper, kb = local_grouper(ROOT / "prolog")
    lines: list[str] = []
    try:
        table1(grouper, lines)
        fig11b(grouper, lines, 10 if quick else 30)
        scaling(lines, quick)
        branch_and_bound(lines, quick)
        group_size(grouper, lines, quick)
        online(grouper, lines)
        online_random(grouper, lines, quick)
        estimates(grouper, lines, quick)
    finally:
        kb.close()
    print("\n".join(lines))
    write_page("viewpoint", "Viewpoint planning benchmark", lines, FULL if not quick else
               "not as `make bench` runs it: --quick: Fig. 11(b)'s times are medians of 10 "
               "instead of 30; fewer group counts in the scaling tables (exhaustive search up "
               "to 8 groups instead of 9) and in branch and bound (20 and 30 groups, 2 scenes "
               "instead of 18-35 and 8); 8 cluster sizes instead of 16; 6 random rooms "
               "instead of 20")


if __name__ == "__main__":
    main()
