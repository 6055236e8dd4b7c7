"""Where the points of a sweep (or the scenarios of ``imc check``) run: in this process one
after another, on a Dask LocalCluster of single-threaded worker processes, or on an existing
Dask scheduler.

A LocalCluster is ``processes=True, threads_per_worker=1`` with a memory limit per worker
(Dask's nanny restarts a worker past it; its task goes to another worker). An existing
cluster is reached by address: start one with ``dask scheduler`` and ``dask worker ADDRESS
--nthreads 1`` on each machine (imcsim installed there), or with dask-jobqueue on a batch
system (``SLURMCluster(...).scale(n)``, then pass ``cluster.scheduler_address``).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

#: environment of LocalCluster workers: one thread for every numeric library (Dask's nanny
#: already sets OMP / MKL / OpenBLAS), no telemetry from the Rerun SDK
WORKER_ENV = {"NUMBA_NUM_THREADS": "1", "RERUN_TELEMETRY_ENABLED": "0"}


def warm_up() -> str:
    """Import what a point needs (the pipeline, the loop's blocks, the correlator and its
    compiled kernels) in a worker before its first point, so the points' figures are the
    runs' own and the import cost is paid once, at the cluster's start. Returns the pid."""
    import imc.pipeline  # noqa: F401
    from compensation import registry  # noqa: F401
    from correlator import kernels  # noqa: F401

    return str(os.getpid())


class SchedulerError(RuntimeError):
    """The Dask scheduler cannot be reached or started; the message is one line."""


@dataclass(frozen=True)
class Task:
    """One unit of work: ``fn(*args)`` under ``key`` (unique in a batch)."""

    key: str
    fn: Callable
    args: tuple


class Lost(Exception):  # noqa: N818 (it is a result, not raised)
    """A task the cluster gave up on (its workers died), not an error of the task itself."""


def default_workers() -> int:
    """The cores this process may use (2 on the project's machines)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


class Runner:
    """Runs tasks and yields (key, result or exception) as each finishes."""

    description = "in process"
    n_workers = 1

    def run(self, tasks: Sequence[Task]) -> Iterator[tuple[str, object]]:
        for t in tasks:
            try:
                yield t.key, t.fn(*t.args)
            except Exception as e:  # the task's own error, handed back like Dask does
                yield t.key, e


class DaskRunner(Runner):
    """Tasks on a Dask distributed client (``pure=False``: a point never reuses a result)."""

    def __init__(self, client, description: str):
        self.client = client
        self.description = description

    @property
    def n_workers(self) -> int:
        return max(1, len(self.client.scheduler_info().get("workers", {})))

    def run(self, tasks: Sequence[Task]) -> Iterator[tuple[str, object]]:
        from distributed import as_completed
        from distributed.client import FutureCancelledError
        from distributed.scheduler import KilledWorker

        futures = {self.client.submit(t.fn, *t.args, key=t.key, pure=False): t.key
                   for t in tasks}
        try:
            for fut in as_completed(list(futures), loop=self.client.loop):
                key = futures[fut]
                try:
                    yield key, fut.result()
                except (KilledWorker, FutureCancelledError) as e:
                    yield key, Lost(f"{type(e).__name__}: {e}".splitlines()[0])
                except Exception as e:
                    yield key, e
                finally:
                    fut.release()
        finally:
            for fut in futures:
                fut.cancel()


@contextmanager
def runner(workers: int | None, scheduler: str | None = None,
           memory_limit: str = "auto", connect_timeout_s: float = 5.0) -> Iterator[Runner]:
    """A Runner: ``scheduler`` (an address) -> that cluster; ``workers`` 0 -> in process;
    otherwise a LocalCluster of ``workers`` (None: one per core) single-threaded processes,
    each limited to ``memory_limit`` (Dask's syntax: '4GiB', 'auto' = memory / workers)."""
    if scheduler is None and workers == 0:
        yield Runner()
        return
    from distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            client = Client(scheduler, timeout=f"{connect_timeout_s}s",
                            set_as_default=False)
        except (OSError, TimeoutError, ValueError) as e:
            raise SchedulerError(
                f"cannot reach the Dask scheduler at {scheduler} ({type(e).__name__}); start "
                "one with `dask scheduler` and `dask worker ADDRESS --nthreads 1`, or leave "
                "out --scheduler for a local cluster") from None
        try:
            try:
                client.run(warm_up)
            except ImportError as e:
                raise SchedulerError(f"the workers of {scheduler} cannot import imcsim ({e}); "
                                     "install imcsim in each worker's environment") from None
            yield DaskRunner(client, f"Dask scheduler {scheduler}")
        finally:
            client.close()
        return
    n = default_workers() if workers is None else int(workers)
    try:
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                               memory_limit=memory_limit, dashboard_address=":0",
                               silence_logs=logging.ERROR, env=dict(WORKER_ENV))
    except (OSError, ValueError, TypeError) as e:
        raise SchedulerError(f"cannot start a local Dask cluster of {n} workers "
                             f"(memory limit {memory_limit}): {e}".splitlines()[0]) from None
    client = Client(cluster, set_as_default=False)
    try:
        client.run(warm_up)
        yield DaskRunner(client, f"Dask LocalCluster: {n} worker processes x 1 thread, "
                         f"memory limit {memory_limit} each")
    finally:
        client.close()
        cluster.close()
