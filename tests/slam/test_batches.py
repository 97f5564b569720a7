"""SLAM batches (numeric.slam.batch): the grid, and a Dask LocalCluster of 2 worker
processes giving the same results as the in-process run."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from chizu.numeric.errors import InvalidInput
from chizu.numeric.slam.batch import expand_grid, run_batch, tasks_for
from chizu.numeric.slam.logs import write_carmen
from chizu.numeric.slam.simulate import simulated_log
from chizu.service.executors import batch_executor


def test_the_grid_expands_and_is_checked() -> None:
    sets = expand_grid({"method": ["icp", "gated"], "seed": [0, 1], "alpha": 0.0})
    assert len(sets) == 4 and {"method": "gated", "seed": 1, "alpha": 0.0} in sets
    with pytest.raises(InvalidInput):
        expand_grid({"method": ["icp", "magic"]})
    with pytest.raises(InvalidInput):
        expand_grid({"particles": [0]})


def test_a_local_dask_cluster_gives_the_in_process_results(tmp_path: Path) -> None:
    log = simulated_log("room_a", seed=3)
    path = tmp_path / "room_a.clf"
    write_carmen(path, log)
    tasks = tasks_for([path], {"method": ["odom", "icp"], "seed": 0}, limit=60)
    here = run_batch(tasks)
    with batch_executor(local_workers=2) as ex:
        assert ex is not None
        there = run_batch(tasks, ex)
    assert [r.options for r in there] == [r.options for r in here]
    for a, b in zip(here, there, strict=True):
        assert a.scans == b.scans == 60
        np.testing.assert_allclose(np.asarray(a.trajectory), np.asarray(b.trajectory),
                                   atol=1e-9)
    # the two methods did differ (the comparison means something)
    assert not np.allclose(np.asarray(here[0].trajectory), np.asarray(here[1].trajectory))
