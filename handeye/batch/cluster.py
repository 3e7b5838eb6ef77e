"""The Dask client a batch runs on: a scheduler of the user's, or a cluster embedded in this process.

The embedded cluster has one single-threaded worker process per core and gives a worker one session at a time
(:data:`ONE_TASK_PER_THREAD`), so that a worker's death counts against the session it ran alone.
"""

from __future__ import annotations

import os
from typing import Optional

from ..errors import InputError, clip

#: the embedded scheduler's ``worker-saturation``: a worker holds only the task it runs, the rest wait on the scheduler
ONE_TASK_PER_THREAD = 1.0


def open_client(scheduler: Optional[str] = None, n_workers: Optional[int] = None):
    """A Dask client of the cluster at ``scheduler`` or of an embedded LocalCluster.

    A Dask client: of the cluster at ``scheduler`` (``tcp://HOST:8786``), or of an embedded
    LocalCluster of ``n_workers`` single-threaded worker processes (default: the CPU count).
    Close it with ``client.close()`` (and the cluster with ``client.cluster.close()``).
    """
    from dask.distributed import Client, LocalCluster

    if scheduler:
        try:
            return Client(scheduler, timeout="30s")
        except OSError as e:  # Dask's "Timed out trying to connect", a refused connection, an unknown host
            raise InputError(
                f"cannot reach the Dask scheduler at {scheduler} ({clip(' '.join(str(e).split()), 120)})",
                hint="check the address and that the scheduler runs there (dask scheduler), or leave out "
                "--scheduler to run on this machine",
            ) from None
    import dask

    n = int(n_workers or os.cpu_count() or 1)
    # one task on a worker at a time (Dask's default, 1.1, gives a single-threaded worker a second one): a worker's
    # death then counts against the session that ran on it alone, never against one queued behind it
    with dask.config.set({"distributed.scheduler.worker-saturation": ONE_TASK_PER_THREAD}):
        cluster = LocalCluster(
            n_workers=n,
            threads_per_worker=1,
            processes=True,
            dashboard_address=":0",  # no fixed port taken
            scheduler_kwargs={"dashboard": False},
        )
    return Client(cluster)
