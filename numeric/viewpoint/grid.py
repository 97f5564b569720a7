"""The planner's view of a free / occupied / unknown grid (Masuzawa & Miura, §4.1).

The grid itself is :class:`chizu.numeric.occupancy.OccupancyMap` -- the same type a SLAM
run commits to a world -- built here from the simulator (the world's true geometry, or
laser scans from known poses as in the paper, which trusts odometry inside one room) or
from a ROS ``nav_msgs/OccupancyGrid``-style array a client posts. :class:`PlanningGrid`
adds what the planner asks of it: is a viewpoint free with clearance, is the line from
a viewpoint to an object clear, which unknown components are there (labelled with
``scipy.ndimage``) and where are their entry points (unknown cells next to free ones,
§6.3).
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from functools import cached_property

import numpy as np
from scipy import ndimage

from chizu.numeric.errors import InvalidInput
from chizu.numeric.geometry import point_segment_distance, ray_crossings
from chizu.numeric.laser import Laser
from chizu.numeric.occupancy import (
    FREE,
    OCCUPIED,
    UNKNOWN,
    Frame,
    OccupancyMap,
    UnknownComponent,
    build_occupancy,
    label_unknown,
)
from chizu.numeric.world import World

MAX_CELLS = 4_000_000
#: The robot looks around in four directions at a stop (the laser covers 240 degrees).
LOOK_AROUND = (0.0, np.pi / 2, np.pi, -np.pi / 2)
MAX_COMPONENTS = 2_000


class PlanningGrid:
    """An occupancy map plus an optional room mask (cells inside the room's known walls:
    the paper gives the robot the room's wall shape, so unknown space outside the room is
    not a region to explore)."""

    def __init__(self, grid: OccupancyMap, room: np.ndarray | None = None) -> None:
        if grid.state.ndim != 2 or min(grid.state.shape) < 1:
            raise InvalidInput("the grid must be a non-empty 2D array", field="grid")
        if room is not None and room.shape != grid.state.shape:
            raise InvalidInput("the room mask must have the grid's shape", field="grid")
        self.grid = grid
        self.room = room
        self._components: dict[tuple[float, int], list[UnknownComponent]] = {}

    @property
    def resolution(self) -> float:
        return self.grid.resolution_m

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The grid's lower-left and upper-right corners (m)."""
        lo = np.asarray(self.grid.origin, dtype=float)
        return lo, lo + np.array(self.state.shape) * self.resolution

    def covers(self, xy: np.ndarray) -> bool:
        """Whether the point ``xy`` (m) lies on the grid."""
        lo, hi = self.bounds()
        return bool(np.all(np.isfinite(xy)) and np.all(xy >= lo) and np.all(xy < hi))

    @property
    def state(self) -> np.ndarray:
        return self.grid.state

    def digest(self, lo: np.ndarray | None = None, hi: np.ndarray | None = None) -> bytes:
        """A digest of the grid's frame and cells, or of the cells of the box ``lo..hi``
        (cell indices, inclusive, clipped to the grid): equal digests, equal maps there."""
        shape = np.array(self.state.shape)
        lo = np.zeros(2, dtype=int) if lo is None else np.asarray(lo, dtype=int)
        hi = shape - 1 if hi is None else np.asarray(hi, dtype=int)
        (i0, j0), (i1, j1) = np.clip(lo, 0, shape), np.clip(hi + 1, 0, shape)
        h = hashlib.blake2b(digest_size=20)
        h.update(np.array([self.resolution, *self.grid.origin, *lo, *hi, *shape]).tobytes())
        h.update(np.ascontiguousarray(self.state[i0:i1, j0:j1]).tobytes())
        return h.digest()

    # -- cells ------------------------------------------------------------------------
    def cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cell indices ``(i, j)`` of points ``(..., 2)`` and whether they are on the grid."""
        return self.grid.cells(xy)

    def centres(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        return self.grid.centres(i, j)

    @cached_property
    def clearance(self) -> np.ndarray:
        """Distance (m) from each cell to the nearest occupied cell."""
        occ = self.state == OCCUPIED
        if not occ.any():
            return np.full(self.state.shape, np.inf)
        return np.asarray(ndimage.distance_transform_edt(~occ) * self.resolution)

    def free(self, xy: np.ndarray, clearance_m: float = 0.25) -> np.ndarray:
        """True where points ``(..., 2)`` are on known free cells at least ``clearance_m``
        from every occupied cell."""
        i, j, inside = self.cells(xy)
        ok = inside & (self.state[i, j] == FREE) & (self.clearance[i, j] >= clearance_m)
        return np.asarray(ok)

    def clear_lines(self, a: np.ndarray, b: np.ndarray, stop_short_m: float = 0.0) -> np.ndarray:
        """True for each pair of points ``a (N, 2)``, ``b (N, 2)`` whose segment crosses no
        occupied cell, ignoring the last ``stop_short_m`` before ``b`` (the object)."""
        a = np.atleast_2d(a).astype(float)
        b = np.atleast_2d(b).astype(float)
        d = b - a
        length = np.hypot(d[:, 0], d[:, 1])
        n = max(2, int(np.ceil(length.max(initial=0.0) / (0.5 * self.resolution))) + 1)
        f = np.linspace(0.0, 1.0, n)
        pts = a[:, None, :] + f[None, :, None] * d[:, None, :]
        keep = (f[None, :] * length[:, None]) <= np.maximum(length[:, None] - stop_short_m, 0.0)
        i, j, inside = self.cells(pts)
        blocked = inside & (self.state[i, j] == OCCUPIED) & keep
        return np.asarray(~blocked.any(axis=1))

    # -- unknown regions (§4.2) -------------------------------------------------------
    @cached_property
    def unknown_labels(self) -> tuple[np.ndarray, int]:
        """Connected unknown components -- inside the room mask when there is one, else
        those not touching the grid border."""
        return label_unknown(self.state, self.room)

    def unknown_components(self, min_area_m2: float = 0.0,
                           at_most: int = MAX_COMPONENTS) -> list[UnknownComponent]:
        """Unknown components of at least ``min_area_m2`` (the candidates for
        unknown-region groups; whether one becomes a group is decided in Prolog), largest
        first, at most ``at_most`` of them, with their entry points (kept per grid: a
        grid is not changed in place, and re-plans on the same map ask again)."""
        key = (min_area_m2, at_most)
        if key not in self._components:
            self._components[key] = self.grid.unknown_components(min_area_m2, at_most,
                                                                 self.unknown_labels)
        return self._components[key]

    def unknown_area(self) -> float:
        lab, _ = self.unknown_labels
        return float(np.count_nonzero(lab)) * self.resolution**2


# -- building grids -------------------------------------------------------------------
def _world_frame(world: World, resolution_m: float, margin_m: float = 0.5,
                 ) -> tuple[np.ndarray, tuple[int, int]]:
    lo, hi = world.bounds
    lo = lo - margin_m
    shape = np.ceil((hi + margin_m - lo) / resolution_m).astype(int)
    if shape[0] * shape[1] > MAX_CELLS:
        raise InvalidInput(f"a {shape[0]}x{shape[1]} grid is too large; use a coarser "
                           "resolution", field="resolution_m")
    return lo, (int(shape[0]), int(shape[1]))


def _cell_centres(lo: np.ndarray, shape: tuple[int, int], resolution_m: float) -> np.ndarray:
    """Centres ``(nx, ny, 2)`` of every cell of a grid with lower corner ``lo``."""
    ii, jj = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
    return np.asarray(lo + (np.stack([ii, jj], axis=-1) + 0.5) * resolution_m)


def room_mask(world: World, resolution_m: float, wall_margin_m: float = 0.1) -> np.ndarray:
    """Cells whose centre is inside the world's walls (even-odd rule, objects included),
    less a ``wall_margin_m`` band along the walls -- unseen wall cells would otherwise
    join unknown regions that only touch the same wall."""
    lo, shape = _world_frame(world, resolution_m)
    xy = _cell_centres(lo, shape, resolution_m).reshape(-1, 2)
    surf = world.surfaces
    walls = ~np.isfinite(surf.top_m)
    inside = world.inside(xy)
    near = point_segment_distance(xy, surf.a[walls], surf.b[walls]).min(axis=1, initial=np.inf)
    return np.asarray((inside & (near >= wall_margin_m)).reshape(shape))


def true_grid(world: World, resolution_m: float = 0.05) -> PlanningGrid:
    """The world's true map: every cell inside the walls known (free, or occupied where a
    wall or object surface passes)."""
    lo, shape = _world_frame(world, resolution_m)
    room = room_mask(world, resolution_m, 0.0)
    state = np.full(shape, UNKNOWN, dtype=np.int8)
    state[room] = FREE
    grid = PlanningGrid(OccupancyMap(lo, resolution_m, state, np.full(shape, np.nan)), room)
    surf = world.surfaces
    for a, b in zip(surf.a, surf.b, strict=True):
        n = max(2, int(np.ceil(np.hypot(*(b - a)) / (0.25 * resolution_m))) + 1)
        i, j, ok = grid.cells(a + np.linspace(0, 1, n)[:, None] * (b - a))
        state[i[ok], j[ok]] = OCCUPIED
    ii, jj = np.nonzero(room)
    xy = grid.centres(ii, jj)
    for o in world.description.objects:  # the inside of a cuboid is not free space
        fp = o.footprint()
        inside = ray_crossings(xy, fp, np.roll(fp, -1, axis=0)) % 2 == 1
        state[ii[inside], jj[inside]] = OCCUPIED
    return grid


def scanned_grid(world: World, poses: Sequence[np.ndarray] | np.ndarray,
                 resolution_m: float = 0.05, laser: Laser | None = None) -> PlanningGrid:
    """The map a robot builds by scanning from ``poses (K, 3)`` whose odometry it trusts
    (§4.1): the simulated laser, ray-traced into free / occupied / unknown, on the world's
    frame, with the room mask of the known walls."""
    laser = laser or Laser(world)
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    frames = []
    ang = laser.config.angles
    ray = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    for p in poses:
        r, i = laser.measure(p)
        ok = r < laser.config.max_range_m
        frames.append(Frame(r[ok, None] * ray[ok], i[ok], laser.config.max_range_m * ray[~ok]))
    lo, shape = _world_frame(world, resolution_m)
    built = build_occupancy(frames, poses, resolution_m=resolution_m,
                            miss_cap_m=laser.config.max_range_m)
    # re-sample onto the world's frame so every grid of a world lines up
    state = np.full(shape, UNKNOWN, dtype=np.int8)
    bi, bj, inside = PlanningGrid(built).cells(_cell_centres(lo, shape, resolution_m))
    state[inside] = built.state[bi[inside], bj[inside]]
    grid = OccupancyMap(lo, resolution_m, state, np.full(shape, np.nan))
    return PlanningGrid(grid, room_mask(world, resolution_m))


def look_around(xy: Sequence[float] | np.ndarray) -> np.ndarray:
    """The scan poses ``(4, 3)`` of one look around at ``xy``."""
    return np.array([[float(xy[0]), float(xy[1]), a] for a in LOOK_AROUND])


def from_occupancy_values(width: int, height: int, resolution_m: float,
                          origin: tuple[float, float], data: Sequence[int],
                          free_thresh: int = 19, occupied_thresh: int = 65) -> PlanningGrid:
    """A grid from ROS ``nav_msgs/OccupancyGrid`` values: row-major with x fastest,
    ``-1`` unknown, ``0..100`` occupancy (``<= free_thresh`` free, ``>= occupied_thresh``
    occupied, between: unknown)."""
    if width < 1 or height < 1 or width * height > MAX_CELLS:
        raise InvalidInput(f"grid of {width}x{height} cells is empty or too large "
                           f"(at most {MAX_CELLS})", field="grid.width")
    try:
        v = np.asarray(data, dtype=np.int64)
    except (OverflowError, ValueError, TypeError):
        raise InvalidInput("grid.data values must be -1 (unknown) or 0..100",
                           field="grid.data") from None
    if v.shape != (width * height,):
        raise InvalidInput(f"grid.data has {v.size} values, width*height is {width * height}",
                           field="grid.data")
    if np.any((v < -1) | (v > 100)):
        raise InvalidInput("grid.data values must be -1 (unknown) or 0..100", field="grid.data")
    vals = v.reshape(height, width).T  # state[i along x, j along y]
    state = np.full(vals.shape, UNKNOWN, dtype=np.int8)
    state[(vals >= 0) & (vals <= free_thresh)] = FREE
    state[vals >= occupied_thresh] = OCCUPIED
    grid = OccupancyMap(np.asarray(origin, dtype=float), resolution_m, state,
                        np.full(state.shape, np.nan))
    return PlanningGrid(grid)


#: cells closer than this to an obstacle are impassable for the robot's body
PASSING_CLEARANCE_M = 0.2
#: geodesic travel times are computed on cells this large (coarsened from the grid)
TRAVEL_CELL_M = 0.2


def travel_cost(grid: PlanningGrid) -> np.ndarray:
    """Cost per cell of moving through it: 1 on free cells, 2 on unknown ones (the robot
    may cross space it has not mapped, carefully), impassable (inf) on occupied cells and
    within PASSING_CLEARANCE_M of one."""
    cost = np.where(grid.state == FREE, 1.0, 2.0)
    cost[(grid.state == OCCUPIED) | (grid.clearance < PASSING_CLEARANCE_M)] = np.inf
    return cost


class TravelMap:
    """Geodesic distances on a planning grid: shortest paths around obstacles on cells of
    TRAVEL_CELL_M, a coarse cell taking the dearest of its fine cells, 8-connected; a
    step between neighbours costs the mean of their costs times its length (1 or
    sqrt 2), as skimage's MCP_Geometric counts it. The graph is built once per map
    (scipy's sparse graphs) and each distance field is one multi-source Dijkstra. A
    point on an impassable cell starts from it anyway (the robot stands there: steps out
    of such a cell count it as free); a target no path reaches gets the straight-line
    distance, as the robot's own route does."""

    def __init__(self, grid: PlanningGrid, cell_m: float = TRAVEL_CELL_M) -> None:
        from scipy.sparse import csr_matrix
        from skimage.measure import block_reduce

        self.grid = grid
        self.factor = max(1, int(round(cell_m / grid.resolution)))
        fine = travel_cost(grid)
        self.cost = np.asarray(block_reduce(fine, (self.factor, self.factor), np.max,
                                            cval=np.inf)) if self.factor > 1 else fine
        self.cell_m = grid.resolution * self.factor
        h, w = self.cost.shape
        ids = np.arange(h * w).reshape(h, w)
        leave = np.where(np.isfinite(self.cost), self.cost, 1.0)  # out of a robot's cell
        rows, cols, vals = [], [], []
        for di, dj in ((0, 1), (1, 0), (1, 1), (1, -1), (0, -1), (-1, 0), (-1, -1), (-1, 1)):
            a = (slice(max(-di, 0), h - max(di, 0)), slice(max(-dj, 0), w - max(dj, 0)))
            b = (slice(max(di, 0), h - max(-di, 0)), slice(max(dj, 0), w - max(-dj, 0)))
            ok = np.isfinite(self.cost[b])
            rows.append(ids[a][ok])
            cols.append(ids[b][ok])
            vals.append((0.5 * (leave[a] + self.cost[b]) * np.hypot(di, dj))[ok])
        self.graph = csr_matrix((np.concatenate(vals), (np.concatenate(rows),
                                                        np.concatenate(cols))), shape=(h * w,) * 2)

    def cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        i, j, inside = self.grid.cells(np.atleast_2d(xy))
        return i // self.factor, j // self.factor, inside

    def field(self, sources: np.ndarray) -> np.ndarray:
        """Distance (m) from the nearest of ``sources (k, 2)`` to every coarse cell."""
        from scipy.sparse.csgraph import dijkstra

        i, j, inside = self.cells(sources)
        if not inside.any():
            return np.full(self.cost.shape, np.inf)
        start = np.unique(i[inside] * self.cost.shape[1] + j[inside])
        d = dijkstra(self.graph, directed=True, indices=start, min_only=True)
        return np.asarray(d).reshape(self.cost.shape) * self.cell_m

    def distances(self, field: np.ndarray, sources: np.ndarray,
                  targets: np.ndarray) -> np.ndarray:
        """``(T,)`` geodesic distance of each target from ``field`` (made from
        ``sources``), the straight line where no path reaches it."""
        targets = np.atleast_2d(targets)
        i, j, inside = self.cells(targets)
        d = np.where(inside, field[i, j], np.inf)
        # a target on an impassable cell: from its cheapest neighbour
        bad = ~np.isfinite(d) & inside
        if bad.any():
            near = ndimage.minimum_filter(field, size=3, mode="constant", cval=np.inf)
            d[bad] = near[i[bad], j[bad]] + self.cell_m
        straight = np.min(np.linalg.norm(np.atleast_2d(sources)[:, None] - targets[None],
                                         axis=2), axis=0)
        return np.asarray(np.where(np.isfinite(d), np.maximum(d, straight), straight))
