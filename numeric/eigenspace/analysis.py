"""The analysis pipeline: learn -> triplets -> eq.-6 constant -> eq.-7 entry model ->
candidate-multiple sets, read top to bottom (paper §2-§3), plus (de)serialisation.

The images come from an :class:`ImageSource`: :class:`SimulatedCamera` renders them in
the world (the paper's experiments, §5), :class:`ImportedImages` takes a user's own
camera's learning images (:mod:`chizu.numeric.eigenspace.image_sets`). The pipeline is the
same; only where c_a's and eq. 7's observations come from differs.
"""

from __future__ import annotations

import io
import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from chizu.numeric.camera import Camera, CameraConfig
from chizu.numeric.eigenspace.image_sets import ImageSet
from chizu.numeric.eigenspace.learning import (
    EigenspaceModel,
    LearningConfig,
    LearningStrategyConfig,
    add_learning_point,
    learn_images,
    learning_grid,
    render_learning_images,
)
from chizu.numeric.eigenspace.localization import (
    LocalizationConfig,
    RegionModel,
    agrees,
    candidate_multiple_sets,
)
from chizu.numeric.eigenspace.movement_strategy import RegionLayout, StrategyConfig
from chizu.numeric.eigenspace.regions import (
    Candidates,
    EntryModel,
    RegionConfig,
    calibration_errors,
    calibration_pairs,
    calibration_poses,
    false_admissions,
    fit_c_a,
    fit_clamped_line,
    fit_entry_model,
    leave_one_out_pairs,
    real_world_distance,
    region_candidates,
)
from chizu.numeric.eigenspace.triplets import (
    TripletConfig,
    Triplets,
    find_localizable_triplets,
    merge,
)
from chizu.numeric.errors import InvalidInput
from chizu.numeric.geometry import wrap_angle
from chizu.numeric.world import World

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
    learning_strategy: LearningStrategyConfig | None = Field(
        LearningStrategyConfig(),
        description="§4.2: after the grid, add learning points until P(Z within n "
                    "observations) reaches the target (simulator only: ignored for a "
                    "camera's images); null: the grid alone")
    seed: int = Field(0, ge=0)


def stored_config(data: dict[str, object]) -> EigenspaceConfig:
    """The config an analysis was learned with. Bounds added since (the movement
    strategy's action lists) must not make a stored analysis unreadable: a part that no
    longer validates falls back to its defaults."""
    try:
        return EigenspaceConfig.model_validate(data)
    except ValidationError as e:
        bad = {str(err["loc"][0]) for err in e.errors() if err["loc"]}
        return EigenspaceConfig.model_validate({k: v for k, v in data.items() if k not in bad})


@dataclass
class EigenspaceAnalysis:
    config: EigenspaceConfig
    model: EigenspaceModel
    triplets: Triplets
    c_a: float
    entry: EntryModel | None  # None: a camera's images without calibration images
    candidate_sets: list[list[int]]
    timings_s: dict[str, float] = field(default_factory=dict)
    rejected_triplets: int = 0
    source: str = "simulator"  # or "images": a user's camera (no simulator to add points)
    # §4.2's additions, one entry per step: added [x, y] or None, points, triplets, P(Z)
    strategy_trace: list[dict[str, object]] = field(default_factory=list)

    @property
    def regions(self) -> RegionModel:
        return RegionModel.of(self.model, self.triplets, self.c_a, self.config.regions)

    @property
    def localization(self) -> LocalizationConfig:
        """How this room localizes: the configuration's, without the whole-turn check
        where learning found the room symmetric (§4.2 learned an added point's twin).
        There a look-alike place explains a whole turn as well as the right one, and the
        admissions may name only one of the two (docs/notes/eigenspace.md, "Why a turn is
        also checked whole")."""
        loc = self.config.localization
        if any(t.get("twin") for t in self.strategy_trace):
            return loc.model_copy(update={"turn_check_fd": None})
        return loc

    def set_of(self) -> np.ndarray:
        s = np.full(len(self.triplets), -1, dtype=int)
        for m, members in enumerate(self.candidate_sets):
            s[members] = m
        return s

    def layout(self, world: World) -> RegionLayout:
        if self.entry is None:
            raise InvalidInput("this eigenspace has no entry model (eq. 7), which the "
                               "movement and learning strategies need: learn it with "
                               "calibration images (role 'calibrate' in poses.csv)",
                               field="calibration")
        surf = world.surfaces
        return RegionLayout(self.entry, self.model.points[self.triplets.point_idx],
                            self.set_of(), (surf.a, surf.b), self.model.points)

    def coverage(self, world: World, cell_m: float = 0.2) -> float | None:
        """Localizable area: share of the free space where one observation enters some
        region with probability >= 0.5, i.e. 1 - prod_l (1 - P(R^(l)|s)) >= 0.5 (eq. 7)."""
        if self.entry is None:
            return None
        return self.coverage_map(world, cell_m).share

    def coverage_map(self, world: World, cell_m: float = 0.2) -> CoverageMap:
        """Eq. 7's 1 - prod_l (1 - P(R^(l)|s)) on a raster of the world's bounds: where
        one turn enters some localizable region, and where the floor is thin."""
        xs, ys = raster_axes(world, cell_m)
        cells = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
        p = np.full(len(cells), np.nan)
        free = world.is_free(cells) if len(cells) else np.zeros(0, dtype=bool)
        if free.any():
            p[free] = self.layout(world).p_any(cells[free])
        return CoverageMap(origin=np.asarray(world.bounds[0], dtype=float), cell_m=cell_m,
                           p_enter=p.reshape(len(ys), len(xs)))

    def summary(self, world: World) -> dict[str, object]:
        return {"images": int(len(self.model.points) * len(self.model.directions)),
                "learning_points": len(self.model.points),
                "directions": len(self.model.directions), "k": self.model.k,
                "image_shape": list(self.model.image_shape),
                "triplets": len(self.triplets), "candidate_sets": len(self.candidate_sets),
                "rejected_triplets": self.rejected_triplets, "source": self.source,
                "c_a": self.c_a, "d_thd_m": self.config.regions.d_thd_m,
                "entry_model": None if self.entry is None else
                {"c0": self.entry.c0, "c1_per_m": self.entry.c1},
                "region_coverage": self.coverage(world),
                "learning_strategy": self.strategy_trace or None, "timings_s": self.timings_s}

    # -- persistence ----------------------------------------------------------------
    def to_bytes(self) -> bytes:
        buf = io.BytesIO()
        m, t = self.model, self.triplets
        meta = {"config": self.config.model_dump(mode="json"), "c_a": self.c_a,
                "entry": None if self.entry is None else [self.entry.c0, self.entry.c1],
                "sets": self.candidate_sets,
                "image_shape": list(m.image_shape),
                "normalize_brightness": m.normalize_brightness, "timings_s": self.timings_s,
                "rejected_triplets": self.rejected_triplets, "source": self.source,
                "strategy_trace": self.strategy_trace}
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
        return EigenspaceAnalysis(stored_config(meta["config"]), model, tr,
                                  float(meta["c_a"]),
                                  None if meta["entry"] is None else EntryModel(*meta["entry"]),
                                  [list(s) for s in meta["sets"]], dict(meta["timings_s"]),
                                  int(meta.get("rejected_triplets", 0)),
                                  str(meta.get("source", "simulator")),
                                  list(meta.get("strategy_trace", [])))


@dataclass
class CoverageMap:
    """P(some region is entered by one turn) per cell ``p_enter (rows, cols)`` (NaN where
    the floor is not free), row ``i`` and column ``j`` centred at ``origin + cell_m
    (j + 1/2, i + 1/2)``; covered where it is at least 0.5."""

    origin: np.ndarray
    cell_m: float
    p_enter: np.ndarray

    @property
    def share(self) -> float:
        """The covered share of the free cells (0 when none is free)."""
        free = self.p_enter[np.isfinite(self.p_enter)]
        return float(np.mean(free >= 0.5)) if len(free) else 0.0


def raster_axes(world: World, cell_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The cell centres along x and along y of a raster of ``cell_m`` over the world's
    bounds (row by row: y outer, x inner)."""
    lo, hi = world.bounds
    return (np.arange(lo[0] + cell_m / 2, hi[0], cell_m),
            np.arange(lo[1] + cell_m / 2, hi[1], cell_m))


def free_grid(world: World, cell_m: float) -> np.ndarray:
    """The centres ``(n, 2)`` of the raster's cells on free floor."""
    xs, ys = raster_axes(world, cell_m)
    g = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    return g[world.is_free(g)]


@dataclass
class EntryObservations:
    """Full turns for fitting eq. 7: taken at ``xy (S, 2)``, the first image at heading
    ``theta0 (S,)``, projected ``(S, Nt, K)``."""

    xy: np.ndarray
    theta0: np.ndarray
    projections: np.ndarray


class ImageSource:
    """Where the analysis gets its images: the learning turns, the observations that
    fit c_a (eq. 6) and the turns that fit P(R|s) (eq. 7)."""

    name = "source"

    def learning_images(self, points: np.ndarray | None,
                        done: Callable[[float], None] | None = None,
                        ) -> tuple[np.ndarray, np.ndarray]:
        """``(points (Nw, 2), images (Nw, Nt, H, W))``; ``done(fraction)`` as they come."""
        raise NotImplementedError

    def calibration(self, model: EigenspaceModel, triplets: Triplets
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(triplet index (M,), pose (M, 3), projection (M, K))`` of observations of
        known pose, each paired with the triplet it calibrates."""
        raise NotImplementedError

    def entry_model(self, model: EigenspaceModel, triplets: Triplets,
                    c_a: float) -> EntryModel | None:
        """Eq. 7's P(R|s), or None when the images cannot tell it."""
        raise NotImplementedError

    def probes(self, model: EigenspaceModel) -> EntryObservations | None:
        """Full turns of known pose spread over the room, to find regions that admit
        far places (:func:`probe_validated`); None when the source has none."""
        return None


class SimulatedCamera(ImageSource):
    """The simulator's camera in ``world`` (§5: the paper's experiments)."""

    name = "simulator"

    def __init__(self, world: World, config: EigenspaceConfig,
                 rng: np.random.Generator) -> None:
        self.world, self.config, self.rng = world, config, rng
        self.camera = Camera(world, config.camera, rng=np.random.default_rng(config.seed + 1))
        self.recorded: dict[str, np.ndarray] = {}
        self._turns: EntryObservations | None = None

    def learning_images(self, points: np.ndarray | None,
                        done: Callable[[float], None] | None = None,
                        ) -> tuple[np.ndarray, np.ndarray]:
        lc = self.config.learning
        pts = learning_grid(self.world, lc.spacing_m, lc.margin_m) if points is None \
            else np.asarray(points, dtype=float).reshape(-1, 2)
        if len(pts) < 3:
            raise InvalidInput("at least 3 learning points are needed", field="points")
        imgs = render_learning_images(self.camera, pts, lc.n_directions, done)
        self.recorded.update(points=pts, turns=imgs)
        return pts, imgs

    def calibration(self, model: EigenspaceModel, triplets: Triplets
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        _, poses = calibration_poses(self.world, model, triplets,
                                     self.config.regions.calibration_per_triplet, self.rng)
        # rendered and projected in chunks: an office's 1 m grid has ~2 700 triplets, and
        # its ~11 000 supersampled renders at once took 2 GB
        step = 512
        imgs = np.concatenate([self.camera.render_many(poses[a:a + step])
                               for a in range(0, len(poses), step)])
        self.recorded.update(calib_poses=poses, calib_images=imgs)
        # paired by where they stand, as a user's calibration images are
        obs, t = calibration_pairs(model, triplets, poses)
        proj = np.concatenate([np.zeros((0, model.k))]
                              + [model.project(imgs[obs[a:a + step]])
                                 for a in range(0, len(obs), step)])
        return t, poses[obs], proj

    def entry_model(self, model: EigenspaceModel, triplets: Triplets,
                    c_a: float) -> EntryModel | None:
        return fit_entry(model, triplets, c_a, self.config, self.entry_observations(model))

    def probes(self, model: EigenspaceModel) -> EntryObservations | None:
        return self.entry_observations(model)

    def entry_observations(self, model: EigenspaceModel) -> EntryObservations:
        """§3.2: full turns at poses spread over the room (rendered once: the same turns
        find far admissions and fit eq. 7)."""
        if self._turns is not None:
            return self._turns
        xy = self.world.sample_free(self.config.entry.samples, self.rng)
        n = len(model.directions)
        th0 = np.empty(len(xy))
        proj = np.empty((len(xy), n, model.k))
        for i, p in enumerate(xy):
            th0[i] = self.rng.uniform(-np.pi, np.pi)
            proj[i] = model.project(self.camera.render_turn(p, th0[i], n))
        self._turns = EntryObservations(xy, th0, proj)
        return self._turns

    def image_set(self) -> ImageSet:
        """What this camera rendered for the learning and c_a, as an image set."""
        r = self.recorded
        return ImageSet(r["points"], r["turns"], r["calib_poses"], r["calib_images"])


class ImportedImages(ImageSource):
    """A user's camera: learning turns and optional calibration images of known pose.

    c_a comes from the calibration images inside the triplets' triangles (as in the
    simulator); with fewer than ``min_pairs`` of them, from the learning images of the
    neighbouring points (:func:`leave_one_out_pairs`, a safe but larger c_a). P(R|s)
    of eq. 7 comes from the calibration images and the learning turns together
    (:meth:`entry_model`)."""

    name = "images"

    def __init__(self, images: ImageSet, config: EigenspaceConfig, min_pairs: int = 8) -> None:
        self.images, self.config, self.min_pairs = images, config, min_pairs

    def learning_images(self, points: np.ndarray | None,
                        done: Callable[[float], None] | None = None,
                        ) -> tuple[np.ndarray, np.ndarray]:
        return self.images.points, self.images.turns

    def calibration(self, model: EigenspaceModel, triplets: Triplets
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        cal = self.images
        obs, t = calibration_pairs(model, triplets, cal.calib_poses)
        if len(obs) >= self.min_pairs:
            q = model.project(cal.calib_images[obs])
            return t, cal.calib_poses[obs], q
        w, j, t = leave_one_out_pairs(model, triplets, self.config.triplets.neighbour_max_m)
        poses = np.column_stack([model.points[w], model.directions[j]])
        return t, poses, model.projections[w, j]

    def entry_model(self, model: EigenspaceModel, triplets: Triplets,
                    c_a: float) -> EntryModel | None:
        """Eq. 7 from observations of known pose: the calibration images inside the
        triangles (D(s) to the paired triplet; entered when its region admits the image
        and places it right) pooled with each learning point's own turn as an
        observation of the regions it is not part of (§3.3 uses learning points as
        observations the same way).

        The calibration images alone stand within 1.4 m of a point (room A), where P is
        still 0.2, so the clamp's zero crossing is unseen and a fit ran it out to 12 m;
        the learning turns add the zeros at one grid spacing and beyond (room A: 0.33 -
        0.16 D, the simulator's turns give 0.39 - 0.29 D). None with fewer than
        ``min_pairs`` calibration images: the learning turns alone hold only zeros (a
        validated region admits no other learning image wrongly and hardly any from
        outside its triangle), and the movement strategy, which needs eq. 7, is then
        unavailable."""
        cal, r, loc = self.images, self.config.regions, self.config.localization
        obs, t = calibration_pairs(model, triplets, cal.calib_poses)
        if len(obs) < self.min_pairs:
            return None
        poses = cal.calib_poses[obs]
        c = region_candidates(model, triplets, model.project(cal.calib_images[obs]), c_a,
                              r.d_thd_m, r.plane_thd_m)
        mine = (c.t == t[c.m]) & agrees(c.pose, poses[c.m], loc.same_position_m,
                                        loc.same_heading_rad)
        y_cal = np.zeros(len(obs))
        y_cal[c.m[mine]] = 1.0
        x_cal = real_world_distance(model, triplets, poses[:, :2])[np.arange(len(obs)), t]
        n_w = len(model.points)
        turns = EntryObservations(model.points, np.full(n_w, model.directions[0]),
                                  model.projections)
        entered = right_entries(model, triplets, c_a, self.config, turns)
        dist = real_world_distance(model, triplets, model.points)
        near = ~triplets.membership(n_w) & (dist <= self.config.entry.max_distance_m)
        x = np.concatenate([x_cal, dist[near]])
        y = np.concatenate([y_cal, entered[near]])
        return EntryModel(*fit_clamped_line(x, y, self.config.entry.max_distance_m))


def placed_hits(model: EigenspaceModel, triplets: Triplets, c_a: float,
                config: EigenspaceConfig, obs: EntryObservations, margin: float = 1.0
                ) -> Iterator[tuple[int, Candidates, np.ndarray]]:
    """For each turn of known pose in ``obs``: its region hits (eq. 6, the regions grown
    by ``margin``) and whether eq. 5 places each within the localization tolerances."""
    n = len(model.directions)
    r, loc = config.regions, config.localization
    plane = None if r.plane_thd_m is None else margin * r.plane_thd_m
    for i, p in enumerate(obs.xy):
        c = region_candidates(model, triplets, obs.projections[i], c_a, margin * r.d_thd_m,
                              plane)
        truth = np.column_stack([np.broadcast_to(p, (len(c), 2)),
                                 wrap_angle(obs.theta0[i] + 2.0 * np.pi * c.m / n)])
        yield i, c, agrees(c.pose, truth, loc.same_position_m, loc.same_heading_rad)


def right_entries(model: EigenspaceModel, triplets: Triplets, c_a: float,
                  config: EigenspaceConfig, obs: EntryObservations) -> np.ndarray:
    """``(S, T)``: which regions each observed turn enters *and* is placed right in,
    within the localization tolerances (the paper assumes an entered region is the
    right one; counting only right entries keeps false ones out of P(R|s))."""
    entered = np.zeros((len(obs.xy), len(triplets)), dtype=bool)
    for i, c, ok in placed_hits(model, triplets, c_a, config, obs):
        entered[i, c.t[ok]] = True
    return entered


def fit_entry(model: EigenspaceModel, triplets: Triplets, c_a: float,
              config: EigenspaceConfig, obs: EntryObservations) -> EntryModel:
    """§3.2: record which regions each observed turn enters rightly
    (:func:`right_entries`) and D(s), and fit eq. 7."""
    return fit_entry_model(real_world_distance(model, triplets, obs.xy),
                           right_entries(model, triplets, c_a, config, obs),
                           config.entry.max_distance_m)


def learning_pixels(world: World, config: EigenspaceConfig) -> int:
    """An upper bound of the pixels a simulator learning renders, known before any
    work: the grid's points (before those near walls are dropped) plus §4.2's
    additions, times N_theta images of W x H pixels, each supersampled."""
    lo, hi = world.bounds
    lc = config.learning
    span = np.maximum(hi - lo - 2 * lc.margin_m, 0.0)
    points = int(np.prod(np.floor(span / lc.spacing_m) + 1))
    if config.learning_strategy is not None:
        points += config.learning_strategy.max_additions
    cam = config.camera
    return points * lc.n_directions * cam.width_px * cam.height_px * cam.supersample**2


def analyse(world: World, config: EigenspaceConfig, points: np.ndarray | None = None,
            progress: Progress | None = None) -> EigenspaceAnalysis:
    """Learn and analyse ``world`` in the simulator (§2.1-§3.3).  ``points`` defaults
    to the learning grid; the learning strategy's additions (§4.2) are
    :func:`chizu.numeric.eigenspace.learning_strategy.learn_with_strategy`."""
    source = SimulatedCamera(world, config, np.random.default_rng(config.seed))
    return analyse_source(world, config, source, points, progress)


def analyse_images(world: World, images: ImageSet, config: EigenspaceConfig,
                   progress: Progress | None = None) -> EigenspaceAnalysis:
    """Analyse a user's learning images of ``world`` (§2.1-§3.3); the world's walls give
    the free space for coverage and the movement strategy, its textures are not used.
    N_theta and the image size come from the images (the camera settings are ignored)."""
    h, w = images.image_shape
    config = config.model_copy(update={
        "learning_strategy": None,  # no simulator to render added points in
        "learning": config.learning.model_copy(update={"n_directions": images.n_directions}),
        "camera": config.camera.model_copy(update={"width_px": w, "height_px": h})})
    return analyse_source(world, config, ImportedImages(images, config), None, progress)


def render_image_set(world: World, config: EigenspaceConfig,
                     points: np.ndarray | None = None) -> tuple[ImageSet, EigenspaceAnalysis]:
    """The simulator's learning and calibration images (and the analysis they gave)."""
    source = SimulatedCamera(world, config, np.random.default_rng(config.seed))
    a = analyse_source(world, config, source, points)
    return source.image_set(), a


def analyse_source(world: World, config: EigenspaceConfig, source: ImageSource,
                   points: np.ndarray | None = None,
                   progress: Progress | None = None) -> EigenspaceAnalysis:
    """The analysis pipeline on ``source``'s images, step by step as in §2-§3."""
    import time

    report = progress or (lambda stage, frac: None)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    report("learning", 0.0)
    # rendering is the long part: report (and let a cancelled job stop) after each point
    pts, imgs = source.learning_images(points, lambda f: report("learning", 0.3 * f))
    model = learn_images(imgs, pts, config.learning)
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
        ts, poses, query = source.calibration(model, triplets)
        if len(ts) == 0:
            raise InvalidInput("no observation of known pose near any triplet to fit c_a "
                               "with: give regions.c_a or calibration images",
                               field="regions.c_a")
        d, err = calibration_errors(model, triplets, ts, poses, query)
        c_a = fit_c_a(d, triplets.area[ts], err)
    found = len(triplets)
    triplets = validated(triplets, model, c_a, config)
    probes = source.probes(model) if len(triplets) else None
    if probes is not None:
        triplets = probe_validated(triplets, model, c_a, config, probes)
    if len(triplets) == 0:
        raise InvalidInput(f"all {found} localizable triplets place other learning images "
                           "wrong: learn more points or directions", field="learning")
    timings["region_model"] = time.perf_counter() - t0
    report("entry model", 0.6)
    t0 = time.perf_counter()
    entry = source.entry_model(model, triplets, c_a)
    timings["entry_model"] = time.perf_counter() - t0
    report("candidate sets", 0.9)
    t0 = time.perf_counter()
    sets = candidate_multiple_sets(RegionModel.of(model, triplets, c_a, config.regions))
    timings["candidate_sets"] = time.perf_counter() - t0
    report("done", 1.0)
    return EigenspaceAnalysis(config, model, triplets, c_a, entry, sets, timings,
                              rejected_triplets=found - len(triplets), source=source.name)


def validated(triplets: Triplets, model: EigenspaceModel, c_a: float,
              config: EigenspaceConfig) -> Triplets:
    """The triplets without false admissions (:func:`false_admissions`; all of them
    when ``regions.reject_false_admissions`` is off). Twins (look-alike places) stay
    when a candidate-multiple set (§3.3) groups them, so a session sees the confusion
    as state Y; twins no set groups would give confident wrong answers and go."""
    if not config.regions.reject_false_admissions or len(triplets) == 0:
        return triplets
    loc, r = config.localization, config.regions
    while len(triplets):  # again until stable: a dropped twin leaves its partner bare
        bad, twins = false_admissions(model, triplets, c_a, r.d_thd_m, loc.same_position_m,
                                      loc.same_heading_rad, r.plane_thd_m)
        keep = np.flatnonzero(bad == 0)
        if twins:
            sets = candidate_multiple_sets(RegionModel.of(model, triplets.subset(keep), c_a,
                                                          r))
            set_of = np.full(len(triplets), -1)
            for m, members in enumerate(sets):
                set_of[keep[members]] = m
            drop = {t for a, b in twins if set_of[a] < 0 or set_of[a] != set_of[b]
                    for t in (a, b)}
            keep = np.array([t for t in keep if int(t) not in drop], dtype=int)
        if len(keep) == len(triplets):
            break
        triplets = triplets.subset(keep)
    return triplets


def far_admissions(model: EigenspaceModel, triplets: Triplets, c_a: float,
                   config: EigenspaceConfig, probes: EntryObservations,
                   set_of: np.ndarray, margin: float = 1.0) -> np.ndarray:
    """``(T,)``: how many probe images each triplet's region admits (eq. 6) from more
    than twice the position tolerance away and places wrong (eq. 5), not counting
    triplets of a candidate-multiple set (a session that only hits one set stays in
    state Y, §3.3). With ``margin`` > 1 the region is grown by that factor: a region
    that nearly admits a far place admits it from a spot nearby, and sparse probes miss
    the spot."""
    return probe_tally(model, triplets, c_a, config, probes, set_of, margin)[0]


def wrong_placements(model: EigenspaceModel, triplets: Triplets, c_a: float,
                     config: EigenspaceConfig, probes: EntryObservations,
                     set_of: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(T,)`` twice: how many probe turns each triplet's region admits (eq. 6), and
    how many of those it places wrong (eq. 5: some admitted image of the turn lands
    beyond the localization tolerances), not counting triplets of a candidate-multiple
    set (their look-alike is the twin's place, §3.3)."""
    _, hits, wrong = probe_tally(model, triplets, c_a, config, probes, set_of)
    return hits, wrong


def probe_tally(model: EigenspaceModel, triplets: Triplets, c_a: float,
                config: EigenspaceConfig, probes: EntryObservations, set_of: np.ndarray,
                margin: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One pass of the region test over the probe turns, with regions grown by
    ``margin``: :func:`far_admissions`' counts, and :func:`wrong_placements`' admitted
    and wrongly placed turns per triplet."""
    far_m = 2 * config.localization.same_position_m
    far_bad = np.zeros(len(triplets), dtype=int)
    hits = np.zeros(len(triplets), dtype=int)
    wrong = np.zeros(len(triplets), dtype=int)
    for i, c, ok in placed_hits(model, triplets, c_a, config, probes, margin):
        corners = model.points[triplets.point_idx[c.t]]                      # (h, 3, 2)
        far = np.linalg.norm(corners - probes.xy[i], axis=2).min(axis=1) > far_m
        bad = ~ok & far & (set_of[c.t] < 0)
        far_bad += np.bincount(c.t[bad], minlength=len(triplets))
        hits[np.unique(c.t)] += 1
        wrong[np.unique(c.t[~ok])] += 1
    wrong[set_of >= 0] = 0
    return far_bad, hits, wrong


def probe_validated(triplets: Triplets, model: EigenspaceModel, c_a: float,
                    config: EigenspaceConfig, probes: EntryObservations,
                    margin: float = 1.0, only: np.ndarray | None = None) -> Triplets:
    """The triplets whose regions admit no far place wrongly (:func:`far_admissions`),
    with the simulator's turns as probes; again until stable, as a dropped triplet can
    dissolve a candidate-multiple set.

    :func:`validated` can only use the learning images, so a look-alike place with no
    learning point near it goes unseen: in a room symmetric under a half turn, the
    learning strategy's added points have no mirror point, their triplets form no set,
    and stops at the mirror place answered confidently on the wrong side (14 of 32
    localized runs). The paper's intent (§2.3-§2.4: a region bounds the error) holds
    only if such triplets go; where the simulator renders, its turns find them.

    Near places count too: a triplet goes when more than ``regions.max_wrong_share``
    of the probe turns its region admits are placed wrong (:func:`wrong_placements`,
    at the region's own size). A region is a bound on the error (§2.4), and c_a is one
    constant for all triplets: some triplets' interpolation errs by 1-1.5 m or 15-30°
    inside their region. In room A at D_thd 0.3 m they made 15 % of the entered images
    wrong; without them, 5 %.
    ``only (T,)`` limits the check to some triplets (the others are kept)."""
    if not config.regions.reject_false_admissions:
        return triplets
    tested = np.ones(len(triplets), dtype=bool) if only is None else np.asarray(only, bool)
    while len(triplets):
        sets = candidate_multiple_sets(RegionModel.of(model, triplets, c_a, config.regions))
        set_of = np.full(len(triplets), -1)
        for m, members in enumerate(sets):
            set_of[members] = m
        # one pass gives both tests at the region's own size; grown regions need another
        far, hits, wrong = probe_tally(model, triplets, c_a, config, probes, set_of, margin)
        bad = far > 0
        share = config.regions.max_wrong_share
        if share is not None:
            if margin != 1.0:
                hits, wrong = wrong_placements(model, triplets, c_a, config, probes, set_of)
            bad |= wrong > share * hits
        keep = np.flatnonzero(~(bad & tested))
        if len(keep) == len(triplets):
            break
        triplets, tested = triplets.subset(keep), tested[keep]
    return triplets


def with_learning_point(analysis: EigenspaceAnalysis, world: World,
                        point: np.ndarray) -> EigenspaceAnalysis:
    """§4.2 step 3: learn at one more point and redo the triplet search for the triples
    that contain it (c_a and the entry model are kept), then the candidate sets."""
    cfg = analysis.config
    if analysis.source != "simulator":
        raise InvalidInput("learning points can be added in the simulator only; this "
                           "eigenspace was learned from a camera's images", field="source")
    camera = Camera(world, cfg.camera, rng=np.random.default_rng(cfg.seed + 1))
    model = add_learning_point(analysis.model, camera, point)
    new = find_localizable_triplets(model, cfg.triplets, only_with={len(model.points) - 1})
    merged = merge(analysis.triplets, new)
    # the new point's images may show that an old triplet's region admits them wrongly
    triplets = validated(merged, model, analysis.c_a, cfg)
    sets = candidate_multiple_sets(RegionModel.of(model, triplets, analysis.c_a, cfg.regions))
    return EigenspaceAnalysis(cfg, model, triplets, analysis.c_a, analysis.entry, sets,
                              dict(analysis.timings_s),
                              analysis.rejected_triplets + len(merged) - len(triplets),
                              analysis.source)
