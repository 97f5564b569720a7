"""Local SLAM alone as a motion estimate: graph SLAM's local steps (Hess et al. 2016,
§IV) -- each scan matched against the robot's own two active submaps -- without loop
closure, and with nothing kept that they no longer match against.

Wheel odometry drifts and, on some robots, runs ahead of or behind the laser by a scan
or two while turning; a localizer predicting each scan from it starts several degrees
off, and where the map does not reach (a part of the building it never saw) has nothing
else to go on. Cartographer's pure localization runs local SLAM all the time for this
reason and adds the map's constraints on top; :class:`ScanOdometry` is that local SLAM
for :mod:`chizu.numeric.slam.map_localization`.
"""

from __future__ import annotations

import numpy as np

from chizu.numeric.probability_grid import ProbabilityGrid
from chizu.numeric.scan import Scan
from chizu.numeric.slam.graph.config import GraphSlamConfig
from chizu.numeric.slam.graph.slam import GraphSlam


class ScanOdometry:
    """Feed scans in time order; each call returns the scan's pose in the local-SLAM
    frame (which starts at the first scan's odometry). :meth:`restart` begins a new
    local map at the next scan (after a gap in the log: the robot may have been carried,
    and a scan from elsewhere must not be matched into the old submaps)."""

    def __init__(self, config: GraphSlamConfig | None = None) -> None:
        cfg = (config or GraphSlamConfig()).model_copy(deep=True)
        cfg.loop.every, cfg.alignment, cfg.submaps.trim_share = None, None, None
        self.config = cfg
        self.restart()

    def restart(self) -> None:
        self._slam = GraphSlam(self.config)
        self._dropped = 0  # submaps whose grids are gone
        self._forgotten = 0  # nodes whose keyframes are gone

    def __call__(self, scan: Scan) -> np.ndarray:
        s = self._slam
        s.process(scan)
        # a finished submap is never matched against again, nor an older node's returns
        while self._dropped < len(s.submaps) and s.submaps[self._dropped].finished:
            sub = s.submaps[self._dropped]
            sub.grid = ProbabilityGrid(sub.grid.config)
            self._dropped += 1
        oldest = min((sub.nodes[0] for sub in s.active() if sub.nodes), default=0)
        while self._forgotten < oldest:
            s.keyframes.forget(self._forgotten)
            self._forgotten += 1
        return s.local_pose()
