"""Laser SLAM with received-light intensity (Hara, Kawata, Ohya, Yuta).

One module per step of the paper: :mod:`scan` (§3, scans with intensity), :mod:`logs`
(CARMEN / ROS readers, TUM trajectories), :mod:`intensity_icp` (§4, eqs. 1-3),
:mod:`keyframes` (the reference "previous scan + map points in sensor range" and the
per-keyframe likelihood fields), :mod:`gated` (§6, eq. 5, plus the plain odometry and
ICP baselines), :mod:`rbpf` (§7, eqs. 6-9), :mod:`occupancy` (map export) and
:mod:`evaluation` (Kümmerle et al. 2009 relation metric).
"""
