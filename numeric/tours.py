"""Orders of items with a cost to start at each, a cost between each pair and a cost
for the last step: ``enter[o1] + sum cost[o_i, o_i+1] + leave[o_m-1, o_m]``. Exact by
dynamic programming over subsets for small sets, nearest neighbour and 2-opt beyond.
Used for the viewpoint planner's tours of groups (paper eqs. 18-20) and its chains of
objects in a large group (eq. 7)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: 2-opt's rounds cost O(n^3) in Python; past this many items the nearest-neighbour
#: order is kept as it is (a scene of 2 000 one-cell unknown regions hung in 2-opt)
TWO_OPT_MAX_ITEMS = 40


def best_order(enter: np.ndarray, cost: np.ndarray, leave: np.ndarray,
               exact_up_to: int = 12) -> list[int]:
    """:func:`order_dp` up to ``exact_up_to`` items, else :func:`nearest_order` improved
    by :func:`two_opt` (up to ``TWO_OPT_MAX_ITEMS`` items)."""
    if len(enter) <= exact_up_to:
        return order_dp(enter, cost, leave)
    order = nearest_order(enter, cost)
    if len(order) > TWO_OPT_MAX_ITEMS:
        return order
    return two_opt(order, enter, cost, leave)


def order_dp(enter: np.ndarray, cost: np.ndarray, leave: np.ndarray) -> list[int]:
    """The order of k items minimising ``enter[o1] + sum cost[o_i, o_i+1] +
    leave[o_k-1, o_k]`` (the last leg priced by ``leave``), by dynamic programming over
    subsets (Held-Karp, vectorised over each subset layer)."""
    k = len(enter)
    if k == 1:
        return [0]
    subs = np.arange(1 << k)
    count = np.zeros(1 << k, dtype=int)
    for i in range(k):
        count += (subs >> i) & 1
    d = np.full((1 << k, k), np.inf)
    arg = np.full((1 << k, k), -1, dtype=np.int16)
    d[1 << np.arange(k), np.arange(k)] = enter
    for size in range(2, k):  # the last item is added with ``leave``
        layer = subs[count == size]
        for i in range(k):
            sel = layer[(layer >> i) & 1 == 1]
            tot = d[sel ^ (1 << i)] + cost[:, i][None, :]
            arg[sel, i] = np.argmin(tot, axis=1)
            d[sel, i] = np.min(tot, axis=1)
    full = (1 << k) - 1
    best, last, prev = np.inf, 0, 0
    for li in range(k):
        for pi in range(k):
            if pi != li and d[full ^ (1 << li), pi] + leave[pi, li] < best:
                best, last, prev = d[full ^ (1 << li), pi] + leave[pi, li], li, pi
    out, sub, i = [last], full ^ (1 << last), prev
    while i >= 0:
        out.append(i)
        nxt = int(arg[sub, i])
        sub ^= 1 << i
        i = nxt
    return out[::-1]


def nearest_order(enter: np.ndarray, cost: np.ndarray) -> list[int]:
    """Greedy order: the quickest first item, then the quickest next one each time."""
    left = set(range(len(enter)))
    at = int(np.argmin(enter))
    out = [at]
    left.discard(at)
    while left:
        at = min(left, key=lambda j: cost[at, j])
        out.append(at)
        left.discard(at)
    return out


def chain_cost(order: Sequence[int], enter: np.ndarray, cost: np.ndarray,
               leave: np.ndarray) -> float:
    mid = sum(cost[a, b] for a, b in zip(order[:-2], order[1:-1], strict=True))
    return float(enter[order[0]] + mid + leave[order[-2], order[-1]])


def two_opt(order: list[int], enter: np.ndarray, cost: np.ndarray, leave: np.ndarray,
            rounds: int = 20) -> list[int]:
    """Improve an order by reversing segments while that shortens it (2-opt)."""
    best = chain_cost(order, enter, cost, leave)
    for _ in range(rounds):
        improved = False
        for i in range(len(order) - 1):
            for j in range(i + 2, len(order) + 1):
                cand = order[:i] + order[i:j][::-1] + order[j:]
                c = chain_cost(cand, enter, cost, leave)
                if c < best - 1e-12:
                    order, best, improved = cand, c, True
        if not improved:
            break
    return order
