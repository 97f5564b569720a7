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
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Literal

import numpy as np
from pydantic import BaseModel, Field
from scipy.spatial import cKDTree

from numeric.errors import InvalidInput
from numeric.geometry import compose, place, relative


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


class Reference:
    """Reference scan m (world-frame points ``(M, 2)`` with intensities) indexed in the
    augmented space of eq. 1."""

    def __init__(self, xy: np.ndarray, intensity: np.ndarray | None, alpha: float) -> None:
        if len(xy) == 0:
            raise InvalidInput("the reference scan is empty", field="reference")
        self.xy = np.asarray(xy, dtype=float)
        self.alpha = alpha if intensity is not None else 0.0
        self.intensity = intensity
        self._w = np.sqrt(self.alpha)
        aug = self.xy if self.alpha == 0 else np.column_stack([self.xy, self._w * intensity])
        self.tree = cKDTree(aug)

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
        d, i = self.tree.query(self.augment(xy, intensity), distance_upper_bound=upper_m)
        return d, i

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
        return np.asarray(vec[:, :, 0])


def rigid_step_point(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """The (x, y, theta) minimising eq. 2, ``sum ||dst - (R src + t)||^2``, in closed
    form (centroids and the SVD of the 2x2 cross-covariance)."""
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    h = (src - cs).T @ (dst - cd)
    u, _, vt = np.linalg.svd(h)
    r = vt.T @ u.T
    if np.linalg.det(r) < 0:
        vt[1] *= -1
        r = vt.T @ u.T
    t = cd - r @ cs
    return np.array([t[0], t[1], np.arctan2(r[1, 0], r[0, 0])])


def rigid_step_line(src: np.ndarray, dst: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """One Gauss-Newton step of the point-to-line objective
    ``sum (n . (R src + t - dst))^2`` (small-angle linearisation)."""
    n = normals
    j = np.column_stack([n[:, 0], n[:, 1], n[:, 1] * src[:, 0] - n[:, 0] * src[:, 1]])
    r = np.einsum("ij,ij->i", n, src - dst)
    h = j.T @ j + 1e-9 * np.eye(3)
    return np.asarray(-np.linalg.solve(h, j.T @ r))


def intensity_icp(reference: Reference, scan_xy: np.ndarray, scan_intensity: np.ndarray | None,
                  initial_pose: np.ndarray, config: IcpConfig) -> IcpResult:
    """Align the scan (robot-frame points ``(N, 2)``, intensities ``(N,)``) to
    ``reference``, starting from ``initial_pose``; eqs. 1-3."""
    init = np.asarray(initial_pose, dtype=float)
    if len(scan_xy) < config.min_inliers:
        return IcpResult(init.copy(), np.zeros(3), False, 0, 0, np.inf)
    z1 = place(scan_xy, init)
    total = np.zeros(3)  # world-frame transform applied to z1 (eq. 3)
    cur = z1
    converged, iterations, inl, resid = False, 0, 0, np.inf
    for it in range(1, config.max_iterations + 1):
        iterations = it
        d, idx = reference.nearest(cur, scan_intensity, config.max_correspondence_m)
        ok = np.isfinite(d)
        if ok.sum() < config.min_inliers:
            break
        keep = d[ok] <= max(config.trim_floor_m, config.trim_factor * float(np.median(d[ok])))
        sel = np.flatnonzero(ok)[keep]
        inl = len(sel)
        if inl < config.min_inliers:
            break
        resid = float(np.mean(d[sel] ** 2))
        dst = reference.xy[idx[sel]]
        if config.metric == "point":
            step = rigid_step_point(cur[sel], dst)
        else:
            step = rigid_step_line(cur[sel], dst, reference.normals[idx[sel]])
        total = compose(step, total)  # the world-frame step after the accumulated one
        cur = place(z1, total)
        if np.hypot(step[0], step[1]) < config.tolerance_m and abs(step[2]) < config.tolerance_rad:
            converged = True
            break
    pose = compose(total, init)  # the pose whose scan lands on ``cur``
    return IcpResult(pose, relative(init, pose), converged, iterations, inl, resid)
