"""Calibration tiles as tasks on Dask (``dask.distributed``): a local cluster or a scheduler.

Imported only when ``calibrate`` is given ``--workers`` or ``--scheduler``: a calibration
without them never imports Dask. Each tile (tiles.py) is one task that reads its own tile's
file of the store (tilestore.py): only the store's path and the tiling travel to the
workers, not arrays, so the work and the memory split between them; the store's directory
(under ``TMPDIR``) must be one the workers can read. The shared values are combined in this
process between the two passes.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager

from dask.distributed import Client, LocalCluster

from es_feedforward.calibration.tiles import DaskSetupError, TileFit, TileJob, TileMap


def _local_cluster(workers: int) -> tuple[LocalCluster, Client]:
    """Start a local cluster of ``workers`` single-threaded processes and its client.

    Raises:
        DaskSetupError: the cluster cannot be started.

    """
    cluster: LocalCluster | None = None
    try:
        cluster = LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.ERROR,
        )
        return cluster, Client(cluster)
    except (OSError, TimeoutError, ValueError, RuntimeError) as err:
        if cluster is not None:
            cluster.close()
        raise DaskSetupError(f"cannot use Dask (a local cluster of {workers} workers): {err}"
                             ) from None


@contextmanager
def dask_map(workers: int | None = None, scheduler: str | None = None) -> Iterator[TileMap]:
    """Yield a tile map running on Dask; close what was started on exit.

    A scheduler is reached at once (a wrong address fails before the calibration); a local
    cluster starts when the first tiles run: its processes would otherwise spend CPU on
    their event loops and heartbeats through the bag passes and the effect search.

    Args:
        workers: start a local cluster of this many single-threaded worker processes.
        scheduler: address of an existing scheduler (``tcp://host:port``); wins over
            ``workers``.

    Raises:
        DaskSetupError: the cluster cannot be started or the scheduler not reached.

    """
    started: list[tuple[LocalCluster | None, Client]] = []
    if scheduler:
        try:
            started.append((None, Client(scheduler, timeout="30s")))
        except (OSError, TimeoutError, ValueError) as err:
            raise DaskSetupError(f"cannot use Dask ({scheduler}): {err}") from None

    def run(fn: Callable[[TileJob], TileFit], jobs: Sequence[TileJob]) -> list[TileFit]:
        if not started:
            started.append(_local_cluster(workers or 1))
        client = started[0][1]
        futures = client.map(fn, list(jobs), pure=False)
        return list(client.gather(futures))

    try:
        yield run
    finally:
        for cluster, client in started:
            client.close()
            if cluster is not None:
                cluster.close()
