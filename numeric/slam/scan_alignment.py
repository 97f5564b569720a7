"""Global scan alignment: the last step of graph SLAM, after Lu & Milios, "Globally
Consistent Range Scan Alignment for Environment Mapping" (Autonomous Robots 4, 1997):
every scan of the run is a pose, every pair of overlapping scans that point-to-line ICP
aligns is a constraint, and all poses are solved for at once.

Graph SLAM's online estimate (:mod:`numeric.slam.graph`) places scans by matching them
to submaps on a 5 cm probability grid and closes loops between nodes; it gets the
topology right but leaves centimetre errors between neighbouring scans (the grid's
cells, scans between nodes tracked in a small window). This step starts from that
estimate and refines it:

1. pairwise matches (:func:`pairwise_matches`): each scan is aligned by point-to-line
   ICP (:func:`numeric.slam.intensity_icp.intensity_icp`, eq. 1's intensity term when
   ``alpha > 0``) to the scans ``sequential`` steps before it and to up to
   ``revisits`` earlier scans within ``revisit_radius_m`` (from different passes),
   starting at their relative pose in the online estimate. A match counts only when
   ICP converged, at least ``min_overlap`` of the scan found a partner within
   ``inlier_m`` and the correction stays inside ``max_correction_m`` /
   ``max_correction_rad`` -- it refines the estimate, it does not re-decide it;
2. its covariance: ``sigma**2 (J^T J)^-1`` from the point-to-line Jacobian at the
   solution (a corridor's length stays uncertain, its width does not), ``sigma`` the
   larger of ``point_sigma_m`` and ``residual_scale`` times the match's residual RMS,
   plus a floor, moved into the matched scan's frame (GTSAM's between-factor error);
3. one batch optimisation (GTSAM Levenberg-Marquardt) of all scan poses over the
   matches (Huber-robust), the odometry between consecutive scans, and the online
   run's loop closures, those two with the online pose graph's noise
   (:class:`numeric.slam.pose_graph.GraphConfig`).

Measured on the full Freiburg logs (README, ``tests/bench/slam.py``): the relation
error of graph SLAM falls by 10-35 % (fr079 0.061 -> 0.040 m). Each pair is matched
in one compiled kernel (:func:`_match_pair`, releasing the GIL), so the thread pool's
workers run side by side: aces's 45 000 pairs take 25 s on two cores, 225 s with the
NumPy iterations that came before it (same matches, same poses).

The improved RBPF ends its runs with the same step (:meth:`RbpfSlam.finish
<numeric.slam.rbpf.RbpfSlam.finish>`): from its best particle's trajectory, whose
increments are then the chain between consecutive scans, and with
:func:`estimate_closures` in place of the online closures (aces, fr079, mit-csail
0.046 / 0.059 / 0.038 -> 0.037 / 0.041 / 0.027 m, seed 0; fr-clinic 1-3 % worse).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import gtsam
import numpy as np
from numba import njit
from pydantic import BaseModel, Field
from scipy.spatial import cKDTree

from numeric.geometry import compose_into, place_into, relative, wrap_angle, wrap_scalar
from numeric.slam.intensity_icp import (
    IcpConfig,
    Reference,
    icp_iterations,
    line_normal_equations,
    nearest_points,
)
from numeric.slam.pose_graph import ANCHOR_SIGMAS, GraphConfig, as_pose2
from numeric.threads import default_threads, thread_map


class AlignmentConfig(BaseModel):
    """Parameters of global scan alignment; one set for every log."""

    sequential: tuple[int, ...] = Field((1, 2, 3, 5, 8), description="each scan is "
                                        "matched to the scans this many steps before it")
    revisit_radius_m: float = Field(1.5, ge=0, description="... and to earlier scans "
                                    "from other passes within this distance")
    revisit_max_turn_rad: float = Field(1.0, ge=0, le=np.pi, description="... facing "
                                        "within this angle of it")
    revisit_min_gap: int = Field(20, ge=1, description="scans between two passes")
    revisits: int = Field(3, ge=0, description="earlier scans per scan: the first, "
                          "middle and last of those in reach")
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


def candidate_pairs(poses: np.ndarray, cfg: AlignmentConfig) -> list[tuple[int, int]]:
    """The scan pairs ``(a, b)``, ``a < b``, to match: the sequential ones and, per
    scan, up to ``revisits`` earlier scans of other passes in reach."""
    n = len(poses)
    pairs = [(b - k, b) for b in range(n) for k in cfg.sequential if b - k >= 0]
    if cfg.revisits == 0 or cfg.revisit_radius_m <= 0 or n == 0:
        return pairs
    near = cKDTree(poses[:, :2]).query_ball_point(poses[:, :2], cfg.revisit_radius_m)
    for b, near_b in enumerate(near):
        js = np.sort(np.asarray(near_b, dtype=np.intp))
        js = js[js < b - cfg.revisit_min_gap]
        js = js[np.abs(wrap_angle(poses[b, 2] - poses[js, 2])) < cfg.revisit_max_turn_rad]
        if len(js):
            picks = sorted({int(js[0]), int(js[len(js) // 2]), int(js[-1])})[: cfg.revisits]
            pairs += [(j, b) for j in picks]
    return pairs


def estimate_closures(poses: np.ndarray, cfg: AlignmentConfig,
                      ) -> list[tuple[int, int, np.ndarray]]:
    """Loop closures an online estimate holds that the revisit matches cannot check:
    each scan's nearest earlier scan of another pass (more than ``revisit_min_gap``
    scans before it) within ``revisit_radius_m`` that faces away from it by at least
    ``revisit_max_turn_rad`` -- a corridor driven both ways, where a 180° laser sees
    too little of the same walls for ICP -- with their relative pose in ``poses``.

    The particle filter places a scan against its map, keyframes from every pass and
    direction, so it relates such pairs where no scan pair can; without them a loop
    driven the other way back is held only through the chain of sequential matches
    (full mit-csail, 512 particles: 0.038 -> 0.035 m but 0.064 -> 0.124 m on the
    loop-spanning relations; with them 0.027 / 0.045)."""
    n = len(poses)
    out: list[tuple[int, int, np.ndarray]] = []
    if n == 0 or cfg.revisit_radius_m <= 0:
        return out
    near = cKDTree(poses[:, :2]).query_ball_point(poses[:, :2], cfg.revisit_radius_m)
    for b, js in enumerate(near):
        js = [j for j in js if j < b - cfg.revisit_min_gap
              and abs(wrap_angle(poses[b, 2] - poses[j, 2])) >= cfg.revisit_max_turn_rad]
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
    ok, pose, cov = _match_pair(
        ref.xy, ref.aug, ref.normals, *ref.index, xy, ref.intensity_column(intensity, len(xy)),
        np.asarray(guess, dtype=float), icp.max_iterations,
        icp.max_correspondence_m, icp.trim_factor, icp.trim_floor_m, icp.tolerance_m,
        icp.tolerance_rad, icp.min_inliers, cfg.max_correction_m, cfg.max_correction_rad,
        cfg.inlier_m, cfg.min_overlap, cfg.point_sigma_m, cfg.residual_scale,
        cfg.floor_sigma_m, cfg.floor_sigma_rad)
    return (pose, cov) if ok else None


def _icp_config(cfg: AlignmentConfig) -> IcpConfig:
    return IcpConfig(alpha=cfg.alpha, metric="line", max_iterations=cfg.max_iterations,
                     max_correspondence_m=cfg.max_correspondence_m)


@njit(cache=True, nogil=True)
def _match_pair(ref_xy: np.ndarray, ref_aug: np.ndarray, normals: np.ndarray,
                keys: np.ndarray, order: np.ndarray, ox: float, oy: float, cell: float,
                top: np.ndarray, xy: np.ndarray, extra: np.ndarray, guess: np.ndarray,
                max_iterations: int, max_corr: float, trim_factor: float,
                trim_floor: float, tol_m: float, tol_rad: float, min_inliers: int,
                max_correction_m: float,
                max_correction_rad: float, inlier_m: float, min_overlap: float,
                point_sigma: float, residual_scale: float, floor_m: float,
                floor_rad: float) -> tuple[bool, np.ndarray, np.ndarray]:
    """Steps 1-2 of one pair, compiled (it releases the GIL, so the thread pool's
    workers run side by side): point-to-line ICP, the correction gate, the overlap
    test and the covariance."""
    pose = np.zeros(3)
    cov = np.zeros((3, 3))
    n = len(xy)
    if n < min_inliers:
        return False, pose, cov
    total, converged, _, _, _ = icp_iterations(
        ref_xy, ref_aug, normals, keys, order, ox, oy, cell, top, xy, extra, guess, True,
        max_iterations, max_corr, trim_factor, trim_floor, tol_m, tol_rad, min_inliers)
    if not converged:
        return False, pose, cov
    compose_into(total, guess, pose)
    pose[2] = wrap_scalar(pose[2])
    # the correction, in the guess's frame (relative(guess, pose))
    c, s = math.cos(guess[2]), math.sin(guess[2])
    dx, dy = pose[0] - guess[0], pose[1] - guess[1]
    if (math.hypot(c * dx + s * dy, -s * dx + c * dy) > max_correction_m
            or abs(wrap_scalar(pose[2] - guess[2])) > max_correction_rad):
        return False, pose, cov
    q = np.empty((n, ref_aug.shape[1]))
    place_into(xy, pose, q)
    q[:, 2:] = extra
    d, idx = nearest_points(ref_aug, keys, order, ox, oy, cell, top, q, inlier_m)
    hits = np.flatnonzero(np.isfinite(d))
    if len(hits) < max(min_overlap * n, 10):
        return False, pose, cov
    info, _, sq = line_normal_equations(q, ref_xy, normals, idx, hits)
    sigma = max(point_sigma, residual_scale * math.sqrt(sq / len(hits)))
    info /= sigma * sigma
    info[0, 0] += 1e-6
    info[1, 1] += 1e-6
    info[2, 2] += 1e-8
    cov[:, :] = np.linalg.inv(info)
    cov[0, 0] += floor_m * floor_m
    cov[1, 1] += floor_m * floor_m
    cov[2, 2] += floor_rad * floor_rad
    # the Jacobian perturbs the pose on the left, in the reference's frame; GTSAM's
    # between-factor error is on the right, in the matched scan's frame: the adjoint
    # of the pose's inverse, (x', y', -theta) with x' = -(c x + s y), y' = s x - c y
    c, s = math.cos(pose[2]), math.sin(pose[2])
    xi, yi = -(c * pose[0] + s * pose[1]), s * pose[0] - c * pose[1]
    adj = np.array([[c, s, yi], [-s, c, -xi], [0.0, 0.0, 1.0]])
    return True, pose, adj @ cov @ adj.T


def pairwise_matches(points: Sequence[np.ndarray], intensities: Sequence[np.ndarray | None],
                     poses: np.ndarray, cfg: AlignmentConfig,
                     threads: int | None = None) -> list[PairwiseMatch]:
    """Step 1-2 over every candidate pair, on the process's thread pool."""
    pairs = candidate_pairs(poses, cfg)
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
                   cfg: AlignmentConfig, noise: GraphConfig | None = None) -> np.ndarray:
    """Step 3: every scan's pose ``(N, 3)`` after one batch optimisation, from the
    online estimate ``poses``; ``odometry`` ``(N, 3)`` the scans' odometry readings,
    ``closures`` ``(a, b, delta)`` the online run's loop closures between scans, both
    with the online pose graph's noise (``noise``, :class:`GraphConfig`)."""
    noise = GraphConfig() if noise is None else noise
    n = len(poses)
    if n < 2:
        return poses.copy()
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for k in range(n):
        values.insert(k, as_pose2(poses[k]))
    graph.add(gtsam.PriorFactorPose2(0, as_pose2(poses[0]),
                                     gtsam.noiseModel.Diagonal.Sigmas(ANCHOR_SIGMAS)))
    u = relative(odometry[:-1], odometry[1:])
    sig = noise.odometry_sigmas(u)
    for k in range(1, n):
        graph.add(gtsam.BetweenFactorPose2(k - 1, k, as_pose2(u[k - 1]),
                                           gtsam.noiseModel.Diagonal.Sigmas(sig[k - 1])))
    huber = gtsam.noiseModel.mEstimator.Huber.Create(cfg.huber_k)
    for m in matches:
        robust = gtsam.noiseModel.Robust.Create(
            huber, gtsam.noiseModel.Gaussian.Covariance(m.covariance))
        graph.add(gtsam.BetweenFactorPose2(m.a, m.b, as_pose2(m.delta), robust))
    loop = noise.loop_noise()
    for a, b, delta in closures:
        graph.add(gtsam.BetweenFactorPose2(int(a), int(b), as_pose2(delta), loop))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(cfg.lm_iterations)
    out = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    return np.array([[p.x(), p.y(), p.theta()] for p in (out.atPose2(k) for k in range(n))])


def align_scans(points: Sequence[np.ndarray], intensities: Sequence[np.ndarray | None],
                poses: np.ndarray, odometry: np.ndarray,
                closures: Sequence[tuple[int, int, np.ndarray]],
                cfg: AlignmentConfig, noise: GraphConfig | None = None,
                ) -> tuple[np.ndarray, int]:
    """Steps 1-3: the aligned poses of all scans and how many pairwise matches held."""
    matches = pairwise_matches(points, intensities, poses, cfg)
    return align_globally(poses, odometry, matches, closures, cfg, noise), len(matches)
