"""What a run uses when it is not told: the function that runs one job (the training job, or
the synthetic one of a dry run with ``$NUTRIBENCH_JOB=fake``), the batched engine's worker
function and the driver's owner token (:func:`nutribench.scheduler.driver.run_grid`)."""

from __future__ import annotations

import os
import socket
import uuid
from collections.abc import Callable

from nutribench.scheduler.registration import RunError
from nutribench.scheduler.worker import JobFn


def default_batch_fn() -> Callable:
    """The batched engine's worker function (``$NUTRIBENCH_JOB=fake``: the synthetic job per spec)."""
    if os.environ.get("NUTRIBENCH_JOB", "").strip() == "fake":
        from nutribench.scheduler.synthetic import synthetic_batch

        return synthetic_batch
    from nutribench.scheduler.batched_job import run_batch

    return run_batch


def job_choice() -> str:
    """``$NUTRIBENCH_JOB``: ``"fake"`` (the synthetic job) or ``"real"`` (unset); another value is
    a one-line :class:`RunError`. Checked before a run starts, without importing the real job
    (it imports torch)."""
    choice = os.environ.get("NUTRIBENCH_JOB", "").strip()
    if choice not in ("", "real", "fake"):
        raise RunError(f"NUTRIBENCH_JOB={choice}: use 'fake' (synthetic jobs) or leave it unset")
    return choice or "real"


def default_job_fn() -> JobFn:
    """``$NUTRIBENCH_JOB=fake`` (tests, dry runs): the synthetic job; else the real one."""
    if job_choice() == "fake":
        from nutribench.scheduler.synthetic import synthetic_job

        return synthetic_job
    try:
        from nutribench.scheduler.single_job import run_job
    except ImportError as e:
        raise RunError(f"the training job cannot be imported ({e}): is nutribench fully installed?") from None
    return run_job


def driver_token() -> str:
    """A unique owner token for one driver: host, process id and a random part (the jobs it claims carry it)."""
    return f"{socket.gethostname()[:80]}:{os.getpid()}:{uuid.uuid4().hex[:12]}"
