"""One map from two: resuming a saved map with a new log, and merging two saved maps of
one building made in unrelated frames (as Cartographer joins trajectories, Hess et al.
2016 §V, and slam_toolbox merges and continues its serialized maps).

Both are the same four steps on a first map A and a second run B (a new log mapped by
graph SLAM on its own, or a second saved map):

1. **Where B lies in A** (:func:`frame_transform`): global localization on A
   (:mod:`chizu.numeric.slam.map_localization`, step 2: branch and bound over the whole map and
   every heading, with its uniqueness test) of B's keyframes, each with the returns of
   B's keyframes within ``context_m`` of travel around it placed by B's own poses. Each
   unique fix is a transform from B's frame to A's; the one the most fixes agree with
   (within ``agree_m`` and ``agree_rad``) is taken, and at least ``min_agree`` must.
   Without it the maps share no place that tells where: refused (field ``map``).
2. **B fitted to A** (:func:`fitted_to_map`): one transform is not enough where the two
   runs drifted differently; each of B's keyframes is matched to A as a localized scan is
   (refined on A's likelihood field, then ICP against A's nearest keyframes), and B's
   pose graph (its own constraints) is solved with those matches as Huber-robust priors,
   ``fit_rounds`` times -- each round starts nearer and matches more keyframes.
3. **One alignment** (:func:`~chizu.numeric.slam.map_localization.align_on_map`): B's scans
   (resume: every scan of the new log; merge: B's keyframes) placed by that transform,
   matched to their neighbours, to A's keyframes they overlap and to A's nearest
   keyframes' returns, and solved for at once with A's keyframes bound by A's own pose
   graph (Lu & Milios 1997): B's loops close against A's keyframes where they overlap,
   and where A was off (a map of part of a building, without the loops the rest
   closes) A moves with them.
4. **The merged map** (:func:`merged`): A's keyframes and constraints, B's keyframes at
   their aligned poses with B's own constraints and the matches between A's keyframes
   and B's as loop constraints, and every scan of both runs with its pose in A's frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import gtsam
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from chizu.numeric.errors import InvalidInput
from chizu.numeric.geometry import compose, invert, place, relative, wrap_angle
from chizu.numeric.scan import LaserLog
from chizu.numeric.slam.alignment import AlignmentConfig, PairwiseMatch, match_pair
from chizu.numeric.slam.keyframes import voxel_downsample
from chizu.numeric.slam.map_localization import (
    KeyframeClouds,
    MapLocalizationConfig,
    MapLocalizer,
    PreparedMap,
    align_on_map,
)
from chizu.numeric.slam.pose_graph import as_pose2
from chizu.numeric.slam.saved_map import EDGE_KINDS, Constraints, Laser, SavedMap


class MergeConfig(BaseModel):
    """The steps' parameters (m, rad); one set for every pair of maps."""

    model_config = ConfigDict(extra="forbid")
    context_m: float = Field(3.0, ge=0.0, description="a keyframe is searched for with "
                             "the returns of this much of B's travel around it")
    searches: int = Field(60, ge=1, le=10_000, description="B's keyframes searched for, "
                          "at most (spread evenly)")
    agree_m: float = Field(0.5, gt=0.0, description="two fixes agree on the transform "
                           "within this distance at B's keyframes ...")
    agree_rad: float = Field(0.05, gt=0.0, le=math.pi, description="... and this angle")
    min_agree: int = Field(3, ge=1, description="fixes that must agree")
    fit_rounds: int = Field(3, ge=0, le=20, description="rounds of step 2")
    icp_keyframes: int = Field(4, ge=0, le=50)
    icp_radius_m: float = Field(4.0, gt=0.0)


@dataclass(frozen=True)
class Placement:
    """Where B's frame lies in A's (``transform``: B's origin in A's frame), and from
    how many of the searched keyframes' fixes that agree (``agree`` of ``searched``,
    ``fixes`` unique ones)."""

    transform: np.ndarray
    agree: int
    fixes: int
    searched: int


def _context(kf_xy: list[np.ndarray], kf_pose: np.ndarray, k: int, context_m: float
             ) -> np.ndarray:
    """Keyframe ``k``'s returns with those of the keyframes within ``context_m`` of
    travel before and after it, in ``k``'s frame (placed by B's own poses)."""
    step = np.r_[0.0, np.hypot(*np.diff(kf_pose[:, :2], axis=0).T)]
    travel = np.cumsum(step)
    near = np.flatnonzero(np.abs(travel - travel[k]) <= context_m)
    return np.vstack([place(kf_xy[j], relative(kf_pose[k], kf_pose[j])) for j in near])


def frame_transform(a: PreparedMap, kf_xy: list[np.ndarray], kf_pose: np.ndarray,
                    config: MergeConfig) -> Placement:
    """Step 1: B's frame in A's, from B's keyframes (robot-frame returns ``kf_xy``, poses
    ``kf_pose`` in B's frame). Raises :class:`InvalidInput` (field ``map``) when too few
    fixes agree."""
    have = np.flatnonzero([len(x) for x in kf_xy])  # a lifelong run forgets some
    n = len(have)
    picks = have[np.unique(np.linspace(0, n - 1, min(n, config.searches)).round().astype(int))
                 ] if n else np.zeros(0, dtype=int)
    found: list[np.ndarray] = []
    for k in picks:
        m = a.globally.fix(_context(kf_xy, kf_pose, int(k), config.context_m))
        if m is not None:
            found.append(compose(np.asarray(m.pose), invert(kf_pose[k])))
    best, support = None, 0
    for t in found:
        agree = sum(_agrees(t, u, kf_pose, config) for u in found)
        if agree > support:
            best, support = t, agree
    if best is None or support < config.min_agree:
        raise InvalidInput(
            f"the maps share no place that says where one lies in the other: of "
            f"{len(picks)} places searched for, {len(found)} were found uniquely and at most "
            f"{support} agree ({config.min_agree} needed)", field="map")
    # the agreeing fixes' mean transform (headings averaged on the circle)
    ts = np.array([t for t in found if _agrees(best, t, kf_pose, config)])
    mean = np.array([ts[:, 0].mean(), ts[:, 1].mean(),
                     math.atan2(np.sin(ts[:, 2]).mean(), np.cos(ts[:, 2]).mean())])
    return Placement(mean, support, len(found), len(picks))


def _agrees(t: np.ndarray, u: np.ndarray, kf_pose: np.ndarray, cfg: MergeConfig) -> bool:
    """Whether transforms ``t`` and ``u`` put B's keyframes within ``agree_m`` of each
    other (at the farthest) and turn them by the same heading within ``agree_rad``."""
    if abs(float(wrap_angle(t[2] - u[2]))) > cfg.agree_rad:
        return False
    d = compose(t, kf_pose)[:, :2] - compose(u, kf_pose)[:, :2]
    return bool(np.hypot(*d.T).max() <= cfg.agree_m)


def fitted_to_map(a: PreparedMap, kf_xy: list[np.ndarray], start: np.ndarray,
                  constraints: Constraints, config: MergeConfig) -> np.ndarray:
    """Step 2: B's keyframe poses in A's frame, from ``start`` (B's keyframes placed by
    the transform of step 1), B's pose graph (``constraints``) and each keyframe's
    match to A."""
    loc = MapLocalizer(a.saved, a.config, a)
    clouds = KeyframeClouds(a.saved, config.icp_keyframes, config.icp_radius_m)
    align = AlignmentConfig()
    pts = [voxel_downsample(xy, None, 0.05)[0] for xy in kf_xy]
    poses = start.copy()
    for _ in range(config.fit_rounds):
        priors = []
        for k, xy in enumerate(kf_xy):
            pose, score, share = loc.fit(xy, poses[k])
            if score < loc.config.lost_score or share < loc.config.min_on_map:
                continue
            ref = clouds.around(pose)
            found = None if ref is None or len(pts[k]) < 10 else match_pair(
                ref, pts[k], None, pose, align)
            if found is not None:
                priors.append((k, found[0], found[1]))
        poses = _solve(poses, constraints, priors, align.huber_k)
    return poses


def _solve(poses: np.ndarray, c: Constraints, priors: list[tuple[int, np.ndarray, np.ndarray]],
           huber_k: float) -> np.ndarray:
    """B's pose graph with the priors (Huber-robust, as are its loop constraints),
    solved by Levenberg-Marquardt; a loose prior on the first node keeps it determined
    where nothing matched."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for k, p in enumerate(poses):
        values.insert(k, as_pose2(p))
    graph.add(gtsam.PriorFactorPose2(0, as_pose2(poses[0]),
                                     gtsam.noiseModel.Diagonal.Sigmas(np.array([10.0, 10.0, 1.0]))))
    huber = gtsam.noiseModel.mEstimator.Huber.Create(huber_k)
    loop = EDGE_KINDS.index("loop")
    for a, b, d, cov, kind in zip(c.a, c.b, c.delta, c.cov, c.kind, strict=True):
        noise: gtsam.noiseModel.Base = gtsam.noiseModel.Gaussian.Covariance(
            np.asarray(cov, dtype=float))
        if kind == loop:
            noise = gtsam.noiseModel.Robust.Create(huber, noise)
        graph.add(gtsam.BetweenFactorPose2(int(a), int(b), as_pose2(d), noise))
    for k, pose, cov in priors:
        graph.add(gtsam.PriorFactorPose2(int(k), as_pose2(pose), gtsam.noiseModel.Robust.Create(
            huber, gtsam.noiseModel.Gaussian.Covariance(cov))))
    out = gtsam.LevenbergMarquardtOptimizer(graph, values,
                                            gtsam.LevenbergMarquardtParams()).optimize()
    return np.array([[p.x(), p.y(), p.theta()] for p in (out.atPose2(k)
                                                         for k in range(len(poses)))])


def _placed(a: SavedMap, b: SavedMap, laser: Laser, cfg: MergeConfig,
            localization: MapLocalizationConfig | None) -> tuple[Placement, np.ndarray]:
    """Steps 1-2 for B (whose scans a ``laser`` took): where it lies in A, and its
    keyframes' poses fitted to A. Another laser than A's is refused (field ``map``)."""
    why = a.laser.compatible(laser)
    if why is not None:
        raise InvalidInput(why, field="map")
    prepared = PreparedMap.of(a, localization or MapLocalizationConfig())
    placed = frame_transform(prepared, b.kf_xy, b.kf_pose, cfg)
    return placed, fitted_to_map(prepared, b.kf_xy, compose(placed.transform, b.kf_pose),
                                 b.constraints, cfg)


def resume(a: SavedMap, b: SavedMap, log: LaserLog,
           config: MergeConfig | None = None,
           localization: MapLocalizationConfig | None = None) -> tuple[SavedMap, np.ndarray]:
    """A saved map ``a`` continued with ``log``, which graph SLAM mapped on its own into
    ``b`` (its scans' poses in the log's frame): the merged map, and the log's scans'
    poses in ``a``'s frame."""
    cfg = config or MergeConfig()
    place_b, kf = _placed(a, b, Laser.of(log), cfg, localization)
    pts = [voxel_downsample(s.points()[0], None, 0.05)[0] for s in log.scans]
    poses, matches, a_kf = align_on_map(a, pts, log.odometry, _follow(b, kf),
                                        AlignmentConfig(), cfg.icp_keyframes,
                                        cfg.icp_radius_m, move_map=True)
    return merged(a, a_kf, b, poses, matches, place_b), poses


def merge(a: SavedMap, b: SavedMap, config: MergeConfig | None = None,
          localization: MapLocalizationConfig | None = None) -> tuple[SavedMap, Placement]:
    """Two saved maps of one building in unrelated frames as one, in ``a``'s frame."""
    cfg = config or MergeConfig()
    place_b, kf = _placed(a, b, b.laser, cfg, localization)
    kf_poses, matches, a_kf = align_on_map(a, b.kf_xy, b.kf_odom, kf, AlignmentConfig(),
                                           cfg.icp_keyframes, cfg.icp_radius_m,
                                           move_map=True)
    scan_poses = _follow(b, kf_poses)
    kf_matches = [PairwiseMatch(m.a, int(b.kf_scan[m.b]), m.delta, m.covariance)
                  for m in matches]
    return merged(a, a_kf, b, scan_poses, kf_matches, place_b), place_b


def _follow(b: SavedMap, kf_poses: np.ndarray) -> np.ndarray:
    """Every scan of ``b`` moved with the keyframe it follows, to ``kf_poses``."""
    k = np.clip(np.searchsorted(b.kf_scan, np.arange(len(b.poses)), side="right") - 1, 0,
                len(b) - 1)
    return np.asarray(compose(kf_poses[k], relative(b.kf_pose[k], b.poses)))


def runs_of(m: SavedMap) -> list[str]:
    """The runs a map holds, by their sources (a map of one run: its own)."""
    runs = m.meta.get("runs")
    if isinstance(runs, list) and all(isinstance(r, str) for r in runs):
        return list(runs)
    return [str(m.meta.get("source", "a map"))]


def merged(a: SavedMap, a_kf: np.ndarray, b: SavedMap, b_poses: np.ndarray,
           matches: list[PairwiseMatch], placement: Placement) -> SavedMap:
    """Step 4: ``a``'s keyframes at ``a_kf`` (its scans moved with them) and ``b``'s at
    the poses its scans now have (``b_poses``, one per scan of ``b``), both runs'
    constraints, and the ``matches`` between ``a``'s keyframes and ``b``'s scans that
    are keyframes as loop constraints."""
    held = len(a)
    kf_of_scan = {int(s): held + i for i, s in enumerate(b.kf_scan)}
    cross = [(m.a, kf_of_scan[m.b], m.delta, m.covariance) for m in matches
             if m.b in kf_of_scan]
    loop = EDGE_KINDS.index("loop")
    ca, cb = a.constraints, b.constraints
    cons = Constraints(
        np.concatenate([ca.a, cb.a + held, [c[0] for c in cross]]).astype(np.int64),
        np.concatenate([ca.b, cb.b + held, [c[1] for c in cross]]).astype(np.int64),
        np.vstack([ca.delta, cb.delta, *[c[2][None] for c in cross]]).reshape(-1, 3),
        np.vstack([ca.cov, cb.cov, *[c[3][None] for c in cross]]).reshape(-1, 3, 3),
        np.concatenate([ca.kind, cb.kind, np.full(len(cross), loop)]).astype(np.int8))
    n_a = len(a.times)
    inten = (a.kf_intensity + b.kf_intensity
             if a.kf_intensity is not None and b.kf_intensity is not None else None)
    meta = {**a.meta, "runs": runs_of(a) + runs_of(b),
            "placement": {"transform": [round(float(v), 6) for v in placement.transform],
                          "agree": placement.agree, "fixes": placement.fixes,
                          "searched": placement.searched}}
    return SavedMap(
        laser=a.laser, resolution_m=a.resolution_m,
        kf_scan=np.concatenate([a.kf_scan, b.kf_scan + n_a]).astype(np.int64),
        kf_time=np.concatenate([a.kf_time, b.kf_time]),
        kf_pose=np.vstack([a_kf, b_poses[b.kf_scan]]),
        kf_odom=np.vstack([a.kf_odom, b.kf_odom]),
        kf_xy=a.kf_xy + b.kf_xy, kf_intensity=inten, kf_misses=a.kf_misses + b.kf_misses,
        times=np.concatenate([a.times, b.times]),
        poses=np.vstack([_follow(a, a_kf), b_poses]),
        constraints=cons, meta=meta)
