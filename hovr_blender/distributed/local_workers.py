"""The classes of a local cluster (distributed/series.local_cluster): a scheduler and workers that
open no HTTP server, and what a worker does when it starts (a Dask WorkerPlugin, so a worker its
nanny restarts does it too). Imported only when a local cluster is made (it imports
dask.distributed); the workers import it by name, as their nannies start them.
"""
from __future__ import annotations

import os
import signal
import threading

from distributed import LocalCluster, Nanny, Scheduler, Worker, WorkerPlugin

from ..engine.processes import watch_parent


class _NoHttp:
    """A Dask server without its HTTP server: Dask starts one on the scheduler and on each worker
    (health, metrics, and the dashboard when asked for) even without a dashboard, on a port any
    user of the machine can reach. Not started at all, rather than closed after the start."""

    def start_http_server(self, routes, dashboard_address, default_port=0, ssl_options=None):
        pass  # no http_server nor http_application attribute: Dask's close checks for the latter


class NoHttpScheduler(_NoHttp, Scheduler):
    """A scheduler that opens no HTTP port."""


class NoHttpWorker(_NoHttp, Worker):
    """A worker that opens no HTTP port."""


class NoHttpNanny(Nanny):
    """A nanny (it opens no HTTP port itself) whose worker process is a NoHttpWorker."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **{**kwargs, "worker_class": NoHttpWorker})


class PrivateCluster(LocalCluster):
    """A LocalCluster of worker processes; with `http=False`, no HTTP server anywhere: its
    scheduler a NoHttpScheduler (LocalCluster always makes Dask's own Scheduler), its nannies'
    workers NoHttpWorkers."""

    def __init__(self, *args, http: bool = True, **kwargs):
        self._scheduler_class = Scheduler if http else NoHttpScheduler
        super().__init__(*args, worker_class=Nanny if http else NoHttpNanny, **kwargs)

    async def _start(self):
        self.scheduler_spec = {**self.scheduler_spec, "cls": self._scheduler_class}
        await super()._start()


class LocalWorkerConfinement(WorkerPlugin):
    """Each worker ends with the process that made the cluster (its nanny lives there:
    engine/processes.watch_parent) and ignores SIGINT (Ctrl-C in a terminal signals the whole
    process group: the process that made the cluster closes it, with one line, instead of every
    worker printing a traceback)."""

    name = "hovr-local-worker"

    def setup(self, worker):
        watch_parent(os.getppid())
        if threading.current_thread() is threading.main_thread():  # where signal handlers are set
            signal.signal(signal.SIGINT, signal.SIG_IGN)
