"""Where the runs of a sweep run (:mod:`sim.evaluate.sweep`): one task, and the backends.

A task (one run: its spec, output folders, the function that evaluates it) is executed by
:func:`execute` wherever it lands: in this process (:class:`_Inline`, ``jobs=1``), in a fresh
spawned worker process per run (:class:`_Local`, ``jobs=N``; the worker dies with its parent) or
as a Ray task (:class:`_Ray`). Each backend has ``capacity``, ``submit(task) -> handle``,
``wait(handles) -> [(handle, outcome)]`` (outcome: execute's dict, or ``status: "died"`` when the
worker ended without one) and ``close(cancel)``.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import multiprocessing.connection
import os
import signal
import socket
import sys
import time
import traceback
from pathlib import Path

from artrecon import workers
from sim.evaluate import pictures, report
from sim.evaluate.runner import run_meta

log = logging.getLogger(__name__)

#: The extra that brings Ray, as the error for a missing Ray names it.
RAY_EXTRA = 'pip install -e ".[ray]"'


class SweepError(RuntimeError):
    """A sweep cannot start (a missing backend, a cluster that cannot be reached, bad runs);
    the message says what to do."""


# ---------------------------------------------------------------------------- one task


def execute(task: dict) -> dict:
    """Run one task (one run) wherever it is: in this process, a worker process or a Ray worker.

    ``task``: ``spec`` (RunSpec), ``run_dir`` (its ``out_dir``), ``picture_dir``, ``report``
    (write the run's own results.json/md into ``run_dir``), ``log`` (a file that takes this
    process's output during the run, or None), ``run_fn``, ``command``.

    Returns
    -------
    dict
        ``{"status": "done", "result": <JSON-ready scene result>, ...}``, or
        ``{"status": "error", "error": ..., "traceback": ...}`` when the run raised; both with
        ``host``, ``pid`` and ``wall_s``.
    """
    spec = task["spec"]  # a sim.evaluate.sweep.RunSpec
    t0 = time.perf_counter()
    where = {"host": socket.gethostname(), "pid": os.getpid()}
    with _output_to(task.get("log")):
        try:
            res = task["run_fn"](spec.scene, spec.config, Path(task["run_dir"]))
            try:
                pictures.write_scene_pictures(res, Path(task["picture_dir"]))
            except Exception as err:  # pictures must not sink the numbers
                log.warning("%s: pictures failed: %s", res.get("scene"), err)
                res["pictures_error"] = f"{type(err).__name__}: {err}"
            result = report.jsonable_scene(res)
            if task.get("report"):
                meta = run_meta(spec.config, task.get("command", ""))
                meta["scene_hashes"][result["scene"]] = result.get("scene_hash")
                report.write_results({"scenes": {result["scene"]: result}, "meta": meta},
                                     Path(task["run_dir"]))
        except Exception as err:
            return {"status": "error", "error": f"{type(err).__name__}: {err}",
                    "traceback": traceback.format_exc(), "wall_s": time.perf_counter() - t0,
                    **where}
    return {"status": "done", "result": result, "wall_s": time.perf_counter() - t0, **where}


@contextlib.contextmanager
def _output_to(path):
    """Send this process's stdout and stderr (file descriptors 1 and 2: Python, C++ and
    subprocesses alike) to ``path`` while the block runs; nothing when ``path`` is None."""
    if path is None:
        yield
        return
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    with open(path, "ab") as fh:
        os.dup2(fh.fileno(), 1)
        os.dup2(fh.fileno(), 2)
        try:
            yield
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)


def _child(task: dict, conn, parent: int) -> None:
    """Entry of a local worker process: run the task, send its outcome, exit. Ctrl-C is the
    parent's to handle (it ends its workers); a killed parent takes its workers with it."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    workers.die_with_parent(parent)
    outcome = execute(task)
    conn.send(outcome)
    conn.close()


# ---------------------------------------------------------------------------- backends


class _Inline:
    """Runs in this process, one after the other (nothing can be retried: a crash ends the
    sweep, and ``resume`` goes on from the runs recorded)."""

    capacity = 1

    def __init__(self):
        self._tasks: dict[int, dict] = {}

    def submit(self, task: dict):
        key = len(self._tasks)
        self._tasks[key] = task
        return key

    def wait(self, handles: list) -> list[tuple[object, dict]]:
        h = handles[0]
        return [(h, execute(self._tasks.pop(h)))]

    def close(self, cancel: bool = False) -> None:
        pass


class _Local:
    """A fresh spawned worker process per run, ``jobs`` at a time; a process that ends without
    sending its outcome died."""

    def __init__(self, jobs: int):
        self.capacity = jobs
        self._ctx = multiprocessing.get_context("spawn")
        self._live: dict[int, tuple] = {}

    def submit(self, task: dict):
        recv, send = self._ctx.Pipe(duplex=False)
        proc = self._ctx.Process(target=_child, args=(task, send, os.getpid()),
                                 name=f"sweep-{task['spec'].run_id}")
        proc.start()
        send.close()  # the child holds the only sending end: its death reads as EOF here
        self._live[proc.sentinel] = (proc, recv)
        return proc.sentinel

    def wait(self, handles: list) -> list[tuple[object, dict]]:
        objs = {}
        for h in handles:
            proc, recv = self._live[h]
            objs[recv] = h
            objs[proc.sentinel] = h
        ready = {objs[o] for o in multiprocessing.connection.wait(list(objs))}
        out = []
        for h in ready:
            proc, recv = self._live.pop(h)
            msg = None
            try:
                msg = recv.recv()  # blocks only until the child's send or its death
            except (EOFError, OSError):
                pass
            recv.close()
            proc.join()
            if msg is None:
                msg = {"status": "died", "error": _exit_text(proc.exitcode)}
            out.append((h, msg))
        return out

    def close(self, cancel: bool = False) -> None:
        for proc, recv in self._live.values():
            if cancel and proc.is_alive():
                proc.kill()  # SIGTERM: glog's handler (pycolmap) would dump a native stack
            proc.join()
            recv.close()
        self._live.clear()


def _exit_text(code: int | None) -> str:
    if code is not None and code < 0:
        try:
            return f"the worker process was killed by signal {signal.Signals(-code).name}"
        except ValueError:
            return f"the worker process was killed by signal {-code}"
    return f"the worker process ended with exit code {code} before returning its result"


class _Ray:
    """Ray tasks (one CPU each) on an existing cluster or a local one started here."""

    def __init__(self, sweep):
        try:
            import ray  # an optional extra (--backend ray): only when asked for
        except ImportError:
            raise SweepError(f"--backend ray needs Ray, which is not installed: {RAY_EXTRA} "
                             "(or pip install ray)") from None
        self.ray = ray
        self.started = False
        if not ray.is_initialized():
            kw = ({"address": sweep.address} if sweep.address
                  else {"num_cpus": sweep.jobs, "include_dashboard": False})
            try:
                ray.init(**kw, log_to_driver=False, logging_level=logging.WARNING)
            except (ConnectionError, RuntimeError, ValueError) as err:
                where = (f"the Ray cluster at {sweep.address!r}" if sweep.address
                         else "a local Ray cluster")
                raise SweepError(f"cannot start or reach {where}: {err}; check the address "
                                 "(`ray status` on the head node shows the cluster)") from err
            self.started = True
        self.capacity = sweep.jobs or 1_000_000  # the cluster queues what it cannot run yet
        # retries are the sweep's own (the same for every backend): none inside Ray
        self._remote = ray.remote(num_cpus=1, max_retries=0)(execute)
        self._live: set = set()

    def submit(self, task: dict):
        ref = self._remote.remote(task)
        self._live.add(ref)
        return ref

    def wait(self, handles: list) -> list[tuple[object, dict]]:
        ray = self.ray
        ready, _ = ray.wait(handles, num_returns=1)
        out = []
        for ref in ready:
            self._live.discard(ref)
            try:
                msg = ray.get(ref)
            except ray.exceptions.RayTaskError as err:  # execute catches the run's own errors
                msg = {"status": "error", "error": str(err).splitlines()[0][:500],
                       "traceback": str(err)}
            except ray.exceptions.RayError as err:  # the worker or its node died
                msg = {"status": "died", "error": f"{type(err).__name__}: "
                       f"{str(err).splitlines()[0][:300] if str(err) else ''}"}
            out.append((ref, msg))
        return out

    def close(self, cancel: bool = False) -> None:
        if cancel:
            for ref in self._live:
                with contextlib.suppress(Exception):
                    self.ray.cancel(ref, force=True)
        self._live.clear()
        if self.started:
            self.ray.shutdown()


def make_backend(sweep):
    """The backend of a :class:`~sim.evaluate.sweep.SweepConfig`: Ray, this process, or
    local worker processes."""
    if sweep.backend == "ray":
        return _Ray(sweep)
    return _Inline() if sweep.inline else _Local(sweep.jobs)
