"""SLAM over many logs and parameter sets: one task per (log, parameter set), each run
whole and evaluated on the log's reference relations (Kümmerle et al. 2009) when it has
them.

The tasks are plain functions of plain data, so any ``concurrent.futures.Executor``
runs them: none (in this process, one after the other), a process pool, or a Dask
cluster through ``distributed.Client.get_executor()`` (``chizu slam-batch
--scheduler``). The results do not depend on where a task ran: every method is seeded.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Iterable, Mapping
from concurrent.futures import Executor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from chizu.numeric.errors import InvalidInput
from chizu.numeric.slam.evaluation import relation_errors
from chizu.numeric.slam.logs import read_log, read_relations
from chizu.numeric.slam.runner import SlamOptions, run_log

LOOP_GAP_S = 60.0  #: relations spanning more than this are "loop" relations


@dataclass(frozen=True)
class BatchTask:
    """One run: a log file, the run's options (``SlamOptions`` fields) and how the log
    is read."""

    log: str
    options: dict[str, Any]
    max_range_m: float = 40.0
    limit: int | None = None
    relations: str | None = None


@dataclass
class BatchResult:
    log: str
    options: dict[str, Any]
    scans: int
    log_s: float
    seconds: float
    trans_m: float | None = None
    trans_std_m: float | None = None
    rot_deg: float | None = None
    loop_trans_m: float | None = None
    relations: int = 0
    trajectory: list[list[float]] = field(default_factory=list)  # t, x, y, theta

    def row(self) -> dict[str, Any]:
        """The result without its trajectory, for a table."""
        d = asdict(self)
        d.pop("trajectory")
        return d


def expand_grid(grid: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Every combination of a parameter grid: a key's list is its values, a scalar is
    one value (``{"method": ["icp", "rbpf"], "seed": [0, 1]}`` -> 4 sets), each
    checked against :class:`SlamOptions` (a wrong name or value: InvalidInput)."""
    keys = list(grid)
    values = [v if isinstance(v, list) else [v] for v in grid.values()]
    sets = [dict(zip(keys, combo, strict=True)) for combo in itertools.product(*values)]
    for i, s in enumerate(sets):
        try:
            SlamOptions(**s)
        except ValueError as e:  # pydantic's ValidationError is a ValueError
            raise InvalidInput(f"parameter set {i} {s}: {e}", field="grid") from None
    return sets


def find_relations(log: str | Path) -> Path | None:
    """The log's reference relations: ``<stem>.relations`` beside it, else the one
    ``*.relations`` file in its folder."""
    p = Path(log)
    own = p.with_suffix(".relations")
    if own.exists():
        return own
    found = sorted(p.parent.glob("*.relations")) if p.parent.is_dir() else []
    return found[0] if len(found) == 1 else None


def tasks_for(logs: Iterable[str | Path], grid: Mapping[str, Any], max_range_m: float = 40.0,
              limit: int | None = None) -> list[BatchTask]:
    """One task per log and parameter set (logs outer, sets inner)."""
    sets = expand_grid(grid)
    out = []
    for log in logs:
        rel = find_relations(log)
        out += [BatchTask(str(log), s, max_range_m, limit, None if rel is None else str(rel))
                for s in sets]
    return out


def run_task(task: BatchTask) -> BatchResult:
    """Read the log, run SLAM over it and evaluate it (a worker runs this)."""
    data = read_log(Path(task.log), max_range_m=task.max_range_m, limit=task.limit)
    opts = SlamOptions(**task.options)
    t0 = time.perf_counter()
    _, res = run_log(data, opts)
    seconds = time.perf_counter() - t0
    out = BatchResult(task.log, task.options, len(data), data.duration_s, seconds,
                      trajectory=np.column_stack([res.times, res.poses]).tolist())
    if task.relations is not None:
        rt, rd = read_relations(task.relations)
        inside = (rt[:, 0] >= res.times[0]) & (rt[:, 1] <= res.times[-1])
        rt, rd = rt[inside], rd[inside]
        if len(rt):
            e = relation_errors(res.times, res.poses, rt, rd)
            out.trans_m, out.trans_std_m, out.rot_deg = e.trans_m, e.trans_std_m, e.rot_deg
            out.relations = e.n
            loop = (rt[:, 1] - rt[:, 0]) > LOOP_GAP_S
            if loop.any():
                out.loop_trans_m = relation_errors(res.times, res.poses, rt[loop],
                                                   rd[loop]).trans_m
    return out


def run_batch(tasks: list[BatchTask], executor: Executor | None = None) -> list[BatchResult]:
    """Every task, in order: on ``executor`` if given, else here, one after the other."""
    if executor is None:
        return [run_task(t) for t in tasks]
    return list(executor.map(run_task, tasks))
