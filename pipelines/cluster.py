"""Dask clusters: a LocalCluster by default, an existing scheduler by address.

Local workers are processes with one thread each, and PoCL is limited to one
thread per worker, so workers do not oversubscribe the cores.
"""

from __future__ import annotations

import contextlib
import logging
import os
from typing import Iterator

from meshsom.bmu import CLIENT_SAYS_FALLBACK_ENV
from pipelines.settings import DaskConfig

log = logging.getLogger(__name__)

#: Environment each local worker starts with: one compute thread per worker.
WORKER_ENV = {
    "POCL_MAX_PTHREAD_COUNT": "1",
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    # the client probes the same device first (pipelines.train.prepare_engine) and says a fallback once
    CLIENT_SAYS_FALLBACK_ENV: "1",
}


@contextlib.contextmanager
def connect(config: DaskConfig, quiet: bool = False) -> Iterator:
    """A ``distributed.Client`` for the configured cluster, closed on exit.

    Prints where the work runs (and the dashboard link, when one is served) unless ``quiet``.
    A LocalCluster serves the dashboard only with ``config.dashboard``.
    """
    from distributed import Client, LocalCluster

    for name in ("distributed", "distributed.scheduler", "distributed.nanny", "distributed.core", "distributed.worker"):
        logging.getLogger(name).setLevel(logging.WARNING)  # the in-process scheduler talks at INFO

    if config.scheduler:
        try:
            client = Client(config.scheduler, timeout="10s")
        except OSError as err:
            from meshsom.errors import MeshsomError

            raise MeshsomError(f"cannot reach the Dask scheduler at {config.scheduler}: {err}") from None
        cluster = None
    else:
        n = config.workers or os.cpu_count() or 1
        old = {k: os.environ.get(k) for k in WORKER_ENV}
        os.environ.update(WORKER_ENV)  # inherited by the worker processes
        try:
            cluster = LocalCluster(
                n_workers=n,
                threads_per_worker=1,
                processes=True,
                memory_limit=config.memory_limit,
                # the scheduler's HTTP server always starts (None would take :8787 when free); the
                # dashboard pages only when configured
                dashboard_address="127.0.0.1:0",
                scheduler_kwargs={"dashboard": bool(config.dashboard)},
                host="127.0.0.1",
                silence_logs=logging.WARNING,
            )
        finally:
            for k, v in old.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
        client = Client(cluster)
    try:
        if not quiet:
            has_dashboard = "dashboard" in client.scheduler_info().get("services", {})
            served = config.dashboard or config.scheduler  # a LocalCluster without one answers 404
            link = client.dashboard_link if has_dashboard and served else None
            where = config.scheduler or f"LocalCluster, {len(client.scheduler_info()['workers'])} workers x 1 thread"
            print(f"dask: {where}" + (f"; dashboard {link}" if link else ""))
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


@contextlib.contextmanager
def connect_serial() -> Iterator:
    """An in-process ``distributed.Client`` with one worker thread: the serial executor of the single-process
    commands (``meshsom ingest``, ``meshsom encode``), which run the drivers of ``meshsom run`` on it."""
    from distributed import Client

    for name in ("distributed", "distributed.scheduler", "distributed.core", "distributed.worker"):
        logging.getLogger(name).setLevel(logging.WARNING)
    with Client(processes=False, n_workers=1, threads_per_worker=1, dashboard_address=None) as client:
        yield client
