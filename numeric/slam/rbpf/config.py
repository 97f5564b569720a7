"""The RBPF's parameters, one nested model per stage: the paper's filter
(:class:`RbpfConfig`, eqs. 6-9), Grisetti et al.'s improved proposal
(:class:`ImprovedConfig`), and within it the loop start, the relocalisation and the
odometry calibration. Why the defaults are what they are: ``docs/notes/slam-rbpf.md``.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, Field, model_validator

from chizu.numeric.slam.alignment import AlignmentConfig
from chizu.numeric.slam.gated import GateConfig
from chizu.numeric.slam.keyframes import FieldConfig, MapConfig
from chizu.numeric.slam.matching.intensity_icp import IcpConfig
from chizu.numeric.slam.matching.likelihood_field import LoopGrid, MatchModel
from chizu.numeric.threads import default_threads

Proposal = Literal["improved", "odometry", "gated-icp"]
Resample = Literal["always", "ess"]


class MotionNoise(BaseModel):
    """Σ_w of eq. 7, one sigma per component, growing with the increment."""

    xy_m: float = Field(0.01, ge=0)
    xy_per_m: float = Field(0.1, ge=0)
    xy_per_rad: float = Field(0.02, ge=0)
    theta_rad: float = Field(0.005, ge=0)
    theta_per_rad: float = Field(0.1, ge=0)
    theta_per_m: float = Field(0.05, ge=0)

    def sigmas(self, u: np.ndarray) -> np.ndarray:
        d, a = float(np.hypot(u[0], u[1])), abs(float(u[2]))
        sxy = self.xy_m + self.xy_per_m * d + self.xy_per_rad * a
        return np.array([sxy, sxy, self.theta_rad + self.theta_per_rad * a + self.theta_per_m * d])


class OdometryCalibrationConfig(BaseModel):
    """The motion model's heading sigma learned from the log
    (:mod:`chizu.numeric.slam.rbpf.odometry`)."""

    window: int = Field(200, ge=0, description="learned from the last this many updates "
                        "(:class:`~chizu.numeric.slam.pose_graph.OdometryCalibration`); 0: fixed")
    lag_m: float = Field(3.0, gt=0, description="each residual is the heading change since "
                         "the newest keyframe at least this much odometry path back, "
                         "matched against that keyframe alone, minus the odometry's")
    lag_headings_rad: tuple[float, ...] = Field(
        (0.0, -0.035, 0.035, -0.07, 0.07),
        description="heading offsets of that match's starts (the best by the scan alone "
                    "wins)")
    min_scale: float = Field(0.03, gt=0, le=1, description="... down to this share of the "
                             "fixed sigma")
    knee: float = Field(0.2, gt=0, le=1, description="a spread up to this is taken as it "
                        "is, one of twice this or more keeps the fixed sigma, linear in "
                        "between")


class LoopStartConfig(BaseModel):
    """The loop-aware start (:mod:`chizu.numeric.slam.rbpf.loop_start`): a wide search of the
    scan against the best particle's old keyframes every ``every`` updates."""

    every: int = Field(1, ge=1, description="updates between two searches")

    radius_m: float = Field(2.0, gt=0, description="half width of its position grid")
    step_m: float = Field(0.2, gt=0, description="... and its spacing")
    angle_rad: float = Field(0.1, ge=0, description="half width of its heading grid")
    angle_step_rad: float = Field(0.025, gt=0, description="... and its spacing")
    coarse_cutoff_m: float = Field(0.2, gt=0, description="residual cap of the grid")
    refine: int = Field(6, ge=1, description="grid poses refined by the scan matcher")
    inlier_m: float = Field(0.05, gt=0, description="a beam this close to the old map is "
                            "explained by it")
    min_fraction: float = Field(0.6, ge=0, le=1, description="the alternative must explain "
                                "this share of the beams")
    min_gain: float = Field(0.25, ge=0, le=1, description="... this share more than the "
                            "current estimate does")
    ambiguity: float = Field(0.15, ge=0, le=1, description="... and this share more than "
                             "any other refined pose at least min_sep_m away")
    min_sep_m: float = Field(0.3, gt=0, description="distinct modes are this far apart")
    min_eig: float = Field(5.0, ge=0, description="smallest eigenvalue of the position "
                           "block of J^T J at the alternative (~beams that pin down its "
                           "weakest direction; a corridor has ~0)")
    min_shift_m: float = Field(0.25, ge=0, description="smaller corrections are left to "
                               "the scan matcher")
    min_old: int = Field(3, ge=1, description="old keyframes needed to search")
    min_free_drop: float = Field(0.1, ge=0, le=1, description="the alternative must put "
                                 "this share of the beams fewer than the current estimate "
                                 "does where the old keyframes saw free space")
    free_cell_m: float = Field(0.1, ge=0.02, le=1.0, description="cell of that free-space "
                               "grid")
    free_margin_m: float = Field(0.1, ge=0, description="free cells this close to a cell "
                                 "not seen free do not count")
    persistence: int = Field(2, ge=1, description="consecutive updates that must agree on "
                             "the correction (within min_sep_m) before it is taken")

    @property
    def grid(self) -> LoopGrid:
        """The search's grid as the kernels take it."""
        return LoopGrid(float(self.radius_m), float(self.step_m), float(self.angle_rad),
                        float(self.angle_step_rad), float(self.coarse_cutoff_m ** 2),
                        int(self.refine), float(self.min_sep_m), float(self.inlier_m ** 2))


class RelocalisationConfig(BaseModel):
    """The relocalisation against the whole old map (:mod:`chizu.numeric.slam.rbpf.relocalisation`):
    a return from a loop farther off than the loop start's window."""

    every: int = Field(5, ge=1, description="updates between two searches")
    min_age_s: float = Field(120.0, ge=0, description="keyframes at least this old make the "
                             "old map")
    radius_m: float = Field(32.0, gt=0, description="... those the best particle placed "
                            "this close to its estimate")
    max_keyframes: int = Field(60, ge=3, description="... at most this many (evenly picked)")
    resolution_m: float = Field(0.1, gt=0, description="cell of its probability grid")
    window_m: float = Field(30.0, gt=0, description="half width of the branch-and-bound "
                            "window in position")
    angle_rad: float = Field(0.45, ge=0, description="... and in heading")
    min_score: float = Field(0.35, gt=0, le=1, description="mean probability of the cells "
                             "the scan falls in at the match")
    min_gain: float = Field(0.1, ge=0, le=1, description="... this much more than at the "
                            "current estimate")
    min_fraction: float = Field(0.3, ge=0, le=1, description="the refined match must explain "
                                "this share of the beams within the loop start's inlier_m")
    persistence: int = Field(3, ge=1, description="consecutive searches that must agree "
                             "(within the loop start's min_sep_m)")
    unique_m: float = Field(1.0, gt=0, description="no second pose this far from the match "
                            "...")
    unique_ratio: float = Field(0.9, gt=0, le=1, description="... scores this share of its "
                                "score")
    max_seen: float | None = Field(0.3, ge=0, le=1, description="a current estimate that "
                                   "puts at most this share of the returns in cells the old "
                                   "keyframes saw (free or hit) cannot be contradicted by "
                                   "them: the match then needs no drop in the free-space "
                                   "share, only its own below min_free_drop ... (None: the "
                                   "drop is always needed)")
    unseen_travel_m: float = Field(3.0, ge=0, description="... and the searches that agree "
                                   "on it must span this much of the estimate's path (a "
                                   "room that looks like an old one fits from where the "
                                   "robot stands)")
    drift_m: float = Field(1.0, ge=0, description="a relocalisation moves the estimate at "
                           "most this far ...")
    drift_per_m: float = Field(0.05, ge=0, description="... plus this much per m of "
                               "odometry path since the robot was last at the old "
                               "keyframes it matched (the drift it can have gathered since)")


class ImprovedConfig(BaseModel):
    """The improved proposal (Grisetti et al. 2007, §IV; :mod:`chizu.numeric.slam.rbpf.improved`).

    ``sigma_m`` is the σ of the likelihood field; ``cutoff_m`` caps each beam's
    residual (a return farther than that from every map point counts the same wherever
    the pose is); ``weight_gain`` tempers the log weight increments (GMapping divides
    them by ``ogain``); 1 is the paper's weight."""

    sigma_m: float = Field(0.05, gt=0, description="σ of the likelihood field (m)")
    cutoff_m: float = Field(0.3, gt=0, description="residual cap of the matcher and of "
                            "p(z|m,x) (at most the fields' own cutoff)")
    weight_gain: float = Field(0.01, gt=0, le=1.0,
                               description="log-weight increments are multiplied by this")
    sample_min_xy_m: float = Field(0.005, gt=0, description="smallest Δ of the samples (m)")
    sample_min_theta_rad: float = Field(0.002, gt=0, description="... and in heading (rad)")
    max_iterations: int = Field(12, ge=1, le=200, description="LM iterations of the matcher")
    min_match_fraction: float = Field(0.3, ge=0, le=1,
                                      description="match fails below this inlier fraction")
    min_inliers: int = Field(10, ge=1)
    start_margin: float = Field(50.0, ge=0, description="log-likelihood units another start "
                                "must beat the odometry start by")
    start_shifts_m: tuple[float, ...] = Field(
        (-0.6, -0.4, -0.2, 0.2, 0.4),
        description="further starts of that match, moved along the predicted heading by "
                    "these distances and matched on the scan alone (odometry that reads "
                    "forward while the robot backs up)")
    start_min_along: float = Field(0.0, ge=0, description="a shifted start wins only "
                                   "where its match pins the position down along the "
                                   "shift: the smallest ``J^T J`` along the heading, in "
                                   "beams (a corridor has ~0; 0: no test)")
    start_headings_rad: tuple[float, ...] = Field(
        (0.0, -0.1, 0.1, -0.2, 0.2, -0.35, 0.35),
        description="heading offsets of the multi-start match that corrects the odometry "
                    "increment once per update (one value: no correction)")
    odometry: OdometryCalibrationConfig = Field(default_factory=OdometryCalibrationConfig)
    loop: LoopStartConfig = Field(default_factory=LoopStartConfig)
    reloc: RelocalisationConfig | None = Field(default_factory=RelocalisationConfig,
                                               description="None: no relocalisation")

    def model(self, field_cutoff_m: float) -> MatchModel:
        """The matcher's constants: the residual cap (the smaller of ours and the
        fields' own), 1/(2σ²) and the iterations."""
        cut = min(self.cutoff_m, field_cutoff_m)
        return MatchModel(float(cut * cut), float(1.0 / (2.0 * self.sigma_m ** 2)),
                          int(self.max_iterations))


class RbpfConfig(BaseModel):
    """Parameters of the RBPF (paper: 512 particles, σ_z and alpha set empirically).

    ``update_linear_m`` / ``update_angular_rad``: the improved proposal updates the
    filter only after this much travel / turn by odometry (GMapping's ``linearUpdate`` /
    ``angularUpdate``); the scans in between follow the best particle's map
    (``track_scans``). ``map``: each particle's map is the keyframes it matches
    against, the last ``recent_keyframes`` and up to ``nearby_keyframes`` older ones
    within ``nearby_radius_m`` (an open scan reaches ``open_points_m``); the paper's
    proposals keep the reference their figures were made with (8 + 8 within 6 m) unless
    ``map`` is given. ``alignment``: the end of a run refines the best particle's
    trajectory by graph SLAM's global scan alignment (:mod:`chizu.numeric.slam.alignment`,
    after Lu & Milios 1997) -- a correction of centimetres that never re-decides a
    loop; the paper's proposals leave their estimate as it is unless it is given."""

    particles: int = Field(512, ge=1, le=4096)
    alpha: float = Field(0.0, ge=0, le=1.0, allow_inf_nan=False,
                         description="intensity weight of eqs. 1 and 9 (m² per unit²)")
    sigma_z: float = Field(0.0005, gt=0, le=10, allow_inf_nan=False,
                           description="sigma of eq. 8, in the units of d_t (m²)")
    beams: int = Field(90, ge=8, le=2000, description="beams used in eq. 9 (evenly picked)")
    proposal: Proposal = Field(
        "improved", description="odometry: eq. 7 on the odometry increment (the paper); "
        "gated-icp: eq. 7 on the increment Intensity-ICP finds for the best particle when "
        "eq. 5 accepts it, with noise scaled by proposal_noise_scale; improved: the "
        "scan-matched Gaussian proposal of Grisetti et al. 2007 for every particle")
    proposal_noise_scale: float = Field(0.3, gt=0)
    improved: ImprovedConfig = Field(default_factory=ImprovedConfig)
    track_scans: bool = Field(True, description="improved: a scan between two updates is "
                              "matched against the best particle's map for its own pose "
                              "(the particles are untouched); else it takes the odometry")
    update_linear_m: float = Field(0.2, ge=0, description="improved: update after this travel")
    update_angular_rad: float = Field(0.05, ge=0, description="improved: ... or this turn")
    icp: IcpConfig = Field(default_factory=IcpConfig)
    gate: GateConfig = Field(default_factory=GateConfig)
    resample: Resample = "ess"
    ess_threshold: float = Field(0.5, gt=0, le=1)
    threads: int = Field(default_factory=default_threads, ge=1, le=64,
                         description="threads the particles' scan matches are split over "
                                     "(the results do not depend on it)")
    intensity_max: float = Field(40000.0, gt=0, description="top of the intensity bands")
    motion: MotionNoise = Field(default_factory=MotionNoise)
    map: MapConfig = Field(default_factory=lambda: MapConfig(recent_keyframes=50,
                                                             nearby_keyframes=24,
                                                             nearby_radius_m=12.0,
                                                             open_points_m=30.0))
    field: FieldConfig = Field(default_factory=FieldConfig)
    seed: int = Field(0, ge=0, le=2**32 - 1)
    alignment: AlignmentConfig | None = Field(
        default_factory=AlignmentConfig, description="global scan alignment when the "
        "run ends (the improved proposal); None: the filter's estimate as it is")

    @classmethod
    def single_hypothesis(cls, alpha: float = 0.0, seed: int = 0) -> RbpfConfig:
        """The paper's single-hypothesis SLAM (Hara et al. §6) with the improved
        proposal's scan matcher as its front end: one particle, whose pose is the
        match's mean gated by eq. 5 (:func:`~chizu.numeric.slam.rbpf.improved.improved_update`);
        the loop start every sixth update (its wide search is most of an update's time),
        no relocalisation and no learned odometry sigma (a particle cloud's spread; one
        hypothesis has none), the scans between updates on odometry, as §6 has them, and
        no end-of-run alignment: an online estimate, update by update. A shifted start of
        the multi-start match wins only where its match pins the position down along the
        heading (``start_min_along``): one hypothesis cannot recover from a slide along a
        corridor that a particle cloud would outvote."""
        imp = ImprovedConfig(loop=LoopStartConfig(every=6), reloc=None,
                             odometry=OdometryCalibrationConfig(window=0),
                             start_min_along=30.0)
        return cls(particles=1, alpha=alpha, seed=seed, improved=imp, track_scans=False,
                   alignment=None)

    @model_validator(mode="after")
    def _paper_reference(self) -> RbpfConfig:
        if self.proposal != "improved" and "map" not in self.model_fields_set:
            self.map = MapConfig(recent_keyframes=8, nearby_keyframes=8)
        if self.proposal != "improved" and "alignment" not in self.model_fields_set:
            self.alignment = None
        return self

    def update_distances(self) -> tuple[float, float]:
        """Travel and turn between filter updates: the improved proposal's own
        (GMapping's linearUpdate / angularUpdate), else the paper's keyframe ones."""
        if self.proposal == "improved":
            return self.update_linear_m, self.update_angular_rad
        return self.map.update_linear_m, self.map.update_angular_rad
