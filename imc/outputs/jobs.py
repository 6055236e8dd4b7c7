"""Where a run's drawing and recording jobs run: inline, or on one helper process.

The figures (matplotlib) and the Rerun recording need nothing of the renderer, only arrays
and the files already in the run folder, and their imports alone take ~0.9 s. On a helper
process started with the run (``spawn``: a fresh interpreter, no fork of the renderer's
threads) those imports overlap the loop, and the drawing overlaps the main imager's renders
in the main process. :class:`InlineJobs` runs each job when it is submitted, in order: what
sweeps and tests use (a sweep's workers are already parallel). Both give the same files.
"""

from __future__ import annotations

import contextlib
import os
import signal
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from typing import Any, Protocol


class Jobs(Protocol):
    """Runs jobs (picklable functions of picklable arguments) and hands back their results."""

    def submit(self, fn: Callable[..., Any], *args: Any) -> int:
        """Queue ``fn(*args)``; returns its ticket for :meth:`result`."""

    def result(self, ticket: int) -> Any:
        """The job's return value (waiting for it); re-raises what it raised."""

    def close(self, cancel: bool = False) -> None:
        """Wait for what is queued (its failures are for :meth:`result`) and stop; with
        ``cancel`` (the run failed) drop what is queued and stop a helper at once."""


@dataclass
class InlineJobs:
    """Each job runs in this process when it is submitted."""

    _done: list[tuple[bool, Any]] = field(default_factory=list)

    def submit(self, fn: Callable[..., Any], *args: Any) -> int:
        try:
            self._done.append((True, fn(*args)))
        except Exception as e:  # kept for result(), as a helper process would
            self._done.append((False, e))
        return len(self._done) - 1

    def result(self, ticket: int) -> Any:
        ok, value = self._done[ticket]
        if not ok:
            raise value
        return value

    def close(self, cancel: bool = False) -> None:
        pass


def _exit_with_parent() -> None:
    """End this helper when the process that started it ends, however it ends (a killed
    run would otherwise leave its helper waiting on its queue for ever): a thread waits
    on the parent's sentinel, which multiprocessing keeps open for the parent's lifetime."""
    import multiprocessing
    import os
    import threading
    from multiprocessing.connection import wait

    parent = multiprocessing.parent_process()
    if parent is None:
        return

    def watch() -> None:
        wait([parent.sentinel])
        os._exit(1)

    threading.Thread(target=watch, name="imc-helper-parent-watch", daemon=True).start()


def _warm(pid_conn=None) -> None:
    """The helper's imports, its first drawing (fonts, the Agg canvas, the PNG writer) and
    first recording, made while the main process runs the loop; and its exit without a
    teardown (what it writes is written atomically and its results are sent when each job
    ends). First of all it sends its PID through ``pid_conn`` (the write end of a pipe), so
    that the main process can stop it without reaching into the pool."""
    import atexit
    import io
    import os
    import signal

    if pid_conn is not None:
        pid_conn.send(os.getpid())
        pid_conn.close()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the run's to report, in a line
    _exit_with_parent()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    import rerun  # noqa: F401
    import scipy.fft  # noqa: F401  (the figures' spectra)
    import scipy.linalg  # noqa: F401

    import imc.outputs.figures  # noqa: F401
    from imc.outputs.rerun_log import warm_up

    warm_up()

    fig, ax = plt.subplots(figsize=(2, 2), dpi=50)
    ax.imshow(np.zeros((4, 4)), cmap="gray")
    ax.semilogy([1.0, 2.0], [1.0, 10.0], label="warm")
    ax.legend()
    ax.set_title("warm")
    fig.tight_layout()
    fig.savefig(io.BytesIO(), format="png")
    plt.close(fig)
    atexit.register(os._exit, 0)  # runs first: the imports' own exit handlers are older


def _ready() -> bool:
    return True


class ProcessJobs:
    """Jobs on one helper process, in the order submitted; a job the helper could not finish
    because the process died is run again inline."""

    def __init__(self) -> None:
        import multiprocessing

        ctx = multiprocessing.get_context("spawn")
        # the helper sends its PID back first thing (see _warm): close(cancel=True) stops it
        self._pid_conn, pid_send = ctx.Pipe(duplex=False)
        self._helper_pid: int | None = None
        self._helper_gone = False  # seen to have died (BrokenProcessPool)
        self._pool = ProcessPoolExecutor(max_workers=1, initializer=_warm, initargs=(pid_send,),
                                         mp_context=ctx)
        self._jobs: list[tuple[Callable[..., Any], tuple, Future]] = []
        try:
            self._pool.submit(_ready)  # start the helper (and its imports) now
        except BaseException:
            self._pool.shutdown(wait=False)
            self._pid_conn.close()
            raise
        finally:
            pid_send.close()  # the helper holds its own copy: its end alone keeps it open

    def submit(self, fn: Callable[..., Any], *args: Any) -> int:
        try:
            fut = self._pool.submit(fn, *args)
        except (BrokenProcessPool, RuntimeError):  # the helper is gone: run it here, after
            self._helper_gone = True
            self._settle(len(self._jobs) - 1)  # the jobs before it that it did not finish
            fut = _run_here(fn, args)
        self._jobs.append((fn, args, fut))
        return len(self._jobs) - 1

    def result(self, ticket: int) -> Any:
        self._settle(ticket)
        return self._jobs[ticket][2].result()

    def _settle(self, last: int) -> None:
        """Run here, in order, the jobs up to ``last`` that the helper could not finish
        (it died): a later job may need what an earlier one writes."""
        for i in range(last + 1):
            fn, args, fut = self._jobs[i]
            try:
                fut.result()
            except BrokenProcessPool:
                self._helper_gone = True
                self._jobs[i] = (fn, args, _run_here(fn, args))
            except Exception:  # noqa: BLE001 (the job's own failure, for result())
                pass

    def _pid(self, timeout_s: float) -> int | None:
        """The helper's PID, waiting up to ``timeout_s`` (s) for it to send it; None if it
        ended (or never started) without sending it."""
        if self._helper_pid is None and not self._pid_conn.closed:
            try:
                if self._pid_conn.poll(timeout_s):
                    self._helper_pid = int(self._pid_conn.recv())
            except (EOFError, OSError):  # it ended before sending its PID
                pass
            self._pid_conn.close()
        return self._helper_pid

    def close(self, cancel: bool = False) -> None:
        if cancel:  # the run failed: nothing it queued is wanted, the helper is stopped now
            pid = self._pid(timeout_s=30.0)  # its first act: seconds at most, unless it died
            if pid is not None and not self._helper_gone:  # a dead helper's PID may be reused
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGTERM)
        self._pool.shutdown(wait=True, cancel_futures=cancel)
        if not self._pid_conn.closed:
            self._pid_conn.close()


def _run_here(fn: Callable[..., Any], args: tuple) -> Future:
    """A finished future of ``fn(*args)`` run in this process."""
    fut: Future = Future()
    try:
        fut.set_result(fn(*args))
    except Exception as e:  # noqa: BLE001 (kept for result())
        fut.set_exception(e)
    return fut


def make_jobs(parallel: bool) -> Jobs:
    """:class:`ProcessJobs` when ``parallel`` and a helper process can be started here,
    else :class:`InlineJobs` (a daemonic process, such as a pool's worker, may not start
    one; nor may a system without the semaphores multiprocessing needs)."""
    if not parallel:
        return InlineJobs()
    try:
        return ProcessJobs()
    except (AssertionError, OSError, ImportError, RuntimeError):
        return InlineJobs()
