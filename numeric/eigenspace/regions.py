"""Localizable regions (paper §2.4, eq. 6) and the chance of entering one (§3.2, eq. 7).

For a triplet t and a query projection x', d is the smallest eq.-3 difference to the
triplet's three images and ``D_err = c_a d / sqrt(A)`` (eq. 6, A the triangle area);
the query lies in the region when ``D_err < D_thd``.  ``c_a`` is fitted by least
squares from observations of known pose inside the triplets' triangles (simulated, or
a user's calibration images).  In the real world the distance of a pose to region t is
``D(s)`` = the smallest distance to the triplet's three learning points, and
``P(R|s) = clamp(c0 + c1 D(s), 0, 1)`` (eq. 7).

Chizu's reading of §2.4 (a region is where eq. 5 is accurate): as d is a minimum over
three images, an image close to one of them but not explained by the interpolation
(far from the plane of eq. 4) passed the paper's test and was placed 1-1.7 m off (the
failures of Table 1 in room A: observers about 1 m from the triplet). The test also
asks eq. 6 of the distance to that plane to stay below ``plane_m`` (0.1 m, half the
paper's D_thd of 200 mm): Table 1 in room A 85 -> 96 %, the Table 2 error ratio 0.43
-> 0.35, at the cost of fewer entries (307 -> 134 of 4320 images in A). The bound is
in metres, not a share of D_thd: it is the accuracy eq. 5 must have, and a larger D_thd
should widen where the paper's test admits, not how far off eq. 5 may place. Tied to
D_thd (0.15 m at D_thd 0.3 m), Table 1 at 0.3 m was 90-96 % in rooms A-D (60 turns
each); with 0.1 m it is 96-100 % (docs/notes/eigenspace.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator
from scipy.spatial.distance import cdist

from chizu.numeric.eigenspace.interpolation import affine_weights, interpolate_pose
from chizu.numeric.eigenspace.learning import DYNAMIC_RANGE, EigenspaceModel, f_d
from chizu.numeric.eigenspace.triplets import Triplets
from chizu.numeric.errors import InvalidInput
from chizu.numeric.geometry import bearing, wrap_angle
from chizu.numeric.world import World


class RegionConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    d_thd_m: float = Field(0.2, gt=0.0, le=100.0, description="D_thd of §2.4 (paper 200 mm)")
    c_a: float | None = Field(None, gt=0.0, description="eq. 6 constant; fitted when None")
    calibration_per_triplet: int = Field(4, ge=1, le=100)
    plane_m: float | None = Field(
        0.1, gt=0.0, le=100.0,
        description="also require eq. 6 on the distance to the triplet's plane (eq. 4) "
                    "below this (m): the accuracy eq. 5 must have, whatever D_thd; None: "
                    "the paper's test on d alone")
    reject_false_admissions: bool = Field(
        True, description="drop triplets whose region admits a learning image of another "
                          "point and places it wrong (false_admissions)")
    max_wrong_share: float | None = Field(
        0.15, ge=0.0, le=1.0,
        description="drop a triplet when more than this share of the probe turns its "
                    "region admits (the simulator's turns of known pose) are placed wrong "
                    "by eq. 5, beyond the localization tolerances; None: keep them")

    @model_validator(mode="before")
    @classmethod
    def _plane_ratio(cls, data: object) -> object:
        """Analyses stored before ``plane_m`` name the bound as ``plane_ratio`` x D_thd."""
        if isinstance(data, dict) and "plane_ratio" in data:
            data = dict(data)
            ratio = data.pop("plane_ratio")
            if "plane_m" not in data:
                thd = data.get("d_thd_m", cls.model_fields["d_thd_m"].default)
                data["plane_m"] = None if ratio is None else float(ratio) * float(thd)
        return data

    @property
    def plane_thd_m(self) -> float | None:
        return self.plane_m


@dataclass
class Candidates:
    """Region hits of M query images against T triplets: for each hit ``m`` (image
    index), ``t`` (triplet), ``d`` (eq. 3 minimum), ``d_err`` (eq. 6) and the
    interpolated pose ``pose (n, 3)`` (eqs. 4-5)."""

    m: np.ndarray
    t: np.ndarray
    d: np.ndarray
    d_err: np.ndarray
    pose: np.ndarray

    def __len__(self) -> int:
        return len(self.m)


#: bytes of the (queries, T, 3, K) difference tensor computed at once
CHUNK_BYTES = 64 * 2**20


def query_chunks(n_queries: int, n_triplets: int, k: int) -> range:
    """Start indices of query chunks whose difference tensor stays under
    :data:`CHUNK_BYTES` (a 1 m grid of an office is 8 000 learning images against 2 700
    triplets: 10 GiB in one piece)."""
    step = max(1, CHUNK_BYTES // max(1, n_triplets * 3 * k * 8))
    return range(0, n_queries, step)


def triplet_differences(model: EigenspaceModel, triplets: Triplets,
                        query: np.ndarray) -> np.ndarray:
    """d of §2.4 for every query projection and triplet: ``(M, T)``, the smallest of
    eq. 2's f_d between the query and the triplet's three images. Each distinct member
    image is measured once (scipy's cdist) and the triplets gather from it: triplets
    share images, and no ``(M, T, 3, K)`` difference tensor is built."""
    n_dirs, k = model.projections.shape[1:]
    flat = triplets.point_idx * n_dirs + triplets.dir_idx  # (T, 3) member image ids
    images, member = np.unique(flat, return_inverse=True)
    member = member.reshape(flat.shape)
    x = model.projections.reshape(-1, k)[images]  # (U, K)
    scale = 1.0 / (DYNAMIC_RANGE * np.sqrt(model.n_pixels))
    out = np.empty((len(query), len(triplets)))
    chunks = query_chunks(len(query), len(triplets), k)
    for a in chunks:
        d = cdist(query[a:a + chunks.step], x) * scale  # (m, U), eq. 2
        out[a:a + len(d)] = d[:, member].min(axis=2)
    return out


def estimation_error(d: np.ndarray, area: np.ndarray, c_a: float) -> np.ndarray:
    """Eq. 6: D_err = c_a d / sqrt(A) [m]."""
    return c_a * d / np.sqrt(area)


def interpolate(model: EigenspaceModel, triplets: Triplets, query: np.ndarray,
                t: np.ndarray) -> np.ndarray:
    """Eqs. 4-5 for pairs (query[i], triplet t[i]): poses ``(n, 3)``."""
    k = affine_weights(query, triplets.projections(model)[t])
    return interpolate_pose(k, triplets.poses(model)[t])


def plane_residual(model: EigenspaceModel, triplets: Triplets, query: np.ndarray,
                   t: np.ndarray) -> np.ndarray:
    """For pairs (query[i], triplet t[i]): the eq.-2 distance from the query to the
    plane of eq. 4 through the triplet's three images (what eq. 4's projection drops)."""
    x3 = triplets.projections(model)[t]
    k = affine_weights(query, x3)
    xp = np.einsum("ni,nik->nk", k, x3)
    return np.asarray(f_d(query, xp, model.n_pixels))


def near_plane(model: EigenspaceModel, triplets: Triplets, query: np.ndarray, t: np.ndarray,
               c_a: float, plane_thd: float) -> np.ndarray:
    """The plane test of :func:`region_candidates` for pairs (query[i], triplet t[i]):
    eq. 6 applied to :func:`plane_residual` below ``plane_thd``."""
    res = estimation_error(plane_residual(model, triplets, query, t), triplets.area[t], c_a)
    return np.asarray(res < plane_thd)


def region_candidates(model: EigenspaceModel, triplets: Triplets, query: np.ndarray,
                      c_a: float, d_thd: float, plane_thd: float | None = None) -> Candidates:
    """Every (image, triplet) pair whose D_err < D_thd, with its interpolated pose.

    With ``plane_thd``, a pair must also lie near the triplet's plane: eq. 6 applied
    to :func:`plane_residual` instead of d below ``plane_thd``."""
    if len(triplets) == 0:
        z = np.zeros(0, dtype=int)
        return Candidates(z, z, np.zeros(0), np.zeros(0), np.zeros((0, 3)))
    z = np.zeros(0, dtype=int)
    ms, ts, ds, es, ps = [z], [z], [np.zeros(0)], [np.zeros(0)], [np.zeros((0, 3))]
    chunks = query_chunks(len(query), len(triplets), query.shape[-1])
    for a in chunks:  # chunk by chunk, the pairs in a region only: memory stays bounded
        q = query[a:a + chunks.step]
        d = triplet_differences(model, triplets, q)
        err = estimation_error(d, triplets.area[None, :], c_a)
        mc, tc = np.nonzero(err < d_thd)
        d_in, err_in = d[mc, tc], err[mc, tc]
        if plane_thd is not None and len(mc):
            keep = near_plane(model, triplets, q[mc], tc, c_a, plane_thd)
            mc, tc, d_in, err_in = mc[keep], tc[keep], d_in[keep], err_in[keep]
        if len(mc):
            ms.append(mc + a)
            ts.append(tc)
            ds.append(d_in)
            es.append(err_in)
            ps.append(interpolate(model, triplets, q[mc], tc))
    return Candidates(np.concatenate(ms), np.concatenate(ts), np.concatenate(ds),
                      np.concatenate(es), np.concatenate(ps))


def agrees(poses: np.ndarray, reference: np.ndarray, position_m: float,
           heading_rad: float) -> np.ndarray:
    """Which poses ``(..., 3)`` lie within ``position_m`` and ``heading_rad`` of
    ``reference`` (``(..., 3)``, broadcast against them): the identification test of
    §2.5."""
    p, q = np.asarray(poses, dtype=float), np.asarray(reference, dtype=float)
    return np.asarray((np.hypot(p[..., 0] - q[..., 0], p[..., 1] - q[..., 1]) <= position_m)
                      & (np.abs(wrap_angle(p[..., 2] - q[..., 2])) <= heading_rad))


def false_admissions(model: EigenspaceModel, triplets: Triplets, c_a: float, d_thd: float,
                     position_m: float, heading_rad: float,
                     plane_thd: float | None = None
                     ) -> tuple[np.ndarray, set[tuple[int, int]]]:
    """How many learning images ``(T,)`` of points outside each triplet fall in its
    region (eq. 6) and are placed by eq. 5 farther than ``position_m`` / ``heading_rad``
    from where they were taken.

    The region is meant as a bound: inside it the error of eq. 5 stays below D_thd
    (§2.4), which is why the paper fixes D_thd where every entered region is a right one
    (Table 1). A learning image of a neighbouring point is an observation whose pose is
    known, so a triplet that places one metres off is a false triplet: typically one of
    its images is bland (close to the mean image), and as d is the minimum over the three
    images, that image matches almost anything (room A: one such triplet entered 25 of 60
    random turns, 15 of them from more than 2 m away). Chizu's reading of §2.3-§2.4:
    such triplets are rejected at learning time, using only the learning images (a user's
    own camera gives no other images of known pose).

    Look-alike places are not necessarily false triplets: when triplet t admits a
    member image of triplet t' and t' admits a member image of t, the two are twins (a
    room symmetric under a turn, a repeated photograph). Those admissions are not
    counted here but returned as ``twins``: the paper resolves such confusions with
    candidate-multiple sets (§3.3, state Y) and moving, so the caller keeps twins that
    a candidate-multiple set groups (:func:`chizu.numeric.eigenspace.analysis.validated`).

    Returns ``(counts (T,), twins)`` with twins the set of twin pairs (t, t')."""
    _, n_t, k = model.projections.shape
    if len(triplets) == 0:
        return np.zeros(0, dtype=int), set()
    c = region_candidates(model, triplets, model.projections.reshape(-1, k), c_a, d_thd,
                          plane_thd)
    w, j = np.divmod(c.m, n_t)
    member = (triplets.point_idx[c.t] == w[:, None]).any(axis=1)
    taken = np.column_stack([model.points[w], model.directions[j]])
    wrong = ~member & ~agrees(c.pose, taken, position_m, heading_rad)
    twin = mutual_admissions(triplets, n_t, c.t[wrong], c.m[wrong])
    return (np.bincount(c.t[wrong][twin < 0], minlength=len(triplets)),
            {(int(a), int(b)) for a, b in zip(c.t[wrong][twin >= 0], twin[twin >= 0],
                                              strict=True)})


def mutual_admissions(triplets: Triplets, n_directions: int, t: np.ndarray,
                      image: np.ndarray) -> np.ndarray:
    """For admissions (triplet ``t[i]`` admits learning image ``image[i]`` = point x
    N_theta + direction): a triplet t' whose member image it is and which in turn
    admits a member image of t[i], or -1."""
    members = triplets.point_idx * n_directions + triplets.dir_idx  # (T, 3) image ids
    owners: dict[int, list[int]] = {}
    for tt, row in enumerate(members):
        for im in row:
            owners.setdefault(int(im), []).append(tt)
    admitted = set(zip(t.tolist(), image.tolist(), strict=True))
    out = np.full(len(t), -1, dtype=int)
    for i, (ti, im) in enumerate(zip(t.tolist(), image.tolist(), strict=True)):
        for t2 in owners.get(im, ()):
            if any((t2, int(mine)) in admitted for mine in members[ti]):
                out[i] = t2
                break
    return out


def calibration_poses(world: World, model: EigenspaceModel, triplets: Triplets,
                      per_triplet: int, rng: np.random.Generator
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Where the simulator observes to fit c_a: for each triplet, poses uniformly inside
    its triangle looking at its target (+-half a direction step), in free space.
    Returns ``(triplet index (M,), pose (M, 3))``."""
    ts, poses = [], []
    step = np.pi / len(model.directions)
    for t in range(len(triplets)):
        tri = model.points[triplets.point_idx[t]]
        for _ in range(per_triplet):
            r1, r2 = rng.random(2)
            if r1 + r2 > 1:
                r1, r2 = 1 - r1, 1 - r2
            xy = tri[0] + r1 * (tri[1] - tri[0]) + r2 * (tri[2] - tri[0])
            th = float(bearing(xy, triplets.target[t])[0]) + rng.uniform(-step, step)
            ts.append(t)
            poses.append((xy[0], xy[1], th))
    if not poses:
        raise InvalidInput("no localizable triplets to calibrate the region model with",
                           field="triplets")
    pose_arr = np.array(poses)
    ok = world.is_free(pose_arr[:, :2], clearance_m=0.1)
    return np.array(ts)[ok], pose_arr[ok]


def calibration_pairs(model: EigenspaceModel, triplets: Triplets,
                      poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which (observation, triplet) pairs calibrate c_a the way the simulator's do: the
    observation stands inside the triangle and looks at the triplet's target within
    half a direction step. Returns ``(observation index, triplet index)``."""
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    if len(poses) == 0 or len(triplets) == 0:
        z = np.zeros(0, dtype=int)
        return z, z
    tri = model.points[triplets.point_idx]  # (T, 3, 2)
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    v0, v1 = b - a, c - a  # (T, 2)
    den = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]  # (T,)
    obs_all, t_all = [np.zeros(0, dtype=int)], [np.zeros(0, dtype=int)]
    step = max(1, 2**22 // len(triplets))  # (M, T) arrays of at most 4 M entries at once
    for s in range(0, len(poses), step):
        p = poses[s:s + step]
        v2 = p[:, None, :2] - a[None]  # (m, T, 2)
        u = (v2[..., 0] * v1[:, 1] - v2[..., 1] * v1[:, 0]) / den
        v = (v0[:, 0] * v2[..., 1] - v0[:, 1] * v2[..., 0]) / den
        inside = (u >= 0) & (v >= 0) & (u + v <= 1)
        look = np.arctan2(triplets.target[None, :, 1] - p[:, None, 1],
                          triplets.target[None, :, 0] - p[:, None, 0])
        facing = np.abs(wrap_angle(p[:, None, 2] - look)) <= np.pi / len(model.directions)
        o, t = np.nonzero(inside & facing)
        obs_all.append(o + s)
        t_all.append(t)
    return np.concatenate(obs_all), np.concatenate(t_all)


def leave_one_out_pairs(model: EigenspaceModel, triplets: Triplets,
                        radius_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Calibration pairs from the learning images alone, for a camera with no other
    images of known pose: each learning point within ``radius_m`` of a triplet it is
    not part of observes it in the learning direction nearest to the triplet's target.
    Returns ``(point index, direction index, triplet index)``.

    These observations stand outside the triangle, where eq. 5 extrapolates, so the c_a
    they give is larger than the one observations inside the triangles give (about 2.7x
    in rooms A and D and in an L-shaped room): the regions are smaller, a safe bound."""
    dist = real_world_distance(model, triplets, model.points)  # (Nw, T)
    w, t = np.nonzero(~triplets.membership(len(model.points)) & (dist <= radius_m))
    look = np.arctan2(triplets.target[t, 1] - model.points[w, 1],
                      triplets.target[t, 0] - model.points[w, 0])
    step = 2.0 * np.pi / len(model.directions)
    j = np.round(wrap_angle(look - model.directions[0]) / step).astype(int) % len(
        model.directions)
    return w, j, t


def calibration_errors(model: EigenspaceModel, triplets: Triplets, t: np.ndarray,
                       poses: np.ndarray, query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For observations ``query (M, K)`` taken at ``poses (M, 3)``, each paired with
    triplet ``t (M,)``: d of §2.4 and the position error of eq. 5 [m]."""
    x3 = triplets.projections(model)[t]  # (M, 3, K)
    d = np.asarray(f_d(query[:, None, :], x3, model.n_pixels)).min(axis=1).reshape(-1)
    est = interpolate(model, triplets, query, t) if len(t) else np.zeros((0, 3))
    return d, np.linalg.norm(est[:, :2] - np.asarray(poses)[:, :2], axis=1)


def fit_c_a(d: np.ndarray, area: np.ndarray, err: np.ndarray) -> float:
    """Least-squares c_a of eq. 6 through the origin: err ~ c_a d / sqrt(A)."""
    x = d / np.sqrt(area)
    den = float(np.dot(x, x))
    if den <= 0:
        raise InvalidInput("cannot fit c_a: all differences are zero", field="c_a")
    return float(np.dot(x, err) / den)


def real_world_distance(model: EigenspaceModel, triplets: Triplets,
                        xy: np.ndarray) -> np.ndarray:
    """D(s) of §3.2: ``(M, T)`` smallest distance from each position to a triplet's points."""
    pts = model.points[triplets.point_idx]  # (T, 3, 2)
    xy = np.atleast_2d(np.asarray(xy, dtype=float))
    return np.asarray(np.linalg.norm(xy[:, None, None, :] - pts[None], axis=-1).min(axis=2))


@dataclass(frozen=True)
class EntryModel:
    """Eq. 7: P(R|s) = clamp(c0 + c1 D(s), 0, 1) with D in metres."""

    c0: float
    c1: float

    def probability(self, distance_m: np.ndarray) -> np.ndarray:
        return np.clip(self.c0 + self.c1 * np.asarray(distance_m), 0.0, 1.0)


def fit_entry_model(distances: np.ndarray, entered: np.ndarray,
                    max_distance_m: float, min_samples: int = 8) -> EntryModel:
    """Fit eq. 7 on (D(s), entered) samples with D <= ``max_distance_m`` (§3.2).

    Eq. 7 is clamped, and so is the fit (:func:`fit_clamped_line`): the chance of
    entering falls to 0 well inside the sample range (room A: 0.38 at D < 0.25 m, 0.05
    at 1-1.5 m, 0 beyond 1.5 m). A straight line through all of it, zeros included,
    halved P near the points and stretched it to 2.3 m (c0 0.21, c1 -0.09 /m), which
    left the movement strategy nothing to prefer. The paper fits each region and
    averages c0 and c1; clamped fits of single regions, with a handful of entries each,
    are steep and their mean fits nothing (c0 0.86, c1 -2.7), so the regions' samples
    are pooled into one fit (room A: c0 0.39, c1 -0.29 /m).

    ``distances`` and ``entered`` are ``(S, T)``: sample poses x regions; regions with
    fewer than ``min_samples`` samples in range are left out.
    """
    near = distances <= max_distance_m
    use = near.sum(axis=0) >= min_samples
    x, y = distances[:, use][near[:, use]], entered[:, use][near[:, use]].astype(float)
    if len(x) == 0 or np.ptp(x) <= 0:
        raise InvalidInput("too few samples near the regions to fit P(R|s)", field="samples")
    return EntryModel(*fit_clamped_line(x, y, max_distance_m))


def fit_clamped_line(x: np.ndarray, y: np.ndarray, max_x: float,
                     steps: int = 64) -> tuple[float, float]:
    """Least squares of ``y ~ clamp(c0 + c1 x, 0, 1)`` with c1 <= 0: for each zero
    crossing x0 on a grid up to ``max_x`` (and beyond, for a line that never reaches
    0 there), the best ``c0`` in closed form, then the best pair. Returns (c0, c1)."""
    best = (np.inf, 0.0, 0.0)
    for x0 in np.linspace(max_x / steps, 4.0 * max_x, 4 * steps):
        f = np.maximum(0.0, 1.0 - x / x0)
        ff = float(f @ f)
        if ff <= 0:
            continue
        a = max(0.0, float(f @ y) / ff)
        sse = float(np.sum((np.clip(a * f, 0.0, 1.0) - y) ** 2))
        if sse < best[0]:
            best = (sse, a, -a / x0)
    return float(best[1]), float(best[2])
