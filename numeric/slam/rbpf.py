"""Rao-Blackwellized particle-filter SLAM with intensity (§7, eqs. 6-9).

Eq. 6 factors the posterior into the trajectory (particles) and the map given the
trajectory (one map per particle). Per matched scan (§7.3):

1. prediction, eq. 7: ``x_t = x_{t-1} (+) (u_t + w)``, w ~ N(0, Σ_w) with Σ_w growing
   with the odometry increment u_t;
2. likelihood, eqs. 8-9: ``d_t`` = mean over the scan's beams of the capped augmented
   squared residual ``||s_m - T s_z||^2 + alpha (l_m - l_z)^2`` to the particle's own
   map (nearest point in the sense of eq. 1, looked up in per-keyframe
   :class:`~numeric.slam.keyframes.LikelihoodField` grids), and
   ``p(z|x, m) ∝ exp(-d_t^2 / (2 sigma_z^2))`` exactly as eq. 8 writes it;
3. resampling with a constant particle count (systematic), every step as in the paper
   or only when the effective sample size drops below ``ess_threshold`` x N;
4. map update: a keyframe is added when the robot has moved far enough; every particle
   stores its own pose for it.

``proposal="improved"`` (the default) replaces steps 1-2 by the improved proposal of
Grisetti, Stachniss & Burgard, "Improved Techniques for Grid Mapping with
Rao-Blackwellized Particle Filters" (IEEE T-RO 2007, the GMapping method; see
:mod:`numeric.slam.proposal`): every particle is scan-matched against its own map, its
pose drawn from a Gaussian fitted to ``p(z|m,x) p(x|x_{t-1},u)`` around the match
(eqs. 14-15) and its weight multiplied by η (eq. 16); the filter then updates only after
``update_linear_m`` / ``update_angular_rad`` of odometry, and the ``beams`` are picked
among the returns within the keyframes' reach (``map.max_points_m``). The scans in
between refine the odometry but do not touch the particles: each is matched against
the best particle's map for its own pose (:meth:`RbpfSlam.track`, ``track_scans``).
When the best particle's reference holds old keyframes (a loop), each update also
searches the scan against them alone, and a clearly better, well-constrained alignment
beyond the matcher's reach becomes every particle's start and motion prior
(:meth:`RbpfSlam._loop_start`, ``improved.loop_search``).
``proposal="odometry"`` is the paper's method unchanged (bit for bit).

Maps are never copied: the keyframe scans are shared and each particle's map is its
keyframe poses, kept as one pose array per keyframe plus a lineage matrix of indices
that resampling permutes. The trajectory is a tree of (pose, parent) arrays, walked back
from the particle with the highest accumulated likelihood (§7.4) at the end.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from pydantic import BaseModel, Field, model_validator
from scipy import ndimage

from numeric.geometry import compose, invert, place, relative, wrap_angle
from numeric.occupancy import FREE, UNKNOWN, build_occupancy, build_probability_grid
from numeric.scan import Scan
from numeric.slam.correlative import PrecomputedGrid
from numeric.slam.gated import GateConfig, inside_gate
from numeric.slam.intensity_icp import IcpConfig, Reference, intensity_icp
from numeric.slam.keyframes import (
    FieldCache,
    FieldConfig,
    Keyframes,
    MapConfig,
    moved,
    voxel_downsample,
)
from numeric.slam.pose_graph import GraphConfig, OdometryCalibration
from numeric.slam.proposal import (
    FieldPack,
    ImprovedConfig,
    count_inliers,
    loglik_all,
    loop_search,
    propose_all,
    robust_increment,
)
from numeric.slam.scan_alignment import AlignmentConfig, align_scans, estimate_closures
from numeric.threads import default_threads, thread_map

#: the scan and the chosen fields as the proposal kernels take them: points, intensities,
#: alpha, then FieldPack's grid, inten, meta, origins and inv_res
ScanMaps = tuple[np.ndarray, np.ndarray, float, np.ndarray, np.ndarray, np.ndarray,
                 np.ndarray, float]


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


class RbpfConfig(BaseModel):
    """Parameters of the RBPF (paper: 512 particles, σ_z and alpha set empirically)."""

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
    #: Filter updates of the improved proposal only after this much travel / turn by
    #: odometry (GMapping's ``linearUpdate`` / ``angularUpdate``, 0.5 m / 0.25 rad in its
    #: examples); the scans in between follow odometry from the last update. Each update
    #: is a scan match per particle, so the thresholds trade accuracy for time. Measured
    #: with one particle (scan matching alone) on the benchmark logs, the error of the
    #: short (consecutive-scan) relations is dominated by the odometry between updates:
    #: on mit-csail 1.57 -> 0.74 deg and on the first 2000 scans of fr079 1.70 -> 0.87 deg
    #: from 0.5 m / 0.1 rad to 0.2 m / 0.05 rad (0.5 m / 0.25 rad is worse still; the
    #: odometry of those logs is off by several degrees within a turn), while aces and
    #: fr-clinic hardly change. 0.2 m / 0.05 rad is at most ~4 updates/s on these logs,
    #: which 512 particles still process faster than real time. The odometry and
    #: gated-icp proposals keep ``map.update_*`` (the paper's 0.1 m / 0.1 rad).
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
    #: Each particle's map is the keyframes it matches against: the last
    #: ``recent_keyframes`` (50 x 0.3 m, about the last 15 m of path) and up to
    #: ``nearby_keyframes`` older ones within ``nearby_radius_m`` -- GMapping matches
    #: against the particle's whole grid. Measured with 32 particles on the full logs
    #: (aces / mit-csail / fr079 / fr-clinic relation error, m): 8 + 8 within 6 m
    #: 0.111 / 0.135 / 1.555 / 1.536; 30 + 16 within 10 m 0.092 / 0.041 / 1.336 / 0.712;
    #: 50 + 24 within 12 m 0.083 / 0.085 / 0.533 / 0.503; 100 + 32 within 15 m is
    #: slower than the field cache (fr079 0.609 at 2.5x real time). The paper's
    #: proposals (odometry, gated-icp) keep the reference their figures were made with,
    #: 8 recent + 8 within 6 m, unless ``map`` is given.
    #: An open scan (more than 10 % of its returns beyond 15 m) reaches 30 m
    #: (:meth:`~numeric.slam.keyframes.Keyframes.reach`). Full logs, 512 particles:
    #: fr-clinic at seeds 0-4 1.058 / 0.694 / 1.049 / 0.525 / 0.485 (mean 0.76) against
    #: 0.636 / 4.217 / 0.967 / 2.542 / 0.387 (mean 1.75) with 15 m for every scan; aces
    #: (52 open scans of 7 374) 0.047 / 0.056 / 0.049 against 0.050 / 0.050 / 0.047; fr079
    #: and mit-csail have no open scan, so nothing changes there (all scans to 30 m had
    #: cost fr079 0.060 -> 0.075).
    map: MapConfig = Field(default_factory=lambda: MapConfig(recent_keyframes=50,
                                                             nearby_keyframes=24,
                                                             nearby_radius_m=12.0,
                                                             open_points_m=30.0))
    field: FieldConfig = Field(default_factory=FieldConfig)
    seed: int = Field(0, ge=0, le=2**32 - 1)
    #: The end of a run (:meth:`RbpfSlam.finish`, beyond Grisetti et al.): the best
    #: particle's trajectory is refined by graph SLAM's global scan alignment
    #: (:mod:`numeric.slam.scan_alignment`, after Lu & Milios 1997). The filter's own
    #: increments are the chain between consecutive scans, point-to-line ICP between
    #: overlapping scans refines them, and the pairs of scans the filter placed close
    #: together facing away from each other keep their relative pose as loop closures
    #: (:func:`~numeric.slam.scan_alignment.estimate_closures`): a correction of
    #: centimetres, it never re-decides a loop. The paper's proposals leave their
    #: estimate as it is unless ``alignment`` is given.
    alignment: AlignmentConfig | None = Field(
        default_factory=AlignmentConfig, description="global scan alignment when the "
        "run ends (the improved proposal); None: the filter's estimate as it is")

    @model_validator(mode="after")
    def _paper_reference(self) -> RbpfConfig:
        if self.proposal != "improved" and "map" not in self.model_fields_set:
            self.map = MapConfig(recent_keyframes=8, nearby_keyframes=8)
        if self.proposal != "improved" and "alignment" not in self.model_fields_set:
            self.alignment = None
        return self


def systematic_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices ``(N,)`` of a systematic resample of normalised ``weights``."""
    n = len(weights)
    c = np.cumsum(weights)
    c[-1] = 1.0
    return np.asarray(np.searchsorted(c, (rng.random() + np.arange(n)) / n), dtype=np.intp)


def world_shift(frm: np.ndarray, to: np.ndarray) -> np.ndarray:
    """``to`` minus ``frm`` in the world frame, the heading wrapped: the correction a
    loop start or relocalisation makes (what the size limits of both are set in, and
    what :class:`Persistence` compares unless ``rigid``)."""
    return np.array([to[0] - frm[0], to[1] - frm[1], wrap_angle(to[2] - frm[2])])


@dataclass(frozen=True)
class RbpfStep:
    """What one scan did to the filter (:meth:`RbpfSlam.step`): ``kind`` "first" (the
    map's first keyframe), "between" (no filter update yet: the scan's pose follows
    the odometry, or the best particle's map when ``track_scans``) or "update" (§7.3's
    four steps); for an update, the effective sample size after weighing, whether the
    particles were resampled and whether a keyframe joined the maps."""

    t: float
    kind: Literal["first", "between", "update"]
    ess: float | None = None
    resampled: bool = False
    keyframe: bool = False


@dataclass
class Persistence:
    """How many consecutive searches agreed on a correction: a loop start or
    relocalisation is taken only after ``need`` in a row, each of whose alternatives
    lies within ``sep_m`` of where the previous correction puts the current estimate,
    and, when asked, over at least ``travel_m`` of the estimate's path.

    A correction is the rigid transform ``H = alt (+) cur^-1`` that moves the estimate
    onto the alternative, not the difference of the two: with a heading error the
    difference changes as the robot drives on (by 2 sin(dθ/2) per metre), while the
    transform stays the same."""

    need: int
    sep_m: float
    streak: int = 0
    travel: float = 0.0
    correction: np.ndarray = field(default_factory=lambda: np.zeros(3))
    last: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def reset(self) -> None:
        self.streak = 0

    def confirm(self, cur: np.ndarray, alt: np.ndarray, travel_m: float = 0.0) -> bool:
        """Count the correction from ``cur`` to ``alt``; True (and start over) once
        ``need`` in a row agree over at least ``travel_m`` of path."""
        moved = compose(self.correction, cur)
        agree = self.streak > 0 and np.hypot(moved[0] - alt[0], moved[1] - alt[1]) < self.sep_m
        if agree:
            self.streak += 1
            self.travel += float(np.hypot(cur[0] - self.last[0], cur[1] - self.last[1]))
        else:
            self.streak, self.travel = 1, 0.0
        self.correction = compose(alt, invert(cur))
        self.last = np.asarray(cur, dtype=float).copy()
        if self.streak < self.need or self.travel < travel_m:
            return False
        self.streak = 0
        return True


def _copies(x: np.ndarray, kf_pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Particles that are copies of each other (the same pose ``x (P, 3)`` and the same
    map, ``kf_pose (K, P, 3)``), so that each is matched once: the index of one of each
    ``(U,)`` and, per particle, which of those it copies ``(P,)``. Particles whose poses
    all differ (every update but those right after a resampling) are told apart by the
    poses alone, without comparing their maps."""
    p = len(x)
    if len(np.unique(x, axis=0)) == p:
        return np.arange(p), np.arange(p)
    key = np.concatenate([x, kf_pose.transpose(1, 0, 2).reshape(p, -1)], axis=1)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    return first, inv.reshape(-1)


@dataclass
class RbpfSlam:
    """Feed scans with :meth:`process`; read :meth:`trajectory` and :meth:`map_poses`."""

    config: RbpfConfig = field(default_factory=RbpfConfig)
    keyframes: Keyframes = field(init=False)
    fields: FieldCache = field(init=False)
    matched: int = 0
    resamples: int = 0
    improved_failures: int = 0  # particle updates that fell back to the motion model
    #: accepted loop starts (:meth:`_loop_start`): time, shift (m), beams explained by
    #: the old keyframes at the current estimate and at the alternative, and the share
    #: of the beams each puts in the old keyframes' free space
    loop_starts: list[tuple[float, float, int, int, float, float]] = field(
        default_factory=list)
    #: candidates refused for the free space alone: time, shift (m), the share at the
    #: current estimate and at the alternative
    loop_refused: list[tuple[float, float, float, float]] = field(default_factory=list)
    #: accepted relocalisations (:meth:`_relocalise`): time, shift (m), turn (rad), the
    #: grid scores at the current estimate and at the match
    relocalisations: list[tuple[float, float, float, float, float]] = field(
        default_factory=list)
    #: relocalisations refused by the drift bound: time, shift (m), the bound (m)
    reloc_refused: list[tuple[float, float, float]] = field(default_factory=list)

    def __post_init__(self) -> None:
        cfg = self.config
        self.rng = np.random.default_rng(cfg.seed)
        self.keyframes = Keyframes(cfg.map)
        use_i = cfg.alpha > 0 and cfg.field.intensity_bands > 1
        edges = None
        if use_i:
            edges = np.linspace(0.0, cfg.intensity_max, cfg.field.intensity_bands + 1)
            edges[-1] = np.inf
            edges[0] = -np.inf
        self.fields = FieldCache(self.keyframes, cfg.field, edges)
        self._kept_pack: tuple[tuple[tuple[int, ...], bool], FieldPack] | None = None
        p = cfg.particles
        self.x = np.zeros((p, 3))
        self.logw = np.zeros(p)
        self.loglik = np.zeros(p)  # accumulated likelihood, inherited on resampling
        self._kf_pose = np.zeros((16, p, 3))  # per keyframe: (P, 3) poses at insertion
        self._n_kf = 0
        self._lineage_buf = np.zeros((16, p), dtype=np.int32)  # per keyframe: which column
        self._hist_pose: list[np.ndarray] = []  # per matched step: (P, 3) float32
        self._hist_parent: list[np.ndarray] = []  # per matched step: (P,) int32
        self._scan_step: list[int] = []  # per scan: its matched step
        self._scan_delta: list[np.ndarray] = []  # per scan: odometry since that step
        self.times: list[float] = []
        self._odom_path: list[float] = []  # per scan: the odometry's path length so far
        self._last_odom: np.ndarray | None = None
        self._anchor_odom: np.ndarray | None = None
        self._last_kf_odom: np.ndarray | None = None
        imp = cfg.improved
        self._loop_agree = Persistence(imp.loop_persistence, imp.loop_min_sep_m)
        self._reloc_agree = Persistence(imp.reloc_persistence, imp.loop_min_sep_m)
        self._reloc_tick = 0  # updates since the last relocalisation search
        # per scan, for finish()'s alignment: its returns (voxel-filtered) and intensities
        self._scan_xy: list[np.ndarray] = []
        self._scan_inten: list[np.ndarray | None] = []
        self._aligned: np.ndarray | None = None  # finish()'s poses, until the next scan
        self.alignment_matches = 0
        self._kf_cal: list[tuple[np.ndarray, float, float]] = []
        self._heading_var = 0.0  # summed fixed heading variance of the updates so far
        self.odometry = OdometryCalibration(cfg.improved.odometry_window,
                                            cfg.improved.odometry_min_scale,
                                            cfg.improved.odometry_knee)

    def sigmas(self, u: np.ndarray) -> np.ndarray:
        """Σ_w of eq. 7 for the increment ``u``, its heading sigma scaled by what
        :class:`OdometryCalibration` has learned (1 unless ``improved.odometry_window``)."""
        sig = self.config.motion.sigmas(u)
        sig[2] *= self.odometry.scale
        return sig

    # -- the four steps of §7.3 (driven by step) -------------------------------------------
    def predict(self, u: np.ndarray, scale: float = 1.0) -> None:
        """Eq. 7."""
        w = self.rng.normal(size=self.x.shape) * (scale * self.sigmas(u))
        self.x = compose(self.x, u + w)

    def matched_increment(self, u: np.ndarray, xy: np.ndarray,
                          inten: np.ndarray | None) -> np.ndarray | None:
        """The "gated-icp" proposal: the increment Intensity-ICP finds for the best
        particle against its own map, if eq. 5 accepts it."""
        cfg = self.config
        b = self.best
        poses = self._kf_poses_of(b)
        chosen = self.keyframes.select(self.x[b], poses[:, :2])
        ref_xy, ref_i = self.keyframes.reference(chosen, poses)
        if len(ref_xy) < cfg.icp.min_inliers:
            return None
        predicted = compose(self.x[b], u)
        res = intensity_icp(Reference(ref_xy, ref_i, cfg.icp.alpha), xy, inten, predicted,
                            cfg.icp)
        if not res.usable(len(xy), cfg.icp) or not inside_gate(self.x[b], res.pose, u,
                                                                cfg.gate):
            return None
        return relative(self.x[b], res.pose)

    def likelihood(self, xy: np.ndarray, inten: np.ndarray | None) -> np.ndarray:
        """log p(z | x, m) per particle, eqs. 8-9 (up to a constant)."""
        cfg = self.config
        best = self.best
        chosen = self.keyframes.select(self.x[best], self._kf_poses_of(best)[:, :2])
        res = np.full((len(self.x), len(xy)), np.inf)
        for k in chosen:
            kf_pose = self._kf_pose[k][self._lineage[k]]  # (P, 3): each particle's own
            rel = relative(kf_pose, self.x)  # particle pose in the keyframe frame
            c, s = np.cos(rel[:, 2]), np.sin(rel[:, 2])
            px = c[:, None] * xy[None, :, 0] - s[:, None] * xy[None, :, 1] + rel[:, 0:1]
            py = s[:, None] * xy[None, :, 0] + c[:, None] * xy[None, :, 1] + rel[:, 1:2]
            r = self.fields.get(int(k)).residual(np.stack([px, py], axis=-1), inten, cfg.alpha)
            np.minimum(res, r, out=res)
        d_t = res.mean(axis=1)  # eq. 9
        return np.asarray(-(d_t**2) / (2 * cfg.sigma_z**2))  # eq. 8

    def improved_step(self, u: np.ndarray, xy: np.ndarray,
                      inten: np.ndarray | None) -> np.ndarray:
        """One filter update with the improved proposal (Grisetti et al. 2007, §IV;
        :mod:`numeric.slam.proposal`). The reference keyframes are chosen once, by the
        best particle (as :meth:`likelihood` does), and every particle matched against
        its own poses of them: it is scan-matched from ``x_{t-1} (+) u`` (step 1), its
        new pose drawn from the Gaussian fitted to τ around the match (steps 2-3, eqs.
        14-15), or from the motion model when the match fails (step 4). Moves ``self.x``
        and returns the log weight increments: ``log η`` (eq. 16) or, after a fallback,
        ``log p(z|m,x_t)``, both times ``improved.weight_gain``."""
        cfg, imp = self.config, self.config.improved
        p = len(self.x)
        best = self.best
        chosen, fp, alpha = self._best_map(u, inten)
        lineage = self._lineage[chosen]  # (K, P)
        kf_pose = self._kf_pose[chosen[:, None], lineage]  # (K, P, 3): each particle's map
        li = np.zeros(len(xy)) if inten is None else np.asarray(inten, dtype=float)
        cut = min(imp.cutoff_m, cfg.field.cutoff_m)
        sig = self.sigmas(u)
        inv_2s2 = 1.0 / (2.0 * imp.sigma_m**2)
        first, inv = _copies(self.x, kf_pose)
        min_in = max(imp.min_inliers, int(np.ceil(imp.min_match_fraction * len(xy))))
        delta = np.array([imp.sample_min_xy_m, imp.sample_min_xy_m, imp.sample_min_theta_rad])
        maps: ScanMaps = (xy, li, alpha, fp.grid, fp.inten, fp.meta, fp.origins, fp.inv_res)
        u_start = u
        if imp.odometry_window:
            self._calibrate(u, maps, kf_pose[:, best:best + 1])
        if len(imp.start_headings_rad) > 1:
            u_start, won = self._robust_start(u, maps, kf_pose[:, best:best + 1])
            if won:  # the odometry failed here: its learned sigma does not apply
                sig = cfg.motion.sigmas(u)
        if imp.loop_search:
            u_loop = self._loop_start(u_start, chosen, maps, kf_pose[:, best:best + 1])
            if u_loop is None and imp.reloc_every:
                u_loop = self._relocalise(u_start, maps)
            if u_loop is not None:  # the loop's increment replaces the odometry's
                u = u_start = u_loop
        xs, kfs = self.x[first], kf_pose[:, first]

        def propose(ix: np.ndarray) -> tuple[np.ndarray, ...]:
            return propose_all(xs[ix], u, u_start, sig, *maps,
                               np.ascontiguousarray(kfs[:, ix]), cut * cut, inv_2s2, delta,
                               imp.max_iterations, min_in, imp.match_prior)

        # the particles are independent: split over threads (propose_all releases the GIL)
        parts = np.array_split(np.arange(len(first)), max(1, min(cfg.threads,
                                                                   len(first) // 16)))
        done = thread_map(propose, parts, cfg.threads)
        mu, chol, logeta, ok = (np.concatenate([d[i] for d in done]) for i in range(4))
        noise = self.rng.normal(size=(p, 3))
        okp = ok[inv]
        new = np.empty_like(self.x)
        inc = np.empty(p)
        if np.any(okp):
            j = inv[okp]
            draw = mu[j] + np.einsum("pij,pj->pi", chol[j], noise[okp])
            draw[:, 2] = wrap_angle(draw[:, 2])
            new[okp] = draw
            inc[okp] = logeta[j]
        fb = ~okp
        if np.any(fb):  # the plain RBPF step: eq. 7, weighted by the likelihood
            new[fb] = compose(self.x[fb], u + noise[fb] * sig)
            inc[fb] = loglik_all(new[fb], *maps, np.ascontiguousarray(kf_pose[:, fb]),
                                 cut * cut, inv_2s2)
        self.x = new
        self.improved_failures += int(fb.sum())
        return np.asarray(imp.weight_gain * inc)

    def _loop_start(self, u_start: np.ndarray, chosen: np.ndarray, maps: ScanMaps,
                    kf_best: np.ndarray) -> np.ndarray | None:
        """A loop-closing increment for every particle, or None.

        The improved proposal (Grisetti et al. 2007, §IV) only refines a pose inside the
        matcher's basin: after a long loop the place seen before can be farther off than
        the likelihood field's cutoff, and then no particle is pulled back (the paper
        relies on enough particles having drifted the right way). When the best
        particle's reference holds old keyframes (not among the recent ones), the scan is
        searched for against them alone (:func:`loop_search`, a correlative grid around
        the current estimate ``x_best (+) u_start``, refined by the scan matcher). The
        best alternative is taken only on strong evidence: it explains at least
        ``loop_min_fraction`` of the beams within ``loop_inlier_m`` of the old map,
        ``loop_min_gain`` more than the current estimate (the better of it as it is and
        refined by the scan matcher against the old map: if that refinement itself
        reaches the alternative, there is nothing to gain) and ``loop_ambiguity`` more
        than any other mode, its position is well constrained (``loop_min_eig``), it
        lowers the share of beams in the old map's free space by ``loop_min_free_drop``
        against the current estimate as it is (:meth:`_free_space_share`) and
        ``loop_persistence`` consecutive updates agree. Every particle then starts at, and
        is drawn around (the motion prior centred on), its pose (+) the returned
        increment: the shift is common, so the relative weights hold, and the residual
        being the minimum over the keyframes, the old ones explain the scan there."""
        cfg, imp = self.config, self.config.improved
        old = np.flatnonzero(chosen < self._n_kf - cfg.map.recent_keyframes)
        xy, li, alpha = maps[0], maps[1], maps[2]
        n_b = len(xy)
        if len(old) < imp.loop_min_old:
            self._loop_agree.reset()
            return None
        fp = self._pack(chosen[old], alpha > 0)
        kf_old = np.ascontiguousarray(kf_best[old])
        fields = (fp.grid, fp.inten, fp.meta, fp.origins, fp.inv_res)
        x0 = self.x[self.best]
        cur = compose(x0, u_start)
        in2 = imp.loop_inlier_m ** 2
        n_cur = int(count_inliers(cur, xy, li, alpha, *fields, kf_old, in2))
        if n_cur + imp.loop_min_gain * n_b > n_b:  # cannot gain enough
            self._loop_agree.reset()
            return None
        cut = min(imp.cutoff_m, cfg.field.cutoff_m)
        poses, inl, eig = loop_search(
            cur, xy, li, alpha, *fields, kf_old, cut * cut, imp.loop_coarse_cutoff_m ** 2,
            in2, 1.0 / (2.0 * imp.sigma_m ** 2), imp.max_iterations, imp.loop_radius_m,
            imp.loop_step_m, imp.loop_angle_rad, imp.loop_angle_step_rad, imp.loop_refine,
            imp.loop_min_sep_m, cfg.threads)
        # the current estimate refined against the old map is the first rival: the
        # alternatives are refined, and the unrefined estimate's count would understate
        # it (this alone did not stop fr079's false closure at 806 s, which the free
        # space below does: refined, the true pose still explains 20 of 90 beams)
        n_cur = max(n_cur, int(inl[0]))
        r = int(np.argmax(inl))
        alt = poses[r]
        apart = np.hypot(poses[:, 0] - alt[0], poses[:, 1] - alt[1]) >= imp.loop_min_sep_m
        second = int(inl[apart].max()) if np.any(apart) else 0
        shift = world_shift(cur, alt)
        good = (inl[r] >= imp.loop_min_fraction * n_b
                and inl[r] - n_cur >= imp.loop_min_gain * n_b
                and inl[r] - second >= imp.loop_ambiguity * n_b
                and eig[r] >= imp.loop_min_eig
                and np.hypot(shift[0], shift[1]) >= imp.loop_min_shift_m)
        if not good:
            self._loop_agree.reset()
            return None
        free_cur, free = self._free_space_share(np.stack([cur, alt]), xy, chosen[old],
                                                kf_old[:, 0])[0]
        if free_cur - free < imp.loop_min_free_drop:
            self.loop_refused.append((self.times[-1], float(np.hypot(shift[0], shift[1])),
                                      free_cur, free))
            self._loop_agree.reset()
            return None
        if not self._loop_agree.confirm(cur, alt):
            return None
        self.loop_starts.append((self.times[-1], float(np.hypot(shift[0], shift[1])), n_cur,
                                 int(inl[r]), float(free_cur), float(free)))
        return np.asarray(relative(x0, alt))

    def _relocalise(self, u_start: np.ndarray, maps: ScanMaps) -> np.ndarray | None:
        """A relocalising increment for every particle, or None: the scan searched for in
        the whole old map around the estimate, for a return from a loop long enough that
        the estimate drifted beyond :meth:`_loop_start`'s window (fr-clinic's last loop
        comes back 2-27 m and 5-18° off).

        Every ``reloc_every`` updates, the keyframes at least ``reloc_min_age_s`` old that
        the best particle placed within ``reloc_radius_m`` of its estimate are ray-cast
        into one probability grid (:func:`~numeric.occupancy.build_probability_grid`),
        and the scan is matched in it by branch and bound (Hess et al. 2016, §V,
        Algorithms 2-3: :class:`~numeric.slam.correlative.PrecomputedGrid`) within
        ``reloc_window_m`` / ``reloc_angle_rad``. The score is the mean probability of
        the cells the returns fall in, so free space the old map saw counts against a
        pose. The match is taken when it scores ``reloc_min_score`` and
        ``reloc_min_gain`` more than the current estimate, no pose ``reloc_unique_m``
        away scores ``reloc_unique_ratio`` of it (a corridor's repeated doors), the
        scan matcher refines it against the old keyframes nearest it (all those old
        enough, not only the ones picked for the grid) to a pose that explains
        ``reloc_min_fraction`` of the beams within ``loop_inlier_m``, well
        constrained (``loop_min_eig``), it lowers the share of returns in the old free
        space by ``loop_min_free_drop`` (:meth:`_free_space_share`), and
        ``reloc_persistence`` consecutive searches agree (:class:`Persistence`: on one
        rigid correction, ``rigid_persistence``). Shifts :meth:`_loop_start` could take
        (within ``loop_radius_m`` and ``loop_angle_rad``) are left to it.

        Why the refinement takes the nearest of all the old keyframes (session 26):
        with keyframes within 32 m, the 60 picked evenly for the grid are half as dense
        as within 22 m, and on fr-clinic seed 1 the 12.8 m return at 4 386-4 410 s,
        found by every search there, refined to only 11-25 of 90 beams against the
        picked ones (27 needed); against the nearest of all it refined to 32-36 and was
        taken at 4 398 s (from a snapshot at 4 000 s: 0.473 -> 0.180; the full run with
        the session-26 defaults 0.207).

        From where the old map never was (``reloc_max_seen``; session 25): an
        estimate that has drifted into space the old keyframes never saw (at most
        ``reloc_max_seen`` of its returns in cells they saw) cannot be contradicted by
        them, and then the free-space drop cannot decide. Such a match is taken when it
        puts fewer than ``loop_min_free_drop`` of the returns in the old free space and
        the agreeing searches span ``reloc_unseen_travel_m`` of the estimate's path. On
        fr-clinic seed 5 (session 25) the return at 4 406-4 441 s was found 29 m and
        0.32 rad off, free-space shares 0.18 / 0.08, then 0.03 / 0.03, 0.01 / 0.03, 0.00
        / 0.04 (estimate / match), with 1-23 % of the estimate's returns in seen cells.
        A look-alike found at 4 108-4 119 s (21-25 m off, the robot truly in new space)
        passed every test but this one; it slid 1 m along a corridor between searches,
        which the rigid persistence refuses, and followed as a fixed correction it put
        0.23 then 0.37 of the returns in the old free space within 10 s, while the true
        one explained 55-75 % of them for 37 s. A robot standing in a room like an old
        one passes every single-scan test (the room next door); only travel tells.

        The drift bound (``reloc_drift_m`` + ``reloc_drift_per_m`` per m of odometry path
        since the robot was last at the keyframes the match was refined against; session
        27): in a simulated office of identical rooms (``tests/bench/slam_unseen.py``,
        office 1) the filter relocalised into the room three doors down, 20.6 m off,
        50 m of path after it had seen the first -- a match from where the old map never
        was that nothing else contradicts (loop-spanning error 20.1 m; with the bound
        0.24 m with the URG-04LX, 0.004 m with the 30 m laser). fr-clinic's returns come
        4-29 m off 740-1 210 m of path after the robot was last there (its first loop at
        1 800-2 000 s, or the start), inside the bound (38-62 m).

        Why the thresholds are lower than the loop start's: the old map is made of
        keyframes the filter itself placed, and after a long loop they disagree with
        each other and with the new scan by more than a cell. On fr-clinic (seed 2, 512
        particles) the return at 4 390-4 450 s was found by 20 consecutive searches,
        2.6 m and 0.24 rad from the estimate, each with no second pose within 90 % of
        its score, yet at scores of 0.36-0.51 and with 29-55 of 90 beams within 5 cm
        after refinement; the free space decided it (0.82 of the returns in the old
        free space at the estimate, 0.12-0.30 at the match). Uniqueness, free space and
        three agreeing searches carry the evidence the scores cannot."""
        cfg, imp = self.config, self.config.improved
        self._reloc_tick += 1
        if self._reloc_tick < imp.reloc_every:
            return None
        self._reloc_tick = 0
        xy, li, alpha = maps[0], maps[1], maps[2]
        n_b = len(xy)
        best = self.best
        x0 = self.x[best]
        cur = compose(x0, u_start)
        kfp = self._kf_poses_of(best)
        frames = self.keyframes.frames
        t_now = self.times[-1]
        age = t_now - np.asarray(self.times)[[f.scan_index for f in frames]]
        aged = age >= imp.reloc_min_age_s
        near = np.hypot(kfp[:, 0] - cur[0], kfp[:, 1] - cur[1]) <= imp.reloc_radius_m
        old = np.flatnonzero(near & aged)
        if len(old) < imp.loop_min_old:
            self._reloc_agree.reset()
            return None
        old = old[np.unique(np.linspace(0, len(old) - 1,
                                        min(len(old), imp.reloc_max_keyframes)).astype(int))]
        grid, _ = build_probability_grid([frames[int(k)] for k in old], kfp[old],
                                         resolution_m=imp.reloc_resolution_m, margin_m=0.5)
        pre = PrecomputedGrid(grid, depth=6)
        m = pre.match(xy, cur, imp.reloc_window_m, imp.reloc_angle_rad, imp.reloc_min_score)
        if m is None:
            self._reloc_agree.reset()
            return None
        shift = world_shift(cur, m.pose)
        if (np.hypot(shift[0], shift[1]) <= imp.loop_radius_m
                and abs(shift[2]) <= imp.loop_angle_rad):
            self._reloc_agree.reset()  # the loop start's window covers it
            return None
        s_cur = pre.score(xy, cur)
        if (m.score - s_cur < imp.reloc_min_gain
                or pre.second_score(xy, cur, imp.reloc_window_m, imp.reloc_angle_rad, m,
                                    imp.reloc_unique_m, imp.reloc_unique_ratio) > 0):
            self._reloc_agree.reset()
            return None
        # refine against the old keyframes nearest the match (all of them, not only
        # those picked for the grid), with the scan matcher
        cand = np.flatnonzero(aged)
        d = np.hypot(kfp[cand, 0] - m.pose[0], kfp[cand, 1] - m.pose[1])
        ref = cand[np.argsort(d)[:max(cfg.map.nearby_keyframes, imp.loop_min_old)]]
        fp = self._pack(ref, alpha > 0)
        kf_ref = np.ascontiguousarray(kfp[ref][:, None, :])
        in2 = imp.loop_inlier_m ** 2
        cut = min(imp.cutoff_m, cfg.field.cutoff_m)
        step = imp.reloc_resolution_m
        poses, inl, eig = loop_search(
            m.pose, xy, li, alpha, fp.grid, fp.inten, fp.meta, fp.origins, fp.inv_res, kf_ref,
            cut * cut, imp.loop_coarse_cutoff_m ** 2, in2, 1.0 / (2.0 * imp.sigma_m ** 2),
            imp.max_iterations, step, step, imp.loop_angle_step_rad,
            imp.loop_angle_step_rad, 1, imp.loop_min_sep_m)
        r = int(np.argmax(inl))
        alt = poses[r]
        if inl[r] < imp.reloc_min_fraction * n_b or eig[r] < imp.loop_min_eig:
            self._reloc_agree.reset()
            return None
        # drift bound: since the robot was last at the match's keyframes it has
        # travelled so far that its estimate can be this far off, no farther (a room
        # like one seen 50 m of path ago is not where the robot is, however well the
        # scan fits it)
        last_seen = max(frames[int(k)].scan_index for k in ref)
        since = self._odom_path[-1] - self._odom_path[last_seen]
        shift = world_shift(cur, alt)
        dist = float(np.hypot(shift[0], shift[1]))
        bound = imp.reloc_drift_m + imp.reloc_drift_per_m * since
        if dist > bound:
            self.reloc_refused.append((t_now, dist, bound))
            self._reloc_agree.reset()
            return None
        (free_cur, free), (seen_cur, _) = self._free_space_share(np.stack([cur, alt]), xy,
                                                                 old, kfp[old])
        contradicted = free_cur - free >= imp.loop_min_free_drop
        unseen = (imp.reloc_max_seen is not None and seen_cur <= imp.reloc_max_seen
                  and free < imp.loop_min_free_drop)
        if not (contradicted or unseen):
            self._reloc_agree.reset()
            return None
        travel = 0.0 if contradicted else imp.reloc_unseen_travel_m
        if not self._reloc_agree.confirm(cur, alt, travel):
            return None
        self.relocalisations.append((t_now, dist, float(shift[2]), s_cur, m.score))
        return np.asarray(relative(x0, alt))

    def _free_space_share(self, poses: np.ndarray, xy: np.ndarray, frames: np.ndarray,
                          kf_poses: np.ndarray) -> np.ndarray:
        """For each of ``poses`` (M, 3): row 0, the share of the scan's returns ``xy``
        that land where the keyframes ``frames`` (at ``kf_poses`` (K, 3)) saw free space
        -- row 1, the share that land in cells they saw at all (free or hit). Free: cells
        their beams passed through, at least ``loop_free_margin_m`` from any cell they
        did not see as free -- the negative evidence of an occupancy map, which the
        inlier counts of :meth:`_loop_start` lack (Hess et al. 2016 score closures on a
        probability grid, free cells included).

        Why :meth:`_loop_start` asks the alternative to lower this share: a robot in the
        room next to one it mapped explains the mapped room's walls well 2.5 m off
        (fr079 at 806 s, ±2 m search: 70 of 90 beams within 5 cm, 20 at the true pose,
        where the scan sees only the shared wall). There the current estimate puts no
        return in the old free space (0.00; the rest of its scan is in unknown space)
        and the alternative 0.19. The true closures of aces seed 1 (0.8-2.0 m) lower it
        from 0.33-0.54 to 0-0.20 (what is left: people in the corridor). ``xy`` are the
        beams picked for the match (:meth:`_beams`)."""
        imp = self.config.improved
        occ = build_occupancy([self.keyframes.frames[int(k)] for k in frames], kf_poses,
                              resolution_m=imp.loop_free_cell_m, margin_m=0.0)
        steps = int(round(imp.loop_free_margin_m / imp.loop_free_cell_m))
        free = occ.state == FREE
        if steps > 0:  # (iterations=0 would erode until nothing changes)
            free = ndimage.binary_erosion(free, structure=np.ones((3, 3)), iterations=steps)
        out = np.zeros((2, len(poses)))
        for m, pose in enumerate(poses):
            i, j, on = occ.cells(place(xy, pose))
            out[0, m] = float((free[i, j] & on).sum()) / max(len(xy), 1)
            out[1, m] = float((on & (occ.state[i, j] != UNKNOWN)).sum()) / max(len(xy), 1)
        return out

    def _pack(self, ids: Iterable[int], with_intensity: bool, keep: bool = False,
              ) -> FieldPack:
        """:meth:`FieldPack.of` the keyframes ``ids``; with ``keep`` the pack is kept for
        the next call with ``keep`` (one pack: the best particle's reference, asked for
        on every scan and mostly the same keyframes from one scan to the next). A pack
        is a flat copy of all their grids (15 MB and 1.5 ms on aces; on fr-clinic,
        whose 30 m scans make large grids, keeping the last three packs of any kind
        took the whole run's peak memory to 1.53 GB, keeping this one 1.31 GB, where
        session 32 measured 1.15 GB). A keyframe's field never changes,
        so a kept pack is the one :meth:`FieldPack.of` would build; its fields are still
        asked of the field cache, which keeps them as recently used as before."""
        key = (tuple(int(k) for k in ids), with_intensity)
        fields = [self.fields.get(k) for k in key[0]]
        if keep and self._kept_pack is not None and self._kept_pack[0] == key:
            return self._kept_pack[1]
        fp = FieldPack.of(fields, with_intensity)
        if keep:
            self._kept_pack = (key, fp)
        return fp

    def _best_map(self, u: np.ndarray, inten: np.ndarray | None,
                  ) -> tuple[np.ndarray, FieldPack, float]:
        """The keyframes the best particle's reference is made of at ``x_best (+) u``
        (:meth:`Keyframes.select`), their likelihood fields, and the intensity weight."""
        cfg = self.config
        best = self.best
        chosen = self.keyframes.select(compose(self.x[best], u), self._kf_poses_of(best)[:, :2])
        alpha = cfg.alpha if inten is not None else 0.0
        return chosen, self._pack(chosen, alpha > 0, keep=True), alpha

    def track(self, u: np.ndarray, xy: np.ndarray, inten: np.ndarray | None) -> np.ndarray:
        """A scan between two updates: its increment from the last update, found as each
        update finds its start (:func:`robust_increment`: the best particle's map, the
        odometry prediction turned and shifted). Only the scan's own pose uses it --
        Grisetti et al.'s updates stay every ``update_linear_m``, and the particles
        are not touched (the issue's "scans in between refine odometry")."""
        best = self.best
        chosen, fp, alpha = self._best_map(u, inten)
        kf_pose = self._kf_pose[chosen, self._lineage[chosen, best]][:, None, :]
        li = np.zeros(len(xy)) if inten is None else np.asarray(inten, dtype=float)
        maps: ScanMaps = (xy, li, alpha, fp.grid, fp.inten, fp.meta, fp.origins, fp.inv_res)
        return self._robust_start(u, maps, kf_pose)[0]

    def _robust_start(self, u: np.ndarray, maps: ScanMaps, kf_best: np.ndarray,
                      alone: bool = False) -> tuple[np.ndarray, int]:
        """:func:`robust_increment` of the best particle (its map ``kf_best`` (K, 1, 3))
        from ``x_best (+) u``, with the scan and fields ``maps`` as the kernels take them;
        ``alone``: one start, the odometry's, matched on the likelihood alone. It scores
        the starts with the fixed motion model, not the learned one
        (:class:`OdometryCalibration`): it is what finds the odometry's failures, the
        tail a spread learned from the core does not cover."""
        cfg, imp = self.config, self.config.improved
        cut = min(imp.cutoff_m, cfg.field.cutoff_m)
        headings = np.zeros(1) if alone else np.asarray(imp.start_headings_rad, dtype=float)
        shifts = np.zeros(0) if alone else np.asarray(imp.start_shifts_m, dtype=float)
        inc, won = robust_increment(
            self.x[self.best], u, cfg.motion.sigmas(u), *maps, np.ascontiguousarray(kf_best),
            cut * cut, 1.0 / (2.0 * imp.sigma_m**2), imp.max_iterations, headings,
            imp.start_margin, imp.match_prior and not alone, shifts)
        return np.asarray(inc), int(won)

    def _calibrate(self, u: np.ndarray, maps: ScanMaps, kf_best: np.ndarray) -> None:
        """One residual for :class:`OdometryCalibration`, over the fixed heading sigma.

        With ``improved.odometry_lag_m`` 0: the heading of the best particle's match on
        the likelihood alone, started at the odometry prediction, minus the odometry's.
        Within about ±1° that match stays where it starts, so odometry whose heading
        walks by less than that per update looks exact (session 28: the simulated
        office's URG-04LX run learned 8-20 % of the fixed sigma where the odometry's
        walk is about 50 %, and drifted 6°).

        Else the residual spans a lag: the newest keyframe at least ``odometry_lag_m``
        of odometry path back, ``A``, is matched against the scan alone (the best of
        starts turned by ``odometry_lag_headings_rad``, chosen by the scan's likelihood
        alone), and the heading change it finds from the best particle's pose of ``A``
        minus the odometry's change since ``A`` is divided by the fixed model's sigma of
        that change (the square root of the summed per-update variances). That match
        compares two scans, not the estimate, so it sees the odometry's heading error
        summed over the lag whichever way the filter followed it. No residual when the
        match explains fewer than ``min_match_fraction`` of the beams (no overlap).

        Measured (session 30, full logs and offices, 512 particles, seed 0; one-update
        residual -> lagged 3 m): office 1 with the URG-04LX, loop-spanning 0.243 ->
        0.033 m (learned share 0.04-0.2 -> 0.8-1; the fixed sigma gives 0.030);
        fr-clinic 0.242 -> 0.199 (it still learns 0.06-0.5); aces 0.037 -> 0.036
        (loop-spanning 0.054 -> 0.072), mit-csail 0.027 -> 0.027, fr079 0.041 -> 0.041;
        offices 1 LMS, 2 URG, 2 LMS loop-spanning 0.004 / 0.005 / 0.005 -> 0.004 /
        0.005 / 0.005."""
        imp = self.config.improved
        sig = float(self.config.motion.sigmas(u)[2])
        self._heading_var += sig * sig
        assert self._anchor_odom is not None
        odom = compose(self._anchor_odom, u)
        path = self._odom_path[-1]
        k = len(self._kf_cal) - 1
        while k >= 0 and path - self._kf_cal[k][1] < imp.odometry_lag_m:
            k -= 1
        if k < 0:
            return
        kf_odom, _, kf_var = self._kf_cal[k]
        best = self.best
        xy, li, alpha = maps[0], maps[1], maps[2]
        fp = self._pack([k], alpha > 0)
        kf = self._kf_pose[k, self._lineage[k, best]][None, None, :]
        one: ScanMaps = (xy, li, alpha, fp.grid, fp.inten, fp.meta, fp.origins, fp.inv_res)
        cut = min(imp.cutoff_m, self.config.field.cutoff_m)
        x0 = self.x[best]
        # sigmas of 1e6: the motion model neither pulls nor scores the starts (the
        # prior is off), so the best start is the one the scan alone fits best
        inc, _ = robust_increment(
            x0, u, np.full(3, 1e6), *one, np.ascontiguousarray(kf), cut * cut,
            1.0 / (2.0 * imp.sigma_m**2), imp.max_iterations,
            np.asarray(imp.odometry_lag_headings_rad, dtype=float), 0.0, False, np.zeros(0))
        pose = compose(x0, np.asarray(inc))
        inl = count_inliers(pose, *one, np.ascontiguousarray(kf), (2.0 * imp.sigma_m) ** 2)
        if inl < max(imp.min_inliers, imp.min_match_fraction * len(xy)):
            return
        turned = float(wrap_angle(pose[2] - kf[0, 0, 2]))
        odo_turned = float(wrap_angle(odom[2] - kf_odom[2]))
        spread = math.sqrt(max(self._heading_var - kf_var, sig * sig))
        self.odometry.add(float(wrap_angle(turned - odo_turned)) / spread)

    def effective_sample_size(self) -> float:
        """N_eff = 1 / Σ w² of the normalised weights."""
        w = np.exp(self.logw - self.logw.max())
        w /= w.sum()
        return 1.0 / float(np.sum(w * w))

    def maybe_resample(self, ess: float) -> np.ndarray | None:
        """Step 3: systematic resampling, every update (the paper) or only when
        ``ess`` < ``ess_threshold`` x N (Grisetti et al.'s selective resampling);
        returns the drawn indices, or None. Maps follow their particles through the
        lineage matrix: nothing is copied."""
        if self.config.resample == "ess" and ess >= self.config.ess_threshold * len(self.x):
            return None
        w = np.exp(self.logw - self.logw.max())
        w /= w.sum()
        idx = systematic_resample(w, self.rng)
        self.x = self.x[idx]
        self.loglik = self.loglik[idx]
        self.logw = np.zeros(len(w))
        if self._n_kf:
            self._lineage_buf[:self._n_kf] = self._lineage[:, idx]
        self.resamples += 1
        return idx

    def add_keyframe(self, scan_index: int, xy: np.ndarray, inten: np.ndarray | None) -> None:
        self.keyframes.add(scan_index, xy, inten)
        if self._n_kf == len(self._kf_pose):  # grow by doubling: amortised O(1)
            self._kf_pose = np.concatenate([self._kf_pose, np.zeros_like(self._kf_pose)])
        if self._n_kf == len(self._lineage_buf):
            self._lineage_buf = np.concatenate([self._lineage_buf,
                                                np.zeros_like(self._lineage_buf)])
        self._kf_pose[self._n_kf] = self.x
        # for _calibrate: the keyframe's odometry, odometry path and summed heading variance
        self._kf_cal.append((self._last_odom.copy() if self._last_odom is not None
                             else np.zeros(3), self._odom_path[-1] if self._odom_path else 0.0,
                             self._heading_var))
        self._lineage_buf[self._n_kf] = np.arange(len(self.x), dtype=np.int32)
        self._n_kf += 1

    # -- driver -------------------------------------------------------------------------
    def process(self, scan: Scan) -> RbpfStep:
        """:meth:`step` (the name every estimator shares)."""
        return self.step(scan)

    def step(self, scan: Scan) -> RbpfStep:
        """One scan through §7.3: the first starts the map; between two updates (less
        than the update distance or turn of odometry) the scan's pose is refined but
        the particles stay; else predict and weigh (eqs. 7-9, or the improved
        proposal), maybe resample, update the maps."""
        xy, inten = scan.points()
        self.times.append(scan.t)
        self._odom_path.append(0.0 if self._last_odom is None else self._odom_path[-1] + float(
            np.hypot(*(scan.odom[:2] - self._last_odom[:2]))))
        self._last_odom = scan.odom.copy()
        self._aligned = None  # a new scan: the filter's estimate is current again
        if self.config.alignment is not None:
            pts, pin = voxel_downsample(xy, inten, self.config.map.voxel_m)
            self._scan_xy.append(pts)
            self._scan_inten.append(pin)
        if self._anchor_odom is None:
            self._first(scan, xy, inten)
            return RbpfStep(scan.t, "first", keyframe=True)
        u = relative(self._anchor_odom, scan.odom)
        lin, ang = self._update_distances()
        if not moved(self._anchor_odom, scan.odom, lin, ang) or len(xy) < 8:
            self._between(u, xy, inten)
            return RbpfStep(scan.t, "between")
        ll = self.predict_and_weigh(u, xy, inten)
        self.logw += ll
        self.loglik += ll
        ess = self.effective_sample_size()
        idx = self.maybe_resample(ess)
        keyframe = self.update_maps(scan, xy, inten, idx)
        return RbpfStep(scan.t, "update", ess, idx is not None, keyframe)

    def _first(self, scan: Scan, xy: np.ndarray, inten: np.ndarray | None) -> None:
        self.x[:] = scan.odom
        self._anchor_odom = scan.odom.copy()
        self._last_kf_odom = scan.odom.copy()
        self._store_step(None)
        self._scan_delta.append(np.zeros(3))
        self.add_keyframe(0, xy, inten)

    def _update_distances(self) -> tuple[float, float]:
        """Travel and turn between filter updates: the improved proposal's own
        (GMapping's linearUpdate / angularUpdate), else the paper's keyframe ones."""
        cfg = self.config
        if cfg.proposal == "improved":
            return cfg.update_linear_m, cfg.update_angular_rad
        return cfg.map.update_linear_m, cfg.map.update_angular_rad

    def _between(self, u: np.ndarray, xy: np.ndarray, inten: np.ndarray | None) -> None:
        """A scan between two updates: its pose is the last update's best particle (+)
        ``u`` (the odometry since), or (+) the increment :meth:`track` matches."""
        cfg = self.config
        self._scan_step.append(len(self._hist_pose) - 1)
        if cfg.proposal == "improved" and cfg.track_scans and len(xy) >= 8:
            pick = self._beams(xy, True)
            u = self.track(u, xy[pick], None if inten is None else inten[pick])
        self._scan_delta.append(u)

    def predict_and_weigh(self, u: np.ndarray, xy: np.ndarray,
                          inten: np.ndarray | None) -> np.ndarray:
        """Steps 1-2: move the particles by the proposal and return their log weight
        increments -- the improved proposal's η (:meth:`improved_step`), or eq. 7's
        prediction (on the odometry, or on the gated Intensity-ICP increment) weighed by
        eqs. 8-9 (:meth:`likelihood`)."""
        cfg = self.config
        improved = cfg.proposal == "improved"
        pick = self._beams(xy, improved)
        xs, its = xy[pick], None if inten is None else inten[pick]
        if improved:
            return self.improved_step(u, xs, its)
        um = self.matched_increment(u, xy, inten) if cfg.proposal == "gated-icp" else None
        if um is None:
            self.predict(u)
        else:
            self.predict(um, cfg.proposal_noise_scale)
        return self.likelihood(xs, its)

    def update_maps(self, scan: Scan, xy: np.ndarray, inten: np.ndarray | None,
                    idx: np.ndarray | None) -> bool:
        """Step 4: record the update in the trajectory tree and, once the robot has moved
        ``keyframe_linear_m`` / ``keyframe_angular_rad`` since the last keyframe, add
        the scan as a keyframe every particle places at its own pose. Returns whether
        one was added."""
        cfg = self.config
        self.matched += 1
        self._store_step(idx)
        self._scan_delta.append(np.zeros(3))
        self._anchor_odom = scan.odom.copy()
        assert self._last_kf_odom is not None
        if not moved(self._last_kf_odom, scan.odom, cfg.map.keyframe_linear_m,
                     cfg.map.keyframe_angular_rad):
            return False
        self.add_keyframe(len(self.times) - 1, xy, inten)
        self._last_kf_odom = scan.odom.copy()
        return True

    def _beams(self, xy: np.ndarray, improved: bool) -> np.ndarray:
        """The ``beams`` a match uses, evenly picked; with the improved proposal among
        the returns within the keyframes' reach only (:meth:`Keyframes.reach`:
        ``max_points_m``, or ``open_points_m`` for an open scan; beyond it they never
        find a map point)."""
        cfg = self.config
        cand = np.arange(len(xy))
        if improved:
            near = np.flatnonzero(self.keyframes.in_reach(xy))
            if len(near) >= 8:
                cand = near
        return cand[np.linspace(0, len(cand) - 1, min(cfg.beams, len(cand))).astype(int)]

    def _store_step(self, idx: np.ndarray | None) -> None:
        p = len(self.x)
        self._hist_pose.append(self.x.astype(np.float32))
        self._hist_parent.append((np.arange(p) if idx is None else idx).astype(np.int32))
        self._scan_step.append(len(self._hist_pose) - 1)

    @property
    def _lineage(self) -> np.ndarray:
        """``(K, P)``: for each keyframe, which of its stored poses each particle owns."""
        return self._lineage_buf[:self._n_kf]

    def _kf_poses_of(self, particle: int) -> np.ndarray:
        """The keyframe poses ``(K, 3)`` of one particle: its map."""
        k = self._n_kf
        return np.asarray(self._kf_pose[np.arange(k), self._lineage[:k, particle]])

    def finish(self) -> int:
        """The end of a run: global scan alignment of every scan so far from the best
        particle's trajectory (``config.alignment``, see :class:`RbpfConfig`); until the
        next scan arrives, the trajectory, the pose and the map's poses are the aligned
        ones. Returns how many pairwise matches held (0 when alignment is off)."""
        cfg = self.config.alignment
        if cfg is None or len(self.times) < 2:
            return 0
        if self._aligned is not None:
            return self.alignment_matches
        _, poses = self._filter_trajectory()
        if self.config.alpha > 0 and cfg.alpha == 0:
            cfg = cfg.model_copy(update={"alpha": self.config.alpha})
        self._aligned, self.alignment_matches = align_scans(
            self._scan_xy, self._scan_inten, poses, poses, estimate_closures(poses, cfg),
            cfg, GraphConfig())
        return self.alignment_matches

    @property
    def aligned(self) -> bool:
        """Whether the outputs are finish()'s aligned poses."""
        return self._aligned is not None

    # -- outputs ------------------------------------------------------------------------
    @property
    def best(self) -> int:
        """The particle with the highest accumulated likelihood (§7.4)."""
        return int(np.argmax(self.loglik))

    @property
    def pose(self) -> np.ndarray:
        """Current pose of the best particle, with the odometry since its last update
        (after :meth:`finish`, the last scan's aligned pose)."""
        if self._aligned is not None:
            return self._aligned[-1].copy()
        if not self._scan_delta:
            return np.zeros(3)
        return compose(self.x[self.best], self._scan_delta[-1])

    def trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """Times and poses ``(N, 3)`` of every scan along the best particle's history
        (after :meth:`finish`, aligned)."""
        if self._aligned is not None:
            return np.array(self.times), self._aligned.copy()
        return self._filter_trajectory()

    def _filter_trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        steps = len(self._hist_pose)
        path = np.zeros((steps, 3))
        i = self.best
        for s in range(steps - 1, -1, -1):
            path[s] = self._hist_pose[s][i]
            i = int(self._hist_parent[s][i])
        poses = compose(path[np.array(self._scan_step)], np.array(self._scan_delta))
        return np.array(self.times), poses

    def map_poses(self) -> np.ndarray:
        """The best particle's keyframe poses ``(K, 3)``: its map (after :meth:`finish`,
        their scans' aligned poses)."""
        if self._aligned is not None:
            return self._aligned[[kf.scan_index for kf in self.keyframes.frames]]
        return self._kf_poses_of(self.best)
