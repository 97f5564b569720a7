"""The one geometry module: angles, segments, line of sight and ray casting.

Conventions: SI units, points as ``(N, 2)`` float arrays in the world frame,
angles in radians wrapped to (-pi, pi].
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
_EPS = 1e-12


def wrap_angle(a: ArrayLike) -> FloatArray:
    """Wrap angles to (-pi, pi]."""
    w = np.mod(np.asarray(a, dtype=float) + np.pi, 2.0 * np.pi) - np.pi
    return np.where(w <= -np.pi, w + 2.0 * np.pi, w)


@njit(cache=True, nogil=True)
def wrap_scalar(a: float) -> float:
    """:func:`wrap_angle` of one angle, for compiled kernels."""
    w = (a + math.pi) % (2.0 * math.pi) - math.pi
    return w + 2.0 * math.pi if w <= -math.pi else w


@njit(cache=True, nogil=True)
def compose_into(x0: np.ndarray, u: np.ndarray, out: np.ndarray) -> None:
    """``out = x0 (+) u`` (:func:`compose` of one pose, for compiled kernels), the
    heading left unwrapped."""
    c = math.cos(x0[2])
    s = math.sin(x0[2])
    out[0] = x0[0] + c * u[0] - s * u[1]
    out[1] = x0[1] + s * u[0] + c * u[1]
    out[2] = x0[2] + u[2]


@njit(cache=True, nogil=True)
def place_into(xy: np.ndarray, pose: np.ndarray, out: np.ndarray) -> None:
    """``out[:, :2] = place(xy, pose)`` (:func:`place`, for compiled kernels); other
    columns of ``out`` are left as they are."""
    c = math.cos(pose[2])
    s = math.sin(pose[2])
    for i in range(len(xy)):
        out[i, 0] = c * xy[i, 0] - s * xy[i, 1] + pose[0]
        out[i, 1] = s * xy[i, 0] + c * xy[i, 1] + pose[1]


def heading_bin(theta: ArrayLike, n: int) -> NDArray[np.intp]:
    """Index ``j`` of the nearest of ``n`` evenly spaced headings 2 pi j / n."""
    step = 2.0 * np.pi / n
    return np.asarray(np.round(np.mod(np.asarray(theta, dtype=float), 2.0 * np.pi) / step)
                      .astype(np.intp) % n)


def circular_mean(angles: ArrayLike, weights: ArrayLike | None = None) -> float:
    """Mean direction of ``angles`` (handles wrap-around)."""
    a = np.asarray(angles, dtype=float)
    w = np.ones_like(a) if weights is None else np.asarray(weights, dtype=float)
    return float(np.arctan2(np.sum(w * np.sin(a)), np.sum(w * np.cos(a))))


def bearing(origin: ArrayLike, targets: ArrayLike) -> FloatArray:
    """World-frame direction from ``origin`` (2,) to each of ``targets`` (N, 2)."""
    d = np.atleast_2d(np.asarray(targets, dtype=float)) - np.asarray(origin, dtype=float)
    return np.arctan2(d[:, 1], d[:, 0])


def segments_cross(
    p: ArrayLike, q: ArrayLike, wall_a: FloatArray, wall_b: FloatArray
) -> NDArray[np.bool_]:
    """Which of the segments p->q (N, 2) cross any wall a->b (W, 2).

    Returns a bool array (N,). Touching at an endpoint counts as crossing
    (a robot brushing a wall end collides).
    """
    p = np.atleast_2d(np.asarray(p, dtype=float))
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if len(wall_a) == 0:
        return np.zeros(max(len(p), len(q)), dtype=bool)
    r = (q - p)[:, None, :]  # (N,1,2)
    s = (wall_b - wall_a)[None, :, :]  # (1,W,2)
    qp = wall_a[None, :, :] - p[:, None, :]  # (N,W,2)
    denom = r[..., 0] * s[..., 1] - r[..., 1] * s[..., 0]
    t_num = qp[..., 0] * s[..., 1] - qp[..., 1] * s[..., 0]
    u_num = qp[..., 0] * r[..., 1] - qp[..., 1] * r[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = t_num / denom
        u = u_num / denom
    hit = (np.abs(denom) > _EPS) & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)
    return np.asarray(hit.any(axis=1))


def line_of_sight(
    origin: ArrayLike, targets: ArrayLike, wall_a: FloatArray, wall_b: FloatArray
) -> NDArray[np.bool_]:
    """True for each target (N, 2) visible from ``origin`` (2,) past the walls."""
    t = np.atleast_2d(np.asarray(targets, dtype=float))
    o = np.broadcast_to(np.asarray(origin, dtype=float), t.shape)
    return ~segments_cross(o, t, wall_a, wall_b)


def ray_cast(
    origin: ArrayLike, angles: ArrayLike, wall_a: FloatArray, wall_b: FloatArray,
    max_range: float = np.inf,
) -> tuple[FloatArray, NDArray[np.intp]]:
    """Distance along each ray to the nearest wall, and that wall's index.

    ``angles`` (M,) are world-frame directions. Rays that hit nothing within
    ``max_range`` return ``inf`` and index -1.
    """
    ang = np.atleast_1d(np.asarray(angles, dtype=float))
    m = len(ang)
    if len(wall_a) == 0:
        return np.full(m, np.inf), np.full(m, -1, dtype=np.intp)
    t = _ray_wall_distances(np.asarray(origin, dtype=float), ang, wall_a, wall_b, max_range)
    idx = np.argmin(t, axis=1)
    dist = t[np.arange(m), idx]
    idx = np.where(np.isfinite(dist), idx, -1)
    return dist, idx


def point_segment_distance(points: ArrayLike, seg_a: FloatArray, seg_b: FloatArray) -> FloatArray:
    """Distances ``(M, S)`` from each point ``(M, 2)`` to each segment a->b ``(S, 2)``."""
    p = np.atleast_2d(np.asarray(points, dtype=float))
    if len(seg_a) == 0:
        return np.full((len(p), 0), np.inf)
    ab = (seg_b - seg_a)[None, :, :]
    ap = p[:, None, :] - seg_a[None, :, :]
    denom = np.maximum(np.sum(ab * ab, axis=-1), _EPS)
    t = np.clip(np.sum(ap * ab, axis=-1) / denom, 0.0, 1.0)
    return np.asarray(np.linalg.norm(ap - t[..., None] * ab, axis=-1))


def ray_crossings(points: ArrayLike, seg_a: FloatArray, seg_b: FloatArray) -> NDArray[np.intp]:
    """How many segments a ray from each point ``(M, 2)`` towards +x crosses (even-odd
    rule: odd means inside a closed outline)."""
    p = np.atleast_2d(np.asarray(points, dtype=float))
    if len(seg_a) == 0:
        return np.zeros(len(p), dtype=np.intp)
    ay, by = seg_a[None, :, 1], seg_b[None, :, 1]
    px, py = p[:, 0:1], p[:, 1:2]
    straddle = (ay > py) != (by > py)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_at = seg_a[None, :, 0] + (py - ay) * (seg_b[None, :, 0] - seg_a[None, :, 0]) / (by - ay)
    return np.asarray(np.sum(straddle & (x_at > px), axis=1), dtype=np.intp)


def inside_outline(points: ArrayLike, seg_a: FloatArray, seg_b: FloatArray) -> NDArray[np.bool_]:
    """Even-odd inside test that tolerates open inner walls: odd crossings towards any of
    +x, -x, +y, -y. A closed outline gives the same parity in every direction; a partition
    wall (a segment whose ends touch other walls, as between the rooms of an office) flips
    the parity only on its own side, so a room is inside when some direction misses it. A
    closed obstacle (a pillar) is even in every direction: outside."""
    p = np.atleast_2d(np.asarray(points, dtype=float))
    out = np.zeros(len(p), dtype=bool)
    for rot in (np.eye(2), -np.eye(2), np.array([[0.0, 1.0], [-1.0, 0.0]]),
                np.array([[0.0, -1.0], [1.0, 0.0]])):
        out |= ray_crossings(p @ rot.T, seg_a @ rot.T, seg_b @ rot.T) % 2 == 1
    return out


def enclosed_cells(seg_a: FloatArray, seg_b: FloatArray, resolution_m: float,
                   max_side: int = 2000) -> tuple[FloatArray, float, NDArray[np.bool_]]:
    """Cells no path from outside the segments' bounding box reaches without crossing a
    segment (a flood fill over a raster of the segments, 4-connected, scipy.ndimage):
    ``(origin (2,), resolution, mask (H, W))`` indexed ``[iy, ix]``, the segments' own
    cells excluded. The resolution is coarsened until neither side has more than
    ``max_side`` cells (so memory and time stay bounded for any coordinates); gaps
    narrower than a cell are closed."""
    from scipy import ndimage

    pts = np.vstack([seg_a, seg_b])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    res = float(max(resolution_m, float(np.max(hi - lo)) / (max_side - 5)))
    lo = lo - 2 * res
    shape = (int(np.ceil((hi[1] - lo[1]) / res)) + 3, int(np.ceil((hi[0] - lo[0]) / res)) + 3)
    wall = np.zeros(shape, dtype=bool)
    for a, b in zip(seg_a, seg_b, strict=True):
        # at most ~3 points per cell along the segment: at most 3 * 1.5 * max_side
        n = max(2, int(np.ceil(np.hypot(*(b - a)) / (0.3 * res))) + 1)
        q = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
        ij = np.clip(np.floor((q - lo) / res).astype(int), 0, np.array(shape[::-1]) - 1)
        wall[ij[:, 1], ij[:, 0]] = True
    labels, _ = ndimage.label(~wall)
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    outside = np.isin(labels, border[border > 0])
    return lo, res, ~outside & ~wall


def compose(pose: ArrayLike, delta: ArrayLike) -> FloatArray:
    """``pose (+) delta`` for poses (..., 3): ``delta`` is expressed in ``pose``'s frame."""
    p, d = np.asarray(pose, dtype=float), np.asarray(delta, dtype=float)
    c, s = np.cos(p[..., 2]), np.sin(p[..., 2])
    out = np.empty(np.broadcast(p, d).shape)
    out[..., 0] = p[..., 0] + c * d[..., 0] - s * d[..., 1]
    out[..., 1] = p[..., 1] + s * d[..., 0] + c * d[..., 1]
    out[..., 2] = wrap_angle(p[..., 2] + d[..., 2])
    return out


def place(xy: ArrayLike, pose: ArrayLike) -> FloatArray:
    """Points ``(N, 2)`` given in the frame of ``pose`` (3,), expressed in the world."""
    p = np.asarray(pose, dtype=float)
    c, s = np.cos(p[2]), np.sin(p[2])
    return np.asarray(np.asarray(xy, dtype=float) @ np.array([[c, s], [-s, c]]) + p[:2])


def relative(pose: ArrayLike, other: ArrayLike) -> FloatArray:
    """``pose (-) other``: ``other`` expressed in ``pose``'s frame (inverse of compose)."""
    p, o = np.asarray(pose, dtype=float), np.asarray(other, dtype=float)
    c, s = np.cos(p[..., 2]), np.sin(p[..., 2])
    dx, dy = o[..., 0] - p[..., 0], o[..., 1] - p[..., 1]
    out = np.empty(np.broadcast(p, o).shape)
    out[..., 0] = c * dx + s * dy
    out[..., 1] = -s * dx + c * dy
    out[..., 2] = wrap_angle(o[..., 2] - p[..., 2])
    return out


def invert(pose: ArrayLike) -> FloatArray:
    """``pose^-1`` for poses (..., 3): the origin expressed in ``pose``'s frame, so that
    ``compose(pose, invert(pose))`` is the identity."""
    p = np.asarray(pose, dtype=float)
    return relative(p, np.zeros(p.shape))


def free_distance(origins: ArrayLike, angles: ArrayLike, wall_a: FloatArray,
                  wall_b: FloatArray) -> FloatArray:
    """Distance ``(N,)`` from each origin ``(N, 2)`` along its own direction ``(N,)`` to
    the nearest wall (``inf`` if none): :func:`ray_cast` for many origins."""
    o = np.atleast_2d(np.asarray(origins, dtype=float))
    ang = np.asarray(angles, dtype=float).reshape(-1)
    if len(wall_a) == 0:
        return np.full(len(o), np.inf)
    return np.asarray(_ray_wall_distances(o, ang, wall_a, wall_b).min(axis=1))


def _ray_wall_distances(origin: FloatArray, angles: FloatArray, wall_a: FloatArray,
                        wall_b: FloatArray, max_range: float = np.inf) -> FloatArray:
    """Distance ``(M, W)`` along each ray to each wall (``inf`` where it misses).

    ``origin`` is one point ``(2,)`` shared by all rays or one per ray ``(M, 2)``.
    """
    r = np.stack([np.cos(angles), np.sin(angles)], axis=1)[:, None, :]  # (M,1,2)
    s = (wall_b - wall_a)[None, :, :]
    qp = wall_a[None, :, :] - np.atleast_2d(origin)[:, None, :]  # (1|M, W, 2)
    denom = r[..., 0] * s[..., 1] - r[..., 1] * s[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (qp[..., 0] * s[..., 1] - qp[..., 1] * s[..., 0]) / denom
        u = (qp[..., 0] * r[..., 1] - qp[..., 1] * r[..., 0]) / denom
    ok = (np.abs(denom) > _EPS) & (t > 0) & (u >= 0) & (u <= 1) & (t <= max_range)
    return np.asarray(np.where(ok, t, np.inf))
