"""One probability grid for every map chizu builds from laser scans.

The submaps of graph SLAM and the final occupancy maps of every method are the same
structure: a growable 2-D grid of occupancy probabilities updated along each beam by ray
casting (Moravec & Elfes; Hess et al. 2016, §IV: "odds" updates with a hit and a miss
probability, clamped). Per scan, a cell is updated at most once and hits win over misses
(the cell a beam ends in is never cleared by another beam of the same scan), which is
what keeps walls one cell thick instead of being painted over by grazing beams.
No-return beams clear free space only up to ``miss_cap_m``.

Cells are indexed ``[i, j]`` with ``i`` along x, the lower-left corner of cell (0, 0) at
``origin``; a value of 0 means "never observed", else the probability in
``[p_min, p_max]``. The inner loops (ray casting, bilinear lookups) are numba kernels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from pydantic import BaseModel, Field


class GridConfig(BaseModel):
    """Hit/miss model of the grid. Defaults are the probabilities a final map uses (hit
    0.7 / miss 0.4, clamped to [0.12, 0.97]); submaps use Cartographer's gentler
    0.55 / 0.49 so that a few odd beams do not flip a cell."""

    resolution_m: float = Field(0.05, gt=0, le=1.0)
    p_hit: float = Field(0.7, gt=0.5, lt=1.0)
    p_miss: float = Field(0.4, gt=0.0, lt=0.5)
    p_min: float = Field(0.12, gt=0.0, lt=0.5)
    p_max: float = Field(0.97, gt=0.5, lt=1.0)
    max_range_m: float = Field(30.0, gt=0, description="hits beyond are ignored")
    miss_cap_m: float = Field(5.0, ge=0, description="no-return beams clear this far")
    grow_margin_m: float = Field(4.0, ge=0)


@njit(cache=True)
def _odds_update(p: float, odds_factor: float, lo: float, hi: float) -> float:
    if p == 0.0:
        p = 0.5
    o = p / (1.0 - p) * odds_factor
    q = o / (1.0 + o)
    return min(max(q, lo), hi)


@njit(cache=True)
def insert_rays(prob: np.ndarray, stamp: np.ndarray, scan_id: int, ox: float, oy: float,
                ends: np.ndarray, is_hit: np.ndarray, cast: np.ndarray, hit_odds: float,
                miss_odds: float, lo: float, hi: float) -> None:
    """Update ``prob`` with one scan: ``(ox, oy)`` the sensor and ``ends (n, 2)`` the
    beam ends, both in continuous cell coordinates. Hit ends get the hit update, every
    cell a beam passes through (before its end) the miss update where ``cast`` (a
    surface point between two returns is a hit without a beam of its own); a cell is
    updated once per scan (``stamp``), hits first."""
    nx, ny = prob.shape
    for k in range(ends.shape[0]):
        if not is_hit[k]:
            continue
        i = int(math.floor(ends[k, 0]))
        j = int(math.floor(ends[k, 1]))
        if 0 <= i < nx and 0 <= j < ny and stamp[i, j] != scan_id:
            stamp[i, j] = scan_id
            prob[i, j] = _odds_update(prob[i, j], hit_odds, lo, hi)
    for k in range(ends.shape[0]):
        if not cast[k]:
            continue
        ex, ey = ends[k, 0], ends[k, 1]
        dx, dy = ex - ox, ey - oy
        i, j = int(math.floor(ox)), int(math.floor(oy))
        ei, ej = int(math.floor(ex)), int(math.floor(ey))
        si = 1 if dx > 0 else -1
        sj = 1 if dy > 0 else -1
        # Amanatides & Woo: parameter t along the beam at the next x / y cell border
        tdx = abs(1.0 / dx) if dx != 0 else 1e30
        tdy = abs(1.0 / dy) if dy != 0 else 1e30
        tx = ((i + 1 - ox) if dx > 0 else (ox - i)) * tdx if dx != 0 else 1e30
        ty = ((j + 1 - oy) if dy > 0 else (oy - j)) * tdy if dy != 0 else 1e30
        n = abs(ei - i) + abs(ej - j)
        for _ in range(n):
            if 0 <= i < nx and 0 <= j < ny and stamp[i, j] != scan_id:
                stamp[i, j] = scan_id
                prob[i, j] = _odds_update(prob[i, j], miss_odds, lo, hi)
            if tx < ty:
                tx += tdx
                i += si
            else:
                ty += tdy
                j += sj


@njit(cache=True)
def bilinear(prob: np.ndarray, x: float, y: float) -> tuple[float, float, float]:
    """Value and gradient (per cell) of ``prob`` at continuous cell coordinates, the
    value at a cell's centre being its probability (unknown = 0)."""
    nx, ny = prob.shape
    u = x - 0.5
    v = y - 0.5
    i = int(math.floor(u))
    j = int(math.floor(v))
    fu = u - i
    fv = v - j
    if i < 0 or j < 0 or i + 1 >= nx or j + 1 >= ny:
        return 0.0, 0.0, 0.0
    p00 = prob[i, j]
    p10 = prob[i + 1, j]
    p01 = prob[i, j + 1]
    p11 = prob[i + 1, j + 1]
    val = (p00 * (1 - fu) * (1 - fv) + p10 * fu * (1 - fv) + p01 * (1 - fu) * fv
           + p11 * fu * fv)
    gx = (p10 - p00) * (1 - fv) + (p11 - p01) * fv
    gy = (p01 - p00) * (1 - fu) + (p11 - p10) * fu
    return val, gx, gy


def logit(p: float) -> float:
    return float(np.log(p / (1.0 - p)))


def no_stamps(shape: tuple[int, ...]) -> np.ndarray:
    """Scan stamps for a grid nobody inserts into any more: a read-only view of one
    zero (no memory); an insert would fail loudly on it."""
    return np.broadcast_to(np.zeros(1, dtype=np.int32), shape)


@dataclass
class ProbabilityGrid:
    """A growable probability grid (see the module docstring)."""

    config: GridConfig = field(default_factory=GridConfig)
    origin: np.ndarray = field(default_factory=lambda: np.zeros(2))
    prob: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=np.float32))
    stamp: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=np.int32))
    scans: int = 0

    @property
    def resolution_m(self) -> float:
        return self.config.resolution_m

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.prob.shape[0]), int(self.prob.shape[1]))

    def to_cells(self, xy: np.ndarray) -> np.ndarray:
        """World points ``(..., 2)`` in continuous cell coordinates."""
        return np.asarray((xy - self.origin) / self.config.resolution_m)

    def ensure(self, lo: np.ndarray, hi: np.ndarray) -> None:
        """Grow the grid (with a margin) so that it covers the box ``lo``-``hi`` (m)."""
        res, m = self.config.resolution_m, self.config.grow_margin_m
        if self.prob.size:
            have_lo = self.origin
            have_hi = self.origin + np.array(self.prob.shape) * res
            if np.all(lo >= have_lo) and np.all(hi <= have_hi):
                return
            lo = np.minimum(lo - m, have_lo)
            hi = np.maximum(hi + m, have_hi)
        else:
            lo, hi = lo - m, hi + m
        lo = np.floor(lo / res) * res
        shape = np.ceil((hi - lo) / res).astype(int) + 1
        prob = np.zeros((int(shape[0]), int(shape[1])), dtype=np.float32)
        stamp = np.zeros_like(prob, dtype=np.int32)
        if self.prob.size:
            off = np.round((self.origin - lo) / res).astype(int)
            sx, sy = self.prob.shape
            prob[off[0]:off[0] + sx, off[1]:off[1] + sy] = self.prob
            stamp[off[0]:off[0] + sx, off[1]:off[1] + sy] = self.stamp
        self.origin, self.prob, self.stamp = lo, prob, stamp

    def insert(self, sensor_xy: np.ndarray, hits: np.ndarray,
               misses: np.ndarray | None = None, surface: np.ndarray | None = None) -> None:
        """Insert one scan: ``sensor_xy (2,)`` the sensor position, ``hits (n, 2)`` the
        returns and ``misses (m, 2)`` the ends of no-return beams, world frame (m);
        ``surface (s, 2)``: more occupied points, hit without ray casting (the surface
        between neighbouring returns, :func:`chizu.numeric.slam.keyframes.connect_returns`).
        Hits farther than ``max_range_m`` are ignored; misses are cut at ``miss_cap_m``."""
        cfg = self.config
        d = hits - sensor_xy
        keep = np.hypot(d[:, 0], d[:, 1]) <= cfg.max_range_m
        hits = hits[keep]
        if surface is not None and len(surface):
            d = surface - sensor_xy
            surface = surface[np.hypot(d[:, 0], d[:, 1]) <= cfg.max_range_m]
            hits = np.vstack([hits, surface])
        n_cast = len(hits) - (0 if surface is None else len(surface))
        ends = [hits]
        if misses is not None and len(misses) and cfg.miss_cap_m > 0:
            d = misses - sensor_xy
            r = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
            ends.append(sensor_xy + d * (np.minimum(r, cfg.miss_cap_m) / r)[:, None])
        allp = np.vstack([*ends, sensor_xy[None, :]])
        self.ensure(allp.min(axis=0), allp.max(axis=0))
        is_hit = np.zeros(sum(len(e) for e in ends), dtype=np.bool_)
        is_hit[:len(hits)] = True
        cast = np.ones_like(is_hit)
        cast[n_cast:len(hits)] = False
        cells = self.to_cells(np.vstack(ends))
        o = self.to_cells(sensor_xy)
        self.scans += 1
        insert_rays(self.prob, self.stamp, self.scans, float(o[0]), float(o[1]), cells,
                    is_hit, cast, cfg.p_hit / (1 - cfg.p_hit), cfg.p_miss / (1 - cfg.p_miss),
                    cfg.p_min, cfg.p_max)

    def known(self) -> np.ndarray:
        return np.asarray(self.prob > 0)

    def cropped(self) -> ProbabilityGrid:
        """The smallest grid holding every observed cell (one cell of border)."""
        k = self.known()
        if not np.any(k):
            return self
        ii = np.flatnonzero(k.any(axis=1))
        jj = np.flatnonzero(k.any(axis=0))
        i0, i1 = max(ii[0] - 1, 0), min(ii[-1] + 2, k.shape[0])
        j0, j1 = max(jj[0] - 1, 0), min(jj[-1] + 2, k.shape[1])
        res = self.config.resolution_m
        return ProbabilityGrid(self.config, self.origin + np.array([i0, j0]) * res,
                               np.ascontiguousarray(self.prob[i0:i1, j0:j1]),
                               np.ascontiguousarray(self.stamp[i0:i1, j0:j1]), self.scans)

    def frozen(self) -> ProbabilityGrid:
        """This grid, read-only from now on: the per-cell scan stamps that keep a cell to
        one update per scan are dropped (half the memory of a finished submap)."""
        return ProbabilityGrid(self.config, self.origin, self.prob, no_stamps(self.shape),
                               self.scans)

    @staticmethod
    def stitched(grids: list[ProbabilityGrid]) -> ProbabilityGrid:
        """One grid covering ``grids`` (same frame and resolution), each cell the
        largest probability any of them gives it."""
        if len(grids) == 1:
            return grids[0]
        res = grids[0].resolution_m
        lo = np.min([np.round(g.origin / res) for g in grids], axis=0).astype(int)
        hi = np.max([np.round(g.origin / res) + g.shape for g in grids], axis=0).astype(int)
        prob = np.zeros(tuple(hi - lo), dtype=np.float32)
        for g in grids:
            o = np.round(g.origin / res).astype(int) - lo
            sl = prob[o[0]:o[0] + g.shape[0], o[1]:o[1] + g.shape[1]]
            np.maximum(sl, g.prob, out=sl)
        return ProbabilityGrid(grids[0].config, lo * res, prob, no_stamps(prob.shape),
                               sum(g.scans for g in grids))

    def coarsened(self, factor: int) -> ProbabilityGrid:
        """The grid at ``factor`` times the cell size, each cell the maximum of the
        ``factor x factor`` cells it covers (so no wall is lost: what branch and bound
        needs to bound scores from above)."""
        if factor == 1:
            return self
        nx, ny = self.shape
        px, py = (-nx) % factor, (-ny) % factor
        p = np.pad(self.prob, ((0, px), (0, py)))
        p = p.reshape(p.shape[0] // factor, factor, p.shape[1] // factor, factor).max(axis=(1, 3))
        cfg = self.config.model_copy(update={"resolution_m": self.resolution_m * factor})
        return ProbabilityGrid(cfg, self.origin.copy(), np.ascontiguousarray(p),
                               no_stamps(p.shape), self.scans)

