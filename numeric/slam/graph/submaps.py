"""Submaps (Hess et al. 2016, §III-B): probability grids in the local-SLAM frame, each
anchored at a node; a submap is finished after ``scans`` nodes and a new one starts
halfway, so two always overlap. A node's scan is inserted with the surface between
neighbouring returns (``connect_gap_m``: one scan of a wall seen at a slant in 1° steps
is otherwise a dotted line that moves with the robot, and the next scan fits it best
where the first was taken) and the collinear returns of a wall seen at grazing
incidence joined farther apart (``grazing_gap_m``), so that such a wall fixes a scan
across itself and leaves it free along it. Loop closure matches against a submap
stitched with its neighbours in time (:meth:`Submaps.loop_map`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from numeric.geometry import place
from numeric.probability_grid import ProbabilityGrid
from numeric.slam.graph.config import GraphSlamConfig
from numeric.slam.keyframes import connect_returns
from numeric.slam.matching.correlative import PrecomputedGrid


@dataclass
class Submap:
    """A probability grid in the local-SLAM frame, anchored at one node."""

    anchor: int
    grid: ProbabilityGrid
    nodes: list[int] = field(default_factory=list)
    finished: bool = False


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


class Submaps:
    """The submap steps of :class:`~numeric.slam.graph.slam.GraphSlam`."""

    config: GraphSlamConfig
    submaps: list[Submap]
    local: list[np.ndarray]
    _travel: list[float]
    _span_lo: np.ndarray
    _span_hi: np.ndarray
    _tied_at: np.ndarray
    _loop_maps: dict[tuple[int, tuple[int, ...]], LoopMap]

    def active(self) -> list[Submap]:
        """The (at most two) submaps scans are inserted into."""
        return [s for s in self.submaps if not s.finished][-2:]

    def insert(self, node: int, xy: np.ndarray, misses: np.ndarray) -> None:
        """Insert the node's scan into the active submaps; start and finish submaps."""
        cfg = self.config
        act = self.active()
        if not act or len(act[-1].nodes) >= cfg.submaps.scans // 2:
            self.submaps.append(Submap(node, ProbabilityGrid(cfg.submaps.grid)))
            travel = self._travel[node]
            self._span_lo = np.append(self._span_lo, travel)
            self._span_hi = np.append(self._span_hi, travel)
            self._tied_at = np.append(self._tied_at, -np.inf)
            act = self.active()
        pose = self.local[node]
        hits, miss = place(xy, pose), place(misses, pose) if len(misses) else None
        surface = None
        if cfg.submaps.connect_gap_m is not None:
            joined, _ = connect_returns(xy, None, cfg.submaps.connect_gap_m,
                                        0.5 * cfg.submaps.grid.resolution_m,
                                        cfg.submaps.grazing_gap_m)
            surface = place(joined[len(xy):], pose)
        for s in act:
            s.grid.insert(pose[:2], hits, miss, surface)
            s.nodes.append(node)
        self._span_hi[len(self.submaps) - len(act):] = self._travel[node]
        for s in act:
            if len(s.nodes) >= cfg.submaps.scans:
                s.finished = True
                s.grid = s.grid.cropped().frozen()

    def loop_map(self, k: int, node: int) -> LoopMap:
        """Submap ``k`` stitched with its finished neighbours in time, ``loop.neighbours``
        on each side (none holding ``node``): all in the local-SLAM frame, where
        neighbours in time agree to within local SLAM's short-term drift. A scan
        returning after a long loop sees more of the place than the ~9 m of path one
        submap holds; on fr-clinic its match against the one submap scored 0.23-0.38
        where the right place was, below any threshold that rejects false matches."""
        n = self.config.loop.neighbours
        ks = tuple(j for j in range(k - n, k + n + 1) if 0 <= j < len(self.submaps)
                   and self.submaps[j].finished and node not in self.submaps[j].nodes)
        key = (k, ks)
        lm = self._loop_maps.pop(key, None)
        if lm is None:
            grid = ProbabilityGrid.stitched([self.submaps[j].grid for j in ks])
            lm = LoopMap(grid, PrecomputedGrid(grid.coarsened(self.config.loop.coarsen),
                                               self.config.loop.depth))
        self._loop_maps[key] = lm  # most recently used last
        budget = self.config.loop.cache_mb * 2**20
        held = sum(m.nbytes for m in self._loop_maps.values())
        while len(self._loop_maps) > 1 and (len(self._loop_maps) > self.config.loop.cache
                                            or held > budget):
            held -= self._loop_maps.pop(next(iter(self._loop_maps))).nbytes
        return lm
