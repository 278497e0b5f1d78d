"""What a local cluster's worker does when it starts (distributed/series.local_cluster): a Dask
WorkerPlugin, so a worker its nanny restarts does it too. Imported only when a local cluster is
made (it imports dask.distributed)."""
from __future__ import annotations

import os

from distributed import WorkerPlugin

from ..engine.processes import watch_parent


def close_http(dask_scheduler=None, dask_worker=None):
    """Stop a Dask server's HTTP listener: Dask starts one (health, metrics, and more) even
    without a dashboard, on a port anyone on the machine can reach."""
    server = getattr(dask_scheduler or dask_worker, "http_server", None)
    if server is not None:
        server.stop()


class LocalWorkerConfinement(WorkerPlugin):
    """Each worker ends with the process that made the cluster (its nanny lives there:
    engine/processes.watch_parent) and, unless a dashboard was asked for, closes its HTTP listener."""

    name = "hovr-local-worker"

    def __init__(self, no_http: bool = True):
        self.no_http = no_http

    def setup(self, worker):
        watch_parent(os.getppid())
        if self.no_http:
            close_http(dask_worker=worker)
