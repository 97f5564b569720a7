"""Global scan alignment: the last step of graph SLAM, after Lu & Milios, "Globally
Consistent Range Scan Alignment for Environment Mapping" (Autonomous Robots 4, 1997):
every scan of the run is a pose, every pair of overlapping scans that point-to-line ICP
aligns is a constraint, and all poses are solved for at once.

Graph SLAM's online estimate (:mod:`chizu.numeric.slam.graph`) places scans by matching them
to submaps on a 5 cm probability grid and closes loops between nodes; it gets the
topology right but leaves centimetre errors between neighbouring scans (the grid's
cells, scans between nodes tracked in a small window). This step starts from that
estimate and refines it:

1. pairwise matches (:func:`pairwise_matches`): each scan is aligned by point-to-line
   ICP (:func:`chizu.numeric.slam.matching.intensity_icp.intensity_icp`, eq. 1's intensity term when
   ``alpha > 0``) to the scans ``sequential`` steps before it and to up to
   ``revisits`` earlier scans within ``revisit_radius_m`` (from different passes, by
   default at any heading: a place passed the other way is a loop closure too),
   starting at their relative pose in the online estimate. A match counts only when ICP
   converged, at least ``min_overlap`` of the scan found a partner within ``inlier_m``
   and the correction stays inside ``max_correction_m`` / ``max_correction_rad`` --
   it refines the estimate, it does not re-decide it;
2. its covariance: ``sigma**2 (J^T J)^-1`` from the point-to-line Jacobian at the
   solution (a corridor's length stays uncertain, its width does not), ``sigma`` the
   larger of ``point_sigma_m`` and ``residual_scale`` times the match's residual RMS,
   plus a floor, moved into the matched scan's frame (GTSAM's between-factor error);
3. one batch optimisation (GTSAM Levenberg-Marquardt) of all scan poses over the
   matches (Huber-robust), the odometry between consecutive scans, and the online
   run's loop closures, those two with the online pose graph's noise
   (:class:`chizu.numeric.slam.pose_graph.GraphConfig`).

Each pair is matched in one compiled kernel (:func:`_match_pair`, releasing the GIL), so
the thread pool's workers run side by side. The improved RBPF ends its runs with the
same step, from its best particle's trajectory, whose increments are then the chain
between consecutive scans, and with :func:`estimate_closures` in place of the online
closures. What it gains on the logs: ``docs/notes/slam-graph.md``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import gtsam
import numpy as np
from numba import njit
from pydantic import BaseModel, Field
from scipy.spatial import cKDTree

from chizu.numeric.geometry import compose_into, place_into, relative, wrap_angle, wrap_scalar
from chizu.numeric.slam.matching.intensity_icp import (
    IcpConfig,
    IcpSteps,
    Reference,
    RefIndex,
    icp_iterations,
    line_normal_equations,
    nearest_points,
)
from chizu.numeric.slam.pose_graph import ANCHOR_SIGMAS, GraphConfig, as_pose2
from chizu.numeric.threads import default_threads, thread_map


class AlignmentConfig(BaseModel):
    """Parameters of global scan alignment; one set for every log."""

    sequential: tuple[int, ...] = Field((1, 2, 3, 5, 8), description="each scan is "
                                        "matched to the scans this many steps before it")
    revisit_radius_m: float = Field(1.5, ge=0, description="... and to earlier scans "
                                    "from other passes within this distance")
    revisit_max_turn_rad: float = Field(np.pi, gt=0, le=np.pi, description="... facing "
                                        "within this angle of it (π: at any heading)")
    revisit_min_gap: int = Field(20, ge=1, description="scans between two passes")
    revisits: int = Field(3, ge=0, description="earlier scans per scan: the first, "
                          "middle and last of those in reach")
    apart_rad: float = Field(1.0, ge=0, le=np.pi, description="estimate_closures keeps "
                             "the online estimate's pairs whose headings differ by at "
                             "least this")
    max_correspondence_m: float = Field(0.3, gt=0, description="ICP pairs beyond this "
                                        "are outliers")
    max_iterations: int = Field(30, ge=1)
    inlier_m: float = Field(0.1, gt=0, description="a point with a partner this close "
                            "at the solution overlaps")
    min_overlap: float = Field(0.5, gt=0, le=1, description="share of a scan's points "
                               "that must overlap for a match to count")
    max_correction_m: float = Field(0.1, gt=0)
    max_correction_rad: float = Field(0.03, gt=0)
    point_sigma_m: float = Field(0.01, gt=0, description="noise of one point-to-line "
                                 "residual, at least (the laser's) ...")
    residual_scale: float = Field(3.0, ge=0, description="... and at least this many "
                                  "times the match's own residual RMS (rough walls, "
                                  "sparse beams and residuals that are not independent "
                                  "make a match weaker)")
    floor_sigma_m: float = Field(0.01, gt=0, description="added to every match's sigma")
    floor_sigma_rad: float = Field(0.001, gt=0)
    huber_k: float = Field(1.345, gt=0, description="Huber threshold of the matches "
                           "(whitened units)")
    lm_iterations: int = Field(50, ge=1)
    alpha: float = Field(0.0, ge=0, description="intensity weight of eq. 1 in ICP")


@dataclass(frozen=True)
class PairwiseMatch:
    """Scan ``b`` at ``delta`` in scan ``a``'s frame, with the covariance of ``delta``
    in ``b``'s frame (GTSAM's between-factor error)."""

    a: int
    b: int
    delta: np.ndarray
    covariance: np.ndarray


def candidate_pairs(poses: np.ndarray, cfg: AlignmentConfig,
                    first: int = 0) -> list[tuple[int, int]]:
    """The scan pairs ``(a, b)``, ``a < b``, to match: the sequential ones and, per
    scan, up to ``revisits`` earlier scans of other passes in reach facing within
    ``revisit_max_turn_rad`` of it (by default at any heading: the overlap test refuses
    a pair facing apart that sees too little of the same walls); only those with
    ``b >= first`` (the scans before ``first`` are held where they are)."""
    n = len(poses)
    pairs = [(b - k, b) for b in range(first, n) for k in cfg.sequential if b - k >= 0]
    if cfg.revisits == 0 or cfg.revisit_radius_m <= 0 or n <= first:
        return pairs
    near = cKDTree(poses[:, :2]).query_ball_point(poses[first:, :2], cfg.revisit_radius_m)
    for b, near_b in enumerate(near, start=first):
        js = np.sort(np.asarray(near_b, dtype=np.intp))
        js = js[js < b - cfg.revisit_min_gap]
        if cfg.revisit_max_turn_rad < np.pi:
            js = js[np.abs(wrap_angle(poses[b, 2] - poses[js, 2])) < cfg.revisit_max_turn_rad]
        if len(js):
            picks = sorted({int(js[0]), int(js[len(js) // 2]), int(js[-1])})[: cfg.revisits]
            pairs += [(j, b) for j in picks]
    return pairs


def estimate_closures(poses: np.ndarray, cfg: AlignmentConfig,
                      ) -> list[tuple[int, int, np.ndarray]]:
    """Loop closures an online estimate holds that the revisit matches often cannot
    check: each scan's nearest earlier scan of another pass (more than
    ``revisit_min_gap`` scans before it) within ``revisit_radius_m`` that faces away
    from it by at least ``apart_rad`` -- a corridor driven both ways, where
    a 180° laser sees too little of the same walls for ICP's overlap test -- with their
    relative pose in ``poses``.

    The particle filter places a scan against its map, keyframes from every pass and
    direction, so it relates such pairs where no scan pair can; without them a loop
    driven the other way back is held only through the chain of sequential matches."""
    n = len(poses)
    out: list[tuple[int, int, np.ndarray]] = []
    if n == 0 or cfg.revisit_radius_m <= 0:
        return out
    near = cKDTree(poses[:, :2]).query_ball_point(poses[:, :2], cfg.revisit_radius_m)
    for b, js in enumerate(near):
        js = [j for j in js if j < b - cfg.revisit_min_gap
              and abs(wrap_angle(poses[b, 2] - poses[j, 2])) >= cfg.apart_rad]
        if js:
            j = min(js, key=lambda j: float(np.hypot(*(poses[j, :2] - poses[b, :2]))))
            out.append((j, b, relative(poses[j], poses[b])))
    return out


def match_pair(ref: Reference, xy: np.ndarray, intensity: np.ndarray | None,
               guess: np.ndarray, cfg: AlignmentConfig, icp: IcpConfig | None = None,
               ) -> tuple[np.ndarray, np.ndarray] | None:
    """Align scan points ``xy`` (own frame) to ``ref`` (the other scan, its frame) from
    ``guess``; the pose found and its covariance (in the found pose's frame), or None
    when the match does not count (see the module's step 1). ``icp``: the ICP's
    parameters, made from ``cfg`` when not given."""
    icp = _icp_config(cfg) if icp is None else icp
    xy = np.ascontiguousarray(xy, dtype=float)
    ok, pose, cov = _match_pair(ref.kernel(True), xy, ref.intensity_column(intensity, len(xy)),
                                np.asarray(guess, dtype=float), IcpSteps.of(icp, True),
                                PairGate.of(cfg))
    return (pose, cov) if ok else None


def _icp_config(cfg: AlignmentConfig) -> IcpConfig:
    return IcpConfig(alpha=cfg.alpha, metric="line", max_iterations=cfg.max_iterations,
                     max_correspondence_m=cfg.max_correspondence_m)


class PairGate(NamedTuple):
    """When a pair's match counts and what its covariance is (from
    :class:`AlignmentConfig`, as the compiled kernel takes it)."""

    max_correction_m: float
    max_correction_rad: float
    inlier_m: float
    min_overlap: float
    point_sigma: float
    residual_scale: float
    floor_m: float
    floor_rad: float

    @staticmethod
    def of(cfg: AlignmentConfig) -> PairGate:
        return PairGate(float(cfg.max_correction_m), float(cfg.max_correction_rad),
                        float(cfg.inlier_m), float(cfg.min_overlap), float(cfg.point_sigma_m),
                        float(cfg.residual_scale), float(cfg.floor_sigma_m),
                        float(cfg.floor_sigma_rad))


@njit(cache=True, nogil=True)
def _match_pair(ref: RefIndex, xy: np.ndarray, extra: np.ndarray, guess: np.ndarray,
                steps: IcpSteps, gate: PairGate) -> tuple[bool, np.ndarray, np.ndarray]:
    """Steps 1-2 of one pair, compiled (it releases the GIL, so the thread pool's
    workers run side by side): point-to-line ICP, the correction gate, the overlap
    test and the covariance."""
    pose = np.zeros(3)
    cov = np.zeros((3, 3))
    n = len(xy)
    if n < steps.min_inliers:
        return False, pose, cov
    total, converged, _, _, _ = icp_iterations(ref, xy, extra, guess, steps)
    if not converged:
        return False, pose, cov
    compose_into(total, guess, pose)
    pose[2] = wrap_scalar(pose[2])
    # the correction, in the guess's frame (relative(guess, pose))
    c, s = math.cos(guess[2]), math.sin(guess[2])
    dx, dy = pose[0] - guess[0], pose[1] - guess[1]
    if (math.hypot(c * dx + s * dy, -s * dx + c * dy) > gate.max_correction_m
            or abs(wrap_scalar(pose[2] - guess[2])) > gate.max_correction_rad):
        return False, pose, cov
    q = np.empty((n, ref.aug.shape[1]))
    place_into(xy, pose, q)
    q[:, 2:] = extra
    d, idx = nearest_points(ref.aug, ref.keys, ref.order, ref.ox, ref.oy, ref.cell, ref.top, q,
                            gate.inlier_m)
    hits = np.flatnonzero(np.isfinite(d))
    if len(hits) < max(gate.min_overlap * n, 10):
        return False, pose, cov
    info, _, sq = line_normal_equations(q, ref.xy, ref.normals, idx, hits)
    sigma = max(gate.point_sigma, gate.residual_scale * math.sqrt(sq / len(hits)))
    info /= sigma * sigma
    info[0, 0] += 1e-6
    info[1, 1] += 1e-6
    info[2, 2] += 1e-8
    cov[:, :] = np.linalg.inv(info)
    cov[0, 0] += gate.floor_m * gate.floor_m
    cov[1, 1] += gate.floor_m * gate.floor_m
    cov[2, 2] += gate.floor_rad * gate.floor_rad
    # the Jacobian perturbs the pose on the left, in the reference's frame; GTSAM's
    # between-factor error is on the right, in the matched scan's frame: the adjoint
    # of the pose's inverse, (x', y', -theta) with x' = -(c x + s y), y' = s x - c y
    c, s = math.cos(pose[2]), math.sin(pose[2])
    xi, yi = -(c * pose[0] + s * pose[1]), s * pose[0] - c * pose[1]
    adj = np.array([[c, s, yi], [-s, c, -xi], [0.0, 0.0, 1.0]])
    return True, pose, adj @ cov @ adj.T


def pairwise_matches(points: Sequence[np.ndarray], intensities: Sequence[np.ndarray | None],
                     poses: np.ndarray, cfg: AlignmentConfig, threads: int | None = None,
                     first: int = 0) -> list[PairwiseMatch]:
    """Step 1-2 over every candidate pair (those of :func:`candidate_pairs` with
    ``first``), on the process's thread pool."""
    pairs = candidate_pairs(poses, cfg, first)
    refs: dict[int, Reference] = {}
    for a in sorted({a for a, _ in pairs}):
        if len(points[a]) >= 10:
            refs[a] = Reference(points[a], intensities[a], cfg.alpha)
    # the normals computed once, before the threads share the references
    thread_map(lambda r: r.normals, list(refs.values()),
               default_threads() if threads is None else threads)
    icp = _icp_config(cfg)
    ia = np.array([a for a, _ in pairs], dtype=np.intp)
    ib = np.array([b for _, b in pairs], dtype=np.intp)
    guesses = relative(poses[ia], poses[ib]) if len(pairs) else np.zeros((0, 3))

    def one(k: int) -> PairwiseMatch | None:
        a, b = pairs[k]
        if a not in refs or len(points[b]) < 10:
            return None
        found = match_pair(refs[a], points[b], intensities[b], guesses[k], cfg, icp)
        return None if found is None else PairwiseMatch(a, b, *found)

    chunk = 256
    batches = [range(i, min(i + chunk, len(pairs))) for i in range(0, len(pairs), chunk)]
    done = thread_map(lambda ks: [one(k) for k in ks], batches,
                      default_threads() if threads is None else threads)
    return [m for batch in done for m in batch if m is not None]


def align_globally(poses: np.ndarray, odometry: np.ndarray, matches: Sequence[PairwiseMatch],
                   closures: Sequence[tuple[int, int, np.ndarray]],
                   cfg: AlignmentConfig, noise: GraphConfig | None = None,
                   held: int = 0,
                   priors: Sequence[tuple[int, np.ndarray, np.ndarray]] = (),
                   breaks: Sequence[int] = (),
                   local: Sequence[tuple[int, int, np.ndarray]] = ()) -> np.ndarray:
    """Step 3: every scan's pose ``(N, 3)`` after one batch optimisation, from the
    online estimate ``poses``; ``odometry`` ``(N, 3)`` the scans' odometry readings,
    ``closures`` ``(a, b, delta)`` the online run's loop closures between scans, both
    with the online pose graph's noise (``noise``, :class:`GraphConfig`). The first
    pose is anchored; with ``held`` > 0 the first ``held`` poses are a saved map's
    keyframes, each anchored where it is, and the odometry chain starts after them.
    ``priors`` ``(k, pose, covariance)`` place single scans in the world frame (a
    scan matched to a saved map), Huber-robust like the matches. The odometry chain
    starts again at each scan of ``breaks`` (another run's first scan: nothing but the
    matches, the closures and the priors ties it to the scan before). ``local`` ``(a, b,
    delta)``: relative poses of the online estimate held as local SLAM's edges hold
    them (the noise's local sigmas, not robust: they are no guess to be outvoted)."""
    noise = GraphConfig() if noise is None else noise
    n = len(poses)
    if n < 2:
        return poses.copy()
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for k in range(n):
        values.insert(k, as_pose2(poses[k]))
    anchor = gtsam.noiseModel.Diagonal.Sigmas(ANCHOR_SIGMAS)
    for k in range(max(1, held)):
        graph.add(gtsam.PriorFactorPose2(k, as_pose2(poses[k]), anchor))
    huber = gtsam.noiseModel.mEstimator.Huber.Create(cfg.huber_k)
    u = relative(odometry[:-1], odometry[1:])
    sig = noise.odometry_sigmas(u)
    cut = set(breaks)
    for k in range(held + 1 if held else 1, n):
        if k in cut:
            continue
        graph.add(gtsam.BetweenFactorPose2(k - 1, k, as_pose2(u[k - 1]),
                                           gtsam.noiseModel.Diagonal.Sigmas(sig[k - 1])))
    for m in matches:
        robust = gtsam.noiseModel.Robust.Create(
            huber, gtsam.noiseModel.Gaussian.Covariance(m.covariance))
        graph.add(gtsam.BetweenFactorPose2(m.a, m.b, as_pose2(m.delta), robust))
    for k, pose, cov in priors:
        robust = gtsam.noiseModel.Robust.Create(huber, gtsam.noiseModel.Gaussian.Covariance(cov))
        graph.add(gtsam.PriorFactorPose2(int(k), as_pose2(pose), robust))
    loop = noise.loop_noise()
    for a, b, delta in closures:
        graph.add(gtsam.BetweenFactorPose2(int(a), int(b), as_pose2(delta), loop))
    for a, b, delta in local:
        graph.add(gtsam.BetweenFactorPose2(int(a), int(b), as_pose2(delta),
                                           gtsam.noiseModel.Diagonal.Sigmas(
                                               noise.local_sigmas(delta))))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(cfg.lm_iterations)
    out = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    return np.array([[p.x(), p.y(), p.theta()] for p in (out.atPose2(k) for k in range(n))])


def align_scans(points: Sequence[np.ndarray], intensities: Sequence[np.ndarray | None],
                poses: np.ndarray, odometry: np.ndarray,
                closures: Sequence[tuple[int, int, np.ndarray]],
                cfg: AlignmentConfig, noise: GraphConfig | None = None,
                local: Sequence[tuple[int, int, np.ndarray]] = (),
                ) -> tuple[np.ndarray, int]:
    """Steps 1-3: the aligned poses of all scans and how many pairwise matches held
    (``local``: see :func:`align_globally`)."""
    matches = pairwise_matches(points, intensities, poses, cfg)
    return (align_globally(poses, odometry, matches, closures, cfg, noise, local=local),
            len(matches))


@dataclass
class ScanStore:
    """Every scan of a run as :func:`align_scans` takes it at the end: its points and
    intensities (down-sampled) and, where the estimator has it, its odometry; and the
    aligned poses once :meth:`AlignedOutputs.finish` has run (until the next scan).

    A long run forgets the points of scans whose place the map already holds
    (:meth:`forget`; graph SLAM's trimmed submaps): the alignment matches such a scan to
    nothing, and the online estimate's relative poses hold it to its neighbours."""

    xy: list[np.ndarray] = field(default_factory=list)
    inten: list[np.ndarray | None] = field(default_factory=list)
    odom: list[np.ndarray] = field(default_factory=list)
    #: one byte per scan, 1 where its points were forgotten
    forgotten: bytearray = field(default_factory=bytearray)
    aligned: np.ndarray | None = None
    matches: int = 0

    def add(self, xy: np.ndarray, inten: np.ndarray | None,
            odom: np.ndarray | None = None) -> None:
        self.xy.append(xy)
        self.inten.append(inten)
        if odom is not None:
            self.odom.append(odom.copy())
        self.forgotten.append(0)

    def forget(self, start: int, stop: int) -> None:
        """Drop the points of scans ``start`` to ``stop - 1``."""
        for i in range(start, min(stop, len(self.xy))):
            self.xy[i], self.inten[i] = _NO_POINTS, None
            self.forgotten[i] = 1

    def kept(self) -> np.ndarray:
        """The indices of the scans whose points are kept."""
        return np.flatnonzero(self._mask() == 0)

    def lost(self) -> np.ndarray:
        """The indices of the scans whose points were forgotten."""
        return np.flatnonzero(self._mask())

    def _mask(self) -> np.ndarray:
        return np.frombuffer(bytes(self.forgotten), dtype=np.uint8)


_NO_POINTS = np.zeros((0, 2))


class AlignedOutputs:
    """``finish()`` and the outputs both estimators share: until :meth:`finish` the
    pose, the trajectory and the map's poses are the estimator's online ones
    (``_online_*``); after it, until the next scan, the global alignment's
    (:func:`align_scans` over every scan from the online trajectory)."""

    times: list[float]
    scans: ScanStore

    def _alignment(self) -> tuple[AlignmentConfig | None, float]:
        """The alignment's config (None: off) and the estimator's intensity weight."""
        raise NotImplementedError

    def _alignment_inputs(self, poses: np.ndarray,
                          ) -> tuple[np.ndarray, list[tuple[int, int, np.ndarray]],
                                     GraphConfig]:
        """For the online ``poses`` of every scan: the odometry chain, the closures
        (scan, scan, relative pose) and the pose graph's noise the alignment keeps."""
        raise NotImplementedError

    def _online_trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def _online_pose(self) -> np.ndarray:
        raise NotImplementedError

    def _online_map_poses(self) -> np.ndarray:
        raise NotImplementedError

    def _map_scans(self) -> np.ndarray:
        """The scan index of each map keyframe ``(K,)``."""
        raise NotImplementedError

    def finish(self) -> int:
        """The end of a run: global scan alignment of every scan so far from the online
        estimate; until the next scan arrives, the trajectory, the pose and the map's
        poses are the aligned ones. Returns how many pairwise matches held (0 when
        alignment is off)."""
        cfg, alpha = self._alignment()
        if cfg is None or len(self.times) < 2:
            return 0
        if self.scans.aligned is not None:
            return self.scans.matches
        _, poses = self._online_trajectory()
        odometry, closures, noise = self._alignment_inputs(poses)
        if alpha > 0 and cfg.alpha == 0:
            cfg = cfg.model_copy(update={"alpha": alpha})
        # a forgotten scan has no points to match: it is held to its neighbours by the
        # online estimate's relative poses, as firmly as local SLAM's edges held them
        # online, so that it moves with the aligned scans
        lost = self.scans.lost()
        pairs = np.union1d(lost, lost - 1)
        pairs = pairs[(pairs >= 0) & (pairs + 1 < len(poses))]
        chain = [(int(i), int(i + 1), relative(poses[i], poses[i + 1])) for i in pairs]
        self.scans.aligned, self.scans.matches = align_scans(
            self.scans.xy, self.scans.inten, poses, odometry, closures, cfg, noise, chain)
        return self.scans.matches

    @property
    def aligned(self) -> bool:
        """Whether the outputs are finish()'s aligned poses."""
        return self.scans.aligned is not None

    @property
    def pose(self) -> np.ndarray:
        """The latest scan's pose."""
        if self.scans.aligned is not None:
            return self.scans.aligned[-1].copy()
        return self._online_pose()

    def trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """Times and poses ``(N, 3)`` of every scan."""
        if self.scans.aligned is not None:
            return np.array(self.times), self.scans.aligned.copy()
        return self._online_trajectory()

    def map_poses(self) -> np.ndarray:
        """The poses ``(K, 3)`` of the map's keyframes."""
        if self.scans.aligned is not None:
            return self.scans.aligned[self._map_scans()]
        return self._online_map_poses()
