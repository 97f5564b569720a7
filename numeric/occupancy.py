"""Maps out of a SLAM run: an occupancy grid (free / occupied / unknown) with the mean
received intensity of occupied cells, exported as an intensity-coloured PNG and as a
ROS ``map_server`` PGM + YAML pair, and summarised for the knowledge base (cell areas
and the enclosed unknown regions the planners look at)."""

from __future__ import annotations

import io
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from scipy import ndimage

from chizu.numeric.errors import InvalidInput
from chizu.numeric.geometry import place
from chizu.numeric.probability_grid import GridConfig, ProbabilityGrid

UNKNOWN, FREE, OCCUPIED = -1, 0, 100
#: probability from which a cell is occupied (map_server's default occupied_thresh)
OCCUPIED_P = 0.5


@dataclass(frozen=True)
class UnknownComponent:
    """A connected unknown region: its label, centroid, area and entry points (centres
    of its cells that touch free cells, §6.3 of the viewpoint paper)."""

    label: int
    centroid: np.ndarray
    area_m2: float
    entries: np.ndarray


def label_unknown(state: np.ndarray, room: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Connected unknown components (8-neighbourhood) of a grid -- inside ``room`` when
    given, else those enclosed by the mapped area (not touching the grid border)."""
    unk = state == UNKNOWN
    if room is not None:
        unk &= room
    lab, n = ndimage.label(unk, structure=np.ones((3, 3)))
    if room is None and n:
        border = np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))
        lab[np.isin(lab, border[border > 0])] = 0
    return lab, int(n)


@dataclass(frozen=True)
class OccupancyMap:
    """``state[i, j]`` for the cell whose lower-left corner is ``origin + (i, j) *
    resolution`` (i along x); ``intensity`` the mean intensity of occupied cells (NaN
    where none was measured)."""

    origin: np.ndarray
    resolution_m: float
    state: np.ndarray
    intensity: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.state.shape[0]), int(self.state.shape[1]))

    def summary(self) -> dict[str, float]:
        cell = self.resolution_m**2
        return {"free_m2": float(np.sum(self.state == FREE) * cell),
                "occupied_m2": float(np.sum(self.state == OCCUPIED) * cell),
                "unknown_m2": float(np.sum(self.state == UNKNOWN) * cell),
                "resolution_m": self.resolution_m,
                "width": self.shape[0], "height": self.shape[1]}

    def cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cell indices ``(i, j)`` of points ``(..., 2)`` and whether they are on the
        grid (off-grid points get index 0)."""
        c = np.floor((np.asarray(xy, float) - self.origin) / self.resolution_m).astype(int)
        i, j = c[..., 0], c[..., 1]
        inside = (i >= 0) & (j >= 0) & (i < self.state.shape[0]) & (j < self.state.shape[1])
        return np.where(inside, i, 0), np.where(inside, j, 0), inside

    def centres(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """Centres (..., 2) of the cells ``(i, j)``."""
        return np.asarray(self.origin + (np.stack([i, j], axis=-1) + 0.5) * self.resolution_m)

    def unknown_components(self, min_area_m2: float = 0.0, at_most: int | None = None,
                           labels: tuple[np.ndarray, int] | None = None,
                           ) -> list[UnknownComponent]:
        """Unknown components of at least ``min_area_m2``, largest first, at most
        ``at_most``, with their entry points; ``labels`` from :func:`label_unknown`
        (default: the enclosed components). Each component is visited inside its
        bounding box only, so many small ones stay cheap."""
        lab, n = labels if labels is not None else label_unknown(self.state)
        if n == 0:
            return []
        idx = np.arange(1, n + 1)
        ones = np.ones_like(lab)
        area = np.asarray(ndimage.sum_labels(ones, lab, idx)) * self.resolution_m**2
        with np.errstate(invalid="ignore"):  # labels dropped at the border have no cells
            centroid = np.asarray(ndimage.center_of_mass(ones, lab, idx)).reshape(-1, 2)
        boxes = ndimage.find_objects(lab)
        touch = ndimage.binary_dilation(self.state == FREE,
                                        structure=ndimage.generate_binary_structure(2, 1))
        order = [int(k) for k in np.argsort(-area, kind="stable")
                 if area[k] > 0 and area[k] >= min_area_m2][:at_most]
        out = []
        for k in order:
            box = boxes[k]
            assert box is not None
            ei, ej = np.nonzero((lab[box] == k + 1) & touch[box])
            entries = self.centres(ei + box[0].start, ej + box[1].start)
            out.append(UnknownComponent(k + 1, self.origin + (centroid[k] + 0.5)
                                        * self.resolution_m, float(area[k]), entries))
        return out

    def unknown_regions(self, min_area_m2: float) -> list[dict[str, float]]:
        """The enclosed unknown components of at least ``min_area_m2``: centroid and area,
        largest first (the facts a committed SLAM map reports)."""
        return [{"x": float(c.centroid[0]), "y": float(c.centroid[1]), "area_m2": c.area_m2}
                for c in self.unknown_components(min_area_m2)]

    # -- exports ------------------------------------------------------------------------
    def downsampled(self, max_side: int) -> OccupancyMap:
        """The grid with at most ``max_side`` cells a side, for drawing: each block of f x f
        cells becomes one, occupied if any of them is, else free if any is, else unknown
        (walls stay visible at any scale); its intensity the block's largest."""
        f = -(-max(self.shape) // max(1, max_side))
        if f <= 1:
            return self
        nx, ny = -(-self.shape[0] // f), -(-self.shape[1] // f)
        state = np.full((nx * f, ny * f), UNKNOWN, dtype=self.state.dtype)
        state[:self.shape[0], :self.shape[1]] = self.state
        inten = np.full((nx * f, ny * f), -np.inf)
        inten[:self.shape[0], :self.shape[1]] = np.where(np.isnan(self.intensity), -np.inf,
                                                         self.intensity)
        # OCCUPIED > FREE > UNKNOWN: a block's maximum is its state
        block_state = state.reshape(nx, f, ny, f).max(axis=(1, 3))
        block_inten = inten.reshape(nx, f, ny, f).max(axis=(1, 3))
        return OccupancyMap(self.origin.copy(), self.resolution_m * f, block_state,
                            np.where(np.isinf(block_inten), np.nan, block_inten))

    def image_rows(self) -> np.ndarray:
        """The grid as image rows (top row = largest y)."""
        return np.asarray(self.state.T[::-1])

    def to_pgm(self) -> bytes:
        """ROS map_server PGM: 0 occupied, 254 free, 205 unknown."""
        rows = self.image_rows()
        img = np.full(rows.shape, 205, dtype=np.uint8)
        img[rows == FREE] = 254
        img[rows == OCCUPIED] = 0
        h, w = rows.shape
        head = f"P5\n# chizu map, {self.resolution_m} m/cell\n{w} {h}\n255\n"
        return head.encode("ascii") + img.tobytes()

    def to_yaml(self, image: str = "map.pgm") -> str:
        """map_server YAML for :meth:`to_pgm` saved as ``image``."""
        return (f"image: {image}\nresolution: {self.resolution_m:.6f}\n"
                f"origin: [{self.origin[0]:.6f}, {self.origin[1]:.6f}, 0.0]\n"
                "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n")

    def to_png(self) -> bytes:
        """RGB PNG: free white, unknown grey, occupied cells coloured by intensity
        (viridis over the map's intensity range; black where no intensity)."""
        from matplotlib import colormaps
        from PIL import Image

        rows = self.image_rows()
        inten = np.asarray(self.intensity.T[::-1])
        img = np.full((*rows.shape, 3), 160, dtype=np.uint8)
        img[rows == FREE] = 255
        occ = rows == OCCUPIED
        have = occ & np.isfinite(inten)
        img[occ] = 0
        if np.any(have):
            lo, hi = np.nanpercentile(inten[have], [2, 98])
            v = np.clip((inten[have] - lo) / max(hi - lo, 1e-9), 0, 1)
            img[have] = (colormaps["viridis"](v)[:, :3] * 255).astype(np.uint8)
        buf = io.BytesIO()
        Image.fromarray(img, "RGB").save(buf, format="PNG")
        return buf.getvalue()

    def to_npz(self) -> bytes:
        buf = io.BytesIO()
        np.savez_compressed(buf, origin=self.origin, resolution_m=self.resolution_m,
                            state=self.state, intensity=self.intensity)
        return buf.getvalue()

    @classmethod
    def from_npz(cls, blob: bytes) -> OccupancyMap:
        z = np.load(io.BytesIO(blob))
        return cls(z["origin"], float(z["resolution_m"]), z["state"], z["intensity"])


class ScanFrame(Protocol):
    """One scan as the occupancy builder reads it: its returns ``xy (n, 2)``, their
    ``intensity (n,)`` (or None) and the ends of its no-return beams ``misses (m, 2)``
    (or None), in the robot frame (a SLAM keyframe, or a simulated look around)."""

    @property
    def xy(self) -> np.ndarray: ...

    @property
    def intensity(self) -> np.ndarray | None: ...

    @property
    def misses(self) -> np.ndarray | None: ...


@dataclass(frozen=True)
class Frame:
    """A plain :class:`ScanFrame`."""

    xy: np.ndarray
    intensity: np.ndarray | None = None
    misses: np.ndarray | None = None


def build_probability_grid(frames: Sequence[ScanFrame], poses: np.ndarray,
                           resolution_m: float = 0.05, margin_m: float = 1.0,
                           max_cells: int = 16_000_000, miss_cap_m: float = 5.0,
                           grid: GridConfig | None = None,
                           ) -> tuple[ProbabilityGrid, list[np.ndarray]]:
    """The :class:`~chizu.numeric.probability_grid.ProbabilityGrid` the scans ``frames`` placed
    at ``poses (K, 3)`` make (each ray-cast into it: hits raise a cell's odds, cells a
    beam passes through lower them, clamped; a scan's ``misses`` clear free space up to
    ``miss_cap_m``), sized to them with ``margin_m``, and each scan's returns in the
    world frame."""
    if len(frames) == 0:
        raise InvalidInput("the run has no keyframes yet", field="run")
    cfg = (grid or GridConfig()).model_copy(update={"resolution_m": resolution_m,
                                                     "miss_cap_m": miss_cap_m,
                                                     "grow_margin_m": 0.0})
    miss = [f.misses for f in frames]
    world = [place(f.xy, poses[k]) for k, f in enumerate(frames)]
    clear = [None if m is None or len(m) == 0 else place(m, poses[k])
             for k, m in enumerate(miss)]
    for k, c in enumerate(clear):  # cut the no-return beams at the cap before sizing
        if c is not None:
            d = c - poses[k, :2]
            r = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
            clear[k] = poses[k, :2] + d * (np.minimum(r, miss_cap_m) / r)[:, None]
    kept = [w[np.hypot(*(w - poses[k, :2]).T) <= cfg.max_range_m] for k, w in enumerate(world)]
    allp = np.vstack(kept + [c for c in clear if c is not None] + [poses[:, :2]])
    lo = allp.min(axis=0) - margin_m
    hi = allp.max(axis=0) + margin_m
    shape = np.ceil((hi - lo) / resolution_m).astype(int) + 1
    if shape[0] * shape[1] > max_cells:
        raise InvalidInput(f"a {shape[0]}x{shape[1]} grid at {resolution_m} m is too large; "
                           "use a coarser resolution", field="resolution_m")
    g = ProbabilityGrid(cfg)
    g.ensure(lo, hi)
    for k, pts in enumerate(kept):
        g.insert(poses[k, :2], pts, clear[k])
    return g, world


def build_occupancy(frames: Sequence[ScanFrame], poses: np.ndarray, resolution_m: float = 0.05,
                    margin_m: float = 1.0, max_cells: int = 16_000_000,
                    miss_cap_m: float = 5.0,
                    grid: GridConfig | None = None) -> OccupancyMap:
    """The occupancy grid of the scans ``frames`` placed at ``poses (K, 3)``: every scan
    is ray-cast into one :class:`~chizu.numeric.probability_grid.ProbabilityGrid` (hits
    raise a cell's odds, cells a beam passes through lower them, once per scan with hits
    winning, clamped), then thresholded the way ``map_server`` reads a map: occupied at
    ``p >= 0.65``, free below 0.5, unknown where never observed or undecided.
    A scan's ``misses`` (the ends of its no-return beams) clear free space up to
    ``miss_cap_m`` and mark nothing occupied."""
    g, world = build_probability_grid(frames, poses, resolution_m, margin_m, max_cells,
                                      miss_cap_m, grid)
    nx, ny = g.shape
    isum = np.zeros(nx * ny)
    icnt = np.zeros(nx * ny)
    for k, f in enumerate(frames):
        if f.intensity is None or len(world[k]) == 0:
            continue
        c = np.floor(g.to_cells(world[k])).astype(np.int64)
        ok = (c[:, 0] >= 0) & (c[:, 0] < nx) & (c[:, 1] >= 0) & (c[:, 1] < ny)
        cells = c[ok, 0] * ny + c[ok, 1]
        isum += np.bincount(cells, weights=f.intensity[ok], minlength=nx * ny)
        icnt += np.bincount(cells, minlength=nx * ny)
    state = np.full((nx, ny), UNKNOWN, dtype=np.int8)
    p = g.prob
    state[(p > 0) & (p < 0.5)] = FREE
    state[p >= OCCUPIED_P] = OCCUPIED
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_i = np.where(icnt > 0, isum / icnt, np.nan)
    return OccupancyMap(g.origin, resolution_m, state, mean_i.reshape(nx, ny))


def build_occupancy_fitting(frames: Sequence[ScanFrame], poses: np.ndarray,
                            resolution_m: float) -> OccupancyMap:
    """:func:`build_occupancy` at ``resolution_m``, or at the finest doubling of it that
    fits the grid size limit (a hospital floor at 5 cm does not): a long run is never
    lost to its map."""
    for _ in range(6):
        try:
            return build_occupancy(frames, poses, resolution_m)
        except InvalidInput as e:
            if e.field != "resolution_m":
                raise
            resolution_m *= 2
    return build_occupancy(frames, poses, resolution_m)
