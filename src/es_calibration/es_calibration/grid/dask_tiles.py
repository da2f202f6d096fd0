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
from typing import Final

import dask
from dask.distributed import Client, LocalCluster

from es_calibration.grid.tiles import DaskSetupError, TileFit, TileJob, TileMap

#: Dask's nanny sets ``MALLOC_TRIM_THRESHOLD_=65536`` in a worker's environment before it
#: spawns it (so that freed memory goes back to the system). Setting it switches glibc's
#: dynamic mmap threshold off: every array above 128 KiB is then mmapped and unmapped, and a
#: tile fit's numpy temporaries fault their pages in afresh each time. Measured on the 48
#: tile fits (16 tiles, 3 maps) of a 64 x 64 x 1 min calibration in one worker: 6.2 M minor
#: faults and 18.9-22.5 s CPU (9.7-11.8 s of it system time) with it, 0.4 M and 11.2-13.3 s
#: without it, as in this process (11.2 s); the worker's peak RSS 289 and 292 MB. The local
#: cluster's workers run without it, like the serial path; Dask's BLAS/OpenMP thread limits
#: (1 per worker) stay.
_UNSET_IN_WORKERS: Final = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}


def _local_cluster(workers: int) -> tuple[LocalCluster, Client]:
    """Start a local cluster of ``workers`` single-threaded processes and its client.

    The workers get Dask's pre-spawn environment but ``MALLOC_TRIM_THRESHOLD_``
    (``_UNSET_IN_WORKERS``; one set in this process's environment is still inherited).

    Raises:
        DaskSetupError: the cluster cannot be started.

    """
    cluster: LocalCluster | None = None
    try:
        with dask.config.set(_UNSET_IN_WORKERS):  # read by each nanny when it is made
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
