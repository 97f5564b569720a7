"""Learning strategy (paper §4.2): add learning points until the robot is localized
within n observations with probability >= target.

1. Candidates: a grid finer than the learning spacing, outside the localizable area.
   For each, assume the triples it forms with its neighbouring learning points become
   regions and measure the localizable area gained (eq. 7 regions, area on a raster).
2. One best candidate: learn there.  Several tied: take the first move a_1 of the
   movement strategy, and on the circle of radius |a_1| around the tied candidates
   learn at the point least likely to be in a region (it raises P(Z_1 | a_1)).
3. Redo the triplet search around the new point; stop when P(Z | a_1..a_{n-1}) >= target.

``random_additions`` is the paper's baseline: the next point is drawn at random from
the same candidates.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import Executor
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree

from chizu.numeric.eigenspace.analysis import (
    EigenspaceAnalysis,
    EigenspaceConfig,
    Progress,
    SimulatedCamera,
    analyse,
    free_grid,
    probe_validated,
    with_learning_point,
)
from chizu.numeric.eigenspace.learning import LearningStrategyConfig
from chizu.numeric.eigenspace.localization import RegionModel, candidate_multiple_sets
from chizu.numeric.eigenspace.movement_strategy import (
    RegionLayout,
    initial_samples,
    p_z_curve,
)
from chizu.numeric.eigenspace.triplets import triangle_area
from chizu.numeric.eigenspace.twins import twin_transform
from chizu.numeric.world import World


@dataclass
class LearningStep:
    added: list[float] | None
    p_z: list[float]
    triplets: int
    learning_points: int
    #: the added point's twin place, learned with it (:mod:`chizu.numeric.eigenspace.twins`)
    twin: list[float] | None = None


@dataclass
class LearningResult:
    analysis: EigenspaceAnalysis
    steps: list[LearningStep] = field(default_factory=list)

    @property
    def additions(self) -> int:
        return sum(1 for s in self.steps if s.added is not None)


def hypothetical_gain(layout: RegionLayout, points: np.ndarray, candidates: np.ndarray,
                      grid: np.ndarray, neighbour_max_m: float, min_area_m2: float
                      ) -> np.ndarray:
    """Localizable area (m^2 up to the cell size) gained if each candidate formed regions
    with every pair of nearby learning points (step 1)."""
    p_base = layout.p_any(grid)
    miss_base = 1.0 - p_base
    covered = p_base >= 0.5
    gains = np.zeros(len(candidates))
    for c, xy in enumerate(candidates):
        near = np.flatnonzero(np.linalg.norm(points - xy, axis=1) <= neighbour_max_m)
        tri = [(i, j) for a, i in enumerate(near) for j in near[a + 1:]
               if np.linalg.norm(points[i] - points[j]) <= neighbour_max_m
               and triangle_area(np.array([xy, points[i], points[j]])) >= min_area_m2]
        if not tri:
            continue
        pts = np.array([[xy, points[i], points[j]] for i, j in tri])  # (n, 3, 2)
        d = np.linalg.norm(grid[:, None, None, :] - pts[None], axis=-1).min(axis=2)
        miss = miss_base * np.prod(1.0 - layout.entry.probability(d), axis=1)
        gains[c] = np.sum((1.0 - miss >= 0.5) & ~covered)
    return gains


def choose_learning_point(analysis: EigenspaceAnalysis, world: World,
                          config: LearningStrategyConfig, first_move_m: float,
                          rng: np.random.Generator, random_choice: bool = False
                          ) -> np.ndarray | None:
    """Steps 1-2: where to learn next (or at random among the candidates); None when
    every candidate already has a learning point.

    A candidate within half the candidate spacing of a learning point is not one: a
    point whose triplets were all rejected gains nothing, so it stayed the best
    candidate and was learned again and again (a 14 m x 6 m hall: the same point
    three times in a row)."""
    layout = analysis.layout(world)
    fresh = free_grid(world, config.candidate_spacing_m)
    fresh = fresh[far_from(fresh, analysis.model.points, config.candidate_spacing_m / 2)]
    if len(fresh) == 0:
        return None
    cand = fresh[layout.p_any(fresh) < 0.5] if len(analysis.triplets) else fresh
    if len(cand) == 0:
        cand = fresh
    if random_choice:
        return np.asarray(cand[rng.integers(len(cand))])
    grid = free_grid(world, config.area_cell_m)
    tcfg = analysis.config.triplets
    gains = hypothetical_gain(layout, analysis.model.points, cand, grid, tcfg.neighbour_max_m,
                              tcfg.min_area_m2)
    best = np.flatnonzero(gains >= gains.max())
    if len(best) == 1 or first_move_m <= 0:
        return np.asarray(cand[best[0]])
    ang = 2 * np.pi * np.arange(config.circle_points) / config.circle_points
    ring = (cand[best][:, None, :] + first_move_m * np.stack([np.cos(ang), np.sin(ang)], 1)
            ).reshape(-1, 2)
    ring = ring[world.is_free(ring)]
    ring = ring[far_from(ring, analysis.model.points, config.candidate_spacing_m / 2)]
    if len(ring) == 0:
        return np.asarray(cand[best[0]])
    return np.asarray(ring[int(np.argmin(layout.p_any(ring)))])


def far_from(xy: np.ndarray, points: np.ndarray, min_m: float) -> np.ndarray:
    """Whether each of ``xy (n, 2)`` is at least ``min_m`` from every one of ``points``."""
    if len(xy) == 0 or len(points) == 0:
        return np.ones(len(xy), dtype=bool)
    return np.asarray(cKDTree(points).query(xy)[0] >= min_m)


def strategy_samples(world: World, config: EigenspaceConfig) -> np.ndarray:
    """The initial poses over which P(Z within n) is judged (eq. 8's Monte Carlo
    samples), the same for every step of one learning."""
    return initial_samples(world.sample_free, config.strategy.n_samples,
                           np.random.default_rng(config.seed + 7))


def learning_strategy(analysis: EigenspaceAnalysis, world: World,
                      config: LearningStrategyConfig, rng: np.random.Generator,
                      random_additions: bool = False, executor: Executor | None = None,
                      progress: Callable[[LearningStep], None] | None = None
                      ) -> LearningResult:
    """Add learning points (§4.2) until P(Z within n observations) >= target.

    Where the learned turns show the room to be symmetric (:func:`twin_transform` of
    the starting points), each added point's twin place is learned with it (the
    addition counts once): otherwise the added triplets have no look-alike triplet for
    §3.3 to group them with, and a robot at the twin place is answered on the wrong
    side."""
    samples = strategy_samples(world, analysis.config)
    result = LearningResult(analysis)
    added: list[float] | None = None
    twin: list[float] | None = None
    symmetry = twin_transform(analysis.model) if config.learn_twins else None
    for _ in range(config.max_additions + 1):
        layout = result.analysis.layout(world)
        curve, acts = p_z_curve(samples, layout, result.analysis.config.strategy,
                                config.n_observations, executor)
        step = LearningStep(added, curve, len(result.analysis.triplets),
                            len(result.analysis.model.points), twin)
        result.steps.append(step)
        if progress:
            progress(step)
        if curve[-1] >= config.target_probability or len(result.steps) > config.max_additions:
            break
        first = float(acts[0][1]) if acts else 0.0
        point = choose_learning_point(result.analysis, world, config, first, rng,
                                      random_additions)
        if point is None:
            break
        result.analysis = with_learning_point(result.analysis, world, point)
        added, twin = [float(point[0]), float(point[1])], None
        if symmetry is not None:
            other = symmetry.apply(point)
            # near the symmetry's centre the point is its own twin's neighbourhood
            if (np.hypot(*(other - point)) >= 2 * config.candidate_spacing_m
                    and world.is_free(other[None])[0]
                    and far_from(other[None], result.analysis.model.points,
                                 config.candidate_spacing_m / 2)[0]):
                result.analysis = with_learning_point(result.analysis, world, other)
                twin = [float(other[0]), float(other[1])]
    return result


#: the added points' triplets are checked against this many times eq. 7's sample turns,
#: with their regions grown by PROBE_MARGIN (sparse probes miss a look-alike spot)
PROBE_DENSITY = 4
PROBE_MARGIN = 2.0


def learn_with_strategy(world: World, config: EigenspaceConfig,
                        progress: Progress | None = None,
                        executor: Executor | None = None) -> EigenspaceAnalysis:
    """§4: learn on the grid and analyse, then, with ``config.learning_strategy``, add
    learning points (§4.2) until P(Z within n observations) reaches the target. The
    trace of additions and P(Z) is kept on the analysis (``strategy_trace``); when
    points were added, its last entry (``"checked": true``) is P(Z) after the added
    triplets met the probes."""
    strategy = config.learning_strategy
    report = progress or (lambda stage, frac: None)
    if strategy is None:
        return analyse(world, config, None, progress)
    a = analyse(world, config, None, lambda stage, frac: report(stage, 0.5 * frac))
    t0 = time.perf_counter()

    def step(st: LearningStep) -> None:
        done = len(trace) / max(1, strategy.max_additions)
        trace.append({"added": st.added, "learning_points": st.learning_points,
                      "triplets": st.triplets, "p_z": st.p_z, "twin": st.twin})
        report(f"learning strategy: {st.learning_points} points, P(Z within "
               f"{strategy.n_observations}) {st.p_z[-1]:.2f}", 0.5 + 0.5 * min(1.0, done))

    trace: list[dict[str, object]] = []
    res = learning_strategy(a, world, strategy, np.random.default_rng(config.seed + 11),
                            executor=executor, progress=step)
    out = res.analysis
    if res.additions:
        # the added points have no twin learning point in a symmetric room: their
        # triplets against far places, with denser probes and grown regions
        report("checking the new regions", 0.98)
        dense = config.model_copy(update={"entry": config.entry.model_copy(update={
            "samples": PROBE_DENSITY * config.entry.samples})})
        probes = SimulatedCamera(world, dense, np.random.default_rng(config.seed + 13)
                                 ).entry_observations(out.model)
        new = np.asarray((out.triplets.point_idx >= len(a.model.points)).any(axis=1))
        kept = probe_validated(out.triplets, out.model, out.c_a, config, probes,
                               PROBE_MARGIN, new)
        sets = candidate_multiple_sets(RegionModel.of(out.model, kept, out.c_a,
                                                      config.regions))
        out = replace(out, triplets=kept, candidate_sets=sets,
                      rejected_triplets=out.rejected_triplets + len(out.triplets) - len(kept))
        # P(Z) of what is left, as the last entry of the trace
        curve, _ = p_z_curve(strategy_samples(world, config), out.layout(world),
                             config.strategy,
                             strategy.n_observations, executor)
        trace.append({"added": None, "learning_points": len(out.model.points),
                      "triplets": len(kept), "p_z": curve, "checked": True})
    timings = dict(out.timings_s, learning_strategy=time.perf_counter() - t0)
    report("done", 1.0)
    return replace(out, timings_s=timings, strategy_trace=trace)
