"""t_seq for every subset of a group (Masuzawa & Miura, §5.2, eqs. 7-8).

Eq. 7 verifies the objects one after the other, handing over at a viewpoint of the
previous object, in the best order; eq. 8's joint observation leaves a set of failures
to verify the same way. The paper writes both for two objects. For k objects
:class:`HandoverDP` solves eq. 7 for every subset of the group at once by dynamic
programming over subsets from the goal backwards, which serves t_seq and all of t_par's
failure sets; that is exact and takes 2^k k^2 small min-plus products. Past
:data:`chizu.numeric.viewpoint.verification.EXACT_GROUP` objects :class:`PortChain` verifies
them along one chain over every hand-over viewpoint: the time of a policy the robot can
follow, an upper bound flagged ``exact = False``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial.distance import cdist

from chizu.numeric.tours import best_order
from chizu.numeric.viewpoint.single import min_plus, min_plus_arg
from chizu.numeric.viewpoint.viewpoints import Candidate

if TYPE_CHECKING:
    from chizu.numeric.viewpoint.verification import Verifier

#: a larger group's chain is the best order by dynamic programming up to this size
SCALAR_DP_MAX = 12


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
