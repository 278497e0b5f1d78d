"""What a local cluster's worker does when it starts (distributed/series.local_cluster): a Dask
WorkerPlugin, so a worker its nanny restarts does it too. Imported only when a local cluster is
made (it imports dask.distributed)."""
from __future__ import annotations

import os
import signal
import threading

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
    engine/processes.watch_parent), ignores SIGINT (Ctrl-C in a terminal signals the whole process
    group: the process that made the cluster closes it, with one line, instead of every worker
    printing a traceback) and, unless a dashboard was asked for, closes its HTTP listener."""

    name = "hovr-local-worker"

    def __init__(self, no_http: bool = True):
        self.no_http = no_http

    def setup(self, worker):
        watch_parent(os.getppid())
        if threading.current_thread() is threading.main_thread():  # where signal handlers are set
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        if self.no_http:
            close_http(dask_worker=worker)
