"""Laser SLAM with received-light intensity (Hara, Kawata, Ohya, Yuta), and graph SLAM
with loop closure beyond it (Hess et al. 2016).

Where each part of the papers lives:

- the scans with intensity (§3): :mod:`chizu.numeric.scan`; logs (CARMEN, ROS bags) and TUM
  trajectories: :mod:`~chizu.numeric.slam.logs`;
- Intensity-ICP (§4, eqs. 1-3) and the other scan matchers both estimators share:
  :mod:`~chizu.numeric.slam.matching`;
- the map the matchers match against, keyframes and their likelihood fields:
  :mod:`~chizu.numeric.slam.keyframes`;
- the gated single-hypothesis SLAM (§6, eq. 5) and the odometry and ICP baselines:
  :mod:`~chizu.numeric.slam.gated`;
- the Rao-Blackwellized particle filter (§7, eqs. 6-9) with Grisetti et al.'s improved
  proposal: :mod:`~chizu.numeric.slam.rbpf`;
- graph SLAM (Hess et al. 2016, Cartographer): :mod:`~chizu.numeric.slam.graph`, its pose
  graph on GTSAM in :mod:`~chizu.numeric.slam.pose_graph`;
- the global scan alignment both estimators end a run with (after Lu & Milios 1997):
  :mod:`~chizu.numeric.slam.alignment`;
- one entry point for every method: :mod:`~chizu.numeric.slam.runner`; batches over logs and
  settings: :mod:`~chizu.numeric.slam.batch`; simulated logs: :mod:`~chizu.numeric.slam.simulate`;
- the relation metric of Kümmerle et al. 2009: :mod:`~chizu.numeric.slam.evaluation`.
"""
