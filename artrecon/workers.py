"""Worker processes that leave Ctrl-C to their parent.

A terminal's Ctrl-C sends SIGINT to the whole foreground process group: to the command and to
the worker processes it spawned (configuration B beside A). A worker that gets it while it is
still starting (importing, unpickling its task: seconds on a busy machine) prints its own
``KeyboardInterrupt`` traceback, outside any ``try`` of ours. So workers start with SIGINT
ignored (:func:`submit`: the disposition is inherited, and Python keeps an ignored SIGINT
ignored), the parent alone turns Ctrl-C into one line and exit status 130, and it stops its
workers at once (:func:`stop`) instead of waiting for their task to end.

A parent that is killed outright (SIGKILL, SIGTERM: a job scheduler, a timeout, ``kill``) runs
no code at all: its workers are made to die with it (:func:`pool`, Linux's parent-death signal),
instead of running on for minutes as orphans and competing for the cores.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import multiprocessing
import os
import signal
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor
from contextlib import contextmanager
from typing import TypeVar

import cv2
from threadpoolctl import threadpool_limits

log = logging.getLogger(__name__)

__all__ = ["die_with_parent", "interrupts_remembered", "pool", "raise_if_interrupted",
           "side_by_side", "single_threaded", "submit", "stop"]

A = TypeVar("A")
B = TypeVar("B")

#: prctl(2) option: the signal the calling process gets when its parent dies.
_PR_SET_PDEATHSIG = 1


def die_with_parent(parent: int) -> None:
    """Worker initializer (or a worker's first call): SIGKILL this process when its parent
    dies (Linux; elsewhere a no-op), and exit now if the parent is already gone (it died while
    this one started)."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):  # not Linux: orphans stay possible
        return
    if os.getppid() != parent:
        os._exit(1)


def _worker_start(parent: int) -> None:
    """Initializer of :func:`pool`'s workers: :func:`die_with_parent`, and a progress-bar lock
    of the worker's own.

    tqdm's first bar in a process, shown or not, creates a ``multiprocessing.RLock``: a named
    semaphore registered with the resource tracker this worker shares with its parent. A worker
    killed by :func:`stop` never unregisters it, and at the parent's exit the tracker printed
    "There appear to be 1 leaked semaphore objects to clean up" after the one "interrupted"
    line (test_faults, every time the interrupt came after the second capture's first bar).
    A worker's bars are its own (nothing shares them across processes): a thread lock serves."""
    die_with_parent(parent)
    from tqdm import tqdm
    tqdm.set_lock(threading.RLock())


def pool(max_workers: int = 1) -> ProcessPoolExecutor:
    """A process pool of spawned workers that die with this process and hold no semaphore of
    the resource tracker's (see the module doc and :func:`_worker_start`).

    Create it from the thread that lives as long as the pool: Linux sends the parent-death
    signal when the thread that started the worker ends."""
    return ProcessPoolExecutor(max_workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_worker_start, initargs=(os.getpid(),))


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


def processes(pool: ProcessPoolExecutor | None) -> list:
    """The worker processes a pool has started so far (none before its first submit, or
    without a pool): ``ProcessPoolExecutor`` keeps them in a private mapping."""
    return list((getattr(pool, "_processes", None) or {}).values())


def stop(pool: ProcessPoolExecutor) -> None:
    """Kill a pool's worker processes and shut it down without waiting for their tasks; used
    when the parent was interrupted. Their partial output is the parent's to discard (work
    folders, removed by the next run if not now).

    SIGKILL, not SIGTERM: importing pycolmap installs glog's failure signal handler, which
    answers SIGTERM with a 30-line native stack dump on stderr (the worker ends no cleaner
    for it: Python has no SIGTERM handler of its own here)."""
    for process in processes(pool):
        if process.is_alive():
            process.kill()
    # waits only for the pool's manager thread, which ends at once with its workers dead: left
    # running, it closed its wake-up pipe while the interpreter's exit hook wrote to it, and
    # Python 3.11 printed that hook's "Bad file descriptor" traceback after our one line
    pool.shutdown(wait=True, cancel_futures=True)


def side_by_side(task_a: Callable[[], A], task_b: Callable[[], B]) -> tuple[A, B]:
    """``(task_a(), task_b())``, ``task_b`` in a thread beside this one: for the two
    configurations' independent work after their stage (free space, image reads, the labelling
    cues) and for the two halves of independent work (the A x B retrieval's images, the
    segmentation's restarts), whose numpy, OpenCV and SciPy calls release the GIL. The tasks
    must not share mutable state; each gives what it gives alone (the results do not depend on
    the threads).
    Run it under one BLAS and one OpenCV thread per task (the machine has two cores). An
    exception of either task is raised here, ``task_a``'s first, after both ended."""
    with ThreadPoolExecutor(1, thread_name_prefix="artrecon-b") as ex:
        future = ex.submit(task_b)
        try:
            a = task_a()
        except BaseException:
            future.cancel()
            raise
        return a, future.result()


#: Set by the SIGINT handler of :func:`interrupts_remembered`.
_INTERRUPTED = threading.Event()


@contextmanager
def interrupts_remembered() -> Iterator[None]:
    """Ctrl-C raises KeyboardInterrupt as usual within the block, and is also remembered, for
    :func:`raise_if_interrupted` to raise it again: a library may swallow the exception (a
    capture interrupted in CI ran on to the end and published its images, exit status 0; where
    it was lost is not known: PyOpenGL, which reports an interrupt in its argument conversion as
    a ``ctypes.ArgumentError``, an ``Exception``, is the likely place).

    Only in the main thread of a process that takes Ctrl-C (not in workers, which ignore it:
    :func:`submit`); elsewhere the block runs unchanged."""
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler):
        yield
        return

    def remember(signum, frame):
        _INTERRUPTED.set()
        raise KeyboardInterrupt

    _INTERRUPTED.clear()
    previous = signal.signal(signal.SIGINT, remember)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def raise_if_interrupted() -> None:
    """KeyboardInterrupt if Ctrl-C came within :func:`interrupts_remembered`'s block, whether or
    not its exception got through: call it where a run commits (before it publishes a result),
    and between units of work."""
    if _INTERRUPTED.is_set():
        raise KeyboardInterrupt


@contextmanager
def single_threaded() -> Iterator[None]:
    """One BLAS thread and one OpenCV thread per calling thread, for a block whose work is run
    side by side (:func:`side_by_side`) or made of small products (points by 3 x 3 rotations:
    a second OpenBLAS thread costs 40 ms of CPU per 150k points instead of 1 ms). The results
    are those of the libraries' one-thread code (products of large float32 matrices may
    differ from their multithreaded result in the last bit)."""
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        with threadpool_limits(limits=1, user_api="blas"):
            yield
    finally:
        cv2.setNumThreads(threads)
