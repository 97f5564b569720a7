"""Odometry calibration from scan matching: the heading sigma of eq. 7's motion model
learned from the log (:class:`~chizu.numeric.slam.pose_graph.OdometryCalibration`).

A robot's odometry can be far better than the fixed Σ_w says; with the fixed sigma the
scan match decides the heading alone, also where the scan hardly constrains it, and
there small pulls of the matcher add up. Each update the best particle's scan is
matched on the likelihood alone against the newest keyframe at least ``lag_m`` of
odometry path back, and the heading change it finds minus the odometry's, divided by
the fixed model's sigma of that change, is one residual. Over a lag the odometry's
heading error adds up while the match's, between two scans, does not; within one
update a heading walk inside the matcher's flat basin would stay hidden.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from chizu.numeric.geometry import compose, wrap_angle
from chizu.numeric.slam.matching.likelihood_field import Beams, count_inliers
from chizu.numeric.slam.pose_graph import OdometryCalibration
from chizu.numeric.slam.rbpf.config import OdometryCalibrationConfig
from chizu.numeric.slam.rbpf.proposal import Starts, robust_increment

if TYPE_CHECKING:
    from chizu.numeric.slam.rbpf.filter import RbpfSlam


@dataclass
class HeadingCalibration:
    """The residuals' bookkeeping: per keyframe its odometry, the odometry path and the
    summed fixed heading variance when it was added; the variance summed over the
    updates so far; and what has been learned (``learned``)."""

    config: OdometryCalibrationConfig
    learned: OdometryCalibration = field(init=False)
    keyframes: list[tuple[np.ndarray, float, float]] = field(default_factory=list)
    heading_var: float = 0.0

    def __post_init__(self) -> None:
        cfg = self.config
        self.learned = OdometryCalibration(cfg.window, cfg.min_scale, cfg.knee)

    def keyframe_added(self, odom: np.ndarray | None, path_m: float) -> None:
        self.keyframes.append((odom.copy() if odom is not None else np.zeros(3), path_m,
                               self.heading_var))

    def add_residual(self, slam: RbpfSlam, u: np.ndarray, beams: Beams) -> None:
        """One residual at this update: the lagged keyframe ``A`` is matched against the
        scan alone (the best of starts turned by ``lag_headings_rad``, chosen by the
        scan's likelihood alone), and the heading change it finds from the best
        particle's pose of ``A`` minus the odometry's change since ``A`` is divided by
        the fixed model's sigma of that change (the square root of the summed
        per-update variances). No residual when the match explains fewer than
        ``min_match_fraction`` of the beams (no overlap)."""
        imp = slam.config.improved
        sig = float(slam.config.motion.sigmas(u)[2])
        self.heading_var += sig * sig
        assert slam._anchor_odom is not None
        odom = compose(slam._anchor_odom, u)
        path = slam._odom_path[-1]
        k = len(self.keyframes) - 1
        while k >= 0 and path - self.keyframes[k][1] < self.config.lag_m:
            k -= 1
        if k < 0:
            return
        kf_odom, _, kf_var = self.keyframes[k]
        fp = slam.field_pack([k], beams.alpha > 0)
        kf = np.ascontiguousarray(slam._kf_pose[k, slam._lineage[k, slam.best]][None, None, :])
        x0 = slam.x[slam.best]
        # sigmas of 1e6: the motion model neither pulls nor scores the starts (the
        # prior is off), so the best start is the one the scan alone fits best
        starts = Starts(np.asarray(self.config.lag_headings_rad, dtype=float), np.zeros(0),
                        0.0, False)
        inc, _ = robust_increment(x0, u, np.full(3, 1e6), beams, fp, kf, slam.model, starts,
                                  slam.config.threads)
        pose = compose(x0, np.asarray(inc))
        inl = count_inliers(pose, beams, fp, kf, (2.0 * imp.sigma_m) ** 2)
        if inl < max(imp.min_inliers, imp.min_match_fraction * len(beams.pts)):
            return
        turned = float(wrap_angle(pose[2] - kf[0, 0, 2]))
        odo_turned = float(wrap_angle(odom[2] - kf_odom[2]))
        spread = math.sqrt(max(self.heading_var - kf_var, sig * sig))
        self.learned.add(float(wrap_angle(turned - odo_turned)) / spread)
