"""Where the work runs: in-process (synchronous scheduler), a LocalCluster, or a cluster by address.

:func:`get_client` is shared with design studies (the optimiser evaluates candidates on the
same client). Workers run one torch thread each (docs/platform.md: 2 threads per process were up
to 16x slower on a loaded 2-core machine), so a LocalCluster has ``threads_per_worker=1``
and parallelism comes from processes.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from lfm_studio.engine.batch.extras import require_scale

require_scale()

from distributed import Client, LocalCluster  # noqa: E402


def check_placement(client: Client | None, workers: int | None, scheduler: str | None) -> None:
    """Refuse contradictory or invalid ``client``/``workers``/``scheduler`` (before any work starts)."""
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ValueError(f"workers must be an integer >= 1; got {workers!r}. Fix: e.g. workers=2.")
    if client is not None and (workers is not None or scheduler is not None):
        raise ValueError("pass either client or workers/scheduler, not both. Fix: drop workers/scheduler.")
    if workers is not None and scheduler is not None:
        raise ValueError(
            f"workers={workers} and scheduler={scheduler!r} both given; a remote cluster has its "
            "own workers. Fix: pass one of them."
        )


def get_client(workers: int | None = None, scheduler: str | None = None) -> Client | None:
    """A Dask client, or None for in-process work.

    ``scheduler="tcp://host:8786"``: connect to that cluster (``workers`` must be None);
    ``workers`` N > 1: a new ``LocalCluster(n_workers=N, threads_per_worker=1)`` (closed with
    the client: ``client.close(); client.cluster.close()``, or use :func:`client_for`);
    ``workers`` None or 1: None, meaning the synchronous scheduler in this process.
    """
    check_placement(None, workers, scheduler)
    if scheduler is not None:
        return Client(scheduler)
    if workers is None or workers == 1:
        return None
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0")
    return Client(cluster)


@contextlib.contextmanager
def client_for(
    client: Client | None, workers: int | None = None, scheduler: str | None = None
) -> Iterator[Client | None]:
    """``client`` when given, else :func:`get_client` (closed on exit, its LocalCluster too)."""
    check_placement(client, workers, scheduler)
    if client is not None:
        yield client
        return
    owned = get_client(workers, scheduler)
    try:
        yield owned
    finally:
        if owned is not None:
            cluster = owned.cluster
            owned.close()
            if cluster is not None and scheduler is None:
                cluster.close()


def dashboard_link(client: Client | None) -> str | None:
    """The Dask dashboard address of ``client`` (None in-process or without one)."""
    if client is None:
        return None
    try:
        return client.dashboard_link or None
    except (AttributeError, KeyError):
        return None
