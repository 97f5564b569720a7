"""Process memory: large arrays returned to the system when freed.

glibc serves an allocation above its mmap threshold with its own ``mmap`` and unmaps it
on ``free``; but after such a free it raises the threshold to that size (up to 32 MiB),
so later grids of a few MiB come from the heap, where a freed one stays resident. A long
SLAM run makes and drops grids all the time (submaps finished and trimmed, loop-closure
grids stitched and evicted): fixing the threshold keeps its resident memory to what it
holds (measured in ``docs/notes/slam-graph.md``, on lifelong runs)."""

from __future__ import annotations

import ctypes
import ctypes.util

#: glibc's mallopt parameter M_MMAP_THRESHOLD
_M_MMAP_THRESHOLD = -3


def return_large_frees(threshold_bytes: int = 256 * 1024) -> bool:
    """Serve allocations above ``threshold_bytes`` by ``mmap`` for the rest of the
    process (a fixed threshold, which glibc then no longer raises). Returns whether the
    C library took it (False off glibc)."""
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        mallopt = ctypes.CDLL(name).mallopt
    except (OSError, AttributeError):
        return False
    return bool(mallopt(_M_MMAP_THRESHOLD, int(threshold_bytes)))
