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
the 2**k outcomes. Unknown regions: t_u = t_sea + t_obj_hat (eqs. 9-10).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.distance import cdist

from numeric.errors import InvalidInput
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
MAX_SEQ_OBJECTS = 7  # t_seq tries every order up to this group size
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


def min_plus(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The min-plus matrix product ``out[i, j] = min_k a[i, k] + b[k, j]``: chaining
    expected times through intermediate viewpoints."""
    return np.asarray(np.min(a[:, :, None] + b[None, :, :], axis=1))


def single_dp(points: np.ndarray, recog: NDArray[np.bool_], belief: np.ndarray,
              goals: np.ndarray, speed: float, t_verify: float) -> tuple[np.ndarray, bool]:
    """Eq. 5 by dynamic programming over (viewpoint, remaining orientation set).

    ``points (V, 2)`` the usable viewpoints, ``recog (V, N)`` eq. 4's indicator per
    orientation, ``belief (N,)`` P(theta_i), ``goals (G, 2)``. Returns ``Q (G, V)``, the
    expected time from arriving at viewpoint v (about to observe) to the goal, and
    whether any viewpoint can recognise the object at all. Then
    ``t_single(X_s, g) = min_v |X_s - v| / speed + Q[g, v]``.
    """
    n_v = len(points)
    n_g = len(goals)
    b = np.asarray(belief, dtype=float)
    start = sum(1 << i for i in range(len(b)) if b[i] > 1e-12)
    rbits = [sum(1 << int(i) for i in np.nonzero(row)[0]) for row in recog]
    rf = recog.astype(float)
    if n_v == 0 or not any(start & r for r in rbits):
        return np.full((n_g, n_v), np.inf), False
    # reachable orientation sets: start minus the sets of the viewpoints that failed
    seen = {start}
    todo = [start]
    while todo:
        m = todo.pop()
        for r in rbits:
            if m & r:
                nxt = m & ~r
                if nxt not in seen:
                    seen.add(nxt)
                    todo.append(nxt)
    order = sorted(seen, key=lambda m: bin(m).count("1"))
    d_vv = cdist(points, points) / speed          # (V, V)
    d_vg = cdist(points, goals).T / speed         # (G, V)
    n_bits = len(b)
    t_at: dict[int, np.ndarray] = {}              # mask -> (G, V): time from viewpoint a
    for m in order:
        bits = np.array([(m >> i) & 1 for i in range(n_bits)], dtype=float)
        mass = float(bits @ b)
        p = rf @ (bits * b) / mass if mass > 0 else np.zeros(n_v)
        useful = p > 0
        q = np.full((n_g, n_v), np.inf)
        if not useful.any():
            t_at[m] = d_vg.copy()  # nothing left to try: go to the goal
            continue
        for v in np.nonzero(useful)[0]:
            rest = t_at[m & ~rbits[v]][:, v] if p[v] < 1 else 0.0
            q[:, v] = t_verify + p[v] * d_vg[:, v] + (1 - p[v]) * rest
        # T(a, m) = min_v d(a, v) + Q(v, m)
        t_at[m] = min_plus(q, d_vv)
    return q, True  # the last set in the order is the start set


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
        key = (model.params.model_dump_json(), model.n_theta, radii, pattern, rotation,
               np.round(belief, 9).tobytes(), speed, t_verify)
        tab = self.tables.get(key)
        if tab is not None:
            self.hits += 1
            return tab
        self.builds += 1
        pts = viewpoint_circles(np.zeros(2), radii)[pattern_indices(pattern, rotation)]
        rec = model.recognisable(pts, np.zeros(2))
        q, ok = single_dp(pts, rec, belief, pts, speed, t_verify)
        d = cdist(pts, pts) / speed
        times = min_plus(q, d) if ok else d.T
        tab = VerificationTable(pts, times, ok)
        self.tables[key] = tab
        return tab


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


class Verifier:
    """Expected verification times on a grid (§5); ``use_table`` selects eq. 6's pattern
    tables (default, as the paper) or the exact eq. 5 on the actual usable viewpoints."""

    def __init__(self, grid: PlanningGrid | None, speed: float, t_verify: float,
                 clearance_m: float = 0.25, use_table: bool = True,
                 tables: TableCache | None = None) -> None:
        if not (speed > 0 and np.isfinite(speed)):
            raise InvalidInput("speed must be > 0", field="speed")
        self.grid = grid
        self.speed = speed
        self.t_verify = t_verify
        self.clearance = clearance_m
        self.use_table = use_table
        self.tables = tables if tables is not None else TableCache()
        self._sets: dict[str, ViewpointSet] = {}

    # -- viewpoints -------------------------------------------------------------------
    def radii(self, cand: Candidate) -> tuple[float, float, float]:
        return cand.model.radii(min_standoff_m=self.clearance + 0.25)

    def viewpoints(self, cand: Candidate) -> ViewpointSet:
        """The usable viewpoints of ``cand`` (cached per candidate id)."""
        vs = self._sets.get(cand.id)
        if vs is not None:
            return vs
        radii = self.radii(cand)
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
            for name in PATTERNS:
                for rot in range(DIRECTIONS):
                    idx = pattern_indices(name, rot)
                    if usable[idx].all():
                        tab = self.tables.get(cand.model, radii, name, rot, prior,
                                              self.speed, self.t_verify)
                        vs = ViewpointSet(pts[idx], cand.model.recognisable(pts[idx], cand.xy),
                                          name, rot, entries, pts[usable], tab)
                        self._sets[cand.id] = vs
                        return vs
                    if name == "open":
                        break  # the open pattern is rotation invariant
        idx = np.nonzero(usable)[0]
        vs = ViewpointSet(pts[idx], cand.model.recognisable(pts[idx], cand.xy), None, 0, entries,
                          pts[usable])
        self._sets[cand.id] = vs
        return vs

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
    def sequential(self, cands: Sequence[Candidate], starts: np.ndarray, goals: np.ndarray,
                   ) -> tuple[np.ndarray, np.ndarray, list[tuple[str, ...]]]:
        """t_seq from every start ``(S, 2)`` to every goal ``(G, 2)``: ``(S, G)``, the
        index of the best order per pair and the orders tried. The objects are verified
        one after the other, handing over at the previous object's viewpoint (eq. 7), in
        every order (up to MAX_SEQ_OBJECTS objects; beyond, nearest-neighbour order)."""
        starts = np.atleast_2d(starts)
        goals = np.atleast_2d(goals)
        if len(cands) == 1:
            return (self.single(cands[0], starts, goals),
                    np.zeros((len(starts), len(goals)), dtype=int), [(cands[0].id,)])
        pts = {c.id: self.viewpoints(c).points for c in cands}
        first = {c.id: self.single(c, starts, pts[c.id]) for c in cands}      # (S, Vc)
        pair: dict[tuple[str, str], np.ndarray] = {}
        last: dict[tuple[str, str], np.ndarray] = {}
        orders: list[tuple[Candidate, ...]]
        if len(cands) <= MAX_SEQ_OBJECTS:
            orders = list(itertools.permutations(cands))
        else:
            orders = [tuple(self._nearest_order(cands, starts[0]))]
        best = np.full((len(starts), len(goals)), np.inf)
        which = np.zeros(best.shape, dtype=int)
        for k, order in enumerate(orders):
            vec = first[order[0].id]                                          # (S, V0)
            for prev, cur in zip(order[:-2], order[1:-1], strict=True):
                key = (prev.id, cur.id)
                if key not in pair:
                    pair[key] = self.single(cur, pts[prev.id], pts[cur.id])   # (Vp, Vc)
                vec = min_plus(vec, pair[key])
            key = (order[-2].id, order[-1].id)
            if key not in last:  # the last object: from the hand-over point to the goal
                last[key] = self.single(order[-1], pts[order[-2].id], goals)  # (Vp, G)
            tot = min_plus(vec, last[key])                                    # (S, G)
            better = tot < best
            best = np.where(better, tot, best)
            which = np.where(better, k, which)
        return best, which, [tuple(c.id for c in o) for o in orders]

    def _nearest_order(self, cands: Sequence[Candidate], start: np.ndarray) -> list[Candidate]:
        left = list(cands)
        out = []
        at = start
        while left:
            k = int(np.argmin([np.hypot(*(c.xy - at)) for c in left]))
            at = left[k].xy
            out.append(left.pop(k))
        return out

    # -- t_par (eq. 8, k >= 2) --------------------------------------------------------
    def joint_points(self, cands: Sequence[Candidate]) -> np.ndarray:
        """S_par: free cells from which every candidate of the group has P_recog > 0 (the
        overlap of their observable regions, Fig. 9(b)), at most MAX_PAR_POINTS."""
        xy = np.array([c.xy for c in cands])
        r = max(self.radii(c)[2] for c in cands)
        lo, hi = xy.min(0) - r, xy.max(0) + r
        step = self.grid.resolution if self.grid is not None else 0.1
        while True:
            gx, gy = np.meshgrid(np.arange(lo[0], hi[0], step), np.arange(lo[1], hi[1], step))
            pts = np.stack([gx.ravel(), gy.ravel()], 1)
            ok = np.ones(len(pts), dtype=bool)
            for c in cands:
                ok &= np.hypot(*(pts - c.xy).T) <= self.radii(c)[2]
            pts = pts[ok]
            if len(pts) <= MAX_PAR_POINTS * 4:
                break
            step *= 1.5
        if self.grid is not None and len(pts):
            keep = self.grid.free(pts, self.clearance)
            for c in cands:
                keep &= self.grid.clear_lines(pts, np.broadcast_to(c.xy, pts.shape), 0.35)
            pts = pts[keep]
        if len(pts):
            p = np.stack([c.model.p_recog(pts, c.xy, c.prior()) for c in cands], 1)
            pts = pts[(p > 0).all(axis=1)]
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
        # cost after the joint observation, per outcome F (set of failures): (J, N)
        after = np.zeros((len(jp), n))
        for mask in range(1 << k):
            failed = [cands[i] for i in range(k) if mask >> i & 1]
            prob = np.prod(np.where([(mask >> i) & 1 for i in range(k)], 1 - p, p), axis=1)
            if not failed:
                rest = cdist(jp, goals) / self.speed
            elif len(failed) == 1:
                rest = self.single(failed[0], jp, goals)
            else:
                rest = self.sequential(failed, jp, goals)[0]
            with np.errstate(invalid="ignore"):
                after += np.where(prob[:, None] > 0, prob[:, None] * rest, 0.0)
        total = cdist(starts, jp) / self.speed + k * self.t_verify + after.T    # (N, J)
        j = np.argmin(total, axis=1)
        return total[np.arange(n), j], jp[j]

    def group(self, cands: Sequence[Candidate], starts: np.ndarray, goals: np.ndarray,
              ) -> list[LocalPlan]:
        """The better of t_seq and t_par (§5.2) for paired starts/goals; t_single for one."""
        starts = np.atleast_2d(starts)
        goals = np.atleast_2d(goals)
        n = len(starts)
        seq_m, which, orders_tried = self.sequential(cands, starts, goals)
        seq = seq_m[np.arange(n), np.arange(n)]
        orders = [orders_tried[which[i, i]] for i in range(n)]
        if len(cands) == 1:
            return [LocalPlan(float(t), "single", o) for t, o in zip(seq, orders, strict=True)]
        par, jp = self.parallel(cands, starts, goals)
        out = []
        for i in range(len(starts)):
            if par[i] < seq[i]:
                out.append(LocalPlan(float(par[i]), "par", tuple(c.id for c in cands),
                                     (float(jp[i, 0]), float(jp[i, 1])), float(seq[i]),
                                     float(par[i])))
            else:
                out.append(LocalPlan(float(seq[i]), "seq", orders[i], None, float(seq[i]),
                                     float(par[i]) if np.isfinite(par[i]) else None))
        return out


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
