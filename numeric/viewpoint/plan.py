"""Global viewpoint planning: which groups to observe, in which order (Masuzawa & Miura,
§6, eqs. 11-14 and 18-20).

A plan is an ordered subset G_1..G_N of the observation groups. Its utility (eq. 11) is

    U = V - L(t_mov + sum_i t_obs(G_i)),

with V the sum of the group values (eqs. 15-17), t_mov the travel from the robot through
the groups' entry/exit points to the room's exit (eqs. 18-20) and L one of the losses of
eqs. 12-14. The paper's search (§6.4) enumerates every ordered subset (sum_i nPi
plans); that is kept as :func:`solve_exhaustive`, the reference. The default
:func:`solve` is exact too: V and sum t_obs depend only on the *set* of groups and every
loss is non-decreasing in time, so the best order of a set is its fastest tour, found
for all sets at once by Held-Karp dynamic programming over subsets (O(2^n n^2),
vectorised with numpy). Both return the same optimum utility; ties (e.g. a plan and its
reverse when the exit is the start) are broken by fewer groups, then the shorter time,
then the group indices.

Held-Karp grows as 2^n n^2, so past MAX_GROUPS_EXACT groups it is not offered and past
DP_AUTO_MAX :func:`solve_auto` turns to :func:`solve_bnb`: a branch and bound over layers
of partial tours, vectorised with numpy, with a knapsack bound on what the remaining
groups can still add; it proves the optimum or, when its time budget runs out, returns
the best plan found with the gap to its upper bound.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numba import njit
from pydantic import BaseModel, ConfigDict, Field

from chizu.numeric.errors import InvalidInput
from chizu.numeric.tours import best_order

MAX_GROUPS_EXACT = 20
#: the branch and bound bounds this many states at a time between looks at the clock
BOUND_CHUNK = 20_000
#: the branch and bound starts from the DP's best plans over this many groups
SEED_GROUPS = 14


class Loss(BaseModel):
    """The time loss (eqs. 12-14): L1 forbids passing ``t_limit``; L2 grows as
    ``k_lim (t - t_limit)^2`` past it; L3 ignores time."""

    model_config = ConfigDict(extra="forbid")
    kind: Literal["L1", "L2", "L3"] = "L2"
    t_limit_s: float = Field(60.0, ge=0, allow_inf_nan=False)
    k_lim: float = Field(0.5, ge=0, allow_inf_nan=False)

    def __call__(self, t: np.ndarray | float) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        over = t >= self.t_limit_s
        if self.kind == "L1":
            return np.asarray(np.where(over, np.inf, 0.0))
        if self.kind == "L2":
            return np.asarray(np.where(over, self.k_lim * (t - self.t_limit_s) ** 2, 0.0))
        return np.zeros_like(t)


@dataclass(frozen=True)
class GroupCost:
    """What the global planner needs of a group: value (eq. 16/17), observation time
    t_obs (§5) and entry/exit candidate points (§6.3)."""

    name: str
    kind: str
    value: float
    t_obs: float
    entries: np.ndarray


@dataclass(frozen=True)
class Problem:
    """Eqs. 11 and 18-20 in matrix form (times in s)."""

    value: np.ndarray     # (n,)
    t_obs: np.ndarray     # (n,)
    t_start: np.ndarray   # (n,) robot -> group (eq. 19)
    t_gg: np.ndarray      # (n, n) group -> group (eq. 20)
    t_exit: np.ndarray    # (n,) group -> exit (eq. 19)
    t_leave: float        # robot -> exit, the empty plan
    loss: Loss

    @property
    def n(self) -> int:
        return len(self.value)

    def way_in(self) -> np.ndarray:
        """``(n,)``: the cheapest travel into each group, from the robot or from any
        other group (a lower bound of the leg before it in any plan)."""
        others = self.t_gg + np.diag(np.full(self.n, np.inf))
        return np.asarray(np.minimum(self.t_start, others.min(axis=0, initial=np.inf)))

    @classmethod
    def build(cls, groups: list[GroupCost], robot_xy: np.ndarray, exit_xy: np.ndarray,
              speed: float, loss: Loss) -> Problem:
        """Travel times between entry/exit point sets in straight lines (eqs. 18-20 as
        in the paper)."""
        return cls.with_travel(groups, robot_xy, exit_xy, speed, loss, straight)

    @classmethod
    def with_travel(cls, groups: list[GroupCost], robot_xy: np.ndarray, exit_xy: np.ndarray,
                    speed: float, loss: Loss,
                    distance: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> Problem:
        """Eqs. 18-20 with travel along ``distance`` (e.g. shortest paths on the grid)."""
        t_start, t_gg, t_exit, t_leave = travel_times(groups, robot_xy, exit_xy, speed,
                                                      distance)
        return cls(np.array([g.value for g in groups], dtype=float),
                   np.array([g.t_obs for g in groups], dtype=float),
                   t_start, t_gg, t_exit, t_leave, loss)


def straight(sources: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Straight-line distance from the nearest of the sources to each target (eqs.
    18-20 as the paper writes them)."""
    return np.asarray(np.min(np.linalg.norm(np.atleast_2d(sources)[:, None]
                                            - np.atleast_2d(targets)[None], axis=2), axis=0))


def travel_times(groups: list[GroupCost], robot_xy: np.ndarray, exit_xy: np.ndarray,
                 speed: float, distance: Callable[[np.ndarray, np.ndarray], np.ndarray],
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Eqs. 18-20 with a distance of choice: ``distance(sources (k, 2), targets (m, 2))``
    gives the distance (m) from the nearest source to each target. Returns t_start,
    t_gg, t_exit (s) and t_leave."""
    n = len(groups)
    robot = np.asarray(robot_xy, float)[None, :2]
    exit_ = np.asarray(exit_xy, float)[None, :2]
    # every group's entry points and the exit as one target set: one call per source
    targets = np.vstack([*(np.atleast_2d(g.entries) for g in groups), exit_])
    cuts = np.cumsum([0, *(len(np.atleast_2d(g.entries)) for g in groups)])

    def per_group(d: np.ndarray) -> np.ndarray:
        return np.array([d[cuts[j]:cuts[j + 1]].min() for j in range(n)])

    t_gg = np.zeros((n, n))
    t_exit = np.zeros(n)
    for i, g in enumerate(groups):
        d = distance(g.entries, targets)
        t_gg[i] = per_group(d) / speed
        t_exit[i] = d[-1] / speed
    np.fill_diagonal(t_gg, 0.0)
    t_gg = np.minimum(t_gg, t_gg.T)  # either way round: the shorter estimate
    d = distance(robot, targets)
    return (per_group(d) / speed).reshape(n), t_gg, t_exit, float(d[-1] / speed)


@dataclass(frozen=True)
class Plan:
    """An ordered plan (group indices) and its figures (eq. 11)."""

    order: tuple[int, ...]
    value: float
    t_move: float
    t_obs: float
    loss: float
    utility: float

    @property
    def time(self) -> float:
        return self.t_move + self.t_obs


def evaluate(p: Problem, order: tuple[int, ...]) -> Plan:
    """Eq. 11 for one ordered plan."""
    if not order:
        t_move = p.t_leave
        value = t_obs = 0.0
    else:
        t_move = float(p.t_start[order[0]] + p.t_exit[order[-1]]
                       + sum(p.t_gg[a, b] for a, b in itertools.pairwise(order)))
        value = float(p.value[list(order)].sum())
        t_obs = float(p.t_obs[list(order)].sum())
    loss = float(p.loss(t_move + t_obs))
    return Plan(order, value, t_move, t_obs, loss, value - loss)


def _rank(plan: Plan) -> tuple[float, int, float, tuple[int, ...]]:
    u = plan.utility if np.isfinite(plan.utility) else -np.inf
    # rounded: a set's value summed in another order differs in the last bits
    return (-round(u, 9), len(plan.order), round(plan.time, 9), plan.order)


def solve_exhaustive(p: Problem) -> list[Plan]:
    """The paper's search (§6.4): every ordered subset, best first."""
    plans = [evaluate(p, ())]
    for r in range(1, p.n + 1):
        for order in itertools.permutations(range(p.n), r):
            plans.append(evaluate(p, order))
    return sorted(plans, key=_rank)


def _subset_sums(values: np.ndarray) -> np.ndarray:
    out = np.zeros(1 << len(values))
    for i, v in enumerate(values):
        out[1 << i: 1 << (i + 1)] = out[: 1 << i] + v
    return out


def fastest_tours(p: Problem) -> np.ndarray:
    """Held-Karp: ``dp[S, j]`` = the least travel time from the robot through every group
    of the set S (bit mask) ending at group j."""
    n = p.n
    size = 1 << n
    dp = np.full((size, n), np.inf)
    for j in range(n):
        dp[1 << j, j] = p.t_start[j]
    masks = np.arange(size)
    pop = np.zeros(size, dtype=np.int64)
    for i in range(n):
        pop += (masks >> i) & 1
    for k in range(1, n):
        layer = masks[pop == k]
        for j in range(n):
            sel = layer[((layer >> j) & 1) == 0]
            if len(sel) == 0:
                continue
            cand = np.min(dp[sel] + p.t_gg[:, j][None, :], axis=1)
            tgt = sel | (1 << j)
            dp[tgt, j] = np.minimum(dp[tgt, j], cand)
    return dp


def _order_of(p: Problem, dp: np.ndarray, mask: int) -> tuple[int, ...]:
    """The fastest order of the set ``mask`` by backtracking through ``dp``."""
    if mask == 0:
        return ()
    members = [j for j in range(p.n) if mask >> j & 1]
    j = min(members, key=lambda m: (dp[mask, m] + p.t_exit[m], m))
    order = [j]
    while mask != (1 << j):
        prev_mask = mask & ~(1 << j)
        prev = [i for i in range(p.n) if prev_mask >> i & 1]
        i = min(prev, key=lambda m: (dp[prev_mask, m] + p.t_gg[m, j], m))
        order.append(i)
        mask, j = prev_mask, i
    return tuple(reversed(order))


def solve(p: Problem, runner_ups: int = 5) -> list[Plan]:
    """The best plan and up to ``runner_ups`` next-best plans of *other* group sets (each
    in its fastest order), exactly, by dynamic programming over subsets."""
    if p.n > MAX_GROUPS_EXACT:
        raise InvalidInput(f"{p.n} groups: the exact planner handles at most "
                           f"{MAX_GROUPS_EXACT}", field="candidates")
    if p.n == 0:
        return [evaluate(p, ())]
    dp = fastest_tours(p)
    tour = np.min(dp + p.t_exit[None, :], axis=1)
    tour[0] = p.t_leave
    total = tour + _subset_sums(p.t_obs)
    utility = _subset_sums(p.value) - p.loss(total)
    utility = np.where(np.isfinite(utility), utility, -np.inf)
    k = min(runner_ups + 1, len(utility))
    top = np.argpartition(-utility, k - 1)[:k] if k < len(utility) else np.arange(len(utility))
    plans = [evaluate(p, _order_of(p, dp, int(m))) for m in top]
    # a plan tied with the k-th one may be missing from the partition: include ties
    cut = utility[top].min()
    ties = np.nonzero(utility == cut)[0]
    plans += [evaluate(p, _order_of(p, dp, int(m))) for m in ties if m not in set(top.tolist())]
    return sorted(plans, key=_rank)[: runner_ups + 1]


# -- branch and bound past the DP's reach -----------------------------------------------
@dataclass(frozen=True)
class Solution:
    """Plans best first, and what is proven: ``upper_bound`` >= every plan's utility, so
    ``gap = upper_bound - plans[0].utility`` is 0 when the best plan is optimal."""

    plans: list[Plan]
    upper_bound: float
    nodes: int
    returned_early: bool

    @property
    def gap(self) -> float:
        u = self.plans[0].utility
        return max(0.0, self.upper_bound - u) if np.isfinite(u) else float("inf")

    @property
    def optimal(self) -> bool:
        return self.gap <= 1e-9 * max(1.0, abs(self.upper_bound))


_LOSS_KIND = {"L1": 1, "L2": 2, "L3": 3}


def state_bounds(p: Problem, masks: np.ndarray, last: np.ndarray, t: np.ndarray,
                 val: np.ndarray, entry_min: np.ndarray) -> np.ndarray:
    """The best utility of any plan through each state ``(groups done as a bit mask,
    the last one, time so far, value so far)``: leave now, or go on with more groups.

    Going on is bounded by a concave knapsack over the groups still to do: each weighs
    its t_obs plus its cheapest way in from any group or the robot (``entry_min``, see
    :meth:`Problem.way_in`), the tour ends with at least the cheapest way out of them,
    and the fractional optimum takes them by value per second, best first, while a
    second more is worth what it costs (L1: until the limit; L2: until the slope
    2 k_lim (T - t_limit) reaches the ratio; L3: every group of positive value). The
    weights do not depend on the state, so the order is sorted once and each state
    is one pass over it (numba)."""
    w = p.t_obs + entry_min
    order = np.argsort(-p.value / np.maximum(w, 1e-12), kind="stable")
    k_lim = p.loss.k_lim
    kind = _LOSS_KIND[p.loss.kind]
    if kind == 2 and k_lim <= 0:
        kind = 3
    return _state_bounds(np.ascontiguousarray(masks, dtype=np.int64),
                         np.ascontiguousarray(last, dtype=np.int64),
                         np.ascontiguousarray(t, dtype=np.float64),
                         np.ascontiguousarray(val, dtype=np.float64), order.astype(np.int64),
                         p.value.astype(np.float64), w.astype(np.float64),
                         p.t_exit.astype(np.float64), kind, float(p.loss.t_limit_s),
                         float(k_lim))


@njit(cache=True)
def _loss(kind: int, t: float, t_limit: float, k_lim: float) -> float:
    if t < t_limit or kind == 3:
        return 0.0
    if kind == 1:
        return np.inf
    return k_lim * (t - t_limit) ** 2


@njit(cache=True)
def _state_bounds(masks: np.ndarray, last: np.ndarray, t: np.ndarray, val: np.ndarray,
                  order: np.ndarray, value: np.ndarray, w: np.ndarray, t_exit: np.ndarray,
                  kind: int, t_limit: float, k_lim: float) -> np.ndarray:
    out = np.empty(len(masks))
    n = len(order)
    for s in range(len(masks)):
        m = masks[s]
        exit_min = np.inf
        todo = 0
        for g in range(n):
            if (m >> g) & 1 == 0 and value[g] > 0:
                todo += 1
                exit_min = min(exit_min, t_exit[g])
        best = val[s] - _loss(kind, t[s] + t_exit[last[s]], t_limit, k_lim)
        if not np.isfinite(best):
            best = -np.inf
        if todo:
            t0 = t[s] + (exit_min if np.isfinite(exit_min) else 0.0)
            more = -np.inf
            if kind == 3:
                more = 0.0
                for g in range(n):
                    if (m >> g) & 1 == 0 and value[g] > 0:
                        more += value[g]
            elif kind == 1:
                if t_limit - t0 > 0:
                    before, acc = t0, 0.0
                    for g in order:
                        if (m >> g) & 1 or value[g] <= 0:
                            continue
                        room = t_limit - before
                        if w[g] > 0:
                            x = min(max(room, 0.0), w[g])
                            acc += value[g] * x / w[g]
                        else:
                            x = 0.0
                            acc += value[g] if room >= 0 else 0.0
                        if x < w[g]:  # the first group that does not fit whole: the last
                            break
                        before += w[g]
                    if acc > 0:
                        more = acc
            else:
                before, gain, t_end = t0, 0.0, t0
                for g in order:
                    if (m >> g) & 1 or value[g] <= 0:
                        continue
                    r = value[g] / max(w[g], 1e-12)
                    x = min(w[g], max(0.0, r / (2 * k_lim) + t_limit - before))
                    gain += r * x if w[g] > 0 else value[g]
                    t_end += x
                    if x < w[g]:
                        break
                    before += w[g]
                more = gain - _loss(kind, t_end, t_limit, k_lim)
            best = max(best, val[s] + more)
        out[s] = best
    return out


def solve_bnb(p: Problem, runner_ups: int = 5, budget_s: float = 1.0,
              max_states: int = 100_000) -> Solution:
    """The best plan by branch and bound, one layer of partial tours at a time.

    A state is (groups done, the last one, time so far, value so far); layer k holds the
    tours of k groups from the robot. Each state yields the plan that leaves from it
    and bounds every longer plan through it (:func:`state_bounds`); states whose bound
    cannot beat the best plan found are cut, and of the states with the same groups and
    the same last group only the earliest is kept (every loss is non-decreasing in
    time). Bounds and children are computed layer by layer in numba (a hash table finds
    the duplicates; a few million states per second). The search starts from the exact
    DP's plans over a part of the groups (:func:`seed_plans`). It is exact when it runs
    out of states; past ``budget_s``, or when more than ``max_states`` states of a layer
    survive their bounds (then those with the best bounds go on, which bounds the memory
    at ~40 bytes per child), the largest bound left out makes the gap. The
    runner-ups are the next-best other sets met on the way (exact only from the DP).
    Each returned set is toured in its fastest order."""
    import time as _time

    n = p.n
    _compile(p)  # numba's first call compiles: not part of the search's time budget
    t_end = _time.perf_counter() + budget_s
    best_sets: dict[int, float] = {0: evaluate(p, ()).utility}
    for plan in seed_plans(p):
        best_sets[sum(1 << i for i in plan.order)] = plan.utility
    best = max(best_sets.values())
    keep = runner_ups + 1
    entry_min = p.way_in()
    masks = (1 << np.arange(n)).astype(np.int64)
    last = np.arange(n)
    t = p.t_start + p.t_obs
    val = p.value.astype(float)
    parent = np.full(n, np.inf)  # a bound of each state: its parent's
    left_out = -np.inf
    nodes, early = 0, False
    while len(masks):
        nodes += len(masks)
        now = val - p.loss(t + p.t_exit[last])
        for i in np.argsort(-now)[:keep]:
            m = int(masks[i])
            if np.isfinite(now[i]) and now[i] > best_sets.get(m, -np.inf):
                best_sets[m] = float(now[i])
        best = max(best, float(np.max(np.where(np.isfinite(now), now, -np.inf))))
        bound = np.full(len(masks), -np.inf)
        for c0 in range(0, len(masks), BOUND_CHUNK):
            sl = slice(c0, c0 + BOUND_CHUNK)
            bound[sl] = state_bounds(p, masks[sl], last[sl], t[sl], val[sl], entry_min)
            if _time.perf_counter() > t_end and c0 + BOUND_CHUNK < len(masks):
                early = True
                left_out = max(left_out, float(parent[c0 + BOUND_CHUNK:].max()))
                break
        live = bound > best + 1e-9
        if early or _time.perf_counter() > t_end:
            early = True
            left_out = max(left_out, float(bound[live].max()) if live.any() else -np.inf)
            break
        masks, last, t, val, bound = masks[live], last[live], t[live], val[live], bound[live]
        if not len(masks):
            break
        if len(masks) > max_states:  # expand the most promising, remember the rest
            top = np.argpartition(-bound, max_states)[:max_states]
            drop = np.ones(len(masks), dtype=bool)
            drop[top] = False
            early, left_out = True, max(left_out, float(bound[drop].max()))
            masks, last, t, val, bound = masks[top], last[top], t[top], val[top], bound[top]
        # children: every state x every group not done, the earliest per (set, last)
        masks, last, t, val, parent = _children(masks, last, t, val, bound, p.t_gg,
                                                p.t_obs.astype(np.float64),
                                                p.value.astype(np.float64))
    ub = max(best, left_out)
    top_sets = sorted(best_sets, key=lambda m: -best_sets[m])[:keep]
    plans = sorted((evaluate(p, fastest_order(p, m)) for m in top_sets), key=_rank)
    return Solution(plans, max(ub, plans[0].utility), nodes, early)


def _compile(p: Problem) -> None:
    """Call the numba kernels once on one state of ``p`` (same argument types), so that
    their compilation -- seconds on a fresh install or a loaded machine -- happens
    before the budget's clock starts and is not mistaken for search time."""
    if p.n == 0:
        return
    one = np.zeros(1, dtype=np.int64)
    z = np.zeros(1)
    state_bounds(p, one, one, z, z, p.way_in())
    _children(one, one, z, z, z, p.t_gg, p.t_obs.astype(np.float64),
              p.value.astype(np.float64))


@njit(cache=True)
def _children(masks: np.ndarray, last: np.ndarray, t: np.ndarray, val: np.ndarray,
              bound: np.ndarray, t_gg: np.ndarray, t_obs: np.ndarray, value: np.ndarray,
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The next layer: each state extended by each group not done, one child per (set,
    last group) -- the earliest (every loss is non-decreasing in time) -- found with an
    open-addressing hash table. Returns the children's masks, last groups, times,
    values and their parents' bounds."""
    n = len(value)
    cap = 0
    for s in range(len(masks)):
        m = masks[s]
        for g in range(n):
            cap += 1 - ((m >> g) & 1)
    bits = 1
    while (1 << bits) < 2 * cap:
        bits += 1
    size = 1 << bits
    slot = np.full(size, -1, dtype=np.int64)
    out_m = np.empty(cap, dtype=np.int64)
    out_l = np.empty(cap, dtype=np.int64)
    out_t = np.empty(cap)
    out_v = np.empty(cap)
    out_b = np.empty(cap)
    k = 0
    for s in range(len(masks)):
        m, a = masks[s], last[s]
        for g in range(n):
            if (m >> g) & 1:
                continue
            m2 = m | (np.int64(1) << g)
            t2 = t[s] + t_gg[a, g] + t_obs[g]
            h = (np.uint64(m2 * n + g) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(64 - bits)
            i = np.int64(h)
            while True:
                j = slot[i]
                if j < 0:
                    slot[i] = k
                    out_m[k], out_l[k], out_t[k] = m2, g, t2
                    out_v[k], out_b[k] = val[s] + value[g], bound[s]
                    k += 1
                    break
                if out_m[j] == m2 and out_l[j] == g:
                    if t2 < out_t[j]:
                        out_t[j], out_b[j] = t2, bound[s]
                    break
                i = (i + 1) & (size - 1)
    return out_m[:k], out_l[:k], out_t[:k], out_v[:k], out_b[:k]


def seed_plans(p: Problem, size: int = SEED_GROUPS) -> list[Plan]:
    """Good plans to start the branch and bound from: every group of positive value
    (L3's optimum), and the exact DP over the ``size`` groups of most value per second
    (t_obs plus the cheapest way in) and over the ``size`` groups nearest the robot."""
    out = []
    positive = [i for i in range(p.n) if p.value[i] > 0]
    if positive and p.n > 1:  # L3's optimum; a bound to beat for the others
        out.append(evaluate(p, fastest_order(p, sum(1 << i for i in positive))))
    if p.n <= size:
        return out
    per_s = p.value / np.maximum(p.t_obs + p.way_in(), 1e-9)
    for rank in (np.argsort(-per_s), np.argsort(p.t_start)):
        members = sorted(int(i) for i in rank[:size])
        sub = Problem(p.value[members], p.t_obs[members], p.t_start[members],
                      p.t_gg[np.ix_(members, members)], p.t_exit[members], p.t_leave, p.loss)
        best = solve(sub, runner_ups=0)[0]
        out.append(evaluate(p, tuple(members[i] for i in best.order)))
    return out


def fastest_order(p: Problem, mask: int) -> tuple[int, ...]:
    """The fastest tour of the groups in ``mask`` from the robot to the exit: exact up
    to 15 groups, nearest neighbour and 2-opt beyond (:func:`chizu.numeric.tours.best_order`)."""
    members = [j for j in range(p.n) if mask >> j & 1]
    if len(members) <= 1:
        return tuple(members)
    gg = p.t_gg[np.ix_(members, members)]
    order = best_order(p.t_start[members], gg, gg + p.t_exit[members][None, :], 15)
    return tuple(members[i] for i in order)


#: the exact DP below this many groups (tens of ms), branch and bound from here on
DP_AUTO_MAX = 16


def solve_auto(p: Problem, runner_ups: int = 5, budget_s: float = 1.0,
               solver: str = "auto") -> Solution:
    """The global plan by ``solver``: ``dp`` (exact, at most MAX_GROUPS_EXACT groups),
    ``bnb`` (branch and bound, exact unless ``budget_s`` runs out, then with its gap),
    ``exhaustive`` (the paper's search, small problems) or ``auto`` (dp up to
    DP_AUTO_MAX groups, else bnb)."""
    if solver == "exhaustive":
        plans = solve_exhaustive(p)[: runner_ups + 1]
        return Solution(plans, plans[0].utility, 0, False)
    if solver == "dp" or (solver == "auto" and p.n <= DP_AUTO_MAX):
        plans = solve(p, runner_ups)
        return Solution(plans, plans[0].utility, 0, False)
    return solve_bnb(p, runner_ups, budget_s)
