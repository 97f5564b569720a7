"""Graph SLAM with loop closure, beyond the paper: Hess, Kohler, Rapp, Andor, "Real-Time
Loop Closure in 2D LIDAR SLAM" (ICRA 2016, Cartographer).

Local SLAM (§IV): a scan becomes a node once the robot has moved ``node_linear_m`` /
``node_angular_rad`` (or ``node_time_s`` passed) since the last node. The node is
placed by matching the scan against the older of the two active submaps -- first a
correlative search of a small window around the odometry prediction, then
Gauss-Newton refinement on the interpolated probability grid with priors towards the
prediction; when the search's best lies on its window's edge it is repeated in a
``local_escalation`` times wider window and kept if it fits clearly better -- and
inserted into both active submaps (a submap is finished after
``scans_per_submap`` nodes; a new one starts halfway, so two always overlap) with the
surface between neighbouring returns (``submap_connect_gap_m``: one scan of a wall
seen at a slant in 1° steps is otherwise a dotted line that moves with the robot, and
the next scan fits it best where the first was taken; and ``submap_grazing_gap_m``:
the collinear returns of a wall seen at grazing incidence are joined too, farther
apart, so that such a wall fixes a scan across itself and leaves it free along it).
Scans between nodes are matched the same way but inserted nowhere: their pose
relative to their node comes from the match, not from the odometry
(:meth:`GraphSlam.track`).

Loop closure (§V): every ``loop_every``-th node is matched by branch and bound against
the finished submaps within ``loop_max_distance_m`` of it -- each stitched with its
``loop_neighbours`` neighbours in time on both sides (:meth:`GraphSlam.loop_map`), and,
those grids overlapping, every ``loop_neighbours + 1``-th of them per search in turn
-- in a window of
``loop_linear_window_m`` / ``loop_angular_window_rad`` (both growing with the path
along which local SLAM may have drifted from that submap, :meth:`GraphSlam.drift_path`;
the linear one at most
``loop_near_window_m`` plus ``loop_near_rate`` times the path since the submap was
left, which local SLAM cannot have drifted beyond); a match above ``loop_min_score``
with no second pose as good beyond ``loop_unique_m`` in the window (a scan that fits
two places says nothing about which), refined by Gauss-Newton to above
``loop_min_refined_score``, becomes a robust between-edge from the submap's anchor
node once a nearby node's match moves that node the same way (the confirming match
needs no uniqueness test). On 12 simulated tours (loop and room_a, seeds 1-8 and 1-4,
0.8 m/s) 11 of 363 accepted closures are off by more than 0.5 m. The drift bound on the
window is what holds in a building of identical rooms and evenly spaced doors
(``tests/bench/slam_unseen.py``), where the uniqueness test and the confirming match
both pass an aliased place: with ``loop_near_rate`` 0.1, 238 of 835 closures of one such
tour were 2.5-6.9 m off; with 0.03 the loop-spanning error is 0.015 m instead of 3.6 m.

Optimisation: the nodes and edges (local matches, odometry, closures) form a pose graph
optimised incrementally by iSAM2 (:mod:`numeric.slam.pose_graph`); after a closure the
whole trajectory moves. Submaps keep their grids in the local-SLAM frame; a submap's
place in the world is its anchor node's optimised pose. The final map is rebuilt from
the optimised node poses (:func:`numeric.occupancy.build_occupancy`).

The end of a run (:meth:`GraphSlam.finish`, beyond Hess et al.): global scan alignment
(:mod:`numeric.slam.scan_alignment`, after Lu & Milios 1997) refines every scan's pose
by point-to-line ICP between overlapping scans and one batch optimisation, starting
from the online estimate; the trajectory and the map are then the aligned ones.

The intensity channel of the paper (eq. 1) enters as an optional extra term: with
``alpha > 0`` the local match is followed by Intensity-ICP against the previous node's
scan, initialised at the grid match and accepted only inside eq. 5's box around it.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from pydantic import BaseModel, Field

from numeric.geometry import compose, invert, place, relative, wrap_angle
from numeric.probability_grid import GridConfig, ProbabilityGrid
from numeric.scan import Scan
from numeric.slam.correlative import (
    Match,
    PrecomputedGrid,
    correlative_search,
    refine,
    window_cells,
)
from numeric.slam.gated import GateConfig, inside_gate
from numeric.slam.intensity_icp import IcpConfig, Reference, intensity_icp
from numeric.slam.keyframes import (
    Keyframes,
    MapConfig,
    connect_returns,
    moved,
    voxel_downsample,
)
from numeric.slam.pose_graph import GraphConfig, OdometryCalibration, PoseGraph
from numeric.slam.scan_alignment import AlignmentConfig, align_scans
from numeric.threads import default_threads, thread_map


def _submap_grid() -> GridConfig:
    # Cartographer's 2D submap model: gentle hits/misses, clamped to [0.1, 0.9]
    return GridConfig(p_hit=0.55, p_miss=0.49, p_min=0.1, p_max=0.9, max_range_m=30.0)


class GraphSlamConfig(BaseModel):
    """Parameters of graph SLAM; one set for every log (see the README's table)."""

    node_linear_m: float = Field(0.1, ge=0)
    node_angular_rad: float = Field(0.05, ge=0)
    node_time_s: float = Field(5.0, gt=0)
    scans_per_submap: int = Field(90, ge=2)
    submap: GridConfig = Field(default_factory=_submap_grid)
    match_voxel_m: float = Field(0.05, gt=0, description="scan down-sampling for matching")
    submap_connect_gap_m: float | None = Field(
        0.5, gt=0, description="submaps: neighbouring returns closer than this are joined "
        "into a surface (GraphSlam.insert; None: the returns alone). Session 28, all "
        "relations / loop-spanning (m), None -> 0.5: aces 0.034 -> 0.034 / 0.047 -> "
        "0.047, mit-csail 0.028 -> 0.027 / 0.041 -> 0.041, fr079 0.041 -> 0.041, "
        "fr-clinic 0.125 -> 0.113 / 0.624 -> 0.440; simulated office 1 with the 30 m "
        "laser 0.224 -> 0.053 (loop)")
    submap_grazing_gap_m: float | None = Field(
        2.0, gt=0, description="submaps: a wall seen at grazing incidence (collinear "
        "returns, keyframes.collinear_grazing_segments) is joined into a line up to "
        "this gap (None: its returns stay dots). Session 32 made it the default; 2.0 m "
        "against None, simulated offices with the 30 m laser (loop-spanning) 1: 0.053 "
        "-> 0.0065, 4: 0.033 -> 0.0086, the other six offices within 2 mm; aces 0.0338 "
        "-> 0.0338, mit-csail 0.0273 -> 0.0272, fr079 0.0408 -> 0.0413, fr-clinic "
        "0.1118 -> 0.1092; simulated loop (URG-04LX, seeds 1-16) mean position error "
        "0.232 -> 0.237 m; fr-clinic with perturbed odometry (seeds 1-12) the return at "
        "4390 s closed late in the same share of runs either way "
        "(docs/notes/slam-graph-unseen.md, sessions 31-32)")
    local_linear_window_m: float = Field(0.15, ge=0)
    local_angular_window_rad: float = Field(0.2, ge=0)
    local_matching: bool = Field(True, description="off: nodes follow odometry (a front "
                                 "end of odometry alone; loop closure still runs)")
    local_escalation: float = Field(3.0, ge=1, description="when the search's best lies "
                                    "on its window's edge it is repeated in a window "
                                    "this many times wider (1: never)")
    track_linear_window_m: float = Field(0.05, ge=0, description="search window of "
                                         "scans between nodes (GraphSlam.track)")
    track_angular_window_rad: float = Field(0.05, ge=0)
    local_min_score: float = Field(0.25, ge=0, le=1,
                                   description="below this the node follows odometry")
    search_translation_cost: float = Field(0.1, ge=0, description="correlative search: "
                                           "score x exp(-hypot(c_t |dt|, c_r |dθ|))")
    search_rotation_cost: float = Field(0.1, ge=0)
    local_min_degeneracy: float = Field(0.05, ge=0, le=1, description="below this the "
                                        "weak direction of a local match follows odometry")
    translation_weight: float = Field(10.0, ge=0, description="refinement prior towards "
                                      "the correlative search's pose")
    rotation_weight: float = Field(40.0, ge=0)
    local_residual_floor: float = Field(0.01, gt=0)
    odometry_window: int = Field(400, ge=0, description="nodes over which the odometry's "
                                 "heading sigma (odometry edges, the local matches' prior) "
                                 "is learned from the local matches (OdometryCalibration; "
                                 "0: the fixed graph.odom_sigma_rad). Session 29: learned "
                                 "0.1-0.3 of the fixed one on fr-clinic, 1 on mit-csail "
                                 "and fr079; docs/notes/slam-graph-unseen.md, session 29")
    odometry_min_scale: float = Field(0.1, gt=0, le=1, description="... down to this "
                                      "share of the fixed one")
    odometry_knee: float = Field(1.0, gt=0, le=1, description="OdometryCalibration.knee")
    odometry_lag: int = Field(20, ge=1, description="each residual compares the heading "
                              "change over this many nodes (GraphSlam.calibrate_odometry)")
    odometry_score_margin: float = Field(0.05, ge=0, description="the search's match "
                                         "replaces the odometry-held one when it scores "
                                         "this much better, while the scans keep "
                                         "contradicting the odometry ...")
    odometry_quiet_margin: float = Field(0.5, ge=0, description="... and this much when "
                                         "they rarely do")
    odometry_noisy_rate: float = Field(0.05, gt=0, le=1, description="share of recent "
                                       "nodes won by the search from which the odometry "
                                       "counts as noisy (margin odometry_score_margin)")
    odometry_rate_nodes: int = Field(100, ge=10, description="recent nodes of that share")
    loop_every: int = Field(4, ge=1, description="nodes between loop-closure searches")
    loop_max_distance_m: float = Field(15.0, gt=0)
    loop_max_submaps: int = Field(1000, ge=1, description="nearest finished submaps "
                                  "searched in the full window per node (tracked ones: all)")
    loop_coarsen: int = Field(2, ge=1, le=8, description="branch and bound on a grid this "
                              "many times coarser (max-pooled); the refinement is on the "
                              "submap's own")
    loop_linear_window_m: float = Field(8.0, gt=0)
    loop_angular_window_rad: float = Field(float(np.radians(30.0)), gt=0)
    loop_min_score: float = Field(0.5, gt=0, le=1, description="branch and bound's score "
                                  "(on the max-pooled grid) a closure needs ...")
    loop_min_refined_score: float = Field(0.4, gt=0, le=1, description="... and its "
                                          "refinement's on the submap's own grid (lower: "
                                          "max-pooling inflates the first; fr-clinic's "
                                          "correct local matches score 0.42-0.46)")
    loop_window_growth: float = Field(0.03, ge=0, description="the candidate radius and "
                                      "linear window of a submap grow by this many m per "
                                      "m of path since the trajectory was last tied to "
                                      "it (GraphSlam.drift_path) ... (0.01 until session "
                                      "33: fr-clinic with perturbed odometry drifts about "
                                      "0.02 m per m and left its old halls outside the "
                                      "radius; docs/notes/slam-graph-unseen.md)")
    loop_window_growth_rad: float = Field(0.0002, ge=0, description="... and the angular "
                                          "window by this many rad per m")
    loop_max_growth_m: float = Field(20.0, ge=0, description="cap of the linear growth")
    loop_angular_step_rad: float = Field(0.005, ge=0, description="coarsest angle step of "
                                         "the search (the refinement recovers the rest)")
    loop_near_window_m: float = Field(1.0, ge=0, description="the linear window "
                                      "against a submap left d metres of path ago is at "
                                      "most this ...")
    loop_near_rate: float = Field(0.03, ge=0, description="... plus this times d: local "
                                  "SLAM cannot have drifted farther from it (0.1 until "
                                  "session 27: in a simulated office of identical rooms "
                                  "it let a room one door down, 6.9 m off, be taken; "
                                  "the Freiburg logs give the same errors at 0.03)")
    loop_unique_m: float = Field(1.0, ge=0, description="a wide-window closure is "
                                 "rejected when the window holds another pose this far "
                                 "from the best ... (0: no test)")
    loop_unique_ratio: float = Field(0.9, gt=0, le=1, description="... scoring at least "
                                     "this share of the best's score")
    loop_verify_nodes: int = Field(15, ge=1, description="a first closure to a submap "
                                   "waits this many nodes for a consistent second one")
    loop_verify_m: float = Field(0.3, gt=0)
    loop_verify_rad: float = Field(0.05, gt=0)
    loop_track_nodes: int = Field(10, ge=0, description="a submap closed within this many "
                                  "nodes is searched in the small tracking window only")
    loop_track_linear_window_m: float = Field(0.5, gt=0)
    loop_track_angular_window_rad: float = Field(0.15, gt=0)
    loop_min_degeneracy: float = Field(0.1, ge=0, le=1, description="reject closures "
                                       "whose match fixes one direction this much less")
    loop_max_points: int = Field(200, ge=10)
    loop_depth: int = Field(6, ge=1, le=10)
    loop_neighbours: int = Field(2, ge=0, description="loop closure matches against a "
                                 "submap stitched with this many finished neighbours "
                                 "in time on each side (GraphSlam.loop_map)")
    loop_cache: int = Field(48, ge=1, description="precomputed submaps kept in memory ...")
    loop_cache_mb: float = Field(256.0, gt=0, description="... and at most this many MiB "
                                 "of them (a hospital hall's stitched grids and their "
                                 "branch-and-bound stacks run to tens of MiB each)")
    loop_threads: int = Field(default_factory=default_threads, ge=1, le=64,
                              description="threads running one node's branch-and-bound "
                              "searches side by side (the results do not depend on it)")
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


@dataclass
class Submap:
    """A probability grid in the local-SLAM frame, anchored at one node."""

    anchor: int
    grid: ProbabilityGrid
    nodes: list[int] = field(default_factory=list)
    finished: bool = False


@dataclass
class LoopClosure:
    """An accepted loop closure: ``node`` matched in ``submap`` (anchored at
    ``anchor``) with ``score``, placing the node at ``delta`` in the anchor's frame."""

    node: int
    submap: int
    anchor: int
    score: float
    delta: np.ndarray


@dataclass
class LoopMap:
    """What loop closure matches a node against: a (stitched) submap grid, on which the
    match is refined, and its precomputation grids for branch and bound."""

    grid: ProbabilityGrid
    search: PrecomputedGrid

    @cached_property
    def nbytes(self) -> int:
        """Memory held by the grids and the branch-and-bound stack (they do not change
        once made)."""
        return int(sum(v.nbytes for obj in (self.grid, self.search, self.search.grid)
                       for v in vars(obj).values()
                       if isinstance(v, np.ndarray) and v.flags.owndata))


def rotate_xy(v: np.ndarray, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def adaptive_voxel(xy: np.ndarray, max_points: int, voxel_m: float = 0.05) -> np.ndarray:
    """Down-sample with the smallest voxel (doubling from ``voxel_m``) that leaves at
    most ``max_points`` points (Hess et al.'s adaptive voxel filter)."""
    out, _ = voxel_downsample(xy, None, voxel_m)
    while len(out) > max_points:
        voxel_m *= 1.5
        out, _ = voxel_downsample(xy, None, voxel_m)
    return out


def tie(tied_at: np.ndarray, span_lo: np.ndarray, span_hi: np.ndarray, k: int,
        travel: float) -> None:
    """A closure at path length ``travel`` to submap ``k`` ties the trajectory to every
    submap ``j``, through the old trajectory between ``k`` and ``j``: as if it had been at
    ``j`` that much path earlier. ``tied_at[j]`` (in place) keeps the latest such tie;
    ``span_lo / span_hi`` are the path lengths of each submap's first and last nodes."""
    gap = np.maximum(0.0, np.maximum(span_lo - span_hi[k], span_lo[k] - span_hi))
    np.maximum(tied_at, travel - gap, out=tied_at)


@dataclass
class GraphSlam:
    """Feed scans with :meth:`process`; read :meth:`trajectory` and :meth:`map_poses`."""

    config: GraphSlamConfig = field(default_factory=GraphSlamConfig)
    seed: int = 0
    submaps: list[Submap] = field(default_factory=list)
    closures: list[LoopClosure] = field(default_factory=list)
    searches: int = 0
    degeneracies: list[float] = field(default_factory=list)
    # when a list: one (node, submap, outcome, score) per loop search -- why a loop did
    # or did not close. Outcome: "none" (nothing above loop_min_score), "refined",
    # "degenerate", "aliased" (failed that test), "pending" (awaits confirmation),
    # "inconsistent" (contradicts the pending one), "accepted" (with the pending match
    # it confirms, if any); score: the refined match's
    loop_log: list[tuple[int, int, str, float]] | None = None

    def __post_init__(self) -> None:
        cfg = self.config
        self.keyframes = Keyframes(cfg.map)
        self.graph = PoseGraph(cfg.graph)
        self.local: list[np.ndarray] = []  # node poses in the local-SLAM frame
        self.node_odom: list[np.ndarray] = []
        self.node_time: list[float] = []
        self.node_xy: list[np.ndarray] = []  # matching points (robot frame)
        self._node_scan: list[int] = []
        self._scan_node: list[int] = []
        self._scan_delta: list[np.ndarray] = []
        self.times: list[float] = []
        # every scan's points (down-sampled), intensities and odometry, for finish()
        self._scan_xy: list[np.ndarray] = []
        self._scan_inten: list[np.ndarray | None] = []
        self._scan_odom: list[np.ndarray] = []
        self._aligned: np.ndarray | None = None  # finish()'s poses of every scan
        self.alignment_matches = 0
        self._global = np.zeros((0, 3))
        self._loop_maps: dict[tuple[int, tuple[int, ...]], LoopMap] = {}
        self._last_closed: dict[int, int] = {}  # submap -> last node closed against it
        self._pending: dict[int, LoopClosure] = {}  # submap -> match awaiting confirmation
        self._prev: tuple[np.ndarray, np.ndarray | None] | None = None  # for alpha > 0
        self.rng = np.random.default_rng(self.seed)
        self._travel: list[float] = []  # path length (local frame) up to each node
        # per submap: the path lengths of its first and last nodes, and where the
        # trajectory was tied to it by a closure (GraphSlam.drift_path)
        self._span_lo = np.zeros(0)
        self._span_hi = np.zeros(0)
        self._tied_at = np.zeros(0)
        # per recent node: did the search beat the odometry by odometry_score_margin?
        self._search_won: deque[bool] = deque(maxlen=self.config.odometry_rate_nodes)
        self.odometry = OdometryCalibration(cfg.odometry_window, cfg.odometry_min_scale,
                                            cfg.odometry_knee)
        self._free_heading: float | None = None  # the last node's match without odometry
        # per node: that heading (nan: none), the odometry's, the model's summed variance
        self._heading_log: deque[tuple[float, float, float]] = deque(
            maxlen=cfg.odometry_lag + 1)

    # -- local SLAM ---------------------------------------------------------------------
    def active(self) -> list[Submap]:
        return [s for s in self.submaps if not s.finished][-2:]

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
        pts, _ = voxel_downsample(xy, None, cfg.match_voxel_m)
        lin, ang = window or (cfg.local_linear_window_m, cfg.local_angular_window_rad)
        start, score = correlative_search(grid, pts, predicted, lin, ang,
                                          cfg.search_translation_cost,
                                          cfg.search_rotation_cost)
        w = window_cells(lin, grid.resolution_m) * grid.resolution_m
        if cfg.local_escalation > 1 and np.max(np.abs(start[:2] - predicted[:2])) > w - 1e-6:
            # the best lies on the window's edge: the odometry may be farther off than
            # the window allows (fr079's odometry reads forward while the robot backs
            # up); a wider search's best replaces it if it fits clearly better
            wide, wide_score = correlative_search(
                grid, pts, predicted, cfg.local_escalation * lin, ang,
                cfg.search_translation_cost, cfg.search_rotation_cost)
            if wide_score > score + cfg.odometry_score_margin:
                start = wide
        r = refine(grid, pts, start, prior=start, translation_weight=cfg.translation_weight,
                   rotation_weight=cfg.rotation_weight)
        # the motion model's own sigmas against a scan weighed by its residuals; kept
        # unless the scan fits clearly better where the search alone puts it (an
        # odometry jump; how clearly: search_overrides_odometry)
        sig = self.odometry_sigmas(np.zeros(3) if u is None else u)
        if record:
            self._free_heading = (float(r.pose[2]) if r.score >= cfg.local_min_score
                                  else None)
        ro = refine(grid, pts, start, prior=predicted, occupied_weight=1.0,
                    translation_weight=1.0 / sig[0], rotation_weight=1.0 / sig[2],
                    residual_floor=cfg.local_residual_floor)
        if not self.search_overrides_odometry(r.score - ro.score, record):
            r = ro
        pose = r.pose
        if r.degeneracy() >= cfg.local_min_degeneracy:
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
        if not cfg.local_matching:
            return u
        last = len(self.local) - 1
        pose, score, _ = self.match_local(xy, compose(self.local[last], u), u, record=False,
                                          window=(cfg.track_linear_window_m,
                                                  cfg.track_angular_window_rad))
        return relative(self.local[last], pose) if score >= cfg.local_min_score else u

    def odometry_sigmas(self, u: np.ndarray) -> np.ndarray:
        """Sigmas (x, y, theta) of the odometry increment ``u``: the fixed model's, the
        heading's scaled by what :meth:`calibrate_odometry` has learned. The odometry
        edges and the local matches' odometry prior both use them."""
        sig = self.graph.odometry_sigmas(u)
        sig[2] *= self.odometry.scale
        return sig

    def calibrate_odometry(self, u: np.ndarray, free: float | None) -> None:
        """One residual for :class:`OdometryCalibration` at the node just added: the
        heading change the scan matches found over the last ``odometry_lag`` nodes
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
        if free is None or len(log) <= cfg.odometry_lag or np.isnan(then[0]):
            return
        e = wrap_angle((free - then[0]) - (log[-1][1] - then[1]))
        self.odometry.add(float(e) / np.sqrt(total - then[2]))

    def search_overrides_odometry(self, gain: float, record: bool = True) -> bool:
        """Whether the search's match, scoring ``gain`` more than the match held near
        the odometry, replaces it. The margin it must beat follows how often the scans
        have contradicted the odometry lately: ``odometry_score_margin`` when the search
        won at least ``odometry_noisy_rate`` of the last ``odometry_rate_nodes`` nodes
        by that margin (fr079's odometry, degrees off in every turn: 44 % of its nodes),
        rising linearly to ``odometry_quiet_margin`` when it never did (fr-clinic's,
        confirmed to a fraction of a degree: 2.5 %), so that one ambiguous scan in a
        doorway or an open hall cannot turn the map by degrees."""
        cfg = self.config
        won = gain > cfg.odometry_score_margin
        hist = self._search_won
        if record:
            hist.append(won)
        if not won:
            return False
        n = len(hist)
        rate = sum(hist) / n if n >= 10 else 1.0
        quiet = max(0.0, 1.0 - rate / cfg.odometry_noisy_rate)
        margin = cfg.odometry_score_margin + (cfg.odometry_quiet_margin
                                              - cfg.odometry_score_margin) * quiet
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

    def insert(self, node: int, xy: np.ndarray, misses: np.ndarray) -> None:
        """Insert the node's scan into the active submaps; start and finish submaps."""
        cfg = self.config
        act = self.active()
        if not act or len(act[-1].nodes) >= cfg.scans_per_submap // 2:
            self.submaps.append(Submap(node, ProbabilityGrid(cfg.submap)))
            travel = self._travel[node]
            self._span_lo = np.append(self._span_lo, travel)
            self._span_hi = np.append(self._span_hi, travel)
            self._tied_at = np.append(self._tied_at, -np.inf)
            act = self.active()
        pose = self.local[node]
        hits, miss = place(xy, pose), place(misses, pose) if len(misses) else None
        surface = None
        if cfg.submap_connect_gap_m is not None:
            joined, _ = connect_returns(xy, None, cfg.submap_connect_gap_m,
                                        0.5 * cfg.submap.resolution_m,
                                        cfg.submap_grazing_gap_m)
            surface = place(joined[len(xy):], pose)
        for s in act:
            s.grid.insert(pose[:2], hits, miss, surface)
            s.nodes.append(node)
        self._span_hi[len(self.submaps) - len(act):] = self._travel[node]
        for s in act:
            if len(s.nodes) >= cfg.scans_per_submap:
                s.finished = True
                s.grid = s.grid.cropped().frozen()

    # -- loop closure -------------------------------------------------------------------
    def loop_map(self, k: int, node: int) -> LoopMap:
        """Submap ``k`` stitched with its finished neighbours in time, ``loop_neighbours``
        on each side (none holding ``node``): all in the local-SLAM frame, where
        neighbours in time agree to within local SLAM's short-term drift. A scan
        returning after a long loop sees more of the place than the ~9 m of path one
        submap holds; on fr-clinic its match against the one submap scored 0.23-0.38
        where the right place was, below any threshold that rejects false matches."""
        n = self.config.loop_neighbours
        ks = tuple(j for j in range(k - n, k + n + 1) if 0 <= j < len(self.submaps)
                   and self.submaps[j].finished and node not in self.submaps[j].nodes)
        key = (k, ks)
        lm = self._loop_maps.pop(key, None)
        if lm is None:
            grid = ProbabilityGrid.stitched([self.submaps[j].grid for j in ks])
            lm = LoopMap(grid, PrecomputedGrid(grid.coarsened(self.config.loop_coarsen),
                                               self.config.loop_depth))
        self._loop_maps[key] = lm  # most recently used last
        budget = self.config.loop_cache_mb * 2**20
        held = sum(m.nbytes for m in self._loop_maps.values())
        while len(self._loop_maps) > 1 and (len(self._loop_maps) > self.config.loop_cache
                                            or held > budget):
            held -= self._loop_maps.pop(next(iter(self._loop_maps))).nbytes
        return lm

    def search_loops(self, node: int) -> int:
        """Branch-and-bound matches of ``node`` against the finished submaps near it
        (Hess et al. §V); accepted matches become robust edges. Returns how many."""
        cfg = self.config
        g = self._global
        pts = adaptive_voxel(self.node_xy[node], cfg.loop_max_points)
        found = 0
        near = []
        # the longer the path since the trajectory was tied to a submap, the farther the
        # estimate may have drifted from it: the radius and the window grow with it
        grow, grow_rad = {}, {}
        for k, s in enumerate(self.submaps):
            if not s.finished or node in s.nodes:
                continue
            since = self.drift_path(node, k)
            grow[k] = min(cfg.loop_window_growth * since, cfg.loop_max_growth_m)
            grow_rad[k] = min(cfg.loop_window_growth_rad * since,
                              np.pi - cfg.loop_angular_window_rad)
            d = float(np.hypot(*(g[s.anchor, :2] - g[node, :2])))
            if d <= cfg.loop_max_distance_m + grow[k]:
                near.append((d, k))
        wide = 0
        jobs = []
        for _, k in sorted(near):
            s = self.submaps[k]
            a = s.anchor
            tracking = node - self._last_closed.get(k, -10**9) <= cfg.loop_track_nodes
            if not tracking:
                if wide >= cfg.loop_max_submaps:
                    continue
                # stitched grids overlap: each search round takes every (n+1)-th
                # submap in turn, whose grids still cover all of them
                stride = cfg.loop_neighbours + 1
                if k % stride != (node // cfg.loop_every) % stride:
                    continue
                wide += 1
            # the node's pose in the submap's (local-SLAM) frame, from the global estimate
            guess = compose(self.local[a], relative(g[a], g[node]))
            near_m = (cfg.loop_near_window_m + cfg.loop_near_rate
                      * (self._travel[node] - self._span_hi[k]))
            lin, ang = ((cfg.loop_track_linear_window_m, cfg.loop_track_angular_window_rad)
                        if tracking else (min(cfg.loop_linear_window_m + grow[k], near_m),
                                          cfg.loop_angular_window_rad + grow_rad[k]))
            jobs.append((k, a, tracking, guess, lin, ang))
        self.searches += len(jobs)
        # the branch-and-bound searches are independent of each other (and release the
        # GIL): a few at a time run side by side (a few, so that no more stitched grids
        # are alive than the cache holds), then their matches are judged in order
        step = 4 * cfg.loop_threads
        for lo in range(0, len(jobs), step):
            chunk = [(*j, self.loop_map(j[0], node)) for j in jobs[lo:lo + step]]
            matches = thread_map(lambda j: j[6].search.match(pts, j[3], j[4], j[5],
                                                             cfg.loop_min_score,
                                                             cfg.loop_angular_step_rad),
                                 chunk, cfg.loop_threads)
            for (k, a, tracking, guess, lin, ang, lm), m in zip(chunk, matches, strict=True):
                found += self._judge(node, pts, k, a, tracking, guess, lin, ang, lm, m)
        return found

    def _judge(self, node: int, pts: np.ndarray, k: int, a: int, tracking: bool,
               guess: np.ndarray, lin: float, ang: float, lm: LoopMap,
               m: Match | None) -> int:
        """Whether branch and bound's match ``m`` of ``node`` against submap ``k``
        (anchor ``a``) becomes a closure: refined, not degenerate, and -- for a first
        match against the submap -- unique in its window and confirmed by a nearby
        node's. Returns how many closures it accepted (0-2)."""
        cfg = self.config
        pre = lm.search
        if m is None:
            self._log(node, k, "none", 0.0)
            return 0
        r = refine(lm.grid, self.node_xy[node], m.pose, prior=m.pose,
                   translation_weight=cfg.translation_weight,
                   rotation_weight=cfg.rotation_weight)
        self.degeneracies.append(r.degeneracy())
        if r.score < cfg.loop_min_refined_score:
            self._log(node, k, "refined", r.score)
            return 0  # refined off the peak
        if r.degeneracy() < cfg.loop_min_degeneracy:
            self._log(node, k, "degenerate", r.score)
            return 0  # e.g. a plain corridor: the match cannot say where along it
            # the scan belongs
        delta = relative(self.local[a], r.pose)
        c = LoopClosure(node, k, a, r.score, delta)
        if not tracking:
            # a first match against this submap must be unique in its window and be
            # confirmed by another one from a nearby node that moves the trajectory
            # the same way (perceptual aliasing rarely repeats consistently); the
            # confirming match needs no uniqueness test of its own, and may be one
            # against an overlapping stitched neighbour (the corrections are
            # compared in the world, whichever submap made them)
            nb = cfg.loop_neighbours
            fresh = [j for j in range(k - nb, k + nb + 1) if j in self._pending
                     and node - self._pending[j].node <= cfg.loop_verify_nodes]
            pk = max(fresh, key=lambda j: self._pending[j].node, default=None)
            if pk is None or not self._consistent(self._pending[pk], c):
                if cfg.loop_unique_m > 0 and pre.second_score(
                        pts, guess, lin, ang, m, cfg.loop_unique_m,
                        cfg.loop_unique_ratio, cfg.loop_angular_step_rad) > 0:
                    self._log(node, k, "aliased", r.score)
                    return 0  # the scan fits two places in the window (aliasing)
                self._pending[k] = c
                self._log(node, k, "inconsistent" if fresh else "pending", r.score)
                return 0
            # both accepted: neither may pend again
            self._accept(self._pending.pop(pk))
        self._accept(c)
        self._log(node, k, "accepted", r.score)
        return 1 if tracking else 2

    def _log(self, node: int, submap: int, outcome: str, score: float) -> None:
        if self.loop_log is not None:
            self.loop_log.append((node, submap, outcome, score))

    def _correction(self, c: LoopClosure) -> np.ndarray:
        """The world-frame transform that moves the node to where the closure puts it."""
        g = self._global
        implied = compose(g[c.anchor], c.delta)
        return compose(implied, invert(g[c.node]))

    def _consistent(self, a: LoopClosure, b: LoopClosure) -> bool:
        """Whether the two closures move node ``b`` (the later one) to the same place:
        their corrections compared where they act, not at the world's origin (far from
        it, a heading difference alone would move the origin by metres)."""
        here = self._global[b.node]
        d = relative(compose(self._correction(a), here), compose(self._correction(b), here))
        cfg = self.config
        return bool(np.hypot(d[0], d[1]) <= cfg.loop_verify_m
                    and abs(d[2]) <= cfg.loop_verify_rad)

    def _accept(self, c: LoopClosure) -> None:
        self.graph.add_loop(c.anchor, c.node, c.delta)
        self.closures.append(c)
        self._last_closed[c.submap] = c.node
        tie(self._tied_at, self._span_lo, self._span_hi, c.submap, self._travel[c.node])

    def drift_path(self, node: int, k: int) -> float:
        """The path (m) along which local SLAM may have drifted between ``node`` and
        submap ``k``: from where the trajectory was last tied to ``k`` -- when it left
        the submap, or at a closure, the closure's own submap that much path away from
        ``k`` along the old trajectory. A closure to a submap just built (a small loop)
        ties the node to the recent past only, not to a submap left long ago (until
        session 28 any closure restarted the drift of every submap; the change moved
        fr-clinic from 0.113 to 0.112 m and no other log or office, and it does not
        rescue fr-clinic's runs with perturbed odometry:
        docs/notes/slam-graph-unseen.md, session 28)."""
        return self._travel[node] - max(float(self._tied_at[k]), float(self._span_hi[k]))

    # -- driver -------------------------------------------------------------------------
    def process(self, scan: Scan) -> None:
        xy, inten = scan.points()
        self.times.append(scan.t)
        cfg = self.config
        self._aligned = None  # a new scan: the online estimate is current again
        pts, pin = voxel_downsample(xy, inten, cfg.match_voxel_m)  # a node's, and finish()'s
        if cfg.alignment is not None:
            self._scan_xy.append(pts)
            self._scan_inten.append(pin)
            self._scan_odom.append(scan.odom.copy())
        if not self.local:
            self._add_node(scan, scan.odom.copy(), scan.odom.copy(), xy, inten, pts)
            return
        last = len(self.local) - 1
        u = relative(self.node_odom[last], scan.odom)
        if (len(xy) < 8 or not (moved(self.node_odom[last], scan.odom, cfg.node_linear_m,
                                      cfg.node_angular_rad)
                                or scan.t - self.node_time[last] >= cfg.node_time_s)):
            self._scan_node.append(last)
            self._scan_delta.append(self.track(xy, u) if len(xy) >= 8 else u)
            return
        predicted = compose(self.local[last], u)
        pose, score, weak = predicted, 0.0, None
        if cfg.local_matching:
            pose, score, weak = self.match_local(xy, predicted, u)
        if score < cfg.local_min_score:
            pose, weak = predicted, None
        elif cfg.alpha > 0:
            pose = self.intensity_step(pose, xy, inten)
        delta = relative(self.local[last], pose)
        node = self._add_node(scan, pose, compose(self._global[last], delta), xy, inten, pts)
        if score >= cfg.local_min_score:  # else odometry alone links the nodes
            self.graph.add_local(last, node, delta, None if weak is None
                                 else rotate_xy(weak, -self.local[last][2]))
        self.graph.add_odometry(last, node, u, self.odometry_sigmas(u))
        self.calibrate_odometry(u, self._free_heading if cfg.local_matching else None)
        if node % cfg.loop_every == 0 and self.search_loops(node):
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
        self.node_xy.append(pts)
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

    # -- the end of a run ------------------------------------------------------------
    def finish(self) -> int:
        """Global scan alignment (:mod:`numeric.slam.scan_alignment`) of every scan so
        far, from the online estimate; until the next scan arrives, the trajectory,
        the pose and the map's poses are the aligned ones. Returns how many pairwise
        matches held (0 when alignment is off)."""
        cfg = self.config.alignment
        if cfg is None or len(self.times) < 2:
            return 0
        if self._aligned is not None:
            return self.alignment_matches
        _, poses = self._online_trajectory()
        closures = [(self._node_scan[c.anchor], self._node_scan[c.node], c.delta)
                    for c in self.closures]
        if self.config.alpha > 0 and cfg.alpha == 0:
            cfg = cfg.model_copy(update={"alpha": self.config.alpha})
        self._aligned, self.alignment_matches = align_scans(
            self._scan_xy, self._scan_inten, poses, np.array(self._scan_odom), closures, cfg,
            self.config.graph)
        return self.alignment_matches

    @property
    def aligned(self) -> bool:
        """Whether the outputs are finish()'s aligned poses."""
        return self._aligned is not None

    # -- outputs ------------------------------------------------------------------------
    @property
    def pose(self) -> np.ndarray:
        """The latest scan's pose on iSAM2's current estimate of its node: the pose the
        trajectory ends with."""
        if self._aligned is not None:
            return self._aligned[-1].copy()
        if not self._scan_node:
            return np.zeros(3)
        return compose(self.graph.pose_of(self._scan_node[-1]), self._scan_delta[-1])

    def optimise(self) -> np.ndarray:
        """iSAM2's current estimate of every node ``(N, 3)``. Reading it changes nothing:
        the loop-closure search keeps its own estimate, so a run fed the same scans
        ends the same whether or not (and how often) it was read in between."""
        return self.graph.poses_now()

    def trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        if self._aligned is not None:
            return np.array(self.times), self._aligned.copy()
        return self._online_trajectory()

    def _online_trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        g = self.optimise()
        poses = compose(g[np.array(self._scan_node)], np.array(self._scan_delta))
        return np.array(self.times), np.asarray(poses).reshape(-1, 3)

    def map_poses(self) -> np.ndarray:
        """Optimised poses ``(K, 3)`` of the nodes (the keyframes of the map); after
        :meth:`finish`, their scans' aligned poses."""
        if self._aligned is not None:
            return self._aligned[np.array(self._node_scan)]
        return self.optimise().copy()

    def loop_closures(self) -> list[tuple[int, int, float]]:
        """The accepted closures as ``(scan of the submap's anchor, scan matched,
        score)``, scan indices counted from 0 in the order the scans came."""
        return [(self._node_scan[c.anchor], self._node_scan[c.node], c.score)
                for c in self.closures]
