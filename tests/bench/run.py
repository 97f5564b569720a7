"""make bench: DRM build time and path latency over REST, and qualitative vs quantitative.

    .venv/bin/python tests/bench/run.py

Writes docs/results/run.md (the tables) and bench-out/qual_vs_quant.png. Speeds are
reported next to a baseline measured in the same run (GET /health over the same HTTP
stack), since these machines are shared and noisy.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from chizu.numeric.qualitative.drm import build_drm, edges_from_records, max_probability_path  # noqa: E402
from chizu.numeric.qualitative.navigation import (  # noqa: E402
    NavConfig,
    estimate_landmark_positions,
    execute_drm_path,
    execute_quantitative,
    execute_quantitative_tracked,
    quantitative_route,
)
from chizu.numeric.qualitative.survey import survey  # noqa: E402
from chizu.numeric.simulator import LandmarkObserver, ObserverConfig, OdometryConfig, Robot  # noqa: E402
from chizu.numeric.world import World  # noqa: E402
from chizu.numeric.worlds import office_world  # noqa: E402
from chizu.service.client import Client  # noqa: E402
from chizu.service.kb import KnowledgeBase  # noqa: E402
from chizu.service.settings import PROLOG_DIR  # noqa: E402
from chizu.service.worlds import WorldService  # noqa: E402
from tests.bench.results import FULL, write_page  # noqa: E402
from tests.conftest import LiveServer  # noqa: E402

OUT = ROOT / "bench-out"


def pct(xs: list[float], q: float) -> float:
    return float(np.percentile(np.array(xs), q))


def bench_rest(sizes: tuple[int, ...] = (4, 20, 40), queries: int = 200) -> list[dict]:
    """Over the typed client, as a user calls it: the paths and the /health baseline both
    go through it (one HTTP stack, each answer validated)."""
    rows = []
    with tempfile.TemporaryDirectory() as d:
        srv = LiveServer(Path(d))
        try:
            with Client(srv.url, timeout_s=120) as c:
                for k in sizes:
                    desc = office_world(name=f"office{k}", rooms_per_side=k)
                    w = World(desc)
                    c.worlds.create_world(desc)
                    obs = survey(w, ObserverConfig(bearing_noise_rad=0.01,
                                                   distance_noise_m=0.02), seed=1)
                    for o in obs:
                        c.qualitative.post_observation(desc.name, o)
                    builds = []
                    for rep in range(5):
                        if rep:  # re-post one observation: invalidates the closure
                            c.qualitative.post_observation(desc.name, obs[rep])
                        t0 = time.perf_counter()
                        drm = c.qualitative.get_drm(desc.name)
                        builds.append(time.perf_counter() - t0)
                    rng = np.random.default_rng(0)
                    ids = w.landmark_ids
                    lat, health = [], []
                    for _ in range(queries):
                        a, b = rng.choice(ids, 2, replace=False)
                        t0 = time.perf_counter()
                        c.qualitative.get_path(desc.name, from_=a, to=b)
                        lat.append(time.perf_counter() - t0)
                        t0 = time.perf_counter()
                        c.health.health()
                        health.append(time.perf_counter() - t0)
                    rows.append({
                        "landmarks": len(ids), "edges": len(drm.edges),
                        "drm_build_ms": statistics.median(builds) * 1e3,
                        "path_p50_ms": pct(lat, 50) * 1e3, "path_p99_ms": pct(lat, 99) * 1e3,
                        "health_p50_ms": pct(health, 50) * 1e3,
                    })
                    print(rows[-1], flush=True)
        finally:
            srv.stop()
    return rows


def world_drm(kb: KnowledgeBase, name: str, ids: list[str], obs: list) -> Any:
    """The DRM the rules build from ``obs`` in a fresh knowledge-base world ``name``."""
    kb.call("create_world", world=name, landmarks=ids, rule_probabilities={}, parameters={})
    for o in obs:
        op, args = WorldService.event_call(name, "observation", o.model_dump())
        kb.call(op, **args)
    drm = kb.call("drm", world=name)
    return build_drm(drm["nodes"], edges_from_records(drm["edges"]))


def navigate_pair(w: World, g: Any, obs: list, est: Any, ocfg: ObserverConfig,
                  a: str, b: str, rng: np.random.Generator) -> dict[str, tuple[bool, float]]:
    """From landmark ``a`` to ``b`` (a random heading) by each planner, the same sensors:
    the DRM's most probable path, the metric route in the estimated map, and that route
    with continuous localisation. ``(success, travelled m)`` per planner."""
    cfg, odo = NavConfig(), OdometryConfig()
    sb = max(ocfg.bearing_noise_rad, 1e-3)
    sd = max(ocfg.distance_noise_m, 1e-2) + 0.05
    start = np.array([*w.landmark_position(a), rng.uniform(-np.pi, np.pi)])

    def robot() -> tuple[Robot, LandmarkObserver]:
        return (Robot(w, start.copy(), odo, np.random.default_rng(rng.integers(1 << 31))),
                LandmarkObserver(w, ocfg, np.random.default_rng(rng.integers(1 << 31))))

    out: dict[str, tuple[bool, float]] = {}
    rob = robot()
    p = max_probability_path(g, a, b)
    r = execute_drm_path(*rob, p.steps, cfg) if p is not None else None
    out["qualitative"] = (r.success, r.travelled_m) if r is not None else (False, 0.0)
    rob = robot()
    route = quantitative_route(obs, est, a, b)
    if route is None:
        return {**out, "quantitative": (False, 0.0), "quantitative_tracked": (False, 0.0)}
    r = execute_quantitative(*rob, route, est, cfg)
    out["quantitative"] = (r.success, r.travelled_m)
    r = execute_quantitative_tracked(*robot(), route, est, cfg, sb, sd)
    out["quantitative_tracked"] = (r.success, r.travelled_m)
    return out


def bench_navigation(levels: tuple[float, ...] = (0.0, 0.5, 1.0, 2.0, 4.0, 8.0),
                     pairs: int = 40, seeds: int = 2) -> list[dict]:
    """Noise level L: bearing sigma = L * 1 deg, range sigma = L * 1 % of range + L * 1 cm."""
    kb = KnowledgeBase(PROLOG_DIR)
    w = World(office_world(name="navbench"))
    ids = w.landmark_ids
    rows = []
    for level in levels:
        ocfg = ObserverConfig(bearing_noise_rad=np.deg2rad(1.0) * level,
                              distance_noise_ratio=0.01 * level, distance_noise_m=0.01 * level)
        res: dict[str, list[tuple[bool, float]]] = {"qualitative": [], "quantitative": [],
                                                     "quantitative_tracked": []}
        for seed in range(seeds):
            obs = survey(w, ocfg, seed=100 + seed)
            name = f"nav_{int(level * 10)}_{seed}"
            g = world_drm(kb, name, ids, obs)
            est = estimate_landmark_positions(obs, max(ocfg.bearing_noise_rad, 1e-3),
                                              max(ocfg.distance_noise_m, 1e-2) + 0.05)
            rng = np.random.default_rng(seed)
            for _ in range(pairs):
                a, b = rng.choice(ids, 2, replace=False)
                for planner, r in navigate_pair(w, g, obs, est, ocfg, a, b, rng).items():
                    res[planner].append(r)
            kb.call("drop_world", world=name)
        for planner, xs in res.items():
            ok = [length for s, length in xs if s]
            rows.append({"noise_level": level, "bearing_sigma_deg": level,
                         "range_sigma": f"{level:.1f}% + {level:.1f} cm", "planner": planner,
                         "runs": len(xs), "success_rate": len(ok) / len(xs),
                         "mean_length_m": float(np.mean(ok)) if ok else float("nan")})
            print(rows[-1], flush=True)
    kb.close()
    return rows


def plot(nav: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    for planner, style in (("qualitative", "o-"), ("quantitative", "s--"),
                           ("quantitative_tracked", "^:")):
        xs = [r for r in nav if r["planner"] == planner]
        ax[0].plot([r["noise_level"] for r in xs], [r["success_rate"] for r in xs], style,
                   label=planner)
        ax[1].plot([r["noise_level"] for r in xs], [r["mean_length_m"] for r in xs], style,
                   label=planner)
    ax[0].set(xlabel="noise level (bearing σ in deg; range σ in % and cm)",
              ylabel="success rate", ylim=(0, 1.05))
    ax[1].set(xlabel="noise level", ylabel="mean path length of successes [m]")
    for a in ax:
        a.grid(alpha=0.3)
        a.legend()
    fig.suptitle("DRM (qualitative) vs metric map (quantitative) navigation, demo office")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def table(rows: list[dict]) -> str:
    keys = list(rows[0])
    out = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    for r in rows:
        out.append("| " + " | ".join(f"{v:.3g}" if isinstance(v, float) else str(v)
                                     for v in r.values()) + " |")
    return "\n".join(out)


def main() -> None:
    OUT.mkdir(exist_ok=True)
    rest = bench_rest()
    nav = bench_navigation()
    plot(nav, OUT / "qual_vs_quant.png")
    body = ["## DRM build and path latency (REST)", "", table(rest), "",
            "## Qualitative vs quantitative navigation", "", table(nav), "",
            "Figure: bench-out/qual_vs_quant.png."]
    print("\n".join(body))
    write_page("run", "Qualitative navigation: DRM over REST, and qualitative vs "
               "quantitative navigation", body, FULL)


if __name__ == "__main__":
    main()
