"""One map from two: resuming a saved map with a new log, and merging two saved maps of
one building made in unrelated frames (as Cartographer joins trajectories, Hess et al.
2016 §V, and slam_toolbox merges and continues its serialized maps).

Both are the same four steps on a first map A and a second run B (a new log mapped by
graph SLAM on its own, or a second saved map):

1. **Where B lies in A** (:func:`frame_transform`): global localization on A
   (:mod:`chizu.numeric.slam.map_localization`, step 2: branch and bound over the whole map and
   every heading, with its uniqueness test) of B's keyframes, each with the returns of
   B's keyframes within ``context_m`` of travel around it placed by B's own poses. Each
   unique fix scoring ``min_score`` is a transform from B's frame to A's; the one the
   most fixes agree with (within ``agree_m`` and ``agree_rad`` where both were found) is
   taken, and at least ``min_agree`` must, spread over more than ``context_m`` of B's
   travel (half of it, when B is shorter than twice that; B standing still has nothing
   to spread over): neighbouring keyframes' contexts are mostly the same scans, and
   their fixes one piece of evidence, not several (a corridor seen turned round fits
   them all alike). No fix counts alone, so a fix may score less than map localization
   asks of the one it acts on. Without such agreement the maps share no place that
   tells where: refused (field ``map``).
2. **One pose graph, its loops closed** (:class:`JoinedMaps`): A's keyframes are graph
   SLAM's nodes again, inserted into submaps at A's poses as A's run built them; B's
   keyframes follow, placed by that transform, the first held there loosely; each map's
   own constraints bind its keyframes at rest where the map has them (their covariances
   say how stiff the map is). Then B's keyframes are searched against A's submaps by
   graph SLAM's own loop closure (Hess et al. §V; :mod:`~chizu.numeric.slam.graph.loop_closure`:
   the same windows growing with the path since the trajectory was tied to a submap,
   uniqueness and confirmation), as the nodes of a run that continued A's would be, B's
   first keyframe tied where it was found. One transform is not enough where the two runs
   drifted differently, and a place A passed twice without closing the loop (two versions
   of it, a metre apart) is pulled together only by matches to each version apart.
3. **One alignment** (:func:`aligned`): graph SLAM's end-of-run scan alignment (Lu &
   Milios 1997) over both maps' keyframes, with both maps' loops and the new closures.
4. **The merged map** (:func:`merged`): both maps' keyframes at their aligned poses
   (every scan moved with the keyframe it follows), both runs' constraints, and the
   closures as loop constraints between A's submap anchors and B's keyframes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from chizu.numeric.errors import InvalidInput
from chizu.numeric.geometry import compose, invert, place, relative, wrap_angle
from chizu.numeric.slam.alignment import AlignmentConfig, align_globally, pairwise_matches
from chizu.numeric.slam.graph.config import GraphSlamConfig
from chizu.numeric.slam.graph.loop_closure import LoopClosing, LoopClosure, tie
from chizu.numeric.slam.graph.submaps import Submap, Submaps
from chizu.numeric.slam.keyframes import voxel_downsample
from chizu.numeric.slam.map_localization import MapLocalizationConfig, PreparedMap
from chizu.numeric.slam.saved_map import EDGE_KINDS, Constraints, SavedMap


class MergeConfig(BaseModel):
    """The steps' parameters (m, rad); one set for every pair of maps."""

    model_config = ConfigDict(extra="forbid")
    context_m: float = Field(10.0, ge=0.0, description="a keyframe is searched for with "
                             "the returns of this much of B's travel around it")
    searches: int = Field(60, ge=1, le=10_000, description="B's keyframes searched for, "
                          "at most (spread evenly)")
    min_score: float = Field(0.4, gt=0.0, lt=1.0, description="a keyframe's fix scores at "
                             "least this (no fix is taken alone: min_agree must agree)")
    agree_m: float = Field(0.5, gt=0.0, description="two fixes agree on the transform "
                           "within this distance at both fixes' keyframes ...")
    agree_rad: float = Field(0.05, gt=0.0, le=math.pi, description="... and this angle")
    min_agree: int = Field(3, ge=2, description="fixes that must agree, spread over "
                           "more than ``context_m`` of travel (half of B's, if less)")
    placed_sigma_m: float = Field(1.0, gt=0.0, description="B's first keyframe is held "
                                  "where step 1 placed it with this sigma ...")
    placed_sigma_rad: float = Field(0.1, gt=0.0, description="... and this one")


@dataclass(frozen=True)
class Placement:
    """Where B's frame lies in A's (``transform``: B's origin in A's frame), and from
    how many of the searched keyframes' fixes that agree (``agree`` of ``searched``,
    ``fixes`` unique ones)."""

    transform: np.ndarray
    agree: int
    fixes: int
    searched: int


def _travel(kf_pose: np.ndarray) -> np.ndarray:
    """Each keyframe's distance travelled since the first (by B's own poses)."""
    return np.cumsum(np.r_[0.0, np.hypot(*np.diff(kf_pose[:, :2], axis=0).T)])


def _context(kf_xy: list[np.ndarray], kf_pose: np.ndarray, travel: np.ndarray, k: int,
             context_m: float) -> np.ndarray:
    """Keyframe ``k``'s returns with those of the keyframes within ``context_m`` of
    travel (``travel``: :func:`_travel`) before and after it, in ``k``'s frame (placed
    by B's own poses)."""
    near = np.flatnonzero(np.abs(travel - travel[k]) <= context_m)
    return np.vstack([place(kf_xy[j], relative(kf_pose[k], kf_pose[j])) for j in near])


def frame_transform(a: PreparedMap, kf_xy: list[np.ndarray], kf_pose: np.ndarray,
                    config: MergeConfig) -> Placement:
    """Step 1: B's frame in A's, from B's keyframes (robot-frame returns ``kf_xy``, poses
    ``kf_pose`` in B's frame). Raises :class:`InvalidInput` (field ``map``) when too few
    fixes agree."""
    have = np.flatnonzero([len(x) for x in kf_xy])  # a lifelong run forgets some
    n = len(have)
    picks = have[np.unique(np.linspace(0, n - 1, min(n, config.searches)).round().astype(int))
                 ] if n else np.zeros(0, dtype=int)
    travel = _travel(kf_pose)
    found: list[tuple[np.ndarray, int]] = []  # (transform, keyframe)
    for k in picks:
        m = a.globally.fix(_context(kf_xy, kf_pose, travel, int(k), config.context_m),
                           config.min_score)
        if m is not None:
            found.append((compose(np.asarray(m.pose), invert(kf_pose[k])), int(k)))
    spread = min(config.context_m, float(travel[-1]) / 2)
    agreeing: list[tuple[np.ndarray, int]] = []  # the best transform's, its own among them
    for t in found:
        them = [u for u in found if _agrees(t, u, kf_pose, config)]
        at = travel[[u[1] for u in them]]
        if (at.max() - at.min() > spread or spread == 0.0) and len(them) > len(agreeing):
            agreeing = them
    support = len(agreeing)
    if support < config.min_agree:
        raise InvalidInput(
            f"the maps share no place that says where one lies in the other: of "
            f"{len(picks)} places searched for, {len(found)} were found uniquely and at most "
            f"{support} agree over more than {spread:.3g} m of travel "
            f"({config.min_agree} needed)", field="map")
    # the agreeing fixes' mean transform (headings averaged on the circle)
    ts = np.array([u[0] for u in agreeing])
    mean = np.array([ts[:, 0].mean(), ts[:, 1].mean(),
                     math.atan2(np.sin(ts[:, 2]).mean(), np.cos(ts[:, 2]).mean())])
    return Placement(mean, support, len(found), len(picks))


def _agrees(t: tuple[np.ndarray, int], u: tuple[np.ndarray, int], kf_pose: np.ndarray,
            cfg: MergeConfig) -> bool:
    """Whether two fixes' transforms (each with the keyframe it was found from) put both
    keyframes within ``agree_m`` of each other and turn them by the same heading within
    ``agree_rad``. Compared where the fixes were made, not over all of B: B's own map
    bends a little along hundreds of metres, and its far ends would part two right
    fixes."""
    if abs(float(wrap_angle(t[0][2] - u[0][2]))) > cfg.agree_rad:
        return False
    at = kf_pose[[t[1], u[1]]]
    d = compose(t[0], at)[:, :2] - compose(u[0], at)[:, :2]
    return bool(np.hypot(*d.T).max() <= cfg.agree_m)


class JoinedMaps(Submaps, LoopClosing):
    """Step 2: graph SLAM's submaps, pose graph and loop closure over the keyframes of
    two saved maps (:meth:`add_map` A, then B, then :meth:`close_loops`)."""

    submaps: list[Submap]
    closures: list[LoopClosure]

    def __init__(self) -> None:
        cfg = GraphSlamConfig()
        cfg.submaps.trim_share = None  # both maps are kept whole
        self.config = cfg
        self.loop_log = None
        self.submaps, self.closures = [], []
        self.searches, self.degeneracies = 0, []
        self.start_loops()

    def add_map(self, saved: SavedMap, poses: np.ndarray, into_submaps: bool) -> int:
        """``saved``'s keyframes as nodes at ``poses`` (in this graph's frame), bound by
        its constraints at rest there; with ``into_submaps`` their returns are inserted
        into submaps (all finished at the end: what later nodes are searched against).
        Returns the first node."""
        first = len(self.local)
        travel = self._travel[-1] if self._travel else 0.0
        for k, p in enumerate(poses):
            if k:
                travel += float(np.hypot(*(p[:2] - poses[k - 1][:2])))
            self._travel.append(travel)
            self.local.append(p.copy())
            self.graph.add_node(p)
            if into_submaps and len(saved.kf_xy[k]):
                self.insert(first + k, saved.kf_xy[k], saved.kf_misses[k])
        self._global = np.vstack([self._global, poses])
        for s in self.active():
            s.finish()
        c = constraints_of(saved)
        for a, b, d, cov, kind in zip(c.a, c.b, relative(poses[c.a], poses[c.b]), c.cov,
                                      c.kind, strict=True):
            self.graph.add_constraint(first + int(a), first + int(b), d, cov, int(kind))
        return first

    def close_loops(self, first: int, pts: list[np.ndarray], sigmas: np.ndarray) -> None:
        """The nodes from ``first`` on (returns ``pts``, robot frame, down-sampled to
        local SLAM's voxel) searched against the submaps as graph SLAM searches its
        nodes, every ``loop.every``-th; the first held where it was placed with
        ``sigmas`` and tied to the submap it lies in."""
        p0 = self._global[first]
        near = int(np.argmin(np.hypot(*(self._global[:first, :2] - p0[:2]).T)))
        for k, s in enumerate(self.submaps):
            if near in s.nodes:
                tie(self._tied_at, self._span_lo, self._span_hi, k, self._travel[first])
        self.graph.add_prior(first, p0, sigmas)
        self.graph.update()
        self._global = self.graph.poses_now()
        every = self.config.loop.every or 1
        for j, xy in enumerate(pts):
            node = first + j
            if node % every or len(xy) < 8:
                continue
            if self.search_loops(node, xy):
                self.graph.update()
                self._global = self.graph.estimate()


def constraints_of(m: SavedMap) -> Constraints:
    """A map's pose-graph constraints; a map of an estimator that kept no pose graph (the
    RBPF, gated SLAM) is bound by its odometry between consecutive keyframes, with the
    odometry model's sigmas."""
    if len(m.constraints) or len(m) < 2:
        return m.constraints
    d = relative(m.kf_odom[:-1], m.kf_odom[1:])
    sig = GraphSlamConfig().graph.odometry_sigmas(d)
    cov = np.zeros((len(d), 3, 3))
    cov[:, [0, 1, 2], [0, 1, 2]] = sig**2
    k = np.arange(len(d), dtype=np.int64)
    return Constraints(k, k + 1, d, cov, np.full(len(d), EDGE_KINDS.index("odometry"),
                                                 dtype=np.int8))


def _joined(a: SavedMap, b: SavedMap, cfg: MergeConfig,
            localization: MapLocalizationConfig | None
            ) -> tuple[Placement, np.ndarray, np.ndarray, list[LoopClosure]]:
    """Steps 1-3 for B: where it lies in A, both maps' keyframe poses in A's frame, and
    the closures between them. Another laser than A's is refused (field ``map``)."""
    why = a.laser.compatible(b.laser)
    if why is not None:
        raise InvalidInput(why, field="map")
    prepared = PreparedMap.of(a, localization or MapLocalizationConfig())
    placed = frame_transform(prepared, b.kf_xy, b.kf_pose, cfg)
    g = JoinedMaps()
    g.add_map(a, a.kf_pose, into_submaps=True)
    first = g.add_map(b, compose(placed.transform, b.kf_pose), into_submaps=False)
    sigmas = np.array([cfg.placed_sigma_m, cfg.placed_sigma_m, cfg.placed_sigma_rad])
    # every keyframe's returns at local SLAM's voxel, as graph SLAM keeps a node's for
    # its loop search (step 2) and for the end-of-run alignment (step 3)
    pts = [voxel_downsample(xy, None, g.config.local.voxel_m)[0] for xy in a.kf_xy + b.kf_xy]
    g.close_loops(first, pts[first:], sigmas)
    poses = aligned(a, b, pts, g.graph.poses_now(), g.closures, g.config, sigmas)
    return placed, poses[:first], poses[first:], g.closures


def aligned(a: SavedMap, b: SavedMap, pts: list[np.ndarray], poses: np.ndarray,
            closures: list[LoopClosure], config: GraphSlamConfig, sigmas: np.ndarray
            ) -> np.ndarray:
    """Step 3: graph SLAM's global scan alignment (Lu & Milios 1997,
    :mod:`chizu.numeric.slam.alignment`) of both maps' keyframes (returns ``pts``,
    down-sampled) from ``poses``, as a run ends: each matched to the keyframes it
    overlaps, of either map, with each run's odometry chain, both maps' loop constraints
    and the ``closures`` between them. Each
    run's first keyframe but A's first -- B's, and those of the runs a merged A already
    holds: a keyframe with no odometry edge from the one before -- starts an odometry
    chain of its own and is held loosely (``sigmas``) where step 2 put it."""
    held = len(a)
    acfg = config.alignment or AlignmentConfig()
    matches = pairwise_matches(pts, [None] * len(pts), poses, acfg)
    loop, odometry = EDGE_KINDS.index("loop"), EDGE_KINDS.index("odometry")
    edges = [(int(i) + off, int(j) + off, d, int(k))
             for c, off in ((constraints_of(a), 0), (constraints_of(b), held))
             for i, j, d, k in zip(c.a, c.b, c.delta, c.kind, strict=True)]
    chained = {j for i, j, _, k in edges if k == odometry and j == i + 1}
    starts = [k for k in range(1, len(poses)) if k not in chained]
    own = [(i, j, d) for i, j, d, k in edges if k == loop]
    cross = [(c.anchor, c.node, c.delta) for c in closures]
    cov = np.diag(sigmas**2)
    return align_globally(poses, np.vstack([a.kf_odom, b.kf_odom]), matches, own + cross,
                          acfg, config.graph, priors=[(k, poses[k], cov) for k in starts],
                          breaks=starts)


def resume(a: SavedMap, b: SavedMap, config: MergeConfig | None = None,
           localization: MapLocalizationConfig | None = None) -> tuple[SavedMap, np.ndarray]:
    """A saved map ``a`` continued with a log that graph SLAM mapped on its own into
    ``b``: the merged map, and the log's scans' poses in ``a``'s frame."""
    m, _ = merge(a, b, config, localization)
    return m, m.poses[len(a.poses):]


def merge(a: SavedMap, b: SavedMap, config: MergeConfig | None = None,
          localization: MapLocalizationConfig | None = None) -> tuple[SavedMap, Placement]:
    """Two saved maps of one building in unrelated frames as one, in ``a``'s frame."""
    placed, a_kf, b_kf, closures = _joined(a, b, config or MergeConfig(), localization)
    return merged(a, a_kf, b, b_kf, closures, placed), placed


def _follow(b: SavedMap, kf_poses: np.ndarray) -> np.ndarray:
    """Every scan of ``b`` moved with the keyframe it follows, to ``kf_poses``."""
    k = np.clip(np.searchsorted(b.kf_scan, np.arange(len(b.poses)), side="right") - 1, 0,
                len(b) - 1)
    return np.asarray(compose(kf_poses[k], relative(b.kf_pose[k], b.poses)))


def runs_of(m: SavedMap) -> list[str]:
    """The runs a map holds, by their sources (a map of one run: its own)."""
    runs = m.meta.get("runs")
    if isinstance(runs, list) and all(isinstance(r, str) for r in runs):
        return list(runs)
    return [str(m.meta.get("source", "a map"))]


def merged(a: SavedMap, a_kf: np.ndarray, b: SavedMap, b_kf: np.ndarray,
           closures: list[LoopClosure], placement: Placement) -> SavedMap:
    """Step 4: ``a``'s keyframes at ``a_kf`` and ``b``'s at ``b_kf`` (every scan moved
    with the keyframe it follows), both runs' constraints, and the ``closures`` (nodes
    numbered ``a``'s keyframes first) as loop constraints."""
    held = len(a)
    loop = EDGE_KINDS.index("loop")
    cov = np.diag(GraphSlamConfig().graph.loop_sigmas() ** 2)
    ca, cb = constraints_of(a), constraints_of(b)
    n = len(closures)
    cons = Constraints(
        np.concatenate([ca.a, cb.a + held, [c.anchor for c in closures]]).astype(np.int64),
        np.concatenate([ca.b, cb.b + held, [c.node for c in closures]]).astype(np.int64),
        np.vstack([ca.delta, cb.delta, *[c.delta[None] for c in closures]]).reshape(-1, 3),
        np.vstack([ca.cov, cb.cov, np.broadcast_to(cov, (n, 3, 3))]).reshape(-1, 3, 3),
        np.concatenate([ca.kind, cb.kind, np.full(n, loop)]).astype(np.int8))
    n_a = len(a.times)
    inten = (a.kf_intensity + b.kf_intensity
             if a.kf_intensity is not None and b.kf_intensity is not None else None)
    meta = {**a.meta, "runs": runs_of(a) + runs_of(b),
            "placement": {"transform": [round(float(v), 6) for v in placement.transform],
                          "agree": placement.agree, "fixes": placement.fixes,
                          "searched": placement.searched, "closures": n}}
    return SavedMap(
        laser=a.laser, resolution_m=a.resolution_m,
        kf_scan=np.concatenate([a.kf_scan, b.kf_scan + n_a]).astype(np.int64),
        kf_time=np.concatenate([a.kf_time, b.kf_time]),
        kf_pose=np.vstack([a_kf, b_kf]),
        kf_odom=np.vstack([a.kf_odom, b.kf_odom]),
        kf_xy=a.kf_xy + b.kf_xy, kf_intensity=inten, kf_misses=a.kf_misses + b.kf_misses,
        times=np.concatenate([a.times, b.times]),
        poses=np.vstack([_follow(a, a_kf), _follow(b, b_kf)]),
        constraints=cons, meta=meta)
