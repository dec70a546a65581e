"""A ``concurrent.futures.Executor`` that runs each job in its own fresh process.

Why not ``ProcessPoolExecutor``: when one of its workers dies (kill -9, the out-of-memory
killer) the whole pool is declared broken and every running and queued future fails. Here a
job owns its process and a private pipe, so a death fails only that job's future (with
:class:`WorkerDied`, naming the signal), and the pipe also carries the job's progress events
to the driver, with no shared queue that a dying process could corrupt. A process per job
also frees all of a job's memory when it ends; with the ``forkserver`` start method and the
heavy modules preloaded, starting one costs milliseconds (jobs run minutes to hours).

Workers run in a session of their own (``os.setsid``: a terminal's Ctrl-C goes to its foreground
process group, the driver's, so only the driver decides what it does; no signal handler is
installed outside the command line) and exit by themselves if the driver dies (a watchdog thread sees the driver's end of a pipe close).
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import threading
from collections import deque
from collections.abc import Callable
from concurrent.futures import Executor, Future
from contextlib import suppress
from multiprocessing.connection import Connection, wait
from typing import Any

from nutribench.scheduler.worker import Sink

_CHANNEL: Connection | None = None  # in a worker: its pipe to the driver


class WorkerDied(RuntimeError):
    """The process running a job ended without returning its outcome."""


class PipeSink:
    """Progress sink of a job run by :class:`LocalProcessExecutor` (picklable, stateless):
    sends each event through the worker's own pipe. A no-op anywhere else."""

    def __call__(self, event: dict[str, Any]) -> None:
        if _CHANNEL is not None:
            _CHANNEL.send(("progress", event))


def _watch_driver(alive: Connection) -> None:
    with suppress(EOFError, OSError):
        alive.recv()  # the driver never sends: this returns only when its end closes
    os._exit(70)


def _child_main(result: Connection, alive: Connection, fn: Callable, args: tuple, kwargs: dict) -> None:
    global _CHANNEL
    os.setsid()  # out of the terminal's process group: a Ctrl-C reaches the driver only, which decides
    _CHANNEL = result
    threading.Thread(target=_watch_driver, args=(alive,), daemon=True).start()
    try:
        msg = ("result", fn(*args, **kwargs))
    except BaseException as e:  # noqa: BLE001 - everything goes back to the driver
        msg = ("error", e)
    try:
        result.send(msg)
    except Exception as e:  # the outcome could not be pickled
        result.send(("error", RuntimeError(f"the job's outcome could not be sent back: {type(e).__name__}: {e}")))
    result.close()


def describe_exit(pid: int | None, exitcode: int | None) -> str:
    if exitcode is not None and exitcode < 0:
        try:
            name = signal.Signals(-exitcode).name
        except ValueError:
            name = f"signal {-exitcode}"
        why = " (kill -9, or the out-of-memory killer)" if -exitcode == signal.SIGKILL else ""
        return f"worker process {pid} was killed by {name}{why}"
    if exitcode == 70:
        return f"worker process {pid} exited because its driver went away"
    return f"worker process {pid} exited with status {exitcode} without returning a result"


class _Running:
    __slots__ = ("future", "process", "conn", "alive", "final")

    def __init__(self, future, process, conn, alive):
        self.future, self.process, self.conn, self.alive, self.final = future, process, conn, alive, False


class LocalProcessExecutor(Executor):
    """At most ``max_workers`` jobs at once, each in a new process.

    ``on_progress(event)`` is called (in the executor's thread) for each progress event a job
    sends through :class:`PipeSink`.
    """

    def __init__(self, max_workers: int, on_progress: Sink | None = None, preload: tuple[str, ...] = ()):
        if max_workers < 1:
            raise ValueError("max_workers must be at least 1")
        method = "forkserver" if "forkserver" in mp.get_all_start_methods() else "spawn"
        self._ctx = mp.get_context(method)
        if method == "forkserver" and preload:
            self._ctx.set_forkserver_preload(list(preload))
        self.max_workers = max_workers
        self._on_progress = on_progress
        self._queue: deque = deque()
        self._running: dict[Connection, _Running] = {}
        self._lock = threading.Lock()
        self._wake_r, self._wake_w = mp.Pipe(duplex=False)
        self._shutdown = False
        self._thread = threading.Thread(target=self._loop, name="nutribench-local-executor", daemon=True)
        self._thread.start()

    # ---- Executor interface ----
    def submit(self, fn, /, *args, **kwargs) -> Future:
        with self._lock:
            if self._shutdown:
                raise RuntimeError("cannot schedule new futures after shutdown")
            future: Future = Future()
            self._queue.append((future, fn, args, kwargs))
        self._wakeup()
        return future

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        with self._lock:
            self._shutdown = True
            if cancel_futures:
                while self._queue:
                    self._queue.popleft()[0].cancel()
        self._wakeup()
        if wait:
            self._thread.join()

    # ---- extras ----
    def terminate_running(self, grace: float = 5.0) -> None:
        """SIGTERM every running job's process, SIGKILL those still alive after ``grace`` s."""
        with self._lock:
            procs = [r.process for r in self._running.values()]
        # The executor's thread may reap (and close) a process meanwhile: a closed process
        # object raises ValueError, and is already gone.
        for p in procs:
            with suppress(ValueError):
                if p.is_alive():
                    p.terminate()
        for p in procs:
            with suppress(ValueError):
                p.join(grace)
                if p.is_alive():
                    p.kill()
                    p.join(1.0)

    # ---- internals ----
    def _wakeup(self) -> None:
        with suppress(OSError):
            self._wake_w.send_bytes(b"x")

    def _start_queued(self) -> None:
        while self._queue and len(self._running) < self.max_workers:
            future, fn, args, kwargs = self._queue.popleft()
            if not future.set_running_or_notify_cancel():
                continue
            conn_r, conn_w = self._ctx.Pipe(duplex=False)
            alive_r, alive_w = self._ctx.Pipe(duplex=False)
            process = self._ctx.Process(target=_child_main, args=(conn_w, alive_r, fn, args, kwargs), daemon=False)
            try:
                process.start()
            except Exception as e:
                for c in (conn_r, conn_w, alive_r, alive_w):
                    c.close()
                future.set_exception(WorkerDied(f"could not start a worker process: {e}"))
                continue
            conn_w.close()
            alive_r.close()
            self._running[conn_r] = _Running(future, process, conn_r, alive_w)

    def _read(self, run: _Running) -> None:
        """Read every message available on a job's pipe."""
        while not run.final:
            try:
                if not run.conn.poll(0):
                    return
                kind, payload = run.conn.recv()
            except (EOFError, OSError):
                return
            if kind == "progress":
                if self._on_progress is not None:
                    with suppress(Exception):
                        self._on_progress(payload)
            else:
                run.final = True
                if not run.future.done():
                    (run.future.set_result if kind == "result" else run.future.set_exception)(payload)

    def _reap(self, run: _Running) -> None:
        self._read(run)
        run.process.join()
        if not run.final and not run.future.done():
            run.future.set_exception(WorkerDied(describe_exit(run.process.pid, run.process.exitcode)))
        run.conn.close()
        run.alive.close()
        run.process.close()

    def _loop(self) -> None:
        while True:
            with self._lock:
                self._start_queued()
                if self._shutdown and not self._queue and not self._running:
                    break
                runs = list(self._running.values())
            handles = [self._wake_r] + [r.conn for r in runs if not r.final] + [r.process.sentinel for r in runs]
            ready = set(wait(handles, timeout=1.0))
            if self._wake_r in ready:
                while self._wake_r.poll(0):
                    self._wake_r.recv_bytes()
            for run in runs:
                if run.conn in ready:
                    self._read(run)
                if run.process.sentinel in ready or (run.final and not run.process.is_alive()):
                    with self._lock:
                        self._running.pop(run.conn, None)
                    self._reap(run)
        self._wake_r.close()
        self._wake_w.close()
