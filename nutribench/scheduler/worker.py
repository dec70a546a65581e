"""The worker side of a job: what it receives and returns (:class:`JobSpec` in,
:class:`JobResult` out: pure, picklable data, no database handle), the entry point every
executor runs, thread limits, and the throttled progress reporter.

A worker never touches the database. It reports progress through ``sink`` (a picklable
callable given by the executor: a pipe to the driver for the local pool, a dask event topic
on a cluster, or nothing), and returns a :class:`JobResult` or raises :class:`JobFailed`.
"""

from __future__ import annotations

import os
import socket
import sys
import time
import traceback
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class JobSpec:
    """One job: train ``agent_config`` on ``regime_config`` with ``seed`` for ``episodes``
    episodes, then evaluate it on ``eval_episodes`` fixed food streams.

    The config objects travel with the spec (an :class:`~nutribench.config.EnvConfig` and an
    agent config), so a worker never rereads a file that may have changed since the driver
    recorded its hash; ``*_sha256`` are those recorded hashes, checked by the worker.
    ``device``: where the batched engine trains the job (``--device``: ``auto``, ``cpu``,
    ``cuda`` or ``cuda:N``, resolved in the worker); the SB3 engine trains on the CPU.
    ``tensorboard``: a folder (on the worker's machine) under which the job writes its
    training diagnostics as TensorBoard events, in a folder of its own (:attr:`run_name`).
    ``eval_every``: every so many training days the greedy policy plays ``val_episodes``
    validation days (:mod:`nutribench.agents.validation`); 0: never (the default).
    """

    job_id: int
    regime: str
    regime_version: int
    regime_sha256: str
    algo: str
    algo_version: int
    algo_sha256: str
    seed: int
    episodes: int
    eval_episodes: int
    model_path: str
    regime_config: Any = field(repr=False, compare=False)
    agent_config: Any = field(repr=False, compare=False)
    attempt: int = 1
    device: str = "cpu"
    tensorboard: str | None = None
    eval_every: int = 0
    val_episodes: int = 5

    @property
    def label(self) -> str:
        return f"{self.regime} {self.algo} seed {self.seed}"

    @property
    def run_name(self) -> str:
        """The job's TensorBoard run folder: ``job<id>-<algo>-<regime>-seed<seed>``."""
        return f"job{self.job_id}-{self.algo}-{self.regime}-seed{self.seed}"


@dataclass
class JobResult:
    """Everything a finished job hands back to the driver, which stores it in one transaction.

    ``train`` / ``eval``: one dict per episode with ``episode`` (0-based) and the metric keys
    of :data:`nutribench.env.metrics.METRIC_KEYS` plus ``entropy``. ``eval_steps``: one dict
    per evaluation step (``episode``, ``step`` 1..H, ``food``, ``action``, ``C``, ``F``,
    ``P``, ``reward``). ``metadata``: reproducibility facts (see :mod:`nutribench.provenance`)
    plus ``started_at``, ``finished_at`` (naive UTC) and ``wall_seconds``. ``diagnostics``:
    one dict per training update, keyed by :data:`nutribench.diagnostics.COLUMNS` (absent
    quantities are NULL). ``validation``: one dict per validation day of each evaluation
    during training: ``train_day``, ``episode`` and the metric keys of ``eval``.
    """

    job_id: int
    train: list[dict[str, Any]]
    eval: list[dict[str, Any]]
    eval_steps: list[dict[str, Any]]
    metadata: dict[str, Any]
    model_path: str | None = None
    diagnostics: list[dict[str, Any]] = field(default_factory=list)
    validation: list[dict[str, Any]] = field(default_factory=list)


class JobFailed(RuntimeError):
    """A job raised: carries the worker's formatted traceback as text (always picklable)."""

    def __init__(self, message: str, traceback_text: str = ""):
        super().__init__(message)
        self.traceback_text = traceback_text

    def __reduce__(self):
        return (JobFailed, (self.args[0], self.traceback_text))


PROGRESS_INTERVAL_S = 1.0  # at most one progress event per job per second
RECENT_EPISODES = 20  # "recent return" = mean over this many training episodes

Sink = Callable[[dict[str, Any]], None]
JobFn = Callable[[JobSpec, Sink | None], JobResult]


#: The BLAS / OpenMP thread variables a job runs with (``1`` unless already set)
THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


@contextmanager
def one_thread() -> Iterator[None]:
    """One worker = one job = one thread of torch / BLAS while the block runs (the variables
    set before a fresh worker imports torch); afterwards the variables and torch's thread count
    are as they were, so that an executor running jobs in the caller's own process (a dask
    cluster of threads) leaves that process as it found it."""
    saved = {var: os.environ.get(var) for var in THREAD_VARIABLES}
    for var in THREAD_VARIABLES:
        os.environ.setdefault(var, "1")
    torch = sys.modules.get("torch")
    threads = torch.get_num_threads() if torch is not None else None
    if torch is not None:
        torch.set_num_threads(1)
    try:
        yield
    finally:
        for var, value in saved.items():
            if value is None:
                os.environ.pop(var, None)
            else:
                os.environ[var] = value
        if torch is not None and threads is not None:
            torch.set_num_threads(threads)


@dataclass(eq=False)
class JobProgress:
    """Throttled progress events of one job: ``start``, then ``episode`` (k done of n, mean
    recent return) at most every ``interval`` seconds and at the last episode.

    An ``episode`` event also says from which day this process trained (``k0``: the days done
    before it, by a batch resumed from a checkpoint; 0 otherwise) and, given ``wall`` (a
    callable), this job's training seconds so far, those before a resume included: what
    ``nutribench run`` and ``nutribench status`` price the rest of a resumed batch by."""

    spec: JobSpec
    sink: Sink | None
    interval: float = PROGRESS_INTERVAL_S
    wall: Callable[[], float] | None = None
    recent: deque[float] = field(init=False, default_factory=lambda: deque(maxlen=RECENT_EPISODES))
    k0: int | None = field(init=False, default=None)  # the days done before this process trained its first
    _last: float = field(init=False, default=0.0)

    def _send(self, event: dict[str, Any]) -> None:
        if self.sink is None:
            return
        with suppress(Exception):  # progress is best effort; it never fails a job
            self.sink({"job_id": self.spec.job_id, "time": time.time(), **event})

    def start(self) -> None:
        self._last = time.monotonic()
        self._send({"kind": "start", "pid": os.getpid(), "host": socket.gethostname(), "k": 0, "n": self.spec.episodes})

    def episode(self, k_done: int, ret: float | None) -> None:
        if self.k0 is None:
            self.k0 = k_done - 1
        if ret is not None:
            self.recent.append(float(ret))
        now = time.monotonic()
        if now - self._last >= self.interval or k_done >= self.spec.episodes:
            self._last = now
            mean = sum(self.recent) / len(self.recent) if self.recent else None
            wall = self.wall() if self.wall is not None else None
            self._send(
                {"kind": "episode", "k": k_done, "k0": self.k0, "n": self.spec.episodes, "ret": mean, "wall": wall}
            )

    def phase(self, name: str) -> None:
        self._send({"kind": "phase", "phase": name})


def execute(fn: Callable[..., Any], spec: JobSpec | list[JobSpec], sink: Sink | None = None) -> Any:
    """Run one job (``fn`` a :data:`JobFn`) or one batch of jobs (the batched engine's ``fn``:
    one result per spec; an exception fails the whole batch) in a worker, with one thread; any
    exception comes back as a picklable :class:`JobFailed`."""
    try:
        with one_thread():
            return fn(spec, sink)
    except JobFailed:
        raise
    except Exception as e:
        raise JobFailed(f"{type(e).__name__}: {e}", traceback.format_exc()) from None
