"""Graph SLAM with loop closure, beyond the paper: Hess, Kohler, Rapp, Andor, "Real-Time
Loop Closure in 2D LIDAR SLAM" (ICRA 2016, Cartographer) -- the estimator that runs the
steps of :mod:`~chizu.numeric.slam.graph.local_slam`, :mod:`~chizu.numeric.slam.graph.submaps` and
:mod:`~chizu.numeric.slam.graph.loop_closure` scan by scan.

The nodes and edges (local matches, odometry, closures) form a pose graph optimised
incrementally by iSAM2 (:mod:`chizu.numeric.slam.pose_graph`); after a closure the whole
trajectory moves. Submaps keep their grids in the local-SLAM frame; a submap's place in
the world is its anchor node's optimised pose. The end of a run
(:meth:`~chizu.numeric.slam.alignment.AlignedOutputs.finish`) refines every scan's pose by the
global scan alignment both estimators share (:mod:`chizu.numeric.slam.alignment`).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from chizu.numeric.geometry import compose, place, relative
from chizu.numeric.scan import Scan
from chizu.numeric.slam.alignment import AlignedOutputs, AlignmentConfig, ScanStore
from chizu.numeric.slam.graph.config import GraphSlamConfig
from chizu.numeric.slam.graph.local_slam import LocalSlam, rotate_xy
from chizu.numeric.slam.graph.loop_closure import LoopClosing, LoopClosure
from chizu.numeric.slam.graph.submaps import Submap, Submaps
from chizu.numeric.slam.keyframes import Keyframes, moved, voxel_downsample
from chizu.numeric.slam.pose_graph import GraphConfig, OdometryCalibration
from chizu.numeric.slam.saved_map import Constraints


@dataclass
class GraphSlam(Submaps, LocalSlam, LoopClosing, AlignedOutputs):
    """Feed scans with :meth:`process`; read :meth:`trajectory` and :meth:`map_poses`."""

    config: GraphSlamConfig = field(default_factory=GraphSlamConfig)
    seed: int = 0
    submaps: list[Submap] = field(default_factory=list)
    closures: list[LoopClosure] = field(default_factory=list)
    searches: int = 0
    degeneracies: list[float] = field(default_factory=list)
    # when a list: one (node, submap, outcome, score) per loop search -- why a loop did
    # or did not close. Outcome: "none" (nothing above loop.min_score), "refined",
    # "degenerate", "aliased" (failed that test), "pending" (awaits confirmation),
    # "inconsistent" (contradicts the pending one), "accepted" (with the pending match
    # it confirms, if any); score: the refined match's
    loop_log: list[tuple[int, int, str, float]] | None = None

    def __post_init__(self) -> None:
        cfg = self.config
        self.keyframes = Keyframes(cfg.map)
        self.start_loops()
        self.node_odom: list[np.ndarray] = []
        self.node_time: list[float] = []
        self._node_scan: list[int] = []
        self._scan_node: list[int] = []
        self._scan_delta: list[np.ndarray] = []
        self.times: list[float] = []
        # every scan's points (down-sampled), intensities and odometry, for finish()
        self.scans = ScanStore()
        self._redundant: deque[int] = deque()  # nodes to forget on a long run (forget)
        self._prev: tuple[np.ndarray, np.ndarray | None] | None = None  # for alpha > 0
        self.rng = np.random.default_rng(self.seed)
        # per recent node: did the search beat the odometry by odometry_score_margin?
        self._search_won: deque[bool] = deque(maxlen=self.config.odometry.rate_nodes)
        self.odometry = OdometryCalibration(cfg.odometry.window, cfg.odometry.min_scale,
                                            cfg.odometry.knee)
        self._free_heading: float | None = None  # the last node's match without odometry
        # per node: that heading (nan: none), the odometry's, the model's summed variance
        self._heading_log: deque[tuple[float, float, float]] = deque(
            maxlen=cfg.odometry.lag + 1)

    def process(self, scan: Scan) -> None:
        """One scan: a node (local SLAM, the pose graph's edges, every ``every``-th node
        a loop search) once the robot has moved far enough, else tracked between nodes."""
        xy, inten = scan.points()
        self.times.append(scan.t)
        cfg = self.config
        self.scans.aligned = None  # a new scan: the online estimate is current again
        pts, pin = voxel_downsample(xy, inten, cfg.local.voxel_m)  # a node's, and finish()'s
        if cfg.alignment is not None:
            self.scans.add(pts, pin, scan.odom)
        self._forget_queued()
        if not self.local:
            self._add_node(scan, scan.odom.copy(), scan.odom.copy(), xy, inten, pts)
            return
        last = len(self.local) - 1
        u = relative(self.node_odom[last], scan.odom)
        if (len(xy) < 8 or not (moved(self.node_odom[last], scan.odom, cfg.local.node_linear_m,
                                      cfg.local.node_angular_rad)
                                or scan.t - self.node_time[last] >= cfg.local.node_time_s)):
            self._scan_node.append(last)
            self._scan_delta.append(self.track(xy, u) if len(xy) >= 8 else u)
            return
        predicted = compose(self.local[last], u)
        pose, score, weak = predicted, 0.0, None
        if cfg.local.matching:
            pose, score, weak = self.match_local(xy, predicted, u)
        if score < cfg.local.min_score:
            pose, weak = predicted, None
        elif cfg.alpha > 0:
            pose = self.intensity_step(pose, xy, inten)
        delta = relative(self.local[last], pose)
        node = self._add_node(scan, pose, compose(self._global[last], delta), xy, inten, pts)
        if score >= cfg.local.min_score:  # else odometry alone links the nodes
            self.graph.add_local(last, node, delta, None if weak is None
                                 else rotate_xy(weak, -self.local[last][2]))
        self.graph.add_odometry(last, node, u, self.odometry_sigmas(u))
        self.calibrate_odometry(u, self._free_heading if cfg.local.matching else None)
        if (cfg.loop.every is not None and node % cfg.loop.every == 0
                and self.search_loops(node, pts)):
            self.graph.update()
            est = self.graph.estimate()
            self._global = est
        else:
            self.graph.update()

    def _add_node(self, scan: Scan, local: np.ndarray, world: np.ndarray, xy: np.ndarray,
                  inten: np.ndarray | None, pts: np.ndarray) -> int:
        """A new node at ``local`` / ``world``; ``pts`` its scan down-sampled for matching."""
        node = len(self.local)
        self._travel.append(0.0 if not self.local else self._travel[-1] + float(
            np.hypot(*(local[:2] - self.local[-1][:2]))))
        self.local.append(local)
        self.node_odom.append(scan.odom.copy())
        self.node_time.append(scan.t)
        self._node_scan.append(len(self.times) - 1)
        self._scan_node.append(node)
        self._scan_delta.append(np.zeros(3))
        self.graph.add_node(world)
        self._global = np.vstack([self._global, world[None, :]])
        misses = scan.misses()
        self.keyframes.add(len(self.times) - 1, xy, inten, misses)
        self.insert(node, xy, misses)
        if self.config.alpha > 0:
            self._prev = (place(xy, local), inten)
        return node

    def forget(self, nodes: list[int]) -> None:
        """``nodes`` are held only by trimmed submaps: the map already had their place.
        Once the run is past ``forget_after_scans`` scans their returns are forgotten
        and they leave the pose graph (:meth:`_forget_queued`), those queued before
        first. Their scans stay in the trajectory."""
        self._redundant.extend(nodes)
        self._forget_queued()

    def _forget_queued(self) -> None:
        """On a run past ``forget_after_scans`` scans, forget the queued nodes' returns:
        their keyframes' points (the keyframes stay, empty) and their scans' (from the
        node's scan to the next node's) for the end-of-run alignment; and take the nodes
        out of the pose graph (:meth:`~chizu.numeric.slam.pose_graph.PoseGraph.remove`:
        their poses then ride with the kept node before them)."""
        if len(self.times) <= self.config.submaps.forget_after_scans or not self._redundant:
            return
        nodes = list(self._redundant)
        self._redundant.clear()
        for n in nodes:
            self.keyframes.forget(n)
            if self.config.alignment is not None and n + 1 < len(self._node_scan):
                self.scans.forget(self._node_scan[n], self._node_scan[n + 1])
        self.graph.remove(nodes)

    # -- outputs ------------------------------------------------------------------------
    def optimise(self) -> np.ndarray:
        """iSAM2's current estimate of every node ``(N, 3)``. Reading it changes nothing:
        the loop-closure search keeps its own estimate, so a run fed the same scans
        ends the same whether or not (and how often) it was read in between."""
        return self.graph.poses_now()

    def loop_closures(self) -> list[tuple[int, int, float]]:
        """The accepted closures as ``(scan of the submap's anchor, scan matched,
        score)``, scan indices counted from 0 in the order the scans came."""
        return [(self._node_scan[c.anchor], self._node_scan[c.node], c.score)
                for c in self.closures]

    def constraints(self) -> Constraints:
        """The pose graph's edges between nodes (= keyframes), for a saved map."""
        e = self.graph.edges
        if not e:
            return Constraints.empty()
        return Constraints(np.array([x[0] for x in e], dtype=np.int64),
                           np.array([x[1] for x in e], dtype=np.int64),
                           np.array([x[2] for x in e]), np.array([x[3] for x in e]),
                           np.array([x[4] for x in e], dtype=np.int8))

    def local_pose(self) -> np.ndarray:
        """The latest scan's pose in the local-SLAM frame: local SLAM's estimate alone,
        which no loop closure moves (zero before the first scan)."""
        if not self._scan_node:
            return np.zeros(3)
        return compose(self.local[self._scan_node[-1]], self._scan_delta[-1])

    def _online_pose(self) -> np.ndarray:
        """The latest scan's pose on iSAM2's current estimate of its node."""
        if not self._scan_node:
            return np.zeros(3)
        return compose(self.graph.pose_of(self._scan_node[-1]), self._scan_delta[-1])

    def _online_trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        g = self.optimise()
        poses = compose(g[np.array(self._scan_node)], np.array(self._scan_delta))
        return np.array(self.times), np.asarray(poses).reshape(-1, 3)

    def _online_map_poses(self) -> np.ndarray:
        """Optimised poses ``(K, 3)`` of the nodes (the keyframes of the map)."""
        return self.optimise().copy()

    def _map_scans(self) -> np.ndarray:
        return np.array(self._node_scan)

    def _alignment(self) -> tuple[AlignmentConfig | None, float]:
        return self.config.alignment, self.config.alpha

    def _alignment_inputs(self, poses: np.ndarray,
                          ) -> tuple[np.ndarray, list[tuple[int, int, np.ndarray]],
                                     GraphConfig]:
        """The log's odometry, the online loop closures (between the scans of their
        nodes) and the online pose graph's noise."""
        closures = [(self._node_scan[c.anchor], self._node_scan[c.node], c.delta)
                    for c in self.closures]
        return np.array(self.scans.odom), closures, self.config.graph
