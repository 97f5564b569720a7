"""Local viewpoint planning: the expected time to verify a group (Masuzawa & Miura, §5).

:class:`Verifier` answers the section's times on a grid, one module per step:

- the viewpoints S_obs (§5.1, Fig. 7), the patterns of Fig. 8 and the joint viewpoints
  S_par (§5.2, Fig. 9(b)): :mod:`chizu.numeric.viewpoint.viewpoints`;
- t_single (§5.1, eq. 5) exactly by dynamic programming, and eq. 6's pattern tables:
  :mod:`chizu.numeric.viewpoint.single`;
- t_seq (§5.2, eq. 7) for every subset of a group, and the expectation over a joint
  observation's failures that eq. 8 needs: :mod:`chizu.numeric.viewpoint.sequential`;
- t_par (§5.2, eq. 8): observe every object of the group at once from a point of S_par,
  then verify the failures singly (one failure) or sequentially (several) -- written for
  k >= 2 objects over the 2**k outcomes (the paper writes it for two); the better of t_seq
  and t_par is the group's local plan (:meth:`Verifier.group`);
- unknown regions (§5.3, eqs. 9-10): :func:`unknown_region_time`.

t_seq and t_par are exact up to EXACT_GROUP objects, an upper bound beyond
(:class:`chizu.numeric.viewpoint.sequential.PortChain`).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.distance import cdist

from chizu.numeric.errors import InvalidInput
from chizu.numeric.viewpoint.appearance import AppearanceModel
from chizu.numeric.viewpoint.grid import PlanningGrid
from chizu.numeric.viewpoint.sequential import HandoverDP, HandoverTable, PortChain, Unverifiable
from chizu.numeric.viewpoint.single import TableCache, min_plus, single_dp
from chizu.numeric.viewpoint.viewpoints import (
    Candidate,
    ViewpointSet,
    entry_points,
    fitting_pattern,
    joint_points,
    pattern_indices,
    usable_viewpoints,
    viewpoint_circles,
)

__all__ = ["EXACT_GROUP", "Candidate", "LocalPlan", "TableCache", "Verifier", "ViewpointSet",
           "unknown_region_time"]

#: t_seq / t_par exact (every order and hand-over viewpoint) up to this group size
EXACT_GROUP = 6


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
        """S_obs of §5.1 less the unusable viewpoints; with tables, the first Fig. 8
        pattern that fits them and its eq.-6 table."""
        pts = viewpoint_circles(cand.xy, radii)
        usable = usable_viewpoints(pts, cand.xy, self.grid, self.clearance)
        entries = entry_points(pts, usable)
        fit = fitting_pattern(usable) if self.use_table else None
        if fit is not None:
            name, rot = fit
            idx = pattern_indices(name, rot)
            tab = self.tables.get(cand.model, radii, name, rot, cand.prior(), self.speed,
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
        """S_par (:func:`chizu.numeric.viewpoint.viewpoints.joint_points`): free cells from
        which every candidate of the group has P_recog > 0, within each one's r_max
        circle."""
        reach = np.array([self.radii(c)[2] for c in cands])
        return joint_points(cands, reach, self.grid, self.clearance)

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
