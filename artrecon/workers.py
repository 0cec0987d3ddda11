"""Worker processes that leave Ctrl-C to their parent.

A terminal's Ctrl-C sends SIGINT to the whole foreground process group: to the command and to
the worker processes it spawned (configuration B beside A). A worker that gets it while it is
still starting (importing, unpickling its task: seconds on a busy machine) prints its own
``KeyboardInterrupt`` traceback, outside any ``try`` of ours. So workers start with SIGINT
ignored (:func:`submit`: the disposition is inherited, and Python keeps an ignored SIGINT
ignored), the parent alone turns Ctrl-C into one line and exit status 130, and it stops its
workers at once (:func:`stop`) instead of waiting for their task to end.
"""

from __future__ import annotations

import logging
import signal
import threading
from concurrent.futures import Future, ProcessPoolExecutor

log = logging.getLogger(__name__)

__all__ = ["submit", "stop"]


def submit(pool: ProcessPoolExecutor, fn, *args, **kwargs) -> Future:
    """``pool.submit(fn, *args, **kwargs)`` with SIGINT ignored while the pool starts its
    worker processes (they are started at the first submit), so they ignore Ctrl-C for good."""
    if threading.current_thread() is not threading.main_thread():
        return pool.submit(fn, *args, **kwargs)  # signals can only be set from the main thread
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        return pool.submit(fn, *args, **kwargs)
    finally:
        signal.signal(signal.SIGINT, previous)


def stop(pool: ProcessPoolExecutor) -> None:
    """Kill a pool's worker processes and shut it down without waiting for their tasks; used
    when the parent was interrupted. Their partial output is the parent's to discard (work
    folders, removed by the next run if not now).

    SIGKILL, not SIGTERM: importing pycolmap installs glog's failure signal handler, which
    answers SIGTERM with a 30-line native stack dump on stderr (the worker ends no cleaner
    for it: Python has no SIGTERM handler of its own here)."""
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        if process.is_alive():
            process.kill()
    # waits only for the pool's manager thread, which ends at once with its workers dead: left
    # running, it closed its wake-up pipe while the interpreter's exit hook wrote to it, and
    # Python 3.11 printed that hook's "Bad file descriptor" traceback after our one line
    pool.shutdown(wait=True, cancel_futures=True)
