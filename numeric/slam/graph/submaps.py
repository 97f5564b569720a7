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
older submaps had not (placed where the pose graph has them now) is trimmed
(:meth:`Submaps.trim`, after Cartographer's overlapping submaps trimmer): its grid is
dropped and loop closure no longer searches it, and on a run past ``forget_after_scans``
scans the returns of its nodes no kept submap holds are forgotten and the nodes leave
the pose graph, their marginal kept (:meth:`~chizu.numeric.slam.pose_graph.PoseGraph.remove`;
their scans stay in the trajectory). Memory and the loop searches then grow with the
building, not with the hours the robot drives through it.
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


@dataclass(frozen=True)
class ObservedCells:
    """The cells of ``cell_m`` a finished submap observed, in the local-SLAM frame, one
    bit each (what :meth:`Submaps.trim` compares; a few kilobytes a submap)."""

    origin: np.ndarray
    shape: tuple[int, int]
    cell_m: float
    bits: np.ndarray

    @classmethod
    def of(cls, grid: ProbabilityGrid, cell_m: float) -> ObservedCells:
        """A grid's observed cells, on cells ``cell_m`` wide (any fine cell observed)."""
        coarse = grid.coarsened(max(1, int(round(cell_m / grid.resolution_m))))
        known = coarse.known()
        return cls(coarse.origin.copy(), (int(known.shape[0]), int(known.shape[1])),
                   coarse.resolution_m, np.packbits(known, axis=None))

    def mask(self) -> np.ndarray:
        n = self.shape[0] * self.shape[1]
        return np.unpackbits(self.bits, count=n).reshape(self.shape).astype(np.bool_)

    def centres(self) -> np.ndarray:
        """The observed cells' centres ``(n, 2)`` (local-SLAM frame, m)."""
        ii, jj = np.nonzero(self.mask())
        return self.origin + (np.stack([ii, jj], axis=1) + 0.5) * self.cell_m

    def bounds(self, to_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The world box holding the cells when the local frame is placed by
        ``to_world``."""
        size = np.array(self.shape) * self.cell_m
        corners = self.origin + np.array([[0, 0], [size[0], 0], [0, size[1]], size])
        w = place(corners, to_world)
        return w.min(axis=0), w.max(axis=0)

    def holds(self, xy: np.ndarray) -> np.ndarray:
        """Whether each point ``xy (n, 2)`` (local-SLAM frame) lies in an observed cell."""
        c = np.floor((xy - self.origin) / self.cell_m).astype(np.int64)
        ok = np.all((c >= 0) & (c < np.array(self.shape)), axis=1)
        out = np.zeros(len(xy), dtype=np.bool_)
        out[ok] = self.mask()[c[ok, 0], c[ok, 1]]
        return out


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
    #: the coarse cells each finished submap observed (Submaps.trim)
    _cells: dict[int, ObservedCells]

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

    def to_world(self, k: int) -> np.ndarray:
        """The transform from the local-SLAM frame to the world for submap ``k``: its
        anchor node's current global pose over its local one."""
        a = self.submaps[k].anchor
        return compose(self._global[a], invert(self.local[a]))

    def covered_share(self, k: int, cells: ObservedCells) -> float:
        """The share of ``cells`` (submap ``k``'s) that submaps finished before its two
        neighbours in time observed, each placed where the pose graph has it now: a
        loop closure that moved the older submaps moves what they cover with them."""
        centres = cells.centres()
        if not len(centres):
            return 1.0
        mine = self.to_world(k)
        world = place(centres, mine)
        lo, hi = world.min(axis=0), world.max(axis=0)
        covered = np.zeros(len(centres), dtype=np.bool_)
        for j, other in self._cells.items():
            if j >= k - 2:
                continue
            theirs = self.to_world(j)
            blo, bhi = other.bounds(theirs)
            if np.any(bhi < lo) or np.any(blo > hi):
                continue
            covered |= other.holds(place(centres, compose(invert(theirs), mine)))
        return float(covered.mean())

    def trim(self, k: int) -> None:
        """Trim the submap ``k`` just finished when at least ``trim_share`` of the cells
        it observed were observed by submaps finished before its two neighbours in time
        (a submap always overlaps the one before it by half, and a robot turning in a
        room fills the next with the same cells): its grid is dropped, loop closure
        skips it, and on a long run the returns of its nodes no kept submap holds are
        forgotten (:meth:`~chizu.numeric.slam.graph.slam.GraphSlam.forget`). Its cells
        count as observed for the submaps after it, trimmed or not: a trimmed submap
        adds at most ``1 - trim_share`` of cells beyond the older ones, and those would
        otherwise be new again to every later pass through the place."""
        cfg = self.config.submaps
        assert cfg.trim_share is not None
        s = self.submaps[k]
        cells = ObservedCells.of(s.grid, cfg.trim_cell_m)
        if self.covered_share(k, cells) >= cfg.trim_share:
            s.trimmed = True
            s.grid = ProbabilityGrid(s.grid.config)
            near = [self.submaps[j] for j in (k - 1, k + 1) if 0 <= j < len(self.submaps)]
            self.forget([n for n in s.nodes if all(
                o.trimmed for o in near if o.nodes and o.nodes[0] <= n <= o.nodes[-1])])
        self._cells[k] = cells

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
