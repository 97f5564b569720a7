"""Scan-to-grid matching for graph SLAM (Hess, Kohler, Rapp, Andor, "Real-Time Loop
Closure in 2D LIDAR SLAM", ICRA 2016; Olson, "Real-Time Correlative Scan Matching",
ICRA 2009).

Three matchers, all scoring a pose by the mean probability of the grid cells the scan's
points fall in:

- :func:`correlative_search` -- exhaustive search of a small window around a prediction
  (the "real-time correlative scan matcher" of local SLAM), with a cost on the distance
  from the prediction;
- :func:`refine` -- Gauss-Newton / Levenberg-Marquardt on the bilinearly interpolated
  grid (Hess et al. eq. CS, the Ceres scan matcher; Kohlbrecher et al.'s Hector
  matcher), with quadratic priors pulling towards the prediction;
- :class:`PrecomputedGrid` and :func:`branch_and_bound` -- the loop-closure matcher
  (Hess et al. §V, Algorithms 2-3): a stack of precomputation grids where level h holds
  the maximum over the 2^h x 2^h cells starting at each cell, so that a candidate at
  depth h bounds every finer candidate it contains; depth-first branch and bound finds
  the same best pose as the brute-force search (:func:`brute_force`, for tests).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from chizu.numeric.geometry import wrap_angle
from chizu.numeric.probability_grid import ProbabilityGrid, bilinear


def angular_step(points: np.ndarray, resolution_m: float) -> float:
    """Search step in angle so that the farthest point moves about one cell (Hess et
    al. eq. 7)."""
    r = float(np.max(np.hypot(points[:, 0], points[:, 1]))) if len(points) else 1.0
    r = max(r, 4 * resolution_m)
    return float(np.arccos(1.0 - resolution_m**2 / (2.0 * r * r)))


def window_cells(linear_window_m: float, resolution_m: float) -> int:
    """Half-width in cells of a search window of ``linear_window_m``: offsets run over
    ``-w .. w`` cells, so the window's edge lies ``w`` cells from its centre."""
    return int(np.ceil(linear_window_m / resolution_m))


def rotated_cells(points: np.ndarray, pose: np.ndarray, thetas: np.ndarray,
                  origin: np.ndarray, resolution_m: float) -> np.ndarray:
    """Continuous cell coordinates ``(A, n, 2)`` of robot-frame ``points (n, 2)`` at the
    position of ``pose`` and each heading ``pose[2] + thetas[a]``."""
    th = pose[2] + thetas
    c, s = np.cos(th)[:, None], np.sin(th)[:, None]
    x = c * points[None, :, 0] - s * points[None, :, 1] + pose[0]
    y = s * points[None, :, 0] + c * points[None, :, 1] + pose[1]
    return np.stack([(x - origin[0]) / resolution_m, (y - origin[1]) / resolution_m], axis=-1)


# -- real-time correlative search (local SLAM) ----------------------------------------------
@njit(cache=True, nogil=True)
def _search_window(prob: np.ndarray, cells: np.ndarray, w: int, step_m: float,
                   thetas: np.ndarray, w_t: float, w_r: float) -> tuple[int, int, int, float]:
    """Every angle ``a`` and cell offset ``(dx, dy)`` in ``-w..w``: the mean probability
    of the points' cells, times the cost term; the best (first of equals in the order
    angle, dx, dy). Per angle the points are floored to cells once and each adds its
    ``(2w+1)^2`` neighbourhood to the offsets' sums, in the points' order (the same
    sums as point by point per offset, 2.5x faster)."""
    nx, ny = prob.shape
    n = cells.shape[1]
    side = 2 * w + 1
    acc = np.empty((side, side))
    ci = np.empty(n, np.int64)
    cj = np.empty(n, np.int64)
    best, ba, bx, by = -1.0, 0, 0, 0
    for a in range(cells.shape[0]):
        for k in range(n):
            ci[k] = int(math.floor(cells[a, k, 0]))
            cj[k] = int(math.floor(cells[a, k, 1]))
        acc[:, :] = 0.0
        for k in range(n):
            i0, j0 = ci[k] - w, cj[k] - w
            if i0 >= 0 and j0 >= 0 and i0 + side <= nx and j0 + side <= ny:
                for u in range(side):
                    for v in range(side):
                        acc[u, v] += prob[i0 + u, j0 + v]
            else:
                for u in range(side):
                    i = i0 + u
                    if 0 <= i < nx:
                        for v in range(side):
                            j = j0 + v
                            if 0 <= j < ny:
                                acc[u, v] += prob[i, j]
        for u in range(side):
            for v in range(side):
                dx, dy = u - w, v - w
                s = acc[u, v] / n
                s *= math.exp(-math.hypot(w_t * step_m * math.hypot(dx, dy),
                                          w_r * thetas[a]))
                if s > best:
                    best, ba, bx, by = s, a, dx, dy
    return ba, bx, by, best


def correlative_search(grid: ProbabilityGrid, points: np.ndarray, pose: np.ndarray,
                       linear_window_m: float, angular_window_rad: float,
                       translation_cost: float = 0.1, rotation_cost: float = 0.1,
                       ) -> tuple[np.ndarray, float]:
    """Best pose in the window around ``pose`` for robot-frame ``points (n, 2)`` and its
    (cost-weighted) score, searching every cell offset and angle step."""
    res = grid.resolution_m
    step = angular_step(points, res)
    na = int(np.ceil(angular_window_rad / step))
    thetas = np.arange(-na, na + 1) * step
    cells = rotated_cells(points, pose, thetas, grid.origin, res)
    w = window_cells(linear_window_m, res)
    a, dx, dy, score = _search_window(grid.prob, cells, w, res, thetas, translation_cost,
                                      rotation_cost)
    return np.array([pose[0] + dx * res, pose[1] + dy * res, pose[2] + thetas[a]]), score


# -- Gauss-Newton refinement ----------------------------------------------------------------
class RefineWeights(NamedTuple):
    """The refinement's objective (:func:`refine`): the weights of the scan term, the
    translation prior and the rotation prior, the iterations, and the floor of the
    scan's residual variance (0: the scan is not weighed by its residuals)."""

    occupied: float
    translation: float
    rotation: float
    iterations: int
    residual_floor: float


@njit(cache=True)
def _refine(prob: np.ndarray, origin: tuple[float, float], res: float, pts: np.ndarray,
            start: tuple[float, float, float], prior: tuple[float, float, float],
            weights: RefineWeights) -> tuple[float, float, float, float, np.ndarray]:
    """Levenberg-Marquardt on :func:`refine`'s objective from ``start``: the pose, the
    mean probability there and the scan term's information."""
    ox, oy = origin
    x, y, t = start
    px, py, pt = prior
    w_occ, w_t, w_r = weights.occupied, weights.translation, weights.rotation
    iters, var_floor = weights.iterations, weights.residual_floor
    n = pts.shape[0]
    wp = w_occ * w_occ / n
    lam = 1e-3
    cost_prev = 1e300
    for _ in range(iters):
        if var_floor > 0:  # weigh the scan by its own residual spread (IRLS)
            c, s = math.cos(t), math.sin(t)
            var = 0.0
            for k in range(n):
                qx, qy = pts[k, 0], pts[k, 1]
                m, _, _ = bilinear(prob, (c * qx - s * qy + x - ox) / res,
                                   (s * qx + c * qy + y - oy) / res)
                var += (1.0 - m) ** 2
            wp = w_occ * w_occ / (n * max(var / n, var_floor))
            cost_prev = 1e300
        h = np.zeros((3, 3))
        g = np.zeros(3)
        c, s = math.cos(t), math.sin(t)
        cost = 0.0
        for k in range(n):
            qx, qy = pts[k, 0], pts[k, 1]
            wx = c * qx - s * qy + x
            wy = s * qx + c * qy + y
            m, gx, gy = bilinear(prob, (wx - ox) / res, (wy - oy) / res)
            r = 1.0 - m
            gx /= res
            gy /= res
            jx, jy = -gx, -gy
            jt = -(gx * (-s * qx - c * qy) + gy * (c * qx - s * qy))
            cost += wp * r * r
            jv = (jx, jy, jt)
            for a in range(3):
                g[a] += wp * jv[a] * r
                for b in range(3):
                    h[a, b] += wp * jv[a] * jv[b]
        dt = t - pt
        dt = (dt + math.pi) % (2 * math.pi) - math.pi
        cost += w_t * w_t * ((x - px) ** 2 + (y - py) ** 2) + w_r * w_r * dt * dt
        g[0] += w_t * w_t * (x - px)
        g[1] += w_t * w_t * (y - py)
        g[2] += w_r * w_r * dt
        h[0, 0] += w_t * w_t
        h[1, 1] += w_t * w_t
        h[2, 2] += w_r * w_r
        if cost > cost_prev:
            lam *= 10.0
        else:
            lam = max(lam * 0.3, 1e-6)
        cost_prev = min(cost, cost_prev)
        for a in range(3):
            h[a, a] *= 1.0 + lam
        d = np.linalg.solve(h, -g)
        x += d[0]
        y += d[1]
        t += d[2]
        if abs(d[0]) < 1e-5 and abs(d[1]) < 1e-5 and abs(d[2]) < 1e-5:
            break
    c, s = math.cos(t), math.sin(t)
    tot = 0.0
    info = np.zeros((3, 3))
    for k in range(n):
        qx, qy = pts[k, 0], pts[k, 1]
        m, gx, gy = bilinear(prob, (c * qx - s * qy + x - ox) / res,
                             (s * qx + c * qy + y - oy) / res)
        tot += m
        gx /= res
        gy /= res
        jv = (gx, gy, gx * (-s * qx - c * qy) + gy * (c * qx - s * qy))
        for a in range(3):
            for b in range(3):
                info[a, b] += jv[a] * jv[b] / n
    return x, y, t, tot / n, info


@dataclass
class Refined:
    """A refined pose, the mean probability of the points there, and the scan term's
    information ``(3, 3)``: the mean of ``J J^T`` over the points (1/m², 1/(m rad),
    1/rad²), whose translational eigenvalues tell how well each direction is fixed --
    along a plain corridor one of them is close to 0."""

    pose: np.ndarray
    score: float
    information: np.ndarray

    def degeneracy(self) -> float:
        """Smallest over largest eigenvalue of the translational information (0 when
        one direction is not constrained at all, 1 when both are equally)."""
        ev = np.linalg.eigvalsh(self.information[:2, :2])
        return float(ev[0] / ev[1]) if ev[1] > 0 else 0.0


def refine(grid: ProbabilityGrid, points: np.ndarray, pose: np.ndarray,
           prior: np.ndarray | None = None, occupied_weight: float = 1.0,
           translation_weight: float = 10.0, rotation_weight: float = 40.0,
           iterations: int = 20, residual_floor: float = 0.0) -> Refined:
    """Pose minimising ``sum (w_occ / sqrt(n))^2 (1 - M(T p))^2 + w_t^2 |t - t_prior|^2
    + w_r^2 (theta - theta_prior)^2`` (M the bilinear interpolation of the grid), from
    ``pose``. With ``residual_floor > 0`` the scan term is divided by the mean squared
    residual (at least the floor), so that a scan that fits the grid poorly weighs less
    against the prior, like a measurement of larger variance."""
    pr = pose if prior is None else prior
    x, y, t, score, info = _refine(
        grid.prob, (float(grid.origin[0]), float(grid.origin[1])), grid.resolution_m,
        np.ascontiguousarray(points, dtype=float),
        (float(pose[0]), float(pose[1]), float(pose[2])),
        (float(pr[0]), float(pr[1]), float(pr[2])),
        RefineWeights(float(occupied_weight), float(translation_weight),
                      float(rotation_weight), int(iterations), float(residual_floor)))
    return Refined(np.array([x, y, (t + np.pi) % (2 * np.pi) - np.pi]), float(score), info)


# -- branch and bound (loop closure) --------------------------------------------------------
@njit(cache=True)
def _precompute(base: np.ndarray, depth: int, pad: int) -> np.ndarray:
    nx, ny = base.shape
    out = np.zeros((depth + 1, nx + 2 * pad, ny + 2 * pad), dtype=np.uint8)
    out[0, pad:pad + nx, pad:pad + ny] = base
    mx, my = nx + 2 * pad, ny + 2 * pad
    tmp = np.zeros((mx, my), dtype=np.uint8)
    for h in range(depth):
        w = 1 << h
        for i in range(mx):
            for j in range(my):
                v = out[h, i, j]
                if i + w < mx and out[h, i + w, j] > v:
                    v = out[h, i + w, j]
                tmp[i, j] = v
        for i in range(mx):
            for j in range(my):
                v = tmp[i, j]
                if j + w < my and tmp[i, j + w] > v:
                    v = tmp[i, j + w]
                out[h + 1, i, j] = v
    return out


@njit(cache=True, nogil=True)
def _score(pre: np.ndarray, h: int, pts: np.ndarray, a: int, dx: int, dy: int) -> float:
    nx, ny = pre.shape[1], pre.shape[2]
    n = pts.shape[1]
    s = 0
    for k in range(n):
        i = pts[a, k, 0] + dx
        j = pts[a, k, 1] + dy
        if 0 <= i < nx and 0 <= j < ny:
            s += pre[h, i, j]
    return s / (255.0 * n)


@njit(cache=True, nogil=True)
def _excluded(x0: int, y0: int, size: int, ex_x: int, ex_y: int, ex_r: int) -> bool:
    """Whether every offset of the node ``[x0, x0 + size)^2`` lies within the excluded
    disc (its four corners do: the disc is convex)."""
    if ex_r < 0:
        return False
    r2 = ex_r * ex_r
    for cx in (x0, x0 + size - 1):
        for cy in (y0, y0 + size - 1):
            if (cx - ex_x) ** 2 + (cy - ex_y) ** 2 > r2:
                return False
    return True


NO_MASK = np.zeros((1, 0, 0), dtype=np.uint8)
NO_SHARED = np.zeros(0)  # no score shared with other parts


def offset_mask(allowed: np.ndarray, depth: int) -> np.ndarray:
    """The pyramid :func:`branch_and_bound` prunes with: level ``h`` holds, at each
    offset, whether any of the ``2^h x 2^h`` offsets from it on is ``allowed`` -- the
    precomputation of Hess et al. §V.B with the maximum over a 0/1 mask."""
    return _precompute(allowed.astype(np.uint8), depth, 0)


@njit(cache=True, nogil=True)
def branch_and_bound(pre: np.ndarray, pts: np.ndarray, wx: int, wy: int,
                     min_score: float, ex_x: int = 0, ex_y: int = 0,
                     ex_r: int = -1, first: bool = False,
                     allowed: np.ndarray = NO_MASK,
                     shared: np.ndarray = NO_SHARED) -> tuple[int, int, int, float]:
    """Best ``(angle index, dx, dy, score)`` over offsets ``[0, wx) x [0, wy)`` with a
    score above ``min_score`` (angle -1 when none), Hess et al. Algorithm 3. ``pts (A,
    n, 2)`` are the points' cells at offset (0, 0) in ``pre``'s padded frame. Offsets
    within ``ex_r`` cells of ``(ex_x, ex_y)`` are excluded (``ex_r < 0``: none): the
    search for a second peak away from the first. A node's bound still covers the
    excluded offsets it contains, so it stays an upper bound; a node wholly inside the
    excluded disc is pruned (near the first peak such nodes keep high bounds, and the
    search would otherwise split them down to single cells). With ``first`` the search
    stops at the first offset above ``min_score`` (whether there is one, not which is
    best: all the uniqueness test asks). With ``allowed`` (a :func:`offset_mask`
    pyramid over the offsets) only the offsets it holds are searched: a node none of
    whose offsets is allowed is pruned before it is scored. Given ``shared`` (one
    element), searches of one window's parts on several threads share ``shared[0]``,
    the best score any of them has found: a node scoring below it is pruned (one below,
    not one equal, so each part still finds its own best when that ties, and the answer
    does not depend on which thread was first); with ``first``, every part stops once
    one has found an offset."""
    depth = pre.shape[0] - 1
    masked = allowed.shape[1] > 0
    share = shared.shape[0] > 0
    na = pts.shape[0]
    step = 1 << depth
    ntx = (wx + step - 1) // step
    nty = (wy + step - 1) // step
    ntop = na * ntx * nty
    cap = ntop + 4 * (depth + 1) + 8
    s_score = np.empty(cap)
    s_a = np.empty(cap, dtype=np.int64)
    s_x = np.empty(cap, dtype=np.int64)
    s_y = np.empty(cap, dtype=np.int64)
    s_h = np.empty(cap, dtype=np.int64)
    top = np.empty(ntop)
    ta = np.empty(ntop, dtype=np.int64)
    tx = np.empty(ntop, dtype=np.int64)
    ty = np.empty(ntop, dtype=np.int64)
    k = 0
    for a in range(na):
        for ix in range(ntx):
            for iy in range(nty):
                if masked and allowed[depth, ix * step, iy * step] == 0:
                    top[k] = -1.0
                else:
                    top[k] = _score(pre, depth, pts, a, ix * step, iy * step)
                ta[k], tx[k], ty[k] = a, ix * step, iy * step
                k += 1
    order = np.argsort(top)  # ascending: the best is pushed last, popped first
    sp = 0
    for q in order:
        if top[q] > min_score and not _excluded(tx[q], ty[q], step, ex_x, ex_y, ex_r):
            s_score[sp], s_a[sp], s_x[sp], s_y[sp], s_h[sp] = top[q], ta[q], tx[q], ty[q], depth
            sp += 1
    best, ba, bx, by = min_score, -1, 0, 0
    # the guess itself (the window's centre) as the first incumbent: a good guess prunes
    # most of the tree at once
    ca, cx0, cy0 = na // 2, wx // 2, wy // 2
    sc0 = _score(pre, 0, pts, ca, cx0, cy0)
    if masked and allowed[0, cx0, cy0] == 0:
        sc0 = -1.0
    if sc0 > best and not _excluded(cx0, cy0, 1, ex_x, ex_y, ex_r):
        best, ba, bx, by = sc0, ca, cx0, cy0
    cs = np.empty(4)
    cx = np.empty(4, dtype=np.int64)
    cy = np.empty(4, dtype=np.int64)
    while sp > 0:
        sp -= 1
        sc, a, x0, y0, h = s_score[sp], s_a[sp], s_x[sp], s_y[sp], s_h[sp]
        if sc <= best:
            continue
        if share and (sc < shared[0] or (first and shared[0] > min_score)):
            if first:
                break
            continue
        if h == 0:
            if not _excluded(x0, y0, 1, ex_x, ex_y, ex_r):
                best, ba, bx, by = sc, a, x0, y0
                if share and sc > shared[0]:
                    shared[0] = sc
                if first:
                    break
            continue
        half = 1 << (h - 1)
        m = 0
        for ox in (0, half):
            for oy in (0, half):
                if x0 + ox < wx and y0 + oy < wy and not (
                        masked and allowed[h - 1, x0 + ox, y0 + oy] == 0):
                    cs[m] = _score(pre, h - 1, pts, a, x0 + ox, y0 + oy)
                    cx[m], cy[m] = x0 + ox, y0 + oy
                    m += 1
        idx = np.argsort(cs[:m])
        for q in idx:
            if cs[q] > best and not _excluded(cx[q], cy[q], half, ex_x, ex_y, ex_r):
                s_score[sp], s_a[sp], s_x[sp], s_y[sp], s_h[sp] = cs[q], a, cx[q], cy[q], h - 1
                sp += 1
    return ba, bx, by, best


@njit(cache=True, nogil=True)
def brute_force(pre: np.ndarray, pts: np.ndarray, wx: int, wy: int, ex_x: int = 0,
                ex_y: int = 0, ex_r: int = -1,
                allowed: np.ndarray = NO_MASK) -> tuple[int, int, int, float]:
    """The exhaustive search :func:`branch_and_bound` must agree with."""
    best, ba, bx, by = -1.0, 0, 0, 0
    for a in range(pts.shape[0]):
        for dx in range(wx):
            for dy in range(wy):
                if _excluded(dx, dy, 1, ex_x, ex_y, ex_r):
                    continue
                if allowed.shape[1] > 0 and allowed[0, dx, dy] == 0:
                    continue
                s = _score(pre, 0, pts, a, dx, dy)
                if s > best:
                    best, ba, bx, by = s, a, dx, dy
    return ba, bx, by, best


@dataclass
class Match:
    """A scan placed in a grid: its pose (grid's world frame) and mean probability."""

    pose: np.ndarray
    score: float


class PrecomputedGrid:
    """The precomputation grids of a finished submap (uint8 probabilities)."""

    def __init__(self, grid: ProbabilityGrid, depth: int = 7) -> None:
        self.grid = grid
        self.depth = depth
        self.pad = (1 << depth) - 1
        base = np.round(np.clip(grid.prob, 0, 1) * 255).astype(np.uint8)
        self.stack = _precompute(base, depth, self.pad)

    @property
    def nbytes(self) -> int:
        return int(self.stack.nbytes)

    def candidates(self, points: np.ndarray, pose: np.ndarray, linear_window_m: float,
                   angular_window_rad: float, min_step_rad: float = 0.0,
                   ) -> tuple[np.ndarray, np.ndarray, int]:
        """Angles searched (at least ``min_step_rad`` apart) and the points' padded
        cells at the window's low corner."""
        g = self.grid
        res = g.resolution_m
        step = max(angular_step(points, res), min_step_rad)
        na = int(np.ceil(angular_window_rad / step))
        thetas = np.arange(-na, na + 1) * step
        w = window_cells(linear_window_m, res)
        cells = np.floor(rotated_cells(points, pose, thetas, g.origin, res)).astype(np.int64)
        return thetas, cells - w + self.pad, w

    def score(self, points: np.ndarray, pose: np.ndarray) -> float:
        """The score :meth:`match` gives ``pose`` itself: the mean probability of the
        cells the robot-frame ``points`` fall in at ``pose`` (outside the grid: 0)."""
        g = self.grid
        cells = np.floor(rotated_cells(points, pose, np.zeros(1), g.origin, g.resolution_m))
        return float(_score(self.stack, 0, cells.astype(np.int64) + self.pad, 0, 0, 0))

    def match(self, points: np.ndarray, pose: np.ndarray, linear_window_m: float,
              angular_window_rad: float, min_score: float,
              min_step_rad: float = 0.0, allowed: np.ndarray = NO_MASK,
              shared: np.ndarray | None = None) -> Match | None:
        """The best pose within the window by branch and bound, or None below
        ``min_score``. A ``min_step_rad`` coarser than Hess et al.'s eq. 7 step trades
        the far points' alignment (refined afterwards) for speed. ``allowed`` and
        ``shared`` as :func:`branch_and_bound` takes them (``shared``: one array for all
        parts of a window searched on several threads)."""
        thetas, cells, w = self.candidates(points, pose, linear_window_m, angular_window_rad,
                                           min_step_rad)
        a, dx, dy, score = branch_and_bound(
            self.stack, cells, 2 * w + 1, 2 * w + 1, min_score, allowed=allowed,
            shared=NO_SHARED if shared is None else shared)
        if a < 0:
            return None
        res = self.grid.resolution_m
        return Match(np.array([pose[0] + (dx - w) * res, pose[1] + (dy - w) * res,
                               pose[2] + thetas[a]]), float(score))

    def second_score(self, points: np.ndarray, pose: np.ndarray, linear_window_m: float,
                     angular_window_rad: float, best: Match, exclusion_m: float,
                     ratio: float, min_step_rad: float = 0.0,
                     exclusion_rad: float = np.pi, allowed: np.ndarray = NO_MASK,
                     shared: np.ndarray | None = None) -> float:
        """A score in :meth:`match`'s window (centred at ``pose``) at least
        ``exclusion_m`` from ``best`` -- or, at a heading more than ``exclusion_rad``
        from best's, anywhere -- and above ``ratio`` times its score, else 0: a peak as
        good elsewhere in the window means the scan fits the submap in two places (a
        corridor's repeated doors, a symmetric room seen turned round) -- a test of the
        match's uniqueness after Olson, "Real-Time Correlative Scan Matching" (ICRA
        2009, §IV: a match is only as good as the response's spread)."""
        thetas, cells, w = self.candidates(points, pose, linear_window_m, angular_window_rad,
                                           min_step_rad)
        res = self.grid.resolution_m
        ex = np.round((best.pose[:2] - pose[:2]) / res).astype(int) + w
        turned = np.abs(wrap_angle(pose[2] + thetas - best.pose[2])) > exclusion_rad
        out = 0.0
        for part, ex_r in ((~turned, int(np.ceil(exclusion_m / res))), (turned, -1)):
            if not part.any():
                continue
            b = branch_and_bound(self.stack, np.ascontiguousarray(cells[part]), 2 * w + 1,
                                 2 * w + 1, ratio * best.score, int(ex[0]), int(ex[1]), ex_r,
                                 True, allowed, NO_SHARED if shared is None else shared)
            out = max(out, float(b[3]) if b[0] >= 0 else 0.0)
        return out
