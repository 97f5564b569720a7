"""Maps out of a SLAM run: an occupancy grid (free / occupied / unknown) with the mean
received intensity of occupied cells, exported as an intensity-coloured PNG and as a
ROS ``map_server`` PGM + YAML pair, and summarised for the knowledge base (cell areas
and the enclosed unknown regions the planners look at)."""

from __future__ import annotations

import io
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from numeric.errors import InvalidInput
from numeric.geometry import place
from numeric.slam.keyframes import Keyframes

UNKNOWN, FREE, OCCUPIED = -1, 0, 100


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

    def unknown_regions(self, min_area_m2: float = 0.5) -> list[dict[str, float]]:
        """The enclosed unknown components of at least ``min_area_m2``: centroid and area,
        largest first (the facts a committed SLAM map reports)."""
        return [{"x": float(c.centroid[0]), "y": float(c.centroid[1]), "area_m2": c.area_m2}
                for c in self.unknown_components(min_area_m2)]

    # -- exports ------------------------------------------------------------------------
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


def build_occupancy(keyframes: Keyframes, poses: np.ndarray, resolution_m: float = 0.05,
                    margin_m: float = 1.0, max_cells: int = 16_000_000,
                    misses: list[np.ndarray] | None = None) -> OccupancyMap:
    """Occupancy grid of the keyframes placed at ``poses (K, 3)``: cells on the rays
    from each keyframe's pose to its points are free, the end cells occupied (an
    occupied hit outvotes free passes 2:1). ``misses[k]`` (robot frame) are the ends of
    keyframe k's no-return beams at maximum range: free up to there, nothing occupied."""
    if len(keyframes) == 0:
        raise InvalidInput("the run has no keyframes yet", field="run")
    world = [place(f.xy, poses[k]) for k, f in enumerate(keyframes.frames)]
    clear = [place(m, poses[k]) for k, m in enumerate(misses)] if misses else []
    allp = np.vstack(world + clear + [poses[:, :2]])
    lo = allp.min(axis=0) - margin_m
    hi = allp.max(axis=0) + margin_m
    shape = np.ceil((hi - lo) / resolution_m).astype(int) + 1
    if shape[0] * shape[1] > max_cells:
        raise InvalidInput(f"a {shape[0]}x{shape[1]} grid at {resolution_m} m is too large; "
                           "use a coarser resolution", field="resolution_m")
    nx, ny = int(shape[0]), int(shape[1])
    free = np.zeros(nx * ny, dtype=np.int32)
    hit = np.zeros(nx * ny, dtype=np.int32)
    isum = np.zeros(nx * ny)
    icnt = np.zeros(nx * ny)

    def flat(p: np.ndarray) -> np.ndarray:
        c = np.floor((p - lo) / resolution_m).astype(np.int64)
        return c[..., 0] * ny + c[..., 1]

    def clear_rays(o: np.ndarray, pts: np.ndarray, stop_m: float) -> None:
        nonlocal free
        d = pts - o
        length = np.hypot(d[:, 0], d[:, 1])
        steps = max(1, int(np.ceil(length.max() / (0.5 * resolution_m))))
        f = np.linspace(0.0, 1.0, steps, endpoint=False)
        ray = o + f[None, :, None] * d[:, None, :]  # (n, steps, 2)
        inside = (f[None, :] * length[:, None]) < (length[:, None] - stop_m)
        free += np.bincount(flat(ray[inside]), minlength=nx * ny).astype(np.int32)

    for k, m in enumerate(clear):
        if len(m):
            clear_rays(poses[k, :2], m, 0.0)
    for k, pts in enumerate(world):
        if len(pts) == 0:
            continue
        clear_rays(poses[k, :2], pts, resolution_m)
        cells = flat(pts)
        hit += np.bincount(cells, minlength=nx * ny).astype(np.int32)
        inten = keyframes.frames[k].intensity
        if inten is not None:
            isum += np.bincount(cells, weights=inten, minlength=nx * ny)
            icnt += np.bincount(cells, minlength=nx * ny)
    state = np.full(nx * ny, UNKNOWN, dtype=np.int8)
    state[free > 0] = FREE
    state[(hit > 0) & (2 * hit >= free)] = OCCUPIED
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_i = np.where(icnt > 0, isum / icnt, np.nan)
    return OccupancyMap(lo, resolution_m, state.reshape(nx, ny), mean_i.reshape(nx, ny))
