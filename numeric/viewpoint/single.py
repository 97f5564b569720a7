"""t_single: the expected time to verify one object (Masuzawa & Miura, §5.1, eqs. 5-6).

Eq. 5 is the expected time of the best policy that observes from viewpoint X, goes to
the goal X_g on success, and otherwise recurses on the remaining viewpoints. With the
recognition indicator of eq. 4 a failed observation from X tells the robot that the
object's orientation is not one of those X would have recognised, so the recursion's
state is (position, remaining orientation set). :func:`single_dp` evaluates eq. 5
*exactly* by dynamic programming over the reachable orientation sets -- 2**N_theta at
most, a few dozen in practice -- instead of over the 24! viewpoint orders; P_recog(X) in
the recursion is eq. 3 conditioned on the remaining set.

Eq. 6's table (:class:`TableCache`): for a viewpoint pattern of Fig. 8
(:mod:`chizu.numeric.viewpoint.viewpoints`) the table holds t_single between every pair of its
viewpoints, which depends only on the object type, the pattern, the rotation and the
belief -- not on where the object is -- so one table serves every object of that type and
every re-plan. Times chain through intermediate viewpoints by min-plus products
(:func:`min_plus`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit
from numpy.typing import NDArray
from scipy.spatial.distance import cdist

from chizu.numeric.viewpoint.appearance import AppearanceModel
from chizu.numeric.viewpoint.viewpoints import DIRECTIONS, pattern_indices, viewpoint_circles


def min_plus(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The min-plus matrix product ``out[i, j] = min_k a[i, k] + b[k, j]``: chaining
    expected times through intermediate viewpoints."""
    return min_plus_arg(a, b)[0]


def min_plus_arg(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`min_plus` and the intermediate index that attains each minimum (the first
    one on ties; 0 where every sum is infinite)."""
    return _min_plus_arg(np.ascontiguousarray(a, dtype=np.float64),
                         np.ascontiguousarray(b, dtype=np.float64))


@njit(cache=True)
def _min_plus_arg(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    # a loop instead of numpy's (n, m, p) temporary: the products here are small and
    # many (one per subset and object in t_seq), and numpy's overhead dominated them
    n, m = a.shape
    p = b.shape[1]
    out = np.empty((n, p))
    arg = np.zeros((n, p), dtype=np.int64)
    for i in range(n):
        for j in range(p):
            best = np.inf
            k_best = 0
            for k in range(m):
                v = a[i, k] + b[k, j]
                if v < best:
                    best = v
                    k_best = k
            out[i, j] = best
            arg[i, j] = k_best
    return out, arg


def single_dp(points: np.ndarray, recog: NDArray[np.bool_], belief: np.ndarray,
              goals: np.ndarray, speed: float, t_verify: float) -> tuple[np.ndarray, bool]:
    """Eq. 5 by dynamic programming over (viewpoint, remaining orientation set).

    ``points (V, 2)`` the usable viewpoints, ``recog (V, N)`` eq. 4's indicator per
    orientation, ``belief (N,)`` P(theta_i), ``goals (G, 2)``. Returns ``Q (G, V)``, the
    expected time from arriving at viewpoint v (about to observe) to the goal, and
    whether any viewpoint can recognise the object at all. Then
    ``t_single(X_s, g) = min_v |X_s - v| / speed + Q[g, v]``.

    The orientation sets still possible are bit masks: the start set (orientations of
    positive belief) minus the sets of the viewpoints that failed. A set depends only on
    smaller ones, so the sets of one size are solved together (a handful of array
    operations per size instead of a Python loop over sets and viewpoints).
    """
    n_v, n_g = len(points), len(goals)
    b = np.asarray(belief, dtype=float)
    if len(b) > 62:
        raise ValueError("single_dp handles at most 62 orientations")
    weight = np.left_shift(np.int64(1), np.arange(len(b), dtype=np.int64))
    start = int(weight[b > 1e-12].sum())
    rbits = (np.asarray(recog, bool).reshape(n_v, len(b)) * weight).sum(axis=1)
    if n_v == 0 or not np.any(rbits & start):
        return np.full((n_g, n_v), np.inf), False
    # the reachable sets: start minus the sets of the viewpoints that failed
    masks = frontier = np.array([start], dtype=np.int64)
    while len(frontier):
        hit = (frontier[:, None] & rbits[None, :]) != 0
        nxt = np.unique((frontier[:, None] & ~rbits[None, :])[hit])
        frontier = np.setdiff1d(nxt, masks, assume_unique=True)
        masks = np.union1d(masks, frontier)
    bits = ((masks[:, None] >> np.arange(len(b))) & 1).astype(float)        # (M, N)
    size = bits.sum(axis=1).astype(int)
    mass = bits @ b
    with np.errstate(invalid="ignore", divide="ignore"):
        p_all = np.where(mass[:, None] > 0, (bits * b) @ recog.T.astype(float)
                         / mass[:, None], 0.0)                              # (M, V)
    d_vv = cdist(points, points) / speed                                     # (V, V)
    d_gv = cdist(goals, points) / speed                                      # (G, V)
    t_at = np.zeros((len(masks), n_g, n_v))   # T(a, set): time from viewpoint a
    v_idx = np.arange(n_v)
    q = np.full((1, n_v, n_g), np.inf)
    for k in np.unique(size):
        ids = np.nonzero(size == k)[0]
        p = p_all[ids]                                                       # (L, V)
        useful = p > 0
        nxt = np.searchsorted(masks, masks[ids, None] & ~rbits[None, :])     # (L, V)
        rest = t_at[np.where(useful & (p < 1), nxt, 0), :, v_idx[None, :]]   # (L, V, G)
        with np.errstate(invalid="ignore"):
            q = np.where(useful[..., None],
                         t_verify + p[..., None] * d_gv.T[None]
                         + np.where(p[..., None] < 1, (1 - p[..., None]) * rest, 0.0),
                         np.inf)                                             # (L, V, G)
        # T(a, set) = min_v d(a, v) + Q(v, set); nothing left to try: go to the goal
        t = np.min(q[:, :, :, None] + d_vv[None, :, None, :], axis=1)        # (L, G, V)
        t[~useful.any(axis=1)] = d_gv
        t_at[ids] = t
    return q[0].T, True  # the last size holds the start set alone


@dataclass
class VerificationTable:
    """Eq. 6's table for one object type, pattern, rotation and belief: ``T[b, a]`` =
    t_single from viewpoint a of the pattern to viewpoint b, object at the origin."""

    points: np.ndarray   # (V, 2) relative to the object
    times: np.ndarray    # (V_goal, V_start)
    feasible: bool


@dataclass
class TableCache:
    """The pattern tables, shared by every object of a type and every re-plan."""

    tables: dict[tuple[object, ...], VerificationTable] = field(default_factory=dict)
    hits: int = 0
    builds: int = 0

    def get(self, model: AppearanceModel, radii: tuple[float, float, float], pattern: str,
            rotation: int, belief: np.ndarray, speed: float, t_verify: float,
            ) -> VerificationTable:
        """The table of ``pattern`` turned by ``rotation`` * 45 deg. The appearance model
        depends only on the angle between the view and the object's orientation, so
        turning the pattern by 45 deg is turning the orientations back by one eighth of
        a turn: when ``n_theta`` is a multiple of 8 the times of rotation r are those of
        rotation 0 with the belief rolled by ``r * n_theta / 8`` (one DP serves all eight
        rotations of a uniform belief)."""
        belief = np.asarray(belief, dtype=float)
        pts = viewpoint_circles(np.zeros(2), radii)[pattern_indices(pattern, rotation)]
        if model.n_theta % DIRECTIONS == 0:
            base_rot, base_belief = 0, np.roll(belief, -rotation * model.n_theta // DIRECTIONS)
        else:
            base_rot, base_belief = rotation, belief
        key = (model.params.model_dump_json(), model.n_theta, radii, pattern, base_rot,
               np.round(base_belief, 9).tobytes(), speed, t_verify)
        hit = self.tables.get(key)
        if hit is not None:
            self.hits += 1
            return VerificationTable(pts, hit.times, hit.feasible)
        self.builds += 1
        base = viewpoint_circles(np.zeros(2), radii)[pattern_indices(pattern, base_rot)]
        rec = model.recognisable(base, np.zeros(2))
        q, ok = single_dp(base, rec, base_belief, base, speed, t_verify)
        d = cdist(base, base) / speed
        times = min_plus(q, d) if ok else d.T
        self.tables[key] = VerificationTable(base, times, ok)
        return VerificationTable(pts, times, ok)
