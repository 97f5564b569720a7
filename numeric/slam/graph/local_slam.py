"""Local SLAM (Hess et al. 2016, §IV): a scan becomes a node once the robot has moved
``node_linear_m`` / ``node_angular_rad`` (or ``node_time_s`` passed) since the last node.
The node is placed by matching the scan against the older of the two active submaps --
first a correlative search of a small window around the odometry prediction, then
Gauss-Newton refinement on the interpolated probability grid; when the search's best
lies on its window's edge it is repeated in a ``escalation`` times wider window and
kept if it fits clearly better. The refinement is held near the odometry by the motion
model's own sigmas (learned from the log, :meth:`LocalSlam.calibrate_odometry`) unless
the scan fits clearly better where the search alone puts it. Scans between nodes are
matched the same way in a smaller window but inserted nowhere (:meth:`LocalSlam.track`).
The paper's intensity term (Hara et al. eq. 1) enters as an optional extra step:
Intensity-ICP against the previous node's scan inside eq. 5's box.
"""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING

import numpy as np

from chizu.numeric.geometry import compose, relative, wrap_angle
from chizu.numeric.slam.gated import inside_gate
from chizu.numeric.slam.graph.config import GraphSlamConfig
from chizu.numeric.slam.graph.submaps import Submap
from chizu.numeric.slam.keyframes import voxel_downsample
from chizu.numeric.slam.matching.correlative import correlative_search, refine, window_cells
from chizu.numeric.slam.matching.intensity_icp import Reference, intensity_icp
from chizu.numeric.slam.pose_graph import OdometryCalibration, PoseGraph


def rotate_xy(v: np.ndarray, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


class LocalSlam:
    """The local-SLAM steps of :class:`~chizu.numeric.slam.graph.slam.GraphSlam`."""

    config: GraphSlamConfig
    submaps: list[Submap]
    graph: PoseGraph
    local: list[np.ndarray]
    node_odom: list[np.ndarray]
    odometry: OdometryCalibration
    _search_won: deque[bool]
    _heading_log: deque[tuple[float, float, float]]
    _free_heading: float | None
    _prev: tuple[np.ndarray, np.ndarray | None] | None

    if TYPE_CHECKING:
        def active(self) -> list[Submap]: ...

    def match_local(self, xy: np.ndarray, predicted: np.ndarray,
                    u: np.ndarray | None = None, record: bool = True,
                    window: tuple[float, float] | None = None,
                    ) -> tuple[np.ndarray, float, np.ndarray | None]:
        """Scan-to-submap matching: correlative search, then Gauss-Newton refinement
        (Hess et al. §IV-C) against the older active submap. Returns the pose, its
        score and the direction the match could not fix (``None`` when it fixed both).
        ``record``: the outcome counts towards :meth:`search_overrides_odometry`'s
        statistics (nodes only); ``window``: the search's (linear m, angular rad)
        window instead of the local one."""
        cfg = self.config
        grid = self.active()[0].grid
        pts, _ = voxel_downsample(xy, None, cfg.local.voxel_m)
        lin, ang = window or (cfg.local.linear_window_m, cfg.local.angular_window_rad)
        start, score = correlative_search(grid, pts, predicted, lin, ang,
                                          cfg.local.translation_cost,
                                          cfg.local.rotation_cost)
        w = window_cells(lin, grid.resolution_m) * grid.resolution_m
        if cfg.local.escalation > 1 and np.max(np.abs(start[:2] - predicted[:2])) > w - 1e-6:
            # the best lies on the window's edge: the odometry may be farther off than
            # the window allows (fr079's odometry reads forward while the robot backs
            # up); a wider search's best replaces it if it fits clearly better
            wide, wide_score = correlative_search(
                grid, pts, predicted, cfg.local.escalation * lin, ang,
                cfg.local.translation_cost, cfg.local.rotation_cost)
            if wide_score > score + cfg.odometry.score_margin:
                start = wide
        r = refine(grid, pts, start, prior=start, translation_weight=cfg.local.translation_weight,
                   rotation_weight=cfg.local.rotation_weight)
        # the motion model's own sigmas against a scan weighed by its residuals; kept
        # unless the scan fits clearly better where the search alone puts it (an
        # odometry jump; how clearly: search_overrides_odometry)
        sig = self.odometry_sigmas(np.zeros(3) if u is None else u)
        if record:
            self._free_heading = (float(r.pose[2]) if r.score >= cfg.local.min_score
                                  else None)
        ro = refine(grid, pts, start, prior=predicted, occupied_weight=1.0,
                    translation_weight=1.0 / sig[0], rotation_weight=1.0 / sig[2],
                    residual_floor=cfg.local.residual_floor)
        if not self.search_overrides_odometry(r.score - ro.score, record):
            r = ro
        pose = r.pose
        if r.degeneracy() >= cfg.local.min_degeneracy:
            return pose, r.score, None
        # a direction the scan cannot fix (a plain corridor): take odometry's word for
        # it (Zhang et al. 2016, "solution remapping")
        _, vec = np.linalg.eigh(r.information[:2, :2])
        v = vec[:, 0]
        pose = pose.copy()
        pose[:2] += v * float(v @ (predicted[:2] - pose[:2]))
        return pose, r.score, v

    def track(self, xy: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The pose of a scan that does not become a node, relative to the last node:
        matched against the submap like a node but in the smaller ``track_*`` window
        (it is within a node's step, 0.1 m / 0.05 rad, of its node), so its pose does
        not inherit the odometry's error since the node; inserted nowhere and not part
        of the graph; the odometry increment ``u`` when matching is off or fails."""
        cfg = self.config
        if not cfg.local.matching:
            return u
        last = len(self.local) - 1
        pose, score, _ = self.match_local(xy, compose(self.local[last], u), u, record=False,
                                          window=(cfg.local.track_linear_window_m,
                                                  cfg.local.track_angular_window_rad))
        return relative(self.local[last], pose) if score >= cfg.local.min_score else u

    def odometry_sigmas(self, u: np.ndarray) -> np.ndarray:
        """Sigmas (x, y, theta) of the odometry increment ``u``: the fixed model's, the
        heading's scaled by what :meth:`calibrate_odometry` has learned. The odometry
        edges and the local matches' odometry prior both use them."""
        sig = self.graph.odometry_sigmas(u)
        sig[2] *= self.odometry.scale
        return sig

    def calibrate_odometry(self, u: np.ndarray, free: float | None) -> None:
        """One residual for :class:`OdometryCalibration` at the node just added: the
        heading change the scan matches found over the last ``lag`` nodes
        (``free``: this node's match refined without the odometry prior) minus the
        odometry's, over the fixed model's sigma of that change. Over one node the
        match's own noise dominates on a good odometry (fr-clinic: a spread of 0.2-0.5° a
        node, against the odometry's 0.04°/m); over K nodes the odometry's error grows
        as √K while the match's, each against its submap, does not (fr-clinic's learned
        share of the fixed sigma: 0.3-0.8 over one node, 0.1-0.3 over 20)."""
        cfg = self.config
        var = float(self.graph.odometry_sigmas(u)[2] ** 2)
        log = self._heading_log
        total = (log[-1][2] if log else 0.0) + var
        log.append((np.nan if free is None else free, float(self.node_odom[-1][2]), total))
        then = log[0]
        if free is None or len(log) <= cfg.odometry.lag or np.isnan(then[0]):
            return
        e = wrap_angle((free - then[0]) - (log[-1][1] - then[1]))
        self.odometry.add(float(e) / np.sqrt(total - then[2]))

    def search_overrides_odometry(self, gain: float, record: bool = True) -> bool:
        """Whether the search's match, scoring ``gain`` more than the match held near
        the odometry, replaces it. The margin it must beat follows how often the scans
        have contradicted the odometry lately: ``score_margin`` when the search
        won at least ``noisy_rate`` of the last ``rate_nodes`` nodes
        by that margin (fr079's odometry, degrees off in every turn: 44 % of its nodes),
        rising linearly to ``quiet_margin`` when it never did (fr-clinic's,
        confirmed to a fraction of a degree: 2.5 %), so that one ambiguous scan in a
        doorway or an open hall cannot turn the map by degrees."""
        cfg = self.config
        won = gain > cfg.odometry.score_margin
        hist = self._search_won
        if record:
            hist.append(won)
        if not won:
            return False
        n = len(hist)
        rate = sum(hist) / n if n >= 10 else 1.0
        quiet = max(0.0, 1.0 - rate / cfg.odometry.noisy_rate)
        margin = cfg.odometry.score_margin + (cfg.odometry.quiet_margin
                                              - cfg.odometry.score_margin) * quiet
        return gain > margin

    def intensity_step(self, pose: np.ndarray, xy: np.ndarray,
                       inten: np.ndarray | None) -> np.ndarray:
        """The paper's intensity term: Intensity-ICP against the previous node's scan
        from the grid match, kept inside eq. 5's box around it."""
        if self._prev is None or inten is None:
            return pose
        icp = self.config.icp.model_copy(update={"alpha": self.config.alpha})
        res = intensity_icp(Reference(self._prev[0], self._prev[1], icp.alpha), xy, inten,
                            pose, icp)
        if res.usable(len(xy), icp) and inside_gate(pose, res.pose, np.zeros(3),
                                                      self.config.gate):
            return res.pose
        return pose
