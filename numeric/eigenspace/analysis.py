"""The analysis pipeline: learn -> triplets -> eq.-6 constant -> eq.-7 entry model ->
candidate-multiple sets, read top to bottom (paper §2-§3), plus (de)serialisation.
"""

from __future__ import annotations

import io
import json
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from numeric.camera import Camera, CameraConfig
from numeric.eigenspace.learning import (
    EigenspaceModel,
    LearningConfig,
    add_learning_point,
    learn,
    learning_grid,
)
from numeric.eigenspace.localization import (
    LocalizationConfig,
    RegionModel,
    agrees,
    candidate_multiple_sets,
)
from numeric.eigenspace.movement_strategy import RegionLayout, StrategyConfig
from numeric.eigenspace.regions import (
    EntryModel,
    RegionConfig,
    calibration_observations,
    false_admissions,
    fit_c_a,
    fit_entry_model,
    real_world_distance,
    region_candidates,
)
from numeric.eigenspace.triplets import TripletConfig, Triplets, find_localizable_triplets, merge
from numeric.errors import InvalidInput
from numeric.world import World

Progress = Callable[[str, float], None]


class EntryFitConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    samples: int = Field(150, ge=10, le=20_000, description="observation poses for eq. 7")
    max_distance_m: float = Field(3.0, gt=0.0, le=100.0)


class EigenspaceConfig(BaseModel):
    """Everything the analysis needs; defaults follow the paper (converted to SI)."""

    model_config = ConfigDict(extra="forbid")
    camera: CameraConfig = CameraConfig()
    learning: LearningConfig = LearningConfig()
    triplets: TripletConfig = TripletConfig()
    regions: RegionConfig = RegionConfig()
    entry: EntryFitConfig = EntryFitConfig()
    localization: LocalizationConfig = LocalizationConfig()
    strategy: StrategyConfig = StrategyConfig()
    seed: int = Field(0, ge=0)


@dataclass
class EigenspaceAnalysis:
    config: EigenspaceConfig
    model: EigenspaceModel
    triplets: Triplets
    c_a: float
    entry: EntryModel
    candidate_sets: list[list[int]]
    timings_s: dict[str, float] = field(default_factory=dict)
    rejected_triplets: int = 0

    @property
    def regions(self) -> RegionModel:
        return RegionModel(self.model, self.triplets, self.c_a, self.config.regions.d_thd_m)

    def set_of(self) -> np.ndarray:
        s = np.full(len(self.triplets), -1, dtype=int)
        for m, members in enumerate(self.candidate_sets):
            s[members] = m
        return s

    def layout(self, world: World) -> RegionLayout:
        surf = world.surfaces
        return RegionLayout(self.entry, self.model.points[self.triplets.point_idx],
                            self.set_of(), (surf.a, surf.b))

    def coverage(self, world: World, cell_m: float = 0.2) -> float:
        """Localizable area: share of the free space where one observation enters some
        region with probability >= 0.5, i.e. 1 - prod_l (1 - P(R^(l)|s)) >= 0.5 (eq. 7)."""
        grid = free_grid(world, cell_m)
        if len(grid) == 0:
            return 0.0
        return float(np.mean(self.layout(world).p_any(grid) >= 0.5))

    def summary(self, world: World) -> dict[str, object]:
        return {"images": int(len(self.model.points) * len(self.model.directions)),
                "learning_points": len(self.model.points),
                "directions": len(self.model.directions), "k": self.model.k,
                "image_shape": list(self.model.image_shape),
                "triplets": len(self.triplets), "candidate_sets": len(self.candidate_sets),
                "rejected_triplets": self.rejected_triplets,
                "c_a": self.c_a, "d_thd_m": self.config.regions.d_thd_m,
                "entry_model": {"c0": self.entry.c0, "c1_per_m": self.entry.c1},
                "region_coverage": self.coverage(world), "timings_s": self.timings_s}

    # -- persistence ----------------------------------------------------------------
    def to_bytes(self) -> bytes:
        buf = io.BytesIO()
        m, t = self.model, self.triplets
        meta = {"config": self.config.model_dump(mode="json"), "c_a": self.c_a,
                "entry": [self.entry.c0, self.entry.c1], "sets": self.candidate_sets,
                "image_shape": list(m.image_shape),
                "normalize_brightness": m.normalize_brightness, "timings_s": self.timings_s,
                "rejected_triplets": self.rejected_triplets}
        np.savez_compressed(buf, points=m.points, directions=m.directions, mean=m.mean,
                            basis=m.basis, projections=m.projections, t_points=t.point_idx,
                            t_dirs=t.dir_idx, t_target=t.target, t_area=t.area,
                            meta=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8))
        return buf.getvalue()

    @staticmethod
    def from_bytes(blob: bytes) -> EigenspaceAnalysis:
        z = np.load(io.BytesIO(blob), allow_pickle=False)
        meta = json.loads(z["meta"].tobytes().decode())
        model = EigenspaceModel(points=z["points"], directions=z["directions"], mean=z["mean"],
                                basis=z["basis"], projections=z["projections"],
                                image_shape=tuple(meta["image_shape"]),  # type: ignore[arg-type]
                                normalize_brightness=bool(meta["normalize_brightness"]))
        tr = Triplets(z["t_points"], z["t_dirs"], z["t_target"], z["t_area"])
        return EigenspaceAnalysis(EigenspaceConfig.model_validate(meta["config"]), model, tr,
                                  float(meta["c_a"]), EntryModel(*meta["entry"]),
                                  [list(s) for s in meta["sets"]], dict(meta["timings_s"]),
                                  int(meta.get("rejected_triplets", 0)))


def free_grid(world: World, cell_m: float) -> np.ndarray:
    lo, hi = world.bounds
    xs = np.arange(lo[0] + cell_m / 2, hi[0], cell_m)
    ys = np.arange(lo[1] + cell_m / 2, hi[1], cell_m)
    g = np.array([(x, y) for y in ys for x in xs]).reshape(-1, 2)
    return g[world.is_free(g)]


def fit_entry(world: World, camera: Camera, model: EigenspaceModel, triplets: Triplets,
              c_a: float, config: EigenspaceConfig, rng: np.random.Generator) -> EntryModel:
    """§3.2: observe full turns at poses spread over the room, record which regions
    each turn enters and D(s), and fit eq. 7.

    The paper assumes an entered region is the right one; here an entry counts only
    when its interpolated pose agrees with the true pose within the localization
    tolerances, so false entries do not inflate P(R|s)."""
    xy = world.sample_free(config.entry.samples, rng)
    n = len(model.directions)
    loc = config.localization
    entered = np.zeros((len(xy), len(triplets)), dtype=bool)
    for i, p in enumerate(xy):
        th0 = rng.uniform(-np.pi, np.pi)
        q = model.project(camera.render_turn(p, th0, n))
        c = region_candidates(model, triplets, q, c_a, config.regions.d_thd_m)
        truth = np.column_stack([np.broadcast_to(p, (len(c), 2)), th0 + 2.0 * np.pi * c.m / n])
        ok = agrees(c.pose, truth, loc.same_position_m, loc.same_heading_rad)
        entered[i, c.t[ok]] = True
    dist = real_world_distance(model, triplets, xy)
    return fit_entry_model(dist, entered, config.entry.max_distance_m)


def analyse(world: World, config: EigenspaceConfig, points: np.ndarray | None = None,
            progress: Progress | None = None) -> EigenspaceAnalysis:
    """Learn and analyse ``world`` (§2.1-§3.3).  ``points`` defaults to the learning grid."""
    import time

    report = progress or (lambda stage, frac: None)
    rng = np.random.default_rng(config.seed)
    camera = Camera(world, config.camera, rng=np.random.default_rng(config.seed + 1))
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    pts = learning_grid(world, config.learning.spacing_m, config.learning.margin_m) \
        if points is None else np.asarray(points, dtype=float).reshape(-1, 2)
    report("learning", 0.0)
    model = learn(camera, pts, config.learning)
    timings["learning"] = time.perf_counter() - t0
    report("triplets", 0.3)
    t0 = time.perf_counter()
    triplets = find_localizable_triplets(model, config.triplets)
    timings["triplets"] = time.perf_counter() - t0
    if len(triplets) == 0:
        raise InvalidInput("no localizable triplets: learn more directions or more points",
                           field="learning")
    report("region model", 0.4)
    t0 = time.perf_counter()
    c_a = config.regions.c_a
    if c_a is None:
        ts, d, err = calibration_observations(world, camera, model, triplets,
                                              config.regions.calibration_per_triplet, rng)
        c_a = fit_c_a(d, triplets.area[ts], err)
    found = len(triplets)
    triplets = validated(triplets, model, c_a, config)
    if len(triplets) == 0:
        raise InvalidInput(f"all {found} localizable triplets place other learning images "
                           "wrong: learn more points or directions", field="learning")
    timings["region_model"] = time.perf_counter() - t0
    report("entry model", 0.6)
    t0 = time.perf_counter()
    entry = fit_entry(world, camera, model, triplets, c_a, config, rng)
    timings["entry_model"] = time.perf_counter() - t0
    report("candidate sets", 0.9)
    t0 = time.perf_counter()
    regions = RegionModel(model, triplets, c_a, config.regions.d_thd_m)
    sets = candidate_multiple_sets(regions)
    timings["candidate_sets"] = time.perf_counter() - t0
    report("done", 1.0)
    return EigenspaceAnalysis(config, model, triplets, c_a, entry, sets, timings,
                              rejected_triplets=found - len(triplets))


def validated(triplets: Triplets, model: EigenspaceModel, c_a: float,
              config: EigenspaceConfig) -> Triplets:
    """The triplets without false admissions (:func:`false_admissions`; all of them
    when ``regions.reject_false_admissions`` is off)."""
    if not config.regions.reject_false_admissions or len(triplets) == 0:
        return triplets
    loc = config.localization
    bad = false_admissions(model, triplets, c_a, config.regions.d_thd_m,
                           loc.same_position_m, loc.same_heading_rad)
    return triplets.subset(np.flatnonzero(bad == 0))


def with_learning_point(analysis: EigenspaceAnalysis, world: World,
                        point: np.ndarray) -> EigenspaceAnalysis:
    """§4.2 step 3: learn at one more point and redo the triplet search for the triples
    that contain it (c_a and the entry model are kept), then the candidate sets."""
    cfg = analysis.config
    camera = Camera(world, cfg.camera, rng=np.random.default_rng(cfg.seed + 1))
    model = add_learning_point(analysis.model, camera, point)
    new = find_localizable_triplets(model, cfg.triplets, only_with={len(model.points) - 1})
    merged = merge(analysis.triplets, new)
    # the new point's images may show that an old triplet's region admits them wrongly
    triplets = validated(merged, model, analysis.c_a, cfg)
    regions = RegionModel(model, triplets, analysis.c_a, cfg.regions.d_thd_m)
    sets = candidate_multiple_sets(regions)
    return EigenspaceAnalysis(cfg, model, triplets, analysis.c_a, analysis.entry, sets,
                              dict(analysis.timings_s),
                              analysis.rejected_triplets + len(merged) - len(triplets))
