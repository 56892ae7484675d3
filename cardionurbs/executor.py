"""Run one function over many inputs on local worker processes or on a Dask cluster,
with a per-task timeout, surviving workers that die.

:func:`run_tasks` calls ``fn(*args)`` for every ``args`` of a list and hands each
result to ``on_result(i, result)`` as soon as it is known (so the caller can write
it durably). A task that raises, runs longer than ``timeout`` seconds, or whose
worker process dies (a crash, ``os._exit``, the out-of-memory killer) ends as
``on_result(i, TaskFailure(...))``; the other tasks go on.

Executors:

- ``"processes"`` (default): ``jobs`` worker processes of this machine, each
  running one task at a time. A worker whose task overruns the timeout is killed
  and replaced; a worker that dies is replaced. Forked from this process where the
  platform allows (no re-import per worker).
- a Dask cluster (``dask="local"`` starts a ``LocalCluster`` of ``jobs``
  single-threaded worker processes on 127.0.0.1; ``dask="tcp://host:port"``
  connects to a running scheduler, e.g. one started by dask-jobqueue on SLURM or
  PBS). At most as many tasks are in flight as the cluster has worker threads, so
  a task starts when it is submitted and its timeout is measured from then; a
  worker holding an overrun task is restarted (its nanny starts a fresh process).
  A task whose worker dies is submitted once more (a worker can die under a task
  that did nothing wrong: the scheduler may have placed it beside a task that
  crashed the process, or on a worker being restarted for an overrun) and fails
  as ``worker died`` when its second worker dies too. The local cluster is
  started with ``distributed.scheduler.allowed-failures = 0`` so that this rule,
  not the scheduler's own retries, decides; set the same on a scheduler of your
  own.

Dask's worker diagnostics cost a CPU-bound, GIL-holding task like ours about a
quarter of its time: the statistical profiler samples the task thread's stack every
10 ms, and the event loop wakes 50 times a second (the blocked-loop check) and takes
the GIL from the task each time. :data:`WORKER_CONFIG` turns the profiler off and
slows those checks to once a second; the local cluster is started with it, and a
cluster of your own should be too (its workers' Dask config). Measured in
reports/benchmark-throughput.md.
"""

from __future__ import annotations

import os
import time
from collections import deque
from dataclasses import dataclass
from multiprocessing.connection import wait as wait_connections
from typing import Any, Callable, Sequence

from cardionurbs.workers import context, exit_text, resolve_jobs, start, stop

#: executor names accepted besides a Dask scheduler address
LOCAL = "processes"
#: submissions of a Dask task whose worker died before it is reported as ``worker died``
MAX_ATTEMPTS_KILLED = 2


#: Dask config for the workers that run studies: no statistical profiler (it samples the
#: task thread every 10 ms), and the event-loop tick, system monitor and memory monitor at
#: 1-5 s instead of 20-500 ms (each wake takes the GIL from the running task). Only the
#: dashboard's profile plots and the reaction time of the memory limit change.
WORKER_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.worker.memory.monitor-interval": "1s",
}


@dataclass(frozen=True)
class TaskFailure:
    """Why a task produced no result: ``kind`` is ``error``, ``timeout`` or ``worker died``.

    Parameters
    ----------
    kind : str
        ``"error"``, ``"timeout"`` or ``"worker died"``.
    message : str
        One line: the exception's message, the timeout in s, or how the worker ended.
    """

    kind: str
    message: str

    def __str__(self) -> str:
        return f"{self.kind}: {self.message}" if self.message else self.kind


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def run_tasks(fn: Callable[..., Any], tasks: Sequence[tuple], on_result: Callable[[int, Any], None],
              *, jobs: int | None = 1, dask: str | None = None, timeout: float | None = None) -> None:
    """Run ``fn(*tasks[i])`` for every i; ``on_result(i, result or TaskFailure)`` once per task,
    in completion order, in this process. ``fn`` must be importable by the workers.
    ``jobs``: worker processes (None: every usable CPU; :func:`cardionurbs.workers.resolve_jobs`).

    Parameters
    ----------
    fn : callable
        ``fn(*args)``, importable by name in the workers; its result must pickle.
    tasks : sequence of tuple
        The arguments of each task.
    on_result : callable
        ``on_result(i, result)`` with the task's result or a :class:`TaskFailure`; called
        once per task, in completion order, in this process.
    jobs : int or None, optional
        Worker processes (default 1; None: every usable CPU).
    dask : str or None, optional
        ``"local"`` or a scheduler address ``tcp://host:port``; None (default): local
        processes.
    timeout : float or None, optional
        Longest run of one task, in s (None: no limit).

    Raises
    ------
    ValueError
        ``timeout`` not > 0, or ``jobs`` not a whole number >= 1 or None.
    cardionurbs.errors.UsageError
        ``dask`` is not ``"local"`` or an address, or no scheduler answers there.
    """
    if not tasks:
        return
    if timeout is not None and not timeout > 0:
        raise ValueError(f"timeout must be > 0 seconds, got {timeout!r}")
    if dask:
        _run_dask(fn, tasks, on_result, jobs=resolve_jobs(jobs), address=dask, timeout=timeout)
    else:
        _run_processes(fn, tasks, on_result, jobs=jobs, timeout=timeout)


# ------------------------------------------------------------------ local processes
def _worker_loop(conn, fn) -> None:
    """Worker process: run tasks sent over ``conn`` until told to stop (None)."""
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:
            return
        i, args = msg
        try:
            out = fn(*args)
        except BaseException as exc:  # noqa: BLE001 - reported as the task's failure
            out = TaskFailure("error", f"{type(exc).__name__}: {_one_line(exc)}")
        try:
            conn.send((i, out))
        except (OSError, ValueError):
            return


class _Worker:
    """One task runner on the worker core (:func:`cardionurbs.workers.start`: daemonic,
    dies with this process)."""

    def __init__(self, ctx, fn) -> None:
        self.proc, self.conn = start(_worker_loop, (fn,), ctx=ctx, name="cardionurbs-task")
        self.task: int | None = None
        self.deadline = float("inf")

    def give(self, i: int, args: tuple, timeout: float | None) -> None:
        self.task = i
        self.deadline = time.monotonic() + timeout if timeout else float("inf")
        self.conn.send((i, args))

    def stop(self, kill: bool = False) -> None:
        stop(self.proc, self.conn, kill=kill, polite=None)


def _run_processes(fn, tasks, on_result, *, jobs: int | None, timeout: float | None) -> None:
    ctx = context()
    todo = deque(range(len(tasks)))
    workers = [_Worker(ctx, fn) for _ in range(max(1, min(resolve_jobs(jobs), len(tasks))))]
    try:
        for w in workers:
            if todo:
                i = todo.popleft()
                w.give(i, tasks[i], timeout)
        while any(w.task is not None for w in workers):
            busy = [w for w in workers if w.task is not None]
            wait_s = min(w.deadline for w in busy) - time.monotonic()
            ready = wait_connections([w.conn for w in busy] + [w.proc.sentinel for w in busy],
                                     timeout=None if wait_s == float("inf") else max(wait_s, 0.0))
            now = time.monotonic()
            for k, w in enumerate(workers):
                if w.task is None:
                    continue
                i, result = w.task, None
                if w.conn in ready or w.conn.poll():
                    try:
                        _, result = w.conn.recv()
                    except (EOFError, OSError):
                        result = None
                if result is None and (w.proc.sentinel in ready or not w.proc.is_alive()):
                    w.proc.join(timeout=1)
                    code = w.proc.exitcode
                    how = exit_text(code)
                    result = TaskFailure("worker died", f"worker process {how}" if code and code < 0
                                         else f"worker process ended with {how}")
                    w.stop(kill=True)
                    workers[k] = w = _Worker(ctx, fn)
                elif result is None and now >= w.deadline:
                    result = TaskFailure("timeout", f"no result after {timeout:g} s; worker stopped")
                    w.stop(kill=True)
                    workers[k] = w = _Worker(ctx, fn)
                if result is None:
                    continue
                w.task = None
                on_result(i, result)
                if todo:
                    j = todo.popleft()
                    w.give(j, tasks[j], timeout)
    finally:
        for w in workers:
            w.stop(kill=w.task is not None)


# ------------------------------------------------------------------ Dask
#: Dask address schemes a scheduler may be given by
DASK_SCHEMES = ("tcp", "tls", "ws", "wss", "ucx")
#: seconds to wait for a scheduler to accept a connection before giving up
DASK_CONNECT_TIMEOUT_S = 5.0


def _excerpt(text: str, n: int = 60) -> str:
    t = "".join(c if c.isprintable() else "?" for c in str(text))
    return repr(t[:n]) + (f"... ({len(t)} characters)" if len(t) > n else "")


def check_dask_address(address: str) -> tuple[str, int] | None:
    """``"local"`` (None) or ``scheme://host:port`` ((host, port)); UsageError otherwise,
    naming an excerpt of the address.

    Parameters
    ----------
    address : str
        The ``--dask`` value.

    Returns
    -------
    tuple of (str, int) or None
        None for ``"local"``, else the scheduler's (host, port).

    Raises
    ------
    cardionurbs.errors.UsageError
        Not ``"local"`` nor a ``scheme://host:port`` address of a Dask scheme.
    """
    from urllib.parse import urlsplit

    from cardionurbs.errors import UsageError
    if address == "local":
        return None
    hint = "expected 'local' or a scheduler address such as tcp://HOST:8786"
    try:
        u = urlsplit(address)
        port = u.port
    except ValueError:
        raise UsageError(f"--dask {_excerpt(address)}: not an address ({hint})") from None
    if u.scheme not in DASK_SCHEMES or not u.hostname or port is None or not 0 < port < 65536:
        raise UsageError(f"--dask {_excerpt(address)}: not an address ({hint})")
    return u.hostname, port


def _reach(address: str, host: str, port: int) -> None:
    """Fail fast (UsageError, one line) when nothing listens at ``host:port``."""
    import socket

    from cardionurbs.errors import UsageError
    try:
        socket.create_connection((host, port), timeout=DASK_CONNECT_TIMEOUT_S).close()
    except OSError as exc:
        raise UsageError(f"--dask {_excerpt(address)}: no scheduler answers there "
                         f"({exc.strerror or type(exc).__name__})") from None


def dask_client(address: str, jobs: int):
    """(client, cluster or None): a LocalCluster of ``jobs`` single-threaded worker processes
    on 127.0.0.1 for ``"local"``, else a client of the scheduler at ``address`` (checked to
    be an address, and to answer within :data:`DASK_CONNECT_TIMEOUT_S`).

    Parameters
    ----------
    address : str
        ``"local"`` or a scheduler address ``tcp://host:port``.
    jobs : int
        Worker processes of a local cluster (ignored for a scheduler of your own).

    Returns
    -------
    client : distributed.Client
        Connected to the cluster.
    cluster : distributed.LocalCluster or None
        The local cluster started here (to be closed by the caller), None for ``address``.

    Raises
    ------
    cardionurbs.errors.UsageError
        ``address`` is not an address, or no scheduler answers there within
        :data:`DASK_CONNECT_TIMEOUT_S` s.
    """
    target = check_dask_address(address)
    if target is not None and target[0] and address.startswith(("tcp", "ws")):
        _reach(address, *target)
    import dask
    from distributed import Client, LocalCluster

    if address == "local":
        with dask.config.set({"distributed.scheduler.allowed-failures": 0, **WORKER_CONFIG}):
            cluster = LocalCluster(n_workers=max(1, jobs), threads_per_worker=1, processes=True,
                                   host="127.0.0.1", dashboard_address=None)
        return Client(cluster), cluster
    return Client(address, timeout=f"{DASK_CONNECT_TIMEOUT_S * 2:g}s"), None


def _import_module(name: str) -> None:
    import importlib
    importlib.import_module(name)


def _run_dask(fn, tasks, on_result, *, jobs: int, address: str, timeout: float | None) -> None:
    from distributed import wait

    client, cluster = dask_client(address, jobs)
    try:
        # import the task's module on every worker first, so that no task's timeout pays it
        client.run(_import_module, fn.__module__)
        slots = max(1, sum(client.nthreads().values()))
        todo = deque(range(len(tasks)))
        inflight: dict = {}            # future -> (task index, deadline)
        token = f"{os.getpid()}-{time.time_ns()}"
        attempts = [0] * len(tasks)

        def submit(i: int) -> None:
            attempts[i] += 1
            fut = client.submit(fn, *tasks[i], key=f"cardionurbs-{token}-{i}-{attempts[i]}",
                                pure=False, retries=0)
            inflight[fut] = (i, time.monotonic() + timeout if timeout else float("inf"))

        while todo or inflight:
            while todo and len(inflight) < slots:
                submit(todo.popleft())
            soonest = min(d for _, d in inflight.values()) - time.monotonic()
            try:
                wait(list(inflight), return_when="FIRST_COMPLETED",
                     timeout=None if soonest == float("inf") else max(soonest, 0.01))
            except TimeoutError:           # a deadline passed: handled below
                pass
            now = time.monotonic()
            for fut in list(inflight):
                i, deadline = inflight[fut]
                if fut.done():
                    del inflight[fut]
                    if fut.status == "finished":
                        result = fut.result()
                    else:
                        exc = fut.exception()
                        name = type(exc).__name__
                        if name == "KilledWorker" and attempts[i] < MAX_ATTEMPTS_KILLED:
                            todo.appendleft(i)     # once more, on another worker
                            continue
                        kind = "worker died" if name == "KilledWorker" else "error"
                        result = TaskFailure(kind, f"{name}: {_one_line(exc)}")
                    on_result(i, result)
                elif now >= deadline:
                    del inflight[fut]
                    holders = [w for w, keys in client.processing().items() if fut.key in keys]
                    fut.cancel()
                    if holders:
                        try:
                            client.restart_workers(holders, timeout=60)
                        except Exception:  # noqa: BLE001 - best effort; the task is already lost
                            pass
                    on_result(i, TaskFailure("timeout", f"no result after {timeout:g} s; "
                                             "worker restarted"))
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
