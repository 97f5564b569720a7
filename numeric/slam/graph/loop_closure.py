"""Loop closure (Hess et al. 2016, §V): every ``every``-th node is matched by branch and
bound against the finished submaps within ``max_distance_m`` of it -- each stitched with
its ``neighbours`` neighbours in time on both sides, and, those grids overlapping, every
``neighbours + 1``-th of them per search in turn -- in a window of ``linear_window_m`` /
``angular_window_rad``, both growing with the path along which local SLAM may have
drifted from that submap (:meth:`LoopClosing.drift_path`), the linear one at most
``near_window_m`` plus ``near_rate`` times the path since the submap was left. A match
above ``min_score`` with no second pose as good beyond ``unique_m`` in the window (a
scan that fits two places says nothing about which), refined by Gauss-Newton to above
``min_refined_score``, becomes a robust between-edge from the submap's anchor node
once a nearby node's match moves that node the same way (the confirming match needs no
uniqueness test). The drift bound on the window is what holds in a building of
identical rooms and evenly spaced doors, where uniqueness and confirmation both pass an
aliased place.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from chizu.numeric.geometry import compose, invert, relative
from chizu.numeric.slam.graph.config import GraphSlamConfig
from chizu.numeric.slam.graph.submaps import LoopMap, ObservedCells, Submap
from chizu.numeric.slam.keyframes import voxel_downsample
from chizu.numeric.slam.matching.correlative import Match, refine
from chizu.numeric.slam.pose_graph import PoseGraph
from chizu.numeric.threads import thread_map


@dataclass
class LoopClosure:
    """An accepted loop closure: ``node`` matched in ``submap`` (anchored at
    ``anchor``) with ``score``, placing the node at ``delta`` in the anchor's frame."""

    node: int
    submap: int
    anchor: int
    score: float
    delta: np.ndarray


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


class LoopClosing:
    """The loop-closure steps of :class:`~chizu.numeric.slam.graph.slam.GraphSlam`."""

    config: GraphSlamConfig
    submaps: list[Submap]
    closures: list[LoopClosure]
    graph: PoseGraph
    local: list[np.ndarray]
    searches: int
    degeneracies: list[float]
    loop_log: list[tuple[int, int, str, float]] | None
    _global: np.ndarray
    _travel: list[float]
    _span_lo: np.ndarray
    _span_hi: np.ndarray
    _tied_at: np.ndarray
    _last_closed: dict[int, int]
    _pending: dict[int, LoopClosure]
    _loop_maps: dict[tuple[int, tuple[int, ...]], LoopMap]
    _cells: dict[int, ObservedCells]

    if TYPE_CHECKING:
        def loop_map(self, k: int, node: int) -> LoopMap: ...

    def start_loops(self) -> None:
        """The empty pose graph, submaps and loop-closure state of a new run (the
        submaps, closures and search counts are the estimator's own fields)."""
        self.graph = PoseGraph(self.config.graph)
        self.local = []  # node poses in the local-SLAM frame
        self._global = np.zeros((0, 3))
        self._loop_maps = {}
        self._cells = {}
        self._last_closed = {}  # submap -> last node closed against it
        self._pending = {}  # submap -> match awaiting confirmation
        self._travel = []  # path length (local frame) up to each node
        # per submap: the path lengths of its first and last nodes, and where the
        # trajectory was tied to it by a closure (drift_path)
        self._span_lo = np.zeros(0)
        self._span_hi = np.zeros(0)
        self._tied_at = np.zeros(0)

    def search_loops(self, node: int, xy: np.ndarray) -> int:
        """Branch-and-bound matches of ``node`` (its returns ``xy``, robot frame)
        against the finished submaps near it (Hess et al. §V); accepted matches become
        robust edges. Returns how many."""
        cfg = self.config
        g = self._global
        pts = adaptive_voxel(xy, cfg.loop.max_points)
        found = 0
        near = []
        # the longer the path since the trajectory was tied to a submap, the farther the
        # estimate may have drifted from it: the radius and the window grow with it
        grow, grow_rad = {}, {}
        for k, s in enumerate(self.submaps):
            if not s.finished or s.trimmed or node in s.nodes:
                continue
            since = self.drift_path(node, k)
            grow[k] = min(cfg.loop.window_growth * since, cfg.loop.max_growth_m)
            grow_rad[k] = min(cfg.loop.window_growth_rad * since,
                              np.pi - cfg.loop.angular_window_rad)
            d = float(np.hypot(*(g[s.anchor, :2] - g[node, :2])))
            if d <= cfg.loop.max_distance_m + grow[k]:
                near.append((d, k))
        wide = 0
        jobs = []
        for _, k in sorted(near):
            s = self.submaps[k]
            a = s.anchor
            tracking = node - self._last_closed.get(k, -10**9) <= cfg.loop.track_nodes
            if not tracking:
                if wide >= cfg.loop.max_submaps:
                    continue
                # stitched grids overlap: each search round takes every (n+1)-th
                # submap in turn, whose grids still cover all of them
                stride = cfg.loop.neighbours + 1
                if k % stride != (node // (cfg.loop.every or 1)) % stride:
                    continue
                wide += 1
            # the node's pose in the submap's (local-SLAM) frame, from the global estimate
            guess = compose(self.local[a], relative(g[a], g[node]))
            near_m = (cfg.loop.near_window_m + cfg.loop.near_rate
                      * (self._travel[node] - self._span_hi[k]))
            lin, ang = ((cfg.loop.track_linear_window_m, cfg.loop.track_angular_window_rad)
                        if tracking else (min(cfg.loop.linear_window_m + grow[k], near_m),
                                          cfg.loop.angular_window_rad + grow_rad[k]))
            jobs.append((k, a, tracking, guess, lin, ang))
        self.searches += len(jobs)
        # the branch-and-bound searches are independent of each other (and release the
        # GIL): a few at a time run side by side (a few, so that no more stitched grids
        # are alive than the cache holds), then their matches are judged in order
        step = 4 * cfg.loop.threads
        for lo in range(0, len(jobs), step):
            chunk = [(*j, self.loop_map(j[0], node)) for j in jobs[lo:lo + step]]
            matches = thread_map(lambda j: j[6].search.match(pts, j[3], j[4], j[5],
                                                             cfg.loop.min_score,
                                                             cfg.loop.angular_step_rad),
                                 chunk, cfg.loop.threads)
            for (k, a, tracking, guess, lin, ang, lm), m in zip(chunk, matches, strict=True):
                found += self._judge(node, xy, pts, k, a, tracking, guess, lin, ang, lm, m)
        return found

    def _judge(self, node: int, xy: np.ndarray, pts: np.ndarray, k: int, a: int,
               tracking: bool, guess: np.ndarray, lin: float, ang: float, lm: LoopMap,
               m: Match | None) -> int:
        """Whether branch and bound's match ``m`` of ``node`` (returns ``xy``; ``pts``
        those searched with) against submap ``k`` (anchor ``a``) becomes a closure:
        refined, not degenerate, and -- for a first match against the submap -- unique
        in its window and confirmed by a nearby node's. Returns how many closures it
        accepted (0-2)."""
        cfg = self.config
        pre = lm.search
        if m is None:
            self._log(node, k, "none", 0.0)
            return 0
        r = refine(lm.grid, xy, m.pose, prior=m.pose,
                   translation_weight=cfg.local.translation_weight,
                   rotation_weight=cfg.local.rotation_weight)
        self.degeneracies.append(r.degeneracy())
        if r.score < cfg.loop.min_refined_score:
            self._log(node, k, "refined", r.score)
            return 0  # refined off the peak
        if r.degeneracy() < cfg.loop.min_degeneracy:
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
            nb = cfg.loop.neighbours
            fresh = [j for j in range(k - nb, k + nb + 1) if j in self._pending
                     and node - self._pending[j].node <= cfg.loop.verify_nodes]
            pk = max(fresh, key=lambda j: self._pending[j].node, default=None)
            if pk is None or not self._consistent(self._pending[pk], c):
                if cfg.loop.unique_m > 0 and pre.second_score(
                        pts, guess, lin, ang, m, cfg.loop.unique_m,
                        cfg.loop.unique_ratio, cfg.loop.angular_step_rad) > 0:
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
        return bool(np.hypot(d[0], d[1]) <= cfg.loop.verify_m
                    and abs(d[2]) <= cfg.loop.verify_rad)

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
        ties the node to the recent past only, not to a submap left long ago."""
        return self._travel[node] - max(float(self._tied_at[k]), float(self._span_hi[k]))
