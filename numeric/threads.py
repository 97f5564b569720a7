"""One process-wide thread pool for numba kernels that release the GIL.

The SLAM inner loops (branch and bound, the per-particle scan match of the improved
proposal) are compiled with ``nogil=True``; running independent calls on threads uses
both cores of a small robot computer without copying maps into other processes. The
results never depend on the number of threads: the work is split, not reordered.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

T = TypeVar("T")
R = TypeVar("R")

_POOLS: dict[int, ThreadPoolExecutor] = {}
_LOCK = threading.Lock()


def default_threads() -> int:
    """The cores this process may run on (``CHIZU_THREADS`` overrides)."""
    env = os.environ.get("CHIZU_THREADS")
    if env:
        return max(1, int(env))
    return max(1, len(os.sched_getaffinity(0)))


def thread_map(fn: Callable[[T], R], items: Sequence[T], threads: int) -> list[R]:
    """``[fn(x) for x in items]`` in order, on up to ``threads`` threads of a shared
    pool when there is more than one item; ``fn`` must release the GIL to gain."""
    if threads <= 1 or len(items) <= 1:
        return [fn(x) for x in items]
    with _LOCK:
        pool = _POOLS.get(threads)
        if pool is None:
            pool = _POOLS[threads] = ThreadPoolExecutor(threads, thread_name_prefix="chizu")
    return list(pool.map(fn, items))
