"""Where batch work runs: here (no executor), or on a Dask cluster (``dask.distributed``):
an existing one (``--scheduler tcp://host:8786`` or ``CHIZU_DASK_SCHEDULER``) or one
started on this machine (``--local-workers N``: N worker processes, one thread each).
What runs there is the same task functions a plain ``concurrent.futures.Executor``
takes (``Client.get_executor()``), so a result does not depend on where it ran. Workers
of an existing cluster need chizu installed (the docker image has it)."""

from __future__ import annotations

import os
from collections.abc import Iterator
from concurrent.futures import Executor
from contextlib import contextmanager


@contextmanager
def batch_executor(scheduler: str | None = None, local_workers: int = 0
                   ) -> Iterator[Executor | None]:
    """An executor for the block: None (in-process) unless a scheduler address (or
    ``CHIZU_DASK_SCHEDULER``) or ``local_workers`` > 0 is given."""
    address = scheduler or os.environ.get("CHIZU_DASK_SCHEDULER") or None
    if address is None and local_workers <= 0:
        yield None
        return
    from distributed import Client, LocalCluster

    cluster = None
    if address is None:
        cluster = LocalCluster(n_workers=local_workers, threads_per_worker=1, processes=True,
                               dashboard_address=None)
        client = Client(cluster)
    else:
        client = Client(address)
    try:
        yield client.get_executor()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
