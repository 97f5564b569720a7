"""Scan matching on keyframe likelihood fields: the measurement model the RBPF's
proposal (Grisetti et al. 2007, §IV-A), its loop start and its odometry calibration
share.

``log p(z | m, x) = -Σ_b ρ_b(x) / (2 σ²)`` with ``ρ_b = min(cutoff², min_k min_band
(d_k,band(T s_b)² + alpha (l_k,band - l_b)²))``: for each beam b of the scan, the squared
distance to the nearest map point in the sense of eq. 1 of Hara et al. (intensity term
included when ``alpha > 0``), bilinearly interpolated in each chosen keyframe's
precomputed squared-distance grid (:class:`~chizu.numeric.slam.keyframes.LikelihoodField`),
the minimum over the keyframes (each placed at the pose the particle holds for it) and
capped.

- :func:`scan_match`: the mode of ``p(z|m,x) p(x|x_{t-1},u)`` by Levenberg-Marquardt
  (Gauss-Newton with a damping that accepts only improving steps and a 5 cm / 0.025 rad
  trust region); full evaluations record each beam's two best keyframes and the
  iterations in between look only at those two;
- :func:`score_offsets`: the same sums at poses near a match, beam by beam (the
  proposal's 27 samples);
- :func:`count_inliers` and :func:`loop_search`: how many beams a map explains at a
  pose, and a correlative grid refined by the matcher (the loop start).

The kernels are compiled with numba and release the GIL. They take a few bundles
(:class:`Beams`, :class:`FieldPack`, :class:`MatchModel`, :class:`Workspace`), not the
arrays one by one. The per-beam helpers (:func:`_beam_value` and what it calls) are
inlined into the beam loops at numba's level (``inline="always"``): called, each lookup
would pass the bundles by value, which made a match six times slower
(docs/notes/slam-rbpf.md, "Speed").
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from chizu.numeric.geometry import wrap_scalar
from chizu.numeric.slam.keyframes import LikelihoodField
from chizu.numeric.threads import thread_map

_MAX_STEP_M = 0.05  # largest Levenberg-Marquardt step (trust region)
_MAX_STEP_RAD = 0.025


class Beams(NamedTuple):
    """The scan as the kernels read it: ``pts (B, 2)`` in the robot frame (m), their
    intensities ``li (B,)`` (zeros when none) and the intensity weight ``alpha`` of
    eq. 1 (0: geometry alone)."""

    pts: np.ndarray
    li: np.ndarray
    alpha: float

    @staticmethod
    def of(xy: np.ndarray, inten: np.ndarray | None, alpha: float) -> Beams:
        li = np.zeros(len(xy)) if inten is None else np.asarray(inten, dtype=float)
        return Beams(xy, li, float(alpha))


class FieldPack(NamedTuple):
    """The chosen keyframes' likelihood fields as the kernels read them: every field's
    squared-distance grid ``(bands, nx, ny)`` flattened into one ``grid`` (and the
    intensity grids into ``inten``, or one dummy value when no intensity is used),
    ``meta (K, 4)`` = offset, bands, nx, ny per keyframe, ``origins (K, 2)`` (m) and the
    common ``inv_res`` (1/m). A flat buffer is what keeps the innermost lookup a plain
    array read."""

    grid: np.ndarray
    inten: np.ndarray
    meta: np.ndarray
    origins: np.ndarray
    inv_res: float

    @staticmethod
    def of(fields: list[LikelihoodField], with_intensity: bool) -> FieldPack:
        meta = np.zeros((len(fields), 4), dtype=np.int64)
        off = 0
        for k, f in enumerate(fields):
            nb, nx, ny = f.dist2.shape
            meta[k] = (off, nb, nx, ny)
            off += nb * nx * ny
        grid = np.concatenate([f.dist2.ravel() for f in fields]).astype(np.float32, copy=False)
        inten = (np.concatenate([f.inten.ravel() for f in fields]).astype(np.float32, copy=False)
                 if with_intensity else np.zeros(1, dtype=np.float32))
        origins = np.array([f.origin for f in fields], dtype=float).reshape(-1, 2)
        return FieldPack(grid, inten, meta, origins, 1.0 / fields[0].res)


class FieldArena:
    """:class:`FieldPack` s of a sequence of mostly overlapping field sets (the best
    particle's reference, asked for on every scan), each field copied once: fields go
    into one float32 buffer and a pack is their offsets in it. When a pack's new fields
    no longer fit, a new buffer of ``HEADROOM`` times the asked fields is made with them
    alone (the old one stays with the packs that use it), so a pack made earlier stays
    valid. A pack reads the same values as :meth:`FieldPack.of` of the same fields."""

    #: a new buffer's size over the asked fields': room for the next fields to come
    HEADROOM = 1.5

    def __init__(self, with_intensity: bool) -> None:
        self.with_intensity = with_intensity
        self._grid = np.empty(0, dtype=np.float32)
        # without intensities the kernels get FieldPack.of's one dummy value
        self._inten = np.zeros(0 if with_intensity else 1, dtype=np.float32)
        self._used = 0
        self._at: dict[int, tuple[int, LikelihoodField]] = {}  # id(field) -> offset

    def pack(self, fields: list[LikelihoodField]) -> FieldPack:
        asked = {id(f): f for f in fields}
        new = [f for k, f in asked.items() if k not in self._at]
        if self._used + sum(f.dist2.size for f in new) > len(self._grid):
            live = sum(f.dist2.size for f in asked.values())
            self._at, self._used, new = {}, 0, list(asked.values())
            self._grid = np.empty(int(self.HEADROOM * live), dtype=np.float32)
            if self.with_intensity:
                self._inten = np.empty(len(self._grid), dtype=np.float32)
        for f in new:
            n = f.dist2.size
            self._grid[self._used:self._used + n] = f.dist2.ravel()
            if self.with_intensity:
                self._inten[self._used:self._used + n] = f.inten.ravel()
            self._at[id(f)] = (self._used, f)  # the field kept: its id stays its own
            self._used += n
        meta = np.array([(self._at[id(f)][0], *f.dist2.shape) for f in fields],
                        dtype=np.int64).reshape(-1, 4)
        origins = np.array([f.origin for f in fields], dtype=float).reshape(-1, 2)
        return FieldPack(self._grid, self._inten, meta, origins, 1.0 / fields[0].res)


class MatchModel(NamedTuple):
    """The matcher's constants, derived once from its config: ``cut2`` the residual cap
    ρ_max² (m²), ``inv_2s2`` = 1 / (2σ²) of the likelihood field (1/m²) and the
    Levenberg-Marquardt iterations ``max_iter``."""

    cut2: float
    inv_2s2: float
    max_iter: int


class Workspace(NamedTuple):
    """Scratch of one evaluation over B beams: each beam's two best keyframes
    ``cand (B, 2)`` (-1: none), ``work (6, B)`` and ``iwork (2, B)``."""

    cand: np.ndarray
    work: np.ndarray
    iwork: np.ndarray


@njit(cache=True, nogil=True)
def new_workspace(n_beams: int) -> Workspace:
    """A :class:`Workspace` for ``n_beams`` beams, no candidates recorded."""
    return Workspace(np.full((n_beams, 2), -1, dtype=np.int64), np.empty((6, n_beams)),
                     np.empty((2, n_beams), dtype=np.int64))


class LoopGrid(NamedTuple):
    """A wide search (:func:`loop_search`): poses ±``radius`` (m) in ``step`` and
    ±``half_angle`` (rad) in ``angle_step`` scored with residuals capped at ``coarse2``
    (m²), the ``n_refine`` best at least ``min_sep`` (m) apart refined, and beams within
    sqrt(``inlier2``) of the map counted as explained."""

    radius: float
    step: float
    half_angle: float
    angle_step: float
    coarse2: float
    n_refine: int
    min_sep: float
    inlier2: float


# -- lookups -------------------------------------------------------------------------------
#: a keyframe's constants as the lookups read them (:func:`_keyframe`): its pose as
#: (cos, sin, x, y), its grid's offset, bands, nx, ny and origin (x, y)
KeyframeConsts = tuple[float, float, float, float, int, int, int, int, float, float]


@njit(cache=True, nogil=True, inline="always")
def _corners(off: int, nx: int, ny: int, ox: float, oy: float, inv_res: float, qx: float,
             qy: float) -> tuple[int, float, float]:
    """Where the bilinear interpolation at the keyframe-frame point (qx, qy) reads one
    band's grid (flat, at ``off``, ``nx`` by ``ny``): the index of its lower corner cell
    and the fractions (fu, fv) along x and y; index -1 outside the grid."""
    u = (qx - ox) * inv_res - 0.5
    v = (qy - oy) * inv_res - 0.5
    if not (u >= 0.0 and v >= 0.0):
        return -1, 0.0, 0.0
    i = int(u)
    j = int(v)
    if i + 1 >= nx or j + 1 >= ny:
        return -1, 0.0, 0.0
    return off + i * ny + j, u - i, v - j


@njit(cache=True, nogil=True, inline="always")
def _interpolate(grid: np.ndarray, base: int, ny: int, fu: float, fv: float) -> float:
    """The bilinear value at :func:`_corners`' cell and fractions."""
    p00 = grid[base]
    p01 = grid[base + 1]
    p10 = grid[base + ny]
    p11 = grid[base + ny + 1]
    return (p00 * (1.0 - fu) * (1.0 - fv) + p10 * fu * (1.0 - fv)
            + p01 * (1.0 - fu) * fv + p11 * fu * fv)


@njit(cache=True, nogil=True, inline="always")
def _slope(grid: np.ndarray, base: int, ny: int, fu: float, fv: float,
           inv_res: float) -> tuple[float, float]:
    """... and its gradient (per m). Apart from :func:`_interpolate`: the matcher needs
    it only where a lookup improves a beam's best, which most lookups do not."""
    p00 = grid[base]
    p01 = grid[base + 1]
    p10 = grid[base + ny]
    p11 = grid[base + ny + 1]
    gx = ((p10 - p00) * (1.0 - fv) + (p11 - p01) * fv) * inv_res
    gy = ((p01 - p00) * (1.0 - fu) + (p11 - p10) * fu) * inv_res
    return gx, gy



@njit(cache=True, nogil=True, inline="always")
def _lookup(fields: FieldPack, kf: KeyframeConsts, qx: float, qy: float, li: float,
            alpha: float, cut2: float, bound: float, grad: bool) -> tuple[float, float, float]:
    """Capped augmented squared residual at the keyframe-frame point (qx, qy) of the
    keyframe ``kf`` and its gradient (per m): the bilinear squared distance per
    intensity band plus ``alpha (l_band - li)^2`` with the nearest cell's intensity, the
    minimum over bands; ``cut2`` and no gradient outside the grid. Only values below
    ``bound`` (a beam's best so far, at most ``cut2``) count, and the gradient (with
    ``grad``) is computed only for them: the result is ``bound`` with no gradient when
    no band goes below it."""
    off, nb, nx, ny, ox, oy = kf[4], kf[5], kf[6], kf[7], kf[8], kf[9]
    grid = fields.grid
    inv_res = fields.inv_res
    best = bound
    gx = 0.0
    gy = 0.0
    base, fu, fv = _corners(off, nx, ny, ox, oy, inv_res, qx, qy)
    if base < 0:
        return cut2, 0.0, 0.0
    band = nx * ny
    for b in range(nb):
        val = _interpolate(grid, base + b * band, ny, fu, fv)
        if val >= cut2:  # capped: the intensity only adds
            continue
        if alpha > 0.0:
            near = base + b * band + (ny if fu >= 0.5 else 0) + (1 if fv >= 0.5 else 0)
            dl = fields.inten[near] - li
            val += alpha * dl * dl
        if val < best:
            best = val
            if grad:
                gx, gy = _slope(grid, base + b * band, ny, fu, fv, inv_res)
    return best, gx, gy


@njit(cache=True, nogil=True, inline="always")
def _keyframe(kpose: np.ndarray, fields: FieldPack, k: int) -> KeyframeConsts:
    """Keyframe ``k``'s constants as the lookups read them: its pose (cos, sin, x, y)
    from ``kpose``, its grid's offset, bands, nx, ny and origin from ``fields``."""
    meta = fields.meta
    origins = fields.origins
    return (kpose[k, 0], kpose[k, 1], kpose[k, 2], kpose[k, 3], meta[k, 0], meta[k, 1],
            meta[k, 2], meta[k, 3], origins[k, 0], origins[k, 1])


@njit(cache=True, nogil=True, inline="always")
def _to_keyframe(kf: KeyframeConsts, wx: float, wy: float) -> tuple[float, float]:
    """The world point (wx, wy) in the frame of keyframe ``kf``."""
    ck, sk, tx, ty = kf[0], kf[1], kf[2], kf[3]
    dx = wx - tx
    dy = wy - ty
    return ck * dx + sk * dy, -sk * dx + ck * dy


@njit(cache=True, nogil=True, inline="always")
def _beam_value(fields: FieldPack, kf: KeyframeConsts, geo: bool, qx: float, qy: float,
                li: float, alpha: float, cut2: float, bound: float,
                grad: bool) -> tuple[bool, float, float, float]:
    """One beam's residual in keyframe ``kf`` at (qx, qy) if it goes below ``bound``:
    (found, value, gradient x, y in the keyframe's frame). ``geo``: one band and no
    intensity, the common case, written out -- most lookups change nothing."""
    if geo:
        base, fu, fv = _corners(kf[4], kf[6], kf[7], kf[8], kf[9], fields.inv_res, qx, qy)
        if base < 0:
            return False, 0.0, 0.0, 0.0
        val = _interpolate(fields.grid, base, kf[7], fu, fv)
        if not val < bound:
            return False, 0.0, 0.0, 0.0
        if not grad:
            return True, val, 0.0, 0.0
        gqx, gqy = _slope(fields.grid, base, kf[7], fu, fv, fields.inv_res)
        return True, val, gqx, gqy
    val, gqx, gqy = _lookup(fields, kf, qx, qy, li, alpha, cut2, bound, grad)
    return val < bound, val, gqx, gqy


# -- the measurement model ----------------------------------------------------------------
@njit(cache=True, nogil=True)
def score(x: float, y: float, th: float, beams: Beams, fields: FieldPack, kpose: np.ndarray,
           cut2: float, mode: int, ws: Workspace, h: np.ndarray, g: np.ndarray,
           grad: bool) -> tuple[float, int]:
    """Σ_b ρ_b at pose (x, y, th) and the number of beams under the cutoff; with
    ``grad`` also the Gauss-Newton system ``h = Σ J^T J``, ``g = Σ J^T e`` of the
    residuals ``e_b = sqrt(ρ_b)`` (derivatives by the world-frame pose).

    ``kpose (K, 4)``: the particle's pose of each keyframe as (cos, sin, x, y). ``mode``
    0: all keyframes; 1: all keyframes, and ``ws.cand (B, 2)`` records each beam's two
    best keyframes (-1 where none is under the cutoff); 2: only the keyframes in
    ``ws.cand`` (the cheap evaluation near a pose where they were recorded)."""
    c = math.cos(th)
    s = math.sin(th)
    pts = beams.pts
    n_b = pts.shape[0]
    work, iwork = ws.work, ws.iwork
    wx, wy, best, second, bgx, bgy = work[0], work[1], work[2], work[3], work[4], work[5]
    k1, k2 = iwork[0], iwork[1]
    for b in range(n_b):
        wx[b] = x + c * pts[b, 0] - s * pts[b, 1]
        wy[b] = y + s * pts[b, 0] + c * pts[b, 1]
        best[b] = cut2
        second[b] = cut2
        bgx[b] = 0.0
        bgy[b] = 0.0
        k1[b] = -1
        k2[b] = -1
    if mode < 2:
        _two_best(beams, fields, kpose, cut2, ws)
        if mode == 1:
            for b in range(n_b):
                ws.cand[b, 0] = k1[b]
                ws.cand[b, 1] = k2[b]
    else:
        _candidates_best(beams, fields, kpose, cut2, ws, grad)
    return _sum_residuals(x, y, cut2, ws, h, g, grad)


@njit(cache=True, nogil=True)
def _two_best(beams: Beams, fields: FieldPack, kpose: np.ndarray, cut2: float,
              ws: Workspace) -> None:
    """Every beam against every keyframe (its constants loaded once, a tight beam loop):
    each beam's best and second best residual, the best's gradient (world frame) and
    both keyframes, into ``ws``."""
    use_i = beams.alpha > 0.0
    work, iwork = ws.work, ws.iwork
    wx, wy, best, second, bgx, bgy = work[0], work[1], work[2], work[3], work[4], work[5]
    k1, k2 = iwork[0], iwork[1]
    for k in range(kpose.shape[0]):
        kf = _keyframe(kpose, fields, k)
        ck, sk = kf[0], kf[1]
        geo = kf[5] == 1 and not use_i
        for b in range(beams.pts.shape[0]):
            qx, qy = _to_keyframe(kf, wx[b], wy[b])
            found, val, gqx, gqy = _beam_value(fields, kf, geo, qx, qy,
                                               beams.li[b] if use_i else 0.0, beams.alpha,
                                               cut2, second[b], True)
            if found:
                if val < best[b]:
                    second[b] = best[b]
                    k2[b] = k1[b]
                    best[b] = val
                    k1[b] = k
                    bgx[b] = ck * gqx - sk * gqy
                    bgy[b] = sk * gqx + ck * gqy
                else:
                    second[b] = val
                    k2[b] = k


@njit(cache=True, nogil=True)
def _candidates_best(beams: Beams, fields: FieldPack, kpose: np.ndarray, cut2: float,
                     ws: Workspace, grad: bool) -> None:
    """Every beam against its candidate keyframes ``ws.cand`` only: its best residual and
    that one's gradient (world frame), into ``ws``."""
    use_i = beams.alpha > 0.0
    work = ws.work
    wx, wy, best, bgx, bgy = work[0], work[1], work[2], work[4], work[5]
    cand = ws.cand
    for b in range(beams.pts.shape[0]):
        for m in range(cand.shape[1]):
            k = cand[b, m]
            if k < 0:
                continue
            kf = _keyframe(kpose, fields, k)
            qx, qy = _to_keyframe(kf, wx[b], wy[b])
            found, val, gqx, gqy = _beam_value(fields, kf, kf[5] == 1 and not use_i, qx, qy,
                                               beams.li[b] if use_i else 0.0, beams.alpha,
                                               cut2, best[b], grad)
            if found:
                best[b] = val
                bgx[b] = kf[0] * gqx - kf[1] * gqy
                bgy[b] = kf[1] * gqx + kf[0] * gqy


@njit(cache=True, nogil=True)
def _sum_residuals(x: float, y: float, cut2: float, ws: Workspace, h: np.ndarray,
                   g: np.ndarray, grad: bool) -> tuple[float, int]:
    """Σ_b ρ_b of the beams' best residuals in ``ws``, the inliers (under ``cut2``) and,
    with ``grad``, the Gauss-Newton system of ``e_b = sqrt(ρ_b)`` at (x, y)."""
    work = ws.work
    wx, wy, best, bgx, bgy = work[0], work[1], work[2], work[4], work[5]
    total = 0.0
    inl = 0
    if grad:
        h[:, :] = 0.0
        g[:] = 0.0
    for b in range(best.shape[0]):
        rb = best[b]
        total += rb
        if rb < cut2:
            inl += 1
            if grad:
                e = math.sqrt(rb)
                if e > 1e-6:
                    f = 0.5 / e
                    j0 = bgx[b] * f
                    j1 = bgy[b] * f
                    j2 = (bgx[b] * (y - wy[b]) + bgy[b] * (wx[b] - x)) * f
                    h[0, 0] += j0 * j0
                    h[0, 1] += j0 * j1
                    h[0, 2] += j0 * j2
                    h[1, 1] += j1 * j1
                    h[1, 2] += j1 * j2
                    h[2, 2] += j2 * j2
                    g[0] += j0 * e
                    g[1] += j1 * e
                    g[2] += j2 * e
    if grad:
        h[1, 0] = h[0, 1]
        h[2, 0] = h[0, 2]
        h[2, 1] = h[1, 2]
    return total, inl


@njit(cache=True, nogil=True)
def score_offsets(hat: np.ndarray, offs: np.ndarray, beams: Beams, fields: FieldPack,
                  kpose: np.ndarray, cut2: float, cand: np.ndarray, out: np.ndarray) -> None:
    """``out[j]`` = Σ_b ρ_b at the pose ``hat + offs[j]`` on each beam's candidate
    keyframes ``cand``: what :func:`score` gives in mode 2 for each pose, to the bit
    (the same sums in the same order), but beam by beam -- one beam's lookups at the
    nearby poses read the same few cells, and its keyframe's constants are loaded once."""
    n = offs.shape[0]
    xs = np.empty(n)
    ys = np.empty(n)
    cs = np.empty(n)
    sn = np.empty(n)
    best = np.empty(n)
    for j in range(n):
        xs[j] = hat[0] + offs[j, 0]
        ys[j] = hat[1] + offs[j, 1]
        t = hat[2] + offs[j, 2]
        cs[j] = math.cos(t)
        sn[j] = math.sin(t)
        out[j] = 0.0
    use_i = beams.alpha > 0.0
    pts = beams.pts
    for b in range(pts.shape[0]):
        px = pts[b, 0]
        py = pts[b, 1]
        lb = beams.li[b] if use_i else 0.0
        for j in range(n):
            best[j] = cut2
        for m in range(cand.shape[1]):
            k = cand[b, m]
            if k < 0:
                continue
            kf = _keyframe(kpose, fields, k)
            geo = kf[5] == 1 and not use_i
            for j in range(n):
                # the world point as score forms it (x + c px - s py), then its frame
                qx, qy = _to_keyframe(kf, xs[j] + cs[j] * px - sn[j] * py,
                                      ys[j] + sn[j] * px + cs[j] * py)
                found, val, _, _ = _beam_value(fields, kf, geo, qx, qy, lb, beams.alpha, cut2,
                                               best[j], False)
                if found:
                    best[j] = val
        for j in range(n):
            out[j] += best[j]


# -- the matcher ----------------------------------------------------------------------------
@njit(cache=True, nogil=True)
def solve3(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> bool:
    """``out = a^-1 b`` for a 3x3 (cofactors); False when (nearly) singular."""
    c00 = a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]
    c01 = a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]
    c02 = a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]
    det = a[0, 0] * c00 + a[0, 1] * c01 + a[0, 2] * c02
    scale = abs(a[0, 0] * a[1, 1] * a[2, 2]) + 1e-300
    if not abs(det) > 1e-12 * scale:
        return False
    c10 = a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]
    c11 = a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]
    c12 = a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]
    c20 = a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]
    c21 = a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]
    c22 = a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]
    out[0] = (c00 * b[0] + c10 * b[1] + c20 * b[2]) / det
    out[1] = (c01 * b[0] + c11 * b[1] + c21 * b[2]) / det
    out[2] = (c02 * b[0] + c12 * b[1] + c22 * b[2]) / det
    return True


@njit(cache=True, nogil=True)
def _energy(cost: float, x: float, y: float, t: float, inv_2s2: float, prior: np.ndarray,
            ) -> float:
    """``-log τ`` up to a constant: ``Σ_b ρ_b / (2σ²)`` plus the motion model's
    ``½ Σ_i ((x_i - x'_i) / σ_i)²``; ``prior (2, 3)`` = x' and 1/σ² (zeros: no prior)."""
    dt = wrap_scalar(t - prior[0, 2])
    return cost * inv_2s2 + 0.5 * (prior[1, 0] * (x - prior[0, 0]) ** 2
                                   + prior[1, 1] * (y - prior[0, 1]) ** 2
                                   + prior[1, 2] * dt * dt)


@njit(cache=True, nogil=True)
def _lm(pose: np.ndarray, beams: Beams, fields: FieldPack, kpose: np.ndarray,
        model: MatchModel, ws: Workspace, prior: np.ndarray) -> None:
    """Levenberg-Marquardt on :func:`_energy` from ``pose`` (updated in place), evaluating
    only each beam's candidate keyframes ``ws.cand`` (mode 2 of :func:`score`)."""
    h = np.zeros((3, 3))
    g = np.zeros(3)
    hn = np.zeros((3, 3))
    gn = np.zeros(3)
    a = np.zeros((3, 3))
    rhs = np.zeros(3)
    step = np.zeros(3)
    cut2, inv_2s2 = model.cut2, model.inv_2s2
    x, y, t = pose[0], pose[1], pose[2]
    cost, inl = score(x, y, t, beams, fields, kpose, cut2, 2, ws, h, g, True)
    e = _energy(cost, x, y, t, inv_2s2, prior)
    lam = 1e-3
    k2 = 2.0 * inv_2s2
    for _ in range(model.max_iter):
        if inl < 3:
            break
        d = (x - prior[0, 0], y - prior[0, 1], wrap_scalar(t - prior[0, 2]))
        for r in range(3):
            for q in range(3):
                a[r, q] = k2 * h[r, q]
            a[r, r] += prior[1, r]
            a[r, r] += lam * a[r, r] + 1e-9
            rhs[r] = -(k2 * g[r] + prior[1, r] * d[r])
        if not solve3(a, rhs, step):
            break
        # a trust region: Gauss-Newton on a truncated cost can jump into another basin
        f = max(math.hypot(step[0], step[1]) / _MAX_STEP_M, abs(step[2]) / _MAX_STEP_RAD)
        if f > 1.0:
            step /= f
        nx, ny, nt = x + step[0], y + step[1], t + step[2]
        c2, i2 = score(nx, ny, nt, beams, fields, kpose, cut2, 2, ws, hn, gn, True)
        e2 = _energy(c2, nx, ny, nt, inv_2s2, prior)
        if e2 < e:
            x, y, t, e, inl = nx, ny, nt, e2, i2
            h[:, :] = hn
            g[:] = gn
            lam = max(lam * 0.3, 1e-7)
            if abs(step[0]) < 1e-4 and abs(step[1]) < 1e-4 and abs(step[2]) < 1e-4:
                break
        else:
            lam *= 10.0
            if lam > 1e4:
                break
    pose[0] = x
    pose[1] = y
    pose[2] = t


@njit(cache=True, nogil=True)
def scan_match(start: np.ndarray, beams: Beams, fields: FieldPack, kpose: np.ndarray,
               model: MatchModel, ws: Workspace, h: np.ndarray,
               prior: np.ndarray) -> tuple[np.ndarray, float, int]:
    """x̂ = argmax_x p(z|m,x) p(x|x_{t-1},u) (:func:`_energy`; ``prior`` all zero:
    argmax p(z|m,x) alone) from ``start``: rounds of a full evaluation (which records
    each beam's two best keyframes in ``ws.cand`` and the Gauss-Newton ``J^T J`` in
    ``h``) followed by Levenberg-Marquardt on those candidates, until a round moves the
    pose by less than half a grid cell and 0.01 rad (at most three rounds). Returns x̂
    and Σ_b ρ_b and the inlier count of the last full evaluation (less than that much
    away from x̂, as are ``ws.cand`` and ``h``)."""
    pose = start.copy()
    g = np.zeros(3)
    tol = 0.5 / fields.inv_res
    cost = 0.0
    inl = 0
    for _ in range(3):
        cost, inl = score(pose[0], pose[1], pose[2], beams, fields, kpose, model.cut2, 1,
                           ws, h, g, True)
        x0, y0, t0 = pose[0], pose[1], pose[2]
        _lm(pose, beams, fields, kpose, model, ws, prior)
        if abs(pose[0] - x0) < tol and abs(pose[1] - y0) < tol and abs(pose[2] - t0) < 0.01:
            break
    pose[2] = wrap_scalar(pose[2])
    return pose, cost, inl


@njit(cache=True, nogil=True)
def kposes(kf_pose: np.ndarray, p: int, out: np.ndarray) -> None:
    """Particle ``p``'s keyframe poses ``kf_pose[:, p]`` as (cos, sin, x, y) rows."""
    for k in range(kf_pose.shape[0]):
        out[k, 0] = math.cos(kf_pose[k, p, 2])
        out[k, 1] = math.sin(kf_pose[k, p, 2])
        out[k, 2] = kf_pose[k, p, 0]
        out[k, 3] = kf_pose[k, p, 1]


@njit(cache=True, nogil=True)
def count_inliers(pose: np.ndarray, beams: Beams, fields: FieldPack, kf_pose: np.ndarray,
                  inlier2: float) -> int:
    """How many beams at ``pose`` lie within ``sqrt(inlier2)`` of the map ``kf_pose
    (K, 1, 3)`` (the minimum over its keyframes)."""
    kpose = np.empty((kf_pose.shape[0], 4))
    kposes(kf_pose, 0, kpose)
    n_b = beams.pts.shape[0]
    ws = Workspace(np.zeros((1, 2), dtype=np.int64), np.empty((6, n_b)),
                   np.empty((2, n_b), dtype=np.int64))
    _, inl = score(pose[0], pose[1], pose[2], beams, fields, kpose, inlier2, 0, ws,
                    np.zeros((3, 3)), np.zeros(3), False)
    return inl


# -- the loop search ------------------------------------------------------------------------
def loop_search(center: np.ndarray, beams: Beams, fields: FieldPack, kf_pose: np.ndarray,
                model: MatchModel, grid: LoopGrid,
                threads: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A wide search of the scan against one map ``kf_pose (K, 1, 3)`` (the old
    keyframes of a loop): a correlative grid of poses around ``center`` (``grid``)
    scored by Σ_b min(ρ_b, ``grid.coarse2``); ``center`` itself and the
    ``grid.n_refine`` best, at least ``grid.min_sep`` apart from each other and from
    ``center``, refined by :func:`scan_match` on the scan alone. Returns the refined
    poses ``(M, 3)`` (the first refined from ``center``), their beams within
    sqrt(``grid.inlier2``) of the map ``(M,)`` and the smallest eigenvalue of the
    position block of ``J^T J`` at each ``(M,)`` (about the number of beams that pin the
    position down in its weakest direction; ~0 along a corridor). The grid's headings
    are split over ``threads`` (the same scores in the same order whatever their
    number)."""
    na = int(round(grid.half_angle / grid.angle_step))
    headings = np.arange(-na, na + 1)
    kpose = np.empty((kf_pose.shape[0], 4))
    kposes(kf_pose, 0, kpose)

    def part(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return _loop_grid(center, beams, fields, kpose, grid, int(a[0]), int(a[-1]) + 1)

    parts = np.array_split(headings, max(1, min(threads, len(headings))))
    done = thread_map(part, parts, threads)
    poses = np.concatenate([d[0] for d in done])
    cost = np.concatenate([d[1] for d in done])
    return _loop_refine(center, poses, cost, beams, fields, kpose, model, grid)


@njit(cache=True, nogil=True)
def _loop_grid(center: np.ndarray, beams: Beams, fields: FieldPack, kpose: np.ndarray,
               grid: LoopGrid, a_from: int, a_to: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`loop_search`'s grid for the heading indices ``a_from .. a_to - 1``: its
    poses ``(N, 3)`` (heading, then x, then y) and their capped costs ``(N,)``."""
    ws = new_workspace(beams.pts.shape[0])
    step = grid.step
    nxy = int(round(grid.radius / step))
    n = (2 * nxy + 1) * (2 * nxy + 1) * (a_to - a_from)
    poses = np.empty((n, 3))
    cost = np.empty(n)
    q = 0
    for a in range(a_from, a_to):
        for i in range(-nxy, nxy + 1):
            for j in range(-nxy, nxy + 1):
                poses[q, 0] = center[0] + i * step
                poses[q, 1] = center[1] + j * step
                poses[q, 2] = center[2] + a * grid.angle_step
                cost[q] = _grid_cost(poses[q, 0], poses[q, 1], poses[q, 2], beams, fields,
                                     kpose, grid.coarse2, ws)
                q += 1
    return poses, cost


@njit(cache=True, nogil=True)
def _grid_cost(x: float, y: float, th: float, beams: Beams, fields: FieldPack,
               kpose: np.ndarray, cut2: float, ws: Workspace) -> float:
    """Σ_b ρ_b at pose (x, y, th): what :func:`score` gives in mode 0, to the bit (each
    beam's minimum over the keyframes, summed in the same order), without what only the
    matcher reads (the second best, the gradients, the inliers)."""
    c = math.cos(th)
    s = math.sin(th)
    pts = beams.pts
    n_b = pts.shape[0]
    work = ws.work
    wx, wy, best = work[0], work[1], work[2]
    for b in range(n_b):
        wx[b] = x + c * pts[b, 0] - s * pts[b, 1]
        wy[b] = y + s * pts[b, 0] + c * pts[b, 1]
        best[b] = cut2
    use_i = beams.alpha > 0.0
    for k in range(kpose.shape[0]):
        kf = _keyframe(kpose, fields, k)
        geo = kf[5] == 1 and not use_i
        for b in range(n_b):
            qx, qy = _to_keyframe(kf, wx[b], wy[b])
            found, val, _, _ = _beam_value(fields, kf, geo, qx, qy,
                                           beams.li[b] if use_i else 0.0, beams.alpha,
                                           cut2, best[b], False)
            if found:
                best[b] = val
    total = 0.0
    for b in range(n_b):
        total += best[b]
    return total


@njit(cache=True, nogil=True)
def _distinct_best(center: np.ndarray, poses: np.ndarray, cost: np.ndarray, n_refine: int,
                   min_sep: float) -> np.ndarray:
    """``center`` and the ``n_refine`` lowest-cost ``poses``, each at least ``min_sep``
    from those before it (``(M, 3)``, M ≤ n_refine + 1)."""
    order = np.argsort(cost)
    kept = np.empty((n_refine + 1, 3))
    kept[0] = center  # the current estimate, refined too: the rival every mode must beat
    m = 1
    for q in order:
        far = True
        for r in range(m):
            if math.hypot(poses[q, 0] - kept[r, 0], poses[q, 1] - kept[r, 1]) < min_sep:
                far = False
                break
        if far:
            kept[m] = poses[q]
            m += 1
            if m == n_refine + 1:
                break
    return kept[:m]


@njit(cache=True, nogil=True)
def _loop_refine(center: np.ndarray, poses: np.ndarray, cost: np.ndarray, beams: Beams,
                 fields: FieldPack, kpose: np.ndarray, model: MatchModel,
                 grid: LoopGrid) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`loop_search`'s refinement of ``center`` and of the best grid poses."""
    ws = new_workspace(beams.pts.shape[0])
    h = np.zeros((3, 3))
    g = np.zeros(3)
    kept = _distinct_best(center, poses, cost, grid.n_refine, grid.min_sep)
    m = kept.shape[0]
    free = np.zeros((2, 3))
    out = np.empty((m, 3))
    inl = np.empty(m, dtype=np.int64)
    eig = np.empty(m)
    for r in range(m):
        hat, _, _ = scan_match(kept[r], beams, fields, kpose, model, ws, h, free)
        out[r] = hat
        tr = h[0, 0] + h[1, 1]
        det = h[0, 0] * h[1, 1] - h[0, 1] * h[0, 1]
        eig[r] = 0.5 * tr - math.sqrt(max(0.25 * tr * tr - det, 0.0))
        _, inl[r] = score(hat[0], hat[1], hat[2], beams, fields, kpose, grid.inlier2, 0, ws,
                           h, g, False)
    return out, inl, eig
