"""The sparse pose graph of graph SLAM, optimised incrementally with GTSAM's iSAM2
(Kaess et al. 2012) as in Hess et al. 2016, §V: nodes are the poses of the inserted
scans, edges are ``Pose2`` between-factors -- consecutive local-SLAM matches (and
odometry) with Gaussian noise, loop closures with a robust (Huber) noise model so that a
wrong closure costs linearly rather than quadratically (Hess et al. eq. SPA with the
Huber loss ρ)."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import gtsam
import numpy as np
from pydantic import BaseModel, Field


class GraphConfig(BaseModel):
    """Noise of the edges (standard deviations, m and rad) and iSAM2's settings."""

    local_sigma_m: float = Field(0.02, gt=0, description="consecutive local matches")
    local_sigma_rad: float = Field(0.005, gt=0)
    local_sigma_per_m: float = Field(0.02, ge=0, description="... growing per metre moved")
    odom_sigma_m: float = Field(0.02, gt=0, description="odometry between nodes")
    odom_sigma_per_m: float = Field(0.1, ge=0, description="... growing per metre moved")
    odom_sigma_rad: float = Field(0.01, gt=0)
    odom_sigma_rad_per_rad: float = Field(0.1, ge=0, description="... per radian turned")
    loop_sigma_m: float = Field(0.05, gt=0, description="loop closures")
    loop_sigma_rad: float = Field(0.01, gt=0)
    huber_k: float = Field(0.1, gt=0, description="Huber threshold (whitened units): "
                           "small, so a wrong closure pulls no harder than a 0.1-sigma one")
    relinearize_threshold: float = Field(0.01, gt=0)
    extra_updates: int = Field(3, ge=0, description="iSAM2 sweeps after a loop closure")

    def odometry_sigmas(self, delta: np.ndarray) -> np.ndarray:
        """Sigmas (x, y, theta) of odometry increments ``delta`` ``(..., 3)``."""
        d = np.asarray(delta, dtype=float)
        s = self.odom_sigma_m + self.odom_sigma_per_m * np.hypot(d[..., 0], d[..., 1])
        return np.stack([s, s, self.odom_sigma_rad
                         + self.odom_sigma_rad_per_rad * np.abs(d[..., 2])], axis=-1)

    def loop_sigmas(self, weight: float = 1.0) -> np.ndarray:
        """A loop closure's sigmas (x, y, theta) over ``weight``."""
        return np.array([self.loop_sigma_m, self.loop_sigma_m, self.loop_sigma_rad]) / weight

    def loop_noise(self, weight: float = 1.0) -> gtsam.noiseModel.Base:
        """A loop closure's noise: :meth:`loop_sigmas`, Huber-robust."""
        return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(
            self.huber_k), gtsam.noiseModel.Diagonal.Sigmas(self.loop_sigmas(weight)))


@dataclass
class OdometryCalibration:
    """The motion model's heading sigma, learned from the log itself (the RBPF's eq. 7
    model, :mod:`chizu.numeric.slam.rbpf.odometry`, and graph SLAM's odometry edges and
    local-match prior, :meth:`~chizu.numeric.slam.graph.local_slam.LocalSlam.calibrate_odometry`;
    each feeds it its own residuals: heading changes found by scan matching minus the
    odometry's, each divided by the fixed model's sigma of that change).

    The sigma is the fixed one times the residuals' robust spread (1.4826 x the median
    of their absolute values over the last ``window``: a stretch where the matcher is
    off does not move it), clamped to ``[min_scale, 1]``. It only ever makes the model
    surer than the fixed one, as far as the log shows it may be. Above ``knee`` the
    spread is not taken as it is: it ramps linearly to the fixed sigma at twice the knee
    -- within about ±1° a scan match leaves the heading where it starts, and a prior as
    narrow as that would take the filter's diversity of headings. What the knee and the
    window were chosen on: ``docs/notes/slam-rbpf.md``."""

    window: int
    min_scale: float
    knee: float = 1.0
    min_count: int = 20
    residuals: deque[float] = field(init=False)

    def __post_init__(self) -> None:
        self.residuals = deque(maxlen=self.window)  # the last ``window`` residuals
        self._scale: float | None = None  # scale's value until the next residual

    def add(self, normalised: float) -> None:
        self.residuals.append(abs(normalised))
        self._scale = None

    @property
    def scale(self) -> float:
        if self._scale is None:
            self._scale = self._spread_scale()
        return self._scale

    def _spread_scale(self) -> float:
        if self.window == 0 or len(self.residuals) < self.min_count:
            return 1.0
        spread = 1.4826 * float(np.median(np.asarray(self.residuals)))
        if spread > self.knee:  # linear from (knee, knee) to (2 knee, 1)
            spread = self.knee + (1.0 - self.knee) * (spread - self.knee) / self.knee
        return min(1.0, max(self.min_scale, spread))


#: the first node's prior: it fixes the frame
ANCHOR_SIGMAS = np.array([1e-3, 1e-3, 1e-4])


def as_pose2(p: np.ndarray) -> gtsam.Pose2:
    return gtsam.Pose2(float(p[0]), float(p[1]), float(p[2]))


@dataclass
class PoseGraph:
    """Add nodes and edges in order; :meth:`estimate` is the current optimum."""

    config: GraphConfig = field(default_factory=GraphConfig)
    closures: int = 0

    def __post_init__(self) -> None:
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(self.config.relinearize_threshold)
        params.relinearizeSkip = 1
        self.isam = gtsam.ISAM2(params)
        self._graph = gtsam.NonlinearFactorGraph()
        self._values = gtsam.Values()
        self._poses = np.zeros((0, 3))
        self._dirty = False
        #: every edge as (a, b, delta, covariance, kind), kind 0 odometry, 1 local, 2
        #: loop (a loop's covariance is its Gaussian core; the Huber loss is not stored)
        self.edges: list[tuple[int, int, np.ndarray, np.ndarray, int]] = []

    def __len__(self) -> int:
        return len(self._poses)

    def add_node(self, initial: np.ndarray, prior: bool = False) -> int:
        """A new node with its initial estimate (world frame); the first is anchored."""
        k = len(self._poses)
        self._values.insert(k, as_pose2(initial))
        self._poses = np.vstack([self._poses, initial[None, :]])
        if prior or k == 0:
            noise = gtsam.noiseModel.Diagonal.Sigmas(ANCHOR_SIGMAS)
            self._graph.add(gtsam.PriorFactorPose2(k, as_pose2(initial), noise))
        return k

    def add_between(self, a: int, b: int, delta: np.ndarray, sigmas: np.ndarray,
                    kind: int = 0) -> None:
        """An edge saying node ``b`` is at ``delta`` in node ``a``'s frame."""
        sig = np.asarray(sigmas, dtype=float)
        noise = gtsam.noiseModel.Diagonal.Sigmas(sig)
        self._graph.add(gtsam.BetweenFactorPose2(a, b, as_pose2(delta), noise))
        self.edges.append((a, b, np.array(delta, dtype=float), np.diag(sig**2), kind))

    def add_constraint(self, a: int, b: int, delta: np.ndarray, cov: np.ndarray,
                       kind: int) -> None:
        """An edge of a saved map (``kind`` as :meth:`add_between`'s, 2 a loop: Huber-
        robust, as the closures are) with its full covariance."""
        cov = np.asarray(cov, dtype=float)
        noise: gtsam.noiseModel.Base = gtsam.noiseModel.Gaussian.Covariance(cov)
        if kind == 2:
            noise = gtsam.noiseModel.Robust.Create(
                gtsam.noiseModel.mEstimator.Huber.Create(self.config.huber_k), noise)
        self._graph.add(gtsam.BetweenFactorPose2(a, b, as_pose2(delta), noise))
        self.edges.append((a, b, np.array(delta, dtype=float), cov, kind))
        self._dirty = True

    def add_prior(self, k: int, pose: np.ndarray, sigmas: np.ndarray) -> None:
        """Node ``k`` held near ``pose`` with ``sigmas`` (x, y, theta)."""
        self._graph.add(gtsam.PriorFactorPose2(k, as_pose2(pose), gtsam.noiseModel.Diagonal.Sigmas(
            np.asarray(sigmas, dtype=float))))
        self._dirty = True

    def add_local(self, a: int, b: int, delta: np.ndarray,
                  weak: np.ndarray | None = None) -> None:
        """A local-SLAM edge; ``weak`` (unit (2,), node a's frame) is a direction the
        match could not fix, which gets odometry's sigma instead."""
        c = self.config
        s = c.local_sigma_m + c.local_sigma_per_m * float(np.hypot(delta[0], delta[1]))
        if weak is None:
            self.add_between(a, b, delta, np.array([s, s, c.local_sigma_rad]), kind=1)
            return
        lateral = np.array([-weak[1], weak[0]])
        cov = np.zeros((3, 3))
        cov[:2, :2] = (self.odometry_sigmas(delta)[0]**2 * np.outer(weak, weak)
                       + s**2 * np.outer(lateral, lateral))
        cov[2, 2] = c.local_sigma_rad**2
        noise = gtsam.noiseModel.Gaussian.Covariance(cov)
        self._graph.add(gtsam.BetweenFactorPose2(a, b, as_pose2(delta), noise))
        self.edges.append((a, b, np.array(delta, dtype=float), cov, 1))

    def odometry_sigmas(self, delta: np.ndarray) -> np.ndarray:
        """Sigmas (x, y, theta) of an odometry increment ``delta``."""
        return self.config.odometry_sigmas(delta)

    def add_odometry(self, a: int, b: int, delta: np.ndarray,
                     sigmas: np.ndarray | None = None) -> None:
        """An odometry edge with ``sigmas`` (x, y, theta), by default
        :meth:`odometry_sigmas` (graph SLAM hands its calibrated ones,
        :meth:`~chizu.numeric.slam.graph.GraphSlam.odometry_sigmas`)."""
        self.add_between(a, b, delta, self.odometry_sigmas(delta) if sigmas is None
                         else sigmas)

    def add_loop(self, a: int, b: int, delta: np.ndarray, weight: float = 1.0) -> None:
        self._graph.add(gtsam.BetweenFactorPose2(a, b, as_pose2(delta),
                                                 self.config.loop_noise(weight)))
        sig = self.config.loop_sigmas(weight)
        self.edges.append((a, b, np.array(delta, dtype=float), np.diag(sig**2), 2))
        self.closures += 1
        self._dirty = True

    def update(self) -> None:
        """Hand the new nodes and edges to iSAM2 (and sweep again after closures)."""
        if self._graph.size() == 0 and self._values.size() == 0:
            return
        self.isam.update(self._graph, self._values)
        self._graph = gtsam.NonlinearFactorGraph()
        self._values = gtsam.Values()
        if self._dirty:
            for _ in range(self.config.extra_updates):
                self.isam.update()
            self._refresh()
            self._dirty = False

    def _refresh(self) -> None:
        self._poses = gtsam.utilities.extractPose2(self.isam.calculateEstimate()).reshape(-1, 3)

    def estimate(self) -> np.ndarray:
        """Current optimised poses ``(N, 3)`` (the initial guesses for nodes added since
        the last closure, which iSAM2 has not moved)."""
        return self._poses.copy()

    def pose_of(self, k: int) -> np.ndarray:
        """iSAM2's current estimate of node ``k`` (what :meth:`poses_now` would say of
        it), without solving for the others."""
        self.update()
        p = self.isam.calculateEstimatePose2(k)
        return np.array([p.x(), p.y(), p.theta()])

    def poses_now(self) -> np.ndarray:
        """Optimise fully and return every node's pose."""
        self.update()
        if len(self._poses):
            self._refresh()
        return self._poses.copy()

    def set_initial(self, k: int, pose: np.ndarray) -> None:
        """Keep the Python-side estimate of a node iSAM2 has not yet moved."""
        self._poses[k] = pose
