"""Local viewpoint planning: the expected time to verify a group of candidates (paper §5).

Viewpoints (§5.1, Fig. 7): 24 candidates on 3 circles around the object -- r_min
(recognisable from any side), r_max (one face only) and their mean -- 8 directions each,
45 degrees apart. Viewpoints on occupied or unknown cells, too close to an obstacle, or
without a clear line to the object are removed.

t_single (eq. 5) is the expected time of the best policy that observes from viewpoint X,
goes to the goal X_g on success, and otherwise recurses on the remaining viewpoints. With
the recognition indicator of eq. 4 a failed observation from X tells the robot that the
object's orientation is not one of those X would have recognised, so the recursion's
state is (position, remaining orientation set). chizu evaluates eq. 5 *exactly* by
dynamic programming over the reachable orientation sets -- 2**N_theta at most, a few
dozen in practice -- instead of over the 24! viewpoint orders; P_recog(X) in the
recursion is eq. 3 conditioned on the remaining set.

The pattern table (eq. 6, Fig. 8): the surroundings of an object are approximated by one
of five viewpoint patterns (directions free around it) rotated in 45-degree steps, tried
from the most open one; for a pattern the table holds t_single between every pair of its
viewpoints, which depends only on the object type, the pattern, the rotation and the
belief -- not on where the object is -- so one table serves every object of that type and
every re-plan. Fig. 8 is not in the text; the five patterns are chizu's reading of it:
open (8 directions), three-quarter (6), wall (5), corner (3), front (1).

t_seq (eq. 7) verifies the objects one after the other, handing over at a viewpoint of
the previous object, in the best order; t_par (eq. 8) observes all objects of the group
at once from a point where every one is recognisable, then verifies the failures
singly (one failure) or sequentially (several) -- eq. 8 written for k >= 2 objects over
the 2**k outcomes. The paper writes both for two objects. For k objects chizu solves
eq. 7 for every subset of the group at once by dynamic programming over subsets from the
goal backwards (:class:`HandoverDP`), which serves t_seq and all of t_par's failure
sets; that is exact and takes 2^k k^2 small min-plus products, so past EXACT_GROUP
objects a chain over every hand-over viewpoint (:class:`PortChain`) gives the time of a
policy the robot can follow -- an upper bound, flagged ``exact = False``. (Before, t_seq
tried all k! orders and t_par called it for every failure set: 9 objects took 10 s, 12
did not finish in 300 s.) Unknown regions: t_u = t_sea + t_obj_hat (eqs. 9-10).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from numpy.typing import NDArray
from scipy.spatial.distance import cdist

from numeric.errors import InvalidInput
from numeric.tours import best_order
from numeric.viewpoint.appearance import AppearanceModel
from numeric.viewpoint.grid import PlanningGrid

DIRECTIONS = 8
RINGS = 3
#: Fig. 8 as chizu reads it: the free directions (multiples of 45 degrees) of each pattern,
#: most open first.
PATTERNS: dict[str, tuple[int, ...]] = {
    "open": tuple(range(8)),
    "three_quarter": tuple(range(6)),
    "wall": tuple(range(5)),
    "corner": (0, 1, 2),
    "front": (0,),
}
#: t_seq / t_par exact (every order and hand-over viewpoint) up to this group size
EXACT_GROUP = 6
#: a larger group's chain is the best order by dynamic programming up to this size
SCALAR_DP_MAX = 12
MAX_PAR_POINTS = 400


def viewpoint_circles(obj_xy: np.ndarray, radii: Sequence[float]) -> np.ndarray:
    """The 24 viewpoint candidates (§5.1): index ``ring * 8 + k`` at direction
    ``k * 45 deg`` on ring ``ring`` (0 = r_min, 1 = mid, 2 = r_max)."""
    ang = np.arange(DIRECTIONS) * (2 * np.pi / DIRECTIONS)
    r = np.repeat(np.asarray(radii, dtype=float), DIRECTIONS)
    a = np.tile(ang, len(radii))
    return np.asarray(np.asarray(obj_xy, float) + r[:, None] * np.stack([np.cos(a), np.sin(a)], 1))


def pattern_indices(pattern: str, rotation: int) -> np.ndarray:
    """Viewpoint indices (all three rings) of ``pattern`` rotated by ``rotation * 45 deg``."""
    dirs = (np.array(PATTERNS[pattern]) + rotation) % DIRECTIONS
    return np.asarray((np.arange(RINGS)[:, None] * DIRECTIONS + dirs[None, :]).ravel())


#: every (pattern, rotation) in the order they are tried -- most open first, the open
#: pattern once (it is rotation invariant) -- and which of the 24 viewpoints each needs
_PATTERN_KEYS = [(name, rot) for name in PATTERNS
                 for rot in (range(1) if name == "open" else range(DIRECTIONS))]
_PATTERN_MASKS = np.zeros((len(_PATTERN_KEYS), RINGS * DIRECTIONS), dtype=bool)
for _k, (_name, _rot) in enumerate(_PATTERN_KEYS):
    _PATTERN_MASKS[_k, pattern_indices(_name, _rot)] = True


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


@dataclass(frozen=True)
class Candidate:
    """A candidate object to verify: id, type, position, its appearance model and the
    current orientation belief (uniform when nothing was observed yet)."""

    id: str
    type: str
    xy: np.ndarray
    model: AppearanceModel
    belief: np.ndarray | None = None

    def prior(self) -> np.ndarray:
        return self.model.uniform_prior() if self.belief is None else self.belief


@dataclass
class ViewpointSet:
    """The viewpoints the planner may use for one candidate."""

    points: np.ndarray          # (V, 2) absolute positions
    recog: NDArray[np.bool_]    # (V, N_theta)
    pattern: str | None         # the Fig. 8 pattern (table mode)
    rotation: int
    entries: np.ndarray         # outermost usable viewpoints: the group's entry points
    usable: np.ndarray          # (U, 2) every usable viewpoint (for executing a plan)
    table: VerificationTable | None = None


@dataclass(frozen=True)
class LocalPlan:
    """Expected verification time of a group and how: ``single``, ``seq`` (order) or
    ``par`` (the joint viewpoint)."""

    time_s: float
    strategy: str
    order: tuple[str, ...] = ()
    joint_point: tuple[float, float] | None = None
    t_seq_s: float | None = None
    t_par_s: float | None = None
    exact: bool = True  # False: a large group's bound (a policy's time, >= the optimum)


class Verifier:
    """Expected verification times on a grid (§5); ``use_table`` selects eq. 6's pattern
    tables (default, as the paper) or the exact eq. 5 on the actual usable viewpoints."""

    def __init__(self, grid: PlanningGrid | None, speed: float, t_verify: float,
                 clearance_m: float = 0.25, use_table: bool = True,
                 tables: TableCache | None = None,
                 kept: dict[bytes, ViewpointSet] | None = None) -> None:
        if not (speed > 0 and np.isfinite(speed)):
            raise InvalidInput("speed must be > 0", field="speed")
        self.grid = grid
        self.speed = speed
        self.t_verify = t_verify
        self.clearance = clearance_m
        self.use_table = use_table
        self.tables = tables if tables is not None else TableCache()
        self._sets: dict[str, ViewpointSet] = {}
        #: viewpoint sets kept across plans (by content, see :meth:`viewpoints`)
        self.kept = kept if kept is not None else {}

    # -- viewpoints -------------------------------------------------------------------
    def radii(self, cand: Candidate) -> tuple[float, float, float]:
        return cand.model.radii(min_standoff_m=self.clearance + 0.25)

    def viewpoints(self, cand: Candidate) -> ViewpointSet:
        """The usable viewpoints of ``cand`` (cached per candidate id, and across plans in
        ``kept`` by what they depend on: the candidate's position, model and belief, the
        verifier's parameters and the grid within reach of its viewpoints -- a re-plan
        after the map changed elsewhere reuses them)."""
        vs = self._sets.get(cand.id)
        if vs is not None:
            return vs
        radii = self.radii(cand)
        key = self._key(cand, radii)
        vs = self.kept.get(key)
        if vs is None:
            vs = self._viewpoints(cand, radii)
            if len(self.kept) >= 4096:
                self.kept.pop(next(iter(self.kept)))
            self.kept[key] = vs
        self._sets[cand.id] = vs
        return vs

    def _key(self, cand: Candidate, radii: tuple[float, float, float]) -> bytes:
        h = hashlib.blake2b(digest_size=20)
        h.update(np.asarray(cand.xy, float).tobytes())
        h.update(cand.model.params.model_dump_json().encode())
        h.update(np.asarray(cand.prior(), float).tobytes())
        h.update(np.array([*radii, self.speed, self.t_verify, self.clearance,
                           float(self.use_table), float(self.grid is None)]).tobytes())
        if self.grid is not None:
            g = self.grid
            pad = radii[2] + self.clearance + 2 * g.resolution
            lo = np.floor((cand.xy - pad - g.grid.origin) / g.resolution).astype(int)
            hi = np.floor((cand.xy + pad - g.grid.origin) / g.resolution).astype(int)
            h.update(g.digest(lo, hi))
        return h.digest()

    def _viewpoints(self, cand: Candidate, radii: tuple[float, float, float]) -> ViewpointSet:
        pts = viewpoint_circles(cand.xy, radii)
        if self.grid is None:
            usable = np.ones(len(pts), dtype=bool)
        else:
            usable = self.grid.free(pts, self.clearance) & self.grid.clear_lines(
                pts, np.broadcast_to(cand.xy, pts.shape), stop_short_m=0.35)
        outer = usable & (np.arange(len(pts)) >= (RINGS - 1) * DIRECTIONS)
        entries = pts[outer] if outer.any() else pts[usable]
        prior = cand.prior()
        if self.use_table:
            fits = np.nonzero((usable[None, :] | ~_PATTERN_MASKS).all(axis=1))[0]
            if len(fits):
                name, rot = _PATTERN_KEYS[int(fits[0])]
                idx = pattern_indices(name, rot)
                tab = self.tables.get(cand.model, radii, name, rot, prior, self.speed,
                                      self.t_verify)
                return ViewpointSet(pts[idx], cand.model.recognisable(pts[idx], cand.xy),
                                    name, rot, entries, pts[usable], tab)
        idx = np.nonzero(usable)[0]
        return ViewpointSet(pts[idx], cand.model.recognisable(pts[idx], cand.xy), None, 0,
                            entries, pts[usable])

    # -- t_single (eqs. 5, 6) ---------------------------------------------------------
    def single(self, cand: Candidate, starts: np.ndarray, goals: np.ndarray) -> np.ndarray:
        """t_single from every start ``(S, 2)`` to every goal ``(G, 2)``: ``(S, G)``;
        ``inf`` when no usable viewpoint can recognise the candidate."""
        vs = self.viewpoints(cand)
        starts = np.atleast_2d(starts)
        goals = np.atleast_2d(goals)
        if vs.table is not None:
            if not vs.table.feasible:
                return np.full((len(starts), len(goals)), np.inf)
            # eq. 6: min_{a,b} d(X_s, a) + T[b, a] + d(b, X_g)
            d_sa = cdist(starts, vs.points) / self.speed                  # (S, A)
            e = min_plus(d_sa, vs.table.times.T)                          # (S, B)
            return min_plus(e, cdist(vs.points, goals) / self.speed)      # (S, G)
        q, ok = single_dp(vs.points, vs.recog, cand.prior(), goals, self.speed, self.t_verify)
        if not ok:
            return np.full((len(starts), len(goals)), np.inf)
        d_sv = cdist(starts, vs.points) / self.speed                      # (S, V)
        return min_plus(d_sv, q.T)

    def next_viewpoint(self, cand: Candidate, start: np.ndarray, goal: np.ndarray,
                       ) -> np.ndarray | None:
        """The first viewpoint of the best eq.-5 policy from ``start`` with the candidate's
        current belief over every usable viewpoint (executing a plan re-plans after each
        observation); ``None`` when no viewpoint can recognise it any more."""
        vs = self.viewpoints(cand)
        pts = vs.usable
        q, ok = single_dp(pts, cand.model.recognisable(pts, cand.xy), cand.prior(),
                          np.atleast_2d(goal), self.speed, self.t_verify)
        if not ok:
            return None
        cost = cdist(np.atleast_2d(start), pts)[0] / self.speed + q[0]
        if not np.isfinite(cost).any():
            return None
        return np.asarray(pts[int(np.argmin(cost))])

    # -- t_seq (eq. 7) ----------------------------------------------------------------
    def handover_table(self, cands: Sequence[Candidate], goals: np.ndarray) -> HandoverTable:
        """Eq. 7 for every subset of the group at once, by dynamic programming over subsets
        from the goal backwards (exact for up to EXACT_GROUP objects, else the fixed-port
        bound of :class:`PortChain`)."""
        goals = np.atleast_2d(goals)
        if any(len(self.viewpoints(c).points) == 0 for c in cands):
            return Unverifiable(goals)
        if len(cands) > EXACT_GROUP:
            return PortChain(self, cands, goals)
        return HandoverDP(self, cands, goals)

    def sequential(self, cands: Sequence[Candidate], starts: np.ndarray, goals: np.ndarray,
                   ) -> tuple[np.ndarray, Callable[[int, int], tuple[str, ...]], bool]:
        """t_seq from every start ``(S, 2)`` to every goal ``(G, 2)``: ``(S, G)``; a function
        giving the best order for a (start, goal) pair; and whether the value is exact.

        Eq. 7 verifies the objects one after the other, handing over at a viewpoint of the
        previous object. Over all orders and hand-over viewpoints this is a shortest path
        over (objects done, last object, its viewpoint), solved by dynamic programming over
        subsets -- 2^k k^2 small min-plus products instead of k! orders -- exactly up to
        EXACT_GROUP objects. Larger groups fix each object's hand-over viewpoint (the one
        nearest the group's centre) and order them by the same DP on scalars: the expected
        time of a policy the robot can follow, so an upper bound of eq. 7's minimum."""
        starts = np.atleast_2d(starts)
        goals = np.atleast_2d(goals)
        if len(cands) == 1:
            order = (cands[0].id,)
            return self.single(cands[0], starts, goals), lambda s, g: order, True
        tab = self.handover_table(cands, goals)
        full = (1 << len(cands)) - 1
        return tab.rest(full, starts), lambda s, g: tab.order(full, starts[s], g), tab.exact

    # -- t_par (eq. 8, k >= 2) --------------------------------------------------------
    def joint_points(self, cands: Sequence[Candidate]) -> np.ndarray:
        """S_par: free cells from which every candidate of the group has P_recog > 0 (the
        overlap of their observable regions, Fig. 9(b)), at most MAX_PAR_POINTS."""
        xy = np.array([c.xy for c in cands])
        reach = np.array([self.radii(c)[2] for c in cands])
        r = reach.max()
        lo, hi = xy.min(0) - r, xy.max(0) + r
        # the discs overlap inside the overlap of their boxes: only the lattice points
        # (from lo, as over the whole box) there are tried
        inner_lo = (xy - reach[:, None]).max(0)
        inner_hi = (xy + reach[:, None]).min(0)
        step = self.grid.resolution if self.grid is not None else 0.1
        while True:
            first = np.ceil(np.round((inner_lo - lo) / step, 9))
            n = np.floor((np.minimum(hi, inner_hi) - lo) / step - 1e-9) - first + 1
            ax = [lo[d] + step * (first[d] + np.arange(max(int(n[d]), 0)))
                  for d in range(2)]
            gx, gy = np.meshgrid(ax[0], ax[1])
            pts = np.stack([gx.ravel(), gy.ravel()], 1)
            ok = np.ones(len(pts), dtype=bool)
            for c, rc in zip(cands, reach, strict=True):
                ok &= np.hypot(*(pts - c.xy).T) <= rc
            pts = pts[ok]
            if len(pts) <= MAX_PAR_POINTS * 4:
                break
            step *= 1.5
        # the cheap tests first: free cells, then recognition, then lines of sight
        if self.grid is not None and len(pts):
            pts = pts[self.grid.free(pts, self.clearance)]
        for c in cands:
            if len(pts):
                pts = pts[c.model.p_recog(pts, c.xy, c.prior()) > 0]
        if self.grid is not None:
            for c in cands:
                if len(pts):
                    pts = pts[self.grid.clear_lines(pts, np.broadcast_to(c.xy, pts.shape),
                                                    0.35)]
        if len(pts) > MAX_PAR_POINTS:
            pts = pts[np.linspace(0, len(pts) - 1, MAX_PAR_POINTS).astype(int)]
        return np.asarray(pts)

    def parallel(self, cands: Sequence[Candidate], starts: np.ndarray, goals: np.ndarray,
                 ) -> tuple[np.ndarray, np.ndarray]:
        """t_par from paired starts/goals ``(N, 2)``: ``(N,)`` and the joint point used
        (eq. 8 over the 2**k outcomes of the joint observation)."""
        starts = np.atleast_2d(starts)
        goals = np.atleast_2d(goals)
        n = len(starts)
        jp = self.joint_points(cands)
        if len(jp) == 0:
            return np.full(n, np.inf), np.full((n, 2), np.nan)
        k = len(cands)
        p = np.stack([c.model.p_recog(jp, c.xy, c.prior()) for c in cands], 1)  # (J, k)
        # cost after the joint observation, summed over the outcomes F (sets of
        # failures) weighted by their probability: (J, G); only the paired goals matter
        tab = self.handover_table(cands, goals)
        after = tab.expected_rest(jp, p)
        total = cdist(starts, jp) / self.speed + k * self.t_verify \
            + after.T[np.arange(n)]                                                # (N, J)
        j = np.argmin(total, axis=1)
        return total[np.arange(n), j], jp[j]

    def group(self, cands: Sequence[Candidate], starts: np.ndarray, goals: np.ndarray,
              ) -> list[LocalPlan]:
        """The better of t_seq and t_par (§5.2) for paired starts/goals; t_single for one."""
        seq, par, jp, order_of, exact = self._seq_par(cands, starts, goals)
        return [self._local(i, seq, par, jp, order_of, exact, cands) for i in range(len(seq))]

    def best(self, cands: Sequence[Candidate], starts: np.ndarray, goals: np.ndarray,
             ) -> LocalPlan:
        """The quickest of :meth:`group`'s plans; only its order is traced back (a group's
        order costs a pass over its viewpoints per start)."""
        seq, par, jp, order_of, exact = self._seq_par(cands, starts, goals)
        i = int(np.argmin(np.minimum(seq, par)))
        return self._local(i, seq, par, jp, order_of, exact, cands)

    def _seq_par(self, cands: Sequence[Candidate], starts: np.ndarray, goals: np.ndarray,
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                            Callable[[int, int], tuple[str, ...]], bool]:
        starts = np.atleast_2d(starts)
        goals = np.atleast_2d(goals)
        n = len(starts)
        seq_m, order_of, exact = self.sequential(cands, starts, goals)
        seq = seq_m[np.arange(n), np.arange(n)]
        if len(cands) == 1:
            return seq, np.full(n, np.inf), np.full((n, 2), np.nan), order_of, exact
        par, jp = self.parallel(cands, starts, goals)
        return seq, par, jp, order_of, exact

    @staticmethod
    def _local(i: int, seq: np.ndarray, par: np.ndarray, jp: np.ndarray,
               order_of: Callable[[int, int], tuple[str, ...]], exact: bool,
               cands: Sequence[Candidate]) -> LocalPlan:
        if len(cands) == 1:
            return LocalPlan(float(seq[i]), "single", order_of(i, i))
        if par[i] < seq[i]:
            return LocalPlan(float(par[i]), "par", tuple(c.id for c in cands),
                             (float(jp[i, 0]), float(jp[i, 1])), float(seq[i]),
                             float(par[i]), exact)
        return LocalPlan(float(seq[i]), "seq", order_of(i, i), None, float(seq[i]),
                         float(par[i]) if np.isfinite(par[i]) else None, exact)


def unknown_region_time(verifier: Verifier, models: dict[str, AppearanceModel],
                        mean_counts: dict[str, float], centroid: np.ndarray, entry: np.ndarray,
                        area_m2: float, total_unknown_m2: float, t_search: float,
                        t_dist: float) -> float:
    """t_u = t_sea + t_obj_hat (eqs. 9-10): the expected time to verify the objects the
    region may hold -- mean count n_bar_j of each type, placed at the region's centroid,
    verified from and back to the entry point -- scaled by the region's share of the
    unknown area, plus t_dist per extra object ((sum n_bar - 1) clamped at 0)."""
    if total_unknown_m2 <= 0:
        return t_search
    free_space = Verifier(None, verifier.speed, verifier.t_verify, verifier.clearance,
                          verifier.use_table, verifier.tables)
    total = 0.0
    for name, n_bar in mean_counts.items():
        if n_bar <= 0 or name not in models:
            continue
        c = Candidate(f"unknown_{name}", name, np.asarray(centroid, float), models[name])
        t = free_space.single(c, entry[None, :], entry[None, :])[0, 0]
        if np.isfinite(t):
            total += n_bar * t
    extra = max(sum(mean_counts.values()) - 1.0, 0.0) * t_dist
    return float(t_search + area_m2 / total_unknown_m2 * (total + extra))


class HandoverTable:
    """Eq. 7 for every subset F of a group (bit i = ``cands[i]``) towards fixed goals:
    ``rest(F, X)`` is the expected time to verify F one after the other from points X and
    reach each goal; ``expected_rest`` averages it over the failures of a joint
    observation (eq. 8)."""

    exact: bool

    def __init__(self, verifier: Verifier, cands: Sequence[Candidate], goals: np.ndarray,
                 ) -> None:
        self.v, self.cands, self.goals = verifier, list(cands), goals
        self.pts = [verifier.viewpoints(c).points for c in cands]

    def rest(self, mask: int, xy: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def order(self, mask: int, xy: np.ndarray, goal: int) -> tuple[str, ...]:
        raise NotImplementedError

    def expected_rest(self, xy: np.ndarray, p: np.ndarray) -> np.ndarray:
        raise NotImplementedError


class Unverifiable(HandoverTable):
    """A group with an object no usable viewpoint can see: every time is infinite."""

    exact = True

    def __init__(self, goals: np.ndarray) -> None:  # no viewpoints to look up
        self.goals = goals

    def rest(self, mask: int, xy: np.ndarray) -> np.ndarray:
        return np.full((len(np.atleast_2d(xy)), len(self.goals)), np.inf)

    def order(self, mask: int, xy: np.ndarray, goal: int) -> tuple[str, ...]:
        return ()

    def expected_rest(self, xy: np.ndarray, p: np.ndarray) -> np.ndarray:
        return np.full((len(xy), len(self.goals)), np.inf)


class HandoverDP(HandoverTable):
    """Exact eq. 7 over every order and hand-over viewpoint, by dynamic programming over
    subsets from the goals backwards: ``H[F, p] (V_p, G)`` is the expected time from a
    viewpoint of object p (just verified, p not in F) to verify F and reach each goal;
    ``H[{c}, p]`` is t_single(v, X_g, c) and ``H[F, p] = min_c min_v t_single(., v, c) +
    H[F - c, c](v)``."""

    exact = True

    def __init__(self, verifier: Verifier, cands: Sequence[Candidate], goals: np.ndarray,
                 ) -> None:
        super().__init__(verifier, cands, goals)
        k = len(cands)
        self.h: dict[tuple[int, int], np.ndarray] = {}
        self.arg: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        # every object's viewpoints stacked: one min-plus product per (set, next object)
        # serves all the objects the robot may come from (rows of the others are unused)
        every = np.vstack(self.pts)
        cut = np.cumsum([0] + [len(p) for p in self.pts])
        rows = [slice(int(cut[i]), int(cut[i + 1])) for i in range(k)]
        pair = [verifier.single(cands[c], every, self.pts[c]) for c in range(k)]
        for mask in sorted(range(1, (1 << k) - 1), key=lambda m: m.bit_count()):
            members = [c for c in range(k) if mask >> c & 1]
            if len(members) == 1:
                best = verifier.single(cands[members[0]], every, goals)
            else:
                best = np.full((len(every), len(goals)), np.inf)
                who = np.full(best.shape, -1)
                port = np.zeros(best.shape, dtype=int)
                for c in members:
                    val, via = min_plus_arg(pair[c], self.h[mask & ~(1 << c), c])
                    better = val < best
                    best = np.where(better, val, best)
                    who = np.where(better, c, who)
                    port = np.where(better, via, port)
            for p in range(k):
                if not mask >> p & 1:
                    self.h[mask, p] = best[rows[p]]
                    if len(members) > 1:
                        self.arg[mask, p] = (who[rows[p]], port[rows[p]])

    def legs(self, xy: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """From points xy: t_single to each object's viewpoints and to the goals."""
        return ([self.v.single(c, xy, pts) for c, pts in zip(self.cands, self.pts, strict=True)],
                [self.v.single(c, xy, self.goals) for c in self.cands])

    def _first(self, mask: int, to_v: list[np.ndarray]
               ) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """Per member c: min over its viewpoints of reaching it and going on, and where."""
        return [(c, *min_plus_arg(to_v[c], self.h[mask & ~(1 << c), c]))
                for c in range(len(self.cands)) if mask >> c & 1]

    def rest(self, mask: int, xy: np.ndarray,
             legs: tuple[list[np.ndarray], list[np.ndarray]] | None = None) -> np.ndarray:
        xy = np.atleast_2d(xy)
        members = [c for c in range(len(self.cands)) if mask >> c & 1]
        if not members:
            return np.asarray(cdist(xy, self.goals) / self.v.speed)
        to_v, to_g = legs if legs is not None else self.legs(xy)
        if len(members) == 1:
            return to_g[members[0]]
        return np.asarray(np.min([val for _, val, _ in self._first(mask, to_v)], axis=0))

    def order(self, mask: int, xy: np.ndarray, goal: int) -> tuple[str, ...]:
        members = [c for c in range(len(self.cands)) if mask >> c & 1]
        if len(members) <= 1:
            return tuple(self.cands[c].id for c in members)
        first = self._first(mask, self.legs(np.atleast_2d(xy))[0])
        c, _, via = min(first, key=lambda f: f[1][0, goal])
        out, v = [c], int(via[0, goal])
        mask &= ~(1 << c)
        while mask.bit_count() > 1:
            who, port = self.arg[mask, c]
            c, v = int(who[v, goal]), int(port[v, goal])
            out.append(c)
            mask &= ~(1 << c)
        out.append(mask.bit_length() - 1)
        return tuple(self.cands[i].id for i in out)

    def expected_rest(self, xy: np.ndarray, p: np.ndarray) -> np.ndarray:
        """``sum_F P(F) rest(F, xy)`` over the 2^k failure sets, ``p (J, k)`` the chance
        that each object is recognised from each point (independent); outcomes whose
        probability is 0 at every point are skipped."""
        k = len(self.cands)
        out = np.zeros((len(xy), len(self.goals)))
        q = 1.0 - p
        legs = self.legs(xy)
        for mask in range(1 << k):
            bits = np.array([mask >> i & 1 for i in range(k)], dtype=bool)
            prob = np.prod(np.where(bits, q, p), axis=1)                  # (J,)
            if not (prob > 0).any():
                continue
            with np.errstate(invalid="ignore"):
                out += np.where(prob[:, None] > 0,
                                prob[:, None] * self.rest(mask, xy, legs), 0.0)
        return out


class PortChain(HandoverTable):
    """Eq. 7 for a large group: the objects are verified in one chain (or its reverse,
    whichever is quicker for a start and goal), over every hand-over viewpoint along it.
    The chain is chosen on scalars -- each object handing over at its viewpoint nearest
    the group's centre, from the centre back to it -- by dynamic programming over
    subsets up to SCALAR_DP_MAX objects, nearest neighbour and 2-opt beyond. Its time is
    that of a policy the robot can follow, so it bounds eq. 7's minimum from above;
    ``exact`` is False. t_par's failures are verified along the same chain with those
    fixed hand-overs, which gives its expectation in closed form in O(k^2) terms
    instead of 2^k outcomes."""

    exact = False

    def __init__(self, verifier: Verifier, cands: Sequence[Candidate], goals: np.ndarray,
                 ) -> None:
        super().__init__(verifier, cands, goals)
        k = len(cands)
        self._pairs: dict[tuple[int, int], np.ndarray] = {}
        self._lasts: dict[tuple[int, int], np.ndarray] = {}
        centre = np.mean([c.xy for c in cands], axis=0)
        self.hand = np.array([pts[int(np.argmin(np.hypot(*(pts - centre).T)))]
                              for pts in self.pts])                          # (k, 2)
        self.cs = np.array([[verifier.single(cands[c], self.hand[p], self.hand[c])[0, 0]
                             if p != c else np.inf for c in range(k)] for p in range(k)])
        self.last = np.array([[verifier.single(cands[c], self.hand[p], goals)[0]
                               for c in range(k)] for p in range(k)])       # (k, k, G)
        enter = np.array([verifier.single(cands[c], centre[None], self.hand[c][None])[0, 0]
                          for c in range(k)])
        home = np.array([[verifier.single(cands[c], self.hand[p], centre[None])[0, 0]
                          for c in range(k)] for p in range(k)])
        order = best_order(enter, self.cs, home, SCALAR_DP_MAX)
        self.chain_idx = order
        self.chain = tuple(cands[i].id for i in order)

    def _pair(self, p: int, c: int) -> np.ndarray:
        """t_single from every viewpoint of object p to every viewpoint of c (cached)."""
        key = (p, c)
        if key not in self._pairs:
            self._pairs[key] = self.v.single(self.cands[c], self.pts[p], self.pts[c])
        return self._pairs[key]

    def _along(self, order: list[int], xy: np.ndarray) -> np.ndarray:
        """Eq. 7 along one order, over every hand-over viewpoint (min-plus chain)."""
        vec = self.v.single(self.cands[order[0]], xy, self.pts[order[0]])
        for a, b in zip(order[:-2], order[1:-1], strict=True):
            vec = min_plus(vec, self._pair(a, b))
        key = (order[-2], order[-1])
        if key not in self._lasts:
            self._lasts[key] = self.v.single(self.cands[order[-1]], self.pts[order[-2]],
                                             self.goals)
        return min_plus(vec, self._lasts[key])

    def rest(self, mask: int, xy: np.ndarray) -> np.ndarray:
        xy = np.atleast_2d(xy)
        order = [i for i in self.chain_idx if mask >> i & 1]
        if not order:
            return np.asarray(cdist(xy, self.goals) / self.v.speed)
        if len(order) == 1:
            return self.v.single(self.cands[order[0]], xy, self.goals)
        return np.minimum(self._along(order, xy), self._along(order[::-1], xy))

    def order(self, mask: int, xy: np.ndarray, goal: int) -> tuple[str, ...]:
        xy = np.atleast_2d(xy)
        order = [i for i in self.chain_idx if mask >> i & 1]
        if len(order) > 1 and (self._along(order[::-1], xy)[0, goal]
                               < self._along(order, xy)[0, goal]):
            order = order[::-1]
        return tuple(self.cands[i].id for i in order)

    def expected_rest(self, xy: np.ndarray, p: np.ndarray) -> np.ndarray:
        """``sum_F P(F) cost(F)`` with F's members verified in the fixed order: the first
        failure is reached from xy, consecutive failures hand over, the last goes to the
        goal; each term's probability is a product over the objects between (closed
        form, O(k^2) terms)."""
        order = list(self.chain_idx)
        p = p[:, order]
        q = 1.0 - p
        k = len(order)
        ones = np.ones((len(xy), 1))
        before = np.hstack([ones, np.cumprod(p, axis=1)])[:, :-1]           # prod_{l<i} p_l
        after = np.hstack([np.cumprod(p[:, ::-1], axis=1)[:, ::-1][:, 1:], ones])  # l>i
        none_fail = before[:, -1] * p[:, -1]
        out = none_fail[:, None] * np.asarray(cdist(xy, self.goals) / self.v.speed)
        for a, ca in enumerate(order):
            alone = q[:, a] * before[:, a] * after[:, a]                     # F = {a}
            lead = q[:, a] * before[:, a] * (1.0 - after[:, a])              # first of >= 2
            with np.errstate(invalid="ignore"):
                out += np.where(alone[:, None] > 0, alone[:, None] * self.v.single(
                    self.cands[ca], xy, self.goals), 0.0)
                out += np.where(lead[:, None] > 0, lead[:, None] * self.v.single(
                    self.cands[ca], xy, self.hand[ca][None]), 0.0)
            between = np.ones(len(xy))
            for b in range(a + 1, k):
                cb = order[b]
                pair = q[:, a] * q[:, b] * between
                go_on, stop = pair * (1.0 - after[:, b]), pair * after[:, b]
                with np.errstate(invalid="ignore"):
                    out += np.where(go_on[:, None] > 0, go_on[:, None] * self.cs[ca, cb], 0.0)
                    out += np.where(stop[:, None] > 0, stop[:, None]
                                    * self.last[ca, cb][None, :], 0.0)
                between = between * p[:, b]
        return out
