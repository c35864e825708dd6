"""Worker processes that live and die with the command that started them (``benchmark run``, ``batch``).

:func:`process_pool` is a spawn-context :class:`~concurrent.futures.ProcessPoolExecutor` whose workers

* die when their parent dies, whatever killed it (Linux: ``prctl(PR_SET_PDEATHSIG, SIGKILL)``; elsewhere a
  thread in the worker polls the parent's pid);
* ignore SIGINT: Ctrl-C in a terminal reaches the whole process group, and the parent alone stops the work;
* print warnings as the command line does (``warning: <message>`` lines, :mod:`seedmap.log`).

An exception leaving the ``with`` block (Ctrl-C, SIGTERM turned into an exception by the command line, an
error) kills the workers at once instead of waiting for their jobs. With every worker gone the
multiprocessing resource tracker sees its pipe close and exits too.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from typing import Callable, Iterator

from seedmap.log import cli_messages_forever

__all__ = ["process_pool"]

#: prctl option: the signal the kernel sends a process when its parent thread exits (linux/prctl.h)
PR_SET_PDEATHSIG = 1
#: seconds between two looks at the parent's pid where prctl is not available
PARENT_POLL_S = 1.0


def _watch_parent(parent: int) -> None:
    while True:
        time.sleep(PARENT_POLL_S)
        if os.getppid() != parent:  # re-parented: the parent is gone
            os._exit(1)


def _die_with_parent(parent: int) -> None:
    """End this process when ``parent`` ends (it may already have ended before we got here)."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            if libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0:
                if os.getppid() != parent:  # died between the spawn and the prctl call
                    os._exit(1)
                return
        except (OSError, AttributeError):  # no libc / no prctl: poll instead
            pass
    threading.Thread(target=_watch_parent, args=(parent,), name="seedmap-parent-watch", daemon=True).start()


def _init_worker(parent: int, initializer: Callable[[], None] | None) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _die_with_parent(parent)
    cli_messages_forever()
    if initializer is not None:
        initializer()


def _stop(pool: ProcessPoolExecutor) -> None:
    """Kill the workers now (their jobs are abandoned) and shut the pool down without waiting."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    for p in procs:
        try:
            p.kill()
        except (OSError, ValueError):  # already gone / already closed
            pass
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        try:
            p.join(timeout=5)
        except (OSError, ValueError, AssertionError):
            pass


@contextmanager
def process_pool(workers: int, initializer: Callable[[], None] | None = None) -> Iterator[ProcessPoolExecutor]:
    """A pool of ``workers`` spawned processes (not forked: GTSAM/torch state) that die with this process;
    ``initializer`` (a top-level function) runs once in each worker."""
    import multiprocessing as mp

    pool = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"), initializer=_init_worker,
                               initargs=(os.getpid(), initializer))
    try:
        yield pool
    except BaseException:
        _stop(pool)
        raise
    pool.shutdown(wait=True)
