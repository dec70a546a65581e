"""What a worker receives and returns: pure, picklable data (no database handle)."""

from __future__ import annotations

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
