"""The map the matchers match against: keyframe scans.

The paper's reference scan is "the previous scan plus the map points inside the sensor
range at the current estimate" (§4). chizu keeps the map as keyframes -- scans taken
whenever the robot has moved far enough -- whose points stay in their own robot frame;
a map is the keyframes placed at their poses. The single-hypothesis methods own one pose
per keyframe; every RBPF particle owns its own keyframe poses (§7.3: "each particle keeps
its own map") while the scan data are shared, so resampling copies indices, never maps.

:class:`LikelihoodField` precomputes, per keyframe and per intensity band, the distance
to the nearest keyframe point and that point's intensity on a grid, so the RBPF can
evaluate eq. 9 for hundreds of particles with array lookups.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, Field
from scipy import ndimage

from chizu.numeric.geometry import place


class MapConfig(BaseModel):
    """When to match and when to add a keyframe, and which keyframes form a reference."""

    update_linear_m: float = Field(0.1, ge=0, description="match after this much travel")
    update_angular_rad: float = Field(0.1, ge=0, description="... or this much turn")
    keyframe_linear_m: float = Field(0.3, ge=0)
    keyframe_angular_rad: float = Field(0.2, ge=0)
    recent_keyframes: int = Field(8, ge=1, description="always part of the reference")
    nearby_radius_m: float = Field(6.0, ge=0, description="older keyframes this close join")
    nearby_keyframes: int = Field(12, ge=0, description="... at most this many of them")
    voxel_m: float = Field(0.05, gt=0, description="reference down-sampling")
    max_points_m: float = Field(15.0, gt=0, description="keyframe points farther are dropped")
    open_points_m: float | None = Field(
        None, gt=0, description="the reach of an open scan (see open_share); None: "
                                "max_points_m for every scan")
    open_share: float = Field(0.1, ge=0, le=1, description="a scan is open when more than "
                              "this share of its returns lie beyond max_points_m")
    connect_gap_m: float | None = Field(
        None, gt=0, description="likelihood fields: join neighbouring returns closer than "
                                "this into a surface (None: the returns alone)")


def moved(a: np.ndarray, b: np.ndarray, linear_m: float, angular_rad: float) -> bool:
    """True when pose ``b`` is at least ``linear_m`` or ``angular_rad`` away from ``a``."""
    d = np.hypot(b[0] - a[0], b[1] - a[1])
    t = abs((b[2] - a[2] + np.pi) % (2 * np.pi) - np.pi)
    return bool(d >= linear_m or t >= angular_rad)


def voxel_downsample(xy: np.ndarray, intensity: np.ndarray | None, voxel_m: float,
                     ) -> tuple[np.ndarray, np.ndarray | None]:
    """One point (the first) per ``voxel_m`` cell."""
    if len(xy) == 0:
        return xy, intensity
    keys = np.floor(xy / voxel_m).astype(np.int64)
    _, first = np.unique(keys[:, 0] * 4_000_003 + keys[:, 1], return_index=True)
    return xy[first], None if intensity is None else intensity[first]


#: joined neighbours must not look along the beam: a segment within this angle of the
#: ray is a depth jump (an edge in front of a farther wall), not a surface
MIN_SURFACE_ANGLE_RAD = np.deg2rad(15.0)


def _segments(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(seg, gap, sin_to_ray)`` of the segments between consecutive returns (beam
    order, robot frame): the vector, its length, and the sine of its angle to the ray
    through its middle."""
    seg = xy[1:] - xy[:-1]
    gap = np.hypot(seg[:, 0], seg[:, 1])
    mid = 0.5 * (xy[1:] + xy[:-1])
    ray = np.maximum(np.hypot(mid[:, 0], mid[:, 1]), 1e-9)
    cross = np.abs(seg[:, 0] * mid[:, 1] - seg[:, 1] * mid[:, 0])
    return seg, gap, cross / np.maximum(gap * ray, 1e-12)


def grazing_returns(xy: np.ndarray) -> np.ndarray:
    """Mask of the returns (beam order, robot frame) whose segments to both neighbours lie
    within :data:`MIN_SURFACE_ANGLE_RAD` of the ray: a surface seen at grazing incidence
    (a corridor's side wall far ahead), where consecutive beams land far apart (1.7 m at
    10 m along a wall 1 m to the side, for 1° beams). One scan draws such a wall as a
    dotted line that moves with the robot, so a scan from a little farther matches it
    best where it was taken; the two ends of a scan count as having a grazing side."""
    out = np.zeros(len(xy), dtype=bool)
    if len(xy) < 3:
        return out
    _, _, sin_to_ray = _segments(xy)
    g = sin_to_ray < np.sin(MIN_SURFACE_ANGLE_RAD)
    out[1:-1] = g[:-1] & g[1:]
    out[0], out[-1] = g[0], g[-1]
    return out


#: a return lies on the line through its two neighbours when it is within this of it
COLLINEAR_M = 0.03


def collinear_grazing_segments(xy: np.ndarray, max_gap_m: float) -> np.ndarray:
    """Mask over the segments between consecutive returns (beam order, robot frame):
    those within :data:`MIN_SURFACE_ANGLE_RAD` of the ray, at most ``max_gap_m`` long,
    whose two ends each lie within :data:`COLLINEAR_M` of the line through their own
    neighbours. A wall seen at grazing incidence is such a run of collinear returns
    spaced ever farther apart; a depth jump (an edge in front of a farther wall) breaks
    the line at the edge, since the jump's two ends each have a neighbour off it."""
    if len(xy) < 4:
        return np.zeros(max(len(xy) - 1, 0), dtype=bool)
    _, gap, sin_to_ray = _segments(xy)
    a, b, c = xy[:-2], xy[1:-1], xy[2:]
    ac = c - a
    dist = np.abs(ac[:, 0] * (b - a)[:, 1] - ac[:, 1] * (b - a)[:, 0]) / np.maximum(
        np.hypot(ac[:, 0], ac[:, 1]), 1e-12)
    on_line = np.zeros(len(xy), dtype=bool)
    on_line[1:-1] = dist < COLLINEAR_M  # return i: between returns i - 1 and i + 1
    return ((sin_to_ray < np.sin(MIN_SURFACE_ANGLE_RAD)) & (gap <= max_gap_m)
            & on_line[:-1] & on_line[1:])


def connect_returns(xy: np.ndarray, intensity: np.ndarray | None, max_gap_m: float,
                    step_m: float, grazing_gap_m: float | None = None,
                    ) -> tuple[np.ndarray, np.ndarray | None]:
    """The scan as a polyline: points every ``step_m`` along the segment between two
    consecutive returns (beam order, robot frame) when they are at most ``max_gap_m``
    apart and the segment is not within :data:`MIN_SURFACE_ANGLE_RAD` of the ray.

    A single scan's returns thin out with range (0.35 m apart at 20 m for 1 deg beams),
    so a likelihood field of the returns alone charges a beam that hits a far wall
    between two of them for the gap; against the polyline it is charged for its
    distance to the surface, the point-to-line residual of Censi's PL-ICP
    ("An ICP variant using a point-to-line metric", ICRA 2008). Intensities are
    interpolated along the segment.

    With ``grazing_gap_m`` the segments of a wall seen at grazing incidence are joined
    too, up to that length (:func:`collinear_grazing_segments`): one scan draws such a
    wall as dots that move with the robot, and a scan from a little farther fits those
    dots best where the first was taken; drawn as a line the wall fixes the scan
    across itself and leaves it free along itself."""
    if len(xy) < 2:
        return xy, intensity
    a = xy[:-1]
    seg, gap, sin_to_ray = _segments(xy)
    join = (gap > step_m) & (gap <= max_gap_m) & (sin_to_ray >= np.sin(MIN_SURFACE_ANGLE_RAD))
    if grazing_gap_m is not None:
        join |= (gap > step_m) & collinear_grazing_segments(xy, grazing_gap_m)
    k = np.flatnonzero(join)
    if len(k) == 0:
        return xy, intensity
    n = np.ceil(gap[k] / step_m).astype(int) - 1  # inner points per joined segment
    seg_of = np.repeat(k, n)
    frac = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n) + 1) / np.repeat(n + 1, n)
    inner = a[seg_of] + frac[:, None] * seg[seg_of]
    out = np.vstack([xy, inner])
    if intensity is None:
        return out, None
    li = intensity[seg_of] + frac * (intensity[seg_of + 1] - intensity[seg_of])
    return out, np.concatenate([intensity, li])


@dataclass
class Keyframe:
    """Scan data of one keyframe in its own robot frame (shared by every hypothesis);
    ``surface`` is what its likelihood field is made of when it differs from the
    returns (:func:`connect_returns`)."""

    scan_index: int
    xy: np.ndarray
    intensity: np.ndarray | None
    misses: np.ndarray | None = None  # ends of no-return beams (robot frame), for maps
    surface: tuple[np.ndarray, np.ndarray | None] | None = None


@dataclass
class Keyframes:
    """The keyframe scans of a run; poses live with the hypotheses that place them."""

    config: MapConfig
    frames: list[Keyframe] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.frames)

    def reach(self, xy: np.ndarray) -> float:
        """How far the returns ``xy`` (robot frame) of one scan are used: ``max_points_m``,
        or ``open_points_m`` when more than ``open_share`` of them lie beyond it.

        Within ``max_points_m`` the beams are dense and the keyframes' far points, placed
        with their keyframe's heading error, cannot mislead a near beam. But in an open
        scan -- an atrium or a long hall -- the near returns may not pin the heading
        at all: fr-clinic at 1 780 s sees a curved wall within 15 m (turning about its
        centre changes nothing) and the walls that fix the heading 20-38 m away. Among
        the benchmark logs the rule picks fr-clinic's scans (85 % have more than 10 %
        of their returns beyond 15 m), a few of aces' (0.7 %), and none of fr079's or
        mit-csail's."""
        return self._reach_of(np.hypot(xy[:, 0], xy[:, 1]))

    def in_reach(self, xy: np.ndarray) -> np.ndarray:
        """Which of the returns ``xy`` (robot frame) of one scan lie within its
        :meth:`reach` (the ranges computed once)."""
        r = np.hypot(xy[:, 0], xy[:, 1])
        return np.asarray(r <= self._reach_of(r))

    def _reach_of(self, ranges: np.ndarray) -> float:
        cfg = self.config
        if cfg.open_points_m is None or len(ranges) == 0:
            return cfg.max_points_m
        open_scan = np.mean(ranges > cfg.max_points_m) > cfg.open_share
        return cfg.open_points_m if open_scan else cfg.max_points_m

    def add(self, scan_index: int, xy: np.ndarray, intensity: np.ndarray | None,
            misses: np.ndarray | None = None) -> int:
        cfg = self.config
        near = self.in_reach(xy)
        xy, intensity = xy[near], None if intensity is None else intensity[near]
        surface = None
        if cfg.connect_gap_m is not None:
            surface = voxel_downsample(*connect_returns(xy, intensity, cfg.connect_gap_m,
                                                        cfg.voxel_m), cfg.voxel_m)
        xy, intensity = voxel_downsample(xy, intensity, cfg.voxel_m)
        self.frames.append(Keyframe(scan_index, xy, intensity, misses, surface))
        return len(self.frames) - 1

    def forget(self, k: int) -> None:
        """Drop keyframe ``k``'s returns (a lifelong run's, where the map already holds
        the place); it stays, empty, so that keyframe indices keep their meaning."""
        f = self.frames[k]
        self.frames[k] = Keyframe(f.scan_index, np.zeros((0, 2)),
                                  None if f.intensity is None else np.zeros(0),
                                  None if f.misses is None else np.zeros((0, 2)))

    def select(self, pose: np.ndarray, kf_xy: np.ndarray) -> np.ndarray:
        """Keyframes forming the reference at ``pose``: the ``recent_keyframes`` last ones
        and up to ``nearby_keyframes`` older ones within ``nearby_radius_m`` (``kf_xy`` =
        the keyframe positions of the hypothesis)."""
        n = len(self.frames)
        cfg = self.config
        recent = np.arange(max(0, n - cfg.recent_keyframes), n)
        old = n - len(recent)
        if old == 0 or cfg.nearby_keyframes == 0:
            return recent
        d = np.hypot(kf_xy[:old, 0] - pose[0], kf_xy[:old, 1] - pose[1])
        cand = np.flatnonzero(d <= cfg.nearby_radius_m)
        cand = cand[np.argsort(d[cand])[:cfg.nearby_keyframes]]
        return np.concatenate([np.sort(cand), recent])

    def reference(self, chosen: np.ndarray, poses: np.ndarray,
                  extra: tuple[np.ndarray, np.ndarray | None] | None = None,
                  ) -> tuple[np.ndarray, np.ndarray | None]:
        """World points and intensities of keyframes ``chosen`` placed at ``poses``,
        plus the ``extra`` world points (the previous scan), down-sampled once."""
        xy = [place(self.frames[k].xy, poses[k]) for k in chosen]
        it: list[np.ndarray | None] = [self.frames[k].intensity for k in chosen]
        if extra is not None:
            xy.append(extra[0])
            it.append(extra[1])
        pts = np.vstack(xy) if xy else np.zeros((0, 2))
        have = [i for i in it if i is not None]
        inten = np.concatenate(have) if have and len(have) == len(it) else None
        return voxel_downsample(pts, inten, self.config.voxel_m)


class FieldConfig(BaseModel):
    """Grid of the likelihood fields (eq. 9 lookups)."""

    resolution_m: float = Field(0.05, gt=0)
    cutoff_m: float = Field(0.3, gt=0, description="residual cap: no correspondence beyond")
    intensity_bands: int = Field(6, ge=1, le=32)
    cache_size: int = Field(96, ge=1)


class LikelihoodField:
    """For one keyframe: per intensity band, the distance from every grid cell to the
    nearest keyframe point of that band and that point's intensity.

    With one band (no intensities, or alpha = 0) this is the classic likelihood field;
    with several, ``min_b (d_b^2 + alpha (l_b - l_z)^2)`` approximates the augmented
    nearest neighbour of eq. 1 (exact up to the spread of intensities inside a band).
    """

    def __init__(self, kf: Keyframe, config: FieldConfig, band_edges: np.ndarray | None) -> None:
        res, cut = config.resolution_m, config.cutoff_m
        self.res = res
        self.cut2 = cut * cut
        xy, kf_intensity = kf.surface if kf.surface is not None else (kf.xy, kf.intensity)
        self.origin = xy.min(axis=0) - cut - res
        shape = np.ceil((xy.max(axis=0) + cut + res - self.origin) / res).astype(int) + 1
        self.shape = (int(shape[0]), int(shape[1]))
        cells = np.floor((xy - self.origin) / res).astype(int)
        if band_edges is None or kf_intensity is None:
            bands = np.zeros(len(xy), dtype=int)
            n_bands = 1
        else:
            bands = np.clip(np.searchsorted(band_edges, kf_intensity) - 1, 0, len(band_edges) - 2)
            n_bands = len(band_edges) - 1
        self.dist2 = np.full((n_bands, *self.shape), self.cut2, dtype=np.float32)
        self.inten = np.zeros((n_bands, *self.shape), dtype=np.float32)
        for b in range(n_bands):
            m = bands == b
            if not np.any(m):
                continue
            occ = np.zeros(self.shape, dtype=bool)
            occ[cells[m, 0], cells[m, 1]] = True
            if kf_intensity is None:  # the nearest return's intensity stays 0
                d = ndimage.distance_transform_edt(~occ)
            else:
                val = np.zeros(self.shape, dtype=np.float32)
                val[cells[m, 0], cells[m, 1]] = kf_intensity[m]
                d, (ix, iy) = ndimage.distance_transform_edt(~occ, return_indices=True)
                self.inten[b] = val[ix, iy]
            self.dist2[b] = np.minimum((d * res) ** 2, self.cut2)

    def residual(self, xy: np.ndarray, intensity: np.ndarray | None, alpha: float) -> np.ndarray:
        """Per point (any leading shape, last axis 2, keyframe frame) the capped
        augmented squared residual ``min(cutoff^2, min_b d_b^2 + alpha (l_b - l)^2)``."""
        c = np.floor((xy - self.origin) / self.res).astype(np.intp)
        inside = ((c[..., 0] >= 0) & (c[..., 0] < self.shape[0])
                  & (c[..., 1] >= 0) & (c[..., 1] < self.shape[1]))
        cx = np.where(inside, c[..., 0], 0)
        cy = np.where(inside, c[..., 1], 0)
        d2 = self.dist2[:, cx, cy]  # (bands, ...)
        if alpha > 0 and intensity is not None:
            d2 = d2 + alpha * (self.inten[:, cx, cy] - intensity) ** 2
        best = d2.min(axis=0)
        return np.where(inside, np.minimum(best, self.cut2), self.cut2)


class FieldCache:
    """Likelihood fields of the keyframes in use (least recently used dropped)."""

    def __init__(self, keyframes: Keyframes, config: FieldConfig,
                 band_edges: np.ndarray | None) -> None:
        self.keyframes = keyframes
        self.config = config
        self.band_edges = band_edges
        self._cache: OrderedDict[int, LikelihoodField] = OrderedDict()

    def get(self, k: int) -> LikelihoodField:
        f = self._cache.get(k)
        if f is None:
            f = LikelihoodField(self.keyframes.frames[k], self.config, self.band_edges)
            self._cache[k] = f
            if len(self._cache) > self.config.cache_size:
                self._cache.popitem(last=False)
        else:
            self._cache.move_to_end(k)
        return f

