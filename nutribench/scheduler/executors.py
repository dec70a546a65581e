"""Executors the scheduler runs jobs on, and the side channel their progress takes.

The scheduler only uses the ``concurrent.futures.Executor`` interface (``submit`` and the
futures it returns). Progress is a side channel chosen with the executor, because a job's
worker cannot share a queue with the driver in every setting:

* ``local`` (default): :class:`~nutribench.scheduler.local.LocalProcessExecutor`, one fresh
  process per job; progress events travel through that job's own pipe.
* ``dask://HOST:PORT``: ``distributed.Client(...).get_executor()``; progress events are dask
  worker events (``Worker.log_event`` on a topic this run subscribes to).
* any other ``Executor`` (library use): no live progress; jobs still report when done and the
  driver still heartbeats them.
"""

from __future__ import annotations

import os
import queue
import uuid
from collections.abc import Callable
from concurrent.futures import Executor
from contextlib import suppress
from dataclasses import dataclass, field
from typing import Any

from nutribench.errors import UserError
from nutribench.scheduler.worker import Sink

# Imported by the fork server once, so that each job's process starts with them loaded.
PRELOAD = ("nutribench.scheduler.preload",)


class ExecutorError(UserError):
    """A bad ``--executor`` value or an unreachable cluster (one line for users)."""


def core_count() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


class DaskSink:
    """Progress sink for jobs on a dask cluster: a worker event on ``topic`` (picklable)."""

    def __init__(self, topic: str):
        self.topic = topic

    def __call__(self, event: dict[str, Any]) -> None:
        with suppress(ImportError, ValueError):  # not inside a dask worker
            from distributed import get_worker

            get_worker().log_event(self.topic, event)


@dataclass
class ExecutorHandle:
    """An executor plus what the scheduler needs around it."""

    executor: Executor
    slots: int  # jobs kept in flight at once
    description: str
    sink: Sink | None = None  # picklable; handed to each job
    events: queue.Queue = field(default_factory=queue.Queue)  # progress events at the driver
    _terminate: Callable[[], None] = lambda: None  # stops what the executor's shutdown leaves running
    _close: Callable[[], None] = lambda: None  # releases what the executor holds (a cluster's client)

    def drain(self) -> list[dict[str, Any]]:
        return [self.events.get_nowait() for _ in range(self.events.qsize())]  # the driver is its one reader

    def terminate_running(self) -> None:
        """Stop the jobs in flight (Ctrl-C): their outcomes will be ignored."""
        try:
            self.executor.shutdown(wait=False, cancel_futures=True)
        except TypeError:  # pragma: no cover - executors without cancel_futures
            self.executor.shutdown(wait=False)
        self._terminate()

    def close(self) -> None:
        try:
            self.executor.shutdown(wait=True)
        finally:
            self._close()


def local_executor(workers: int) -> ExecutorHandle:
    from nutribench.scheduler.local import LocalProcessExecutor, PipeSink

    events: queue.Queue = queue.Queue()
    ex = LocalProcessExecutor(workers, on_progress=events.put, preload=PRELOAD)
    about = f"{workers} local worker process{'es' if workers != 1 else ''}"
    return ExecutorHandle(ex, workers, about, PipeSink(), events, _terminate=ex.terminate_running)


def dask_executor(address: str, workers: int | None) -> ExecutorHandle:
    try:
        from distributed import Client
    except ImportError:
        raise ExecutorError("--executor dask://... needs dask.distributed: pip install 'nutribench[dask]'") from None
    try:
        client = Client(address, timeout="10s", set_as_default=False)
    except (OSError, TimeoutError) as e:
        raise ExecutorError(f"cannot reach the dask scheduler at {address}: {e}") from None
    threads = sum(client.nthreads().values())
    slots = workers or max(threads, 1)
    topic = f"nutribench-progress-{uuid.uuid4().hex[:12]}"
    events: queue.Queue = queue.Queue()

    def handler(event) -> None:  # (timestamp, msg) from the scheduler
        msg = event[1] if isinstance(event, tuple) and len(event) == 2 else event
        if isinstance(msg, dict):
            events.put(msg)

    client.subscribe_topic(topic, handler)

    def close() -> None:
        try:
            client.unsubscribe_topic(topic)
        finally:
            client.close()

    about = f"dask cluster {address} ({len(client.nthreads())} workers, {threads} threads)"
    return ExecutorHandle(client.get_executor(pure=False), slots, about, DaskSink(topic), events, _close=close)


def dask_address(spec: str | None) -> str | None:
    """The dask scheduler's address ``spec`` names (``dask://HOST:PORT`` as ``tcp://HOST:PORT``;
    ``tcp://`` and ``tls://`` as given); None for ``local``; :class:`ExecutorError` for anything else."""
    v = (spec or "local").strip()
    if v == "local":
        return None
    for prefix in ("dask://", "tcp://", "tls://"):
        if v.startswith(prefix) and len(v) > len(prefix):
            return ("tcp://" + v[len(prefix) :]) if prefix == "dask://" else v
    raise ExecutorError(f"unknown --executor '{spec}': use 'local' or 'dask://HOST:PORT'")


def probe_executor(spec: str | None) -> None:
    """Raise :class:`ExecutorError` now if ``spec`` is unknown or names a dask scheduler that
    cannot be reached, so that ``run`` fails before it creates or writes the database."""
    if dask_address(spec) is not None:
        handle, _ = make_executor(spec, None, 1)
        handle.close()


def make_executor(spec: str | None, workers: int | None, n_jobs: int) -> tuple[ExecutorHandle, str | None]:
    """``local`` or ``dask://HOST:PORT`` (or ``tcp://``, ``tls://``). Returns the handle and a
    note for the user when the worker count was reduced."""
    address = dask_address(spec)
    if address is None:
        cores = core_count()
        n = max(1, min(workers or cores, cores, n_jobs))
        more = workers is not None and workers > cores
        note = f"--workers {workers} is more than the {cores} cores here: using {n}" if more else None
        return local_executor(n), note
    handle = dask_executor(address, workers)
    handle.slots = max(1, min(handle.slots, n_jobs))
    return handle, None
