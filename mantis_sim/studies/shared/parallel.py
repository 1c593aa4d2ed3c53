"""Work beyond one process: a Dask cluster (local or given) and a progress line.

The local cluster runs one single-threaded worker process per core and listens on 127.0.0.1
only; a cluster given by address (``tcp://HOST:PORT``) is checked for reachability first, so a
wrong address fails at once rather than after the client's retries.
"""
from __future__ import annotations

from collections.abc import Callable
import os
import socket
import sys
import time

from mantis_sim.errors import InputError
from mantis_sim.studies.shared.blas import one_blas_thread

CONNECT_TIMEOUT_S = 10.0


class ClusterError(InputError):
    """The cluster cannot be reached as asked (names the address and the problem)."""


class Progress:
    """One line on stderr, rewritten: designs done of all, rate, time left."""

    def __init__(self, total: int, already: int = 0, stream=sys.stderr, unit: str = 'designs'):
        self.total, self.done, self.stream, self.unit = total, already, stream, unit
        self.start = time.monotonic()
        self.first = already
        self._last = 0.0

    def advance(self, n: int) -> None:
        self.done += n
        now = time.monotonic()
        if now - self._last >= 0.2 or self.done >= self.total:
            self._last = now
            rate = (self.done - self.first) / max(now - self.start, 1e-9)
            left = (self.total - self.done) / rate if rate > 0 else float('inf')
            width = 30
            filled = int(width * self.done / max(self.total, 1))
            self.stream.write(f'\r[{"#" * filled}{"." * (width - filled)}] {self.done}/'
                              f'{self.total} {self.unit}, {rate:.0f}/s, {left:.0f} s left ')
            self.stream.flush()

    def close(self) -> None:
        self.stream.write('\n')
        self.stream.flush()


def connect(scheduler: str | None, workers: int | None):
    """(client, cluster or None, description) of the cluster to use, each worker with the fast
    engine loaded (or compiled, the first time on its machine) before any work is timed."""
    from mantis_sim.fast import warm_up
    client, cluster, where = _connect(scheduler, workers)
    if cluster is not None:
        client.run(_leave_interrupts_to_the_parent)
    client.run(warm_up)
    return client, cluster, where


def _leave_interrupts_to_the_parent() -> None:
    """A local cluster's workers share the terminal's Ctrl-C with the command that started
    them, and each printed a KeyboardInterrupt traceback beside its one line; they ignore it
    instead, and the command closes the cluster as it stops."""
    import signal
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:          # not the worker's main thread: leave it as it is
        pass


def _connect(scheduler: str | None, workers: int | None):
    from dask.distributed import Client, LocalCluster
    if scheduler is not None:
        check_reachable(scheduler)
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError, ValueError) as exc:
            raise ClusterError(f'--scheduler {scheduler}: cannot reach the Dask scheduler '
                             f'({type(exc).__name__}: {exc})') from None
        return client, None, f'the Dask cluster at {scheduler}'
    n = workers or os.cpu_count() or 1
    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                           host='127.0.0.1', dashboard_address=None)
    return Client(cluster), cluster, 'a local Dask cluster'


def check_reachable(scheduler: str) -> None:
    """Refuse at once a scheduler address that is malformed or where nothing listens (dask's
    own client retries for its whole timeout first)."""
    from urllib.parse import urlsplit
    parts = urlsplit(scheduler)
    try:
        host, port = parts.hostname, parts.port
    except ValueError:
        host = port = None
    if parts.scheme != 'tcp' or not host or not port:
        raise ClusterError(f'--scheduler {scheduler}: expected tcp://HOST:PORT')
    try:
        socket.create_connection((host, port), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as exc:
        raise ClusterError(f'--scheduler {scheduler}: cannot reach the Dask scheduler '
                         f'({exc.strerror or exc})') from None




def _batch(function: Callable, items: list) -> list:
    """[function(item) for item in items]: one task of a map, on a worker."""
    one_blas_thread()
    return [function(item) for item in items]


# A map goes out in batches, at least this many per worker (so that the load balances and the
# workers end together) and at most MAX_BATCH items each: a strike of the fast path costs a few
# ms, a task of Dask about one, and one item per task spent more time scheduling than computing.
BATCHES_PER_WORKER = 4
MAX_BATCH = 64


class ClusterMap:
    """``map(function, items)`` -> results in order, on a Dask cluster (``workers`` local worker
    processes, default one per core, or the cluster at ``scheduler``), or in this process with
    ``workers=0``; a progress line on stderr counts the items done. Use as a context manager."""

    def __init__(self, scheduler: str | None = None, workers: int | None = None,
                 progress: bool = True, unit: str = 'strikes'):
        self.scheduler, self.workers, self.progress, self.unit = (scheduler, workers, progress,
                                                                  unit)
        self.client = self.cluster = None
        self.where = 'this process'

    def __enter__(self) -> ClusterMap:
        if self.scheduler is not None or self.workers != 0:
            self.client, self.cluster, self.where = connect(self.scheduler, self.workers)
        return self

    def __exit__(self, *exc) -> None:
        if self.client is not None:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()

    @property
    def worker_count(self) -> int:
        if self.client is None:
            return 1
        return max(1, len(self.client.scheduler_info().get('workers', {})))

    def __call__(self, function: Callable, items: list) -> list:
        bar = Progress(len(items), unit=self.unit) if self.progress else None
        results: list = [None] * len(items)
        try:
            if self.client is None:
                one_blas_thread()                   # as on any worker (shared.blas)
                for i, item in enumerate(items):
                    results[i] = function(item)
                    if bar:
                        bar.advance(1)
                return results
            from dask.distributed import as_completed
            size = max(1, min(MAX_BATCH, -(-len(items) // (BATCHES_PER_WORKER
                                                            * self.worker_count))))
            starts = range(0, len(items), size)
            futures = [self.client.submit(_batch, function, items[i:i + size], pure=False)
                       for i in starts]
            first = {future.key: i for i, future in zip(starts, futures)}
            for future in as_completed(futures):
                batch = future.result()
                results[first[future.key]:first[future.key] + len(batch)] = batch
                if bar:
                    bar.advance(len(batch))
            return results
        finally:
            if bar:
                bar.close()


__all__ = ['ClusterError', 'ClusterMap', 'Progress', 'check_reachable', 'connect']
