"""The one worker core under :mod:`cardionurbs.parallel` (the ordered fork-map of one
analysis) and :mod:`cardionurbs.executor` (the task runner of a cohort or a phantom
cohort): how a worker process is started, watched, reaped and killed, and what ``jobs``
means.

- :func:`resolve_jobs`: one meaning of ``jobs`` everywhere -- a whole number >= 1, or
  None for every usable CPU (:func:`usable_cpus`); anything else is a ValueError.
- :func:`start`: a daemonic worker process and the parent's end of a pipe to it
  (``fork`` where the platform allows it, else ``spawn``: :func:`context`). Every worker
  first arms the **death-of-parent watch** (:func:`_watch_parent`): on Linux the kernel
  sends it SIGKILL when the thread that started it ends (``prctl(PR_SET_PDEATHSIG)``),
  and a watcher thread ends it within :data:`WATCH_INTERVAL_S` once its parent is
  gone (the parent's pid is recorded before the start, so a parent that died before
  the watch was armed is caught too). A ``kill -9`` of ``cardionurbs cohort --jobs 2``,
  of ``phantom --cohort ... --jobs 2`` or of ``analyze --jobs 2`` therefore leaves no
  worker behind a second later.
- :func:`stop`: end a worker (politely through its pipe, or killed), reap it and close
  the pipe; :func:`exit_text`: the one wording of how a worker ended.

PDEATHSIG is tied to the starting *thread*, so it is armed only for workers started
from the main thread (a worker started from a short-lived helper thread would be killed
when that thread ends); the watcher thread covers the others.
"""

from __future__ import annotations

import ctypes
import multiprocessing as mp
import os
import signal
import sys
import threading
import time
from typing import Any, Callable

#: seconds between two checks of the watcher thread for the parent being gone
WATCH_INTERVAL_S = 0.2
_PR_SET_PDEATHSIG = 1


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity mask; :func:`os.cpu_count` where the
    platform has no affinity).

    Returns
    -------
    int
        At least 1.
    """
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def resolve_jobs(jobs: int | None) -> int:
    """``jobs`` as a number of worker processes: None means :func:`usable_cpus`, a whole
    number >= 1 is itself (``True``, 0, 2.5 and negative numbers are refused).

    Parameters
    ----------
    jobs : int or None
        Worker processes asked for.

    Returns
    -------
    int
        At least 1."""
    if jobs is None:
        return usable_cpus()
    if isinstance(jobs, bool) or not isinstance(jobs, (int, float)) or int(jobs) != jobs \
            or jobs < 1:
        raise ValueError(f"jobs must be a whole number >= 1 (or None: every CPU), got {jobs!r}")
    return int(jobs)


def context(fork: bool = True):
    """The multiprocessing context of the workers: ``fork`` where it exists and is safe
    (not macOS, whose system frameworks do not survive a fork) and ``fork`` is asked for,
    else ``spawn``.

    Parameters
    ----------
    fork : bool, optional
        Ask for ``fork`` (default); ``False`` always gives ``spawn``.

    Returns
    -------
    multiprocessing.context.BaseContext
        The ``fork`` or the ``spawn`` context.
    """
    if fork and "fork" in mp.get_all_start_methods() and sys.platform != "darwin":
        return mp.get_context("fork")
    return mp.get_context("spawn")


def exit_text(exitcode: int | None) -> str:
    """How a worker ended, in words: ``killed by signal 9`` or ``exit code 7``.

    Parameters
    ----------
    exitcode : int or None
        :attr:`multiprocessing.Process.exitcode`: negative for a signal, None while running.

    Returns
    -------
    str
        ``"killed by signal N"`` or ``"exit code N"``.
    """
    if exitcode is not None and exitcode < 0:
        return f"killed by signal {-exitcode}"
    return f"exit code {exitcode}"


def _parent_gone(parent: int) -> bool:
    return os.getppid() != parent


def _watch_parent(parent: int, pdeathsig: bool) -> None:
    """In a new worker: end this process when ``parent`` (the pid that started it) ends."""
    if pdeathsig and sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):
            pass
    if _parent_gone(parent):             # died before the watch was armed
        os._exit(70)

    def watch() -> None:
        while True:
            time.sleep(WATCH_INTERVAL_S)
            if _parent_gone(parent):
                os._exit(70)
    threading.Thread(target=watch, name="cardionurbs-parent-watch", daemon=True).start()


def _child(parent: int, pdeathsig: bool, target: Callable, args: tuple) -> None:
    _watch_parent(parent, pdeathsig)
    target(*args)


def start(target: Callable[..., Any], args: tuple = (), *, ctx=None, duplex: bool = True,
          name: str = "cardionurbs-worker"):
    """Start a daemonic worker ``target(child_conn, *args)`` with the death-of-parent watch
    armed first; returns (process, the parent's end of the pipe). With ``duplex=False``
    the pipe carries messages from the worker to the parent only.

    Parameters
    ----------
    target : callable
        The worker's main function; its first argument is the worker's pipe end.
    args : tuple
        Its other arguments (inherited by a forked worker, pickled for a spawned one).
    ctx : multiprocessing context, optional
        Default :func:`context`.
    duplex : bool
        A two-way pipe (tasks in, results out) or one-way (results out).
    name : str
        The process name (shown by ``ps`` on some systems).

    Returns
    -------
    (multiprocessing.Process, multiprocessing.connection.Connection)"""
    ctx = ctx or context()
    sys.stdout.flush()
    sys.stderr.flush()
    if duplex:
        parent_end, child_end = ctx.Pipe()
    else:
        parent_end, child_end = ctx.Pipe(duplex=False)
    pdeathsig = threading.current_thread() is threading.main_thread()
    proc = ctx.Process(target=_child, args=(os.getpid(), pdeathsig, target, (child_end, *args)),
                       daemon=True, name=name)
    proc.start()
    child_end.close()
    return proc, parent_end


def stop(proc, conn, *, kill: bool = False, polite: Any = None, grace_s: float = 5.0) -> None:
    """End a worker and reap it: killed at once (``kill``), or sent ``polite`` (e.g. None,
    "no more tasks") through ``conn`` and killed if it has not ended after ``grace_s``
    seconds; then ``conn`` is closed.

    Parameters
    ----------
    proc : multiprocessing.Process
        The worker, as returned by :func:`start`.
    conn : multiprocessing.connection.Connection
        The parent's end of its pipe; closed on return.
    kill : bool, optional
        Kill the worker at once instead of asking it to end.
    polite : object, optional
        The message that asks the worker to end (default None).
    grace_s : float, optional
        Seconds to wait for the worker to end before it is killed (default 5).
    """
    if kill:
        if proc.is_alive():
            proc.kill()
    else:
        try:
            conn.send(polite)
        except (OSError, ValueError):
            proc.kill()
    proc.join(timeout=grace_s)
    if proc.is_alive():
        proc.kill()
        proc.join()
    conn.close()
