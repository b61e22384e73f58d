"""The heavy pages' lanes: the lot, board and reason pages' work in a worker process.

Their work is Python (JSON parsing, statistics, charts) that holds the GIL; in a thread of the
server it slows every other request, the line page first (issue 37).  In a worker process
(``spawn``: a fresh interpreter, never a fork of the threaded server) it has an interpreter of
its own.  ``HeavyLanes.run`` takes a module-level function and picklable arguments (the
server's ``WebSettings``: the worker opens the store read-only itself) and returns the page's
context, plain data pickled back.

The pool belongs to the application's lifespan: ``start`` at startup, ``close`` at shutdown,
so no worker outlives the server.  Without a lifespan (an application never started, such
as a TestClient used without ``with``), or where processes cannot be used, the work runs in a
thread as before.  A worker that dies is replaced; the request it was serving is answered
503 (errors.WorkerLost), the next one by the new worker.
"""
from __future__ import annotations

import asyncio
import logging
import multiprocessing
import pickle
import signal
import time
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any, TypeVar

from starlette.concurrency import run_in_threadpool

from .errors import WorkerLost

T = TypeVar("T")
log = logging.getLogger(__name__)
CLOSE_WAIT_S = 10.0  # at shutdown, how long a page being computed may take to finish


def _worker_init() -> None:
    # Ctrl-C reaches the whole process group: the server shuts its pool down in order, so the
    # workers leave SIGINT to it instead of dying mid-page with a KeyboardInterrupt traceback
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _warm() -> None:
    """Import what the pages need, so the first lot page does not wait for it."""
    from . import pages  # noqa: F401


def _call(fn: Callable[..., T], args: tuple[Any, ...]) -> T:
    """``fn(*args)`` in the worker; an exception the server could not unpickle (one whose
    constructor wants other arguments) would break the pool, so it comes back as a RuntimeError."""
    try:
        return fn(*args)
    except Exception as e:
        try:
            pickle.loads(pickle.dumps(e))
        except Exception:
            raise RuntimeError(f"{type(e).__name__}: {e}") from e
        raise


def _spawn_context() -> Any:
    """The ``spawn`` context, or None where this platform cannot start processes that way."""
    if "spawn" not in multiprocessing.get_all_start_methods():
        return None
    return multiprocessing.get_context("spawn")


class HeavyLanes:
    """``n`` lanes for the heavy pages: at most ``n`` run at once, in ``n`` worker processes once
    ``start``ed (in threads otherwise); more wait their turn on the event loop."""

    def __init__(self, n: int) -> None:
        self.n = max(1, n)
        self._turns = asyncio.Semaphore(self.n)  # a waiting request holds no thread and no worker
        self._pool: ProcessPoolExecutor | None = None
        self._worked = False  # a worker has answered once: processes work on this machine

    @property
    def in_processes(self) -> bool:
        return self._pool is not None

    def _new_pool(self) -> ProcessPoolExecutor | None:
        ctx = _spawn_context()
        if ctx is None:
            return None
        try:
            pool = ProcessPoolExecutor(self.n, mp_context=ctx, initializer=_worker_init)
            pool.submit(_warm).add_done_callback(self._answered)
        # no semaphores or /dev/shm (OSError, ImportError), or a process started while this one
        # is still being imported (RuntimeError): the server must still start
        except (OSError, ImportError, NotImplementedError, RuntimeError) as e:
            log.warning("heavy pages run in threads: no worker process (%s)", e)
            return None
        return pool

    def _answered(self, fut: Future[Any]) -> None:
        if not fut.cancelled() and not isinstance(fut.exception(), BrokenProcessPool):
            self._worked = True

    def start(self) -> None:
        """Start the workers (application startup); they import the pages meanwhile."""
        if self._pool is None:
            self._pool = self._new_pool()

    def close(self, wait_s: float = CLOSE_WAIT_S) -> None:
        """Stop the workers (application shutdown): queued pages are dropped, a page being computed
        gets ``wait_s`` to finish; a worker still busy then is terminated, so shutdown never hangs."""
        pool, self._pool = self._pool, None
        if pool is None:
            return
        # the executor has no public handle on its processes before Python 3.14 (terminate_workers)
        procs = list(getattr(pool, "_processes", {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        deadline = time.monotonic() + wait_s
        for p in procs:
            p.join(max(0.0, deadline - time.monotonic()))
            if p.is_alive():
                log.warning("heavy page worker %s still busy at shutdown: terminated", p.pid)
                p.terminate()
                p.join(5)

    def _replace(self, broken: ProcessPoolExecutor) -> None:
        if self._pool is not broken:  # another lane replaced it already
            return
        broken.shutdown(wait=False, cancel_futures=True)
        # a worker that never answered once cannot start here (e.g. a main module that cannot
        # be imported again): threads, as without a pool, rather than a 503 on every page
        self._pool = self._new_pool() if self._worked else None
        if self._pool is None:
            log.warning("heavy pages run in threads from now on: the worker process never started")

    def _submit(self, fn: Callable[..., T], args: tuple[Any, ...]) -> tuple[ProcessPoolExecutor, Future[T]] | None:
        """The pool and the work submitted to it (None: no pool, run it in a thread)."""
        pool = self._pool
        if pool is None:
            return None
        try:
            return pool, pool.submit(_call, fn, args)
        except BrokenProcessPool:  # a worker died between requests: this request did not break it
            self._replace(pool)
            return self._submit(fn, args)
        except RuntimeError:  # shut down meanwhile (application shutdown)
            return None

    async def run(self, fn: Callable[..., T], *args: Any) -> T:
        """``fn(*args)`` in a lane: a worker process (fn at module level, args picklable) or a thread."""
        async with self._turns:
            sent = self._submit(fn, args)
            if sent is None:
                return await run_in_threadpool(fn, *args)
            pool, fut = sent
            try:
                out = await asyncio.wrap_future(fut)
            except BrokenProcessPool as e:
                self._replace(pool)
                if self._pool is None:  # processes do not work here: this page in a thread too
                    return await run_in_threadpool(fn, *args)
                raise WorkerLost(f"the worker process of this page stopped ({e}); a new one has started: "
                                 "load the page again") from e
            self._worked = True
            return out
