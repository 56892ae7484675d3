"""Independent per-frame work of one analysis on forked worker processes.

:func:`fork_map` computes ``fn(item)`` for a list of items (frames) and returns the
results in the items' order, as ``[fn(x) for x in items]`` would. Items named in
``here`` run in this process (what they leave in this process's objects, e.g. a
model's caches, stays); the others run in ``jobs`` worker processes forked from this
one, which therefore see every object of this process as it was at the fork (a
reconstructed model is not pickled). Only their results come back (pickled through a
pipe), so ``fn`` must return everything the caller needs from them, and the caller
merges it.

- Workers take the next item in order from a shared counter (items of unequal cost
  balance themselves); this process runs its ``here`` items meanwhile, then collects.
  :class:`ForkMap` starts the workers at once and collects later, so that this process
  can do other work in between.
- An exception in a worker is raised here, with its type and message (and the worker's
  traceback as its ``__cause__``); as in a serial loop, it is the exception of the first
  failing item in the items' order (the counter stops; items handed out before the
  failing one finish). A worker that dies without a result (a signal, the out-of-memory
  killer) raises :class:`WorkerDied`. Every worker has ended when :func:`fork_map`
  returns or raises.
- It runs serially (``[fn(x) for x in items]`` in this process) when ``jobs`` is 1,
  when only one process would work (one item, or one item and none here), where ``fork``
  is not available (Windows; macOS, where forking a process that has used system
  frameworks is unsafe), and in a daemonic process: a cohort's worker processes (:mod:`cardionurbs.executor`) and Dask's
  are daemonic, cannot have children, and already keep every core busy.
- Workers leave with ``os._exit`` (no ``atexit`` handlers, no flushing of buffers
  copied from this process; :mod:`multiprocessing`'s fork start method), ignore SIGINT
  (Ctrl-C interrupts this process, which then stops them) and take SIGTERM's default
  action. Fork copies only the forking thread; numpy's OpenBLAS shuts its thread pool
  down around ``fork`` (``pthread_atfork``) and a worker starts its own on first use,
  so a worker cannot inherit a held BLAS lock. The CLI runs BLAS on one thread
  (``cardionurbs.cli.one_blas_thread``), so ``jobs`` workers use ``jobs`` cores.
"""

from __future__ import annotations

import gc
import multiprocessing as mp
import os
import pickle
import signal
import sys
import traceback
from multiprocessing.connection import wait as wait_connections
from typing import Any, Callable, Collection, Sequence, TypeVar

from cardionurbs.errors import RemoteTraceback, WorkerDied
from cardionurbs.workers import exit_text, resolve_jobs, start, usable_cpus

T = TypeVar("T")
R = TypeVar("R")


__all__ = ["ForkMap", "RemoteTraceback", "WorkerDied", "can_fork", "fork_map", "usable_cpus",
           "worker_count"]


def can_fork() -> bool:
    """True where :func:`fork_map` may start workers: ``fork`` exists (not Windows, not
    macOS) and this process is not daemonic (a cohort or Dask worker).

    Returns
    -------
    bool
        Whether workers may be forked here.
    """
    return ("fork" in mp.get_all_start_methods() and sys.platform != "darwin"
            and not mp.current_process().daemon)


def worker_count(jobs: int | None, n_items: int, n_here: int = 0) -> int:
    """Worker processes :func:`fork_map` starts for ``n_items`` items given to workers
    beside ``n_here`` items of this process: ``jobs`` (None: :func:`usable_cpus`) capped by
    ``n_items``; 0 (serial) when ``jobs`` is 1, when fewer than two processes would work
    (one worker and nothing here) or when :func:`can_fork` is False. Raises ValueError for
    ``jobs`` < 1.

    Parameters
    ----------
    jobs : int or None
        Worker processes asked for (None: :func:`usable_cpus`; 1: serial).
    n_items : int
        Items that would go to workers.
    n_here : int, optional
        Items run in this process meanwhile (default 0).

    Returns
    -------
    int
        Worker processes to start; 0 means run serially in this process.

    Raises
    ------
    ValueError
        ``jobs`` is not a whole number >= 1 or None.
    """
    jobs = resolve_jobs(jobs)
    n = min(jobs, n_items)
    return n if jobs >= 2 and n + (n_here > 0) >= 2 and can_fork() else 0


def fork_map(fn: Callable[[T], R], items: Sequence[T], *, jobs: int | None = None,
             here: Collection = (), on_result: Callable[[int, R], None] | None = None) -> list[R]:
    """``[fn(x) for x in items]``, the items not in ``here`` computed by forked workers
    (module docstring). ``jobs``: worker processes (None: the usable CPUs; 1: serial).
    ``on_result(i, result)`` is called in this process as each item's result arrives (in
    arrival order; e.g. progress).

    Parameters
    ----------
    fn : callable
        ``fn(item) -> result``; its result must pickle (it comes back through a pipe).
    items : sequence
        The inputs, e.g. frame indices (0-based).
    jobs : int or None, optional
        Worker processes (None: the usable CPUs; 1: serial).
    here : collection, optional
        Items run in this process (what they leave in its objects stays).
    on_result : callable, optional
        ``on_result(i, result)``, called in this process as item ``i``'s result arrives.

    Returns
    -------
    list
        ``fn(x)`` for every item, in the items' order.

    Raises
    ------
    cardionurbs.errors.WorkerDied
        A worker ended without sending its results (a signal, the out-of-memory killer).
    Exception
        The first failing item's exception (type and message), with the worker's traceback
        as its ``__cause__`` (:class:`~cardionurbs.errors.RemoteTraceback`).
    """
    return ForkMap(fn, items, jobs=jobs, here=here).results(on_result)


class ForkMap:
    """:func:`fork_map` started now and collected later: the workers are forked (and start
    on their items) when this is made, while this process goes on with other work;
    :meth:`results` then runs the ``here`` items and collects. Serially (see
    :func:`fork_map`) every item runs in :meth:`results`. A ForkMap whose results are not
    wanted must be cancelled (:meth:`cancel`, or leave its ``with`` block): its workers are
    then killed.

    A worker keeps its results until it has no item left and then sends them all (so that
    it does not wait on a full pipe while this process is busy elsewhere).

    Parameters
    ----------
    fn : callable
        ``fn(item) -> result`` (picklable result).
    items : sequence
        The inputs, e.g. frame indices.
    jobs : int or None, optional
        Worker processes (None: the usable CPUs; 1: serial).
    here : collection, optional
        Items run in this process by :meth:`results`.

    Attributes
    ----------
    workers : int
        Worker processes started (0: serial).
    """

    def __init__(self, fn: Callable[[T], R], items: Sequence[T], *, jobs: int | None = None,
                 here: Collection = ()) -> None:
        self.fn, self.items = fn, list(items)
        self.mine = [i for i, x in enumerate(self.items) if x in here]
        theirs = [i for i, x in enumerate(self.items) if x not in here]
        n = worker_count(jobs, len(theirs), len(self.mine))
        self.workers = n
        self._pool = _Pool(fn, self.items, theirs, n) if n else None
        self._open = True

    def results(self, on_result: Callable[[int, R], None] | None = None) -> list[R]:
        """The results in the items' order (see :func:`fork_map`); once.

        Parameters
        ----------
        on_result : callable, optional
            ``on_result(i, result)``, called in this process as item ``i``'s result arrives.

        Returns
        -------
        list
            ``fn(x)`` for every item, in the items' order.

        Raises
        ------
        RuntimeError
            Called a second time, or after :meth:`cancel`.
        cardionurbs.errors.WorkerDied
            A worker ended without sending its results.
        """
        if not self._open:
            raise RuntimeError("ForkMap results already collected or cancelled")
        self._open = False
        if self._pool is not None:
            return self._pool.run(self.mine, on_result)
        out = []
        for i, x in enumerate(self.items):
            out.append(self.fn(x))
            if on_result is not None:
                on_result(i, out[-1])
        return out

    def cancel(self) -> None:
        """Kill the workers and forget the results (nothing when already collected)."""
        if self._open and self._pool is not None:
            self._pool.abort()
        self._open = False

    def __enter__(self) -> "ForkMap":
        return self

    def __exit__(self, *exc) -> None:
        self.cancel()


# ------------------------------------------------------------------ the workers
_UNSET = object()


class _Pool:
    def __init__(self, fn, items, theirs, n_workers) -> None:
        self.fn, self.items, self.theirs = fn, items, theirs
        self.ctx = mp.get_context("fork")
        self.next = self.ctx.Value("l", 0)          # index into theirs of the next item to hand out
        self.results: list = [_UNSET] * len(items)
        self.errors: dict[int, BaseException] = {}
        self.stopped_at: int | None = None          # items handed out when the counter was stopped
        self.procs: list = []
        self.conns: list = []
        for _ in range(n_workers):              # the worker core: watched, daemonic
            p, parent_end = start(_work, (fn, items, theirs, self.next), ctx=self.ctx,
                                  duplex=False, name="cardionurbs-frames")
            self.procs.append(p)
            self.conns.append(parent_end)

    def run(self, mine: list[int], on_result) -> list:
        try:
            for i in mine:                          # this process's items, meanwhile
                self.results[i] = self.fn(self.items[i])
                if on_result is not None:
                    on_result(i, self.results[i])
            self._collect(on_result)
        except BaseException:
            self.abort()
            raise
        self._stop(kill=bool(self.errors))
        if self.errors:
            first = min(self.errors)
            raise self.errors[first]
        return self.results

    def _collect(self, on_result) -> None:
        live = dict(zip(self.conns, self.procs))
        dead = []
        while live:
            for conn in wait_connections(list(live)):
                try:
                    msg = conn.recv()
                except (EOFError, OSError):      # the worker has ended
                    proc = live.pop(conn)
                    proc.join()
                    if proc.exitcode != 0:
                        dead.append(proc.exitcode)
                        self._hand_out_no_more()
                    continue
                i, ok, payload = msg
                if ok:
                    self.results[i] = payload
                    if on_result is not None:
                        on_result(i, payload)
                else:
                    self.errors[i] = _rebuilt(*payload)
                    self._hand_out_no_more()
        if dead:                                    # the items handed out and never reported
            handed = self.theirs[:self.stopped_at]
            lost = [i for i in handed if self.results[i] is _UNSET and i not in self.errors]
            code = dead[0]
            how = exit_text(code)
            what = f" before reporting item {self.items[lost[0]]!r}" if lost else ""
            self.errors[lost[0] if lost else len(self.items)] = WorkerDied(
                f"a worker process died ({how}){what}")

    def abort(self) -> None:
        """Hand out no more items and kill the workers."""
        self._hand_out_no_more()
        self._stop(kill=True)

    def _hand_out_no_more(self) -> None:
        """Set the shared counter past the last item (a worker that died holding the
        counter's lock cannot block this process: the value is set after 5 s regardless)."""
        lock = self.next.get_lock()
        got = lock.acquire(timeout=5)
        try:
            if self.stopped_at is None:
                self.stopped_at = self.next.value
            self.next.value = max(self.next.value, len(self.theirs))
        finally:
            if got:
                lock.release()

    def _stop(self, kill: bool) -> None:
        for p in self.procs:
            if kill and p.is_alive():
                p.kill()
        for p in self.procs:
            p.join()
        for c in self.conns:
            c.close()


def _work(conn, fn, items, theirs, counter) -> None:
    """A worker: take the next item index from ``counter`` until none is left, then send
    ``(i, True, fn(item))`` of each; on an exception, stop handing out items (the counter
    set past the end) and send the results so far and ``(i, False, exception)``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    gc.freeze()                      # the inherited objects: not traversed (nor copied) by gc
    done = []
    failed = None
    while True:
        with counter.get_lock():
            k = counter.value
            if k >= len(theirs):
                break
            counter.value = k + 1
        i = theirs[k]
        try:
            done.append(pickle.dumps((i, True, fn(items[i])), protocol=pickle.HIGHEST_PROTOCOL))
        except BaseException as exc:  # noqa: BLE001 - re-raised in the parent
            with counter.get_lock():
                counter.value = max(counter.value, len(theirs))
            failed = (i, False, _portable(exc))
            break
    for payload in done:
        conn.send_bytes(payload)
    if failed is not None:
        conn.send(failed)
    conn.close()


def _portable(exc: BaseException) -> tuple:
    """What the parent needs to raise ``exc`` again: (pickled exception or None, type name,
    message, formatted traceback)."""
    tb = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
    try:
        blob = pickle.dumps(exc, protocol=pickle.HIGHEST_PROTOCOL)
        pickle.loads(blob)
    except Exception:  # noqa: BLE001 - an exception that does not pickle: type and message
        blob = None
    return blob, f"{type(exc).__module__}.{type(exc).__qualname__}", str(exc), tb


def _rebuilt(blob, type_name: str, message: str, tb: str) -> BaseException:
    """The worker's exception (its traceback text as ``__cause__``)."""
    exc = None
    if blob is not None:
        try:
            exc = pickle.loads(blob)
        except Exception:  # noqa: BLE001
            exc = None
    if exc is None:
        exc = RuntimeError(f"{type_name}: {message}")
    exc.__cause__ = RemoteTraceback(f"\n\"\"\"\n(in a worker process)\n{tb}\"\"\"")
    return exc
