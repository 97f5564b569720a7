"""Intensity-ICP scan matching (§4, eqs. 1-3).

The measured scan z (robot frame) is placed at the initial pose estimate (z_1) and
aligned to the reference scan m by repeating three steps:

1. correspondence (eq. 1): for every scan point the reference point minimising
   ``||s_m - s_z||^2 + alpha * (l_m - l_z)^2``, i.e. the nearest neighbour in the
   augmented space ``(x, y, sqrt(alpha) * l)``, found with a :class:`scipy.spatial.cKDTree`;
   pairs farther than ``max_correspondence_m`` or ``trim_factor`` x the median pair
   distance (both augmented) are rejected as outliers;
2. the rigid transform ``T_r`` minimising eq. 2, ``F = 1/N sum ||s_m - T_r s_z1||^2``,
   here in closed form (SVD of the 2x2 cross-covariance; the paper used Newton's method
   on the same objective), or, with ``metric="line"``, the point-to-line variant
   (Gauss-Newton on the reference's normals, for long straight walls);
3. re-place the scan with ``T_r`` (eq. 3) and repeat until the update is below the
   tolerances.

The iterations run in one compiled kernel (:func:`icp_iterations`, numba, releasing the
GIL) on a bucket index of the reference (:class:`Reference`: its points sorted by cells of the
correspondence radius); graph SLAM's global scan alignment runs tens of thousands of
these matches per log on a thread pool, where per-iteration NumPy calls on a few
hundred points cost more than the arithmetic.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Literal, NamedTuple

import numpy as np
from numba import njit
from pydantic import BaseModel, Field
from scipy.spatial import cKDTree

from chizu.numeric.errors import InvalidInput
from chizu.numeric.geometry import compose, compose_into, place_into, relative, wrap_scalar


class IcpConfig(BaseModel):
    """Parameters of Intensity-ICP. ``alpha`` weighs intensity against position in eq. 1
    (m² per intensity unit²: with the URG's 0-40 000 scale, 1e-9 makes a contrast of
    10 000 count as 0.32 m); 0 gives plain geometric ICP."""


    alpha: float = Field(0.0, ge=0, allow_inf_nan=False)
    metric: Literal["point", "line"] = "point"
    max_iterations: int = Field(40, ge=1, le=1000)
    max_correspondence_m: float = Field(1.0, gt=0)
    trim_factor: float = Field(3.0, gt=0,
                               description="reject pairs beyond k x median (augmented) distance")
    trim_floor_m: float = Field(0.05, ge=0, description="never trim pairs closer than this")
    tolerance_m: float = Field(1e-4, gt=0)
    tolerance_rad: float = Field(1e-4, gt=0)
    min_inliers: int = Field(10, ge=3)


@dataclass(frozen=True)
class IcpResult:
    """Outcome of one match: the aligned pose (world frame), the correction applied to
    the initial estimate (``transform``, in the initial estimate's frame), whether the
    updates fell below the tolerances, iterations used, inlier pairs, and the mean
    augmented squared residual of the inliers (eq. 9's ``d_t``)."""

    pose: np.ndarray
    transform: np.ndarray
    converged: bool
    iterations: int
    inliers: int
    residual: float

    def usable(self, scan_points: int, config: IcpConfig) -> bool:
        """Enough of the scan found partners (at least 30 % and ``min_inliers``) for the
        pose to be worth considering."""
        return self.inliers >= max(config.min_inliers, 0.3 * scan_points)


class RefIndex(NamedTuple):
    """A reference as the compiled kernels take it: its points ``xy (M, 2)``, their
    augmented coordinates ``aug (M, 2 or 3)`` (eq. 1), line normals ``(M, 2)`` (``(0, 2)``
    for the point metric) and the bucket index: sorted cell keys, the points' order
    under them, the origin (``ox``, ``oy``), the ``cell`` size (m) and the last cell row
    and column ``top``."""

    xy: np.ndarray
    aug: np.ndarray
    normals: np.ndarray
    keys: np.ndarray
    order: np.ndarray
    ox: float
    oy: float
    cell: float
    top: np.ndarray


class IcpSteps(NamedTuple):
    """The iterations' settings as the compiled kernel takes them (from
    :class:`IcpConfig`): point-to-line or point-to-point, at most ``max_iterations``,
    pairs within ``max_corr`` (m) trimmed at ``max(trim_floor, trim_factor x median)``,
    converged below ``tol_m`` / ``tol_rad``, failed below ``min_inliers`` pairs."""

    line: bool
    max_iterations: int
    max_corr: float
    trim_factor: float
    trim_floor: float
    tol_m: float
    tol_rad: float
    min_inliers: int

    @staticmethod
    def of(config: IcpConfig, line: bool) -> IcpSteps:
        return IcpSteps(bool(line), int(config.max_iterations),
                        float(config.max_correspondence_m), float(config.trim_factor),
                        float(config.trim_floor_m), float(config.tolerance_m),
                        float(config.tolerance_rad), int(config.min_inliers))


class Reference:
    """Reference scan m (world-frame points ``(M, 2)`` with intensities) indexed in the
    augmented space of eq. 1: its points sorted into square cells of ``cell_m`` (the
    nearest point within a radius ``r`` lies in the ``ceil(r / cell_m)`` rings of cells
    around a query's own, since the augmented distance is never below the planar one)."""

    def __init__(self, xy: np.ndarray, intensity: np.ndarray | None, alpha: float,
                 cell_m: float = 0.3) -> None:
        if len(xy) == 0:
            raise InvalidInput("the reference scan is empty", field="reference")
        self.xy = np.ascontiguousarray(xy, dtype=float)
        self.alpha = alpha if intensity is not None else 0.0
        self.intensity = intensity
        self._w = np.sqrt(self.alpha)
        self.aug = np.ascontiguousarray(
            self.xy if self.alpha == 0 else np.column_stack([self.xy, self._w * intensity]))
        self.cell_m = float(cell_m)
        self.origin = self.xy.min(axis=0)
        self.keys, self.order = _bucket(self.xy, self.origin, self.cell_m)
        # the last cell row and column that hold points (the first are 0)
        self.top = np.array([_cell(v, o, self.cell_m)
                             for v, o in zip(self.xy.max(axis=0), self.origin, strict=True)])

    @property
    def index(self) -> tuple[np.ndarray, np.ndarray, float, float, float, np.ndarray]:
        """The bucket index as the compiled kernels take it: sorted cell keys, the
        points' order under them, the origin (x, y), the cell size and the last cell
        row and column."""
        return self.keys, self.order, self.origin[0], self.origin[1], self.cell_m, self.top

    def kernel(self, line: bool) -> RefIndex:
        """This reference as the compiled kernels take it; with ``line`` its normals."""
        return RefIndex(self.xy, self.aug, self.normals if line else np.zeros((0, 2)),
                        *self.index)

    def intensity_column(self, intensity: np.ndarray | None, n: int) -> np.ndarray:
        """The augmented coordinates beyond x, y of ``n`` scan points ``(n, 0 or 1)``
        (eq. 1's weighted intensity), as the compiled kernels take them."""
        if self.alpha == 0:
            return np.zeros((n, 0))
        return np.ascontiguousarray(self.augment(np.zeros((n, 2)), intensity)[:, 2:])

    def augment(self, xy: np.ndarray, intensity: np.ndarray | None) -> np.ndarray:
        if self.alpha == 0 or intensity is None:
            if self.alpha == 0:
                return xy
            intensity = np.zeros(len(xy))
        return np.column_stack([xy, self._w * intensity])

    def nearest(self, xy: np.ndarray, intensity: np.ndarray | None,
                upper_m: float) -> tuple[np.ndarray, np.ndarray]:
        """Augmented distance and reference index per point (eq. 1); ``inf`` / ``M``
        beyond ``upper_m``."""
        q = np.ascontiguousarray(self.augment(np.asarray(xy, dtype=float), intensity),
                                 dtype=float)
        return nearest_points(self.aug, *self.index, q, float(upper_m))

    @cached_property
    def normals(self) -> np.ndarray:
        """Unit normals ``(M, 2)`` from the principal axes of each point's 6 nearest
        geometric neighbours (for the point-to-line metric)."""
        k = min(6, len(self.xy))
        _, idx = cKDTree(self.xy).query(self.xy, k=k)
        nb = self.xy[np.atleast_2d(idx).reshape(len(self.xy), k)]
        c = nb - nb.mean(axis=1, keepdims=True)
        cov = np.einsum("nki,nkj->nij", c, c)
        _, vec = np.linalg.eigh(cov)
        return np.ascontiguousarray(vec[:, :, 0])


#: cell keys: (ix + _OFF) * _STRIDE + (iy + _OFF), cells clipped to +-_OFF
_OFF = 1 << 20
_STRIDE = 1 << 22


@njit(cache=True, nogil=True)
def _cell(v: float, o: float, cell: float) -> int:
    c = np.floor((v - o) / cell)
    return int(min(max(c, -_OFF), _OFF))


@njit(cache=True, nogil=True)
def _bucket(xy: np.ndarray, origin: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Cell keys of the points, sorted, and the points' order under them."""
    keys = np.empty(len(xy), dtype=np.int64)
    for i in range(len(xy)):
        keys[i] = ((_cell(xy[i, 0], origin[0], cell) + _OFF) * _STRIDE
                   + _cell(xy[i, 1], origin[1], cell) + _OFF)
    order = np.argsort(keys, kind="mergesort")
    return keys[order], order


@njit(cache=True, nogil=True)
def nearest_points(ref: np.ndarray, keys: np.ndarray, order: np.ndarray, ox: float,
                   oy: float, cell: float, top: np.ndarray, q: np.ndarray, upper: float,
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 1's nearest reference point (augmented distance) of each query row, closer
    than ``upper``: distances (``inf`` for none) and indices (``len(ref)`` for none).
    Only the cells within ``upper`` that hold points (up to row / column ``top``) are
    visited, so a large radius costs no more than the reference's extent."""
    n, dim = q.shape
    span = int(np.ceil(upper / cell))
    dist = np.full(n, np.inf)
    idx = np.full(n, len(ref), dtype=np.int64)
    up2 = upper * upper
    for i in range(n):
        cx, cy = _cell(q[i, 0], ox, cell), _cell(q[i, 1], oy, cell)
        best, bi = up2, -1
        y0, y1 = max(cy - span, 0), min(cy + span, top[1])
        if y0 > y1:
            continue
        for gx in range(max(cx - span, 0), min(cx + span, top[0]) + 1):
            lo_key = (gx + _OFF) * _STRIDE + y0 + _OFF
            lo = np.searchsorted(keys, lo_key)
            hi = np.searchsorted(keys, lo_key + (y1 - y0), side="right")
            for j in range(lo, hi):
                r = order[j]
                d2 = 0.0
                for k in range(dim):
                    e = ref[r, k] - q[i, k]
                    d2 += e * e
                if d2 < best or (d2 == best and bi >= 0 and r < bi):
                    best, bi = d2, r
        if bi >= 0 and best < up2:
            dist[i] = np.sqrt(best)
            idx[i] = bi
    return dist, idx


def intensity_icp(reference: Reference, scan_xy: np.ndarray, scan_intensity: np.ndarray | None,
                  initial_pose: np.ndarray, config: IcpConfig) -> IcpResult:
    """Align the scan (robot-frame points ``(N, 2)``, intensities ``(N,)``) to
    ``reference``, starting from ``initial_pose``; eqs. 1-3."""
    init = np.asarray(initial_pose, dtype=float)
    if len(scan_xy) < config.min_inliers:
        return IcpResult(init.copy(), np.zeros(3), False, 0, 0, np.inf)
    xy = np.ascontiguousarray(scan_xy, dtype=float)
    line = config.metric == "line"
    total, converged, iterations, inl, resid = icp_iterations(
        reference.kernel(line), xy, reference.intensity_column(scan_intensity, len(xy)), init,
        IcpSteps.of(config, line))
    pose = compose(total, init)  # the pose whose scan lands where the last step put it
    return IcpResult(pose, relative(init, pose), bool(converged), int(iterations), int(inl),
                     float(resid))


@njit(cache=True, nogil=True)
def icp_iterations(ref: RefIndex, xy: np.ndarray, extra: np.ndarray, init: np.ndarray,
                   steps: IcpSteps) -> tuple[np.ndarray, bool, int, int, float]:
    """Steps 1-3 until the update is below the tolerances: the world-frame transform
    applied to the scan placed at ``init`` (eq. 3's accumulated ``T_r``), whether it
    converged, the iterations, the last step's inlier pairs and their mean augmented
    squared residual. ``extra (N, 0 or 1)``: the scan's augmented coordinates beyond
    x, y (:meth:`Reference.intensity_column`)."""
    ref_xy, ref_aug, normals = ref.xy, ref.aug, ref.normals
    keys, order, ox, oy, cell, top = ref.keys, ref.order, ref.ox, ref.oy, ref.cell, ref.top
    line, max_iterations, max_corr = steps.line, steps.max_iterations, steps.max_corr
    trim_factor, trim_floor, min_inliers = steps.trim_factor, steps.trim_floor, steps.min_inliers
    tol_m, tol_rad = steps.tol_m, steps.tol_rad
    n = len(xy)
    dim = ref_aug.shape[1]
    z1 = np.empty((n, 2))
    place_into(xy, init, z1)
    q = np.empty((n, dim))
    q[:, :2] = z1
    for k in range(2, dim):
        q[:, k] = extra[:, k - 2]
    total = np.zeros(3)
    converged, iterations, inl, resid = False, 0, 0, np.inf
    for it in range(1, max_iterations + 1):
        iterations = it
        d, idx = nearest_points(ref_aug, keys, order, ox, oy, cell, top, q, max_corr)
        ok = np.flatnonzero(np.isfinite(d))
        if len(ok) < min_inliers:
            break
        cut = max(trim_floor, trim_factor * np.median(d[ok]))
        sel = ok[d[ok] <= cut]
        inl = len(sel)
        if inl < min_inliers:
            break
        resid = np.mean(d[sel] ** 2)
        step = np.zeros(3)
        if line:
            h, g, _ = line_normal_equations(q, ref_xy, normals, idx, sel)
            for a in range(3):
                h[a, a] += 1e-9
            step[:] = -np.linalg.solve(h, g)
        else:
            src = q[sel, :2]
            dst = ref_xy[idx[sel]]
            cs = np.array([src[:, 0].mean(), src[:, 1].mean()])
            cd = np.array([dst[:, 0].mean(), dst[:, 1].mean()])
            hm = np.ascontiguousarray((src - cs).T) @ np.ascontiguousarray(dst - cd)
            u, _, vt = np.linalg.svd(hm)
            rot = vt.T @ u.T
            if np.linalg.det(rot) < 0:
                vt[1] *= -1
                rot = vt.T @ u.T
            t = cd - rot @ cs
            step = np.array([t[0], t[1], np.arctan2(rot[1, 0], rot[0, 0])])
        # total = compose(step, total): the world-frame step after the accumulated one
        after = np.empty(3)
        compose_into(step, total, after)
        after[2] = wrap_scalar(after[2])
        total = after
        place_into(z1, total, q)
        if np.hypot(step[0], step[1]) < tol_m and abs(step[2]) < tol_rad:
            converged = True
            break
    return total, converged, iterations, inl, resid


@njit(cache=True, nogil=True)
def line_normal_equations(q: np.ndarray, ref_xy: np.ndarray, normals: np.ndarray,
                          idx: np.ndarray, rows: np.ndarray,
                          ) -> tuple[np.ndarray, np.ndarray, float]:
    """The point-to-line objective ``sum (n . (p - m))^2`` over the scan points ``q[rows]``
    (world frame) and their partners ``idx[rows]`` in the reference, linearised in the
    pose (small angle): ``J^T J``, ``J^T r`` and ``sum r^2``, the Jacobian's rows
    ``(n_x, n_y, n_y p_x - n_x p_y)``."""
    h = np.zeros((3, 3))
    g = np.zeros(3)
    sq = 0.0
    j = np.empty(3)
    for m in rows:
        r = idx[m]
        nx, ny = normals[r, 0], normals[r, 1]
        j[0], j[1], j[2] = nx, ny, ny * q[m, 0] - nx * q[m, 1]
        e = nx * (q[m, 0] - ref_xy[r, 0]) + ny * (q[m, 1] - ref_xy[r, 1])
        sq += e * e
        for a in range(3):
            g[a] += j[a] * e
            for b in range(3):
                h[a, b] += j[a] * j[b]
    return h, g, sq
