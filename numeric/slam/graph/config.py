"""Graph SLAM's parameters, one nested model per stage: local SLAM, the submaps, the
odometry model, loop closure. One set for every log; why the defaults are what they
are: ``docs/notes/slam-graph.md``."""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, Field

from chizu.numeric.probability_grid import GridConfig
from chizu.numeric.slam.alignment import AlignmentConfig
from chizu.numeric.slam.gated import GateConfig
from chizu.numeric.slam.keyframes import MapConfig
from chizu.numeric.slam.matching.intensity_icp import IcpConfig
from chizu.numeric.slam.pose_graph import GraphConfig
from chizu.numeric.threads import default_threads


def _submap_grid() -> GridConfig:
    # Cartographer's 2D submap model: gentle hits/misses, clamped to [0.1, 0.9]
    return GridConfig(p_hit=0.55, p_miss=0.49, p_min=0.1, p_max=0.9, max_range_m=30.0)


class LocalSlamConfig(BaseModel):
    """Local SLAM (Hess et al. §IV): when a scan becomes a node and how it is matched."""

    node_linear_m: float = Field(0.1, ge=0)
    node_angular_rad: float = Field(0.05, ge=0)
    node_time_s: float = Field(5.0, gt=0)
    voxel_m: float = Field(0.05, gt=0, description="scan down-sampling for matching")
    linear_window_m: float = Field(0.15, ge=0)
    angular_window_rad: float = Field(0.2, ge=0)
    matching: bool = Field(True, description="off: nodes follow odometry (a front end of "
                           "odometry alone; loop closure still runs)")
    escalation: float = Field(3.0, ge=1, description="when the search's best lies on its "
                              "window's edge it is repeated in a window this many times "
                              "wider (1: never)")
    track_linear_window_m: float = Field(0.05, ge=0, description="search window of scans "
                                         "between nodes")
    track_angular_window_rad: float = Field(0.05, ge=0)
    min_score: float = Field(0.25, ge=0, le=1, description="below this the node follows "
                             "odometry")
    translation_cost: float = Field(0.1, ge=0, description="correlative search: score x "
                                    "exp(-hypot(c_t |dt|, c_r |dθ|))")
    rotation_cost: float = Field(0.1, ge=0)
    min_degeneracy: float = Field(0.05, ge=0, le=1, description="below this the weak "
                                  "direction of a local match follows odometry")
    translation_weight: float = Field(10.0, ge=0, description="refinement prior towards "
                                      "the correlative search's pose")
    rotation_weight: float = Field(40.0, ge=0)
    residual_floor: float = Field(0.01, gt=0)


class SubmapConfig(BaseModel):
    """The submaps (Hess et al. §III-B): probability grids of ``scans`` nodes each, two
    always overlapping."""

    scans: int = Field(90, ge=2, description="nodes per submap")
    grid: GridConfig = Field(default_factory=_submap_grid)
    connect_gap_m: float | None = Field(
        0.5, gt=0, description="neighbouring returns closer than this are joined into a "
        "surface (None: the returns alone)")
    grazing_gap_m: float | None = Field(
        2.0, gt=0, description="a wall seen at grazing incidence (collinear returns, "
        "keyframes.collinear_grazing_segments) is joined into a line up to this gap "
        "(None: its returns stay dots)")
    trim_share: float | None = Field(
        0.95, gt=0, le=1, description="a finished submap is trimmed when older kept "
        "submaps observed this share of its cells (Submaps.trim; None: never)")
    trim_cell_m: float = Field(0.25, gt=0, description="cells of that comparison")
    forget_after_scans: int = Field(
        10_000, ge=1, description="a run past this many scans forgets the returns of the "
        "nodes only trimmed submaps hold, their keyframes' and, for the end-of-run "
        "alignment, their scans' (GraphSlam.forget); a shorter run keeps them all")


class OdometryModelConfig(BaseModel):
    """The odometry's heading sigma learned from the local matches, and when a match
    away from the odometry replaces the one held near it."""

    window: int = Field(400, ge=0, description="nodes over which the odometry's heading "
                        "sigma (odometry edges, the local matches' prior) is learned "
                        "(OdometryCalibration; 0: the fixed graph.odom_sigma_rad)")
    min_scale: float = Field(0.1, gt=0, le=1, description="... down to this share of the "
                             "fixed one")
    knee: float = Field(1.0, gt=0, le=1, description="OdometryCalibration.knee")
    lag: int = Field(20, ge=1, description="each residual compares the heading change over "
                     "this many nodes")
    score_margin: float = Field(0.05, ge=0, description="the search's match replaces the "
                                "odometry-held one when it scores this much better, while "
                                "the scans keep contradicting the odometry ...")
    quiet_margin: float = Field(0.5, ge=0, description="... and this much when they rarely "
                                "do")
    noisy_rate: float = Field(0.05, gt=0, le=1, description="share of recent nodes won by "
                              "the search from which the odometry counts as noisy (margin "
                              "score_margin)")
    rate_nodes: int = Field(100, ge=10, description="recent nodes of that share")


class LoopClosureConfig(BaseModel):
    """Loop closure (Hess et al. §V): branch-and-bound matches of nodes against finished
    submaps, verified before they become edges."""

    every: int | None = Field(4, ge=1, description="nodes between loop-closure searches "
                              "(None: no loop closure -- local SLAM alone, "
                              ":class:`~chizu.numeric.slam.graph.scan_odometry.ScanOdometry`)")
    max_distance_m: float = Field(15.0, gt=0)
    max_submaps: int = Field(1000, ge=1, description="nearest finished submaps searched in "
                             "the full window per node (tracked ones: all)")
    coarsen: int = Field(2, ge=1, le=8, description="branch and bound on a grid this many "
                         "times coarser (max-pooled); the refinement is on the submap's own")
    linear_window_m: float = Field(8.0, gt=0)
    angular_window_rad: float = Field(float(np.radians(30.0)), gt=0)
    min_score: float = Field(0.5, gt=0, le=1, description="branch and bound's score (on the "
                             "max-pooled grid) a closure needs ...")
    min_refined_score: float = Field(0.4, gt=0, le=1, description="... and its refinement's "
                                     "on the submap's own grid (lower: max-pooling inflates "
                                     "the first)")
    window_growth: float = Field(0.03, ge=0, description="the candidate radius and linear "
                                 "window of a submap grow by this many m per m of path since "
                                 "the trajectory was last tied to it (GraphSlam.drift_path) "
                                 "...")
    window_growth_rad: float = Field(0.0002, ge=0, description="... and the angular window "
                                     "by this many rad per m")
    max_growth_m: float = Field(20.0, ge=0, description="cap of the linear growth")
    angular_step_rad: float = Field(0.005, ge=0, description="coarsest angle step of the "
                                    "search (the refinement recovers the rest)")
    near_window_m: float = Field(1.0, ge=0, description="the linear window against a submap "
                                 "left d metres of path ago is at most this ...")
    near_rate: float = Field(0.03, ge=0, description="... plus this times d: local SLAM "
                             "cannot have drifted farther from it")
    unique_m: float = Field(1.0, ge=0, description="a wide-window closure is rejected when "
                            "the window holds another pose this far from the best ... (0: no "
                            "test)")
    unique_ratio: float = Field(0.9, gt=0, le=1, description="... scoring at least this "
                                "share of the best's score")
    verify_nodes: int = Field(15, ge=1, description="a first closure to a submap waits this "
                              "many nodes for a consistent second one")
    verify_m: float = Field(0.3, gt=0)
    verify_rad: float = Field(0.05, gt=0)
    track_nodes: int = Field(10, ge=0, description="a submap closed within this many nodes "
                             "is searched in the small tracking window only")
    track_linear_window_m: float = Field(0.5, gt=0)
    track_angular_window_rad: float = Field(0.15, gt=0)
    min_degeneracy: float = Field(0.1, ge=0, le=1, description="reject closures whose match "
                                  "fixes one direction this much less")
    max_points: int = Field(200, ge=10)
    depth: int = Field(6, ge=1, le=10)
    neighbours: int = Field(2, ge=0, description="a node is matched against a submap "
                            "stitched with this many finished neighbours in time on each "
                            "side (GraphSlam.loop_map)")
    cache: int = Field(48, ge=1, description="precomputed submaps kept in memory ...")
    cache_mb: float = Field(256.0, gt=0, description="... and at most this many MiB of them "
                            "(a hospital hall's stitched grids and their branch-and-bound "
                            "stacks run to tens of MiB each)")
    threads: int = Field(default_factory=default_threads, ge=1, le=64,
                         description="threads running one node's branch-and-bound searches "
                                     "side by side (the results do not depend on it)")


class GraphSlamConfig(BaseModel):
    """Parameters of graph SLAM; one set for every log."""

    local: LocalSlamConfig = Field(default_factory=LocalSlamConfig)
    submaps: SubmapConfig = Field(default_factory=SubmapConfig)
    odometry: OdometryModelConfig = Field(default_factory=OdometryModelConfig)
    loop: LoopClosureConfig = Field(default_factory=LoopClosureConfig)
    alpha: float = Field(0.0, ge=0, description="intensity weight of eq. 1 (0: off)")
    icp: IcpConfig = Field(default_factory=IcpConfig)
    gate: GateConfig = Field(default_factory=lambda: GateConfig(eps_xy_m=0.05, eps_xy_ratio=0,
                                                               eps_theta_rad=0.03,
                                                               eps_theta_ratio=0))
    graph: GraphConfig = Field(default_factory=GraphConfig)
    map: MapConfig = Field(default_factory=lambda: MapConfig(max_points_m=30.0))
    alignment: AlignmentConfig | None = Field(
        default_factory=AlignmentConfig, description="global scan alignment when the run "
        "is finished (GraphSlam.finish; None: the online estimate is final)")
