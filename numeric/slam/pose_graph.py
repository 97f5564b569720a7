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

from chizu.numeric.geometry import compose, relative


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
    compact_nodes: int = Field(500, ge=1, description="nodes taken out (PoseGraph.remove) "
                               "before iSAM2 is rebuilt without them")

    def odometry_sigmas(self, delta: np.ndarray) -> np.ndarray:
        """Sigmas (x, y, theta) of odometry increments ``delta`` ``(..., 3)``."""
        d = np.asarray(delta, dtype=float)
        s = self.odom_sigma_m + self.odom_sigma_per_m * np.hypot(d[..., 0], d[..., 1])
        return np.stack([s, s, self.odom_sigma_rad
                         + self.odom_sigma_rad_per_rad * np.abs(d[..., 2])], axis=-1)

    def local_sigmas(self, delta: np.ndarray) -> np.ndarray:
        """Sigmas (x, y, theta) of a local-SLAM edge over relative pose ``delta``."""
        s = self.local_sigma_m + self.local_sigma_per_m * float(np.hypot(delta[0], delta[1]))
        return np.array([s, s, self.local_sigma_rad])

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


def _prior_factor(k: int, pose: np.ndarray, sigmas: np.ndarray) -> gtsam.PriorFactorPose2:
    return gtsam.PriorFactorPose2(k, as_pose2(pose), gtsam.noiseModel.Diagonal.Sigmas(sigmas))


@dataclass
class PoseGraph:
    """Add nodes and edges in order; :meth:`estimate` is the current optimum.

    A long run takes out nodes whose place the map already holds (:meth:`remove`, as
    Cartographer's trimmer deletes the nodes of trimmed submaps): once ``compact_nodes``
    are queued, iSAM2 is rebuilt from the edges between the nodes that stay and the
    removed nodes' marginal (:meth:`_compact`). A removed node then rides with the kept
    node before it, at the relative pose it had when it was taken out.
    """

    config: GraphConfig = field(default_factory=GraphConfig)
    closures: int = 0

    def __post_init__(self) -> None:
        self.isam = gtsam.ISAM2(self._params())
        self._graph = gtsam.NonlinearFactorGraph()
        self._values = gtsam.Values()
        self._poses = np.zeros((0, 3))
        self._dirty = False
        #: the prior factors, as (node, pose, sigmas), for a rebuild
        self._priors: list[tuple[int, np.ndarray, np.ndarray]] = []
        # per node: taken out of iSAM2 (remove), and then the kept node it rides with
        # (-1 while kept) at which relative pose
        self._removed = np.zeros(0, dtype=np.bool_)
        self._ref = np.zeros(0, dtype=np.int64)
        self._rel = np.zeros((0, 3))
        self._leaving: list[int] = []  # queued by remove, still in iSAM2
        #: what removed nodes said of the kept ones (_compact)
        self._marginals: list[gtsam.NonlinearFactor] = []
        #: every edge as (a, b, delta, covariance, kind), kind 0 odometry, 1 local, 2
        #: loop (a loop's covariance is its Gaussian core; the Huber loss is not stored)
        self.edges: list[tuple[int, int, np.ndarray, np.ndarray, int]] = []

    def _params(self) -> gtsam.ISAM2Params:
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(self.config.relinearize_threshold)
        params.relinearizeSkip = 1
        return params

    def __len__(self) -> int:
        return len(self._poses)

    def held(self) -> int:
        """The nodes iSAM2 holds: all but those taken out (:meth:`remove`)."""
        return int(len(self._poses) - self._removed.sum())

    def add_node(self, initial: np.ndarray, prior: bool = False) -> int:
        """A new node with its initial estimate (world frame); the first is anchored."""
        k = len(self._poses)
        self._values.insert(k, as_pose2(initial))
        self._poses = np.vstack([self._poses, initial[None, :]])
        self._removed = np.append(self._removed, False)
        self._ref = np.append(self._ref, -1)
        self._rel = np.vstack([self._rel, np.zeros((1, 3))])
        if prior or k == 0:
            self._add_prior(k, initial, ANCHOR_SIGMAS)
        return k

    def _add_prior(self, k: int, pose: np.ndarray, sigmas: np.ndarray) -> None:
        prior = (k, np.array(pose, dtype=float), np.asarray(sigmas, dtype=float))
        self._graph.add(_prior_factor(*prior))
        self._priors.append(prior)

    def _factor(self, a: int, b: int, delta: np.ndarray, cov: np.ndarray,
                kind: int) -> gtsam.BetweenFactorPose2:
        """The between-factor of an edge: Gaussian with ``cov``, Huber-robust for a loop."""
        noise: gtsam.noiseModel.Base = gtsam.noiseModel.Gaussian.Covariance(cov)
        if kind == 2:
            noise = gtsam.noiseModel.Robust.Create(
                gtsam.noiseModel.mEstimator.Huber.Create(self.config.huber_k), noise)
        return gtsam.BetweenFactorPose2(a, b, as_pose2(delta), noise)

    def _edge(self, a: int, b: int, delta: np.ndarray, cov: np.ndarray, kind: int) -> None:
        """Add an edge (stored for saved maps and rebuilds) and its factor."""
        assert not (self._removed[a] or self._removed[b]), "an edge to a removed node"
        delta, cov = np.array(delta, dtype=float), np.asarray(cov, dtype=float)
        self._graph.add(self._factor(a, b, delta, cov, kind))
        self.edges.append((a, b, delta, cov, kind))

    def add_between(self, a: int, b: int, delta: np.ndarray, sigmas: np.ndarray,
                    kind: int = 0) -> None:
        """An edge saying node ``b`` is at ``delta`` in node ``a``'s frame."""
        self._edge(a, b, delta, np.diag(np.asarray(sigmas, dtype=float)**2), kind)

    def add_constraint(self, a: int, b: int, delta: np.ndarray, cov: np.ndarray,
                       kind: int) -> None:
        """An edge of a saved map (``kind`` as :meth:`add_between`'s, 2 a loop: Huber-
        robust, as the closures are) with its full covariance."""
        self._edge(a, b, delta, cov, kind)
        self._dirty = True

    def add_prior(self, k: int, pose: np.ndarray, sigmas: np.ndarray) -> None:
        """Node ``k`` held near ``pose`` with ``sigmas`` (x, y, theta)."""
        self._add_prior(k, pose, sigmas)
        self._dirty = True

    def add_local(self, a: int, b: int, delta: np.ndarray,
                  weak: np.ndarray | None = None) -> None:
        """A local-SLAM edge; ``weak`` (unit (2,), node a's frame) is a direction the
        match could not fix, which gets odometry's sigma instead."""
        c = self.config
        sig = c.local_sigmas(delta)
        if weak is None:
            self.add_between(a, b, delta, sig, kind=1)
            return
        s = sig[0]
        lateral = np.array([-weak[1], weak[0]])
        cov = np.zeros((3, 3))
        cov[:2, :2] = (self.odometry_sigmas(delta)[0]**2 * np.outer(weak, weak)
                       + s**2 * np.outer(lateral, lateral))
        cov[2, 2] = c.local_sigma_rad**2
        self._edge(a, b, delta, cov, 1)

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
        self._edge(a, b, delta, np.diag(self.config.loop_sigmas(weight)**2), 2)
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
        if len(self._leaving) >= self.config.compact_nodes:
            self._compact()

    def _refresh(self) -> None:
        est = gtsam.utilities.extractPose2(self.isam.calculateEstimate()).reshape(-1, 3)
        if not self._removed.any():
            self._poses = est
            return
        # iSAM2 holds the kept nodes, in key order; the removed ride with theirs
        self._poses[~self._removed] = est
        gone = np.flatnonzero(self._removed)
        self._poses[gone] = compose(self._poses[self._ref[gone]], self._rel[gone])

    def remove(self, nodes: list[int]) -> None:
        """Take ``nodes`` out of the graph (their poses stay readable): queued, and once
        ``compact_nodes`` are, the next :meth:`update` rebuilds iSAM2 without them
        (:meth:`_compact`; not here: the newest node may not have its edges yet)."""
        self._leaving.extend(int(n) for n in nodes if not self._removed[n])

    def _compact(self) -> None:
        """Rebuild iSAM2 without the queued nodes, marginalised out: the factors that
        touch them (their edges, and earlier marginals) linearised at the current
        estimate and the nodes eliminated, which leaves one Gaussian factor on the kept
        nodes they were tied to (their neighbours in the chain and the anchors of their
        loop closures) holding what the removed nodes said of them -- the exact
        marginal at that linearisation point, as GTSAM's fixed-lag smoothers keep it.
        Called by :meth:`update` with nothing pending."""
        self._refresh()
        est = self._poses
        leaving = np.zeros(len(est), dtype=np.bool_)
        leaving[self._leaving] = True
        self._leaving = []
        kept = np.flatnonzero(~(self._removed | leaving))
        if not len(kept):
            return

        def touching(keys: gtsam.KeyVector) -> bool:
            return any(leaving[k] for k in keys)

        out = gtsam.NonlinearFactorGraph()
        for a, b, d, c, kind in self.edges:
            if leaving[a] or leaving[b]:
                out.add(self._factor(a, b, d, c, kind))
        for prior in self._priors:
            if leaving[prior[0]]:
                out.add(_prior_factor(*prior))
        for f in self._marginals:
            if touching(f.keys()):
                out.add(f)
        keys = sorted({int(k) for i in range(out.size()) for k in out.at(i).keys()})
        point = gtsam.Values()
        for k in keys:
            point.insert(k, as_pose2(est[k]))
        order = gtsam.Ordering()
        for k in keys:
            if leaving[k]:
                order.push_back(k)
        _, rest = out.linearize(point).eliminatePartialMultifrontal(order)
        blanket = gtsam.Values()
        for k in keys:
            if not leaving[k]:
                blanket.insert(k, as_pose2(est[k]))
        marginal = gtsam.LinearContainerFactor.ConvertLinearGraph(rest, blanket)
        self._marginals = [f for f in self._marginals if not touching(f.keys())]
        self._marginals += [marginal.at(i) for i in range(marginal.size())]
        # the removed nodes (now and before) ride with the nearest kept node before them
        # (after them, before the first): a run of removed neighbours in time rides with
        # one node and keeps its shape, where the kept node nearest each in space (on
        # another lap) moves each its own way
        self._removed |= leaving
        gone = np.flatnonzero(self._removed)
        ref = kept[np.clip(np.searchsorted(kept, gone) - 1, 0, len(kept) - 1)]
        self._ref[gone] = ref
        self._rel[gone] = relative(est[ref], est[gone])
        # the graph of the kept nodes
        self.edges = [e for e in self.edges if not (leaving[e[0]] or leaving[e[1]])]
        self._priors = [p for p in self._priors if not leaving[p[0]]]
        graph = gtsam.NonlinearFactorGraph()
        for a, b, d, c, kind in self.edges:
            graph.add(self._factor(a, b, d, c, kind))
        for prior in self._priors:
            graph.add(_prior_factor(*prior))
        for f in self._marginals:
            graph.add(f)
        values = gtsam.Values()
        for n in kept:
            values.insert(int(n), as_pose2(est[n]))
        self.isam = gtsam.ISAM2(self._params())
        self.isam.update(graph, values)
        for _ in range(self.config.extra_updates):
            self.isam.update()
        self._refresh()

    def estimate(self) -> np.ndarray:
        """Current optimised poses ``(N, 3)`` (the initial guesses for nodes added since
        the last closure, which iSAM2 has not moved)."""
        return self._poses.copy()

    def pose_of(self, k: int) -> np.ndarray:
        """iSAM2's current estimate of node ``k`` (what :meth:`poses_now` would say of
        it), without solving for the others."""
        self.update()
        if self._removed[k]:
            return compose(self.pose_of(int(self._ref[k])), self._rel[k])
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
