"""Global viewpoint planning: which groups to observe, in which order (paper §6).

A plan is an ordered subset G_1..G_N of the observation groups. Its utility (eq. 11) is

    U = V - L(t_mov + sum_i t_obs(G_i)),

with V the sum of the group values (eqs. 15-17), t_mov the travel from the robot through
the groups' entry/exit points to the room's exit (eqs. 18-20) and L one of the losses of
eqs. 12-14. The paper enumerates every ordered subset (sum_i nPi plans); that is kept as
:func:`solve_exhaustive`, the reference. The default :func:`solve` is exact too: V and
sum t_obs depend only on the *set* of groups and every loss is non-decreasing in time, so
the best order of a set is its fastest tour, found for all sets at once by Held-Karp
dynamic programming over subsets (O(2^n n^2), vectorised with numpy). Both return the same
optimum utility; ties (e.g. a plan and its reverse when the exit is the start) are broken
by fewer groups, then the shorter time, then the group indices.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial.distance import cdist

from numeric.errors import InvalidInput

MAX_GROUPS_EXACT = 20


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

    @classmethod
    def build(cls, groups: list[GroupCost], robot_xy: np.ndarray, exit_xy: np.ndarray,
              speed: float, loss: Loss) -> Problem:
        """Travel times between entry/exit point sets (eqs. 18-20, Euclidean as in the
        paper)."""
        n = len(groups)
        t_gg = np.zeros((n, n))
        for i, j in itertools.combinations(range(n), 2):
            t_gg[i, j] = t_gg[j, i] = cdist(groups[i].entries, groups[j].entries).min() / speed
        t_start = np.array([cdist(g.entries, robot_xy[None, :2]).min() / speed for g in groups])
        t_exit = np.array([cdist(g.entries, exit_xy[None, :2]).min() / speed for g in groups])
        return cls(np.array([g.value for g in groups], dtype=float),
                   np.array([g.t_obs for g in groups], dtype=float),
                   t_start.reshape(n), t_gg, t_exit.reshape(n),
                   float(np.hypot(*(robot_xy[:2] - exit_xy[:2])) / speed), loss)


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
