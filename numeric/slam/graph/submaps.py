"""Submaps (Hess et al. 2016, §III-B): probability grids in the local-SLAM frame, each
anchored at a node; a submap is finished after ``scans`` nodes and a new one starts
halfway, so two always overlap. A node's scan is inserted with the surface between
neighbouring returns (``connect_gap_m``: one scan of a wall seen at a slant in 1° steps
is otherwise a dotted line that moves with the robot, and the next scan fits it best
where the first was taken) and the collinear returns of a wall seen at grazing
incidence joined farther apart (``grazing_gap_m``), so that such a wall fixes a scan
across itself and leaves it free along it. Loop closure matches against a submap
stitched with its neighbours in time (:meth:`Submaps.loop_map`).

On a long run over the same building a finished submap that observed almost nothing the
older submaps had not is trimmed (:meth:`Submaps.trim`, after Cartographer's overlapping
submaps trimmer): its grid is dropped and loop closure no longer searches it, and on a
run past ``forget_after_scans`` scans the returns of its nodes no kept submap holds are
forgotten, while the nodes stay in the pose graph (and their scans in the trajectory).
Memory and the loop searches then grow with the building, not with the hours the robot
drives through it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from chizu.numeric.geometry import compose, invert, place
from chizu.numeric.probability_grid import ProbabilityGrid
from chizu.numeric.slam.graph.config import GraphSlamConfig
from chizu.numeric.slam.keyframes import connect_returns
from chizu.numeric.slam.matching.correlative import PrecomputedGrid


@dataclass
class Submap:
    """A probability grid in the local-SLAM frame, anchored at one node."""

    anchor: int
    grid: ProbabilityGrid
    nodes: list[int] = field(default_factory=list)
    finished: bool = False
    #: its grid was dropped: older submaps had observed what it did (Submaps.trim)
    trimmed: bool = False

    def finish(self) -> None:
        """No more scans go in: the grid cropped to what it observed, and frozen."""
        self.finished = True
        self.grid = self.grid.cropped().frozen()


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
    """The submap steps of :class:`~chizu.numeric.slam.graph.slam.GraphSlam`."""

    config: GraphSlamConfig
    submaps: list[Submap]
    local: list[np.ndarray]
    _travel: list[float]
    _span_lo: np.ndarray
    _span_hi: np.ndarray
    _tied_at: np.ndarray
    _loop_maps: dict[tuple[int, tuple[int, ...]], LoopMap]
    _global: np.ndarray
    #: the coarse world cells each kept finished submap observed, and their union over
    #: the kept submaps old enough to count (Submaps.trim)
    _cells: dict[int, np.ndarray]
    _covered: np.ndarray

    if TYPE_CHECKING:
        def forget(self, nodes: list[int]) -> None: ...

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
        for k in range(len(self.submaps) - len(act), len(self.submaps)):
            s = self.submaps[k]
            if len(s.nodes) >= cfg.submaps.scans:
                s.finish()
                if cfg.submaps.trim_share is not None:
                    self.trim(k)

    def observed_cells(self, k: int) -> np.ndarray:
        """The cells of ``trim_cell_m`` in the world frame that submap ``k`` observed,
        as sorted keys: its grid's observed cells placed by its anchor node's current
        global pose."""
        s, cell = self.submaps[k], self.config.submaps.trim_cell_m
        g = s.grid
        ii, jj = np.nonzero(g.known())
        local = g.origin + (np.stack([ii, jj], axis=1) + 0.5) * g.resolution_m
        world = place(local, compose(self._global[s.anchor], invert(self.local[s.anchor])))
        c = np.floor(world / cell).astype(np.int64)
        return np.unique(c[:, 0] * 2_000_003 + c[:, 1])

    def trim(self, k: int) -> None:
        """Trim the submap ``k`` just finished when at least ``trim_share`` of the cells
        it observed were observed by kept submaps finished before its two neighbours in
        time (a submap always overlaps the one before it by half, and a robot turning in
        a room fills the next with the same cells): its grid is dropped, loop closure
        skips it, and on a long run the returns of its nodes no kept submap holds are
        forgotten (:meth:`~chizu.numeric.slam.graph.slam.GraphSlam.forget`). Else its cells join the
        cover."""
        cfg = self.config.submaps
        keys = self.observed_cells(k)
        old = [j for j in self._cells if j < k - 2]
        for j in old:  # old enough now: into the cover
            self._covered = np.union1d(self._covered, self._cells.pop(j))
        share = (np.isin(keys, self._covered, assume_unique=True).mean() if len(keys)
                 else 1.0)
        assert cfg.trim_share is not None
        if share >= cfg.trim_share:
            s = self.submaps[k]
            s.trimmed = True
            s.grid = ProbabilityGrid(s.grid.config)
            near = [self.submaps[j] for j in (k - 1, k + 1) if 0 <= j < len(self.submaps)]
            self.forget([n for n in s.nodes if all(
                o.trimmed for o in near if o.nodes and o.nodes[0] <= n <= o.nodes[-1])])
        else:
            self._cells[k] = keys

    def loop_map(self, k: int, node: int) -> LoopMap:
        """Submap ``k`` stitched with its finished neighbours in time, ``loop.neighbours``
        on each side (none holding ``node``): all in the local-SLAM frame, where
        neighbours in time agree to within local SLAM's short-term drift. A scan
        returning after a long loop sees more of the place than the ~9 m of path one
        submap holds; on fr-clinic its match against the one submap scored 0.23-0.38
        where the right place was, below any threshold that rejects false matches."""
        n = self.config.loop.neighbours
        ks = tuple(j for j in range(k - n, k + n + 1) if 0 <= j < len(self.submaps)
                   and self.submaps[j].finished and not self.submaps[j].trimmed
                   and node not in self.submaps[j].nodes)
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
