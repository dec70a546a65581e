"""What one :func:`~nutribench.scheduler.driver.run_grid` call runs, as one settings object,
what ``nutribench run`` checks of it and says before and after it runs, and the functions that
run a job and a batch when it is not told (the training job, or the synthetic one of a dry run
with ``$NUTRIBENCH_JOB=fake``; the batched engine's worker function).

:class:`GridSettings` holds the grid (regimes x agent configs x seeds, the budgets) and how it
runs (database, workers, executor, engine, device, models and TensorBoard folders, evaluation
during training). :meth:`GridSettings.check` refuses, in one line each, everything a user can
get wrong (an unknown executor, an engine option it cannot take such as ``--device cuda``
where there is no CUDA, a models folder that is a file, a database path that cannot be written
or an in-memory one, a bad ``$NUTRIBENCH_CHECKPOINT_SECONDS``, a broken config file, evaluation
during training asked of a plug-in) before the database file is created.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from nutribench.engines import Engine
from nutribench.errors import UserError
from nutribench.scheduler.executors import dask_address
from nutribench.scheduler.grid import Grid
from nutribench.scheduler.pools import MAX_BATCH, check_engine
from nutribench.scheduler.registration import RunError, load_grid_configs
from nutribench.scheduler.worker import JobFn
from nutribench.store.engine import (
    StoreError,
    check_sqlite_file,
    database_url,
    hide_secrets,
    in_memory,
    shown_db,
    sqlite_path,
)


@dataclass(frozen=True)
class GridSettings:
    """One run of the grid ``regimes`` x ``algos`` x ``seeds``, each job ``episodes`` training
    days and ``eval_episodes`` evaluation days, into the database ``db``.

    ``workers``: jobs at once (None: the cores); ``executor``: ``local`` or ``dask://HOST:PORT``;
    ``job_fn``/``batch_fn``: what runs one job / one batch (None: :func:`default_job_fn`, :func:`default_batch_fn`);
    ``models_dir``: where trained models go (None: ``models/`` next to the database);
    ``display``: the live progress view; ``retry_failed``: jobs that failed
    :data:`~nutribench.scheduler.lifecycle.MAX_FAILURES` times are tried again.
    ``engine="batched"``: each agent config's jobs train in batches of at most ``max_batch``,
    one per worker, on ``device`` (``auto``: CUDA where a worker has it; the SB3 engine takes
    ``auto`` or ``cpu``). ``tensorboard``: a folder; each job writes its training diagnostics
    there as TensorBoard events, in a run folder of its own. ``eval_every``: every so many
    training days, a greedy evaluation on ``val_episodes`` validation days (stored)."""

    db: str | os.PathLike[str]
    regimes: Sequence[str]
    algos: Sequence[str]
    seeds: Sequence[int]
    episodes: int
    eval_episodes: int = 5
    workers: int | None = None
    executor: str = "local"
    job_fn: Callable | None = None
    models_dir: str | os.PathLike[str] | None = None
    display: bool = True
    retry_failed: bool = False
    engine: str = Engine.SB3
    batch_fn: Callable | None = None
    max_batch: int = MAX_BATCH
    device: str = "auto"
    tensorboard: str | os.PathLike[str] | None = None
    eval_every: int | None = None
    val_episodes: int = 5

    @classmethod
    def of(cls, grid: Grid, db: str | os.PathLike[str], **how: Any) -> GridSettings:
        """The settings that run ``grid`` into ``db`` (``how``: the other fields)."""
        return cls(db, grid.regimes, grid.algos, grid.seeds, grid.episodes, grid.eval_episodes, **how)

    @property
    def grid(self) -> Grid:
        """The grid these settings run."""
        return Grid(tuple(self.regimes), tuple(self.algos), tuple(self.seeds), self.episodes, self.eval_episodes)

    @property
    def models(self) -> Path:
        """Where trained models go: ``models_dir``, else ``models/`` next to a SQLite file, else in
        the current folder."""
        if self.models_dir is not None:
            return Path(self.models_dir)
        path = sqlite_path(database_url(str(self.db)))
        return (path.parent if path is not None else Path.cwd()) / "models"

    def check(self) -> None:
        """Every check ``nutribench run`` makes before the database file exists (see the module
        docstring), each a one-line :class:`~nutribench.errors.UserError`."""
        from nutribench.engine import every_seconds_from_env
        from nutribench.safe_write import check_folder_target, check_tensorboard

        dask_address(self.executor)
        check_engine(self.engine, self.max_batch, self.device)
        # a models folder that cannot be one (a file, a path through a file, not writable): each job
        # would train and then fail to save
        what, hint = ("the models folder", " (--models-dir)") if self.models_dir is None else ("--models-dir", "")
        check_folder_target(self.models, what, RunError, f"give a folder for the trained models{hint}")
        if self.tensorboard is not None:
            check_tensorboard(Path(self.tensorboard))
        check_db(str(self.db))
        try:  # a bad $NUTRIBENCH_CHECKPOINT_SECONDS
            every_seconds_from_env()
        except ValueError as exc:
            raise RunError(str(exc)) from None
        _, agent_cfgs = load_grid_configs(self.grid)  # a broken config file fails here
        check_eval_every_agents(self.eval_every or 0, agent_cfgs)
        if self.job_fn is None:
            job_choice()  # a bad $NUTRIBENCH_JOB

    def starting_line(self) -> str:
        """What the run starts, printed as soon as its options are checked, before the database
        is opened and the workers start: the first line the run writes to a log file."""
        grid, where = self.grid, shown_db(str(self.db))
        at = "" if self.workers is None else f", {self.workers} at a time"
        return (
            f"nutribench run: {_n(len(grid), 'job')} ({_n(len(grid.regimes), 'regime')} x "
            f"{_n(len(grid.algos), 'agent')} {', '.join(grid.algos)} x seeds {', '.join(map(str, grid.seeds))}; "
            f"{_n(grid.episodes, 'training day')} and {_n(grid.eval_episodes, 'evaluation day')} each; "
            f"{self.engine} engine{at}) into {where}: opening it, then the jobs not done yet"
        )


def _n(count: int, word: str) -> str:
    return f"{count:,} {word}{'' if count == 1 else 's'}"


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


def check_db(db: str) -> None:
    """Refuse a database path that cannot be created or is not SQLite, and an in-memory database
    (every result would be lost), before anything runs."""
    url = database_url(db)
    if in_memory(url):
        raise StoreError(
            f"--db {hide_secrets(db)}: an in-memory SQLite database is lost when `run` ends, with every result: "
            "give a file path (e.g. --db nutribench.db)"
        )
    path = sqlite_path(url)
    if path is not None:
        check_sqlite_file(path, create=True)


def check_eval_every_agents(eval_every: int, agent_cfgs: Sequence[Any]) -> None:
    """Evaluation during training runs in the built-in algorithms' loops: a plug-in agent
    (an entry point) is refused, in one line, before anything is written."""
    plugins = [a.name for a in agent_cfgs if getattr(a.obj, "entry_point", None)]
    if eval_every and plugins:
        raise UserError(
            f"--eval-every: {', '.join(plugins)} trains in its own loop (a plug-in agent), which evaluation "
            "during training cannot enter; leave them out of this run or drop --eval-every"
        )


def paper_grid_question(grid: Grid) -> str:
    """What a bare ``nutribench run`` starts (the paper grid), with its cost estimate."""
    import nutribench.agents.registry as registry
    from nutribench.agents.config import load_agent_config

    hours = grid.cpu_hours(lambda name: registry.algorithm(load_agent_config(name)).cost)
    return (
        f"the paper grid: {len(grid.cells())} jobs ({len(grid.regimes)} regimes x {len(grid.algos)} agents x "
        f"{len(grid.seeds)} seeds) x {grid.episodes} days, about {hours:.0f} CPU-hours with the SB3 engine "
        "(an estimate from the agents' relative costs)"
    )
