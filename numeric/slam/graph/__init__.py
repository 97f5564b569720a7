"""Graph SLAM with loop closure after Hess, Kohler, Rapp & Andor, "Real-Time Loop Closure
in 2D LIDAR SLAM" (ICRA 2016, Cartographer), beyond the paper of Hara et al.

One module per stage:

- :mod:`~chizu.numeric.slam.graph.local_slam`: local SLAM (§IV), scan-to-submap matching by
  correlative search and Gauss-Newton refinement, held near a learned odometry model;
- :mod:`~chizu.numeric.slam.graph.submaps`: the submaps (§III-B), two always active, stitched
  with their neighbours for loop closure;
- :mod:`~chizu.numeric.slam.graph.loop_closure`: loop closure by branch and bound (§V,
  Algorithms 2-3), with uniqueness, confirmation and a drift bound on the window;
- :mod:`~chizu.numeric.slam.graph.slam`: the estimator, the pose graph on GTSAM's iSAM2
  (:mod:`chizu.numeric.slam.pose_graph`) and its outputs;
- :mod:`~chizu.numeric.slam.graph.scan_odometry`: local SLAM alone as a motion estimate
  (what localization on a saved map predicts each scan with);
- :mod:`~chizu.numeric.slam.graph.config`: the parameters, one nested model per stage.
"""

from chizu.numeric.slam.graph.config import (
    GraphSlamConfig,
    LocalSlamConfig,
    LoopClosureConfig,
    OdometryModelConfig,
    SubmapConfig,
)
from chizu.numeric.slam.graph.loop_closure import LoopClosure, adaptive_voxel, tie
from chizu.numeric.slam.graph.scan_odometry import ScanOdometry
from chizu.numeric.slam.graph.slam import GraphSlam
from chizu.numeric.slam.graph.submaps import LoopMap, Submap

__all__ = ["GraphSlam", "GraphSlamConfig", "LocalSlamConfig", "LoopClosure",
           "LoopClosureConfig", "LoopMap", "OdometryModelConfig", "ScanOdometry", "Submap",
           "SubmapConfig", "adaptive_voxel", "tie"]
